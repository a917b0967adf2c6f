"""Import a recorded pass into the database: a new plan, a finished pass, its commands,
telemetry frames and audit events, in one transaction.

The pass is marked imported by the audit event ``pass_imported`` (actor: who imported it;
detail: the source, the original pass id, counts), the first thing the log says about it
after its own recorded history. Its state is the recording's ``meta["state"]`` when that is
``complete`` or ``aborted``, else ``complete``: an imported pass never runs again.

A recording from a file is untrusted: every value that would reach a constrained column
(lengths, command kinds and stages, int64 times) is checked first, and what the database
still refuses is the invalid request ``recording_not_storable``; either way nothing is kept.
Before anything is decompressed, a file whose chunks declare more than 64 MiB each, or
more than ``max_uncompressed_bytes`` together (the setting
``max_import_uncompressed_bytes``), is refused as ``invalid_recording`` (docs/mcap.md).
"""

from __future__ import annotations

import hashlib
import io
import time
from collections.abc import Mapping
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any

from sqlalchemy.exc import DataError, IntegrityError
from sqlalchemy.orm import Session

from server.schemas import PassImportPublic
from server.services.errors import InvalidRequestError
from server.services.events import PassImported, with_written
from server.services.events import record as record_event
from server.services.passes import public
from server.settings import Settings
from server.storage import repository as repo
from server.storage.errors import Conflict, InvalidArgument
from server.storage.models import COMMAND_KINDS, COMMAND_STAGES
from telemetry.mcap import RecordingFileError, read_mcap
from telemetry.recording import PassRecording

__all__ = ["InvalidRecording", "import_file_job", "import_mcap", "store_recording"]

_INT64 = 2**63
_FINISHED = ("complete", "aborted")
_MAX_UNCOMPRESSED: int = Settings.model_fields["max_import_uncompressed_bytes"].default


class InvalidRecording(InvalidRequestError):
    """A recording that cannot be read or stored: an invalid request, with the reason."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(code, message)


def _int(meta: Mapping[str, Any], key: str) -> int | None:
    value = meta.get(key)
    if isinstance(value, int) and not isinstance(value, bool) and 0 <= value < _INT64:
        return value
    return None


def _text(meta: Mapping[str, Any], key: str, limit: int) -> str | None:
    value = meta.get(key)
    return value[:limit] if isinstance(value, str) and value else None


def _check(recording: PassRecording) -> None:
    """Refuse what the tables cannot take, naming the first bad value."""
    if len(recording.plan.experiment) > 64:
        raise InvalidRecording(
            "recording_not_storable",
            f"plan experiment name of {len(recording.plan.experiment)} characters exceeds 64",
        )
    if not 0 <= recording.epoch_ns < _INT64:
        raise InvalidRecording("recording_not_storable", f"epoch {recording.epoch_ns} ns")
    for c in recording.commands:
        where = f"command {c.seq}"
        if c.kind not in COMMAND_KINDS:
            raise InvalidRecording("recording_not_storable", f"{where}: kind {c.kind!r}")
        if c.stage not in COMMAND_STAGES:
            raise InvalidRecording("recording_not_storable", f"{where}: stage {c.stage!r}")
        if c.reject_reason is not None and len(c.reject_reason) > 32:
            raise InvalidRecording("recording_not_storable", f"{where}: reject reason too long")
        times = [c.seq, c.execute_time_ns, *(t for t in c.stage_times_ns.values() if t is not None)]
        if any(not -_INT64 <= t < _INT64 for t in times):
            raise InvalidRecording("recording_not_storable", f"{where}: a time beyond int64")
        if c.stage_times_ns.get("queued") is None:
            raise InvalidRecording("recording_not_storable", f"{where}: no queued time")
    for e in recording.events:
        if len(e.kind) > 64 or len(e.actor) > 128 or not -_INT64 <= e.time_ns < _INT64:
            raise InvalidRecording(
                "recording_not_storable", f"event {e.kind[:64]!r}: kind, actor or time too long"
            )


def _window(recording: PassRecording, now_ns: int) -> tuple[int, int]:
    """AOS and LOS (ground clock): as recorded, else the span of the reception times."""
    aos, los = _int(recording.meta, "aos_time_ns"), _int(recording.meta, "los_time_ns")
    if aos is not None and los is not None and los >= aos:
        return aos, los
    rx = recording.frames.reception_time_ns
    if len(rx):
        return int(rx.min()), int(rx.max())
    return now_ns, now_ns


def store_recording(
    session: Session,
    recording: PassRecording,
    actor: str,
    *,
    source: str = "recording",
    detail: Mapping[str, Any] | None = None,
    now_ns: int | None = None,
) -> str:
    """Store ``recording`` as a new imported pass (see the module doc); its id.

    One transaction: committed at the end, rolled back on any error, so a failure part way
    leaves no row behind.
    """
    _check(recording)
    now_ns = time.time_ns() if now_ns is None else now_ns
    meta = recording.meta
    aos_ns, los_ns = _window(recording, now_ns)
    gen = recording.frames.generation_time_ns
    start_ns = _int(meta, "telemetry_start_ns")
    end_ns = _int(meta, "telemetry_end_ns")
    if len(gen):
        start_ns = int(gen.min()) if start_ns is None else start_ns
        end_ns = int(gen.max()) + 1 if end_ns is None else end_ns
    state = meta.get("state") if meta.get("state") in _FINISHED else "complete"
    try:
        # A flight-rules report from outside is not the ground's word: the plan is stored
        # without it, and checked by the ground before any pass of it may start.
        plan = repo.add_plan(
            session=session,
            plan=replace(recording.plan, flight_rules=None),
            created_at_ns=now_ns,
        )
        record = repo.add_pass(
            session=session,
            name=recording.name[:128] or "imported pass",
            plan_id=plan.id,
            aos_time_ns=aos_ns,
            los_time_ns=los_ns,
            relay=_text(meta, "relay", 64) or "imported",
            created_at_ns=now_ns,
        )
        repo.update_pass_state(
            session=session,
            pass_id=record.id,
            expected_version=record.version,
            state=str(state),
            updated_at_ns=now_ns,
            reason=_text(meta, "state_reason", 10_000),
            epoch_ns=recording.epoch_ns,
            telemetry_start_ns=start_ns,
            telemetry_end_ns=end_ns,
        )
        repo.add_event_rows(session=session, pass_id=record.id, events=recording.events)
        repo.add_command_rows(session=session, pass_id=record.id, commands=recording.commands)
        frames = repo.add_frame_arrays(session=session, pass_id=record.id, frames=recording.frames)
        original = meta.get("pass_id")
        imported = PassImported(
            actor=actor,
            pass_id=record.id,
            source=source,
            original_pass_id=original if isinstance(original, str) else None,
            frames=frames,
            commands=len(recording.commands),
            events=len(recording.events),
            extra=dict(detail or {}),
        )
        record_event(session, imported, now_ns)
        pass_id = record.id
        session.commit()
    except (IntegrityError, DataError, Conflict, InvalidArgument) as exc:
        session.rollback()
        reason = getattr(exc, "orig", None) or exc
        raise InvalidRecording("recording_not_storable", f"recording refused: {reason}") from exc
    except BaseException:
        session.rollback()
        raise
    return pass_id


def import_mcap(
    session: Session,
    data: bytes,
    actor: str,
    *,
    source: str,
    max_uncompressed_bytes: int = _MAX_UNCOMPRESSED,
    now_ns: int | None = None,
) -> PassImportPublic:
    """Read an MCAP pass recording (:func:`telemetry.mcap.read_mcap`) and store it (at
    ``now_ns``: the request's time on the server's clock; None: now);
    ``invalid_recording`` with the reader's reason for a bad file, or one whose chunks hold
    more than 64 MiB each or ``max_uncompressed_bytes`` together (nothing decompressed,
    nothing stored)."""
    try:
        recording = read_mcap(io.BytesIO(data), max_uncompressed_bytes=max_uncompressed_bytes)
    except RecordingFileError as exc:
        raise InvalidRecording("invalid_recording", str(exc)) from exc
    detail = {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}
    pass_id = store_recording(
        session, recording, actor, source=source, detail=detail, now_ns=now_ns
    )
    return PassImportPublic(
        imported=public(repo.get_pass(session=session, pass_id=pass_id)),
        frames=len(recording.frames),
        commands=len(recording.commands),
        events=len(recording.events),
    )


def import_file_job(
    url: str, path: str, actor: str, max_uncompressed_bytes: int, now_ns: int | None = None
) -> tuple[PassImportPublic, list[dict[str, Any]]]:
    """A worker job (:mod:`server.services.workers`): :func:`import_mcap` of the upload the
    route spooled to ``path``, on the job's own connection to ``url``; with the events it
    wrote, for the server to publish."""
    from server.services.jobs import session_job

    data = Path(path).read_bytes()
    return session_job(
        url,
        partial(with_written, import_mcap),
        data=data,
        actor=actor,
        source="upload",
        max_uncompressed_bytes=max_uncompressed_bytes,
        now_ns=now_ns,
    )
