"""The plan you check is the plan you fly (issue 40): ``hikoboshi plan pass --out p.json``,
``hikoboshi plan upload p.json`` to a running ground, a pass of the stored plan flown by the
spacecraft process; the commands the vehicle executed are the file's, command for command,
number for number."""

from __future__ import annotations

import asyncio
import json
import os
import re
import subprocess
import sys
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import httpx
import pytest

from server.storage import repository as repo
from server.storage.db import sqlite_url
from spacecraft.process import SpacecraftProcess
from tests.server.link.harness import (
    OPERATOR,
    Ground,
    connected,
    running_ground,
    settled,
    spacecraft,
    wait_for,
)
from tests.support.flight import flying

pytestmark = pytest.mark.realtime  # flies a vehicle over a live link in wall time

#: A pass of PTP alone with short settles: 217 joint commands, 54 s (5.4 s at 10x).
PASS = ("experiments=ptp", "ptp_settle_s=0.25", "transfer_settle_s=0.25")


def _hikoboshi(*args: str, env: dict[str, str] | None = None) -> str:
    done = subprocess.run(
        [sys.executable, "-m", "hikoboshi", *args],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, **(env or {})},
        check=False,
    )
    assert done.returncode == 0, done.stderr
    return done.stdout


async def _fly(ground: Ground, pass_id: str, name: str) -> SpacecraftProcess:
    process, _ = spacecraft(ground)
    async with flying(process), httpx.AsyncClient(base_url=ground.url) as client:
        await connected(client)
        response = await client.post(
            f"/api/passes/{pass_id}/start", json={"confirm": f"START {name}"}, headers=OPERATOR
        )
        assert response.status_code == 200, response.text
        await wait_for(lambda: settled(ground, pass_id), 60.0, "the pass settled")
    return process


def _schedule(ground: Ground, plan_id: str, name: str) -> str:
    now = datetime.now(UTC)
    body = {
        "plan_id": plan_id,
        "name": name,
        "aos_time": now.isoformat(),
        "los_time": (now + timedelta(seconds=1200)).isoformat(),
        "relay": "TDRS-W",
    }
    response = httpx.post(f"{ground.url}/api/passes", json=body, headers=OPERATOR)
    assert response.status_code == 201, response.text
    return str(response.json()["id"])


def test_a_plan_file_uploaded_by_the_cli_is_flown_command_for_command(tmp_path: Path) -> None:
    path = tmp_path / "p.json"
    sets = [arg for pair in PASS for arg in ("--set", pair)]
    _hikoboshi("plan", "pass", *sets, "--out", str(path))
    document: dict[str, Any] = json.loads(path.read_text())
    with running_ground(sqlite_url(tmp_path / "ground")) as ground:
        token = OPERATOR["Authorization"].removeprefix("Bearer ")
        out = _hikoboshi(
            "plan", "upload", str(path), "--url", ground.url, env={"HIKOBOSHI_TOKEN": token}
        )
        found = re.search(r"stored plan ([0-9a-f-]{36}): ", out)
        assert found is not None, out
        plan_id = found.group(1)
        pass_id = _schedule(ground, plan_id, "uploaded-1")
        process = asyncio.run(_fly(ground, pass_id, "uploaded-1"))
        with ground.readers() as session:
            record = repo.get_pass(session=session, pass_id=pass_id)
            commands = repo.list_commands(session=session, pass_id=pass_id)
    assert record.state == "complete" and record.epoch_ns is not None
    joints = [c for c in commands if c.kind == "joints"]
    acs = [c for c in commands if c.kind != "joints"]
    # every command the ground sent was executed on board, at its tag
    assert len(joints) == len(document["commands"]) == 217
    assert len(acs) == len(document["acs_commands"])
    for c in commands:
        ack = process.vehicle.outcome(c.seq)
        assert ack is not None and ack.stage.value == c.stage == "executed", (c.seq, ack)
        assert c.executed_at_ns == c.execute_time_ns
    # command for command, the file's numbers: tags to the nanosecond, angles to the bit
    for c, written in zip(joints, document["commands"], strict=True):
        assert c.execute_time_ns - record.epoch_ns == round(written["t_s"] * 1e9)
        assert c.payload["joints_rad"] == written["joints_rad"]
    for c, written in zip(acs, document["acs_commands"], strict=True):
        assert c.execute_time_ns - record.epoch_ns == round(written["t_s"] * 1e9)
        assert c.payload["mode"] == written["mode"]
        assert (
            c.payload["target_quat_orbit_from_base_xyzw"]
            == (written["target_quat_orbit_from_base_xyzw"])
        )
        assert c.payload["feedforward"] == written["feedforward"]
