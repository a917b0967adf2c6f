"""A stored pass as a :class:`telemetry.recording.PassRecording`: what the analyses, the MCAP
recorder, reports and replay work from.

:func:`load_recording` reads the plan, the telemetry frames (one query, into the column
arrays of the pass's robot's :class:`telemetry.layout.FrameLayout`), the commands with their
stage times, the pass's audit events and its alarms. A pass that has not started yet (no epoch) has
nothing to analyse: :class:`NotFlown`.
"""

from __future__ import annotations

import io
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from planner.plan import Plan
from server.services.errors import ConflictError
from server.services.robots import meshes_for_plan, model_for_plan, urdf_for_plan
from server.storage import alarms as alarm_repo
from server.storage import repository as repo
from server.storage._common import MAX_LIMIT
from server.storage.models import COMMAND_STAGES, EventRecord, TelemetryFrameRecord
from telemetry.mcap import write_mcap
from telemetry.recording import CommandRow, EventRow, FrameArrays, PassRecording

__all__ = ["NotFlown", "load_recording", "not_flown", "recording_mcap", "write_recording"]

_TABLE = TelemetryFrameRecord.__table__


class NotFlown(ConflictError):
    """The pass has not started: no epoch, no telemetry, nothing to analyse or export."""

    def __init__(self, message: str) -> None:
        super().__init__("pass_not_flown", message)


def not_flown(name: str, state: str) -> NotFlown:
    """The refusal for a pass named ``name`` in ``state`` that has no epoch yet."""
    return NotFlown(f"pass {name!r} is {state}: it has not flown")


def _frames(session: Session, pass_id: str) -> FrameArrays:
    """The pass's frames, in the columns of its robot's layout."""
    layout = repo.get_pass_layout(session=session, pass_id=pass_id)
    rows = session.execute(
        select(*(_TABLE.c[name] for name in layout.columns))
        .where(_TABLE.c.pass_id == pass_id)
        .order_by(_TABLE.c.seq, _TABLE.c.generation_time_ns)
    ).all()
    # Storage keeps the first copy of a seq; a seq reused with another time (an onboard
    # restart) is kept there too, but a recording holds one frame per seq: the first.
    seen: set[int] = set()
    unique = []
    for row in rows:
        if row[0] not in seen:
            seen.add(row[0])
            unique.append(tuple(row))
    return layout.rows_to_arrays(unique)


def load_recording(*, session: Session, pass_id: str) -> PassRecording:
    """Everything stored of one pass (``NotFound`` unknown, :class:`NotFlown` never started)."""
    record = repo.get_pass(session=session, pass_id=pass_id)
    if record.epoch_ns is None:
        raise not_flown(record.name, record.state)
    plan = Plan.from_json(repo.get_plan(session=session, plan_id=record.plan_id).document)
    commands = tuple(
        CommandRow(
            seq=c.seq,
            kind=c.kind,
            execute_time_ns=c.execute_time_ns,
            payload=dict(c.payload),
            stage=c.stage,
            reject_reason=c.reject_reason,
            stage_times_ns={s: getattr(c, f"{s}_at_ns") for s in COMMAND_STAGES},
        )
        for c in repo.list_commands(session=session, pass_id=record.id)
    )
    events = tuple(
        EventRow(time_ns=e.time_ns, kind=e.kind, actor=e.actor, detail=dict(e.detail))
        for e in session.scalars(
            select(EventRecord)
            .where(EventRecord.pass_id == record.id)
            .order_by(EventRecord.time_ns, EventRecord.id)
        )
    )
    meta: dict[str, Any] = {
        "pass_id": record.id,
        "state": record.state,
        "state_reason": record.state_reason,
        "relay": record.relay,
        "aos_time_ns": record.aos_time_ns,
        "los_time_ns": record.los_time_ns,
        "telemetry_start_ns": record.telemetry_start_ns,
        "telemetry_end_ns": record.telemetry_end_ns,
        "plan_id": record.plan_id,
    }
    alarms = alarm_repo.list_alarms(session=session, pass_id=record.id, limit=MAX_LIMIT).items
    return PassRecording(
        name=record.name,
        plan=plan,
        epoch_ns=record.epoch_ns,
        frames=_frames(session, record.id),
        commands=commands,
        events=events,
        meta=meta,
        alarms=tuple(alarm_repo.stored_alarm(a) for a in reversed(alarms)),
    )


def recording_mcap(
    *, session: Session, pass_id: str, robot_files: tuple[str, ...] = ()
) -> tuple[str, bytes]:
    """The pass's name and its recording as MCAP bytes (``NotFound`` unknown,
    :class:`NotFlown` never started), with its robot's URDF and transforms (the plan's
    robot: ETS-VII, a shipped description or one of ``robot_files``,
    :func:`server.services.robots.model_for_plan`).

    The read transaction ends before the file is written (seconds for a whole pass): on
    SQLite a transaction holds the write lock the link needs."""
    recording = load_recording(session=session, pass_id=pass_id)
    session.rollback()
    buffer = io.BytesIO()
    model = model_for_plan(recording.plan, robot_files)
    urdf = urdf_for_plan(recording.plan, robot_files)
    meshes = meshes_for_plan(recording.plan, robot_files)
    write_mcap(recording, buffer, model=model, urdf=urdf, meshes=meshes)
    return recording.name, buffer.getvalue()


def write_recording(
    *, session: Session, pass_id: str, path: str, robot_files: tuple[str, ...] = ()
) -> str:
    """:func:`recording_mcap` written to the file ``path`` (the bytes are the same); the
    pass's name. What a worker process runs for ``GET .../recording.mcap``: the file, not
    the bytes, goes back to the server, which streams it."""
    recording = load_recording(session=session, pass_id=pass_id)
    session.rollback()
    model = model_for_plan(recording.plan, robot_files)
    urdf = urdf_for_plan(recording.plan, robot_files)
    meshes = meshes_for_plan(recording.plan, robot_files)
    with open(path, "wb") as stream:
        write_mcap(recording, stream, model=model, urdf=urdf, meshes=meshes)
    return recording.name
