"""Passes: store a scheduled one, list and read them, list their commands.

Scheduling (a window given by hand or named, the plan fitted to it) is an operator's rule:
:mod:`server.operations.scheduling`; the row and its ``pass_scheduled`` event are stored
here (:func:`add_scheduled`).
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime
from typing import Any

from sqlalchemy.orm import Session

from server.schemas import (
    CommandPublic,
    CommandsPublic,
    iso_from_ns,
)
from server.schemas.passes import (
    PassControlPublic,
    PassesPublic,
    PassPublic,
    PassWindowPublic,
)
from server.services.errors import InvalidRequestError
from server.services.events import PassControlRefused, PassScheduled, Recorded
from server.services.events import record as record_event
from server.storage import repository as repo
from server.storage.models import CommandRecord, PassRecord

__all__ = [
    "add_scheduled",
    "check_confirmation",
    "control_state",
    "get_pass",
    "list_commands",
    "list_passes",
    "public",
]


def _window(record: PassRecord) -> PassWindowPublic | None:
    doc = record.window_detail
    if record.window_mission is None or doc is None:
        return None
    return PassWindowPublic(
        mission=record.window_mission,
        mission_sha256=doc["mission_sha256"],
        relay=doc["relay"],
        aos_time=iso_from_ns(doc["aos_time_ns"]),
        los_time=iso_from_ns(doc["los_time_ns"]),
        aos_margin_s=doc["aos_margin_s"],
        los_margin_s=doc["los_margin_s"],
        net_s=doc["net_s"],
        min_range_km=doc["min_range_km"],
        max_range_km=doc["max_range_km"],
        light_time_min_s=doc["light_time_min_s"],
        light_time_max_s=doc["light_time_max_s"],
        processing_delay_s=doc["processing_delay_s"],
    )


def public(record: PassRecord) -> PassPublic:
    return PassPublic(
        id=record.id,
        name=record.name,
        plan_id=record.plan_id,
        aos_time=iso_from_ns(record.aos_time_ns),
        los_time=iso_from_ns(record.los_time_ns),
        relay=record.relay,
        state=record.state,
        state_reason=record.state_reason,
        epoch_ns=record.epoch_ns,
        created_at=iso_from_ns(record.created_at_ns),
        updated_at=iso_from_ns(record.updated_at_ns),
        version=record.version,
        window=_window(record),
    )


def add_scheduled(session: Session, actor: str, now_ns: int, **fields: Any) -> PassRecord:
    """The pass row of ``fields`` and its ``pass_scheduled`` event, committed together."""
    record = repo.add_pass(session=session, created_at_ns=now_ns, **fields)
    scheduled = PassScheduled(
        actor=actor,
        pass_id=record.id,
        plan_id=record.plan_id,
        name=record.name,
        aos_time_ns=record.aos_time_ns,
        los_time_ns=record.los_time_ns,
        relay=record.relay,
    )
    record_event(session, scheduled, now_ns)
    session.commit()
    return record


def get_pass(*, session: Session, pass_id: str) -> PassPublic:
    return public(repo.get_pass(session=session, pass_id=pass_id))


def list_passes(
    *, session: Session, states: Sequence[str] | None, offset: int, limit: int
) -> PassesPublic:
    page = repo.list_passes(session=session, states=states, offset=offset, limit=limit)
    return PassesPublic(data=[public(r) for r in page.items], count=page.count)


def _iso(time_ns: int | None) -> datetime | None:
    return None if time_ns is None else iso_from_ns(time_ns)


def _command(record: CommandRecord) -> CommandPublic:
    return CommandPublic(
        seq=record.seq,
        kind=record.kind,
        execute_time_ns=record.execute_time_ns,
        payload=record.payload,
        stage=record.stage,
        reject_reason=record.reject_reason,
        queued_at=iso_from_ns(record.queued_at_ns),
        released_at=_iso(record.released_at_ns),
        sent_at=_iso(record.sent_at_ns),
        expired_at=_iso(record.expired_at_ns),
        cancelled_at=_iso(record.cancelled_at_ns),
        transmissions=record.transmissions,
        received_at_ns=record.received_at_ns,
        executed_at_ns=record.executed_at_ns,
        rejected_at_ns=record.rejected_at_ns,
    )


def list_commands(
    *,
    session: Session,
    pass_id: str,
    stages: Sequence[str] | None,
    offset: int,
    limit: int,
    kinds: Sequence[str] | None = None,
    t0_ns: int | None = None,
    t1_ns: int | None = None,
) -> CommandsPublic:
    """The pass's commands by time tag, one page of them, and how many match: only those
    at ``stages``, of ``kinds`` and with a time tag in ``[t0_ns, t1_ns)``, where given.

    The repository lists a pass's commands without an offset or a count, so the page is
    cut here; a pass holds a few thousand commands at most (one window at 4 Hz).
    """
    check_range(t0_ns, t1_ns)
    repo.get_pass(session=session, pass_id=pass_id)  # NotFound for an unknown pass
    records = repo.list_commands(
        session=session,
        pass_id=pass_id,
        stages=stages,
        kinds=kinds,
        execute_from_ns=t0_ns,
        execute_to_ns=t1_ns,
    )
    return CommandsPublic(
        data=[_command(r) for r in records[offset : offset + limit]], count=len(records)
    )


def check_range(t0_ns: int | None, t1_ns: int | None) -> None:
    """``InvalidRequestError`` (422 ``empty_range``) when both bounds are given and
    ``[t0_ns, t1_ns)`` holds nothing."""
    if t0_ns is not None and t1_ns is not None and t1_ns <= t0_ns:
        raise InvalidRequestError("empty_range", f"time range [{t0_ns}, {t1_ns}) ns is empty")


def check_confirmation(
    *, session: Session, pass_id: str, action: str, confirm: str, actor: str, time_ns: int
) -> tuple[str, str | None, list[Recorded]]:
    """The pass's id, and the expected text (``"<ACTION> <pass name>"``) when ``confirm`` is
    not it; then the refusal is written to the audit log (``pass_control_refused``, stamped
    ``time_ns``), for the caller to commit and publish (the events returned) before it
    refuses the request."""
    row = repo.get_pass(session=session, pass_id=pass_id)
    expected = f"{action} {row.name}"
    if confirm == expected:
        return row.id, None, []
    refused = PassControlRefused(
        actor=actor, pass_id=row.id, action=action.lower(), confirm=confirm
    )
    return row.id, expected, [record_event(session, refused, time_ns)]


def control_state(*, session: Session, pass_id: str) -> PassControlPublic:
    """The pass's state as start and abort answer it, read afresh."""
    record = repo.get_pass(session=session, pass_id=pass_id, refresh=True)
    return PassControlPublic(
        pass_id=record.id,
        name=record.name,
        state=record.state,
        state_reason=record.state_reason,
        version=record.version,
        epoch_ns=record.epoch_ns,
    )
