"""Writing the ground's alarms (docs/alarms.md): through the command path's database worker,
each published to the consoles (topic ``alarms``) once its write has committed.

A raise, a change of band and a clear are written at once (one job per batch, with their
audit events); an in-band update at most once per :data:`IN_BAND_PERIOD_S` per alarm, by a
flusher that waits for the first one due. A write that fails leaves its alarms dirty, to be
written with the next flush. :class:`~server.services.alarms.AlarmService` owns one
:class:`AlarmWriter`.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from typing import Any

from sqlalchemy.orm import Session

from server.services.alarm_book import Alarm, AlarmBook, Change
from server.services.clock import Clock
from server.services.dbworker import Database, Publisher
from server.services.events import AlarmCleared, AlarmRaised, Event, record
from server.storage import alarms as alarm_repo

__all__ = ["IN_BAND_PERIOD_S", "AlarmWriter"]

log = logging.getLogger("hikoboshi.ground.alarms")

#: An alarm staying in its band is written (and published) at most this often (ground s).
IN_BAND_PERIOD_S = 1.0


class AlarmWriter:
    """Writes the alarms of ``books`` (every book the service holds, asked at each flush)
    and publishes them (see the module docstring)."""

    def __init__(
        self,
        *,
        db: Database,
        publisher: Publisher,
        clock: Clock,
        books: Callable[[], list[AlarmBook]],
    ) -> None:
        self._db = db
        self._publisher = publisher
        self._clock = clock
        self._books = books
        #: the writes not yet committed (or failed)
        self.pending: set[asyncio.Future[Any]] = set()
        self.flusher: asyncio.Task[None] | None = None
        #: set on closing: the flusher stops
        self.closed = False

    def apply(self, changes: list[Change], mono: float) -> None:
        """Write the prompt changes now, the in-band updates once their second is up."""
        due: list[Alarm] = []
        events: list[Event] = []
        waiting = False
        for change in changes:
            alarm = change.alarm
            if change.kind == "updated" and mono - alarm.written_mono < IN_BAND_PERIOD_S:
                waiting = True
                continue
            due.append(alarm)
            event = _event(change)
            if event is not None:
                events.append(event)
        if due:
            self._write(due, events, mono)
        if waiting:
            self._flush_soon()

    def _write(self, alarms: list[Alarm], events: list[Event], mono: float) -> None:
        docs = [a.document() for a in alarms]
        for alarm in alarms:
            alarm.written_mono, alarm.dirty = mono, False
        clock = self._clock

        def job(session: Session) -> list[dict[str, Any]]:
            alarm_repo.save_alarms(session=session, documents=docs)
            return [record(session, e, clock.time_ns()) for e in events]

        future = asyncio.ensure_future(self._db.run(job))
        self.pending.add(future)

        def done(f: asyncio.Future[list[dict[str, Any]]]) -> None:
            self.pending.discard(future)
            if f.cancelled():
                return
            if (exc := f.exception()) is not None:
                log.error("alarms not written: %r", exc)
                for alarm in alarms:
                    alarm.dirty = True  # written again with the next flush
                return
            self._publisher.publish(f.result())
            self._publisher.publish_alarms(docs)

        future.add_done_callback(done)

    def _flush_soon(self) -> None:
        if self.flusher is None or self.flusher.done():
            self.flusher = asyncio.get_running_loop().create_task(
                self._flush_loop(), name="alarms-flush"
            )

    async def _flush_loop(self) -> None:
        clock = self._clock
        while not self.closed:
            dirty = [a for b in self._books() for a in b.listed.values() if a.dirty]
            if not dirty:
                return
            due_at = min(a.written_mono for a in dirty) + IN_BAND_PERIOD_S
            await clock.sleep_until(due_at)
            self.flush()

    def flush(self, *, force: bool = False) -> None:
        """Write the alarms changed since their last write whose second is up."""
        mono = self._clock.monotonic()
        due = [
            a
            for b in self._books()
            for a in b.listed.values()
            if a.dirty and (force or mono - a.written_mono >= IN_BAND_PERIOD_S)
        ]
        if due:
            self._write(due, [], mono)


def _event(change: Change) -> Event | None:
    """The audit event of a change (none for a change of band or an in-band update)."""
    a = change.alarm
    actor = "vehicle" if a.source == "vehicle" else "ground"
    last = a.timeline[-1] if a.timeline else {}
    if change.kind in ("raised", "reopened"):
        return AlarmRaised(
            actor=actor,
            pass_id=a.pass_id,
            alarm_id=a.id,
            source=a.source,
            quantity=a.quantity,
            channel=a.channel,
            severity=a.current_severity or a.severity,
            value=last.get("value"),
            limit=a.limit,
            frame_seq=last.get("frame_seq"),
            generation_time_ns=last.get("generation_time_ns"),
            reopened=change.kind == "reopened",
            detail_text=a.detail,
        )
    if change.kind == "cleared":
        return AlarmCleared(
            actor=actor,
            pass_id=a.pass_id,
            alarm_id=a.id,
            quantity=a.quantity,
            channel=a.channel,
            severity=a.severity,
            value=a.last_value,
            generation_time_ns=a.cleared_generation_time_ns,
        )
    return None
