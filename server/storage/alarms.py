"""Repository functions of the ``alarms`` table (docs/alarms.md); like every repository
function they take keyword arguments only, the ``session`` first, and never commit.

    save_alarms    insert or update alarms from their documents (the monitor's batched writes)
    get_alarm      one alarm
    list_alarms    newest first, by pass and by active
    listed_alarms  a pass's alarms still listed (active): the monitor's state after a restart
    acknowledge    an operator's acknowledgement (with an optional comment)

An alarm's document is its JSON (the console's and the REST's) but for ``limit``, stored as
``limit_value``. "Active" is latching: triggered, or cleared and not yet acknowledged.

Two writers, one owner each: the alarm monitor writes what the telemetry says (severities,
values, timeline) with :func:`save_alarms`, the operator's acknowledgement is written by
:func:`acknowledge` alone. :func:`save_alarms` never changes the acknowledgement of a stored
alarm, so a monitor's write queued before an acknowledgement cannot undo it.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Any

from sqlalchemy import ColumnElement, false, or_, select
from sqlalchemy.orm import Session

from server.storage._common import Page, canonical_id, check_page, paged, stored
from server.storage.errors import Conflict, InvalidArgument
from server.storage.models import (
    ALARM_DIRECTIONS,
    ALARM_SEVERITIES,
    ALARM_SOURCES,
    ALARM_STATES,
    AlarmRecord,
)
from telemetry.alarm import ALARM_FIELDS, AlarmPublic

__all__ = [
    "ALARM_FIELDS",
    "acknowledge",
    "alarm_document",
    "get_alarm",
    "list_alarms",
    "listed_alarms",
    "save_alarms",
    "stored_alarm",
]

_COLUMN = {"limit": "limit_value"}
#: Written by :func:`acknowledge` only (and by :func:`save_alarms` when it inserts).
_ACK_FIELDS = ("acknowledged", "acknowledged_by", "acknowledged_time_ns", "comment")
_FLOATS = ("limit", "trigger_value", "worst_value", "last_value")


def alarm_document(record: AlarmRecord) -> dict[str, Any]:
    """The alarm's JSON document (see the module docstring)."""
    return {name: getattr(record, _COLUMN.get(name, name)) for name in ALARM_FIELDS}


def stored_alarm(record: AlarmRecord) -> AlarmPublic:
    """The stored alarm as its one model (:class:`telemetry.alarm.AlarmPublic`)."""
    return AlarmPublic.model_validate(alarm_document(record))


def _active() -> ColumnElement[bool]:
    return or_(AlarmRecord.state == "triggered", AlarmRecord.acknowledged == false())


def _check(doc: Mapping[str, Any]) -> None:
    checks = (
        ("severity", ALARM_SEVERITIES),
        ("source", ALARM_SOURCES),
        ("state", ALARM_STATES),
        ("direction", ALARM_DIRECTIONS),
    )
    for name, allowed in checks:
        if doc[name] not in allowed:
            raise InvalidArgument(f"alarm {name} {doc[name]!r} is not one of {allowed}")
    current = doc["current_severity"]
    if current is not None and current not in ALARM_SEVERITIES:
        raise InvalidArgument(f"alarm current_severity {current!r} is not one of a severity")
    for name in _FLOATS:
        value = doc[name]
        if value is not None and not math.isfinite(value):
            raise InvalidArgument(f"alarm {name} {value!r} is not a finite number")


def save_alarms(*, session: Session, documents: Iterable[Mapping[str, Any]]) -> int:
    """Store each alarm document: a new row for an id not stored, else the row updated to
    the document (every field but the acknowledgement's, which :func:`acknowledge` owns;
    ``updated_time_ns`` never moves back). Every field of :data:`ALARM_FIELDS` must be
    given; the number saved."""
    n = 0
    for doc in documents:
        missing = [name for name in ALARM_FIELDS if name not in doc]
        if missing:
            raise InvalidArgument(f"alarm document lacks {missing}")
        _check(doc)
        key = canonical_id(str(doc["id"]), what="alarm")
        record = session.get(AlarmRecord, key)
        names: tuple[str, ...] = ALARM_FIELDS[1:]
        if record is None:
            record = AlarmRecord(id=key)
            session.add(record)
        else:
            names = tuple(n for n in names if n not in _ACK_FIELDS)
        for name in names:
            value = doc[name]
            if name == "timeline":
                value = [dict(entry) for entry in value]
            elif name == "updated_time_ns" and record.updated_time_ns is not None:
                value = max(value, record.updated_time_ns)
            setattr(record, _COLUMN.get(name, name), value)
        n += 1
    session.flush()
    return n


def get_alarm(*, session: Session, alarm_id: str) -> AlarmRecord:
    return stored(session, AlarmRecord, alarm_id, what="alarm")


def list_alarms(
    *,
    session: Session,
    pass_id: str | None = None,
    active: bool | None = None,
    offset: int = 0,
    limit: int = 100,
) -> Page[AlarmRecord]:
    """Alarms, newest raised first: of one pass if ``pass_id``; only the active ones
    (triggered or not acknowledged) if ``active`` is True, only the others if False."""
    check_page(offset, limit)
    where: list[ColumnElement[bool]] = []
    if pass_id is not None:
        where.append(AlarmRecord.pass_id == canonical_id(pass_id, what="pass"))
    if active is not None:
        where.append(_active() if active else ~_active())
    order = (AlarmRecord.raised_time_ns.desc(), AlarmRecord.id)
    return paged(session, AlarmRecord, where, order, offset, limit)


def listed_alarms(*, session: Session, pass_id: str | None) -> list[AlarmRecord]:
    """The pass's active alarms (``pass_id`` None: those of no pass), oldest first."""
    owner = (
        AlarmRecord.pass_id.is_(None)
        if pass_id is None
        else AlarmRecord.pass_id == canonical_id(pass_id, what="pass")
    )
    query = select(AlarmRecord).where(owner, _active()).order_by(AlarmRecord.raised_time_ns)
    return list(session.scalars(query))


def acknowledge(
    *, session: Session, alarm_id: str, actor: str, time_ns: int, comment: str | None = None
) -> AlarmRecord:
    """Acknowledge the alarm (``actor`` at ``time_ns``, ground, with ``comment``);
    :class:`NotFound` for an unknown alarm, :class:`Conflict` for one already
    acknowledged."""
    record = stored(session, AlarmRecord, alarm_id, what="alarm", with_for_update=True)
    if record.acknowledged:
        raise Conflict(f"alarm {record.id} was already acknowledged by {record.acknowledged_by!r}")
    record.acknowledged = True
    record.acknowledged_by = actor
    record.acknowledged_time_ns = time_ns
    record.comment = comment
    record.updated_time_ns = max(time_ns, record.updated_time_ns)
    session.flush()
    return record
