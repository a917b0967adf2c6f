"""The events that record a command's stages (docs/protocol.md). The stage rules themselves
(ranks, which stages are final, which move overrules which) are defined once in
:mod:`server.storage.stages` and re-exported here."""

from __future__ import annotations

import time
from typing import Any

from sqlalchemy.orm import Session

from server.storage import repository as repo
from server.storage.stages import FINAL_STAGES, STAGE_RANK, moves

__all__ = [
    "FINAL_STAGES",
    "STAGE_RANK",
    "cancel_commands",
    "event_dict",
    "set_command_stage",
    "write_event",
]


def event_dict(
    kind: str, actor: str, detail: dict[str, Any], pass_id: str | None, time_ns: int
) -> dict[str, Any]:
    return {"kind": kind, "actor": actor, "detail": detail, "pass_id": pass_id, "time_ns": time_ns}


def write_event(
    session: Session, kind: str, actor: str, detail: dict[str, Any], pass_id: str | None = None
) -> dict[str, Any]:
    """Add an event row (ground time now) and return it as the dict to publish."""
    now = time.time_ns()
    record = repo.add_event(
        session=session, time_ns=now, kind=kind, actor=actor, detail=detail, pass_id=pass_id
    )
    return {**event_dict(kind, actor, detail, pass_id, now), "id": record.id}


def set_command_stage(
    session: Session,
    *,
    pass_id: str,
    seq: int,
    stage: str,
    time_ns: int,
    actor: str,
    reason: str | None = None,
    detail: str | None = None,
    transmissions: int | None = None,
) -> list[dict[str, Any]]:
    """Move a command forward to ``stage`` at ``time_ns`` (on the clock the storage models
    name for it) and write the event; nothing if that would move it backwards."""
    record = repo.get_command(session=session, pass_id=pass_id, seq=seq)
    if transmissions is not None and transmissions > record.transmissions:
        record.transmissions = transmissions
    if not moves(record.stage, stage):
        return []
    previous = record.stage
    repo.update_command_stage(
        session=session,
        pass_id=pass_id,
        seq=seq,
        stage=stage,
        time_ns=time_ns,
        reject_reason=reason,
    )
    info: dict[str, Any] = {"seq": seq, "from": previous, "stage": stage, "time_ns": time_ns}
    if reason is not None:
        info["reason"] = reason
    if detail is not None:
        info["detail"] = detail
    return [write_event(session, "command_stage", actor, info, pass_id)]


def cancel_commands(
    session: Session,
    *,
    pass_id: str,
    seqs: list[int],
    time_ns: int,
    actor: str,
    reason: str,
    from_time_ns: int | None,
) -> list[dict[str, Any]]:
    """Mark these commands ``cancelled`` (those not already final) in one statement and
    write **one** event, ``commands_cancelled``, with the count and the seq range: an abort
    of a long pass must not flood the consoles with one event per command."""
    n = repo.cancel_commands(session=session, pass_id=pass_id, seqs=seqs, time_ns=time_ns)
    if not n:
        return []
    detail: dict[str, Any] = {
        "count": n,
        "first_seq": min(seqs),
        "last_seq": max(seqs),
        "from_time_ns": from_time_ns,
        "reason": reason[:200],
    }
    return [write_event(session, "commands_cancelled", actor, detail, pass_id)]
