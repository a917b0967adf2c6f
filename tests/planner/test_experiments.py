"""Experiment 1 (PTP baseline, reactionless), servo-lag compensation and experiment 3."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from planner.attitude_control import AcsMode, default_acs_gains
from planner.closed_loop import fly
from planner.coordination import (
    CoordinationParams,
    closed_loop_metrics,
    optimise_offset,
    plan_coordination,
)
from planner.dynamics import DynamicsWorkspace
from planner.errors import InvalidInput, JointLimitExceeded
from planner.experiments import (
    PtpParams,
    ReactionlessParams,
    joints_at_pose_b,
    plan_ptp,
    plan_reactionless,
)
from planner.frames import matrix_from_rpy
from planner.plan import Plan, check_plan_limits
from planner.prediction import predict
from planner.reactionless import reactionless_line
from planner.reactionless_search import search_reactionless_path
from planner.simulation import FreeFloatingSimulator, follow_commands
from planner.state import State


def _attitude_change_deg(quats: np.ndarray) -> np.ndarray:
    return np.degrees(Rotation.from_quat(quats).magnitude())


def _free_drift_change_deg(ws: DynamicsWorkspace, plan: Plan) -> float:
    """Ideal tracking of the plan's commands with the wheels off (no help from the ACS)."""
    free = predict(ws, plan.command_times_s, plan.command_joints_rad)
    return float(np.max(_attitude_change_deg(free.quat_orbit_from_base_xyzw)))


@pytest.fixture(scope="module")
def ws() -> DynamicsWorkspace:
    from planner.model import default_model

    return DynamicsWorkspace(default_model())


@pytest.fixture(scope="module")
def reactionless(ws: DynamicsWorkspace) -> Plan:
    return plan_reactionless(ws)


def test_ptp_baseline_turns_the_base_by_degrees(ws: DynamicsWorkspace) -> None:
    plan = plan_ptp(ws)
    check_plan_limits(ws.model, plan)
    np.testing.assert_allclose(np.diff(plan.command_times_s), 0.25, rtol=0, atol=0)
    assert _free_drift_change_deg(ws, plan) > 1.0  # "changes it by degrees"
    # with feedback on, the base comes back, but only after a settling wait
    assert plan.metrics["peak_attitude_deg"] > 0.2
    assert plan.metrics["settling_time_after_motion_s"] > 30.0
    # The calibrated law (docs/spacecraft.md) brings it back within the planner's 0.05 deg
    # band 107 s after the motion and leaves it 0.036 deg off at the end of the 120 s wait,
    # inside its 0.035 deg dead band and gravity gradient's push.
    assert plan.metrics["final_attitude_deg"] < 0.1


def test_reactionless_plan_leaves_the_base_still(ws: DynamicsWorkspace, reactionless: Plan) -> None:
    plan = reactionless
    check_plan_limits(ws.model, plan)
    np.testing.assert_allclose(np.diff(plan.command_times_s), 0.25, rtol=0, atol=0)
    # The criterion, with the wheels off so that nothing hides a reaction.
    assert _free_drift_change_deg(ws, plan) < 0.01
    # ... against a PTP motion between the same two poses, which turns it by a degree.
    c_joints = plan.command_joints_rad[round(plan.segment("B->C").t_end_s / 0.25)]
    ptp = plan_ptp(
        ws,
        PtpParams(
            start_joints_deg=tuple(np.degrees(plan.initial_joints_rad)),
            goal_joints_deg=tuple(np.degrees(c_joints)),
            settle_s=0.0,
        ),
    )
    assert _free_drift_change_deg(ws, ptp) > 100 * _free_drift_change_deg(ws, plan)
    # about 0.35 m up at 0.015 m/s, and back to B's joints exactly (the path is retraced)
    assert plan.metrics["hand_travel_m"] == pytest.approx(0.35, abs=0.01)
    np.testing.assert_array_equal(plan.command_joints_rad[-1], plan.initial_joints_rad)
    assert plan.metrics["back_duration_s"] == pytest.approx(
        2 * plan.metrics["out_duration_s"], abs=0.5
    )
    # the constraint costs hand orientation; the plan says how much
    assert 1.0 < plan.metrics["hand_orientation_change_max_deg"] < 30.0


def test_reactionless_faster_leg_leaves_the_larger_residual_in_flight(
    ws: DynamicsWorkspace, reactionless: Plan
) -> None:
    """The joints' different lags (planner.simulation.ETS7_SERVO_LAG_S) bend the path off
    the null space by an amount proportional to the speed: the base steps by it within a few
    seconds as a leg starts or stops. Measured as the largest attitude change within 5 s (as
    telemetry.analysis.reaction does): the wheels' correction, which builds over tens of
    seconds and is the same for both speeds, is left out."""
    gains = default_acs_gains(ws)
    flown = fly(
        ws,
        reactionless.command_times_s,
        reactionless.command_joints_rad,
        acs_commands=reactionless.acs_commands,
        acs_gains=gains,
    )
    rotvec = Rotation.from_quat(flown.quat_orbit_from_base_xyzw).as_rotvec()
    span = round(5.0 / 0.1)  # samples every 0.1 s
    step_deg = np.degrees(np.linalg.norm(rotvec[span:] - rotvec[:-span], axis=1))
    t_end = flown.t_s[span:]

    def peak(segment: str) -> float:
        seg = reactionless.segment(segment)
        return float(np.max(step_deg[(t_end >= seg.t_start_s) & (t_end <= seg.t_end_s + 10)]))

    peak_out, peak_back = peak("B->C"), peak("C->B")
    # Measured 0.0074 against 0.0034 deg (one 0.3 s lag on every joint: 6e-4 against 2e-4).
    assert peak_out < 0.02  # the lagging servos leave a small residual ...
    assert peak_out > 1.7 * peak_back  # ... that grows with speed (SPEC 3.1)


def test_servo_lag_compensation_shrinks_the_residual_reaction(
    ws: DynamicsWorkspace, reactionless: Plan
) -> None:
    compensated = plan_reactionless(ws, ReactionlessParams(compensate_servo_lag=True))
    peaks = []
    tracking = []
    for plan in (reactionless, compensated):
        sim = FreeFloatingSimulator(ws.model, State(joints_rad=plan.command_joints_rad[0]))
        flown = follow_commands(
            sim, plan.command_times_s, plan.command_joints_rad, end_time_s=plan.duration_s
        )
        peaks.append(np.max(_attitude_change_deg(flown.quat_orbit_from_base_xyzw)))
        desired = np.column_stack(
            [
                np.interp(
                    flown.t_s, reactionless.command_times_s, reactionless.command_joints_rad[:, i]
                )
                for i in range(6)
            ]
        )
        tracking.append(np.degrees(np.max(np.abs(flown.joints_rad - desired))))
    plain_deg, shaped_deg = peaks
    # measured: 6.1e-3 deg -> 1.3e-4 deg, joint tracking 0.94 deg -> 0.015 deg, with the
    # joints' own lags (planner.simulation.ETS7_SERVO_LAG_S; one 0.3 s lag on every joint:
    # 6.0e-4 -> 0.8e-4 deg, 0.68 -> 0.014 deg)
    assert shaped_deg < plain_deg / 10.0  # the compensation reads each joint's own lag
    assert tracking[1] < tracking[0] / 10.0


def test_reactionless_refuses_motion_past_a_joint_limit(ws: DynamicsWorkspace) -> None:
    with pytest.raises(JointLimitExceeded, match=r"exceeds limit 170\.000 deg"):
        reactionless_line(
            ws,
            np.radians([31.6, 21.4, -8.8, 165.0, 0.0, 68.6]),
            direction_robot=np.array([0.0, 0.0, 1.0]),
            distance_m=0.35,
            speed_mps=0.015,
        )
    with pytest.raises(InvalidInput):
        plan_reactionless(ws, ReactionlessParams(out_speed_mps=0.0))


def test_search_for_a_reactionless_path_from_a_to_b_reports_honestly(
    ws: DynamicsWorkspace,
) -> None:
    goal_rot = matrix_from_rpy(np.radians([0.0, 90.0, -37.0]))
    goal_pos = np.array([1.170, 0.407, 0.490])
    result = search_reactionless_path(ws, np.zeros(6), goal_pos, goal_rot)
    # SPEC 3.1: no continuous reactionless path from A to B within the joint ranges was found
    # in flight planning; ours stops short too and says why.
    assert not result.reached
    assert result.reason
    start_distance = np.linalg.norm(goal_pos - np.array([1.162, -0.267, 1.497]))
    assert result.best_position_error_m < start_distance  # it did get closer
    # and every step stayed in the null space
    free = predict(ws, np.arange(result.joints_rad.shape[0]) * 0.25, result.joints_rad)
    assert np.max(_attitude_change_deg(free.quat_orbit_from_base_xyzw)) < 0.01
    assert joints_at_pose_b(ws).shape == (6,)


@pytest.fixture(scope="module")
def coordination(ws: DynamicsWorkspace) -> Plan:
    return plan_coordination(ws)


def test_coordination_plan_has_three_variants_with_their_attitude_commands(
    ws: DynamicsWorkspace, coordination: Plan
) -> None:
    plan = coordination
    check_plan_limits(ws.model, plan)
    kinds = [s.name for s in plan.segments if s.kind == "coordination"]
    assert len(kinds) == 6  # forward and back for (a), (b), (c)
    assert any(c.feedforward for c in plan.acs_commands)
    targets = [
        c
        for c in plan.acs_commands
        if not np.allclose(c.target_quat_orbit_from_base_xyzw, [0, 0, 0, 1])
    ]
    # (c): one offset over the whole back-and-forth motion (the flight's one switch on,
    # one off), on 0.5 s after the forward leg starts, off 0.5 s after the back leg stops
    (offset,) = targets
    forward_c, back_c = plan.segment("(c) offset: forward"), plan.segment("(c) offset: back")
    assert offset.t_s == pytest.approx(forward_c.t_start_s + 0.5)
    resets = [c for c in plan.acs_commands if c.t_s > offset.t_s]
    assert [c.t_s for c in resets] == [pytest.approx(back_c.t_end_s + 0.5)]
    assert all(c.mode is AcsMode.FEEDBACK for c in plan.acs_commands)
    # the forward leg's eq. (10) offset pitches the base down, the backward leg's up
    assert plan.metrics["offset_forward_pitch_deg"] < -0.1
    assert plan.metrics["offset_back_pitch_deg"] == pytest.approx(
        -plan.metrics["offset_forward_pitch_deg"], rel=0.05
    )
    # hand 0.2 m forward along x and back, orientation held
    forward = plan.segment("(a) feedback: forward")
    k = round(forward.t_end_s / 0.25)
    hand0 = ws.hand_pose(State(joints_rad=plan.command_joints_rad[0]))
    hand1 = ws.hand_pose(State(joints_rad=plan.command_joints_rad[k]))
    np.testing.assert_allclose(hand1.pos_robot_m - hand0.pos_robot_m, [0.2, 0, 0], atol=1e-3)


def test_offset_window_per_leg_and_refused_names(ws: DynamicsWorkspace) -> None:
    """``offset_window="leg"``: each leg its own offset (the forward leg's down, the back
    leg's up), each switched off after its leg or replaced by the next leg's; an unknown
    window is refused by name."""
    plan = plan_coordination(
        ws, CoordinationParams(variants=("offset",), offset_window="leg", settle_s=10.0)
    )
    targets = [
        c
        for c in plan.acs_commands
        if not np.allclose(c.target_quat_orbit_from_base_xyzw, [0, 0, 0, 1])
    ]
    assert len(targets) == 2
    pitches = [
        Rotation.from_quat(c.target_quat_orbit_from_base_xyzw).as_euler("ZYX", degrees=True)[1]
        for c in targets
    ]
    assert pitches[0] < -0.3 and pitches[1] > 0.3
    forward, back = plan.segment("(c) offset: forward"), plan.segment("(c) offset: back")
    resets = [c.t_s for c in plan.acs_commands if c not in targets and c.t_s > 0.0]
    # with no pause the forward leg's off and the back leg's on fall together: the back
    # leg's target replaces the forward leg's, and nominal comes back after the back leg
    assert targets[1].t_s == pytest.approx(forward.t_end_s + 0.5)
    assert resets == [pytest.approx(back.t_end_s + 0.5)]
    paused = plan_coordination(
        ws,
        CoordinationParams(variants=("offset",), offset_window="leg", pause_s=5.0, settle_s=10.0),
    )
    forward, back = paused.segment("(c) offset: forward"), paused.segment("(c) offset: back")
    assert [c.t_s for c in paused.acs_commands[1:]] == [
        pytest.approx(forward.t_start_s + 0.5),
        pytest.approx(forward.t_end_s + 0.5),
        pytest.approx(back.t_start_s + 0.5),
        pytest.approx(back.t_end_s + 0.5),
    ]
    # An off delay longer than the on delay, with no pause: the back leg's offset replaces
    # the forward leg's (going back to nominal in between would cancel the back leg's)
    forward, back = plan.segment("(c) offset: forward"), plan.segment("(c) offset: back")
    late = plan_coordination(
        ws,
        CoordinationParams(
            variants=("offset",), offset_window="leg", offset_off_delay_s=5.0, settle_s=10.0
        ),
    )
    switches = [(c.t_s, c.target_quat_orbit_from_base_xyzw) for c in late.acs_commands[1:]]
    assert [t for t, _ in switches] == [
        pytest.approx(forward.t_start_s + 0.5),
        pytest.approx(back.t_start_s + 0.5),
        pytest.approx(back.t_end_s + 5.0),
    ]
    assert np.allclose(switches[-1][1], [0, 0, 0, 1])
    assert not np.allclose(switches[1][1], [0, 0, 0, 1])
    with pytest.raises(InvalidInput, match="offset_window = 'legs' must be one of"):
        plan_coordination(ws, CoordinationParams(offset_window="legs"))


def test_feedforward_answers_the_start_fast_then_overshoots_as_in_flight(
    coordination: Plan,
) -> None:
    """Experiment 3b under ideal tracking (paper 3.5, Fig. 9). The feedforward is the flight's
    angular-velocity type (planner.attitude_control), no longer an ideal momentum
    cancellation, so this asserts what the flight showed instead of "beats feedback": a
    smaller first dip than feedback alone, then a recovery that adds to the deceleration
    reaction and overshoots positive, a wider range than feedback alone."""
    pitch = np.degrees(coordination.prediction.rpy_base_rad[:, 1])
    t = coordination.command_times_s

    def dip_and_peak(label: str, variant: str) -> tuple[float, float]:
        forward = coordination.segment(f"{label} {variant}: forward")
        settle = coordination.segment(f"{label} settle")
        leg = (t >= forward.t_start_s) & (t <= forward.t_end_s)
        window = (t >= forward.t_start_s) & (t <= settle.t_end_s)
        return float(np.min(pitch[leg])), float(np.max(pitch[window]))

    fb_dip, fb_peak = dip_and_peak("(a)", "feedback")
    ff_dip, ff_peak = dip_and_peak("(b)", "feedforward")
    # measured with the calibrated law: dips -0.36 (a) and -0.27 (b) deg (flight: -0.5 and
    # "within -0.3"); peaks +0.49 and +0.69 deg
    assert fb_dip < -0.3
    # the feedforward answers the start reaction faster, within the flight's -0.3 deg ...
    assert ff_dip > -0.3 and ff_dip > fb_dip + 0.05
    assert ff_peak > fb_peak + 0.15  # ... and then overshoots strongly
    m = coordination.metrics
    assert m["predicted_feedforward_pitch_range_deg"] > m["predicted_feedback_pitch_range_deg"]


@pytest.mark.slow
def test_optimised_offset_beats_the_unoptimised_rule_in_the_closed_loop(
    ws: DynamicsWorkspace,
) -> None:
    # Calibrated wheel law (docs/spacecraft.md), the offset held over the whole back-and-forth
    # motion; a 150 s window and a second of settling worth 0.006 deg of range. Measured with
    # 12 evaluations (each a closed-loop flight of the motion): the best is 1.06 Omega_b (-0.60
    # deg), on 4.6 s after the start and off at the stop: range 0.54 deg against the paper's
    # rule's 0.56 (1 Omega_b, 0.5 s) and feedback's 0.85, settling in 102.0 s against 102.5 s
    # and 119.1 s (objective 1.150 against 1.178). With 20 evaluations the search goes on to
    # 1.17 Omega_b, on 14.5 s: range 0.47 deg (1.086); bench/bench_planners.py runs 30.
    weight = 0.006
    params = CoordinationParams(settle_s=150.0)
    optimum = optimise_offset(ws, params, max_evaluations=12, settle_weight_deg_per_s=weight)
    objective = optimum.pitch_range_deg + weight * optimum.settling_time_s
    baseline = optimum.paper_rule_pitch_range_deg + weight * optimum.paper_rule_settling_time_s
    assert objective < baseline
    feedback = closed_loop_metrics(ws, params, "feedback")
    assert optimum.pitch_range_deg < feedback["pitch_range_deg"] - 0.1
    assert -1.5 < optimum.offset_forward_pitch_deg < 0.0
