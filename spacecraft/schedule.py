"""The onboard schedule's bookkeeping: the commands received, their acknowledgements, the
onboard rules a command must pass to be queued, and ``schedule_delete`` (SPEC section 6,
docs/spacecraft.md).

:class:`OnboardSchedule` holds the queue (:class:`spacecraft._buffer.CommandBuffer`) and
what the vehicle has said of every seq; :class:`spacecraft.vehicle.Vehicle` owns one, tells
it the onboard time and whether it is safe, and executes what it queues. The rules:

- **Retransmission.** The ground sends each command until it is acknowledged, so copies
  arrive, also out of order. A seq received before *with identical content* is answered with
  that command's latest acknowledgement (:meth:`~OnboardSchedule.outcome`: received,
  executed or rejected) and has no other effect; a different command under a seq already
  used is ``duplicate`` and has no effect either.
- **Acceptance** (:meth:`~OnboardSchedule.receive`, in this order): a command that a
  ``schedule_delete`` barrier covers (tag at or after its ``from_time_ns``, seq at most its
  ``max_seq``) is ``cancelled``; a tag off the step grid, an attitude target whose
  norm is not 1 (within 1e-3), or a joint command for a tag that a queued joint command
  already holds is ``malformed`` (attitude commands may share a tag: they execute in seq
  order); a tag at or before the onboard time is ``late`` (never executed); a joint
  angle beyond +-170 deg, or a move faster than 3 deg/s from the queued joint command
  before it (or, with none, from the current servo target, starting now) or to the queued
  one after it, is ``out_of_limits``; a command that passes all this while the schedule holds
  ``schedule_capacity`` commands is ``schedule_full``. That refusal alone is transient: the
  seq is not recorded, and a later copy is checked afresh.
- **Schedule delete** (:meth:`~OnboardSchedule.delete`, PUS 11): every queued command (joint
  and attitude) tagged at or after ``from_time_ns`` with seq at most ``max_seq`` is deleted
  (its outcome becomes ``cancelled``), and a barrier refuses such commands arriving later.
  The vehicle's target then ramps to the first joint command left, or holds where it stands.
  A repeated ``request_id`` is answered with the first report and does nothing.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from planner.model import RobotModel
from spacecraft._buffer import CommandBuffer
from spacecraft.vehicle_config import QUAT_NORM_TOLERANCE
from telemetry.wire import (
    AcsCommandMsg,
    BufferState,
    CommandAck,
    CommandStage,
    JointCommandMsg,
    RejectReason,
    ScheduleDelete,
    Verification,
)

__all__ = ["OnboardSchedule", "reject"]

Array = NDArray[np.float64]

# Rates are compared with the limit with this relative slack (plans sit at 0.9 of it; the
# slack only absorbs rounding).
_RATE_SLACK = 1e-9
#: At most this many seq ranges in a ``verification`` (telemetry.wire.Verification).
_MAX_RANGES = 1000


def reject(seq: int, now: int, reason: RejectReason, detail: str) -> CommandAck:
    """The ``rejected`` acknowledgement of command ``seq`` at onboard ``now``."""
    return CommandAck(
        seq=seq,
        stage=CommandStage.REJECTED,
        reason=reason,
        detail=detail[:300],
        onboard_time_ns=now,
    )


class OnboardSchedule:
    """The commands queued and what was said of every seq received (see the module doc)."""

    def __init__(self, model: RobotModel, *, epoch_ns: int, step_ns: int, capacity: int) -> None:
        self._model = model
        self._epoch_ns = epoch_ns
        self._step_ns = step_ns
        self._capacity = capacity
        self.buffer = CommandBuffer()
        #: seq -> the command first received under it (any refusal but ``schedule_full``
        #: records it): a copy is recognised by its content.
        self._received: dict[int, JointCommandMsg | AcsCommandMsg] = {}
        #: seq -> the latest acknowledgement of every command received (a duplicate's
        #: rejection never replaces its original's), for ``command_query`` and copies.
        self._outcomes: dict[int, CommandAck] = {}
        #: request_id -> the report of every ``schedule_delete`` carried out, and the
        #: barriers they left: (from_time_ns, max_seq, request_id).
        self._deletions: dict[int, Verification] = {}
        self._barriers: list[tuple[int, int, int]] = []
        #: The highest command seq received, accepted or not (-1 before the first).
        self.last_command_seq = -1
        self.last_executed_seq = -1

    def outcome(self, seq: int) -> CommandAck | None:
        """The latest acknowledgement of command ``seq`` (None: never received)."""
        return self._outcomes.get(seq)

    def state(self) -> BufferState:
        """The schedule's summary that every telemetry frame carries."""
        return BufferState(
            queued=len(self.buffer),
            next_execute_time_ns=self.buffer.next_tag_ns(),
            last_executed_seq=self.last_executed_seq,
            last_queued_time_ns=self.buffer.last_tag_ns(),
            capacity=self._capacity,
        )

    def receive(
        self,
        cmd: JointCommandMsg | AcsCommandMsg,
        now: int,
        *,
        refusal: str | None,
        target_at: Callable[[int], Array],
    ) -> tuple[CommandAck, bool]:
        """Check a command against the onboard rules at onboard ``now`` and queue it:
        ``received``, or ``rejected`` with the reason and a detail that names the value and
        the limit; and whether it was queued now. A copy of a command received before is
        answered with its latest acknowledgement. ``refusal``: why no command is accepted
        now (the vehicle is safe), or None; ``target_at``: the servo target at a time."""
        first = self._received.get(cmd.seq)
        if first is not None:
            if first.model_dump() == cmd.model_dump():
                return self._outcomes[cmd.seq], False  # a retransmission: "you have it"
            return reject(
                cmd.seq,
                now,
                RejectReason.DUPLICATE,
                f"seq {cmd.seq} was received before with other content; the first one stands",
            ), False
        self.last_command_seq = max(self.last_command_seq, cmd.seq)
        ack = self._accept(cmd, now, refusal, target_at)
        if ack.reason is not RejectReason.SCHEDULE_FULL:  # transient: not recorded
            self._received[cmd.seq] = cmd
            self._outcomes[cmd.seq] = ack
        return ack, ack.stage is CommandStage.RECEIVED

    def _accept(
        self,
        cmd: JointCommandMsg | AcsCommandMsg,
        now: int,
        refusal: str | None,
        target_at: Callable[[int], Array],
    ) -> CommandAck:
        if refusal is not None:
            return reject(cmd.seq, now, RejectReason.SAFING, refusal)
        for from_ns, max_seq, request_id in self._barriers:
            if cmd.seq <= max_seq and cmd.execute_time_ns >= from_ns:
                return reject(
                    cmd.seq,
                    now,
                    RejectReason.CANCELLED,
                    f"deleted by schedule_delete request {request_id} (tags from {from_ns}, "
                    f"seqs up to {max_seq})",
                )
        if isinstance(cmd, AcsCommandMsg):
            quat = np.array(cmd.target_quat_orbit_from_base_xyzw, dtype=np.float64)
            norm = float(np.linalg.norm(quat))
            if not abs(norm - 1.0) <= QUAT_NORM_TOLERANCE:
                return reject(
                    cmd.seq,
                    now,
                    RejectReason.MALFORMED,
                    f"target quaternion has norm {norm:.6g}, not 1 (tolerance "
                    f"{QUAT_NORM_TOLERANCE:g})",
                )
            cmd = cmd.model_copy(update={"target_quat_orbit_from_base_xyzw": list(quat / norm)})
        rejection = self._check_time(cmd, now)
        if rejection is None and isinstance(cmd, JointCommandMsg):
            rejection = self._check_joints(cmd, now, target_at)
        if rejection is not None:
            return reject(cmd.seq, now, *rejection)
        if len(self.buffer) >= self._capacity:
            return reject(
                cmd.seq,
                now,
                RejectReason.SCHEDULE_FULL,
                f"the schedule holds {len(self.buffer)} commands, its capacity "
                f"{self._capacity}; send it again when commands have executed",
            )
        self.buffer.add(cmd)
        return CommandAck(seq=cmd.seq, stage=CommandStage.RECEIVED, onboard_time_ns=now)

    def _check_time(
        self, cmd: JointCommandMsg | AcsCommandMsg, now: int
    ) -> tuple[RejectReason, str] | None:
        tag = cmd.execute_time_ns
        off = (tag - self._epoch_ns) % self._step_ns
        if off:
            return RejectReason.MALFORMED, (
                f"execute_time_ns {tag} is {off} ns off the onboard "
                f"{self._step_ns / 1e6:g} ms step grid (epoch {self._epoch_ns})"
            )
        if tag <= now:
            return RejectReason.LATE, (
                f"execute_time_ns {tag} is {(now - tag) / 1e9:.3f} s at or before "
                f"onboard time {now}"
            )
        other = self.buffer.joint_taken_by(tag) if isinstance(cmd, JointCommandMsg) else None
        if other is not None:
            return RejectReason.MALFORMED, (
                f"execute_time_ns {tag} already holds joint command seq {other.seq}"
            )
        return None

    def _check_joints(
        self, cmd: JointCommandMsg, now: int, target_at: Callable[[int], Array]
    ) -> tuple[RejectReason, str] | None:
        model = self._model
        if len(cmd.joints_rad) != model.n_joints:
            # The wire takes any joint count (1..MAX_JOINTS): this robot's is checked here.
            return RejectReason.MALFORMED, (
                f"joints_rad has {len(cmd.joints_rad)} values, this robot has "
                f"{model.n_joints} joints"
            )
        q = np.array(cmd.joints_rad, dtype=np.float64)
        for i, (angle, (lo, hi)) in enumerate(zip(q, model.joint_limit_rad, strict=True)):
            if angle < lo or angle > hi:
                limit = hi if angle > hi else lo
                return RejectReason.OUT_OF_LIMITS, (
                    f"joint {i + 1} at {math.degrees(angle):.3f} deg exceeds limit "
                    f"{math.degrees(limit):.3f} deg"
                )
        tag = cmd.execute_time_ns
        before, after = self.buffer.joint_neighbours(tag)
        steps: list[tuple[Array, int, str]] = []
        if before is not None:
            prev = np.array(before.joints_rad)
            steps.append((prev, tag - before.execute_time_ns, f"from seq {before.seq}"))
        else:  # it will be ramped to from where the target stands now
            steps.append((target_at(now), tag - now, "from the current target"))
        if after is not None:
            steps.append(
                (np.array(after.joints_rad), after.execute_time_ns - tag, f"to seq {after.seq}")
            )
        limits = model.joint_rate_limit_radps
        for other, dt_ns, relation in steps:
            rates = np.abs(q - other) / (dt_ns / 1e9)
            worst = int(np.argmax(rates / limits))
            if rates[worst] > limits[worst] * (1.0 + _RATE_SLACK):
                return RejectReason.OUT_OF_LIMITS, (
                    f"joint {worst + 1} moves {math.degrees(abs(q[worst] - other[worst])):.3f} "
                    f"deg in {dt_ns / 1e9:.3f} s {relation}: "
                    f"{math.degrees(rates[worst]):.3f} deg/s exceeds limit "
                    f"{math.degrees(limits[worst]):.3f} deg/s"
                )
        return None

    def executed(self, seq: int, t: int) -> CommandAck:
        """Command ``seq`` executed at its tag ``t``: its ``executed`` acknowledgement."""
        self.last_executed_seq = seq
        ack = CommandAck(seq=seq, stage=CommandStage.EXECUTED, onboard_time_ns=t)
        self._outcomes[seq] = ack
        return ack

    def drop_all(self, now: int, reason: RejectReason, detail: str) -> list[CommandAck]:
        """Every queued command refused (``reason``): their acknowledgements."""
        return self._refuse(self.buffer.pop_where(lambda _: True), now, reason, detail)

    def drop_joints(self, now: int, reason: RejectReason, detail: str) -> list[CommandAck]:
        """Every queued joint command refused (``reason``): their acknowledgements."""
        return self._refuse(self.buffer.pop_joints(), now, reason, detail)

    def _refuse(
        self,
        commands: Sequence[JointCommandMsg | AcsCommandMsg],
        now: int,
        reason: RejectReason,
        detail: str,
    ) -> list[CommandAck]:
        acks = [reject(cmd.seq, now, reason, detail) for cmd in commands]
        self._outcomes.update((ack.seq, ack) for ack in acks)
        return acks

    def delete(self, req: ScheduleDelete, now: int) -> tuple[Verification, bool]:
        """PUS 11 delete by time range at onboard ``now``: every queued command tagged at
        or after ``req.from_time_ns`` with seq at most ``req.max_seq`` is deleted (outcome
        ``cancelled``), and such commands arriving later are refused ``cancelled``. The
        report counts the deleted commands, lists their seqs and counts those of the range
        that had executed already; and whether it was carried out now (a repeated
        ``request_id`` is answered with the first report)."""
        done = self._deletions.get(req.request_id)
        if done is not None:
            return done, False
        from_ns, max_seq = req.from_time_ns, req.max_seq
        executed = sum(
            1
            for ack in self._outcomes.values()
            # an executed ack's time is the command's tag
            if ack.stage is CommandStage.EXECUTED
            and ack.seq <= max_seq
            and ack.onboard_time_ns >= from_ns
        )
        deleted = self.buffer.pop_where(lambda c: c.seq <= max_seq and c.execute_time_ns >= from_ns)
        why = f"deleted by schedule_delete request {req.request_id}"
        for cmd in deleted:
            self._outcomes[cmd.seq] = reject(cmd.seq, now, RejectReason.CANCELLED, why)
        self._barriers.append((from_ns, max_seq, req.request_id))
        ranges = _ranges(sorted(cmd.seq for cmd in deleted))
        notes = []
        if from_ns <= now:
            notes.append(
                f"from_time_ns {from_ns} is at or before onboard time {now}: every queued "
                f"command up to seq {max_seq} deleted"
            )
        if len(ranges) > _MAX_RANGES:
            notes.append(f"{len(ranges)} seq ranges, the first {_MAX_RANGES} listed")
            ranges = ranges[:_MAX_RANGES]
        report = Verification(
            request_id=req.request_id,
            stage="completed",
            deleted=len(deleted),
            deleted_ranges=ranges,
            executed_after_from=executed,
            detail="; ".join(notes)[:300] or None,
            onboard_time_ns=now,
        )
        self._deletions[req.request_id] = report
        return report, True


def _ranges(seqs: list[int]) -> list[tuple[int, int]]:
    """Sorted seqs as inclusive ranges of consecutive seqs."""
    out: list[tuple[int, int]] = []
    for seq in seqs:
        if out and seq == out[-1][1] + 1:
            out[-1] = (out[-1][0], seq)
        else:
            out.append((seq, seq))
    return out
