"""The free-floating simulation core: invariants of the physics it steps."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from planner.dynamics import DynamicsWorkspace
from planner.errors import InvalidInput
from planner.model import RobotModel
from planner.simulation import (
    FreeFloatingSimulator,
    SimConfig,
    default_servo_gains,
    follow_commands,
)
from planner.state import State


def _momentum(ws: DynamicsWorkspace, state: State) -> tuple[np.ndarray, np.ndarray]:
    q = ws.evaluate(state)
    return q.linear_momentum_nms, q.angular_momentum_nms


def _attitude_change_deg(state: State) -> float:
    return float(np.degrees(Rotation.from_quat(state.quat_orbit_from_base_xyzw).magnitude()))


def test_free_drift_conserves_momentum_under_arm_and_wheel_motion(model: RobotModel) -> None:
    """Eq. (2)-(3): servo and wheel torques are internal.

    The base tumbles and translates; the arm follows 4 Hz commands of an arbitrary smooth
    motion (sums of cosines starting at rest, up to about 2 deg/s) as in operations, while
    the wheels get a new random torque every 0.1 s.
    """
    ws = DynamicsWorkspace(model)
    rng = np.random.default_rng(7)
    initial = State(
        joints_rad=np.radians([10.0, -20.0, 30.0, 40.0, -10.0, 20.0]),
        quat_orbit_from_base_xyzw=Rotation.random(random_state=3).as_quat(),
        vel_base_orbit_mps=np.array([0.01, -0.02, 0.005]),
        omega_base_orbit_radps=np.radians([0.05, -0.02, 0.03]),
        wheel_rates_radps=np.array([20.0, -10.0, 5.0]),
    )
    sim = FreeFloatingSimulator(model, initial)
    p0, l0 = _momentum(ws, sim.state())
    times = np.arange(0.0, 60.0 + 1e-9, 0.25)
    freq = rng.uniform(0.02, 0.06, (3, 6))
    amp = np.radians(rng.uniform(2.0, 5.0, (3, 6)))
    motion = sum(amp[i] * (1 - np.cos(2 * np.pi * freq[i] * times[:, None])) for i in range(3))
    commands = initial.joints_rad + motion
    trajectory = follow_commands(
        sim,
        times,
        commands,
        end_time_s=60.0,
        wheel_controller=lambda _t, _s: rng.uniform(-0.5, 0.5, 3),
    )
    p1, l1 = _momentum(ws, sim.state())
    assert np.linalg.norm(l0) > 1.0 and np.linalg.norm(p0) > 10.0  # not checked against zero
    # Bound reached at the 10 ms RK4 step: 1.2e-8 N s and 2.3e-8 N m s over 60 s (about
    # 4e-10 of the momentum), from RK4 truncation at each wheel-torque step; 1e-7 is the limit.
    assert np.linalg.norm(p1 - p0) < 1e-7
    assert np.linalg.norm(l1 - l0) < 1e-7
    # ... and the motion was real: the arm moved and the wheels traded momentum with the base.
    assert np.max(np.abs(trajectory.joints_rad - initial.joints_rad)) > np.radians(10.0)
    assert (
        np.max(np.abs(trajectory.wheel_momentum_nms[-1] - trajectory.wheel_momentum_nms[0])) > 0.1
    )


def test_momentum_error_under_servo_steps_is_rk4_truncation(model: RobotModel) -> None:
    """A 0.2 rad step on every servo is the harshest input; the momentum that RK4 fails to
    conserve then shrinks at fourth order with the step (~16x per halving)."""
    ws = DynamicsWorkspace(model)
    errors = []
    for dt in (0.01, 0.005, 0.0025):
        initial = State(joints_rad=np.radians([10.0, -20.0, 30.0, 40.0, -10.0, 20.0]))
        sim = FreeFloatingSimulator(model, initial, SimConfig(timestep_s=dt))
        sim.set_joint_target(initial.joints_rad + 0.2)
        sim.advance(10.0)
        errors.append(float(np.linalg.norm(_momentum(ws, sim.state())[1])))
    ratios = np.array(errors[:-1]) / np.array(errors[1:])
    assert errors[0] < 1e-3
    assert np.all(ratios > 12.0), ratios  # 2^4 = 16 in the asymptotic regime


def test_external_torque_changes_angular_momentum_by_its_impulse(model: RobotModel) -> None:
    ws = DynamicsWorkspace(model)
    sim = FreeFloatingSimulator(model, State(joints_rad=np.zeros(6)))
    torque = np.array([0.02, -0.01, 0.03])
    sim.advance(10.0, base_torque_orbit_nm=torque)
    _, momentum = _momentum(ws, sim.state())
    np.testing.assert_allclose(momentum, 10.0 * torque, rtol=1e-9, atol=1e-12)


def test_a_base_impulse_changes_angular_momentum_by_exactly_the_impulse(model: RobotModel) -> None:
    """A bump: the impulse (base frame) lands whole in the system's angular momentum (orbit
    frame), none in its linear momentum, and the pose does not jump; the base, arm and
    spinning wheels all take their share of the velocity change, and free drift then keeps
    the new momentum."""
    ws = DynamicsWorkspace(model)
    initial = State(
        joints_rad=np.radians([31.6, 21.4, -8.8, 77.4, 0.0, 68.6]),
        quat_orbit_from_base_xyzw=Rotation.from_euler("xyz", [10, 20, 30], degrees=True).as_quat(),
        omega_base_orbit_radps=np.radians([0.01, -0.02, 0.015]),
        wheel_rates_radps=np.array([30.0, -12.0, 4.0]),
    )
    sim = FreeFloatingSimulator(model, initial)
    sim.set_joint_target(initial.joints_rad)
    sim.advance(1.0, wheel_torque_nm=np.array([0.1, 0.0, -0.2]))
    before = sim.state()
    p0, l0 = _momentum(ws, before)
    impulse_base = np.array([3.0, -10.0, 5.0])
    sim.apply_base_impulse(impulse_base)
    after = sim.state()
    p1, l1 = _momentum(ws, after)
    np.testing.assert_allclose(l1 - l0, before.rot_orbit_from_base @ impulse_base, atol=1e-9)
    np.testing.assert_allclose(p1, p0, atol=1e-9)
    np.testing.assert_array_equal(after.joints_rad, before.joints_rad)
    np.testing.assert_array_equal(after.quat_orbit_from_base_xyzw, before.quat_orbit_from_base_xyzw)
    assert sim.step_count == 100
    # the base turns about the impulse's direction (11.6 N m s: measured 0.163 deg/s)
    dw = np.degrees(after.omega_base_orbit_radps - before.omega_base_orbit_radps)
    assert np.dot(dw, before.rot_orbit_from_base @ impulse_base) > 0.0
    assert np.linalg.norm(dw) > 0.1
    sim.advance(5.0)
    np.testing.assert_allclose(_momentum(ws, sim.state())[1], l1, atol=1e-7)
    with pytest.raises(InvalidInput, match="3 finite numbers"):
        sim.apply_base_impulse(np.array([np.nan, 0.0, 0.0]))


def test_wheel_torque_turns_the_base_the_other_way(model: RobotModel) -> None:
    ws = DynamicsWorkspace(model)
    sim = FreeFloatingSimulator(model, State(joints_rad=np.zeros(6)))
    sim.advance(5.0, wheel_torque_nm=np.array([0.0, 0.2, 0.0]))
    state = sim.state()
    # The wheel gained +1 N m s about y (relative momentum plus its share of base rotation);
    # the total stays zero, so the base spins negatively about y.
    np.testing.assert_allclose(sim.wheel_momentum_nms()[1], 1.0, rtol=1e-3)
    assert state.omega_base_orbit_radps[1] < 0.0
    np.testing.assert_allclose(_momentum(ws, state)[1], 0.0, atol=1e-9)


def test_wheel_torque_and_momentum_limits(model: RobotModel) -> None:
    config = SimConfig(wheel_torque_limit_nm=0.1, wheel_momentum_limit_nms=0.5)
    sim = FreeFloatingSimulator(model, State(joints_rad=np.zeros(6)), config)
    sim.advance(2.0, wheel_torque_nm=np.array([1.0, -1.0, 0.05]))
    # clipped to 0.1 N m: 0.2 N m s after 2 s (the rotor's own share is negligible)
    np.testing.assert_allclose(sim.wheel_momentum_nms(), [0.2, -0.2, 0.1], rtol=2e-3)
    for _ in range(10):
        sim.advance(1.0, wheel_torque_nm=np.array([1.0, -1.0, 0.0]))
    h = sim.wheel_momentum_nms()
    # saturation stops at the first check past capacity: at most one interval (0.1 N m s) over
    assert 0.5 <= h[0] <= 0.6 + 1e-9
    assert -0.6 - 1e-9 <= h[1] <= -0.5
    # torque that unloads a saturated wheel is accepted
    sim.advance(1.0, wheel_torque_nm=np.array([-0.1, 0.1, 0.0]))
    assert sim.wheel_momentum_nms()[0] < h[0] - 0.09


def test_servo_lags_a_ramp_by_kd_over_kp_times_rate(model: RobotModel) -> None:
    from planner.simulation import ETS7_SERVO_LAG_S

    gains = default_servo_gains(model)
    lag_s = gains.kd_nms_per_rad / gains.kp_nm_per_rad
    # The built-in ETS-VII lags by joint (planner.simulation.ETS7_SERVO_LAG_S).
    np.testing.assert_allclose(lag_s, ETS7_SERVO_LAG_S, rtol=1e-15)
    sim = FreeFloatingSimulator(model, State(joints_rad=np.zeros(6)))
    rate = np.radians(np.full(6, 1.0))
    sim.set_joint_target(np.zeros(6), rate)
    sim.advance(20.0)
    lag = sim.joint_target_rad() - sim.state().joints_rad
    # Steady-state lag of a PD servo without rate feed-forward behind a ramp; coupling
    # through the base and the other joints perturbs it by a few percent.
    np.testing.assert_allclose(lag, lag_s * rate, rtol=0.05)
    # "A few tenths of a degree" (SPEC 6) at 1 deg/s; the stiff shoulder (joint 2) 0.1 deg.
    assert np.all(np.degrees(lag) > 0.09) and np.sum(np.degrees(lag) > 0.25) >= 5
    assert int(np.argmax(lag)) == 3  # the wrist pitch lags most (paper Fig. 6)


def test_servo_gains_take_one_lag_or_one_per_joint(model: RobotModel) -> None:
    one = default_servo_gains(model, bandwidth_radps=6.0, lag_s=0.3)
    np.testing.assert_allclose(one.kd_nms_per_rad, 0.3 * one.kp_nm_per_rad, rtol=1e-15)
    lags = np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
    each = default_servo_gains(model, bandwidth_radps=6.0, lag_s=lags)
    np.testing.assert_array_equal(each.kp_nm_per_rad, one.kp_nm_per_rad)
    np.testing.assert_allclose(each.kd_nms_per_rad, lags * one.kp_nm_per_rad, rtol=1e-15)
    bandwidths = np.array([3.0, 6.0, 6.0, 6.0, 6.0, 12.0])
    wide = default_servo_gains(model, bandwidth_radps=bandwidths, lag_s=0.3)
    np.testing.assert_allclose(
        wide.kp_nm_per_rad, one.kp_nm_per_rad * (bandwidths / 6.0) ** 2, rtol=1e-12
    )
    for kwargs, words in (
        ({"lag_s": [0.3] * 5}, "servo lag_s needs one number or 6"),
        ({"bandwidth_radps": np.ones((2, 3))}, "servo bandwidth_radps needs one number or 6"),
        ({"lag_s": [0.3, 0.3, -0.1, 0.3, 0.3, 0.3]}, "lag_s must be >= 0"),
        ({"bandwidth_radps": 0.0}, "bandwidth_radps must be > 0"),
        ({"lag_s": float("nan")}, "lag_s must be >= 0"),
    ):
        with pytest.raises(InvalidInput, match=words):
            default_servo_gains(model, **kwargs)  # type: ignore[arg-type]


def test_servo_target_saturates_at_the_joint_limit(model: RobotModel) -> None:
    sim = FreeFloatingSimulator(model, State(joints_rad=np.zeros(6)))
    sim.set_joint_target(np.radians([200.0, 0, 0, 0, 0, -300.0]))
    np.testing.assert_allclose(np.degrees(sim.joint_target_rad())[[0, 5]], [170.0, -170.0])
    sim.set_joint_target(np.radians([169.0, 0, 0, 0, 0, 0]), np.radians([5.0, 0, 0, 0, 0, 0]))
    sim.advance(2.0)
    np.testing.assert_allclose(np.degrees(sim.joint_target_rad()[0]), 170.0)


def test_advance_rejects_durations_off_the_step_grid(model: RobotModel) -> None:
    sim = FreeFloatingSimulator(model, State(joints_rad=np.zeros(6)))
    with pytest.raises(InvalidInput, match="whole number"):
        sim.advance(0.015)
    with pytest.raises(InvalidInput):
        sim.set_joint_target(np.zeros(5))


def _rns_path(ws: DynamicsWorkspace, start: np.ndarray, direction: np.ndarray, dt: float, n: int):
    """Joints along ``phi' = P(phi) u / |P(phi) u|`` (unit joint speed), RK4 in phi."""

    def rate(phi: np.ndarray) -> np.ndarray:
        v = ws.evaluate(State(joints_rad=phi)).rns_projector @ direction
        return v / np.linalg.norm(v)

    path = [start]
    phi = start.copy()
    for _ in range(n):
        k1 = rate(phi)
        k2 = rate(phi + 0.5 * dt * k1)
        k3 = rate(phi + 0.5 * dt * k2)
        k4 = rate(phi + dt * k3)
        phi = phi + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        path.append(phi)
    return np.array(path)


@pytest.mark.slow
def test_motion_along_the_reaction_null_space_keeps_the_base_still(model: RobotModel) -> None:
    """Eq. (4)-(5): reactionless manipulation, compared with a motion of the same size."""
    ws = DynamicsWorkspace(model)
    start = np.radians([31.6, 21.4, -8.8, 77.4, 0.0, 68.6])  # pose B
    direction = np.array([0.3, -0.5, 0.8, -0.2, 0.4, 0.1])
    # 20 s at a joint speed of 0.01 rad/s (0.57 deg/s): 11 degrees of joint motion.
    speed, duration_s, period_s = 0.01, 20.0, 0.05
    n = round(duration_s / period_s)
    path_rns = _rns_path(ws, start, direction, speed * period_s, n)
    path_plain = start + np.outer(
        np.arange(n + 1) * speed * period_s, direction / np.linalg.norm(direction)
    )
    # Stiff servos so that what is tested is the null space, not the servo lag.
    config = SimConfig(
        timestep_s=0.002, servo=default_servo_gains(model, bandwidth_radps=40.0, lag_s=0.05)
    )
    times = np.arange(n + 1) * period_s
    changes = []
    for path in (path_rns, path_plain):
        sim = FreeFloatingSimulator(model, State(joints_rad=start), config)
        follow_commands(sim, times, path, end_time_s=duration_s + 2.0, sample_period_s=0.5)
        np.testing.assert_allclose(sim.state().joints_rad, path[-1], atol=1e-5)
        changes.append(_attitude_change_deg(sim.state()))
    rns_deg, plain_deg = changes
    assert plain_deg > 0.05
    # Residual from the servo's lag and from linear interpolation between 20 Hz points.
    assert rns_deg < 1e-3
    assert rns_deg < plain_deg / 100.0


def test_generalized_jacobian_predicts_the_simulated_hand_velocity(model: RobotModel) -> None:
    """Eq. (8): in free drift at zero momentum the hand moves at J_g phi'."""
    ws = DynamicsWorkspace(model)
    sim = FreeFloatingSimulator(model, State(joints_rad=np.radians([0, -23.0, 10.0, 0, 0, 0])))
    sim.set_joint_target(sim.state().joints_rad, np.radians([1.5, -2.0, 2.5, 1.0, -2.0, 3.0]))
    dt = sim.config.timestep_s
    checked = 0
    for _ in range(4):
        sim.advance(3.0)
        before = ws.hand_pose(sim.state())
        sim.advance(dt)
        mid = sim.state()
        sim.advance(dt)
        after = ws.hand_pose(sim.state())
        v_fd = (after.pos_orbit_m - before.pos_orbit_m) / (2 * dt)
        d_rot = after.rot_orbit_from_hand @ before.rot_orbit_from_hand.T
        w_fd = Rotation.from_matrix(d_rot).as_rotvec() / (2 * dt)
        predicted = ws.evaluate(mid).J_g @ mid.joint_rates_radps
        assert np.linalg.norm(mid.joint_rates_radps) > np.radians(1.0)
        # Central differences over 10 ms: O(dt^2) truncation, 1e-4 relative is ample.
        np.testing.assert_allclose(v_fd, predicted[:3], rtol=1e-4, atol=1e-8)
        np.testing.assert_allclose(w_fd, predicted[3:], rtol=1e-4, atol=1e-8)
        # The fixed-base Jacobian J_m alone would be wrong by the base's reaction.
        assert np.linalg.norm(ws.evaluate(mid).J_m @ mid.joint_rates_radps - predicted) > 1e-5
        checked += 1
    assert checked == 4


def test_gravity_gradient_torque_is_applied_and_accumulates(model: RobotModel) -> None:
    """Eq. (14): with the torque on and the wheels idle, angular momentum grows by the
    torque's impulse, and the torque is eq. (11) at the current attitude."""
    ws = DynamicsWorkspace(model)
    config = SimConfig(gravity_gradient=True, gravity_gradient_update_s=0.5)
    sim = FreeFloatingSimulator(model, State(joints_rad=np.zeros(6)), config)
    impulse = np.zeros(3)
    for _ in range(200):
        state = sim.state()
        sim.advance(0.5)
        applied_base = sim.gravity_gradient_torque_base_nm()
        expected_base = ws.evaluate(state).gravity_gradient_torque_base_nm
        np.testing.assert_allclose(applied_base, expected_base, rtol=1e-9, atol=1e-15)
        impulse += 0.5 * state.rot_orbit_from_base @ applied_base
    _, momentum = _momentum(ws, sim.state())
    np.testing.assert_allclose(momentum, impulse, rtol=1e-8, atol=1e-15)
    assert np.linalg.norm(momentum) > 0.05  # 100 s of about 1e-4 N m
    # Earth-pointing to within the drift: pitch and roll torques, (almost) none about yaw.
    assert abs(momentum[2]) < 1e-3 * np.linalg.norm(momentum)
