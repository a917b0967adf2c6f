"""Bulk writes of a whole recorded pass: frames with their own reception times, commands with
their stage times, audit events.

:func:`ingest_frames` stores frames as the link receives them (one reception time per
batch, wire objects); an imported recording already holds every frame's reception time and
its columns as arrays, so these write the columns straight: SQLite through the same
``INSERT`` as the link, PostgreSQL through the same binary ``COPY`` and staging table (see
``_telemetry``). Like every repository function they run inside the caller's transaction and
never commit; a failure part way is undone by the caller's rollback.
"""

from __future__ import annotations

import uuid
from collections.abc import Sequence
from typing import Any

import numpy as np
from sqlalchemy import insert
from sqlalchemy.exc import DBAPIError, IntegrityError
from sqlalchemy.orm import Session

from server.storage._common import require_pass
from server.storage._telemetry import (
    _PG_COPY,
    _PG_CREATE_STAGE,
    _PG_MOVE,
    _PG_STATEMENTS,
    _PG_TYPES,
    _SQLITE_INSERT,
)
from server.storage.errors import Conflict
from server.storage.models import COMMAND_STAGES, CommandRecord, EventRecord
from telemetry.recording import CommandRow, EventRow, FrameArrays

__all__ = ["add_command_rows", "add_event_rows", "add_frame_arrays"]


def _frame_rows(pass_key: object, frames: FrameArrays) -> list[tuple[Any, ...]]:
    """Rows in ``_telemetry._COLUMNS`` order, as plain Python values."""
    n = len(frames)
    numbers = np.hstack(
        [
            frames.joints_rad,
            frames.joint_targets_rad,
            frames.quat_orbit_from_base_xyzw,
            frames.omega_base_in_base_radps,
            frames.wheel_speeds_radps,
            frames.wheel_momentum_nms,
        ]
    ).tolist()
    target = frames.acs_target_quat_xyzw.tolist()
    next_tag = [None if t < 0 else t for t in frames.buffer_next_execute_time_ns.tolist()]
    columns = zip(
        frames.seq.tolist(),
        frames.generation_time_ns.tolist(),
        frames.reception_time_ns.tolist(),
        numbers,
        frames.acs_mode.tolist(),
        target,
        frames.acs_feedforward.tolist(),
        frames.buffer_queued.tolist(),
        next_tag,
        frames.buffer_last_executed_seq.tolist(),
        strict=True,
    )
    rows = [
        (pass_key, seq, gen, rx, *values, str(mode), *tq, bool(ff), queued, tag, last)
        for seq, gen, rx, values, mode, tq, ff, queued, tag, last in columns
    ]
    assert len(rows) == n
    return rows


def add_frame_arrays(*, session: Session, pass_id: str, frames: FrameArrays) -> int:
    """Store every row of ``frames`` for the pass, each with its own ``reception_time_ns``
    (a ``buffer_next_execute_time_ns`` of -1 is stored as NULL: nothing queued); the number
    stored. A ``seq`` the pass already holds raises :class:`Conflict`."""
    key = require_pass(session, pass_id)
    if len(frames) == 0:
        return 0
    connection = session.connection()
    dialect = connection.dialect
    if dialect.name == "postgresql":
        rows = _frame_rows(uuid.UUID(key), frames)
        driver_connection: Any = connection.connection.driver_connection
        try:
            with driver_connection.cursor() as cursor:
                cursor.execute(_PG_CREATE_STAGE)
                with cursor.copy(_PG_COPY) as copy:
                    copy.set_types(_PG_TYPES)
                    for row in rows:
                        copy.write_row(row)
                cursor.execute(_PG_MOVE)
                inserted = int(cursor.rowcount)
        except dialect.loaded_dbapi.Error as exc:
            raise DBAPIError.instance(
                _PG_STATEMENTS, None, exc, dialect.loaded_dbapi.Error
            ) from exc
    else:
        rows = _frame_rows(uuid.UUID(key).hex, frames)
        inserted = connection.exec_driver_sql(_SQLITE_INSERT, rows).rowcount
    if inserted != len(frames):
        raise Conflict(
            f"pass {key} already holds {len(frames) - inserted} of the {len(frames)} frames"
        )
    return inserted


def add_command_rows(*, session: Session, pass_id: str, commands: Sequence[CommandRow]) -> int:
    """Store commands with their stage and the time each stage was reached; the number
    stored. ``queued`` must have a time (the column is NOT NULL); a ``seq`` the pass already
    has raises :class:`Conflict`."""
    key = require_pass(session, pass_id)
    rows = []
    for command in commands:
        row: dict[str, Any] = {
            "pass_id": key,
            "seq": command.seq,
            "kind": command.kind,
            "execute_time_ns": command.execute_time_ns,
            "payload": dict(command.payload),
            "stage": command.stage,
            "reject_reason": command.reject_reason,
        }
        for stage in COMMAND_STAGES:
            row[f"{stage}_at_ns"] = command.stage_times_ns.get(stage)
        rows.append(row)
    if not rows:
        return 0
    try:
        session.execute(insert(CommandRecord), rows)
    except IntegrityError as exc:
        raise Conflict(f"commands of pass {key}: {exc.orig}") from exc
    return len(rows)


def add_event_rows(*, session: Session, pass_id: str, events: Sequence[EventRow]) -> int:
    """Append recorded audit events to the log, attached to the pass; the number stored."""
    key = require_pass(session, pass_id)
    rows = [
        {
            "pass_id": key,
            "time_ns": event.time_ns,
            "kind": event.kind,
            "actor": event.actor,
            "detail": dict(event.detail),
        }
        for event in events
    ]
    if rows:
        session.execute(insert(EventRecord), rows)
    return len(rows)
