"""The command tracker, the one definition of a final stage, and events on the injected
clock (issue 23). Simulated time throughout (``simulated.py``)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from pathlib import Path
from typing import Any

from sqlalchemy import select

from server.services import command_stages
from server.services.clock import ManualClock
from server.services.link import CommandAcked, CommandsUnknown, LinkEvent
from server.services.tracker import MAX_COMMAND_QUERIES, CommandTracker
from server.storage import stages
from server.storage.models import COMMAND_STAGES, EventRecord
from tests.server.link.sim_runs import run_pass
from tests.server.link.simulated import pass_state


def test_final_is_defined_once_from_the_ranks() -> None:
    assert stages.FINAL_STAGES == ("executed", "rejected", "expired", "cancelled")
    assert command_stages.FINAL_STAGES is stages.FINAL_STAGES
    assert set(stages.OPEN_STAGES) | set(stages.FINAL_STAGES) == set(COMMAND_STAGES)
    assert stages.AWAITING_ACK_STAGES == ("released", "sent", "received")
    # the vehicle's own word overrules the ground's inference, never the other way round
    assert stages.moves("expired", "executed") and stages.moves("cancelled", "rejected")
    assert not stages.moves("executed", "cancelled") and not stages.moves("received", "sent")


class _FakeLink:
    """What a tracker reads of the link: its listeners, the onboard clock, the queries."""

    def __init__(self, clock: ManualClock) -> None:
        self.clock = clock
        self.connected = True
        self.listeners: list[Callable[[LinkEvent], None]] = []
        self.queries: list[list[int]] = []

    def add_listener(self, callback: Callable[[LinkEvent], None]) -> Callable[[], None]:
        self.listeners.append(callback)
        return lambda: self.listeners.remove(callback)

    def emit(self, event: LinkEvent) -> None:
        for callback in list(self.listeners):
            callback(event)

    def onboard_now_ns(self) -> int:
        return round(self.clock.monotonic() * 1e9)

    def mono_at_onboard(self, onboard_ns: int) -> float:
        return onboard_ns / 1e9

    async def query_commands(self, seqs: list[int]) -> bool:
        self.queries.append(list(seqs))
        return self.connected


def _tracker(clock: ManualClock, link: _FakeLink, fates: list[tuple[int, str, int]]) -> Any:
    # no database: resolving reads and writes none
    return CommandTracker(
        "p",
        fates,
        link=link,
        db=None,
        clock=clock,
        one_way_delay_s=3.0,  # type: ignore[arg-type]
    )


def test_resolution_waits_on_acknowledgements_not_on_a_database_poll() -> None:
    async def scenario() -> None:
        clock = ManualClock(start=1000.0)
        link = _FakeLink(clock)
        tag = 990 * 10**9  # passed
        tracker = _tracker(
            clock, link, [(1, "sent", tag), (2, "received", tag), (3, "executed", tag)]
        )
        assert tracker.outstanding() == [(1, tag), (2, tag)]
        stop = asyncio.Event()
        resolving = asyncio.ensure_future(tracker.resolve(stop))
        await clock.settle()
        assert link.queries == [[1, 2]]  # asked at once about both
        link.emit(CommandAcked(1, "executed", None, tag, clock.monotonic()))
        await clock.settle()
        assert not resolving.done()
        link.emit(CommandAcked(2, "rejected", "late", tag, clock.monotonic()))
        await clock.settle()
        # done on the acknowledgement itself: no time passed, no second query
        assert resolving.done() and resolving.result() == 0
        assert link.queries == [[1, 2]] and clock.monotonic() == 1000.0
        assert tracker.stage(2) == "rejected"
        tracker.close()
        assert link.listeners == []

    asyncio.run(scenario())


def test_commands_unknown_onboard_expire_and_the_queries_end() -> None:
    async def scenario() -> None:
        clock = ManualClock(start=1000.0)
        link = _FakeLink(clock)
        passed, due_later = 990 * 10**9, 1010 * 10**9
        tracker = _tracker(clock, link, [(1, "sent", passed), (2, "sent", due_later)])
        resolving = asyncio.ensure_future(tracker.resolve(asyncio.Event()))
        await clock.settle()
        assert link.queries == [[1]]  # only what is due: 2's tag has not passed
        link.emit(CommandsUnknown((1, 2), link.onboard_now_ns()))
        assert tracker.stage(1) == "expired"  # never received, its tag passed
        assert tracker.stage(2) == "sent"  # not due yet: still to be sent
        # a round trip and a second between queries, until they are used up
        await clock.advance(7.0 * MAX_COMMAND_QUERIES + 20.0)
        assert resolving.done() and resolving.result() == 1  # 2 never answered
        assert link.queries == [[1]] + [[2]] * (MAX_COMMAND_QUERIES - 1)
        tracker.close()

    asyncio.run(scenario())


def test_every_event_of_a_pass_is_stamped_by_the_injected_clock(tmp_path: Path) -> None:
    """Event rows and their details on one clock: the ManualClock's wall time, not the
    process's (this ManualClock's wall time starts in 2027, after any real clock here)."""

    async def scenario() -> tuple[list[EventRecord], int, str]:
        _, g, pass_id = await run_pass(tmp_path, 40, seconds=60)
        with g.sessions() as session:  # type: ignore[attr-defined]
            rows = list(session.scalars(select(EventRecord).order_by(EventRecord.id)))
        return rows, g.link.clock.time_ns(), pass_state(g.sessions, pass_id)  # type: ignore[attr-defined]

    start_ns = ManualClock().time_ns()  # the simulated ground's clock at its start
    rows, end_ns, state = asyncio.run(scenario())
    assert state == "complete"
    kinds = {r.kind for r in rows}
    assert {"link_connected", "link_hello", "pass_state", "command_stage"} <= kinds
    assert all(start_ns <= r.time_ns <= end_ns for r in rows), [
        (r.kind, r.time_ns) for r in rows if not start_ns <= r.time_ns <= end_ns
    ][:5]
    # a stage's ground time (sent) and its row's time: one clock, the row written after
    sent = [r for r in rows if r.kind == "command_stage" and r.detail["stage"] == "sent"]
    assert sent and all(start_ns <= r.detail["time_ns"] <= r.time_ns for r in sent)
