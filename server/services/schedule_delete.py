"""The ``schedule_delete`` (PUS 11) of an aborted pass, until the vehicle verifies it.

With something of the pass sent, the abort asks the vehicle to delete the pass's seqs from
the next 0.25 s grid tag ``T`` at least (delay + margin) ahead: the request goes up at once
:data:`DELETE_COPIES` times and then on the retransmission timer until the vehicle's
``verification`` arrives; the arm holds at the last target before ``T`` (the vehicle ramps to
it and stops). The link down at the abort: ``T`` is chosen when it is back. The telemetry
window closes ``settle`` after ``T``. Once verified, the report is filed
(``schedule_deleted``) and the commands it deleted, and those tagged from ``T`` on, become
``cancelled``; the vehicle's own word on a command (it executed after all, the delete
arriving late) overrules that. Unverified by the time every tag has passed:
``schedule_delete_unverified``.
"""

from __future__ import annotations

import asyncio
import math
from dataclasses import dataclass, field
from typing import Any

from sqlalchemy.orm import Session

from server.services.clock import Clock
from server.services.command_stages import cancel_commands
from server.services.dbworker import Database
from server.services.downlink import GroundDownlink
from server.services.events import (
    Recorded,
    ScheduleDeleted,
    ScheduleDeleteUnverified,
    event_job,
    record,
)
from server.services.link import GroundLink, LinkEvent, LinkUp, RequestVerified, TelemetryWindow
from server.services.tracker import LINK_DOWN_POLL_S, CommandTracker
from server.services.uplink import RttEstimator
from telemetry.uplink import GRID_NS
from telemetry.wire import ScheduleDelete, Verification

__all__ = ["DELETE_COPIES", "Deletion", "ScheduleDeletes"]

#: Copies of a ``schedule_delete`` sent at once (then one per retransmission timeout).
DELETE_COPIES = 3


@dataclass
class Deletion:
    """A ``schedule_delete`` on its way: retransmitted until verified."""

    tracker: CommandTracker
    window: TelemetryWindow
    last_tag_ns: int  # the pass's last tag: nothing left to delete after it
    #: (seq, tag) of the commands of the pass's uplink
    commands: tuple[tuple[int, int], ...]
    max_seq: int
    reason: str
    actor: str
    rtt: RttEstimator
    request: ScheduleDelete | None = None  # None: the link was down, T not chosen yet
    verified: asyncio.Event = field(default_factory=asyncio.Event)
    report: Verification | None = None
    sends: int = 0

    @property
    def from_ns(self) -> int | None:
        """``T``, once chosen."""
        return None if self.request is None else self.request.from_time_ns


class ScheduleDeletes:
    """The ``schedule_delete`` requests of the ground (see the module docstring), matched
    with their ``verification`` by request id."""

    def __init__(
        self,
        *,
        link: GroundLink,
        downlink: GroundDownlink,
        db: Database,
        clock: Clock,
        lead_ns: int,
        settle_ns: int,
    ) -> None:
        self._link = link
        self._downlink = downlink
        self._db = db
        self._clock = clock
        self._lead_ns = lead_ns
        self._settle_ns = settle_ns
        self._pending: dict[int, Deletion] = {}  # request id -> deletion
        self._link_up = asyncio.Event()
        link.add_listener(self._on_link_event)

    def _on_link_event(self, event: LinkEvent) -> None:
        if isinstance(event, RequestVerified):
            deletion = self._pending.get(event.report.request_id)
            if deletion is not None and deletion.report is None:
                deletion.report = event.report
                deletion.verified.set()
        elif isinstance(event, LinkUp):
            self._link_up.set()

    def _choose(self, deletion: Deletion) -> int:
        """Choose ``T`` (the link is up) and register the request; ``T``."""
        earliest = self._link.onboard_now_ns() + self._lead_ns
        from_ns = math.ceil(earliest / GRID_NS) * GRID_NS
        deletion.request = ScheduleDelete(
            request_id=deletion.max_seq, from_time_ns=from_ns, max_seq=deletion.max_seq
        )
        self._pending[deletion.max_seq] = deletion
        return from_ns

    async def _send(self, deletion: Deletion, copies: int) -> None:
        assert deletion.request is not None
        for _ in range(copies):
            if await self._link.send_schedule_delete(deletion.request):
                deletion.sends += 1

    async def begin(self, deletion: Deletion) -> None:
        """Send the first copies at once if the link is up (``T`` chosen): before any
        database work, since ``T`` is (delay + margin) ahead of now and a backlog of writes
        must not make it late."""
        if self._link.connected:
            self._choose(deletion)
            await self._send(deletion, DELETE_COPIES)

    async def complete(self, deletion: Deletion, closing: asyncio.Event) -> None:
        """Retransmit until the verification arrives (choosing ``T`` once the link is back,
        if it was down at the abort), then file the vehicle's report and cancel what it
        deleted."""
        link, clock = self._link, self._clock
        while not closing.is_set() and not deletion.verified.is_set():
            if not link.connected:
                self._link_up.clear()
                await clock.sleep_until(clock.monotonic() + LINK_DOWN_POLL_S, self._link_up)
                continue
            if link.onboard_now_ns() > deletion.last_tag_ns:
                break  # every command's tag has passed: nothing left to delete
            if deletion.request is None:
                from_ns = self._choose(deletion)
                self._downlink.close_window(deletion.window, from_ns + self._settle_ns)
                await self._send(deletion, DELETE_COPIES)
            else:
                await self._send(deletion, 1)
            timeout = deletion.rtt.rto_s  # fixed, as the commands' own timer
            await clock.sleep_until(clock.monotonic() + timeout, deletion.verified)
        report, request = deletion.report, deletion.request
        if request is not None:
            self._pending.pop(request.request_id, None)
        if report is not None and request is not None:
            await self._db.write(self._deleted_job(deletion, report, request))
        elif not closing.is_set():
            unverified = ScheduleDeleteUnverified(
                actor="ground",
                pass_id=deletion.tracker.pass_id,
                request_id=None if request is None else request.request_id,
            )
            await self._db.write(event_job(unverified, self._clock))

    def _deleted_job(
        self, deletion: Deletion, report: Verification, request: ScheduleDelete
    ) -> Any:
        tracker = deletion.tracker
        seqs = [s for lo, hi in report.deleted_ranges for s in range(lo, hi + 1)]
        seqs += [seq for seq, tag in deletion.commands if tag >= request.from_time_ns]
        pass_id = tracker.pass_id
        deleted = ScheduleDeleted(
            actor="ground",
            pass_id=pass_id,
            request_id=report.request_id,
            from_time_ns=request.from_time_ns,
            deleted=report.deleted,
            executed_after_from=report.executed_after_from,
            copies_sent=deletion.sends,
        )
        clock = self._clock
        now = clock.time_ns()

        def job(session: Session) -> list[Recorded]:
            events = [record(session, deleted, clock.time_ns())]
            if seqs:
                events += cancel_commands(
                    session,
                    clock=clock,
                    pass_id=pass_id,
                    seqs=seqs,
                    time_ns=now,
                    actor=deletion.actor,
                    reason=f"{deletion.reason} (deleted from the schedule)",
                    from_time_ns=request.from_time_ns,
                )
            return events

        tracker.cancelled(seqs)
        return job

    async def after_abort(
        self,
        tracker: CommandTracker,
        deletion: Deletion | None,
        closing: asyncio.Event,
        *,
        safed: bool = False,
        ask_about: list[int] | None = None,
    ) -> None:
        """In the background after an abort: the ``schedule_delete`` (if any) to its end,
        then the stages of the commands before ``T`` as their tags pass (``safed``: the
        vehicle safed itself, so every command not final is asked about at once;
        ``ask_about``: commands the vehicle holds with no send on file, asked about
        first while still ``queued`` or only taken as ``expired``)."""
        try:
            if deletion is not None:
                await self.complete(deletion, closing)
            await tracker.resolve(closing, any_tag=safed, ask_about=ask_about or ())
        finally:
            tracker.close()
