"""A noisy link cannot starve the uplink: 400 malformed messages a wall second for 6 s of
wall time (:data:`FLOOD_WALL_S`, three of the ground's audit intervals, set to 2 s here) on
the spacecraft link during a 20x pass, on PostgreSQL (the backend whose ingest fell behind
under load: tests/server/link/test_load.py). The issue's 30 s flood at the default
5 s interval on both backends: ``HIKOBOSHI_TEST_FLOOD_S=30 HIKOBOSHI_TEST_AUDIT_S=5
HIKOBOSHI_TEST_NOISE_BACKENDS=sqlite,postgresql``; the flood's cost to
the link's real traffic, against no flood, is ``bench/bench_link_noise.py``'s.

Real processes on loopback: ``hikoboshi serve`` and ``hikoboshi spacecraft --garbage``
(its rehearsal noise, spacecraft/garbage.py: invalid JSON, unknown types, wrong versions
and malformed telemetry in turn). The noise is dropped and counted beside the valid traffic,
never a reason to close the link (server/services/malformed.py): the ground reads every
malformed message sent, closes nothing, every command executes at its tag, every frame of
the pass is stored, and the audit log stays bounded (one row per kind per interval).
The same rules on SQLite, on the simulated clock and the same garbage: test_malformed.py
(the suite ran this scenario on both backends: a minute of its real-time chain each).
"""

from __future__ import annotations

import asyncio
import json
import math
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from server.services.summary import pass_summary
from server.storage import repository as repo
from server.storage.db import make_engine, read_session_factory, session_factory
from tests.server.link.harness import serve_process, store_pass
from tests.support.processes import free_port

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time

SCALE = 20.0
RATE = 400.0  # malformed messages a wall second
#: The ground's audit interval here (wall s, ``malformed_interval_s``; 5 s by default):
#: one audit row per kind per interval, and how long a run of nothing but malformed
#: messages must last before the link can be found unusable (shorter: a stricter test)
INTERVAL_S = float(os.environ.get("HIKOBOSHI_TEST_AUDIT_S", "2"))
#: wall s of flood: three audit intervals, and more malformed messages in a row than
#: ``malformed_unusable_after`` (1,000) and than the rule of before let through (1,000 in
#: 5 s), 2,400 aimed; the issue's 30 s with ``HIKOBOSHI_TEST_FLOOD_S=30``
FLOOD_WALL_S = float(os.environ.get("HIKOBOSHI_TEST_FLOOD_S", "6"))
#: onboard s of the spacecraft's clock (8 wall s after it starts): the flood starts once
#: the pass's commands are executing (asserted against its truth log's epoch)
FLOOD_START_S = 160.0
#: onboard s the pass holds past the flood's end (2 wall s): its last commands and frames
#: come after the noise
HOLD_PAST_FLOOD_S = 40.0
#: The backends flown: PostgreSQL (the issue's run on both: ``HIKOBOSHI_TEST_NOISE_BACKENDS=
#: sqlite,postgresql``)
BACKENDS = os.environ.get("HIKOBOSHI_TEST_NOISE_BACKENDS", "postgresql").split(",")
OPERATOR_TOKEN = "operator-token-0123456789"
SPACECRAFT_TOKEN = "spacecraft-token-01234567"
TOKENS = f"{OPERATOR_TOKEN}=otto:operator,{SPACECRAFT_TOKEN}=ets7:spacecraft"
OPERATOR = {"Authorization": f"Bearer {OPERATOR_TOKEN}"}


def _state(readers: object, pass_id: str) -> str:
    with readers() as session:  # type: ignore[operator]
        return repo.get_pass(session=session, pass_id=pass_id, refresh=True).state


@pytest.mark.slow
@pytest.mark.parametrize("database_url", BACKENDS, indirect=True)
def test_a_pass_flies_untouched_through_400_malformed_messages_a_second(
    database_url: str, tmp_path: Path
) -> None:
    port = free_port()
    engine = make_engine(database_url)
    sessions = session_factory(engine)
    readers = read_session_factory(engine)
    env = {
        "HIKOBOSHI_TOKENS": TOKENS,
        "HIKOBOSHI_DATA_DIR": str(tmp_path / "data"),
        "HIKOBOSHI_MALFORMED_INTERVAL_S": str(INTERVAL_S),
    }
    vehicle_log = tmp_path / "spacecraft.log"
    truth = tmp_path / "truth.jsonl"
    flood_end_s = FLOOD_START_S + FLOOD_WALL_S * SCALE
    garbage = f"{FLOOD_START_S:g}:{flood_end_s:g}:{RATE:g}"

    async def scenario(flown: str) -> tuple[dict[str, object], float]:
        async with httpx.AsyncClient(
            base_url=f"http://127.0.0.1:{port}", timeout=60.0, headers=OPERATOR
        ) as op:
            with vehicle_log.open("ab") as out:
                vehicle = subprocess.Popen(
                    [
                        *(sys.executable, "-m", "hikoboshi", "spacecraft"),
                        *("--ground", f"ws://127.0.0.1:{port}/api/link"),
                        *("--token", SPACECRAFT_TOKEN, "--time-scale", str(SCALE)),
                        *("--seed", "5", "--garbage", garbage, "--truth-log", str(truth)),
                    ],
                    stdout=out,
                    stderr=subprocess.STDOUT,
                )
            try:
                while not (await op.get("/api/link/status")).json()["connected"]:
                    assert vehicle.poll() is None, vehicle_log.read_text()[-2000:]
                    await asyncio.sleep(0.1)
                t0 = time.monotonic()
                response = await op.post(
                    f"/api/passes/{flown}/start", json={"confirm": "START noisy"}
                )
                assert response.status_code == 200, response.text
                deadline = time.monotonic() + 300.0  # a guard against a hang
                while _state(readers, flown) in ("running", "los"):
                    assert time.monotonic() < deadline, "the pass did not end"
                    await asyncio.sleep(0.5)
                assert _state(readers, flown) == "complete"
                # the interval's rows are written at its end; the frames drained
                await asyncio.sleep(INTERVAL_S + 1.0)
                status = (await op.get("/api/link/status")).json()
            finally:
                vehicle.terminate()
                vehicle.wait(timeout=60)
        return status, time.monotonic() - t0

    try:
        with serve_process(database_url, port, tmp_path / "server.log", env):
            # planned before the spacecraft starts: its clock runs toward the flood
            # 10 s of motion, then holding to past the flood's end (onboard s)
            flown = store_pass(
                sessions, "noisy", (10.0, 0.0, 0.0, 10.0, 0.0, 0.0), flood_end_s + HOLD_PAST_FLOOD_S
            )
            status, wall_s = asyncio.run(scenario(flown))
        with sessions() as session:
            commands = repo.list_commands(session=session, pass_id=flown)
            summary = pass_summary(session=session, pass_id=flown)
            noise = repo.list_events(
                session=session, kinds=["link_error_replied", "link_error_received"], limit=1000
            ).items
            closes = repo.list_events(
                session=session, kinds=["link_closed_malformed"], limit=1000
            ).items
    finally:
        engine.dispose()

    sent = re.search(r"(\d+)\s+malformed\s+messages\s+sent", vehicle_log.read_text())
    assert sent is not None, vehicle_log.read_text()[-2000:]
    n_sent = int(sent.group(1))
    # the flood was real: aimed at 400 a second; the spacecraft process that sends
    # it shares the cores with the ground it floods, and fell to 307 a second on a loaded
    # machine: at least 240 a second
    assert n_sent >= 0.6 * RATE * FLOOD_WALL_S, n_sent
    # the flood fell inside the pass (onboard s of the spacecraft's clock)
    epoch_ns = json.loads(truth.read_text().splitlines()[0])["onboard_time_ns"]
    tags_s = sorted((c.execute_time_ns - epoch_ns) / 1e9 for c in commands)
    assert tags_s[0] < FLOOD_START_S and tags_s[-1] > flood_end_s, (tags_s[0], tags_s[-1])
    # the pass flew untouched: every command executed at its tag, every frame stored
    assert len(commands) > 4 * flood_end_s  # 4 Hz to past the flood
    assert {c.stage for c in commands} == {"executed"}
    assert all(c.executed_at_ns == c.execute_time_ns for c in commands)
    assert summary.frames_missing == 0 and summary.gaps_open == 0
    assert summary.commands_expired == 0
    # the link was never closed: the ground read every malformed message sent (none lost
    # in a socket it closed), counted each, and the audit log is bounded: per interval one
    # row per kind (four kinds; intervals restart with the noise)
    assert closes == [] and status["malformed_closes"] == 0, [e.detail for e in closes]
    assert status["malformed_received"] == n_sent, (status["malformed_received"], n_sent)
    assert sum(e.detail["count"] for e in noise) == n_sent
    intervals = math.ceil(FLOOD_WALL_S / INTERVAL_S) + 2
    assert len(noise) <= 4 * intervals, len(noise)
    assert status["errors_replied"] <= 10 * (wall_s + 1)  # type: ignore[operator]
    print(
        f"sent {n_sent}, read {status['malformed_received']}, replied "
        f"{status['errors_replied']}, closes {len(closes)}, audit rows {len(noise)}, "
        f"{len(commands)} commands executed at their tags, frames missing "
        f"{summary.frames_missing}, wall {wall_s:.0f} s"
    )
