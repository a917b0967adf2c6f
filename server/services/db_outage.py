"""A database outage as the command path's database worker sees it
(:class:`server.services.dbworker.Database`): when it began, the journal of writes waiting
for the database, and what the last one cost (docs/operations.md "A database outage")."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

__all__ = ["RETRY_FIRST_S", "RETRY_MAX_S", "JournalFull", "Outage"]


#: Wall s between tries while the database does not answer: from this, doubling ...
RETRY_FIRST_S = 0.1
#: ... up to this.
RETRY_MAX_S = 2.0


class JournalFull(RuntimeError):
    """A write refused because the database has been away long enough for ``journal_max``
    writes to wait for it."""


@dataclass
class Outage:
    """The database worker's view of the database's availability (for /metrics, the
    consoles' link status and the log). Monotonic wall s."""

    #: when the current outage began (None: the database answers)
    down_since: float | None = None
    #: tries since it began
    tried: int = 0
    outages: int = 0
    #: jobs waiting at its start, at its peak, and when the database came back
    journal_at_start: int = 0
    journal_peak: int = 0
    journal_at_return: int = 0
    #: the last outage's length, and how long its journal's replay took
    last_down_s: float | None = None
    last_replay_s: float | None = None
    #: writes refused because the journal was full (JournalFull)
    refused: int = 0
    replay_since: float | None = None
    jobs_at_return: int = 0

    def begin(self, now: float, waiting: int) -> None:
        self.down_since, self.tried = now, 0
        self.outages += 1
        self.journal_at_start = self.journal_peak = waiting

    def end(self, now: float, waiting: int, jobs: int) -> float:
        assert self.down_since is not None
        waited = now - self.down_since
        self.down_since, self.last_down_s = None, waited
        self.journal_at_return = waiting
        self.journal_peak = max(self.journal_peak, waiting)
        self.replay_since, self.jobs_at_return = now, jobs
        return waited

    def replayed(self, now: float, jobs: int) -> int:
        assert self.replay_since is not None
        self.last_replay_s = now - self.replay_since
        self.replay_since = None
        return jobs - self.jobs_at_return

    def status(self, waiting: int) -> dict[str, Any]:
        """What /metrics and the consoles show (``waiting``: the worker's journal now)."""
        if self.down_since is not None:
            self.journal_peak = max(self.journal_peak, waiting)
        return {
            "reachable": self.down_since is None,
            "down_s": None if self.down_since is None else time.monotonic() - self.down_since,
            "journal": waiting,
            "journal_peak": self.journal_peak,
            "outages": self.outages,
            "last_down_s": self.last_down_s,
            "last_replay_s": self.last_replay_s,
            "refused": self.refused,
        }
