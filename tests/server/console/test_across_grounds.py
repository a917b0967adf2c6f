"""Consoles across grounds through a real NATS JetStream (docs/console.md "Across grounds").

Two hubs, as two grounds would hold them, each with its own publisher and its own
connection to one ``nats-server -js``: what ground A commits is seen by a console on ground
B with the same ``seq`` and ``epoch`` as on A; a console that read part of a stream on A
resumes on B from its last seq, from B's ring or read back from JetStream, every message
once. The grounds as processes, with a vehicle and one killed, are
``test_across_grounds_e2e.py``.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest

from server.services._console_jetstream import AcrossGrounds
from server.services.console import ConsoleHub, ConsoleLimits
from server.services.dbworker import Publisher
from server.services.events import CommandStage, PassState, Recorded
from server.services.jetstream import BusConfig, LiveBus, token
from server.services.link import LinkStatus
from tests.nats_server import nats_server

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time

N = 40


def _status() -> LinkStatus:
    raise AssertionError("the link poll is not started in these tests")


class Socket:
    def __init__(self) -> None:
        self.received: list[dict[str, Any]] = []

    async def send_text(self, text: str) -> None:
        self.received.append(json.loads(text))

    async def close(self, code: int, reason: str) -> None:
        raise AssertionError(f"closed {code} {reason}")

    def events(self) -> list[dict[str, Any]]:
        return [m for m in self.received if m["type"] == "event"]


def _event(n: int) -> Recorded:
    stage = CommandStage(actor="ground", seq=n, from_stage="released", stage="sent", time_ns=n)
    return Recorded(stage, n, n)


def _pass_state(n: int) -> Recorded:
    state = PassState(actor="ground", from_state="aos", to="running", reason="start", version=n)
    return Recorded(state, n, 10**6 + n)


async def _until(predicate: Callable[[], bool], what: str) -> None:
    async def wait() -> None:
        while not predicate():
            await asyncio.sleep(0.01)

    await asyncio.wait_for(wait(), 30.0)  # a guard, not a timing assertion: ``what``


class _Ground:
    def __init__(self, url: str, name: str, limits: ConsoleLimits) -> None:
        self.publisher = Publisher()
        config = BusConfig(url, "TEST", max_age_s=3600.0, max_bytes=64 << 20, lease="vehicle")
        self.across = AcrossGrounds(LiveBus(config, name=name), commanding=lambda: True)
        self.limits = limits
        self.hub: ConsoleHub | None = None

    async def open(self) -> ConsoleHub:
        await self.across.bus.open()
        await self.across.open(self.publisher)
        self.hub = ConsoleHub(
            publisher=self.publisher,
            link_status=_status,
            sessions=None,  # type: ignore[arg-type]
            limits=self.limits,
            across=self.across,
        )
        self.across.attach(self.hub.book)  # no link poll, no lag watch
        return self.hub

    async def close(self) -> None:
        if self.hub is not None:
            await self.hub.close()
        await self.across.close()


async def _console(
    hub: ConsoleHub, **subscribe: Any
) -> tuple[Socket, Callable[[], Awaitable[None]]]:
    socket = Socket()
    client = hub.connect(
        actor="vera", role="viewer", send_text=socket.send_text, close=socket.close
    )
    await hub.handle(client, json.dumps({"v": 1, "type": "subscribe", **subscribe}))

    async def disconnect() -> None:
        await hub.disconnect(client)

    return socket, disconnect


def test_subject_tokens_hold_no_separator_or_wildcard() -> None:
    assert token("7d3c0000-0000-4000-8000-000000000001") == "7d3c0000-0000-4000-8000-000000000001"
    assert token("ets.vii *>") == "ets%2Evii%20%2A%3E"


def test_a_console_on_another_ground_sees_the_same_stream_and_resumes_there(
    tmp_path: Path,
) -> None:
    async def scenario() -> dict[str, Any]:
        out: dict[str, Any] = {}
        with nats_server(tmp_path) as url:
            # ring of 4: a resume past it is read back from JetStream
            a, b = _Ground(url, "a", ConsoleLimits(ring_size=4)), _Ground(url, "b", ConsoleLimits())
            hub_a, hub_b = await a.open(), await b.open()
            try:
                assert hub_a.epoch == hub_b.epoch and hub_a.epoch.startswith("js-")
                on_a, leave_a = await _console(hub_a, topic="commands")
                on_b, _ = await _console(hub_b, topic="events")
                # A commits N stage moves and a pass state; B's console gets them as A's
                for n in range(1, N + 1):
                    a.publisher.publish([_event(n)])
                    if n == N // 2:
                        a.publisher.publish([_pass_state(n)])
                await _until(lambda: len(on_a.events()) == N, "A's console has every stage")
                await _until(lambda: len(on_b.events()) == N + 1, "B's console, every event")
                out["a"], out["b"] = on_a.events(), on_b.events()
                # A's console read 10 then lost A: it resumes on B from its last seq
                await leave_a()
                last = out["a"][9]["seq"]
                resumed, _ = await _console(
                    hub_b, topic="commands", since_seq=last, epoch=hub_a.epoch
                )
                await _until(lambda: len(resumed.events()) == N - 10, "the resume on B")
                out["resumed"] = resumed.events()
                # and the same from A's own hub, whose ring of 4 no longer holds it
                again, _ = await _console(
                    hub_a, topic="commands", since_seq=last, epoch=hub_a.epoch
                )
                await _until(lambda: len(again.events()) == N - 10, "the resume from JetStream")
                out["again"] = again.events()
                # a seq ahead of JetStream's is refused, one behind A's hub but in
                # JetStream is not (another ground may be ahead of this one)
                ahead, _ = await _console(
                    hub_b, topic="commands", since_seq=10**9, epoch=hub_a.epoch
                )
                await _until(lambda: bool(ahead.received[1:]), "the refusal")
                out["ahead"] = ahead.received[1]
            finally:
                await a.close()
                await b.close()
        return out

    out = asyncio.run(scenario())
    seqs_a = [m["seq"] for m in out["a"]]
    assert seqs_a == sorted(set(seqs_a))  # increasing, each once (not contiguous: JetStream's)
    assert [m["event"]["detail"]["seq"] for m in out["a"]] == list(range(1, N + 1))
    commands_on_b = [m for m in out["b"] if m["event"]["kind"] == "command_stage"]
    assert [m["seq"] for m in commands_on_b] == seqs_a  # one numbering on both grounds
    for resumed in (out["resumed"], out["again"]):
        assert [m["seq"] for m in resumed] == seqs_a[10:]  # every message after it, once
        assert [m["event"] for m in resumed] == [m["event"] for m in out["a"][10:]]
    assert out["ahead"]["type"] == "error" and "ahead of the stream" in out["ahead"]["reason"]
