"""What the archive holds that an alert must see: passes by state and the alarms no operator
has acknowledged, by severity (``/metrics``: server/services/metrics.py).

One grouped count of each, on a read session; ``GET /metrics`` takes them in a thread, at
most every :data:`REFRESH_S`, so a scrape never waits on the database on the event loop and
a burst of scrapes costs one query.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import get_args

from sqlalchemy import false, func, select
from sqlalchemy.orm import Session

from planner.limits import SEVERITIES
from server.schemas import PassState
from server.storage.models import AlarmRecord, PassRecord

__all__ = ["REFRESH_S", "RecordCounter", "RecordCounts", "count_records"]

#: Wall s: counts this fresh are served again instead of asking the database.
REFRESH_S = 5.0


@dataclass(frozen=True)
class RecordCounts:
    """Passes by state, every state present (0 when none); alarms not acknowledged, by the
    severity they reached, every severity present."""

    passes: dict[str, int] = field(default_factory=dict)
    unacknowledged_alarms: dict[str, int] = field(default_factory=dict)


def count_records(session: Session) -> RecordCounts:
    passes = dict.fromkeys(get_args(PassState), 0)
    for state, n in session.execute(
        select(PassRecord.state, func.count()).group_by(PassRecord.state)
    ):
        passes[state] = int(n)
    alarms = dict.fromkeys((s.value for s in SEVERITIES), 0)
    for severity, n in session.execute(
        select(AlarmRecord.severity, func.count())
        .where(AlarmRecord.acknowledged == false())
        .group_by(AlarmRecord.severity)
    ):
        alarms[severity] = int(n)
    return RecordCounts(passes=passes, unacknowledged_alarms=alarms)


class RecordCounter:
    """The latest :class:`RecordCounts` of ``sessions``, asked again when older than
    :data:`REFRESH_S` (``clock``: monotonic s, injectable). Thread-safe: one query at a time."""

    def __init__(
        self, sessions: Callable[[], Session], clock: Callable[[], float] = time.monotonic
    ) -> None:
        self._sessions = sessions
        self._clock = clock
        self._lock = threading.Lock()
        self._at: float | None = None
        self.latest: RecordCounts | None = None

    def refresh(self) -> RecordCounts:
        """The counts, asked of the database when the last are stale (call in a thread)."""
        with self._lock:
            now = self._clock()
            if self.latest is None or self._at is None or now - self._at >= REFRESH_S:
                with self._sessions() as session:
                    self.latest = count_records(session)
                self._at = now
            return self.latest
