"""Bulk writes of a whole recorded pass: frames with their own reception times, commands with
their stage times, audit events.

:func:`ingest_frames` stores frames as the link receives them (one reception time per
batch, wire objects); an imported recording already holds every frame's reception time and
its columns as arrays, so these write the columns straight (flattened by the pass's
:class:`telemetry.layout.FrameLayout`): SQLite through the same ``INSERT`` as the link,
PostgreSQL through the same binary ``COPY`` and staging table (see ``_telemetry``). Like
every repository function they run inside the caller's transaction and never commit; a
failure part way is undone by the caller's rollback.
"""

from __future__ import annotations

import uuid
from collections.abc import Sequence
from typing import Any

from sqlalchemy.orm import Session

from server.storage._common import insert_rows, require_pass
from server.storage._telemetry import pass_layout, write_rows
from server.storage.errors import Conflict, InvalidArgument
from server.storage.models import COMMAND_STAGES, CommandRecord, EventRecord
from telemetry.layout import FrameLayoutError
from telemetry.recording import CommandRow, EventRow, FrameArrays

__all__ = ["add_command_rows", "add_event_rows", "add_frame_arrays"]


def add_frame_arrays(*, session: Session, pass_id: str, frames: FrameArrays) -> int:
    """Store every row of ``frames`` for the pass, each with its own ``reception_time_ns``
    (a ``buffer_next_execute_time_ns`` of -1 is stored as NULL: nothing queued); the number
    stored. A ``seq`` the pass already holds raises :class:`Conflict`; arrays of another
    layout than the pass's robot (its plan's joint count) :class:`InvalidArgument`."""
    key = require_pass(session, pass_id)
    if len(frames) == 0:
        return 0
    layout = pass_layout(session, key)
    try:
        pass_key = uuid.UUID(key)
        rows = [(pass_key, *row) for row in layout.arrays_to_rows(frames)]
    except FrameLayoutError as exc:
        raise InvalidArgument(f"pass {key}: {exc}") from None
    inserted = write_rows(session, layout, rows)
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
    return insert_rows(session, CommandRecord, rows, what=f"commands of pass {key}")


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
    return insert_rows(session, EventRecord, rows, what=f"events of pass {key}")
