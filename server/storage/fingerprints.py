"""Cheap summaries of what a pass's stored rows hold, for telling whether something computed
from them (a recording, a report) is still what they would give: each summary changes
whenever the rows it covers do.

Why these few aggregates are enough, table by table (the writers are in this package and
:mod:`server.services`; the argument must be checked again when one of them changes):

- ``passes``: every update of a row bumps its ``version`` (the optimistic lock, done by the
  ORM; no statement updates the table around it), so the row's id and version fix it.
- ``plans``, ``telemetry_frames``, ``events``, ``analysis_results``: rows are only ever
  inserted (frames ``ON CONFLICT DO NOTHING``), never updated or deleted, so the rows of a
  pass are fixed by their count; the largest key is added for good measure.
- ``commands``: inserted once per pass, then only their ``stage`` (with its ``*_at_ns``
  time and ``reject_reason``) and ``transmissions`` change. A stage moves only to a higher
  rank, or once from the ground's inference to the vehicle's final word
  (:mod:`server.storage.stages`), so each move fills a stage time that was NULL: the count
  of each stage time column grows at every move. The count per stage, the largest time of
  each column and the reasons' count are added.
- ``alarms``: few per pass, and updated in place (counts, values, acknowledgement): their
  documents are hashed whole.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any

from sqlalchemy import case, func, select
from sqlalchemy.orm import Session

from server.storage._common import stored
from server.storage.alarms import alarm_document
from server.storage.models import (
    COMMAND_STAGES,
    AlarmRecord,
    AnalysisRecord,
    CommandRecord,
    EventRecord,
    PassRecord,
    TelemetryFrameRecord,
)

__all__ = [
    "alarms_digest",
    "analyses_summary",
    "commands_summary",
    "events_summary",
    "frames_summary",
    "pass_row",
]


def pass_row(session: Session, pass_id: str) -> PassRecord:
    """The pass, read afresh (its ``version`` names its content); ``NotFound`` if none."""
    return stored(session, PassRecord, pass_id, what="pass", populate_existing=True)


def _row(session: Session, *columns: Any, where: Any) -> list[int | None]:
    row = session.execute(select(*columns).where(where)).one()
    return [None if value is None else int(value) for value in row]


def frames_summary(session: Session, pass_id: str) -> list[int | None]:
    """The count and largest seq of the pass's stored frames."""
    t = TelemetryFrameRecord
    return _row(session, func.count(), func.max(t.seq), where=t.pass_id == pass_id)


def events_summary(session: Session, pass_id: str, kind: str | None = None) -> list[int | None]:
    """The count and largest id of the pass's events (of ``kind`` only, if given)."""
    e = EventRecord
    where = e.pass_id == pass_id if kind is None else (e.pass_id == pass_id) & (e.kind == kind)
    return _row(session, func.count(), func.max(e.id), where=where)


def analyses_summary(session: Session, pass_id: str, kind: str | None = None) -> list[int | None]:
    """The count and largest id of the pass's stored analyses (of ``kind`` only, if given)."""
    a = AnalysisRecord
    where = a.pass_id == pass_id if kind is None else (a.pass_id == pass_id) & (a.kind == kind)
    return _row(session, func.count(), func.max(a.id), where=where)


def commands_summary(session: Session, pass_id: str) -> list[int | None]:
    """The commands' count; per stage time column its count and largest value; the count
    per stage; the count of reject reasons."""
    c = CommandRecord
    times = [getattr(c, f"{stage}_at_ns") for stage in COMMAND_STAGES]
    return _row(
        session,
        func.count(),
        *(func.count(column) for column in times),
        *(func.max(column) for column in times),
        *(func.sum(case((c.stage == stage, 1), else_=0)) for stage in COMMAND_STAGES),
        func.count(c.reject_reason),
        where=c.pass_id == pass_id,
    )


def alarms_digest(session: Session, pass_id: str) -> str:
    """A SHA-256 of the pass's alarm documents, in id order."""
    rows = session.scalars(
        select(AlarmRecord).where(AlarmRecord.pass_id == pass_id).order_by(AlarmRecord.id)
    )
    documents = [alarm_document(row) for row in rows]
    text = json.dumps(documents, sort_keys=True, default=str, allow_nan=True)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()
