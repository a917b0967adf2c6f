"""A pass's summary: the frames of its telemetry window and what became of its commands.

The frame count expected is the number of frame slots in the window: frames are numbered
without gaps at a fixed rate (docs/protocol.md), so a stored frame's ``(seq,
generation_time_ns)`` and the rate between the first and the last stored frame place every
slot of ``[start, end)``, including those lost at either edge.

**Outcome** (:func:`command_outcome`, the one place it is computed; docs/operations.md): a
pass is ``nominal`` when every one of its commands executed on board exactly at its time
tag, and ``degraded`` otherwise, with the counts of what became of the others: executed late
(after its tag), expired (never reached the vehicle in time), rejected, cancelled (deleted
from the schedule, or dropped by the vehicle's safing) and unresolved (the ground does not
know: still ``queued``, ``released``, ``sent`` or ``received``). The summary gives it for a
pass that has ended; the ``complete`` transition's reason says it ("complete, degraded: 393
of 6190 commands expired").
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Literal

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from server.schemas.passes import PassSummaryPublic
from server.storage import repository as repo
from server.storage.models import CommandRecord, TelemetryFrameRecord
from server.storage.stages import AWAITING_ACK_STAGES, OPEN_STAGES

__all__ = ["ENDED_STATES", "CommandOutcome", "command_outcome", "pass_summary"]

#: The states a pass ends in: its outcome is given from then on.
ENDED_STATES = ("complete", "aborted", "safed")


@dataclass(frozen=True)
class CommandOutcome:
    """What became of a pass's commands, and the word for it (see the module docstring)."""

    total: int
    executed_at_tag: int
    late: int
    expired: int
    rejected: int
    cancelled: int
    unresolved: int

    @property
    def word(self) -> Literal["nominal", "degraded"]:
        return "nominal" if self.executed_at_tag == self.total else "degraded"

    def document(self) -> dict[str, Any]:
        """The outcome as a report's table takes it (:mod:`server.services.report_tables`)."""
        return {"outcome": self.word, "text": self.sentence(), **asdict(self)}

    def sentence(self) -> str:
        """``nominal: all 6190 commands executed at their tags`` or ``degraded: 393 of 6190
        commands expired, 2 rejected``."""
        if self.total == 0:
            return "nominal: no commands"
        if self.word == "nominal":
            return f"nominal: all {self.total} commands executed at their tags"
        counts = [
            (n, what)
            for n, what in (
                (self.expired, "expired"),
                (self.late, "executed late"),
                (self.rejected, "rejected"),
                (self.cancelled, "cancelled"),
                (self.unresolved, "unresolved"),
            )
            if n
        ]
        (n, what), *rest = counts
        first = f"{n} of {self.total} commands {what}"
        return "degraded: " + ", ".join([first, *(f"{m} {w}" for m, w in rest)])


def command_outcome(session: Session, pass_id: str) -> CommandOutcome:
    """The outcome of the pass's commands as the archive has them now."""
    cmd = CommandRecord
    key = repo.get_pass(session=session, pass_id=pass_id).id
    stages = dict(
        session.execute(
            select(cmd.stage, func.count()).where(cmd.pass_id == key).group_by(cmd.stage)
        ).all()
    )
    at_tag = session.scalar(
        select(func.count()).where(
            cmd.pass_id == key, cmd.stage == "executed", cmd.executed_at_ns == cmd.execute_time_ns
        )
    )
    executed, at_tag = int(stages.get("executed", 0)), int(at_tag or 0)
    return CommandOutcome(
        total=int(sum(stages.values())),
        executed_at_tag=at_tag,
        late=executed - at_tag,
        expired=int(stages.get("expired", 0)),
        rejected=int(stages.get("rejected", 0)),
        cancelled=int(stages.get("cancelled", 0)),
        unresolved=int(sum(stages.get(s, 0) for s in OPEN_STAGES)),
    )


def _expected_seqs(
    session: Session, pass_id: str, start_ns: int | None, end_ns: int | None
) -> tuple[int, int] | None:
    """The first and last frame seq of the window, or None when no frame says the rate."""
    frame = TelemetryFrameRecord
    lo_seq, hi_seq, lo_ns, hi_ns = session.execute(
        select(
            func.min(frame.seq),
            func.max(frame.seq),
            func.min(frame.generation_time_ns),
            func.max(frame.generation_time_ns),
        ).where(frame.pass_id == pass_id)
    ).one()
    if lo_seq is None:
        return None
    first, last = int(lo_seq), int(hi_seq)
    if hi_seq > lo_seq:
        period_ns = (hi_ns - lo_ns) / (hi_seq - lo_seq)
        if start_ns is not None:
            first -= max(0, math.floor((lo_ns - start_ns) / period_ns + 1e-6))
        if end_ns is not None:
            last += max(0, math.ceil((end_ns - hi_ns) / period_ns - 1e-6) - 1)
    return first, last


def pass_summary(
    *, session: Session, pass_id: str, duplicates_dropped: int = 0
) -> PassSummaryPublic:
    record = repo.get_pass(session=session, pass_id=pass_id)
    key = record.id
    seqs = repo.frame_seqs(session=session, pass_id=key)
    rows = repo.count_frames(session=session, pass_id=key)
    span = _expected_seqs(session, key, record.telemetry_start_ns, record.telemetry_end_ns)
    expected = missing = gaps = None
    if span is not None:
        first, last = span
        expected = last - first + 1
        inside = [s for s in seqs if first <= s <= last]
        missing = expected - len(inside)
        gaps = 0
        previous = first - 1
        for seq in [*inside, last + 1]:
            if seq > previous + 1:
                gaps += 1
            previous = seq
    cmd = CommandRecord
    outcome = command_outcome(session, key)
    rejected = dict(
        session.execute(
            select(cmd.reject_reason, func.count())
            .where(cmd.pass_id == key, cmd.stage == "rejected")
            .group_by(cmd.reject_reason)
        ).all()
    )
    sent = session.scalar(
        select(func.count()).where(cmd.pass_id == key, cmd.sent_at_ns.is_not(None))
    )
    retransmitted = session.scalar(
        select(func.count()).where(cmd.pass_id == key, cmd.transmissions > 1)
    )
    outstanding = session.scalar(
        select(func.count()).where(cmd.pass_id == key, cmd.stage.in_(AWAITING_ACK_STAGES))
    )
    # how far ahead of its tag the vehicle had each command (onboard ns): the uplink's margin
    lead_ns = session.scalar(
        select(func.min(cmd.execute_time_ns - cmd.received_at_ns)).where(
            cmd.pass_id == key, cmd.received_at_ns.is_not(None)
        )
    )
    return PassSummaryPublic(
        pass_id=key,
        name=record.name,
        state=record.state,
        state_reason=record.state_reason,
        epoch_ns=record.epoch_ns,
        telemetry_start_ns=record.telemetry_start_ns,
        telemetry_end_ns=record.telemetry_end_ns,
        frames_expected=expected,
        frames_stored=len(seqs),
        frames_missing=missing,
        gaps_open=gaps,
        duplicates_stored=rows - len(seqs),
        duplicates_dropped=duplicates_dropped,
        commands_total=outcome.total,
        commands_sent=sent or 0,
        commands_executed=outcome.executed_at_tag + outcome.late,
        commands_executed_at_tag=outcome.executed_at_tag,
        commands_executed_late=outcome.late,
        commands_rejected={str(k): int(v) for k, v in rejected.items()},
        commands_expired=outcome.expired,
        commands_cancelled=outcome.cancelled,
        commands_retransmitted=retransmitted or 0,
        min_command_lead_s=None if lead_ns is None else lead_ns / 1e9,
        commands_outstanding=outstanding or 0,
        commands_unresolved=outcome.unresolved,
        outcome=outcome.word if record.state in ENDED_STATES else None,
        outcome_text=outcome.sentence() if record.state in ENDED_STATES else None,
    )
