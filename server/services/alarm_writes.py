"""Writing the ground's alarms (docs/alarms.md): through the command path's database worker,
each published (to the consoles' topic ``alarms``) once its write has committed, after the
audit events of the same transaction (:func:`~server.services.event_log.on_commit`).

A raise, a change of band and a clear are written at once (one job per batch, with their
audit events); an in-band update at most once per :data:`IN_BAND_PERIOD_S` per alarm, by a
flusher that waits for the first one due. A write that fails leaves its alarms dirty, to be
written with the next flush. :class:`~server.services.alarms.AlarmService` owns one
:class:`AlarmWriter`.
"""

from __future__ import annotations

import asyncio
import logging
import math
from typing import Any

from sqlalchemy.orm import Session

from server.services.alarm_book import Change
from server.services.clock import Clock
from server.services.dbworker import Database
from server.services.events import AlarmCleared, AlarmRaised, Event, on_commit, record
from server.storage import alarms as alarm_repo
from telemetry.alarm import AlarmPublic

__all__ = ["IN_BAND_PERIOD_S", "AlarmWriter"]

log = logging.getLogger("hikoboshi.ground.alarms")

#: An alarm staying in its band is written (and published) at most this often (ground s).
IN_BAND_PERIOD_S = 1.0


class AlarmWriter:
    """Writes the alarms the books changed and publishes them (see the module docstring)."""

    def __init__(self, *, db: Database, clock: Clock) -> None:
        self._db = db
        self._clock = clock
        #: ground monotonic s of each alarm's last write (in-band updates wait a second)
        self._written_mono: dict[str, float] = {}
        #: the alarms changed since they were last written, by id
        self._dirty: dict[str, AlarmPublic] = {}
        #: the writes not yet committed (or failed)
        self.pending: set[asyncio.Future[Any]] = set()
        self.flusher: asyncio.Task[None] | None = None
        #: set on closing: the flusher stops
        self.closed = False

    def _last_written(self, alarm: AlarmPublic) -> float:
        return self._written_mono.get(alarm.id, -math.inf)

    def apply(self, changes: list[Change], mono: float) -> None:
        """Write the prompt changes now, the in-band updates once their second is up."""
        due: list[AlarmPublic] = []
        events: list[Event] = []
        for change in changes:
            alarm = change.alarm
            self._dirty[alarm.id] = alarm
            if change.kind == "updated" and mono - self._last_written(alarm) < IN_BAND_PERIOD_S:
                continue
            due.append(alarm)
            event = _event(change)
            if event is not None:
                events.append(event)
        if due:
            self._write(due, events, mono)
        if self._dirty:
            self._flush_soon()

    def _write(self, alarms: list[AlarmPublic], events: list[Event], mono: float) -> None:
        # as they are now (the books go on changing them; a timeline's entries never change)
        docs = [a.model_copy(update={"timeline": list(a.timeline)}) for a in alarms]
        for alarm in alarms:
            self._written_mono[alarm.id] = mono
            self._dirty.pop(alarm.id, None)
        clock = self._clock

        def job(session: Session) -> None:
            alarm_repo.save_alarms(
                session=session, documents=[d.model_dump(mode="json") for d in docs]
            )
            for e in events:
                record(session, e, clock.time_ns())
            on_commit(session, *docs)  # the alarms after their events, once committed

        future = asyncio.ensure_future(self._db.run(job))
        self.pending.add(future)

        def done(f: asyncio.Future[None]) -> None:
            self.pending.discard(future)
            if not f.cancelled() and (exc := f.exception()) is not None:
                log.error("alarms not written: %r", exc)
                for alarm in alarms:  # written again with the next flush
                    self._dirty.setdefault(alarm.id, alarm)

        future.add_done_callback(done)

    def _flush_soon(self) -> None:
        if self.flusher is None or self.flusher.done():
            self.flusher = asyncio.get_running_loop().create_task(
                self._flush_loop(), name="alarms-flush"
            )

    async def _flush_loop(self) -> None:
        clock = self._clock
        while not self.closed and self._dirty:
            due_at = min(self._last_written(a) for a in self._dirty.values()) + IN_BAND_PERIOD_S
            await clock.sleep_until(due_at)
            self.flush()

    def flush(self, *, force: bool = False) -> None:
        """Write the alarms changed since their last write whose second is up."""
        mono = self._clock.monotonic()
        due = [
            a
            for a in self._dirty.values()
            if force or mono - self._last_written(a) >= IN_BAND_PERIOD_S
        ]
        if due:
            self._write(due, [], mono)


def _event(change: Change) -> Event | None:
    """The audit event of a change (none for a change of band or an in-band update)."""
    a = change.alarm
    # the alarm, as both its events name it
    alarm: dict[str, Any] = {
        "actor": "vehicle" if a.source == "vehicle" else "ground",
        "pass_id": a.pass_id,
        "alarm_id": a.id,
        "quantity": a.quantity,
        "channel": a.channel,
    }
    last = a.timeline[-1] if a.timeline else None
    if change.kind in ("raised", "reopened"):
        return AlarmRaised(
            **alarm,
            source=a.source,
            severity=a.current_severity or a.severity,
            value=None if last is None else last.value,
            limit=a.limit,
            frame_seq=None if last is None else last.frame_seq,
            generation_time_ns=None if last is None else last.generation_time_ns,
            reopened=change.kind == "reopened",
            detail_text=a.detail,
        )
    if change.kind == "cleared":
        return AlarmCleared(
            **alarm,
            severity=a.severity,
            value=a.last_value,
            generation_time_ns=a.cleared_generation_time_ns,
        )
    return None
