"""A pass planned from an explicit initial state (where a campaign's previous pass left the
vehicle): the arm's joints, the base's attitude and rate and the wheels' momentum are where
the plan and its prediction start, and the prediction keeps the system's angular momentum."""

from __future__ import annotations

import numpy as np
import pytest

from planner.dynamics import DynamicsWorkspace
from planner.errors import InvalidInput, JointLimitExceeded
from planner.frames import matrix_from_quat_xyzw
from planner.plan import Plan
from planner.prediction import predict
from planner.schedule import PassParams, plan_pass
from planner.state import VehicleState

JOINTS = np.radians([6.0, 11.0, 3.0, -17.0, 2.0, 5.0])
QUAT = np.array([0.0009, -0.0012, 0.0004, 1.0]) / np.linalg.norm([0.0009, -0.0012, 0.0004, 1.0])
OMEGA = np.array([2e-5, -1e-5, 3e-5])  # rad/s, orbit frame
WHEELS = np.array([0.4, -0.7, 0.2])  # N m s, base frame
START = VehicleState(JOINTS, QUAT, OMEGA, WHEELS)


def total_momentum_orbit_nms(
    ws: DynamicsWorkspace, joints: np.ndarray, quat: np.ndarray, omega: np.ndarray, h: np.ndarray
) -> np.ndarray:
    """Eq. (3) plus the wheels, the arm at rest: ``R (H~_b R^T w + h_w)``, orbit frame."""
    rot = matrix_from_quat_xyzw(quat)
    inertia = ws.momentum_blocks(joints)[0]
    return np.asarray(rot @ (inertia @ (rot.T @ omega) + h))


@pytest.fixture(scope="module")
def from_state() -> Plan:
    from planner.model import default_model

    return plan_pass(
        DynamicsWorkspace(default_model()), PassParams(experiments=("ptp",)), initial_state=START
    )


@pytest.mark.slow
def test_the_plan_starts_at_the_given_state(from_state: Plan) -> None:
    plan = from_state
    np.testing.assert_array_equal(plan.initial_joints_rad, JOINTS)
    np.testing.assert_array_equal(plan.command_joints_rad[0], JOINTS)
    np.testing.assert_allclose(plan.initial_quat_orbit_from_base_xyzw, QUAT, atol=1e-15)
    np.testing.assert_allclose(plan.prediction.quat_orbit_from_base_xyzw[0], QUAT, atol=1e-15)
    np.testing.assert_array_equal(plan.prediction.wheel_momentum_nms[0], WHEELS)
    # the arm is taken from the given joints to the experiment's start (pose A) first
    assert plan.segments[0].name == "transfer to ptp"
    assert not np.allclose(plan.command_joints_rad[-1], JOINTS)
    # the document carries it: the plan file starts where the state says
    again = Plan.from_json(plan.to_json())
    np.testing.assert_array_equal(again.initial_joints_rad, JOINTS)
    np.testing.assert_array_equal(again.prediction.wheel_momentum_nms[0], WHEELS)


@pytest.mark.slow
def test_the_prediction_keeps_the_momentum_the_state_starts_with(
    workspace: DynamicsWorkspace, from_state: Plan
) -> None:
    """No external torque in the pass: the base's and wheels' momentum at the start (the
    given rate included) is what the base and wheels hold at the end, both at rest arms."""
    p = from_state.prediction
    start = total_momentum_orbit_nms(workspace, JOINTS, QUAT, OMEGA, WHEELS)
    end = total_momentum_orbit_nms(
        workspace,
        p.joints_rad[-1],
        p.quat_orbit_from_base_xyzw[-1],
        p.omega_base_orbit_radps[-1],
        p.wheel_momentum_nms[-1],
    )
    assert np.linalg.norm(start) > 0.5  # not a test of zeros
    np.testing.assert_allclose(end, start, atol=1e-9)


@pytest.mark.slow
def test_the_default_start_differs_from_the_given_one(
    workspace: DynamicsWorkspace, from_state: Plan
) -> None:
    default = plan_pass(workspace, PassParams(experiments=("ptp",)))
    np.testing.assert_array_equal(default.initial_joints_rad, np.zeros(6))
    np.testing.assert_array_equal(default.prediction.wheel_momentum_nms[0], np.zeros(3))
    # with its momentum and rate, the given start ends the pass with other wheel momentum
    gap = from_state.prediction.wheel_momentum_nms[-1] - default.prediction.wheel_momentum_nms[-1]
    assert np.linalg.norm(gap) > 0.3


def test_predict_starts_the_base_at_the_given_rate(workspace: DynamicsWorkspace) -> None:
    """An arm holding still: the base turns at the given rate from the first row on."""
    times = np.array([0.0, 0.25, 0.5])
    joints = np.tile(JOINTS, (3, 1))
    p = predict(
        workspace,
        times,
        joints,
        initial_quat_orbit_from_base_xyzw=QUAT,
        initial_wheel_momentum_nms=WHEELS,
        initial_omega_base_orbit_radps=OMEGA,
    )
    np.testing.assert_allclose(p.omega_base_orbit_radps[0], OMEGA, atol=1e-15)
    still = predict(workspace, times, joints, initial_wheel_momentum_nms=WHEELS)
    np.testing.assert_allclose(still.omega_base_orbit_radps, 0.0, atol=1e-15)


def test_a_start_outside_the_limits_or_of_another_arm_is_refused(
    workspace: DynamicsWorkspace,
) -> None:
    with pytest.raises(JointLimitExceeded, match="joint 4"):
        plan_pass(
            workspace,
            PassParams(experiments=("ptp",)),
            initial_state=VehicleState(np.radians([0.0, 0.0, 0.0, 175.0, 0.0, 0.0])),
        )
    with pytest.raises(InvalidInput, match="7 joints, the robot 6"):
        plan_pass(
            workspace,
            PassParams(experiments=("ptp",)),
            initial_state=VehicleState(np.zeros(7)),
        )


def test_a_vehicle_state_round_trips_and_refuses_nonsense() -> None:
    again = VehicleState.from_dict(START.to_dict())
    for name in ("joints_rad", "quat_orbit_from_base_xyzw", "omega_base_orbit_radps"):
        np.testing.assert_array_equal(getattr(again, name), getattr(START, name))
    np.testing.assert_array_equal(again.wheel_momentum_nms, WHEELS)
    with pytest.raises(InvalidInput, match="wheel_momentum_nms must have shape"):
        VehicleState(JOINTS, wheel_momentum_nms=np.zeros(2))
    with pytest.raises(InvalidInput, match="not a rotation"):
        VehicleState(JOINTS, quat_orbit_from_base_xyzw=np.zeros(4))
    with pytest.raises(InvalidInput, match="malformed vehicle state"):
        VehicleState.from_dict({"joints_rad": [0.0]})


@pytest.mark.slow
def test_the_start_given_as_parameters_is_the_start_given_as_a_state(
    from_state: Plan, workspace: DynamicsWorkspace
) -> None:
    params = PassParams.starting_at(START, experiments=("ptp",))
    again = plan_pass(workspace, params)
    np.testing.assert_array_equal(again.command_joints_rad, from_state.command_joints_rad)
    np.testing.assert_array_equal(
        again.prediction.wheel_momentum_nms, from_state.prediction.wheel_momentum_nms
    )
    assert again.parameters["start_wheel_momentum_nms"] == tuple(WHEELS)
    with pytest.raises(InvalidInput, match="given twice"):
        plan_pass(workspace, params, initial_state=START)
    with pytest.raises(InvalidInput, match="must hold 3 numbers"):
        PassParams(start_wheel_momentum_nms=(1.0, 2.0)).check()
    with pytest.raises(InvalidInput, match="gravity_gradient_radius_m"):
        PassParams(gravity_gradient_radius_m=100.0).check()
