"""Abort of a long pass with consoles watching (#14): the rest of the pass is cancelled in
one event, every console stays connected and sees that one event, and the operator's abort
is answered at once.

The real ground (uvicorn, loopback) and the spacecraft process at 10x; three consoles on
real websockets. The pass is 14,000 commands (almost an hour of plan at 4 Hz), so nearly
all of it is cancelled.
"""

from __future__ import annotations

import asyncio
import itertools
import json
import time
from pathlib import Path
from typing import Any

import pytest
import websockets

from server.storage import repository as repo
from server.storage.db import sqlite_url
from tests.server.link.harness import (
    OPERATOR,
    Ground,
    add_plan_and_pass,
    deleted_from_ns,
    in_contact,
    running_ground,
    spacecraft,
    start_pass,
    wait_for,
)
from tests.server.storage.factories import make_plan

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time

N_COMMANDS = 14_000
#: The abort sends the ``schedule_delete`` and writes one statement and one event, whatever
#: the pass's length: it answers in a fraction of a second (bench/bench_isolation.py measures
#: it). This bound is a lock-out guard, not a timing: a wait on the pass's length (14,000
#: stage writes) took tens of seconds.
ABORT_ANSWER_S = 10.0
_ids = itertools.count()


class Console:
    """One operator console on the ``commands`` and ``passes`` topics."""

    def __init__(self, ws: Any) -> None:
        self.ws = ws
        self.messages: list[dict[str, Any]] = []

    @classmethod
    async def open(cls, ground: Ground) -> Console:
        url = ground.url.replace("http://", "ws://") + "/api/console"
        # read as a browser reads (no flow control of its own): the test is of the server
        ws = await websockets.connect(url, max_size=None, max_queue=None)
        await ws.send(json.dumps({"v": 1, "type": "auth", "token": "v-token"}))
        console = cls(ws)
        welcome = json.loads(await ws.recv())
        assert welcome["type"] == "welcome", welcome
        for topic in ("commands", "passes"):
            await ws.send(json.dumps({"v": 1, "type": "subscribe", "topic": topic}))
            reply = json.loads(await ws.recv())
            assert reply["type"] == "subscribed", reply
        return console

    async def sync(self) -> list[dict[str, Any]]:
        """Every message the server queued for this console before now (a ping's pong comes
        after them); raises if the server closed the connection."""
        marker = f"sync-{next(_ids)}"
        await self.ws.send(json.dumps({"v": 1, "type": "ping", "id": marker}))
        while True:
            message = json.loads(await asyncio.wait_for(self.ws.recv(), 60.0))
            if message["type"] == "pong" and message.get("id") == marker:
                return self.messages
            self.messages.append(message)

    def events(self, kind: str) -> list[dict[str, Any]]:
        return [
            m["event"] for m in self.messages if m["type"] == "event" and m["event"]["kind"] == kind
        ]


def _stages(ground: Ground, pass_id: str) -> dict[str, int]:
    with ground.readers() as session:
        rows = repo.list_commands(session=session, pass_id=pass_id)
    counts: dict[str, int] = {}
    for row in rows:
        counts[row.stage] = counts.get(row.stage, 0) + 1
    return counts


@pytest.mark.slow
def test_abort_of_a_long_pass_is_one_event_and_keeps_every_console(tmp_path: Path) -> None:
    async def scenario(ground: Ground, pass_id: str) -> tuple[float, list[Console]]:
        process, _ = spacecraft(ground)
        consoles: list[Console] = []
        try:
            async with in_contact(process, ground.url, timeout_s=60.0, drain_s=60.0) as client:
                consoles = [await Console.open(ground) for _ in range(3)]
                await start_pass(client, pass_id, "long")
                await wait_for(
                    lambda: _stages(ground, pass_id).get("executed", 0) >= 20,
                    60.0,
                    "20 commands executed",
                )
                for console in consoles:
                    await console.sync()
                t0 = time.monotonic()
                response = await client.post(
                    f"/api/passes/{pass_id}/abort",
                    json={"confirm": "ABORT long", "reason": "load test abort"},
                    headers=OPERATOR,
                )
                answered_s = time.monotonic() - t0
                assert response.status_code == 200, response.text
                assert response.json()["state"] == "aborted"
                await wait_for(
                    lambda: not ground.app.state.runner.resolving, 60.0, "the abort resolved"
                )
                for console in consoles:
                    await console.sync()  # still connected: the pong comes back
        finally:
            for console in consoles:
                await console.ws.close()
        return answered_s, consoles

    with running_ground(sqlite_url(tmp_path)) as ground:
        pass_id = add_plan_and_pass(
            ground.sessions, make_plan(N_COMMANDS), "long", now_ns=time.time_ns(), window_s=7200.0
        )
        answered_s, consoles = asyncio.run(scenario(ground, pass_id))
        stages = _stages(ground, pass_id)
        from_ns = deleted_from_ns(ground, pass_id)
        with ground.readers() as session:
            rows = repo.list_commands(session=session, pass_id=pass_id)

    assert answered_s < ABORT_ANSWER_S, f"abort answered in {answered_s:.2f} s"
    total = N_COMMANDS + 1  # and the plan's ACS command
    assert sum(stages.values()) == total
    assert set(stages) <= {"executed", "cancelled"}, stages  # nothing left open or lost
    # what was due before the abort's tag executed, everything from it on was cancelled
    # (when the abort comes depends on how fast a loaded machine stores the first stages)
    assert all(r.stage == "executed" for r in rows if r.execute_time_ns < from_ns)
    assert all(r.stage == "cancelled" for r in rows if r.execute_time_ns >= from_ns)
    assert stages["cancelled"] > N_COMMANDS // 2, stages  # most of the hour was cut
    for console in consoles:
        [cancelled] = console.events("commands_cancelled")  # one event, on every console
        detail = cancelled["detail"]
        assert detail["count"] == stages["cancelled"]
        assert detail["first_seq"] <= detail["last_seq"]
        assert detail["reason"].startswith("load test abort")
        assert not [m for m in console.messages if m["type"] == "unsubscribed"]
        states = [e["detail"]["to"] for e in console.events("pass_state")]
        assert states[-1] == "aborted"
