"""Kill the ground service mid-pass (SIGKILL: no shutdown), start it again on the same
database: no committed row is lost or rewritten, and the pass resumes and completes.

The server runs as its own process (``hikoboshi serve``) so the kill is real; the spacecraft
runs in the test's event loop and reconnects by itself, as in flight.
"""

from __future__ import annotations

import asyncio
import signal
import subprocess
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import httpx
import pytest
from sqlalchemy import select

from server.storage import repository as repo
from server.storage.db import make_engine, read_session_factory, session_factory
from server.storage.models import EventRecord
from spacecraft.link import LinkConfig
from spacecraft.process import ProcessConfig, SpacecraftProcess
from tests.server.link.harness import (
    OPERATOR,
    VIEWER,
    _free_port,
    generated_frames,
    serve_process,
    store_pass,
    wait_for,
)

#: Slower than the other end-to-end tests: a restart takes seconds of wall time, and at 20x
#: that would be a minute onboard. At 10x it is 20-40 s of a 130 s pass.
SCALE = 10.0
TOKENS = "o-token=otto:operator,v-token=vera:viewer,s-token=ets7:spacecraft"
#: The uplink's lead window here (onboard s; 120 s in flight): the schedule loaded at the
#: kill (15 s of wall at 10x) must ride out the restart, which takes 5-12 s of wall on a
#: loaded machine (a fresh interpreter's imports and the migrations); with 60 s the last
#: commands loaded ran before the new ground was up, and the next ones expired.
LEAD_WINDOW_S = 150.0


@contextmanager
def serve(database_url: str, port: int, log: Path) -> Iterator[subprocess.Popen[bytes]]:
    env = {"HIKOBOSHI_TOKENS": TOKENS, "HIKOBOSHI_UPLINK_LEAD_WINDOW_S": str(LEAD_WINDOW_S)}
    with serve_process(database_url, port, log, env) as proc:
        yield proc


def _snapshot(sessions: Any, pass_id: str) -> dict[str, Any]:
    with sessions() as session:
        commands = {
            c.seq: (
                c.queued_at_ns,
                c.released_at_ns,
                c.sent_at_ns,
                c.received_at_ns,
                c.executed_at_ns,
                c.rejected_at_ns,
                c.expired_at_ns,
                c.cancelled_at_ns,
            )
            for c in repo.list_commands(session=session, pass_id=pass_id)
        }
        events = {e.id: (e.kind, e.time_ns) for e in session.scalars(select(EventRecord)).all()}
        frames = repo.frame_seqs(session=session, pass_id=pass_id)
        record = repo.get_pass(session=session, pass_id=pass_id)
        return {"commands": commands, "events": events, "frames": frames, "pass": record}


@pytest.mark.slow
def test_a_killed_ground_resumes_the_pass_and_loses_no_row(
    database_url: str, tmp_path: Path
) -> None:
    port = _free_port()
    log = tmp_path / "server.log"
    base = f"http://127.0.0.1:{port}"
    engine = make_engine(database_url)
    sessions = session_factory(engine)
    readers = read_session_factory(engine)  # polling takes no write lock on SQLite
    process = SpacecraftProcess(
        ProcessConfig(
            ground_url=f"ws://127.0.0.1:{port}/api/link",
            token="s-token",
            time_scale=SCALE,
            uplink=LinkConfig(seed=21),
            downlink=LinkConfig(seed=22),
            seed=5,
            backoff_initial_s=0.05,
            backoff_max_s=0.3,
            drain_timeout_s=90.0,  # a loaded machine: PostgreSQL beside a busy core
        )
    )
    generated = generated_frames(process)

    def executed(pass_id: str) -> int:
        with readers() as session:
            return len(repo.list_commands(session=session, pass_id=pass_id, stages=["executed"]))

    def state(pass_id: str) -> str:
        with readers() as session:
            return repo.get_pass(session=session, pass_id=pass_id).state

    async def connected(client: httpx.AsyncClient) -> bool:
        with_status = await client.get("/api/link/status", headers=VIEWER)
        return bool(with_status.json()["connected"])

    async def scenario() -> tuple[dict[str, Any], str]:
        stop = asyncio.Event()
        task = asyncio.create_task(process.run(stop))
        try:
            with serve(database_url, port, log) as first:
                # 10 s of motion, then 260 s holding: 27 s wall at 10x, so a kill that comes
                # late on a loaded machine still finds the pass running, and the resumed
                # ground has a good part of it (past the lead window) still to send
                pass_id = store_pass(sessions, "restart", (10.0, 0.0, 0.0, 10.0, 0.0, 0.0), 260.0)
                async with httpx.AsyncClient(base_url=base) as client:
                    deadline = time.monotonic() + 20.0
                    while not await connected(client):
                        assert time.monotonic() < deadline, "no spacecraft"
                        await asyncio.sleep(0.05)
                    response = await client.post(
                        f"/api/passes/{pass_id}/start",
                        json={"confirm": "START restart"},
                        headers=OPERATOR,
                    )
                    assert response.status_code == 200, response.text
                await wait_for(lambda: executed(pass_id) >= 30, 30.0, "30 commands executed")
                first.send_signal(signal.SIGKILL)
                first.wait(timeout=10)
            before = _snapshot(sessions, pass_id)
            assert before["pass"].state == "running"
            with serve(database_url, port, log):
                await wait_for(
                    lambda: state(pass_id) in ("complete", "aborted"), 120.0, "the pass ended"
                )
                stop.set()  # drain the onboard store while the ground is still there
                await asyncio.wait_for(task, 100.0)
                assert process.store.unacked == 0
        finally:
            stop.set()
            await asyncio.wait_for(task, 100.0)
        return before, pass_id

    try:
        before, pass_id = asyncio.run(scenario())
        after = _snapshot(sessions, pass_id)
        with sessions() as session:
            commands = repo.list_commands(session=session, pass_id=pass_id)
            resumed = repo.list_events(session=session, pass_id=pass_id, kinds=["pass_resumed"])
    finally:
        engine.dispose()

    # No committed row lost or rewritten: every stage time written before the kill is
    # unchanged (later stages may have been added), every event and frame is still there.
    for seq, times in before["commands"].items():
        now = after["commands"][seq]
        assert all(b is None or b == a for b, a in zip(times, now, strict=True)), seq
    assert before["events"].items() <= after["events"].items()
    assert set(before["frames"]) <= set(after["frames"])
    # The pass resumed where the uplink stopped, and completed: the schedule loaded before
    # the kill ran on board while the ground was away (LOS policy continue), and the
    # resumed ground sent the rest; the clock it re-learnt from a hello read late by a
    # busy, freshly started process is corrected by the onboard stamps that follow.
    assert resumed.count == 1 and resumed.items[0].detail["state"] == "running"
    record = after["pass"]
    assert record.state == "complete", (record.state, record.state_reason)
    # Each command's stage is what became of it on board: every one executed at its tag.
    for c in commands:
        ack = process.vehicle.outcome(c.seq)
        assert ack is not None and c.stage == ack.stage.value == "executed", (c, ack)
        assert c.executed_at_ns == c.execute_time_ns
    # Sent first by the resumed ground (never sent before the kill) and executed on board:
    sent_before = {seq for seq, times in before["commands"].items() if times[2] is not None}
    resent = [c for c in commands if c.seq not in sent_before]
    assert len(resent) > 200  # most of the hold went up after the restart
    # Every frame generated in the pass's telemetry window was archived once.
    assert record.telemetry_start_ns is not None and record.telemetry_end_ns is not None
    window = sorted(
        f.seq
        for f in generated
        if record.telemetry_start_ns <= f.generation_time_ns < record.telemetry_end_ns
    )
    assert after["frames"] == window
