"""Alarms on the ground: every archived frame checked against its pass's limits, the link's
health on a timer, the vehicle's safing, and the operator's acknowledgement (docs/alarms.md).

:class:`AlarmService` is built by the composition root beside the downlink and fed by the
consoles' :class:`~server.services.dbworker.Publisher`: its frames (each batch as it is
committed, before the consoles get it) and its events (``pass_state`` and ``pass_resumed``
say which pass runs). Nothing of the link, the downlink or the runner was changed for it.

- **Per pass** a monitor (:class:`~server.services.alarm_monitor.PassMonitor`: the pass's
  frame evaluator and alarm book), loaded on the first frame or the pass's start; frames
  that arrive meanwhile wait for it. A batch is evaluated at once, vectorised, on the event
  loop; frames older than the newest evaluated (a resent gap) are not evaluated again.
- **Writes** (:class:`~server.services.alarm_writes.AlarmWriter`) go through the command
  path's database worker: a raise, a change of band, a clear at once, an in-band update at
  most once per second per alarm, each published to the consoles when it has committed.
- **Link health** (``frames_behind``, ``frame_age_s``) every :data:`LINK_PERIOD_S` of the
  injected clock while a pass is ``running``; their alarms clear when it leaves that state
  (LOS, an abort, safing: its telemetry window closes, no frame of it is expected).
- **The vehicle's safing**: :meth:`AlarmService.vehicle_safed` raises the ``critical``
  alarm of source ``vehicle``, quantity ``vehicle_safing`` (reports repeated while the
  vehicle stays safe update it), :meth:`AlarmService.vehicle_nominal` clears it.
- **Acknowledgement** (:meth:`AlarmService.acknowledge`, operators only at the API): a
  control job of the database worker; 404 ``alarm_not_found``, 409
  ``already_acknowledged``.

``Settings.limit_checking`` False turns the frames' and the link's checks off (the vehicle's
alarms and acknowledgements stay).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable
from typing import Any

from sqlalchemy.orm import Session

from planner.limits import QUANTITIES, Severity
from server.schemas.alarms import AlarmPublic, AlarmsPublic
from server.services._console_limits import canonical_pass
from server.services.alarm_book import AlarmBook, Observation, QuantityInfo
from server.services.alarm_monitor import PassMonitor, observation
from server.services.alarm_writes import AlarmWriter
from server.services.clock import Clock
from server.services.dbworker import Database, Publisher
from server.services.downlink import GroundDownlink
from server.services.errors import ConflictError, NotFoundError
from server.services.events import (
    AlarmAcknowledged,
    PassResumed,
    PassState,
    Recorded,
    on_commit,
    record,
)
from server.services.link import GroundLink, LinkUnavailable
from server.settings import Settings
from server.storage import alarms as alarm_repo
from server.storage import repository as repo
from server.storage.errors import Conflict, NotFound
from telemetry.limits import link_readings
from telemetry.wire import Safing, TelemetryFrame

__all__ = [
    "LINK_PERIOD_S",
    "LINK_QUANTITIES",
    "VEHICLE_SAFING",
    "AlarmService",
    "list_alarms",
]

log = logging.getLogger("hikoboshi.ground.alarms")

#: Ground s between two link-health checks while a pass runs (injected clock).
LINK_PERIOD_S = 1.0
#: The quantities checked on the ground's timer, not per frame.
LINK_QUANTITIES = ("frames_behind", "frame_age_s")
#: The quantity of the vehicle's safing alarm.
VEHICLE_SAFING = "vehicle_safing"
#: Frames held for a monitor still loading, at most (the newest kept).
MAX_PENDING_FRAMES = 100_000


class AlarmService:
    """The ground's alarms (see the module docstring); :meth:`start` subscribes it."""

    def __init__(
        self,
        *,
        db: Database,
        publisher: Publisher,
        clock: Clock,
        downlink: GroundDownlink,
        link: GroundLink,
        settings: Settings,
    ) -> None:
        self._db = db
        self._publisher = publisher
        self._clock = clock
        self._downlink = downlink
        self._link = link
        self._settings = settings
        self.checking = settings.limit_checking
        self._monitors: dict[str, PassMonitor] = {}
        #: the vehicle's safing alarms, by pass (None: of no pass)
        self._vehicle: dict[str | None, AlarmBook] = {}
        self._unhook: list[Callable[[], None]] = []
        self._link_task: asyncio.Task[None] | None = None
        self._writer = AlarmWriter(db=db, clock=clock)
        self._closed = False
        #: frames not evaluated: older than the newest evaluated of their pass
        self.frames_late = 0
        self.frames_evaluated = 0

    # -- lifecycle -----------------------------------------------------------------------

    def start(self) -> None:
        self._unhook = [
            self._publisher.subscribe(self._on_event),
            self._publisher.subscribe_frames(self._on_frames),
        ]

    async def load_vehicle_alarms(self) -> None:
        """Take over the vehicle's alarms still listed (after a restart)."""

        def job(session: Session) -> list[AlarmPublic]:
            page = alarm_repo.list_alarms(session=session, active=True, limit=1000)
            return [alarm_repo.stored_alarm(r) for r in page.items if r.source == "vehicle"]

        for alarm in await self._db.run(job):
            self._vehicle_book(alarm.pass_id).restore([alarm])

    async def close(self) -> None:
        """Stop watching; what is left to write is written."""
        self._closed = True
        self._writer.closed = True
        for unhook in self._unhook:
            unhook()
        self._unhook = []
        for task in (self._link_task, self._writer.flusher, *self._loads()):
            if task is not None:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await task
        self._writer.flush(force=True)
        await self.settled()

    def _loads(self) -> list[asyncio.Task[None]]:
        return [m.loading for m in self._monitors.values() if m.loading is not None]

    async def settled(self) -> None:
        """Wait until every monitor has loaded and every alarm write has committed (tests,
        shutdown)."""
        while True:
            loads = [t for t in self._loads() if not t.done()]
            if loads:
                await asyncio.gather(*loads, return_exceptions=True)
                continue
            if self._writer.pending:
                await asyncio.gather(*list(self._writer.pending), return_exceptions=True)
                await asyncio.sleep(0)
                continue
            return

    # -- passes --------------------------------------------------------------------------

    def _on_event(self, recorded: Recorded) -> None:
        match recorded.event:
            case PassState(pass_id=str(pass_id), to=state):
                pass
            case PassResumed(pass_id=str(pass_id), state=state):
                pass
            case _:
                return
        monitor = self._monitors.get(pass_id)
        if monitor is None:
            if state not in ("running", "los") or not self.checking:
                return
            monitor = self._monitor(pass_id)
        was_watched = monitor.watched
        monitor.state = state
        if state == "running" and monitor.last_frame_ns is None:
            monitor.last_frame_ns = recorded.time_ns
        if monitor.watched and self.checking:
            self._watch_link()
        elif was_watched and not monitor.watched and monitor.book is not None:
            why = f"the pass is {state}: the link is no longer watched for it"
            changes = monitor.book.clear_all(self._clock.time_ns(), why, LINK_QUANTITIES)
            self._writer.apply(changes, self._clock.monotonic())

    def _monitor(self, pass_id: str) -> PassMonitor:
        monitor = self._monitors.get(pass_id)
        if monitor is None:
            monitor = self._monitors[pass_id] = PassMonitor(pass_id)
            monitor.loading = asyncio.get_running_loop().create_task(
                self._load(monitor), name=f"alarms-load-{pass_id}"
            )
        return monitor

    async def _load(self, monitor: PassMonitor) -> None:
        if not await monitor.load(self._db, self._settings.robot_files):
            return
        pending, monitor.pending = monitor.pending, []
        if pending:
            self._evaluate(monitor, pending)
        if monitor.watched and self.checking:
            self._watch_link()

    # -- frames --------------------------------------------------------------------------

    def _on_frames(
        self, pass_id: str, frames: list[TelemetryFrame], reception_time_ns: int
    ) -> None:
        if not self.checking or self._closed or not frames:
            return
        monitor = self._monitor(str(pass_id))
        monitor.last_frame_ns = max(monitor.last_frame_ns or 0, reception_time_ns)
        if monitor.disabled:
            return
        if monitor.evaluator is None:
            monitor.pending.extend(frames)
            del monitor.pending[:-MAX_PENDING_FRAMES]
            return
        self._evaluate(monitor, frames)

    def _evaluate(self, monitor: PassMonitor, frames: list[TelemetryFrame]) -> None:
        last = monitor.last_seq
        fresh = [f for f in frames if f.seq > last]
        self.frames_late += len(frames) - len(fresh)
        if not fresh:
            return
        if any(fresh[k].seq > fresh[k + 1].seq for k in range(len(fresh) - 1)):
            fresh.sort(key=lambda f: f.seq)
        monitor.last_seq = fresh[-1].seq
        self.frames_evaluated += len(fresh)
        assert monitor.evaluator is not None and monitor.book is not None
        try:
            readings = monitor.evaluator.evaluate(fresh)
        except ValueError as exc:  # frames of another robot than the pass's plan's
            log.warning(
                "pass %s: frames no longer checked against limits: %s", monitor.pass_id, exc
            )
            monitor.disabled = True
            return
        if not readings:
            return
        changes = monitor.book.observe([observation(r) for r in readings], self._clock.time_ns())
        self._writer.apply(changes, self._clock.monotonic())

    # -- the link's health -----------------------------------------------------------------

    def _watch_link(self) -> None:
        if self._link_task is None or self._link_task.done():
            self._link_task = asyncio.get_running_loop().create_task(
                self._link_loop(), name="alarms-link-health"
            )

    def _watched(self) -> PassMonitor | None:
        watched = [m for m in self._monitors.values() if m.watched and m.book is not None]
        return watched[-1] if watched else None

    async def _link_loop(self) -> None:
        clock = self._clock
        while not self._closed:
            monitor = self._watched()
            if monitor is None:
                if not any(m.watched for m in self._monitors.values()):
                    return  # a pass still loading starts the loop again once loaded
            else:
                self.check_link(monitor.pass_id)
            await clock.sleep_until(clock.monotonic() + LINK_PERIOD_S)

    def check_link(self, pass_id: str) -> None:
        """One check of the link's health for the pass ``pass_id`` (running)."""
        monitor = self._monitors.get(pass_id)
        if monitor is None or monitor.book is None or monitor.limits is None:
            return
        now_ns = self._clock.time_ns()
        try:
            onboard: int | None = self._link.onboard_now_ns()
        except LinkUnavailable:
            onboard = None
        behind = self._downlink.frames_behind(onboard)
        try:  # onboard seconds: a demo at 20x ages its frames as a real pass would
            scale = self._link.time_scale
        except LinkUnavailable:
            scale = 1.0
        age_s = (
            None
            if monitor.last_frame_ns is None
            else (now_ns - monitor.last_frame_ns) / 1e9 * scale
        )
        values: dict[str, float | None] = {
            "frames_behind": None if behind is None else float(behind),
            "frame_age_s": age_s,
        }
        readings = link_readings(monitor.limits, frames_behind=behind, frame_age_s=age_s)
        found = {(r.quantity, r.channel) for r in readings}
        # a sample of the ground's, not of a frame: no seq, no onboard time
        observations = [
            observation(r)._replace(frame_seq=None, generation_time_ns=None) for r in readings
        ]
        for quantity, value in values.items():
            if (quantity, "") not in found:
                observations.append(Observation(quantity, "", value, None, None, None))
        changes = monitor.book.observe(observations, now_ns)
        self._writer.apply(changes, self._clock.monotonic())

    # -- the vehicle's safing --------------------------------------------------------------

    def _vehicle_book(self, pass_id: str | None) -> AlarmBook:
        book = self._vehicle.get(pass_id)
        if book is None:
            book = self._vehicle[pass_id] = AlarmBook(
                pass_id, lambda quantity: None, source="vehicle"
            )
        return book

    def vehicle_safed(self, pass_id: str | None, report: Safing) -> None:
        """The vehicle reports it is safe (``report.state`` ``safe``), during pass
        ``pass_id`` (None: no pass ran): the ``critical`` alarm of source ``vehicle``,
        quantity ``vehicle_safing``, raised (a report repeated while it stays safe updates
        it; after an exit it is raised again, or reopened while still listed)."""
        pass_id = canonical_pass(pass_id)
        trigger = report.trigger
        spec = None if trigger is None else QUANTITIES.get(trigger.quantity)
        if trigger is None:
            text = "the vehicle safed itself (no trigger reported)"
            value = limit = None
        else:
            where = f"{trigger.quantity} {trigger.channel}".strip()
            unit = "" if spec is None else f" {spec.unit}"
            text = (
                f"the vehicle safed itself: {where} at {trigger.value:.4g}{unit} beyond its "
                f"red limit {trigger.limit:.4g}{unit}"
            )
            if trigger.detail:
                text += f" ({trigger.detail})"
            value, limit = trigger.value, trigger.limit
        label = "vehicle safing" + ("" if spec is None else f": {spec.label}")
        info = QuantityInfo(
            label[:128],
            "" if spec is None else spec.unit[:16],
            "high" if spec is None else spec.direction,
            lambda _severity: limit,
        )
        observation = Observation(
            VEHICLE_SAFING, "", value, Severity.CRITICAL, None, report.since_time_ns
        )
        now_ns = self._clock.time_ns()
        changes = self._vehicle_book(pass_id).observe([observation], now_ns, text, info)
        self._writer.apply(changes, self._clock.monotonic())

    def vehicle_nominal(self, pass_id: str | None, report: Safing) -> None:
        """The vehicle left SAFE (``report.state`` ``nominal``): its safing alarm of that
        pass clears (it stays listed until acknowledged)."""
        book = self._vehicle.get(canonical_pass(pass_id))
        if book is None:
            return
        observation = Observation(VEHICLE_SAFING, "", None, None, None, report.onboard_time_ns)
        changes = book.observe([observation], self._clock.time_ns())
        self._writer.apply(changes, self._clock.monotonic())

    # -- writes --------------------------------------------------------------------------

    def _books(self) -> list[AlarmBook]:
        """Every book held (the passes' and the vehicle's): what the writer flushes."""
        books = [m.book for m in self._monitors.values() if m.book is not None]
        return books + list(self._vehicle.values())

    # -- acknowledgement -------------------------------------------------------------------

    async def acknowledge(self, alarm_id: str, actor: str, comment: str | None) -> AlarmPublic:
        """An operator acknowledges the alarm (with ``comment``); the alarm as it now is.
        ``NotFoundError`` ``alarm_not_found``; ``ConflictError`` ``already_acknowledged``."""
        clock = self._clock
        now_ns = clock.time_ns()
        # what the monitor knows beyond the stored row (an in-band update not yet written)
        key = canonical_pass(alarm_id) or ""
        held = next((a for b in self._books() if (a := b.holds(key)) is not None), None)
        known = None if held is None else held.model_copy(update={"timeline": list(held.timeline)})

        def job(session: Session) -> AlarmPublic:
            try:
                stored = alarm_repo.acknowledge(
                    session=session, alarm_id=alarm_id, actor=actor, time_ns=now_ns,
                    comment=comment,
                )  # fmt: skip
            except NotFound as exc:
                raise NotFoundError("alarm_not_found", str(exc)) from None
            except Conflict as exc:
                raise ConflictError("already_acknowledged", str(exc)) from None
            event = AlarmAcknowledged(
                actor=actor,
                pass_id=stored.pass_id,
                alarm_id=stored.id,
                quantity=stored.quantity,
                channel=stored.channel,
                severity=stored.severity,
                state=stored.state,
                comment=comment,
            )
            record(session, event, clock.time_ns())
            alarm = alarm_repo.stored_alarm(stored)
            if known is not None and known.id == alarm.id:
                updated_ns = max(known.updated_time_ns, now_ns)
                alarm = known.model_copy(
                    update={**_ack_fields(alarm), "updated_time_ns": updated_ns}
                )
            on_commit(session, alarm)  # after its event, once committed
            return alarm

        alarm = await self._db.run(job, control=True)
        for book in self._books():
            if book.holds(alarm.id) is not None:
                book.acknowledged(alarm.id, actor, now_ns, comment)
        return alarm


def _ack_fields(alarm: AlarmPublic) -> dict[str, Any]:
    keys = ("acknowledged", "acknowledged_by", "acknowledged_time_ns", "comment")
    return {k: getattr(alarm, k) for k in keys}


def list_alarms(
    *,
    session: Session,
    pass_id: str | None = None,
    active: bool | None = None,
    offset: int = 0,
    limit: int = 100,
) -> AlarmsPublic:
    """Alarms newest first (of ``pass_id``; active or not), as the REST serves them; an
    unknown pass is ``NotFound``."""
    if pass_id is not None:
        pass_id = repo.get_pass(session=session, pass_id=pass_id).id
    page = alarm_repo.list_alarms(
        session=session, pass_id=pass_id, active=active, offset=offset, limit=limit
    )
    alarms = [alarm_repo.stored_alarm(r) for r in page.items]
    return AlarmsPublic(alarms=alarms, count=page.count)
