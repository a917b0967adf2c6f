"""The live downlink stores a backlog of telemetry messages in one write, and one message
that cannot be stored costs only itself (simulated time, the real link and SQLite)."""

from __future__ import annotations

import asyncio
import threading
from pathlib import Path
from typing import Any

import pytest

from server.services.clock import ManualClock
from server.storage import repository as repo
from telemetry.layout import FrameLayout
from telemetry.wire import TelemetryMsg, encode
from tests.server.link.simulated import SimulatedSpacecraft, ground, make_sessions, store_pass
from tests.server.storage.factories import make_frames

SEVEN = FrameLayout(7, 3)


def test_a_backlog_is_stored_together_and_a_bad_message_alone_is_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    writes: list[int] = []  # messages per write of several
    ingest_messages = repo.ingest_messages

    def counted(**kw: Any) -> repo.IngestResult:
        writes.append(len(kw["messages"]))
        return ingest_messages(**kw)

    monkeypatch.setattr(repo, "ingest_messages", counted)

    async def scenario() -> tuple[list[int], Any]:
        clock = ManualClock()
        sessions = make_sessions(tmp_path)
        g = ground(sessions, clock)
        sc = SimulatedSpacecraft(clock)
        await sc.connect(g)
        pass_id = store_pass(sessions, 40, clock)  # a six-joint plan
        g.downlink.open_window(pass_id, 0)
        gate = threading.Event()

        def held(session: Any) -> list[dict[str, Any]]:
            assert gate.wait(60.0)
            return []

        g.db.submit(held)  # the database is busy: messages pile up behind it
        messages = [
            make_frames(range(0, 10)),
            make_frames(range(10, 20)),
            make_frames(range(20, 30), layout=SEVEN),  # frames another robot would send
            make_frames(range(30, 40)),
        ]
        for frames in messages:
            await g.link.handle(sc.conn, encode(TelemetryMsg(frames=frames)))
        gate.set()
        await g.downlink.settled()
        await g.db.drain()
        with sessions() as session:
            stored = repo.frame_seqs(session=session, pass_id=pass_id)
        return stored, g.downlink.held

    stored, held = asyncio.run(scenario())
    good = [*range(0, 20), *range(30, 40)]
    assert stored == good
    # acknowledged (held) exactly what was stored: the bad message goes unacknowledged
    assert [s for s in range(40) if s in held] == good
    # the first message went alone (the database was busy); the three that piled up behind
    # it were tried in one write, which the bad one failed (then each was stored alone)
    assert writes == [3]


def test_a_retransmission_s_frames_the_archive_held_are_published_once(tmp_path: Path) -> None:
    """After a takeover (or a restart) the vehicle resends what the ground gone stored but
    never acknowledged: those copies are not published again (the consoles had them, or the
    takeover's backfill gives them), while the frames new to the archive are."""

    async def scenario() -> tuple[list[int], list[int], set[int]]:
        clock = ManualClock()
        sessions = make_sessions(tmp_path)
        pass_id = store_pass(sessions, 40, clock)
        with sessions() as session:  # what the ground gone stored
            repo.ingest_frames(
                session=session,
                pass_id=pass_id,
                frames=make_frames(range(0, 20)),
                reception_time_ns=clock.time_ns(),
            )
            session.commit()
        g = ground(sessions, clock)
        sc = SimulatedSpacecraft(clock)
        await sc.connect(g)
        g.downlink.open_window(pass_id, 0)
        published: list[int] = []
        g.downlink._publisher.subscribe_frames(
            lambda _, frames, __: published.extend(f.seq for f in frames)
        )
        resent = TelemetryMsg(frames=make_frames(range(10, 30)), retransmission=True)
        await g.link.handle(sc.conn, encode(resent))
        await g.link.handle(sc.conn, encode(TelemetryMsg(frames=make_frames(range(30, 40)))))
        await g.downlink.settled()
        await g.db.drain()
        with sessions() as session:
            stored = repo.frame_seqs(session=session, pass_id=pass_id)
        return stored, published, {s for s in range(40) if s in g.downlink.held}

    stored, published, held = asyncio.run(scenario())
    assert stored == list(range(40))
    assert published == list(range(20, 40))
    assert held == set(range(10, 40))  # every frame received acknowledged, copies included


def test_frames_behind_is_the_backlog_of_a_connected_link_and_absent_without_one(
    tmp_path: Path,
) -> None:
    """The vehicle sends 10 frames at 10 Hz, then goes: ``frames_behind`` (the link's
    status, ``/metrics``) is what the connected vehicle has made that the ground does not
    hold, and absent once it has gone, however long it stays away (estimated from the
    onboard clock, it grew for ever after every pass: an alert on it never cleared). The
    alarms of a running pass watch the link on their own (docs/alarms.md)."""

    async def scenario() -> list[int | None]:
        clock = ManualClock()
        sessions = make_sessions(tmp_path)
        g = ground(sessions, clock)
        sc = SimulatedSpacecraft(clock)
        await sc.connect(g)
        g.downlink.open_window(store_pass(sessions, 40, clock), 0)
        start = sc.onboard_ns()
        frames = [
            f.model_copy(update={"generation_time_ns": start + f.seq * 100_000_000})
            for f in make_frames(range(10))
        ]
        await g.link.handle(sc.conn, encode(TelemetryMsg(frames=frames)))  # type: ignore[arg-type]
        await g.downlink.settled()
        await g.db.drain()
        seen: list[int | None] = []
        for step_s in (1.0, 11.0):
            clock.jump(step_s)
            seen.append(g.link.status().frames_behind)
        await sc.disconnect()
        for step_s in (0.0, 100.0):
            clock.jump(step_s)
            seen.append(g.link.status().frames_behind)
        return seen

    up, later, gone, long_gone = asyncio.run(scenario())
    # 1 s after the 10th frame: at least 10 more made, none held (the ground's idea of the
    # onboard clock runs ahead of the frames by the relay's delay); 11 s on, 110 more
    assert up is not None and up >= 10 and later == up + 110
    assert gone is None and long_gone is None
