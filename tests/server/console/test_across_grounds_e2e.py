"""Two grounds, one PostgreSQL, one NATS JetStream: a console sees the same live pass on
either, and one whose ground is killed resumes on the other (docs/console.md "Across
grounds").

Ground A (``hikoboshi serve``, the lease's holder) flies a pass; ground B (a standby on the
same database schema and the same ``nats-server -js``) serves consoles. A console on B sees
the frames and command stages A commits, with A's seqs. A console on A reads the pass's
telemetry; A is killed (SIGKILL); the console reconnects to B, subscribes with its last seq
and epoch, and goes on: every frame of the pass comes once, none twice, through the takeover
(B first publishes what A archived and never published, then stores and publishes its own).
"""

from __future__ import annotations

import asyncio
import json
import signal
import time
from pathlib import Path
from typing import Any

import pytest
from websockets.asyncio.client import ClientConnection, connect

from server.storage import repository as repo
from server.storage.db import make_engine, read_session_factory, session_factory
from tests.nats_server import nats_server
from tests.server.link.harness import (
    OPERATOR,
    serve_process,
    spacecraft_of_grounds,
    store_pass,
    wait_for,
)
from tests.support.processes import free_port

pytestmark = [pytest.mark.realtime, pytest.mark.slow]

SCALE = 10.0
TOKENS = "o-token=otto:operator,v-token=vera:viewer,s-token=ets7:spacecraft"
VIEWER = {"Authorization": "Bearer v-token"}
GUARD_S = 90.0  # a guard against a hang, not a timing assertion


def _env(name: str, nats_url: str) -> dict[str, str]:
    return {
        "HIKOBOSHI_TOKENS": TOKENS,
        "HIKOBOSHI_UPLINK_LEAD_WINDOW_S": "150",
        "HIKOBOSHI_GROUND_NAME": name,
        "HIKOBOSHI_LEASE_TTL_S": "3",
        "HIKOBOSHI_LEASE_RENEW_S": "0.5",
        "HIKOBOSHI_NATS_URL": nats_url,
        "HIKOBOSHI_NATS_STREAM": "E2E",
    }


class Console:
    """A console websocket's messages as they come, with their arrival (monotonic s)."""

    def __init__(self, ws: ClientConnection) -> None:
        self.ws = ws
        self.messages: list[tuple[float, dict[str, Any]]] = []
        self.task = asyncio.create_task(self._read())
        self.closed = asyncio.Event()

    @classmethod
    async def open(cls, port: int) -> Console:
        ws = await connect(f"ws://127.0.0.1:{port}/api/console", additional_headers=VIEWER)
        return cls(ws)

    async def _read(self) -> None:
        try:
            async for text in self.ws:
                self.messages.append((time.monotonic(), json.loads(text)))
        except Exception:
            pass
        finally:
            self.closed.set()

    async def subscribe(self, **fields: Any) -> None:
        await self.ws.send(json.dumps({"v": 1, "type": "subscribe", **fields}))

    def of(self, type_: str, topic: str | None = None) -> list[dict[str, Any]]:
        return [
            m
            for _, m in self.messages
            if m["type"] == type_ and (topic is None or m.get("topic") == topic)
        ]

    def welcome(self) -> dict[str, Any]:
        return self.of("welcome")[0]


def _frame_seqs(messages: list[dict[str, Any]]) -> list[int]:
    return [seq for m in messages for seq in m["columns"]["seq"]]


async def _jetstream_frames(url: str, pass_id: str, upto: int) -> list[int]:
    """The pass's frames JetStream holds up to stream seq ``upto``, read on their own."""
    import nats

    nc = await nats.connect(url)
    try:
        js = nc.jetstream()
        sub = await js.subscribe(f"hikoboshi.vehicle.{pass_id}.telemetry", ordered_consumer=True)
        seqs: list[int] = []
        while True:
            msg = await sub.next_msg(timeout=10.0)  # a guard
            if msg.metadata.sequence.stream > upto:
                break
            seqs.extend(row[0] for row in json.loads(msg.data)["rows"])
            if msg.metadata.sequence.stream == upto or msg.metadata.num_pending == 0:
                break
        return seqs
    finally:
        await nc.close()


def test_a_console_sees_the_holders_pass_on_the_standby_and_resumes_there_after_a_kill(
    postgres_schema_url: str, tmp_path: Path
) -> None:
    (tmp_path / "nats").mkdir()
    port_a, port_b = free_port(), free_port()
    engine = make_engine(postgres_schema_url)
    sessions, readers = session_factory(engine), read_session_factory(engine)
    process = spacecraft_of_grounds((port_a, port_b), scale=SCALE, seed=4, drain_timeout_s=5.0)

    def stored(pass_id: str) -> list[int]:
        with readers() as session:
            return list(repo.frame_seqs(session=session, pass_id=pass_id))

    async def scenario(nats_url: str) -> dict[str, Any]:
        import httpx

        seen: dict[str, Any] = {}
        stop = asyncio.Event()
        flying = asyncio.create_task(process.run(stop))
        log_a, log_b = tmp_path / "ground-a.log", tmp_path / "ground-b.log"
        try:
            with serve_process(postgres_schema_url, port_a, log_a, _env("a", nats_url)) as a:
                pass_id = store_pass(sessions, "across", (10.0, 0.0, 0.0, 10.0, 0.0, 0.0), 120.0)
                seen["pass_id"] = pass_id
                await wait_for(lambda: process.connections > 0, GUARD_S, "a spacecraft")
                with serve_process(postgres_schema_url, port_b, log_b, _env("b", nats_url)):
                    on_a, on_b = await Console.open(port_a), await Console.open(port_b)
                    await wait_for(lambda: on_a.of("welcome") and on_b.of("welcome"), 30, "hi")
                    epoch = on_a.welcome()["epoch"]
                    assert on_b.welcome()["epoch"] == epoch  # one numbering: JetStream's
                    for console in (on_a, on_b):
                        await console.subscribe(topic="telemetry", pass_id=pass_id)
                    await on_b.subscribe(topic="commands")
                    async with httpx.AsyncClient(base_url=f"http://127.0.0.1:{port_a}") as http:
                        started = await http.post(
                            f"/api/passes/{pass_id}/start",
                            json={"confirm": "START across"},
                            headers=OPERATOR,
                            timeout=30.0,
                        )
                        assert started.status_code == 200, started.text
                    # the standby's console sees the holder's pass live
                    await wait_for(
                        lambda: len(on_a.of("telemetry")) >= 30 and on_b.of("event", "commands"),
                        GUARD_S,
                        "frames on A, stages on B",
                    )
                    seen["b_stages"] = len(on_b.of("event", "commands"))
                    a.send_signal(signal.SIGKILL)
                    killed = time.monotonic()
                    a.wait(30)
                    await asyncio.wait_for(on_a.closed.wait(), GUARD_S)
                    before = on_a.of("telemetry")
                    last_seq = before[-1]["seq"]
                    # the console reconnects to B and resumes from its last seq
                    resumed = await Console.open(port_b)
                    await wait_for(lambda: resumed.of("welcome"), 30, "welcome on B")
                    assert resumed.welcome()["epoch"] == epoch
                    await resumed.subscribe(
                        topic="telemetry", pass_id=pass_id, since_seq=last_seq, epoch=epoch
                    )
                    held = stored(pass_id)
                    b_before, a_last = len(held), max(held)
                    # until B, holder now, has stored (and published) frames of its own
                    await wait_for(
                        lambda: (
                            len(stored(pass_id)) > b_before + 50
                            and resumed.of("telemetry")
                            and _frame_seqs(resumed.of("telemetry"))[-1] >= stored(pass_id)[-1] - 60
                        ),
                        GUARD_S,
                        "B's own frames on the resumed console",
                    )
                    after = resumed.of("telemetry")
                    first_after = next(t for t, m in resumed.messages if m["type"] == "telemetry")
                    live_after = next(
                        t
                        for t, m in resumed.messages
                        if m["type"] == "telemetry" and min(m["columns"]["seq"]) > a_last
                    )
                    seen |= {
                        "before": before,
                        "after": after,
                        "on_b": on_b.of("telemetry"),
                        "resume_s": first_after - killed,
                        "live_again_s": live_after - killed,
                        "errors": [m for _, m in resumed.messages if m["type"] == "error"],
                        "resyncs": [m for _, m in resumed.messages if m["type"] == "resync"],
                    }
                    for console in (on_b, resumed):
                        await console.ws.close()
                    seen["in_jetstream"] = await _jetstream_frames(
                        nats_url, pass_id, after[-1]["seq"]
                    )
                    # every frame archived is on the stream once: A's, those A archived and
                    # never published (B's backfill), B's own, retransmissions included
                    deadline = time.monotonic() + GUARD_S
                    while True:
                        held = stored(pass_id)
                        published = await _jetstream_frames(nats_url, pass_id, 2**62)
                        if set(held) <= set(published) or time.monotonic() > deadline:
                            break
                        await asyncio.sleep(0.5)
                    seen["stored"], seen["published"] = held, published
        finally:
            stop.set()
            await asyncio.wait_for(flying, GUARD_S)
        return seen

    try:
        with nats_server(tmp_path / "nats") as url:
            seen = asyncio.run(scenario(url))
    finally:
        engine.dispose()
    assert seen["b_stages"] > 0
    assert not seen["errors"] and not seen["resyncs"], (seen["errors"], seen["resyncs"])
    # the standby's console saw A's messages with A's seqs
    seqs_a = {m["seq"]: m["columns"]["seq"] for m in seen["before"]}
    on_b = {m["seq"]: m["columns"]["seq"] for m in seen["on_b"] if m["seq"] in seqs_a}
    assert on_b == seqs_a
    # the resumed console: every frame JetStream holds for the pass up to the last message
    # it read, once (A's part, then B's replay and B's own live frames)
    messages = seen["before"] + seen["after"]
    seqs = [m["seq"] for m in messages]
    assert seqs == sorted(set(seqs))
    frames = _frame_seqs(messages)
    assert len(frames) == len(set(frames)), "a frame seen twice"
    assert sorted(frames) == sorted(seen["in_jetstream"])
    # the stream: every frame archived once, those the killed ground had stored but not yet
    # published too (B published them on taking over)
    published, held = seen["published"], seen["stored"]
    unpublished = sorted(set(held) - set(published))
    print(
        f"\nconsole across a kill: {len(frames)} frames once each; on the stream "
        f"{len(published)} frames, {len(published) - len(set(published))} twice, "
        f"{len(unpublished)} archived and never published; resumed {seen['resume_s']:.2f} s "
        f"after the kill, B's own frames {seen['live_again_s']:.2f} s after it (3 s lease)"
    )
    assert len(published) == len(set(published)), "a frame published twice"
    assert not unpublished, f"{len(unpublished)} archived, never published: {unpublished[:20]}"
