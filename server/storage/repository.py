"""Repository functions: every read and write of the ground service's tables.

Every function takes keyword arguments only, the first being the ``session``; none commits
or rolls back (the service owns the transaction). Writes flush, so database errors surface
at the call, mapped to :mod:`server.storage.errors`; after one, roll the session back.
Times are integer ns (see :mod:`server.storage.models` for which clock).

    plans      add_plan, get_plan, list_plans
    passes     add_pass, get_pass, list_passes, update_pass_state (optimistic lock),
               get_pass_layout (its telemetry's layout: the plan's robot)
    commands   add_commands (bulk), get_command, update_command_stage, cancel_commands,
               list_commands, load_commands and update_commands (many in a few statements;
               from ``_commands``)
    events     add_event, add_events (many in one statement), list_events
    analysis   add_analysis, get_analysis, list_analyses
    import     add_frame_arrays, add_command_rows, add_event_rows: a whole recorded pass
               (from ``_import``)
    telemetry  ingest_frames, ingest_messages, frame_seqs, missing_seqs, count_frames,
               telemetry_range, telemetry_buckets, telemetry_extent (from ``_telemetry``)
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from typing import Any

from sqlalchemy import ColumnElement, insert, select
from sqlalchemy.orm import Session, defer
from sqlalchemy.orm.exc import StaleDataError

from planner.plan import Plan
from server.storage._commands import (
    add_commands,
    cancel_commands,
    get_command,
    list_commands,
    load_commands,
    update_command_stage,
    update_commands,
)
from server.storage._common import (
    Page,
    canonical_id,
    check_one_of,
    check_page,
    check_time_range,
    flush,
    new_id,
    paged,
    require_pass,
    stored,
    within,
)
from server.storage._import import add_command_rows, add_event_rows, add_frame_arrays
from server.storage._telemetry import (
    Bucket,
    IngestResult,
    count_frames,
    frame_seqs,
    ingest_frames,
    ingest_messages,
    missing_seqs,
    pass_layout,
    stored_among,
    telemetry_buckets,
    telemetry_extent,
    telemetry_range,
)
from server.storage.errors import Conflict, InvalidArgument, NotFound
from server.storage.models import (
    PASS_STATES,
    AnalysisRecord,
    EventRecord,
    PassRecord,
    PlanRecord,
    stored_layout,
)
from telemetry.layout import FrameLayout

__all__ = [
    "Bucket",
    "IngestResult",
    "Page",
    "add_analysis",
    "add_command_rows",
    "add_commands",
    "add_event",
    "add_event_rows",
    "add_events",
    "add_frame_arrays",
    "add_pass",
    "add_plan",
    "cancel_commands",
    "count_frames",
    "frame_seqs",
    "get_analysis",
    "get_command",
    "get_pass",
    "get_pass_layout",
    "get_plan",
    "ingest_frames",
    "ingest_messages",
    "list_analyses",
    "list_commands",
    "list_events",
    "list_passes",
    "list_plans",
    "load_commands",
    "missing_seqs",
    "set_plan_document",
    "stored_among",
    "telemetry_buckets",
    "telemetry_extent",
    "telemetry_range",
    "update_command_stage",
    "update_commands",
    "update_pass_state",
]


# --- plans ---------------------------------------------------------------------------------


def add_plan(
    *, session: Session, plan: Plan, created_at_ns: int, plan_id: str | None = None
) -> PlanRecord:
    """Store ``plan`` (its JSON document and a summary); a new UUID unless ``plan_id``."""
    key = new_id() if plan_id is None else canonical_id(plan_id, what="plan")
    if plan_id is not None and session.get(PlanRecord, key) is not None:
        raise Conflict(f"plan {key} is already stored")
    n_joints = len(plan.initial_joints_rad)
    try:
        stored_layout(n_joints)
    except ValueError as exc:
        raise InvalidArgument(f"plan {key}: {exc}") from None
    record = PlanRecord(
        id=key,
        experiment=plan.experiment,
        parameters=dict(plan.parameters),
        document=plan.to_json(),
        duration_s=plan.duration_s,
        n_commands=len(plan.command_times_s) + len(plan.acs_commands),
        created_at_ns=created_at_ns,
        n_joints=n_joints,
    )
    session.add(record)
    flush(session, f"plan {record.id}")
    return record


def set_plan_document(*, session: Session, plan_id: str, plan: Plan) -> PlanRecord:
    """Replace the stored document of plan ``plan_id`` with ``plan``'s: the same plan with
    more said of it (its flight-rules report). Anything a summary column holds must be
    unchanged: :class:`InvalidArgument` otherwise (a plan's commands never change)."""
    record = get_plan(session=session, plan_id=plan_id)
    summary = (plan.experiment, plan.duration_s, len(plan.initial_joints_rad))
    if summary != (record.experiment, record.duration_s, record.n_joints):
        raise InvalidArgument(
            f"plan {record.id}: the new document's experiment, duration or joints "
            f"{summary} differ from the stored "
            f"{(record.experiment, record.duration_s, record.n_joints)}"
        )
    record.document = plan.to_json()
    flush(session, f"plan {record.id}")
    return record


def get_plan(*, session: Session, plan_id: str) -> PlanRecord:
    """The plan, document included (``Plan.from_json(record.document)`` rebuilds it)."""
    return stored(session, PlanRecord, plan_id, what="plan")


def list_plans(
    *, session: Session, experiment: str | None = None, offset: int = 0, limit: int = 100
) -> Page[PlanRecord]:
    """Plans, newest first, without their documents (reading ``document`` raises)."""
    check_page(offset, limit)
    where: list[ColumnElement[bool]] = []
    if experiment is not None:
        where.append(PlanRecord.experiment == experiment)
    order = (PlanRecord.created_at_ns.desc(), PlanRecord.id)
    options = (defer(PlanRecord.document, raiseload=True),)
    return paged(session, PlanRecord, where, order, offset, limit, options)


# --- passes --------------------------------------------------------------------------------


def add_pass(
    *,
    session: Session,
    name: str,
    plan_id: str,
    aos_time_ns: int,
    los_time_ns: int,
    relay: str,
    created_at_ns: int,
    pass_id: str | None = None,
    window_mission: str | None = None,
    window_detail: dict[str, Any] | None = None,
) -> PassRecord:
    """A new pass of ``plan_id`` in state ``scheduled``, version 1; ``window_mission`` and
    ``window_detail``: the computed window it was scheduled in, if any."""
    plan_key = get_plan(session=session, plan_id=plan_id).id
    if los_time_ns < aos_time_ns:
        raise InvalidArgument(f"pass LOS {los_time_ns} ns is before its AOS {aos_time_ns} ns")
    key = new_id() if pass_id is None else canonical_id(pass_id, what="pass")
    if pass_id is not None and session.get(PassRecord, key) is not None:
        raise Conflict(f"pass {key} is already stored")
    record = PassRecord(
        id=key,
        name=name,
        plan_id=plan_key,
        aos_time_ns=aos_time_ns,
        los_time_ns=los_time_ns,
        relay=relay,
        state="scheduled",
        state_reason=None,
        epoch_ns=None,
        window_mission=window_mission,
        window_detail=window_detail,
        created_at_ns=created_at_ns,
        updated_at_ns=created_at_ns,
    )
    session.add(record)
    flush(session, f"pass {record.id}")
    return record


def get_pass(*, session: Session, pass_id: str, refresh: bool = False) -> PassRecord:
    """The pass; ``refresh`` re-reads it even when the session already holds it."""
    return stored(session, PassRecord, pass_id, what="pass", populate_existing=refresh)


def get_pass_layout(*, session: Session, pass_id: str) -> FrameLayout:
    """The telemetry layout of the pass: its plan's joint count (and the three wheels the
    archive stores)."""
    return pass_layout(session, require_pass(session, pass_id))


def list_passes(
    *,
    session: Session,
    states: Collection[str] | None = None,
    offset: int = 0,
    limit: int = 100,
) -> Page[PassRecord]:
    """Passes in AOS order, optionally only those in ``states``."""
    check_page(offset, limit)
    where: list[ColumnElement[bool]] = []
    if states is not None:
        for state in states:
            check_one_of(state, PASS_STATES, what="pass state")
        where.append(PassRecord.state.in_(list(states)))
    order = (PassRecord.aos_time_ns, PassRecord.id)
    return paged(session, PassRecord, where, order, offset, limit)


def update_pass_state(
    *,
    session: Session,
    pass_id: str,
    expected_version: int,
    state: str,
    updated_at_ns: int,
    reason: str | None = None,
    epoch_ns: int | None = None,
    telemetry_start_ns: int | None = None,
    telemetry_end_ns: int | None = None,
) -> PassRecord:
    """Move the pass to ``state`` (with ``reason``; ``epoch_ns`` and the telemetry window's
    ends if given), version + 1.

    Raises :class:`Conflict` unless the stored version is ``expected_version``: the row is
    read afresh (``FOR UPDATE`` on PostgreSQL) and the UPDATE is also conditional on the
    version, so a writer in between is caught either way. Which transitions are allowed is
    the service's rule, not the storage's.
    """
    check_one_of(state, PASS_STATES, what="pass state")
    key = canonical_id(pass_id, what="pass")
    # The stored version, read past the session's own copy (which may be from an earlier
    # transaction): a plain column query does not go through the identity map.
    current = session.scalar(
        select(PassRecord.version).where(PassRecord.id == key).with_for_update()
    )
    if current is None:
        raise NotFound(f"pass {pass_id!r} not found")
    if current != expected_version:
        raise Conflict(f"pass {key} is at version {current}, not the expected {expected_version}")
    record = session.get_one(PassRecord, key)
    if record.version != current:
        session.expire(record)  # a stale copy: reload it rather than write against it
    record.state = state
    record.state_reason = reason
    record.updated_at_ns = updated_at_ns
    if epoch_ns is not None:
        record.epoch_ns = epoch_ns
    if telemetry_start_ns is not None:
        record.telemetry_start_ns = telemetry_start_ns
    if telemetry_end_ns is not None:
        record.telemetry_end_ns = telemetry_end_ns
    try:
        session.flush()
    except StaleDataError as exc:
        raise Conflict(f"pass {key} changed under version {expected_version}") from exc
    return record


# --- events --------------------------------------------------------------------------------


def add_event(
    *,
    session: Session,
    time_ns: int,
    kind: str,
    actor: str,
    detail: Mapping[str, Any] | None = None,
    pass_id: str | None = None,
) -> EventRecord:
    """Append to the audit log; the record carries its new ``id``."""
    record = EventRecord(
        pass_id=None if pass_id is None else require_pass(session, pass_id),
        time_ns=time_ns,
        kind=kind,
        actor=actor,
        detail=dict(detail or {}),
    )
    session.add(record)
    flush(session, f"event {kind!r}")
    return record


def add_events(*, session: Session, rows: list[dict[str, Any]]) -> list[int]:
    """Append many events to the audit log in one statement (each row as :func:`add_event`'s
    arguments: ``time_ns``, ``kind``, ``actor``, ``detail``, ``pass_id``); their new ids,
    in the rows' order."""
    if not rows:
        return []
    keys: dict[str, str] = {}
    values = []
    for row in rows:
        pass_id = row.get("pass_id")
        if pass_id is not None and pass_id not in keys:
            keys[pass_id] = require_pass(session, pass_id)
        values.append(
            {
                "pass_id": None if pass_id is None else keys[pass_id],
                "time_ns": row["time_ns"],
                "kind": row["kind"],
                "actor": row["actor"],
                "detail": dict(row.get("detail") or {}),
            }
        )
    statement = insert(EventRecord).returning(EventRecord.id, sort_by_parameter_order=True)
    return list(session.scalars(statement, values))


def list_events(
    *,
    session: Session,
    pass_id: str | None = None,
    kinds: Collection[str] | None = None,
    t0_ns: int | None = None,
    t1_ns: int | None = None,
    offset: int = 0,
    limit: int = 100,
    actors: Collection[str] | None = None,
) -> Page[EventRecord]:
    """Events in time order (then id), filtered by pass, kinds, actors and
    ``[t0_ns, t1_ns)``."""
    check_page(offset, limit)
    where: list[ColumnElement[bool]] = []
    if pass_id is not None:
        where.append(EventRecord.pass_id == canonical_id(pass_id, what="pass"))
    if kinds is not None:
        where.append(EventRecord.kind.in_(list(kinds)))
    if actors is not None:
        where.append(EventRecord.actor.in_(list(actors)))
    if t0_ns is not None and t1_ns is not None:
        check_time_range(t0_ns, t1_ns)
    where += within(EventRecord.time_ns, t0_ns, t1_ns)
    order = (EventRecord.time_ns, EventRecord.id)
    return paged(session, EventRecord, where, order, offset, limit)


# --- analysis ------------------------------------------------------------------------------


def add_analysis(
    *,
    session: Session,
    pass_id: str,
    kind: str,
    result: Mapping[str, Any],
    created_at_ns: int,
) -> AnalysisRecord:
    """Store an analysis result (JSON: no NaN or infinity); the newest of a kind is current."""
    record = AnalysisRecord(
        pass_id=require_pass(session, pass_id),
        kind=kind,
        created_at_ns=created_at_ns,
        result=dict(result),
    )
    session.add(record)
    flush(session, f"analysis {kind!r} of pass {pass_id}")
    return record


def get_analysis(*, session: Session, pass_id: str, kind: str) -> AnalysisRecord:
    """The newest analysis of ``kind`` for the pass."""
    query = (
        select(AnalysisRecord)
        .where(
            AnalysisRecord.pass_id == canonical_id(pass_id, what="pass"),
            AnalysisRecord.kind == kind,
        )
        .order_by(AnalysisRecord.created_at_ns.desc(), AnalysisRecord.id.desc())
        .limit(1)
    )
    record = session.scalar(query)
    if record is None:
        raise NotFound(f"no {kind!r} analysis of pass {pass_id!r}")
    return record


def list_analyses(*, session: Session, pass_id: str) -> list[AnalysisRecord]:
    """Every analysis of the pass, oldest first."""
    query = (
        select(AnalysisRecord)
        .where(AnalysisRecord.pass_id == canonical_id(pass_id, what="pass"))
        .order_by(AnalysisRecord.created_at_ns, AnalysisRecord.id)
    )
    return list(session.scalars(query))
