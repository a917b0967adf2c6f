"""PTP command generation and the eq. (9)-(10) free-drift prediction."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from planner.dynamics import DynamicsWorkspace
from planner.errors import InvalidInput, JointLimitExceeded
from planner.free_drift import predict_base_attitude, quat_multiply_xyzw
from planner.model import RobotModel
from planner.ptp import COMMAND_PERIOD_S, ptp_commands
from planner.simulation import (
    FreeFloatingSimulator,
    SimConfig,
    default_servo_gains,
    follow_commands,
)
from planner.state import State

JOINTS_B_RAD = np.radians([31.6, 21.4, -8.8, 77.4, 0.0, 68.6])


def test_ptp_commands_lie_on_the_4hz_grid_within_rate_limits(model: RobotModel) -> None:
    t, q = ptp_commands(model, np.zeros(6), JOINTS_B_RAD)
    np.testing.assert_allclose(np.diff(t), COMMAND_PERIOD_S, rtol=0, atol=1e-12)
    np.testing.assert_allclose(q[0], 0.0, atol=0)
    np.testing.assert_allclose(q[-1], JOINTS_B_RAD, atol=1e-15)
    rates = np.abs(np.diff(q, axis=0)) / COMMAND_PERIOD_S
    assert np.all(rates <= model.joint_rate_limit_radps + 1e-12)
    # the slowest joint sets the duration: joint 4 (77.4 deg) peaks near 90 % of 3 deg/s
    assert np.max(rates[:, 3]) > 0.85 * model.joint_rate_limit_radps[3]
    # starts and ends at rest
    assert np.max(rates[0]) < 0.01 * model.joint_rate_limit_radps[0]
    assert np.max(rates[-1]) < 0.01 * model.joint_rate_limit_radps[0]


def test_ptp_rejects_goals_outside_the_limits(model: RobotModel) -> None:
    with pytest.raises(JointLimitExceeded, match=r"joint 3 at 175\.000 deg exceeds limit 170\.000"):
        ptp_commands(model, np.zeros(6), np.radians([0, 0, 175.0, 0, 0, 0]))
    with pytest.raises(InvalidInput):
        ptp_commands(model, np.zeros(6), np.zeros(6), rate_fraction=1.5)


def test_quaternion_product_matches_scipy() -> None:
    a, b = Rotation.random(2, random_state=5)
    np.testing.assert_allclose(
        quat_multiply_xyzw(a.as_quat(), b.as_quat()), (a * b).as_quat(), atol=1e-15
    )


def test_prediction_matches_the_simulated_attitude_with_stiff_servos(model: RobotModel) -> None:
    """Eq. (10) vs the MuJoCo free-drift simulation tracking the same 4 Hz commands."""
    ws = DynamicsWorkspace(model)
    t, q = ptp_commands(model, np.zeros(6), JOINTS_B_RAD)
    predicted, omega = predict_base_attitude(ws, t, q)
    config = SimConfig(
        timestep_s=0.002, servo=default_servo_gains(model, bandwidth_radps=40.0, lag_s=0.05)
    )
    sim = FreeFloatingSimulator(model, State(joints_rad=np.zeros(6)), config)
    follow_commands(sim, t, q, end_time_s=float(t[-1]) + 5.0, sample_period_s=0.25)
    simulated = Rotation.from_quat(sim.state().quat_orbit_from_base_xyzw)
    change_deg = np.degrees(simulated.magnitude())
    error_deg = np.degrees((simulated * Rotation.from_quat(predicted[-1]).inv()).magnitude())
    assert change_deg > 1.0  # PTP A->B turns the base by degrees
    # The residual is the stiff servo's lag (0.05 s) along the path.
    assert error_deg < 1e-3 * change_deg
    assert omega.shape == (t.size - 1, 3)


def test_prediction_of_no_motion_is_no_rotation(workspace: DynamicsWorkspace) -> None:
    t = np.arange(5) * COMMAND_PERIOD_S
    q = np.tile(JOINTS_B_RAD, (5, 1))
    quats, omega = predict_base_attitude(workspace, t, q)
    np.testing.assert_allclose(quats, np.tile([0, 0, 0, 1.0], (5, 1)), atol=0)
    np.testing.assert_allclose(omega, 0.0, atol=0)
