"""Both shipped robots, loaded from their description files, against the independent NumPy
reference (which reads the same files with its own reader), finite differences of the hand
kinematics, and momentum conservation in free drift (the ETS-VII-only versions of these
live in test_dynamics_reference.py and test_simulation.py)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from planner.description import ETS7_DESCRIPTION, EXAMPLES_DIR, RobotDescription, load_robot
from planner.dynamics import DynamicsWorkspace, Quantities
from planner.simulation import FreeFloatingSimulator, SimConfig, follow_commands
from planner.state import State
from tests import reference_dynamics as ref
from tests.support import dynamics
from tests.support.dynamics import (
    COMPARED,
    FD_ATOL,
    FD_STEP,
    RTOL_REFERENCE,
    RTOL_REFERENCE_METHODS,
    relative_error,
)

Array = NDArray[np.float64]

ROBOTS = {"ets7": ETS7_DESCRIPTION, "orihime": EXAMPLES_DIR / "orihime" / "orihime.toml"}
N_RANDOM_STATES = 12


@dataclass(frozen=True)
class Robot:
    description: RobotDescription
    workspace: DynamicsWorkspace
    reference: ref.RobotData


@pytest.fixture(scope="module", params=list(ROBOTS))
def robot(request: pytest.FixtureRequest) -> Robot:
    path: Path = ROBOTS[request.param]
    description = load_robot(path)
    return Robot(
        description, DynamicsWorkspace(description.model), ref.robot_from_description(path)
    )


def random_state(rng: np.random.Generator, description: RobotDescription) -> State:
    limits = description.model.joint_limit_rad
    return dynamics.random_state(rng, rng.uniform(limits[:, 0], limits[:, 1]))


def reference_at(robot: Robot, state: State) -> ref.Reference:
    wheels = np.array([w.spin_inertia_kgm2 for w in robot.description.model.wheels])
    return dynamics.reference_at(state, wheels, robot.reference)


@pytest.fixture(scope="module")
def cases(robot: Robot) -> list[tuple[State, Quantities, ref.Reference]]:
    rng = np.random.default_rng(20261125)
    states = [random_state(rng, robot.description) for _ in range(N_RANDOM_STATES)]
    return [(s, robot.workspace.evaluate(s), reference_at(robot, s)) for s in states]


# --- 1. project vs reference ---------------------------------------------------------------


@pytest.mark.parametrize("name", list(COMPARED))
def test_project_matches_reference(
    name: str, robot: Robot, cases: list[tuple[State, Quantities, ref.Reference]]
) -> None:
    get_project, get_reference = COMPARED[name]
    errors = [relative_error(get_project(q), get_reference(r)) for _, q, r in cases]
    assert max(errors) <= RTOL_REFERENCE, f"{name}: relative error {max(errors):.3e}"


def test_shapes_follow_the_joint_count(
    robot: Robot, cases: list[tuple[State, Quantities, ref.Reference]]
) -> None:
    n = robot.description.n_joints
    assert robot.reference.n_joints == n
    for _, q, r in cases:
        assert q.J_g.shape == (6, n) and q.reaction_map.shape == (3, n)
        assert q.H_m.shape == (n, n) and q.rns_basis.shape == (n, n - 3)
        assert np.linalg.matrix_rank(q.rns_projector, tol=1e-6) == n - 3
        assert relative_error(r.H_crb, r.H_jacobian_sum) <= RTOL_REFERENCE_METHODS


def test_reference_momentum_matches_eq2_and_eq3(
    robot: Robot, cases: list[tuple[State, Quantities, ref.Reference]]
) -> None:
    spin = np.array([w.spin_inertia_kgm2 for w in robot.description.model.wheels])
    for s, _, r in cases:
        momentum = r.H_b @ s.base_twist_orbit + r.H_bm @ s.joint_rates_radps
        assert relative_error(r.linear_momentum_nms, momentum[:3]) <= RTOL_REFERENCE_METHODS
        h_w = r.kinematics.rot_orbit_from_base @ (spin * s.wheel_rates_radps)
        eq3 = r.H_b_tilde @ s.omega_base_orbit_radps + r.H_bm_tilde @ s.joint_rates_radps + h_w
        assert relative_error(r.angular_momentum_nms, eq3) <= RTOL_REFERENCE_METHODS


# --- 2. finite differences -----------------------------------------------------------------


def _with_joints(state: State, joints_rad: Array) -> State:
    return State(
        joints_rad=joints_rad,
        quat_orbit_from_base_xyzw=state.quat_orbit_from_base_xyzw,
        pos_base_orbit_m=state.pos_base_orbit_m,
        joint_rates_radps=np.zeros_like(joints_rad),
    )


def test_joint_finite_differences_match_J_m(robot: Robot) -> None:
    ws, n = robot.workspace, robot.description.n_joints
    rng = np.random.default_rng(3)
    for _ in range(4):
        s = random_state(rng, robot.description)
        J_m = ws.evaluate(s).J_m
        h0 = ws.hand_pose(s)
        for j in range(n):
            step = FD_STEP * np.eye(n)[j]
            hp = ws.hand_pose(_with_joints(s, s.joints_rad + step))
            hm = ws.hand_pose(_with_joints(s, s.joints_rad - step))
            vel = (hp.pos_orbit_m - hm.pos_orbit_m) / (2.0 * FD_STEP)
            rot_rate = (hp.rot_orbit_from_hand - hm.rot_orbit_from_hand) / (2.0 * FD_STEP)
            omega = ref.vee(rot_rate @ h0.rot_orbit_from_hand.T)
            np.testing.assert_allclose(
                J_m[:, j], np.concatenate([vel, omega]), rtol=0.0, atol=FD_ATOL, err_msg=f"{j}"
            )


def test_reference_hand_matches_the_named_poses(robot: Robot) -> None:
    """Poses given both ways agree in the reference's kinematics too (the loader checks them
    with the project's)."""
    for pose in robot.description.poses.values():
        if pose.joints_rad is None or pose.hand_pos_robot_m is None:
            continue
        kin = ref.forward_kinematics(
            pose.joints_rad, np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3), robot.reference
        )
        # ETS-VII's B is the paper's, joints to 0.1 deg: 5 mm; the others are exact to 1 mm.
        np.testing.assert_allclose(kin.hand_pos_robot_m, pose.hand_pos_robot_m, atol=5e-3)


# --- 3. free drift conserves momentum ------------------------------------------------------


@pytest.mark.slow
def test_free_drift_conserves_momentum(robot: Robot) -> None:
    """Eq. (2)-(3): servo and wheel torques are internal. The base tumbles, the arm follows
    4 Hz commands of a smooth motion, the wheels get a new random torque every 0.1 s."""
    description, ws = robot.description, robot.workspace
    n = description.n_joints
    rng = np.random.default_rng(7)
    initial = State(
        joints_rad=np.radians(rng.uniform(-20.0, 20.0, n)),
        quat_orbit_from_base_xyzw=Rotation.random(random_state=3).as_quat(),
        vel_base_orbit_mps=np.array([0.01, -0.02, 0.005]),
        omega_base_orbit_radps=np.radians([0.05, -0.02, 0.03]),
        joint_rates_radps=np.zeros(n),
        wheel_rates_radps=np.array([20.0, -10.0, 5.0]),
    )
    sim = FreeFloatingSimulator(
        description.model, initial, SimConfig(servo=description.servo_gains())
    )
    q0 = ws.evaluate(sim.state())
    times = np.arange(0.0, 30.0 + 1e-9, 0.25)
    freq = rng.uniform(0.03, 0.08, (3, n))
    amp = np.radians(rng.uniform(2.0, 5.0, (3, n)))
    motion = sum(amp[i] * (1 - np.cos(2 * np.pi * freq[i] * times[:, None])) for i in range(3))
    trajectory = follow_commands(
        sim,
        times,
        initial.joints_rad + motion,
        end_time_s=30.0,
        wheel_controller=lambda _t, _s: rng.uniform(-0.1, 0.1, 3),
    )
    q1 = ws.evaluate(sim.state())
    assert np.linalg.norm(q0.angular_momentum_nms) > 0.1
    assert np.linalg.norm(q0.linear_momentum_nms) > 1.0
    # test_simulation.py's bound for ETS-VII at the 10 ms RK4 step.
    assert np.linalg.norm(q1.linear_momentum_nms - q0.linear_momentum_nms) < 1e-7
    assert np.linalg.norm(q1.angular_momentum_nms - q0.angular_momentum_nms) < 1e-7
    # ... and the motion was real: the arm moved, the wheels traded momentum with the base.
    assert np.max(np.abs(trajectory.joints_rad - initial.joints_rad)) > np.radians(5.0)
    wheel = trajectory.wheel_momentum_nms
    assert np.max(np.abs(wheel[-1] - wheel[0])) > 0.05


def _fastest_servo_modes(description: RobotDescription, samples: int) -> list[float]:
    """The fastest servo mode (1/s) at random poses within the joint limits: with
    kd = lag kp, the largest eigenvalue of M^-1 Kd, M the free-floating joint inertia."""
    model, n = description.model, description.n_joints
    ws = DynamicsWorkspace(model)
    kd = np.diag(description.servo_gains().kd_nms_per_rad)
    rng = np.random.default_rng(0)
    rates = []
    for _ in range(samples):
        joints = rng.uniform(model.joint_limit_rad[:, 0], model.joint_limit_rad[:, 1])
        q = ws.evaluate(State(joints_rad=joints, joint_rates_radps=np.zeros(n)))
        free = q.H_m - q.H_bm.T @ np.linalg.solve(q.H_b, q.H_bm)
        rates.append(float(np.linalg.eigvals(np.linalg.solve(free, kd)).real.max()))
    return rates


def test_orihime_servo_modes_suit_the_simulator_step() -> None:
    """RK4 at the simulator's 10 ms step is stable for a decaying mode up to 2.78 / 0.01 s;
    beyond it MuJoCo resets a diverged run. Orihime's roll joints lose two orders of their
    inertia near the straight shoulder and elbow, hence its 4 rad/s servos and +-70 deg
    pitch limits: its fastest mode stays inside the interval, and below ETS-VII's (whose
    6 rad/s servos leave it at a few corners of its +-170 deg ranges, 344 1/s at worst)."""
    limit = 2.78 / SimConfig().timestep_s
    orihime = _fastest_servo_modes(load_robot(ROBOTS["orihime"]), 300)
    ets7 = _fastest_servo_modes(load_robot(ROBOTS["ets7"]), 300)
    assert max(orihime) < limit
    assert max(orihime) < max(ets7)
    assert np.median(orihime) < np.median(ets7)
