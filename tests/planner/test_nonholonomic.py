"""Experiment 4: non-holonomic end-point control by the bi-directional approach."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from planner.attitude_control import AcsMode
from planner.dynamics import DynamicsWorkspace
from planner.errors import DidNotConverge, InvalidInput, JointLimitExceeded
from planner.free_drift import predict_base_attitude
from planner.model import RobotModel
from planner.nonholonomic import (
    PAPER_PHI_MID_DEG,
    Meeting,
    NonholonomicParams,
    find_meeting,
    plan_nonholonomic,
)
from planner.plan import AcsCommand, Plan, check_plan_limits
from planner.prediction import predict
from planner.ptp import ptp_commands
from planner.simulation import (
    FreeFloatingSimulator,
    SimConfig,
    default_servo_gains,
    follow_commands,
)
from planner.state import State

PARAMS = NonholonomicParams()
PHI_INIT_RAD = np.radians(PARAMS.phi_init_deg)
PHI_END_RAD = np.radians(PARAMS.phi_end_deg)
FREE_DRIFT = (AcsCommand(0.0, AcsMode.FREE_DRIFT),)


@pytest.fixture(scope="module")
def plan(model: RobotModel) -> Plan:
    return plan_nonholonomic(DynamicsWorkspace(model), PARAMS)


@pytest.fixture(scope="module")
def meeting(model: RobotModel) -> Meeting:
    return find_meeting(DynamicsWorkspace(model), PARAMS)


def _angle_rad(quat_xyzw: np.ndarray) -> float:
    return float(Rotation.from_quat(quat_xyzw).magnitude())


def test_commands_are_on_the_4hz_grid_within_limits_from_start_to_goal(
    plan: Plan, model: RobotModel
) -> None:
    times, joints = plan.command_times_s, plan.command_joints_rad
    np.testing.assert_array_equal(times, np.arange(times.size) * 0.25)
    check_plan_limits(model, plan)
    rates_degps = np.degrees(np.abs(np.diff(joints, axis=0))) / 0.25
    # rate_fraction 0.9 of 3 deg/s; the final correction may move a path by ~1e-4 rad.
    assert rates_degps.max() < 2.7 + 0.01
    assert rates_degps.max() > 2.0  # and the re-timing does use the rate it has
    np.testing.assert_array_equal(joints[0], PHI_INIT_RAD)
    np.testing.assert_array_equal(plan.initial_joints_rad, PHI_INIT_RAD)
    np.testing.assert_array_equal(joints[-1], PHI_END_RAD)
    assert [(s.name, s.kind) for s in plan.segments] == [
        ("lead", "hold"),
        ("forward", "nonholonomic"),
        ("backward", "nonholonomic"),
        ("tail", "hold"),
    ]
    # Smooth start and stop of each path (quintic): the first and last 0.25 s of a path move
    # at under 2 % of the rate limit; the arm stops at the meeting point.
    for name in ("forward", "backward"):
        seg = plan.segment(name)
        first, last = round(seg.t_start_s / 0.25), round(seg.t_end_s / 0.25)
        assert rates_degps[first].max() < 0.06 and rates_degps[last - 1].max() < 0.06
        assert rates_degps[first : last - 1].max() > 2.0
    assert plan.metrics["duration_s"] == times[-1]


def test_prediction_ends_at_the_goal_after_steering_the_attitude(
    plan: Plan, workspace: DynamicsWorkspace
) -> None:
    prediction = plan.prediction
    rpy_end_deg = np.degrees(prediction.rpy_base_rad[-1])
    assert np.all(np.abs(rpy_end_deg) < 0.05)  # issue acceptance, per axis
    assert np.max(np.abs(np.degrees(prediction.joints_rad[-1] - PHI_END_RAD))) < 0.01
    # The planner's own target: the 4 Hz sequence ends within attitude_tolerance_rad.
    assert _angle_rad(prediction.quat_orbit_from_base_xyzw[-1]) < PARAMS.attitude_tolerance_rad
    # An independent integrator (eq. 10, planner.free_drift) agrees.
    quats, _ = predict_base_attitude(workspace, plan.command_times_s, plan.command_joints_rad)
    assert _angle_rad(quats[-1]) < PARAMS.attitude_tolerance_rad
    # The attitude was steered, not left alone: mid-plan the base turned by 0.60 deg on this
    # model (our loops are smaller than the flight's), 4 times the straight path's residual.
    peak_deg = max(math.degrees(_angle_rad(q)) for q in prediction.quat_orbit_from_base_xyzw)
    assert peak_deg > 0.4
    assert plan.metrics["peak_attitude_change_deg"] == pytest.approx(peak_deg, rel=1e-12)
    assert plan.metrics["predicted_end_attitude_error_deg"] < 1e-5


def test_forward_and_backward_paths_meet(meeting: Meeting, plan: Plan, model: RobotModel) -> None:
    assert meeting.joint_gap_rad < 1e-6
    assert meeting.attitude_gap_rad < PARAMS.attitude_tolerance_rad
    np.testing.assert_array_equal(meeting.forward_joints_rad[0], PHI_INIT_RAD)
    np.testing.assert_array_equal(meeting.backward_joints_rad[0], PHI_END_RAD)
    np.testing.assert_allclose(meeting.forward_joints_rad[-1], meeting.joints_rad, atol=1e-12)
    np.testing.assert_allclose(meeting.backward_joints_rad[-1], meeting.joints_rad, atol=1e-12)
    # Independently: integrate each path's samples linearly interpolated (planner.free_drift).
    # The chords leave an error ~ 1/n^2 (6e-8 rad at n = 400); Richardson extrapolation over
    # n = 400 and 200 removes it, leaving the planner's RK4 error (2e-9 rad).
    ws = DynamicsWorkspace(model)

    def gap(stride: int) -> np.ndarray:
        ends = []
        for path in (meeting.forward_joints_rad[::stride], meeting.backward_joints_rad[::stride]):
            quats, _ = predict_base_attitude(ws, np.arange(len(path), dtype=float), path)
            ends.append(Rotation.from_quat(quats[-1]))  # both start at the identity
        return np.asarray((ends[1].inv() * ends[0]).as_rotvec())

    fine, coarse = gap(1), gap(2)
    assert np.linalg.norm(fine) < 1e-6
    assert np.linalg.norm((4.0 * fine - coarse) / 3.0) < 1e-8
    # Reported in the plan; compared with (not fitted to) the flight's phi_mid.
    meeting_deg = np.degrees(meeting.joints_rad)
    for i in range(6):
        assert plan.metrics[f"meeting_joint{i + 1}_deg"] == pytest.approx(meeting_deg[i], abs=1e-9)
    distance = float(np.linalg.norm(meeting_deg - np.array(PAPER_PHI_MID_DEG)))
    assert plan.metrics["paper_meeting_distance_deg"] == pytest.approx(distance, rel=1e-12)
    assert meeting.paper_distance_deg == pytest.approx(distance, rel=1e-12)
    assert plan.metrics["iterations"] == meeting.iterations >= 1
    assert np.all(np.abs(meeting.forward_joints_rad) < np.radians(170.0))
    assert np.all(np.abs(meeting.backward_joints_rad) < np.radians(170.0))


def test_truth_simulation_with_stiff_servos_ends_at_the_goal(plan: Plan, model: RobotModel) -> None:
    config = SimConfig(
        timestep_s=0.002, servo=default_servo_gains(model, bandwidth_radps=40.0, lag_s=0.05)
    )
    initial = State(
        joints_rad=plan.initial_joints_rad,
        quat_orbit_from_base_xyzw=plan.initial_quat_orbit_from_base_xyzw,
    )
    sim = FreeFloatingSimulator(model, initial, config)
    end_s = float(plan.command_times_s[-1])
    trajectory = follow_commands(
        sim, plan.command_times_s, plan.command_joints_rad, end_time_s=end_s
    )
    # The servos do lag (0.13 deg behind their moving target) ...
    lag_deg = np.degrees(np.abs(trajectory.joints_rad - trajectory.joint_targets_rad).max())
    assert lag_deg > 0.05
    # ... but along the same path, so the attitude lands: 6e-6 deg reached; bound 1e-3 deg.
    assert math.degrees(_angle_rad(trajectory.quat_orbit_from_base_xyzw[-1])) < 1e-3
    assert np.degrees(np.abs(trajectory.joints_rad[-1] - PHI_END_RAD)).max() < 1e-3
    peak_deg = max(math.degrees(_angle_rad(q)) for q in trajectory.quat_orbit_from_base_xyzw)
    assert peak_deg > 0.4


def test_a_straight_joint_path_leaves_the_attitude_off(
    plan: Plan, workspace: DynamicsWorkspace, model: RobotModel
) -> None:
    times, joints = ptp_commands(model, PHI_INIT_RAD, PHI_END_RAD)
    prediction = predict(workspace, times, joints, acs_commands=FREE_DRIFT)
    naive_deg = math.degrees(_angle_rad(prediction.quat_orbit_from_base_xyzw[-1]))
    assert naive_deg > 0.1  # 0.154 deg on this model
    assert plan.metrics["straight_path_attitude_error_deg"] == pytest.approx(naive_deg, rel=1e-3)
    assert plan.metrics["predicted_end_attitude_error_deg"] < 1e-4 * naive_deg


def test_plan_is_the_same_under_a_common_attitude_offset(plan: Plan, model: RobotModel) -> None:
    """Eq. (9) in the base frame does not see the attitude: offsetting both ends alike
    changes nothing but the attitude column of the prediction."""
    offset = NonholonomicParams(
        attitude_init_deg=(2.0, 1.0, -3.0), attitude_end_deg=(2.0, 1.0, -3.0)
    )
    other = plan_nonholonomic(DynamicsWorkspace(model), offset)
    # Round-off in R_end^T R_init (1e-16) passes through the finite-difference Jacobian
    # (step 1e-7 rad) into the iterates: 1.2e-8 rad measured, 1e-6 rad allowed.
    np.testing.assert_allclose(other.command_joints_rad, plan.command_joints_rad, atol=1e-6)
    np.testing.assert_allclose(
        np.degrees(other.prediction.rpy_base_rad[-1]), [2.0, 1.0, -3.0], atol=1e-5
    )


def test_steers_to_a_nonzero_attitude_target(model: RobotModel) -> None:
    target = NonholonomicParams(attitude_end_deg=(0.5, -0.5, 0.3))
    plan = plan_nonholonomic(DynamicsWorkspace(model), target)
    rpy_deg = np.degrees(plan.prediction.rpy_base_rad[-1])
    np.testing.assert_allclose(rpy_deg, [0.5, -0.5, 0.3], atol=1e-5)
    np.testing.assert_array_equal(plan.command_joints_rad[-1], PHI_END_RAD)


def test_plan_round_trips_through_json(plan: Plan) -> None:
    again = Plan.from_json(plan.to_json())
    assert again.to_json() == plan.to_json()
    assert again.experiment == "nonholonomic"
    assert again.parameters["phi_init_deg"] == list(PARAMS.phi_init_deg)
    assert again.acs_commands[0].mode is AcsMode.FREE_DRIFT
    np.testing.assert_array_equal(again.command_joints_rad, plan.command_joints_rad)
    assert again.metrics == plan.metrics


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"phi_init_deg": (9.6, -2.0, 2.0)}, r"phi_init_deg needs 6 values"),
        ({"phi_end_deg": (0.0, 0.0, math.inf, 0.0, 0.0, 0.0)}, r"phi_end_deg must be finite"),
        ({"attitude_end_deg": (0.0, math.nan, 0.0)}, r"attitude_end_deg must be finite"),
        ({"attitude_init_deg": (200.0, 0.0, 0.0)}, r"exceeds limit 180 deg"),
        ({"rate_fraction": 1.5}, r"rate_fraction 1\.5 outside \[0\.001, 1\]"),
        ({"lead_s": 0.3}, r"lead_s 0\.3 s is not a multiple of 0\.25 s"),
        ({"max_iterations": 0}, r"max_iterations 0 must be an integer in \[1, 10000\]"),
    ],
)
def test_bad_parameters_are_rejected(kwargs: dict[str, object], match: str) -> None:
    with pytest.raises(InvalidInput, match=match):
        NonholonomicParams(**kwargs)  # type: ignore[arg-type]


def test_joints_outside_limits_and_no_meeting_raise_domain_errors(
    workspace: DynamicsWorkspace,
) -> None:
    beyond = NonholonomicParams(phi_end_deg=(0.0, 175.0, 0.0, 0.0, 0.0, 0.0))
    with pytest.raises(
        JointLimitExceeded, match=r"joint 2 in phi_end_deg at 175\.000 deg exceeds limit 170"
    ):
        plan_nonholonomic(workspace, beyond)
    with pytest.raises(DidNotConverge, match=r"did not meet in 1 iterations"):
        find_meeting(workspace, NonholonomicParams(max_iterations=1))
