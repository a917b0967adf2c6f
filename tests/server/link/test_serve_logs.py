"""What an operator's log collector reads from a real ``hikoboshi serve`` over a pass, in
both formats: the start, an authentication failure, a pass started and an operator's abort,
each a line with a UTC timestamp, a level and a logger, the pass's id where there is one
(docs/operations.md, *Logs*).

The server runs as its own process, configured from the environment as a container would
(``HIKOBOSHI_LOG_FORMAT``), and the spacecraft as another.
"""

from __future__ import annotations

import json
import re
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import httpx
import pytest

from planner.plan import Plan
from server.storage import repository as repo
from server.storage.db import make_engine, read_session_factory, session_factory, upgrade
from tests.server.link.harness import (
    OPERATOR,
    add_plan_and_pass,
    serve_process,
)
from tests.server.link.load import spacecraft_process
from tests.server.link.long_pass import long_plan
from tests.support.processes import free_port

if TYPE_CHECKING:
    from tests.support.made_once import MadeOnce

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time

#: The vehicle's time scale: the pass (the long plan's 400 s of settle, 20 s of wall) is
#: aborted long before it ends.
SCALE = 20.0
TOKENS = "o-token=otto:operator,v-token=vera:viewer,s-token=ets7:spacecraft"
#: A timestamp of every line: UTC, milliseconds (server/logs.py).
STAMP = r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z"
WRONG = "not-a-token-0123456789"
#: Guards against a hang, not timing assertions.
GUARD_S = 120.0
#: Wall s one poll of the link's status waits for its answer before it is asked again.
PROBE_S = 5.0


def _until(check: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + GUARD_S
    while not check():
        assert time.monotonic() < deadline, f"{what}: not within {GUARD_S} s"
        time.sleep(0.1)


@pytest.fixture(scope="module")
def plan(made_once: MadeOnce) -> Plan:
    """The pass's plan: tests/server/link/long_pass.py's, planned once per run."""
    return long_plan(made_once)


def _fly_and_abort(database_url: str, tmp_path: Path, log_format: str, plan: Plan) -> str:
    """A pass started, aborted by the operator once 5 of its commands executed; its id.
    The server and the spacecraft are processes of their own."""
    port = free_port()
    engine = make_engine(database_url)
    upgrade(engine)
    readers = read_session_factory(engine)

    def stage_count(pass_id: str, stage: str) -> int:
        with readers() as session:
            return len(repo.list_commands(session=session, pass_id=pass_id, stages=(stage,)))

    def state(pass_id: str) -> str:
        with readers() as session:
            return repo.get_pass(session=session, pass_id=pass_id).state

    env = {"HIKOBOSHI_TOKENS": TOKENS, "HIKOBOSHI_LOG_FORMAT": log_format}
    vehicle = None
    try:
        # the vehicle's process starts beside the server's, not after it (each is seconds of
        # imports on a loaded machine): it tries the link again until the server listens
        vehicle = spacecraft_process(port, "s-token", SCALE, tmp_path / "spacecraft.log")
        with (
            serve_process(database_url, port, tmp_path / "server.log", env),
            httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=30.0) as client,
        ):
            pass_id = add_plan_and_pass(
                session_factory(engine), plan, "logged", now_ns=time.time_ns(), window_s=1200.0
            )

            def connected() -> bool:
                # A poll: a probe that gets no answer is given up soon and asked again. With
                # the client's 30 s, a probe that timed out (a TransportError too) was asked
                # again only 30 s later, and _until's guard, read between probes, let four
                # such go by: a case could pass after some 150 s (one took 149 s).
                try:
                    status = client.get("/api/link/status", headers=OPERATOR, timeout=PROBE_S)
                except httpx.TransportError:  # a fresh process on a loaded machine
                    return False
                return bool(status.json()["connected"])

            _until(connected, "the spacecraft connected")
            wrong = {"Authorization": f"Bearer {WRONG}"}
            assert client.get("/api/passes", headers=wrong).status_code == 401
            started = client.post(
                f"/api/passes/{pass_id}/start", json={"confirm": "START logged"}, headers=OPERATOR
            )
            assert started.status_code == 200, started.text
            _until(lambda: stage_count(pass_id, "executed") >= 5, "5 commands executed")
            response = client.post(
                f"/api/passes/{pass_id}/abort",
                json={"confirm": "ABORT logged", "reason": "arm drifting"},
                headers=OPERATOR,
            )
            assert response.status_code == 200, response.text
            _until(lambda: state(pass_id) == "aborted", "the pass aborted")
    finally:
        if vehicle is not None:
            # the ground stopped first (its stop with the vehicle connected is logged): the
            # vehicle's drain would wait its 30 s for a ground that does not come back
            vehicle.kill()
            vehicle.wait(timeout=60)
        engine.dispose()
    return pass_id


@pytest.mark.parametrize("log_format", ["text", "json"])
def test_a_pass_started_and_aborted_on_a_real_serve_is_logged(
    tmp_path: Path, log_format: str, plan: Plan
) -> None:
    pass_id = _fly_and_abort(f"sqlite:///{tmp_path / 'ground.db'}", tmp_path, log_format, plan)
    text = (tmp_path / "server.log").read_text()
    assert WRONG not in text
    lines = [line for line in text.splitlines() if line.strip()]
    # a routine stop with the vehicle connected is not an error
    assert not [x for x in lines if "ERROR" in x or "Traceback" in x], text[-3000:]
    if log_format == "json":
        assert [line for line in lines if not line.startswith("{")] == [], text[-3000:]
        records = [json.loads(line) for line in lines]
        assert all(re.fullmatch(STAMP, r["time"]) for r in records)
        (up,) = [r for r in records if "Uvicorn running on" in r["message"]]
        assert (up["level"], up["logger"]) == ("INFO", "uvicorn.error")
        (failed,) = [r for r in records if r.get("event") == "authentication_failed"]
        assert (failed["level"], failed["logger"], failed["path"]) == (
            "WARNING",
            "hikoboshi.audit",
            "/api/passes",
        )
        (started,) = [r for r in records if r.get("event") == "pass_started"]
        assert started["pass_id"] == pass_id and started["actor"] == "otto"
        assert started["logger"] == "hikoboshi.ground.runner" and started["commands"] > 5
        (abort,) = [r for r in records if r.get("event") == "pass_aborted"]
        assert abort["pass_id"] == pass_id and abort["level"] == "INFO"
        assert (abort["actor"], abort["reason"]) == ("otto", "arm drifting")
        return
    assert any(
        re.fullmatch(rf"{STAMP} INFO uvicorn\.error Uvicorn running on .*", x) for x in lines
    )
    failed = [x for x in lines if "authentication failed" in x]
    assert len(failed) == 1 and re.match(rf"{STAMP} WARNING hikoboshi\.audit ", failed[0]), failed
    started = [x for x in lines if "event=pass_started" in x]
    assert len(started) == 1, lines
    assert re.fullmatch(
        rf"{STAMP} INFO hikoboshi\.ground\.runner \[pass {pass_id}\] pass logged started by "
        r"otto: \d+ commands event=pass_started actor=otto commands=\d+",
        started[0],
    ), started[0]
    abort = [x for x in lines if "event=pass_aborted" in x]
    assert len(abort) == 1, lines
    assert re.fullmatch(
        rf"{STAMP} INFO hikoboshi\.ground\.runner \[pass {pass_id}\] pass aborted by otto: "
        r"arm drifting event=pass_aborted actor=otto reason=[\"']arm drifting[\"']",
        abort[0],
    ), abort[0]
