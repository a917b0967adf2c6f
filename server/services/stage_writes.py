"""The command stages' writes of the live path, batched: :class:`StageWrites`.

The uplink's ``released`` and ``sent`` (ground times, with the count of transmissions), its
``expired``, and the vehicle's acknowledgements (:mod:`server.services.command_fates`) are
each a :class:`StageMove`; a database job of moves is a
:class:`~server.services.db_batch.Batched` of :class:`StageWrites`, so the worker runs the
consecutive ones of a group commit together: every row they touch read in one statement,
the moves applied in order in memory (the rules of :func:`set_command_stage`, one
``command_stage`` event each), then the rows written in one statement per set of columns
and the events in one (:mod:`server.services.db_batch` says why).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from server.services.clock import Clock
from server.services.db_batch import Batched
from server.services.event_log import Event, Recorded, record_many
from server.services.events import CommandAckUnknown, CommandStage
from server.storage import repository as repo
from server.storage._common import canonical_id
from server.storage.errors import NotFound
from server.storage.models import CommandRecord
from server.storage.stages import moves

__all__ = ["StageMove", "StageWrites", "newest_pass_of"]

Events = list[Recorded]


@dataclass(frozen=True)
class StageMove:
    """A command moved forward to ``stage`` at ``time_ns`` (as
    :func:`~server.services.command_stages.set_command_stage`), or only its count of
    ``transmissions`` raised (``stage`` None)."""

    pass_id: str | None  # None: the newest pass that queued the seq (an acknowledgement's)
    seq: int
    stage: str | None
    time_ns: int = 0
    actor: str = "ground"
    reason: str | None = None
    detail: str | None = None
    transmissions: int | None = None
    #: the stage the vehicle reported (an acknowledgement's): audited if no pass holds the seq
    acked: str | None = None


def newest_pass_of(session: Session, seq: int) -> str | None:
    """The newest pass that queued ``seq``."""
    return session.scalar(
        select(CommandRecord.pass_id)
        .where(CommandRecord.seq == seq)
        .order_by(CommandRecord.queued_at_ns.desc())
        .limit(1)
    )


@dataclass(frozen=True)
class StageWrites:
    """The batch kind of the stage moves (jobs of one clock batch together): each payload is
    one job's moves, its result the events it wrote (published once committed)."""

    clock: Clock

    def job(self, stage_moves: Iterable[StageMove]) -> Batched[Sequence[StageMove], Events]:
        return Batched(self, tuple(stage_moves))

    def __call__(self, session: Session, payloads: list[Sequence[StageMove]]) -> list[Events]:
        owners = {
            m.seq: newest_pass_of(session, m.seq)
            for payload in payloads
            for m in payload
            if m.pass_id is None
        }
        wanted: dict[str, set[int]] = {}  # by canonical pass id
        for payload in payloads:
            for m in payload:
                pass_id = owners[m.seq] if m.pass_id is None else m.pass_id
                if pass_id is not None:
                    wanted.setdefault(canonical_id(pass_id, what="pass"), set()).add(m.seq)
        rows = {
            p: repo.load_commands(session=session, pass_id=p, seqs=s) for p, s in wanted.items()
        }
        changed: dict[str, dict[int, dict[str, Any]]] = {p: {} for p in rows}
        stamped: list[list[tuple[Event, int]]] = []
        for payload in payloads:
            events: list[tuple[Event, int]] = []
            for m in payload:
                pass_id = owners[m.seq] if m.pass_id is None else m.pass_id
                if pass_id is None:
                    unknown = CommandAckUnknown(actor=m.actor, seq=m.seq, stage=m.acked or "")
                    events.append((unknown, self.clock.time_ns()))
                    continue
                key = canonical_id(pass_id, what="pass")
                event = _apply(rows[key], changed[key], pass_id, m)
                if event is not None:
                    events.append((event, self.clock.time_ns()))
            stamped.append(events)
        for pass_id, values in changed.items():
            repo.update_commands(session=session, records=rows[pass_id], values=values)
        written = record_many(session, [e for events in stamped for e in events])
        out: list[Events] = []
        for events in stamped:
            out.append(written[: len(events)])
            written = written[len(events) :]
        return out


def _apply(
    rows: dict[int, CommandRecord],
    changed: dict[int, dict[str, Any]],
    pass_id: str,
    m: StageMove,
) -> CommandStage | None:
    """``m`` on the row as the moves before it left it (``changed``: what to write); its
    event, if the stage moved."""
    row = rows.get(m.seq)
    if row is None:
        raise NotFound(f"command {m.seq} of pass {pass_id!r} not found")
    values = changed.setdefault(m.seq, {})
    transmissions = values.get("transmissions", row.transmissions)
    if m.transmissions is not None and m.transmissions > transmissions:
        values["transmissions"] = m.transmissions
    current = values.get("stage", row.stage)
    if m.stage is None or not moves(current, m.stage):
        return None
    values["stage"] = m.stage
    values[f"{m.stage}_at_ns"] = m.time_ns
    if m.reason is not None:
        values["reject_reason"] = m.reason
    return CommandStage(
        actor=m.actor,
        pass_id=pass_id,
        seq=m.seq,
        from_stage=current,
        stage=m.stage,
        time_ns=m.time_ns,
        reason=m.reason,
        detail_text=m.detail,
    )
