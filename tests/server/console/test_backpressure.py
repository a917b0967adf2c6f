"""A slow console: its subscription is dropped, publishing never waits, it resumes losslessly.

The hub on its own (no app): one console whose socket does not take anything until released,
one that takes everything.
"""

from __future__ import annotations

import asyncio
import json
from typing import Any

from server.services.console import ConsoleHub, ConsoleLimits
from server.services.dbworker import Publisher
from server.services.link import LinkStatus

N_EVENTS = 50


def _status() -> LinkStatus:
    raise AssertionError("the link poll is not started in these tests")


class Socket:
    def __init__(self, *, blocked: bool) -> None:
        self.received: list[dict[str, Any]] = []
        self.open = asyncio.Event()
        if not blocked:
            self.open.set()

    async def send_text(self, text: str) -> None:
        await self.open.wait()
        self.received.append(json.loads(text))

    async def close(self, code: int, reason: str) -> None:
        raise AssertionError(f"closed {code} {reason}")


def _event(n: int) -> dict[str, Any]:
    detail = {"seq": n, "from": "released", "stage": "sent", "time_ns": n}
    return {
        "kind": "command_stage",
        "actor": "ground",
        "detail": detail,
        "pass_id": None,
        "time_ns": n,
    }


async def _settle() -> None:
    # Let the send tasks run until nothing is left to take (bounded: no timing assumed).
    for _ in range(10 * N_EVENTS):
        await asyncio.sleep(0)


def test_a_slow_console_is_dropped_without_holding_up_the_publisher() -> None:
    async def scenario() -> tuple[list[dict[str, Any]], list[dict[str, Any]], list[bool]]:
        publisher = Publisher()
        # About ten event messages of ~170 bytes.
        limits = ConsoleLimits(queue_bytes=1700, ring_size=N_EVENTS)
        hub = ConsoleHub(
            publisher=publisher,
            link_status=_status,
            sessions=None,  # type: ignore[arg-type]
            limits=limits,
        )
        hub._unhook = [publisher.subscribe(hub._on_event)]  # no link poll
        slow, fast = Socket(blocked=True), Socket(blocked=False)
        clients = {}
        for name, socket in (("slow", slow), ("fast", fast)):
            clients[name] = hub.connect(
                actor=name, role="viewer", send_text=socket.send_text, close=socket.close
            )
            subscribe = {"v": 1, "type": "subscribe", "topic": "commands"}
            await hub.handle(clients[name], json.dumps(subscribe))
        returned = []
        for n in range(1, N_EVENTS + 1):
            publisher.publish([_event(n)])  # synchronous: it cannot wait for a socket
            returned.append(True)
            await asyncio.sleep(0)  # the link awaits its database between batches
        # The slow console catches up (its socket drains) and resumes where it was dropped.
        slow.open.set()
        await _settle()
        dropped = next(m for m in slow.received if m["type"] == "unsubscribed")
        resume = {"v": 1, "type": "subscribe", "topic": "commands"}
        resume |= {"since_seq": dropped["seq"], "epoch": hub.epoch}
        await hub.handle(clients["slow"], json.dumps(resume))
        await _settle()
        await hub.close()
        return slow.received, fast.received, returned

    slow, fast, returned = asyncio.run(scenario())
    assert len(returned) == N_EVENTS
    assert [m["seq"] for m in fast if m["type"] == "event"] == list(range(1, N_EVENTS + 1))
    [dropped] = [m for m in slow if m["type"] == "unsubscribed"]
    assert dropped["reason"].startswith("overflow") and dropped["topic"] == "commands"
    # What was queued before the drop went out, then the notice, then the resumed rest.
    events = [m["seq"] for m in slow if m["type"] == "event"]
    assert events == list(range(1, N_EVENTS + 1))
    before_drop = [m["seq"] for m in slow[: slow.index(dropped)] if m["type"] == "event"]
    assert 5 <= dropped["seq"] == len(before_drop) < N_EVENTS // 2
