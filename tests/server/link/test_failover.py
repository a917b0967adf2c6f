"""Two grounds on one PostgreSQL: exactly one commands the vehicle, the other is a hot standby
that takes over when the holder dies (docs/operations.md "One ground in command").

Ground A runs a pass; ground B, started on the same database as if by mistake, is a standby:
it says so, refuses to start a pass and writes nothing on the running one. A is then killed
(SIGKILL: no shutdown, its lease left to expire); B takes the lease over, resumes the pass
from the database and the vehicle's ``hello``, and the vehicle (given both grounds' URLs)
moves to it. The pass completes, each command's stage the vehicle's own record, and every
frame of the pass's window is stored once. Both grounds are processes of their own
(``hikoboshi serve``), so the kill is real; the spacecraft runs in the test's loop.
"""

from __future__ import annotations

import asyncio
import signal
import time
from pathlib import Path
from typing import Any

import httpx
import pytest

from server.storage import repository as repo
from server.storage.db import make_engine, read_session_factory, session_factory
from tests.server.link.harness import (
    OPERATOR,
    VIEWER,
    assert_every_frame_once,
    assert_stages_are_the_vehicles,
    executed_on_board,
    generated_frames,
    pass_resolved,
    serve_process,
    spacecraft_of_grounds,
    store_pass,
    wait_for,
)
from tests.support.processes import free_port

pytestmark = pytest.mark.realtime

SCALE = 10.0
TOKENS = "o-token=otto:operator,v-token=vera:viewer,s-token=ets7:spacecraft"
#: The lease here: the standby takes over 3 s (wall) after the holder's last renewal.
LEASE = {"HIKOBOSHI_LEASE_TTL_S": "3", "HIKOBOSHI_LEASE_RENEW_S": "0.5"}
#: onboard s: the schedule loaded before the kill rides out the takeover (3-4 s of lease
#: and recovery, 30-40 s onboard at 10x, more on a loaded machine)
LEAD_WINDOW_S = 150.0
#: A connection per request: a keep-alive connection the server closes after its idle
#: timeout (5 s) while this loop is busy flying the spacecraft races the next request
#: ("Server disconnected without sending a response", seen at load average 8).
ONE_SHOT = httpx.Limits(max_keepalive_connections=0)


def _client(url: str) -> httpx.AsyncClient:
    return httpx.AsyncClient(base_url=url, timeout=30.0, limits=ONE_SHOT)


def _env(name: str) -> dict[str, str]:
    return {
        "HIKOBOSHI_TOKENS": TOKENS,
        "HIKOBOSHI_UPLINK_LEAD_WINDOW_S": str(LEAD_WINDOW_S),
        "HIKOBOSHI_GROUND_NAME": name,
        **LEASE,
    }


@pytest.mark.slow
def test_a_standby_writes_nothing_then_takes_over_from_a_killed_holder(
    postgres_schema_url: str, tmp_path: Path
) -> None:
    database_url = postgres_schema_url
    port_a, port_b = free_port(), free_port()
    engine = make_engine(database_url)
    sessions, readers = session_factory(engine), read_session_factory(engine)
    process = spacecraft_of_grounds((port_a, port_b), scale=SCALE, seed=3, drain_timeout_s=90.0)
    generated = generated_frames(process)
    pass_id = ""  # the pass, once stored

    def on_board_30() -> bool:
        return executed_on_board(readers, process, pass_id, 30)

    def ended() -> bool:
        return pass_resolved(readers, pass_id)

    def events(pass_id: str, *kinds: str) -> list[Any]:
        with readers() as session:
            return list(repo.list_events(session=session, pass_id=pass_id, kinds=kinds).items)

    async def scenario() -> dict[str, Any]:
        nonlocal pass_id
        seen: dict[str, Any] = {}
        stop = asyncio.Event()
        task = asyncio.create_task(process.run(stop))
        log_a, log_b = tmp_path / "ground-a.log", tmp_path / "ground-b.log"
        a_url, b_url = f"http://127.0.0.1:{port_a}", f"http://127.0.0.1:{port_b}"
        try:
            with serve_process(database_url, port_a, log_a, _env("ground-a")) as ground_a:
                pass_id = store_pass(sessions, "failover", (10.0, 0.0, 0.0, 10.0, 0.0, 0.0), 200.0)
                seen["pass_id"] = pass_id
                async with _client(a_url) as a:
                    assert (await a.get("/api/health")).json()["command"] == "holder"
                    await wait_for(lambda: process.connections > 0, 60.0, "a spacecraft")
                    started = await a.post(
                        f"/api/passes/{pass_id}/start",
                        json={"confirm": "START failover"},
                        headers=OPERATOR,
                    )
                    assert started.status_code == 200, started.text
                with serve_process(database_url, port_b, log_b, _env("ground-b")) as ground_b:
                    async with _client(b_url) as b:
                        health = (await b.get("/api/health")).json()
                        assert health == {"status": "ok", "command": "standby"}
                        assert (await b.get("/api/ready")).json()["command"] == "standby"
                        command = await b.get("/api/command")  # a load balancer's probe
                        assert command.status_code == 503
                        assert command.json()["error"]["code"] == "standby"
                        metrics = (await b.get("/metrics", headers=VIEWER)).text
                        assert "hikoboshi_command_lease_holder 0.0" in metrics
                        refused = await b.post(
                            f"/api/passes/{pass_id}/start",
                            json={"confirm": "START failover"},
                            headers=OPERATOR,
                        )
                        assert refused.status_code == 409, refused.text
                        body = refused.json()["error"]
                        assert body["code"] == "standby", body
                        assert "ground-a" in body["message"]
                        # a standby serves reads: the running pass, as the holder writes it
                        got = await b.get(f"/api/passes/{pass_id}", headers=VIEWER)
                        assert got.status_code == 200 and got.json()["state"] == "running"
                    await wait_for(on_board_30, 60.0, "30 commands executed")
                    # the standby wrote nothing on the running pass
                    assert not events(pass_id, "pass_resumed", "ground_stopped")
                    connections_before = process.connections
                    ground_a.send_signal(signal.SIGKILL)
                    killed = time.monotonic()
                    killed_ns = time.time_ns()
                    ground_a.wait(30)
                    await wait_for(
                        lambda: events(pass_id, "pass_resumed"), 60.0, "the standby took over"
                    )
                    seen["takeover_s"] = time.monotonic() - killed
                    await wait_for(ended, 120.0, "the pass ended, resolved")
                    async with _client(b_url) as b:
                        health = (await b.get("/api/health")).json()
                        assert health["command"] == "holder"
                        command = await b.get("/api/command")
                        assert command.status_code == 200 and command.json()["token"] == 2
                        summary = await b.get(f"/api/passes/{pass_id}/summary", headers=VIEWER)
                        assert summary.status_code == 200, summary.text
                        seen["summary"] = summary.json()
                    stop.set()  # drain the onboard store while the new holder is there
                    await asyncio.wait_for(task, 100.0)
                    assert process.store.unacked == 0
                    assert process.connections > connections_before  # moved to B
                    seen["killed_ns"] = killed_ns
                    assert ground_b.poll() is None
        finally:
            stop.set()
            await asyncio.wait_for(task, 100.0)
        return seen

    try:
        seen = asyncio.run(scenario())
        pass_id = seen["pass_id"]
        with sessions() as session:
            commands = repo.list_commands(session=session, pass_id=pass_id)
            record = repo.get_pass(session=session, pass_id=pass_id)
            frames = repo.frame_seqs(session=session, pass_id=pass_id)
            resumed = repo.list_events(session=session, pass_id=pass_id, kinds=["pass_resumed"])
    finally:
        engine.dispose()
    [resumed_event] = resumed.items
    assert resumed_event.detail["state"] == "running"
    assert_stages_are_the_vehicles(commands, process)
    assert all(c.stage == "executed" for c in commands)
    summary = seen["summary"]
    assert summary["commands_unresolved"] == summary["commands_cancelled"] == 0
    assert record.state == "complete", (record.state, record.state_reason)
    assert record.state_reason == f"complete, {summary['outcome_text']}"
    assert_every_frame_once(record, frames, generated)  # the archive's key: once
    print(
        f"takeover (kill to pass_resumed): {seen['takeover_s']:.1f} s wall with a "
        f"{LEASE['HIKOBOSHI_LEASE_TTL_S']} s lease; {summary['outcome_text']}"
    )
