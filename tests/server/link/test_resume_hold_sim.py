"""A ground back after more than the lead window, in simulated time: it never uplinks a jump
the vehicle must refuse. A gap in the motion holds the rest of it (cancelled, with the
reason) and the pass ends ``complete, degraded``; a gap in a holding segment, or a restart
shorter than the lead window, resumes as nominal.

The rule: server/services/continuity.py (docs/protocol.md, "Resuming after a gap"). The
vehicle here refuses a joint command as the real one does (spacecraft/schedule.py): a move
faster than its rate limit from the queued joint command before it (with none, from where
its target stands now) or to the one after it is ``out_of_limits``.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from server.services import continuity
from server.services.clock import ManualClock
from server.services.continuity import hold_after_gap
from server.services.summary import pass_summary
from server.storage import repository as repo
from telemetry.wire import CommandAck, CommandStage, JointCommandMsg, RejectReason, decode_ground
from tests.server.link.harness import add_plan_and_pass
from tests.server.link.simulated import (
    Ground,
    SimulatedSpacecraft,
    commands,
    ground,
    make_sessions,
    pass_state,
    simulated,
)
from tests.server.storage.factories import make_plan

#: The vehicle's joint rate limit (docs/protocol.md, "The onboard schedule": 3 deg/s).
RATE_LIMIT_RADPS = math.radians(3.0)
#: 0.57 deg/s: a 30 s gap leaves the plan 17 deg from the pose the vehicle holds.
MOTION_RAD = 1.0
N_COMMANDS = 400  # 100 s at 4 Hz
LEAD_S = 10.0


class RateLimitedSpacecraft(SimulatedSpacecraft):
    """The simulated vehicle, refusing joint moves faster than its rate limit."""

    def _target_rad(self, now_ns: int) -> np.ndarray:
        """Where the servo target stands: the last joint command executed (the plan's start
        before any), ramping to the first queued one."""
        v = self.vehicle
        done = [s for s in v.executed if isinstance(self.sent_joints.get(s), JointCommandMsg)]
        last = max(done, key=lambda s: v.executed[s][-1], default=None)
        q0 = np.zeros(6) if last is None else np.array(self.sent_joints[last].joints_rad)
        t0 = now_ns if last is None else v.executed[last][-1]
        queued = sorted(
            (c.execute_time_ns, c.seq)
            for c in v.schedule.values()
            if isinstance(c, JointCommandMsg)
        )
        if not queued or last is None:
            return q0
        tag, seq = queued[0]
        q1 = np.array(self.sent_joints[seq].joints_rad)
        return np.asarray(q0 + (q1 - q0) * min(1.0, (now_ns - t0) / (tag - t0)), dtype=float)

    def _too_fast(self, cmd: JointCommandMsg, now_ns: int) -> bool:
        joints = [c for c in self.vehicle.schedule.values() if isinstance(c, JointCommandMsg)]
        before = [c for c in joints if c.execute_time_ns < cmd.execute_time_ns]
        after = [c for c in joints if c.execute_time_ns > cmd.execute_time_ns]
        q = np.array(cmd.joints_rad)
        steps = []
        if before:
            prev = max(before, key=lambda c: c.execute_time_ns)
            steps.append((np.array(prev.joints_rad), cmd.execute_time_ns - prev.execute_time_ns))
        else:
            steps.append((self._target_rad(now_ns), cmd.execute_time_ns - now_ns))
        if after:
            nxt = min(after, key=lambda c: c.execute_time_ns)
            steps.append((np.array(nxt.joints_rad), nxt.execute_time_ns - cmd.execute_time_ns))
        return any(
            dt_ns > 0 and float(np.max(np.abs(q - other))) / (dt_ns / 1e9) > RATE_LIMIT_RADPS
            for other, dt_ns in steps
        )

    def _receive(self, text: str, now_ns: int) -> None:
        if not hasattr(self, "sent_joints"):
            self.sent_joints: dict[int, JointCommandMsg] = {}
        message = decode_ground(text)
        v = self.vehicle
        if isinstance(message, JointCommandMsg) and message.seq not in v.contents:
            self.sent_joints[message.seq] = message
            late = message.execute_time_ns <= now_ns
            if not late and v.barrier is None and self._too_fast(message, now_ns):
                self._execute_until(now_ns)
                v.contents[message.seq] = message.model_dump()
                ack = CommandAck(
                    seq=message.seq,
                    stage=CommandStage.REJECTED,
                    reason=RejectReason.OUT_OF_LIMITS,
                    onboard_time_ns=now_ns,
                )
                v.outcomes[message.seq] = ack
                self._ack(ack)
                return
        super()._receive(text, now_ns)


def _plan(hold_after: int | None = None) -> Any:
    """400 joint commands moving every joint by :data:`MOTION_RAD` (or, with ``hold_after``,
    moving that many and holding the last pose)."""
    plan = make_plan(N_COMMANDS)
    moving = N_COMMANDS if hold_after is None else hold_after
    ramp = np.minimum(np.arange(N_COMMANDS), moving - 1) / (N_COMMANDS - 1) * MOTION_RAD
    return dataclasses.replace(plan, command_joints_rad=ramp[:, None] * np.ones(6))


def _refused(sc: SimulatedSpacecraft) -> dict[int, str]:
    return {
        seq: ack.reason.value
        for seq, ack in sc.vehicle.outcomes.items()
        if ack.stage == CommandStage.REJECTED and ack.reason is not None
    }


async def _restart(
    tmp_path: Path, plan: Any, *, stop_at_s: float, down_s: float, lead_s: float = LEAD_S
) -> tuple[Any, str, RateLimitedSpacecraft, Ground]:
    """A pass of ``plan`` started, the ground stopped gracefully ``stop_at_s`` in, a new one
    started ``down_s`` later; run until the pass is over."""
    clock = ManualClock()
    sessions = make_sessions(tmp_path)
    first = ground(sessions, clock, uplink_lead_window_s=lead_s)
    sc = RateLimitedSpacecraft(clock, seed=4)
    await sc.connect(first)
    pass_id = add_plan_and_pass(sessions, plan, "hold", now_ns=clock.time_ns(), window_s=3600.0)
    await first.runner.start(pass_id, "otto")
    await sc.run(stop_at_s)
    await first.runner.shutdown()
    await first.link.close()
    sc.lose_ground()
    await sc.run(down_s)
    second = ground(sessions, clock, uplink_lead_window_s=lead_s)
    await second.restarted()
    await sc.connect(second)
    await sc.run(150.0)
    return sessions, pass_id, sc, second


def _stages(rows: list[Any]) -> dict[str, int]:
    out: dict[str, int] = {}
    for row in rows:
        out[row.stage] = out.get(row.stage, 0) + 1
    return out


def _as_the_vehicle_did(sc: SimulatedSpacecraft, rows: list[Any]) -> None:
    executed = sc.vehicle.executed
    for r in rows:
        if r.seq in executed:
            assert r.stage == "executed" and executed[r.seq] == [r.execute_time_ns], r.seq
        else:
            assert r.stage in ("expired", "cancelled"), (r.seq, r.stage)
            assert r.seq not in sc.vehicle.outcomes  # never on board


@simulated
async def test_a_ground_back_after_the_lead_window_mid_motion_holds_and_ends_degraded(
    tmp_path: Path,
) -> None:
    """Stopped 10 s into the pass (its first tag some 30 s after its start), loaded 10 s
    ahead, back 30 s later: the vehicle ran dry 20 s into the motion and holds there."""
    sessions, pass_id, sc, second = await _restart(tmp_path, _plan(), stop_at_s=40.0, down_s=30.0)
    assert _refused(sc) == {}  # not one jump sent: nothing out_of_limits, nothing late
    rows = commands(sessions, pass_id)
    stages = _stages(rows)
    assert pass_state(sessions, pass_id) == "complete"
    assert set(stages) == {"executed", "expired", "cancelled"}, stages
    _as_the_vehicle_did(sc, rows)
    # the vehicle flew the plan up to its last loaded command and holds that pose
    flown = sorted(r.seq for r in rows if r.stage == "executed")
    assert flown == list(range(rows[0].seq, flown[-1] + 1))
    cancelled = [r for r in rows if r.stage == "cancelled"]
    assert min(r.seq for r in cancelled) > max(r.seq for r in rows if r.stage == "expired")
    with sessions() as session:
        summary = pass_summary(session=session, pass_id=pass_id)
        reason = repo.get_pass(session=session, pass_id=pass_id).state_reason
        [event] = repo.list_events(
            session=session, pass_id=pass_id, kinds=["commands_cancelled"]
        ).items
    assert summary.outcome == "degraded" and summary.commands_unresolved == 0
    assert summary.outcome_text == (
        f"degraded: {stages['expired']} of {len(rows)} commands expired, "
        f"{stages['cancelled']} cancelled"
    )
    assert reason == f"complete, {summary.outcome_text}"
    lost = min((r for r in rows if r.stage == "expired"), key=lambda r: r.seq)
    at_s = (lost.execute_time_ns - rows[0].execute_time_ns) / 1e9
    assert event.detail["count"] == stages["cancelled"]
    assert event.detail["reason"] == (
        f"held after a restart: seq {lost.seq} (t = {at_s:.2f} s) can no longer reach the "
        f"vehicle and moves the arm; the vehicle holds the pose of seq {flown[-1]}, the rest "
        "is not sent"
    )
    assert second.runner.active_pass_id is None


@simulated
async def test_without_the_hold_the_vehicle_refuses_the_jump_and_the_pass_is_aborted(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The scenario above as it was before the hold: the check is not vacuous."""
    monkeypatch.setattr(continuity, "hold_after_gap", lambda *a, **k: None)
    sessions, pass_id, sc, _ = await _restart(tmp_path, _plan(), stop_at_s=40.0, down_s=30.0)
    assert set(_refused(sc).values()) >= {"out_of_limits"}
    assert pass_state(sessions, pass_id) == "aborted"


@simulated
async def test_a_restart_shorter_than_the_lead_window_stays_nominal(tmp_path: Path) -> None:
    sessions, pass_id, sc, _ = await _restart(
        tmp_path, _plan(), stop_at_s=40.0, down_s=15.0, lead_s=40.0
    )
    assert _refused(sc) == {}
    rows = commands(sessions, pass_id)
    assert pass_state(sessions, pass_id) == "complete"
    assert _stages(rows) == {"executed": len(rows)}
    _as_the_vehicle_did(sc, rows)
    with sessions() as session:
        reason = repo.get_pass(session=session, pass_id=pass_id).state_reason
        events = repo.list_events(session=session, pass_id=pass_id, kinds=["commands_cancelled"])
    assert reason == f"complete, nominal: all {len(rows)} commands executed at their tags"
    assert not events.items


@simulated
async def test_a_gap_in_a_holding_segment_resumes_the_pass(tmp_path: Path) -> None:
    """The motion ends 25 s into the pass (whose first tag is some 30 s after its start);
    the ground stops 40 s in and the vehicle, loaded 10 s ahead, runs dry 50 s in and holds
    the final pose, as the plan does: the lost commands only repeat it, so the rest goes up
    and executes (the lost ones expire)."""
    plan = _plan(hold_after=100)
    sessions, pass_id, sc, _ = await _restart(tmp_path, plan, stop_at_s=70.0, down_s=30.0)
    assert _refused(sc) == {}
    rows = commands(sessions, pass_id)
    stages = _stages(rows)
    assert pass_state(sessions, pass_id) == "complete"
    assert set(stages) == {"executed", "expired"} and stages["expired"] > 50, stages
    _as_the_vehicle_did(sc, rows)
    assert max(r.seq for r in rows if r.stage == "executed") == rows[-1].seq


@simulated
async def test_a_ground_back_after_the_pass_s_last_tag_expires_what_the_vehicle_never_had(
    tmp_path: Path,
) -> None:
    """Back after the last tag (the pass's LOS before the clock is confirmed): the commands
    never on board expire at once, none is left ``queued``."""
    sessions, pass_id, sc, _ = await _restart(tmp_path, _plan(), stop_at_s=40.0, down_s=150.0)
    assert _refused(sc) == {}
    rows = commands(sessions, pass_id)
    assert pass_state(sessions, pass_id) == "complete"
    assert set(_stages(rows)) == {"executed", "expired"}, _stages(rows)
    _as_the_vehicle_did(sc, rows)


def _row(seq: int, tag_s: float, joints: float | None, stage: str = "queued") -> Any:
    kind = "acs" if joints is None else "joints"
    payload = {} if joints is None else {"joints_rad": [joints] * 6}
    return SimpleNamespace(
        seq=seq, execute_time_ns=round(tag_s * 1e9), kind=kind, payload=payload, stage=stage
    )


def test_the_rule_holds_from_the_first_lost_command_that_changes_what_the_vehicle_does() -> None:
    decide = functools.partial(hold_after_gap, arrival_ns=5 * 10**9)
    # seqs 0-3 on board (0.25 s apart), now 10 s: tags up to 15 s are lost
    moving = [_row(i, i * 0.25, 0.01 * i) for i in range(80)]
    hold = decide(moving, onboard_ns=10 * 10**9, last_command_seq=3)
    assert hold is not None and (hold.held_seq, hold.break_seq) == (3, 4)
    assert hold.withheld == tuple(range(61, 80))  # tags beyond now + 5 s
    # nothing lost: the next command can still arrive (the nominal resume)
    assert decide(moving, onboard_ns=2 * 10**9, last_command_seq=30) is None
    # lost commands that repeat the held pose are harmless
    holding = [_row(i, i * 0.25, 0.03 if i >= 3 else 0.01 * i) for i in range(80)]
    assert decide(holding, onboard_ns=10 * 10**9, last_command_seq=3) is None
    # a lost attitude-control command breaks it too; so does a pose the vehicle never had
    with_acs = [*holding[:10], _row(100, 2.6, None), *holding[10:]]
    acs = decide(with_acs, onboard_ns=10 * 10**9, last_command_seq=3)
    assert acs is not None and acs.break_seq == 100 and "attitude control" in acs.reason
    none = decide(moving, onboard_ns=10 * 10**9, last_command_seq=-1)
    assert none is not None and none.held_seq is None and none.break_seq == 0
    # commands already final are not withheld again
    done = [*moving[:79], _row(79, 79 * 0.25, 0.79, stage="expired")]
    final = decide(done, onboard_ns=10 * 10**9, last_command_seq=3)
    assert final is not None and 79 not in final.withheld
