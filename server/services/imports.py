"""Import a recorded pass into the database: a new plan, a finished pass, its commands,
telemetry frames, audit events and alarms (each under a new id), in one transaction.

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

An upload is spooled to a file before it is read; :class:`SpoolBudget` bounds the bytes
all concurrent imports may hold on disk together (the setting
``import_spool_budget_bytes``, docs/security.md "Import spools"): an upload is admitted for
its declared size before its first byte is read, or chunk by chunk when it declares none,
and one that would take the spools past the budget is refused as unavailable (``busy``,
with the time to retry after) and its partial spool deleted. What an import holds is given
back on every path, success, refusal, failure or a client gone.
"""

from __future__ import annotations

import hashlib
import io
import time
import uuid
from collections.abc import Mapping, Sequence
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any

from sqlalchemy.exc import DataError, IntegrityError
from sqlalchemy.orm import Session

from server.schemas import name_problem
from server.schemas.analyses import PassImportPublic
from server.services.errors import InvalidRequestError, UnavailableError
from server.services.events import PassImported, with_written
from server.services.events import record as record_event
from server.services.passes import public
from server.settings import Settings
from server.storage import alarms as alarm_repo
from server.storage import repository as repo
from server.storage.errors import Conflict, InvalidArgument
from server.storage.models import COMMAND_KINDS, COMMAND_STAGES
from telemetry.mcap import RecordingFileError, read_mcap
from telemetry.recording import PassRecording

__all__ = [
    "InvalidRecording",
    "SpoolBudget",
    "SpoolHold",
    "import_file_job",
    "import_mcap",
    "store_recording",
]

_INT64 = 2**63
_FINISHED = ("complete", "aborted")
_MAX_UNCOMPRESSED: int = Settings.model_fields["max_import_uncompressed_bytes"].default


class InvalidRecording(InvalidRequestError):
    """A recording that cannot be read or stored: an invalid request, with the reason."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(code, message)


#: How long a refused import is told to wait before it tries again (s): an import of the
#: 20-minute demo pass takes about 30 s on a loaded 2-core machine (settings.py).
SPOOL_RETRY_AFTER_S = 30.0


class SpoolBudget:
    """The bytes every import's spool file may hold on disk together (``budget_bytes``).

    Used from the event loop only (no lock): :meth:`hold` opens an import's share, which it
    grows with :meth:`SpoolHold.take` as bytes arrive and gives back when closed.
    """

    def __init__(self, budget_bytes: int) -> None:
        if budget_bytes < 1:
            raise ValueError(f"spool budget {budget_bytes} bytes must be >= 1")
        self.budget_bytes = budget_bytes
        self.held_bytes = 0
        self.imports = 0

    def hold(self) -> SpoolHold:
        return SpoolHold(self)

    def _take(self, nbytes: int, total: int) -> None:
        if self.held_bytes + nbytes > self.budget_bytes:
            others = self.held_bytes - (total - nbytes)
            refusal = UnavailableError(
                f"an import of {total} bytes would take the import spools past their budget "
                f"of {self.budget_bytes} bytes ({others} bytes held by {self.imports - 1} "
                "other imports); try again later",
                SPOOL_RETRY_AFTER_S,
                "busy",
            )
            refusal.detail.update(
                budget_bytes=self.budget_bytes, held_bytes=others, upload_bytes=total
            )
            raise refusal
        self.held_bytes += nbytes


class SpoolHold:
    """One import's share of a :class:`SpoolBudget`: a context manager that gives back all
    it took when it closes, however the import ends."""

    def __init__(self, budget: SpoolBudget) -> None:
        self._budget = budget
        self.bytes = 0
        self._open = False

    def __enter__(self) -> SpoolHold:
        self._open = True
        self._budget.imports += 1
        return self

    def take(self, total_bytes: int) -> None:
        """Grow this import's share to ``total_bytes`` (never shrinks it); unavailable
        (``busy``) when the budget cannot hold it, nothing taken."""
        if not self._open:
            raise RuntimeError("a spool hold is used inside its with block")
        more = total_bytes - self.bytes
        if more > 0:
            self._budget._take(more, total_bytes)
            self.bytes = total_bytes

    def __exit__(self, *exc: object) -> None:
        if self._open:
            self._budget.held_bytes -= self.bytes
            self._budget.imports -= 1
            self.bytes = 0
            self._open = False


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
    problem = name_problem(recording.name[:128])
    if problem is not None:  # shown and quoted to operators as any pass's name
        raise InvalidRecording("recording_not_storable", f"pass name: {problem}")
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


#: The alarm columns of bounded length.
_ALARM_TEXT = {"quantity": 64, "channel": 32, "label": 128, "unit": 16, "acknowledged_by": 128}


def _alarms(recording: PassRecording, pass_id: str) -> list[dict[str, Any]]:
    """The recording's alarms as documents of the new pass (each a new id), or the reason
    the first one cannot be stored."""
    out = []
    for k, raw in enumerate(recording.alarms):
        doc = raw.model_dump(mode="json")  # checked by the reader (telemetry.mcap)
        for name, limit in _ALARM_TEXT.items():
            if len(doc[name] or "") > limit:
                raise InvalidRecording(
                    "recording_not_storable", f"alarm {k}: {name} longer than {limit}"
                )
        times = [v for n, v in doc.items() if n.endswith("_ns") or n == "raised_frame_seq"]
        if any(v is not None and not -_INT64 <= v < _INT64 for v in times):
            raise InvalidRecording("recording_not_storable", f"alarm {k}: a time beyond int64")
        out.append({**doc, "id": str(uuid.uuid4()), "pass_id": pass_id})
    return out


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
        alarm_repo.save_alarms(session=session, documents=_alarms(recording, record.id))
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
) -> tuple[PassImportPublic, Sequence[Any]]:
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
