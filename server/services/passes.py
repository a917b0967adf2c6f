"""Passes: schedule one against a stored plan, list and read them, list their commands.

A window must hold the whole plan and the start lead before its first command: the
first command is tagged ``uplink_start_lead_s`` (at least one-way delay + margin, SPEC 6)
after the start, so that it too can be sent again if the relay loses it, and nothing can be
sent before AOS.

A window is given by hand (``aos_time``, ``los_time``) or named (mission, relay, AOS time:
:mod:`server.services.missions` computes it); a named window's pass runs in its net time
(the window less the mission's margins), the window is stored with the pass, and a plan
that does not fit the net time is the conflict ``plan_exceeds_window`` (docs/missions.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime
from typing import Any

from sqlalchemy.orm import Session

from server.schemas import (
    EARLIEST,
    LATEST,
    CommandPublic,
    CommandsPublic,
    iso_from_ns,
    ns_from_datetime,
)
from server.schemas.passes import (
    PassControlPublic,
    PassCreate,
    PassCreateFromWindow,
    PassesPublic,
    PassPublic,
    PassWindowPublic,
)
from server.services.errors import ConflictError, InvalidRequestError
from server.services.events import PassControlRefused, PassScheduled, Recorded
from server.services.events import record as record_event
from server.settings import Settings
from server.storage import repository as repo
from server.storage.models import CommandRecord, PassRecord

__all__ = [
    "check_confirmation",
    "control_state",
    "get_pass",
    "list_commands",
    "list_passes",
    "schedule_pass",
    "start_lead_s",
]


def start_lead_s(settings: Settings) -> float:
    """The part of a pass's window before its plan's first command (s): the start lead
    (``uplink_start_lead_s``, at least the one-way delay, the margin and 1 s for the start
    itself). A window must hold it and the plan; the rest is the plan's to use
    (the flight rule ``fits_pass`` at start)."""
    return max(
        settings.uplink_start_lead_s,
        settings.link_one_way_delay_s + settings.uplink_margin_s + 1.0,
    )


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


def schedule_pass(
    *,
    session: Session,
    settings: Settings,
    request: PassCreate | PassCreateFromWindow,
    actor: str,
    now_ns: int,
) -> PassPublic:
    """Store a ``scheduled`` pass and the audit event ``pass_scheduled`` in one transaction.

    Storage's ``NotFound`` for an unknown plan; an invalid request for a window that is
    reversed, outside 1970..2200 or too short for the plan; for a named window, the
    refusals of :mod:`server.services.missions` and the conflict ``plan_exceeds_window``.
    """
    if isinstance(request, PassCreateFromWindow):
        return _schedule_in_window(
            session=session, settings=settings, request=request, actor=actor, now_ns=now_ns
        )
    for label, value in (("aos_time", request.aos_time), ("los_time", request.los_time)):
        if not EARLIEST <= value < LATEST:
            raise InvalidRequestError(
                "time_out_of_range", f"{label} {value.isoformat()} is outside 1970..2200"
            )
    aos_ns = ns_from_datetime(request.aos_time)
    los_ns = ns_from_datetime(request.los_time)
    if los_ns <= aos_ns:
        raise InvalidRequestError(
            "window_reversed",
            f"los_time {request.los_time.isoformat()} is not after "
            f"aos_time {request.aos_time.isoformat()}",
        )
    try:
        plan = repo.get_plan(session=session, plan_id=request.plan_id)
        lead_s = start_lead_s(settings)
        window_s = (los_ns - aos_ns) / 1e9
        if window_s < plan.duration_s + lead_s:
            raise InvalidRequestError(
                "window_too_short",
                f"window of {window_s:.3f} s is shorter than plan {plan.id}'s "
                f"{plan.duration_s:.3f} s plus the {lead_s:.3f} s start lead",
            )
        record = _add_scheduled(
            session,
            actor,
            now_ns,
            name=request.name,
            plan_id=plan.id,
            aos_time_ns=aos_ns,
            los_time_ns=los_ns,
            relay=request.relay,
        )
    except BaseException:
        session.rollback()
        raise
    return public(record)


def _add_scheduled(session: Session, actor: str, now_ns: int, **fields: Any) -> PassRecord:
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


def _schedule_in_window(
    *,
    session: Session,
    settings: Settings,
    request: PassCreateFromWindow,
    actor: str,
    now_ns: int,
) -> PassPublic:
    from server.services.missions import window_for_pass

    window, document = window_for_pass(settings, request.window)
    aos_ns = ns_from_datetime(window.net_start_utc)
    los_ns = ns_from_datetime(window.net_end_utc)
    try:
        plan = repo.get_plan(session=session, plan_id=request.plan_id)
        lead_s = start_lead_s(settings)
        if window.net_s < plan.duration_s + lead_s:
            raise ConflictError(
                "plan_exceeds_window",
                f"plan {plan.id} needs {plan.duration_s + lead_s:.3f} s ({plan.duration_s:.3f} s "
                f"and the {lead_s:.3f} s start lead); {window.relay}'s window at "
                f"{window.aos_utc.isoformat()} holds {window.net_s:.3f} s net "
                f"({window.duration_s:.3f} s less {window.aos_margin_s:g} s after AOS and "
                f"{window.los_margin_s:g} s before LOS)",
                {"needed_s": plan.duration_s + lead_s, "net_s": window.net_s},
            )
        record = _add_scheduled(
            session,
            actor,
            now_ns,
            name=request.name,
            plan_id=plan.id,
            aos_time_ns=aos_ns,
            los_time_ns=los_ns,
            relay=window.relay,
            window_mission=document["mission"],
            window_detail=document,
        )
    except BaseException:
        session.rollback()
        raise
    return public(record)


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
