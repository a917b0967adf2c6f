"""The archive as the tests count it."""

from __future__ import annotations

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from server.storage.models import (
    CommandRecord,
    EventRecord,
    PassRecord,
    PlanRecord,
    TelemetryFrameRecord,
)

#: The tables a pass's import writes.
TABLES = (PlanRecord, PassRecord, CommandRecord, TelemetryFrameRecord, EventRecord)


def row_counts(session: Session) -> dict[str, int]:
    """Each table's rows (a write that failed must leave them as they were)."""
    return {
        t.__tablename__: session.scalar(select(func.count()).select_from(t)) or 0 for t in TABLES
    }
