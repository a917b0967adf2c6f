"""The writes that move a command's stage, and their events (docs/protocol.md). The stage
rules themselves (ranks, which stages are final, which move overrules which) are defined once
in :mod:`server.storage.stages` and re-exported here. Their events are stamped by the
writer's injected clock (``clock``), like every event (:mod:`server.services.events`)."""

from __future__ import annotations

from sqlalchemy.orm import Session

from server.services.clock import Clock
from server.services.events import CommandsCancelled, Recorded, record
from server.storage import repository as repo
from server.storage.stages import FINAL_STAGES, STAGE_RANK

__all__ = [
    "FINAL_STAGES",
    "STAGE_RANK",
    "cancel_commands",
    "set_command_stage",
]


def set_command_stage(
    session: Session,
    *,
    clock: Clock,
    pass_id: str,
    seq: int,
    stage: str,
    time_ns: int,
    actor: str,
    reason: str | None = None,
    detail: str | None = None,
    transmissions: int | None = None,
) -> list[Recorded]:
    """Move a command forward to ``stage`` at ``time_ns`` (on the clock the storage models
    name for it) and write the event; nothing if that would move it backwards. One move of
    :class:`~server.services.stage_writes.StageWrites`, whose rules the live path's batches
    share."""
    from server.services.stage_writes import StageMove, StageWrites

    move = StageMove(pass_id, seq, stage, time_ns, actor, reason, detail, transmissions)
    [events] = StageWrites(clock)(session, [[move]])
    return events


def cancel_commands(
    session: Session,
    *,
    clock: Clock,
    pass_id: str,
    seqs: list[int],
    time_ns: int,
    actor: str,
    reason: str,
    from_time_ns: int | None,
) -> list[Recorded]:
    """Mark these commands ``cancelled`` (those not already final) in one statement and
    write **one** event, ``commands_cancelled``, with the count and the seq range: an abort
    of a long pass must not flood the consoles with one event per command."""
    n = repo.cancel_commands(session=session, pass_id=pass_id, seqs=seqs, time_ns=time_ns)
    if not n:
        return []
    event = CommandsCancelled(
        actor=actor,
        pass_id=pass_id,
        count=n,
        first_seq=min(seqs),
        last_seq=max(seqs),
        from_time_ns=from_time_ns,
        reason=reason[:200],
    )
    return [record(session, event, clock.time_ns())]
