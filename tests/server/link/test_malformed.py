"""Malformed messages on the spacecraft link cost bounded work (server/services/malformed.py):
the ground's link on the simulated clock, fed a flood of the spacecraft's rehearsal garbage
(spacecraft/garbage.py). Replies at a bounded rate, one audit row per kind per interval
with its count, the well-formed messages between the garbage still handled, a flood beside
them never a reason to close, and a connection closed, with its reason, only when its stream
is unusable (nothing readable for a whole interval under a run of malformed messages)."""

from __future__ import annotations

import asyncio
import json
import logging
from pathlib import Path
from typing import Any

import pytest

from server.services.clock import ManualClock
from server.services.link import Connection, GroundLink
from server.storage import repository as repo
from spacecraft.garbage import GarbageMaker
from telemetry.wire import Hello, Pong, encode
from tests.server.link.simulated import ground, make_sessions

HELLO = Hello(vehicle="ETS-VII", onboard_time_ns=10**18, time_scale=20.0, next_telemetry_seq=0)
#: the kinds the garbage's four makes fall in, as the ground counts them (type:code)
GARBAGE_KINDS = {"-:not_json", "other:unknown_type", "telemetry:version", "telemetry:invalid"}


class Socket:
    """What the ground sent on one connection, and how it was closed."""

    def __init__(self) -> None:
        self.sent: list[dict[str, Any]] = []
        self.closed: tuple[int, str] | None = None

    def connection(self) -> Connection:
        async def send_text(text: str) -> None:
            self.sent.append(json.loads(text))

        async def close(code: int, reason: str) -> None:
            self.closed = (code, reason)

        return Connection(actor="ets7", send_text=send_text, close=close)

    def errors(self) -> list[dict[str, Any]]:
        return [m for m in self.sent if m["type"] == "error"]


async def _connect(link: GroundLink, socket: Socket) -> Connection:
    conn = socket.connection()
    await link.attach(conn)
    await link.handle(conn, encode(HELLO))
    assert link.connected
    return conn


def _events(sessions: Any, *kinds: str) -> list[Any]:
    with sessions() as session:
        return list(repo.list_events(session=session, kinds=list(kinds), limit=1000).items)


def test_replies_are_bounded_and_each_kind_is_one_audit_row_per_interval(tmp_path: Path) -> None:
    sessions = make_sessions(tmp_path)
    clock = ManualClock()
    g = ground(
        sessions,
        clock,
        malformed_interval_s=5.0,
        malformed_replies_per_s=10.0,
    )
    garbage = GarbageMaker(seed=1)
    socket = Socket()

    async def scenario() -> None:
        conn = await _connect(g.link, socket)
        # 400 a second for 3 s, in steps of 10 ms; a pong between every 40 (its round trip
        # is taken: the link still reads what it understands)
        for step in range(300):
            for _ in range(4):
                await g.link.handle(conn, garbage.next(), clock.monotonic())
            if step % 10 == 0:
                pong = Pong(ping_id=step, ground_time_ns=1, onboard_time_ns=10**18 + step)
                await g.link.handle(conn, encode(pong), clock.monotonic())
            await clock.advance(0.01)
        await clock.advance(5.0)  # past the interval's end: its rows are written
        await g.db.drain()
        assert socket.closed is None

    asyncio.run(scenario())
    status = g.link.status()
    errors = socket.errors()
    # at most 10 a second, and a burst of 10: 3 s of flood get 10 + 3 x 10 at most
    assert 30 <= len(errors) <= 40, len(errors)
    assert status.malformed_received == 1200
    assert status.errors_replied == len(errors)
    assert status.errors_unanswered == 1200 - len(errors)
    assert set(status.malformed_by_kind) == GARBAGE_KINDS
    assert all(n == 300 for n in status.malformed_by_kind.values())
    # each reply after unanswered ones says how many were passed over since the last
    skipped = [e for e in errors if "unanswered before this one" in e["reason"]]
    assert len(skipped) == len(errors) - 10
    assert all(len(e["reason"]) <= 500 for e in errors)
    # one row per kind for the one interval the flood fell in, with its count
    rows = _events(sessions, "link_error_replied")
    assert len(rows) == 4
    counted = {(r.detail["ref_type"] is None, r.detail["code"]): r.detail for r in rows}
    assert set(counted) == {
        (True, "not_json"),
        (False, "unknown_type"),
        (False, "version"),
        (False, "invalid"),
    }
    assert all(d["count"] == 300 for d in counted.values())
    assert sum(d["replied"] for d in counted.values()) == len(errors)
    assert "not JSON" in counted[(True, "not_json")]["reason"]
    assert counted[(False, "version")]["ref_type"] == "telemetry"
    for detail in counted.values():
        assert detail["first_time_ns"] < detail["last_time_ns"]
    assert g.link.round_trip_s is not None  # the pongs between the garbage were read


def test_a_second_interval_gets_rows_of_its_own(tmp_path: Path) -> None:
    sessions = make_sessions(tmp_path)
    clock = ManualClock()
    g = ground(sessions, clock, malformed_interval_s=2.0)
    garbage = GarbageMaker(seed=2)

    async def scenario() -> None:
        conn = await _connect(g.link, Socket())
        for burst in (8, 12):  # two intervals, 2 s apart
            for _ in range(burst):
                await g.link.handle(conn, garbage.next(), clock.monotonic())
            await clock.advance(2.5)
        await g.db.drain()

    asyncio.run(scenario())
    rows = _events(sessions, "link_error_replied")
    assert len(rows) == 8
    assert sorted(r.detail["count"] for r in rows) == [2] * 4 + [3] * 4


def test_a_flood_beside_valid_messages_never_closes_the_link(tmp_path: Path) -> None:
    """400 malformed messages a second for 20 s, 1,800 in a row between two pongs 4.5 s
    apart: more than ``malformed_unusable_after`` (1000) a run and 2,000 an interval (the
    rule of before closed at 1,001 in 5 s), yet every run has a readable message within the
    interval: the link stays up, the noise dropped and counted, the pongs read."""
    sessions = make_sessions(tmp_path)
    clock = ManualClock()
    g = ground(sessions, clock)  # the defaults: 5 s, 1000
    garbage = GarbageMaker(seed=4)
    socket = Socket()
    pongs = 0

    async def scenario() -> None:
        nonlocal pongs
        conn = await _connect(g.link, socket)
        for step in range(2000):  # 10 ms steps
            for _ in range(4):
                await g.link.handle(conn, garbage.next(), clock.monotonic())
            if step % 450 == 449:
                pong = Pong(ping_id=step, ground_time_ns=1, onboard_time_ns=10**18 + step)
                await g.link.handle(conn, encode(pong), clock.monotonic())
                pongs += 1
            await clock.advance(0.01)
        await clock.advance(6.0)
        await g.db.drain()

    asyncio.run(scenario())
    assert pongs == 4
    assert socket.closed is None and g.link.connected
    status = g.link.status()
    assert status.malformed_received == 8000 and status.malformed_closes == 0
    assert _events(sessions, "link_closed_malformed") == []
    assert sum(r.detail["count"] for r in _events(sessions, "link_error_replied")) == 8000
    assert g.link.clock_confirmed  # the pongs' onboard stamps were read


def test_an_unusable_stream_is_closed_with_the_reason(tmp_path: Path) -> None:
    """Nothing readable after the hello, only garbage: kept while the run is short of the
    count or of the interval, closed (1008, audited) on the first malformed message that
    finds both past; a reconnected vehicle's hello starts a run of its own."""
    sessions = make_sessions(tmp_path)
    clock = ManualClock()
    g = ground(sessions, clock, malformed_interval_s=5.0, malformed_unusable_after=100)
    garbage = GarbageMaker(seed=3)
    first, second = Socket(), Socket()

    async def scenario() -> None:
        conn = await _connect(g.link, first)
        for _ in range(500):  # 500 in 1 s: past the count, not the interval
            await g.link.handle(conn, garbage.next(), clock.monotonic())
            await clock.advance(0.002)
        assert first.closed is None
        await clock.advance(3.999)  # 4.999 s since the run's first
        await g.link.handle(conn, garbage.next(), clock.monotonic())
        assert first.closed is None
        await clock.advance(0.01)  # 5.009 s
        await g.link.handle(conn, garbage.next(), clock.monotonic())
        reason = "unusable stream: 502 malformed messages and nothing readable for 5.0 s"
        assert first.closed == (1008, reason)
        await g.link.detach(conn, "closed by the ground (1008)")
        # the vehicle reconnects: its hello is readable, a new run starts; 100 malformed
        # over 10 s (a whole interval, not the count) keep it
        conn = await _connect(g.link, second)
        for _ in range(100):
            await g.link.handle(conn, garbage.next(), clock.monotonic())
            await clock.advance(0.1)
        assert second.closed is None and g.link.connected
        await clock.advance(6.0)
        await g.db.drain()

    asyncio.run(scenario())
    [closed] = _events(sessions, "link_closed_malformed")
    assert closed.detail["reason"].startswith("unusable stream: 502 malformed messages")
    assert closed.detail["count"] == 502 and closed.detail["interval_s"] == 5.0
    assert closed.detail["unreadable_s"] == pytest.approx(5.009, abs=1e-6)
    assert g.link.status().malformed_closes == 1
    rows = _events(sessions, "link_error_replied")
    assert sum(r.detail["count"] for r in rows) == 602


def test_error_messages_from_the_vehicle_are_tallied_never_answered(tmp_path: Path) -> None:
    sessions = make_sessions(tmp_path)
    clock = ManualClock()
    g = ground(sessions, clock, malformed_interval_s=1.0, malformed_unusable_after=10)
    socket = Socket()

    async def scenario() -> None:
        conn = await _connect(g.link, socket)
        error = json.dumps({"v": 2, "type": "error", "reason": "cannot read", "ref_type": "ping"})
        for _ in range(50):  # well-formed, readable: 50 over 2.5 s never close the link
            await g.link.handle(conn, error, clock.monotonic())
            await clock.advance(0.05)
        await clock.advance(1.5)
        await g.db.drain()

    asyncio.run(scenario())
    assert socket.errors() == [] and socket.closed is None
    rows = _events(sessions, "link_error_received")
    assert sum(r.detail["count"] for r in rows) == 50 and len(rows) == 3  # 1 s intervals
    row = rows[0]
    assert {r.detail["code"] for r in rows} == {"received"}
    assert row.detail["reason"] == "cannot read" and row.detail["ref_type"] == "ping"
    assert g.link.status().errors_received == 50


def test_a_diverged_vehicle_s_frames_are_refused_and_counted_by_their_reason(
    tmp_path: Path,
) -> None:
    """Frames no real vehicle can send (a joint at 1e15 rad, a base turning at 1e30 rad/s:
    issue 28's diverged Panda) are refused before the archive, answered with the reason and
    counted as ``telemetry:unphysical``; a NaN stays ``telemetry:invalid``."""
    from tests.support.wire import telemetry_text as _telemetry_text

    sessions = make_sessions(tmp_path)
    clock = ManualClock()
    g = ground(sessions, clock, malformed_interval_s=5.0)
    socket = Socket()

    async def scenario() -> None:
        conn = await _connect(g.link, socket)
        diverged = _telemetry_text(joints_rad=[0.0, 0.0, 1e15, 0.0, 0.0, 0.0])
        await g.link.handle(conn, diverged, clock.monotonic())
        spinning = _telemetry_text(omega_base_in_base_radps=[0.0, 1e30, 0.0])
        await g.link.handle(conn, spinning, clock.monotonic())
        nan = _telemetry_text(joints_rad=[0.0, float("nan"), 0.0, 0.0, 0.0, 0.0])
        await g.link.handle(conn, nan, clock.monotonic())
        await clock.advance(6.0)
        await g.db.drain()

    asyncio.run(scenario())
    assert g.link.status().malformed_by_kind == {"telemetry:unphysical": 2, "telemetry:invalid": 1}
    reasons = [e["reason"] for e in socket.errors()]
    assert any("joints_rad[2] = 1e+15 rad" in r for r in reasons), reasons
    assert any("base rate 1e+30 rad/s" in r for r in reasons), reasons
    rows = {r.detail["code"]: r.detail for r in _events(sessions, "link_error_replied")}
    assert rows["unphysical"]["count"] == 2


def test_a_closed_socket_s_failed_sends_are_logged_once_and_counted(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """After the ground closes a connection (an unusable stream, above), the uplink's sends
    fail until the handler detaches it: one warning names the connection and the first
    failure, and the detach gives the count (a flood's closes used to log a warning per
    queued command: 898 of a 948-line log)."""
    sessions = make_sessions(tmp_path)
    g = ground(sessions, ManualClock())

    async def scenario() -> None:
        conn = await _connect(g.link, Socket())

        async def gone(text: str) -> None:
            raise ConnectionResetError("socket closed")

        conn.send_text = gone
        with caplog.at_level(logging.WARNING, logger="hikoboshi.ground.link"):
            sent = [await g.link.send(encode(HELLO)) for _ in range(50)]
            await g.link.detach(conn, "closed by the ground (1008)")
        assert sent == [False] * 50
        assert conn.send_failures == 50

    asyncio.run(scenario())
    lines = [r.getMessage() for r in caplog.records if r.name == "hikoboshi.ground.link"]
    failed = [m for m in lines if "send to spacecraft failed" in m]
    assert len(failed) == 1 and "connection " in failed[0], lines
    assert any("50 sends failed" in m for m in lines), lines
