"""planner.dynamics against the independent NumPy reference (tests/reference_dynamics.py).

The project evaluates everything through MuJoCo (:mod:`planner.dynamics`); the reference
re-types the SPEC tables and uses other algorithms (product of exponentials, composite rigid
bodies, Jacobian sums, body-by-body momentum). Besides the entry-by-entry comparison this
module checks finite differences of the hand kinematics, the pose-A anchor, the reaction null
space, the gravity-gradient torque of eq. (11)-(13) and the MuJoCo conventions that
:mod:`planner.mujoco_conventions` owns.

Tolerances are stated where they are used. "Relative" means the largest entry-wise error
divided by the largest entry of the expected quantity (an entry-wise relative error would
blow up on entries that are zero). The two float64 implementations agree to about 1e-14.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
import pytest
from numpy.typing import NDArray

from planner.dynamics import DynamicsWorkspace, Quantities
from planner.frames import matrix_from_quat_xyzw
from planner.gravity_gradient import Orbit, gravity_gradient_torque_base_nm
from planner.mjcf import compile_model
from planner.model import RobotModel, default_model
from planner.mujoco_conventions import (
    MjLayout,
    quat_wxyz_from_xyzw,
    quat_xyzw_from_wxyz,
    read_state,
    write_state,
)
from planner.state import State
from tests import reference_dynamics as ref
from tests.support import dynamics
from tests.support.dynamics import (
    COMPARED,
    FD_ATOL,
    FD_STEP,
    RTOL_REFERENCE,
    RTOL_REFERENCE_METHODS,
    random_unit_quat_xyzw,
    relative_error,
)

Array = NDArray[np.float64]

N_RANDOM_STATES = 24
JOINT_RANGE_RAD = np.radians(170.0)


# --- helpers --------------------------------------------------------------------------------


def random_state(rng: np.random.Generator) -> State:
    return dynamics.random_state(rng, rng.uniform(-JOINT_RANGE_RAD, JOINT_RANGE_RAD, 6))


def reference_at(model: RobotModel, state: State) -> ref.Reference:
    # The one parameter taken from the model: SPEC leaves the rotors unpublished.
    return dynamics.reference_at(state, np.array([w.spin_inertia_kgm2 for w in model.wheels]))


def with_(state: State, **changes: Array) -> State:
    fields = {
        "joints_rad": state.joints_rad,
        "quat_orbit_from_base_xyzw": state.quat_orbit_from_base_xyzw,
        "pos_base_orbit_m": state.pos_base_orbit_m,
        "vel_base_orbit_mps": state.vel_base_orbit_mps,
        "omega_base_orbit_radps": state.omega_base_orbit_radps,
        "joint_rates_radps": state.joint_rates_radps,
        "wheel_rates_radps": state.wheel_rates_radps,
    }
    fields.update(changes)
    return State(**fields)


@dataclass(frozen=True)
class Case:
    state: State
    project: Quantities
    reference: ref.Reference


@pytest.fixture(scope="module")
def model() -> RobotModel:
    return default_model()


@pytest.fixture(scope="module")
def workspace(model: RobotModel) -> DynamicsWorkspace:
    return DynamicsWorkspace(model)


@pytest.fixture(scope="module")
def cases(model: RobotModel, workspace: DynamicsWorkspace) -> list[Case]:
    rng = np.random.default_rng(20240601)
    states = [random_state(rng) for _ in range(N_RANDOM_STATES)]
    return [Case(s, workspace.evaluate(s), reference_at(model, s)) for s in states]


# --- 1. project vs reference at random states --------------------------------------------


@pytest.mark.parametrize("name", list(COMPARED))
def test_project_matches_reference(name: str, cases: list[Case]) -> None:
    get_project, get_reference = COMPARED[name]
    errors = [relative_error(get_project(c.project), get_reference(c.reference)) for c in cases]
    worst = int(np.argmax(errors))
    assert errors[worst] <= RTOL_REFERENCE, (
        f"{name}: relative error {errors[worst]:.3e} > {RTOL_REFERENCE:.0e} at random state "
        f"{worst}\nproject:\n{get_project(cases[worst].project)}\n"
        f"reference:\n{get_reference(cases[worst].reference)}"
    )


def test_random_states_cover_the_joint_range_and_attitudes(cases: list[Case]) -> None:
    """Guards the comparison above against a degenerate sample."""
    joints = np.array([c.state.joints_rad for c in cases])
    assert joints.shape == (N_RANDOM_STATES, 6)
    assert np.all(joints.max(axis=0) > np.radians(60.0))
    assert np.all(joints.min(axis=0) < np.radians(-60.0))
    tilt_rad = [
        np.arccos(np.clip(c.reference.kinematics.rot_orbit_from_base[2, 2], -1, 1)) for c in cases
    ]
    assert max(tilt_rad) > np.radians(90.0)


# --- 2. the reference's own cross-checks ---------------------------------------------------


def test_reference_crb_equals_jacobian_sum(cases: list[Case]) -> None:
    for c in cases:
        r = c.reference
        assert relative_error(r.H_crb, r.H_jacobian_sum) <= RTOL_REFERENCE_METHODS
        # Symmetric positive definite, as any inertia matrix.
        assert np.linalg.eigvalsh(r.H_crb).min() > 0.0


def test_reference_momentum_matches_its_inertia_matrix(
    model: RobotModel, cases: list[Case]
) -> None:
    """Body-by-body momentum (reference) vs eq. (2) and eq. (3) plus the wheels' h_w."""
    spin_kgm2 = np.array([w.spin_inertia_kgm2 for w in model.wheels])
    for c in cases:
        r, s = c.reference, c.state
        momentum = r.H_b @ s.base_twist_orbit + r.H_bm @ s.joint_rates_radps
        assert relative_error(r.linear_momentum_nms, momentum[:3]) <= RTOL_REFERENCE_METHODS
        h_w = r.kinematics.rot_orbit_from_base @ (spin_kgm2 * s.wheel_rates_radps)
        eq3 = r.H_b_tilde @ s.omega_base_orbit_radps + r.H_bm_tilde @ s.joint_rates_radps + h_w
        assert relative_error(r.angular_momentum_nms, eq3) <= RTOL_REFERENCE_METHODS
        # H~ is the Schur complement of H_b's linear block (v_b eliminated through P).
        m = r.total_mass_kg
        coupling = r.H_b[3:, :3]
        schur_b = r.H_b[3:, 3:] - coupling @ r.H_b[:3, 3:] / m
        schur_bm = r.H_bm[3:] - coupling @ r.H_bm[:3] / m
        assert relative_error(r.H_b_tilde, schur_b) <= RTOL_REFERENCE_METHODS
        assert relative_error(r.H_bm_tilde, schur_bm) <= RTOL_REFERENCE_METHODS


# --- 3. finite differences of the project's hand kinematics ----------------------------------


def hand_twist_fd(workspace: DynamicsWorkspace, plus: State, minus: State, nominal: State) -> Array:
    """(hand-point velocity, hand angular velocity), orbit frame, per unit step."""
    hp, hm, h0 = workspace.hand_pose(plus), workspace.hand_pose(minus), workspace.hand_pose(nominal)
    vel = (hp.pos_orbit_m - hm.pos_orbit_m) / (2.0 * FD_STEP)
    rot_rate = (hp.rot_orbit_from_hand - hm.rot_orbit_from_hand) / (2.0 * FD_STEP)
    omega = ref.vee(rot_rate @ h0.rot_orbit_from_hand.T)
    return np.concatenate([vel, omega])


@pytest.fixture(scope="module")
def fd_states() -> list[State]:
    rng = np.random.default_rng(7)
    return [random_state(rng) for _ in range(6)]


def test_joint_finite_differences_match_J_m(
    workspace: DynamicsWorkspace, fd_states: list[State]
) -> None:
    for s in fd_states:
        J_m = workspace.evaluate(s).J_m
        for j in range(6):
            step = FD_STEP * np.eye(6)[j]
            twist = hand_twist_fd(
                workspace,
                with_(s, joints_rad=s.joints_rad + step),
                with_(s, joints_rad=s.joints_rad - step),
                s,
            )
            np.testing.assert_allclose(
                J_m[:, j], twist, rtol=0.0, atol=FD_ATOL, err_msg=f"J_m column {j}"
            )


def test_base_finite_differences_match_J_b(
    workspace: DynamicsWorkspace, fd_states: list[State]
) -> None:
    for s in fd_states:
        J_b = workspace.evaluate(s).J_b
        for k in range(3):
            step = FD_STEP * np.eye(3)[k]
            twist = hand_twist_fd(
                workspace,
                with_(s, pos_base_orbit_m=s.pos_base_orbit_m + step),
                with_(s, pos_base_orbit_m=s.pos_base_orbit_m - step),
                s,
            )
            np.testing.assert_allclose(
                J_b[:, k], twist, rtol=0.0, atol=FD_ATOL, err_msg=f"J_b linear column {k}"
            )
            # A small rotation about orbit axis k, applied on the left: w_b in the orbit frame.
            quats = [
                ref.quat_multiply_xyzw(
                    ref.quat_xyzw_about_axis(np.eye(3)[k], sign * FD_STEP),
                    s.quat_orbit_from_base_xyzw,
                )
                for sign in (1.0, -1.0)
            ]
            twist = hand_twist_fd(
                workspace,
                with_(s, quat_orbit_from_base_xyzw=quats[0]),
                with_(s, quat_orbit_from_base_xyzw=quats[1]),
                s,
            )
            np.testing.assert_allclose(
                J_b[:, 3 + k], twist, rtol=0.0, atol=FD_ATOL, err_msg=f"J_b angular column {k}"
            )


# --- 4. anchors: pose A and the total mass -------------------------------------------------

POSE_A_ROBOT_M = np.array([1.162, -0.267, 1.497])
TOTAL_MASS_KG = 2690.4  # 2550 + 35 + 22.5 + 21.9 + 16.5 + 26 + 18.5


def test_all_zero_pose_puts_the_hand_at_A(model: RobotModel, workspace: DynamicsWorkspace) -> None:
    state = State(joints_rad=np.zeros(6))
    q = workspace.evaluate(state)
    # The table is built so that A is exact; 1e-12 m allows only float round-off.
    np.testing.assert_allclose(q.hand.pos_robot_m, POSE_A_ROBOT_M, rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(q.hand.rot_robot_from_hand, np.eye(3), rtol=0.0, atol=1e-12)
    robot_origin_base_m = np.array([-0.785, -0.295, 1.000])
    np.testing.assert_allclose(
        q.hand.pos_base_m, POSE_A_ROBOT_M + robot_origin_base_m, rtol=0.0, atol=1e-12
    )
    r = reference_at(model, state).kinematics
    np.testing.assert_allclose(r.hand_pos_robot_m, POSE_A_ROBOT_M, rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(r.rot_robot_from_hand, np.eye(3), rtol=0.0, atol=1e-12)


def test_total_mass(model: RobotModel, workspace: DynamicsWorkspace) -> None:
    # Sums of a few decimal numbers: 1e-9 kg is float round-off, far below any real slip.
    q = workspace.evaluate(State(joints_rad=np.zeros(6)))
    for what, mass_kg in (
        ("Quantities", q.total_mass_kg),
        ("RobotModel", model.total_mass_kg),
        ("reference", ref.TOTAL_MASS_KG),
    ):
        assert abs(mass_kg - TOTAL_MASS_KG) <= 1e-9, f"{what}: {mass_kg!r} kg"


def test_reference_reaches_pose_B_at_the_spec_joints() -> None:
    """SPEC 1.2/7: B (1.170, 0.407, 0.490) m, rpy (0, 90, -37) deg at joints
    (31.6, 21.4, -8.8, 77.4, 0.0, 68.6) deg. The joints are given to 0.1 deg (up to 1.7 mrad
    times a reach of ~1.7 m), hence 5 mm and 0.5 deg."""
    joints_rad = np.radians([31.6, 21.4, -8.8, 77.4, 0.0, 68.6])
    kin = ref.forward_kinematics(joints_rad, np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3))
    np.testing.assert_allclose(kin.hand_pos_robot_m, [1.170, 0.407, 0.490], rtol=0.0, atol=5e-3)
    pitch, yaw = np.radians(90.0), np.radians(-37.0)
    rot_z = np.array(
        [[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]]
    )
    rot_y = np.array(
        [[np.cos(pitch), 0.0, np.sin(pitch)], [0.0, 1.0, 0.0], [-np.sin(pitch), 0.0, np.cos(pitch)]]
    )
    rot_b = rot_z @ rot_y  # Rz(yaw) Ry(pitch) Rx(0)
    err_rad = np.arccos(np.clip((np.trace(rot_b.T @ kin.rot_robot_from_hand) - 1.0) / 2.0, -1, 1))
    assert err_rad < np.radians(0.5)


# --- 5. reaction null space (eq. 4-5) ------------------------------------------------------

# Products of O(1) orthonormal factors from one SVD: round-off is ~1e-15.
ATOL_RNS = 1e-12


def test_rns_projector_and_basis(cases: list[Case]) -> None:
    for c in cases:
        q = c.project
        proj, basis = q.rns_projector, q.rns_basis
        assert basis.shape == (6, 3)
        np.testing.assert_allclose(proj, proj.T, rtol=0.0, atol=ATOL_RNS)
        np.testing.assert_allclose(proj @ proj, proj, rtol=0.0, atol=ATOL_RNS)
        assert np.trace(proj) == pytest.approx(3.0, abs=ATOL_RNS)
        assert np.linalg.matrix_rank(proj, tol=1e-6) == 3  # n - 3
        np.testing.assert_allclose(basis.T @ basis, np.eye(3), rtol=0.0, atol=ATOL_RNS)
        np.testing.assert_allclose(proj @ basis, basis, rtol=0.0, atol=ATOL_RNS)
        # Reactionless: no angular momentum, no base rotation (relative to the matrices' size).
        scale = np.abs(q.H_bm_tilde).max()
        np.testing.assert_allclose(q.H_bm_tilde @ basis / scale, 0.0, rtol=0.0, atol=ATOL_RNS)
        scale = np.abs(q.reaction_map).max()
        np.testing.assert_allclose(q.reaction_map @ basis / scale, 0.0, rtol=0.0, atol=ATOL_RNS)
        assert q.coupling_min_singular_kgm2 > 0.0


# --- 6. gravity gradient (eq. 11-13) -------------------------------------------------------

GRADIENT_COEFFICIENT_PS2 = 3.0 * 3.986004418e14 / (6378.137e3 + 550e3) ** 3  # 3 mu / R^3


def test_gravity_gradient_earth_pointing_is_eq13(
    cases: list[Case], workspace: DynamicsWorkspace
) -> None:
    identity_xyzw = np.array([0.0, 0.0, 0.0, 1.0])
    for c in cases[:6]:
        q = workspace.evaluate(with_(c.state, quat_orbit_from_base_xyzw=identity_xyzw))
        inertia = q.inertia_com_base_kgm2
        expected = GRADIENT_COEFFICIENT_PS2 * np.array([-inertia[1, 2], inertia[0, 2], 0.0])
        assert relative_error(q.gravity_gradient_torque_base_nm, expected) <= RTOL_REFERENCE
        assert q.gravity_gradient_torque_base_nm[2] == 0.0  # never about yaw
        assert np.abs(q.gravity_gradient_torque_base_nm[:2]).max() > 1e-5  # Ixz = 120 kg m^2


def test_gravity_gradient_vanishes_with_a_principal_axis_at_the_earth() -> None:
    orbit = Orbit()
    inertia = np.diag([6200.0, 3540.0, 7090.0])
    # Base z nadir (identity), then base x nadir: Ry(-90 deg) maps base x to orbit z.
    rot_x_nadir = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    for rot in (np.eye(3), rot_x_nadir):
        torque = gravity_gradient_torque_base_nm(inertia, rot, orbit)
        np.testing.assert_allclose(torque, 0.0, rtol=0.0, atol=1e-12)
    # A 30 deg roll leaves no principal axis on the nadir: nadir in the base frame is
    # (0, sin, cos), so N_x = 3 mu / R^3 (Izz - Iyy) sin cos. It turns the axis of least
    # inertia toward the vertical: with Izz > Iyy it increases the roll (z-nadir is unstable).
    roll = np.radians(30.0)
    rot_roll = ref.matrix_from_quat_xyzw(ref.quat_xyzw_about_axis(np.eye(3)[0], roll))
    torque = gravity_gradient_torque_base_nm(inertia, rot_roll, orbit)
    expected_x = GRADIENT_COEFFICIENT_PS2 * (7090.0 - 3540.0) * np.sin(roll) * np.cos(roll)
    np.testing.assert_allclose(torque, [expected_x, 0.0, 0.0], rtol=1e-12, atol=1e-15)


def test_gravity_gradient_function_matches_reference_at_random_attitudes() -> None:
    rng = np.random.default_rng(11)
    orbit = Orbit()
    for _ in range(20):
        root = rng.normal(size=(3, 3))
        inertia = root @ root.T * 1000.0 + 100.0 * np.eye(3)
        rot = ref.matrix_from_quat_xyzw(random_unit_quat_xyzw(rng))
        assert (
            relative_error(
                gravity_gradient_torque_base_nm(inertia, rot, orbit),
                ref.gravity_gradient_torque_base_nm(inertia, rot),
            )
            <= RTOL_REFERENCE
        )


# --- 7. conventions pinned (planner.mujoco_conventions) ------------------------------------


def test_quaternion_order_conversions() -> None:
    half = np.sqrt(0.5)
    about_z_90_xyzw = np.array([0.0, 0.0, half, half])
    np.testing.assert_array_equal(quat_wxyz_from_xyzw(about_z_90_xyzw), [half, 0.0, 0.0, half])
    np.testing.assert_array_equal(
        quat_xyzw_from_wxyz(np.array([half, 0.0, 0.0, half])), about_z_90_xyzw
    )
    # All three readings of that quaternion give the same matrix: x -> y, y -> -x.
    expected = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    mat_mujoco = np.zeros(9)
    mujoco.mju_quat2Mat(mat_mujoco, quat_wxyz_from_xyzw(about_z_90_xyzw))
    np.testing.assert_allclose(mat_mujoco.reshape(3, 3), expected, rtol=0.0, atol=1e-15)
    np.testing.assert_allclose(matrix_from_quat_xyzw(about_z_90_xyzw), expected, atol=1e-15)
    np.testing.assert_allclose(ref.matrix_from_quat_xyzw(about_z_90_xyzw), expected, atol=1e-15)
    rng = np.random.default_rng(3)
    for _ in range(10):
        quat = random_unit_quat_xyzw(rng)
        np.testing.assert_array_equal(quat_xyzw_from_wxyz(quat_wxyz_from_xyzw(quat)), quat)


@pytest.fixture(scope="module")
def mj(model: RobotModel) -> tuple[mujoco.MjModel, mujoco.MjData, MjLayout]:
    mjm = compile_model(model)
    return mjm, mujoco.MjData(mjm), MjLayout.of(mjm, 6, 3)


def test_write_read_state_round_trip(mj: tuple[mujoco.MjModel, mujoco.MjData, MjLayout]) -> None:
    _, mjd, layout = mj
    rng = np.random.default_rng(5)
    for _ in range(5):
        state = random_state(rng)
        write_state(mjd, layout, state)
        back = read_state(mjd, layout)
        for name in (
            "joints_rad",
            "quat_orbit_from_base_xyzw",
            "pos_base_orbit_m",
            "vel_base_orbit_mps",
            "omega_base_orbit_radps",
            "joint_rates_radps",
            "wheel_rates_radps",
        ):
            # Only R (R^T w) and a renormalisation touch the numbers: float round-off.
            np.testing.assert_allclose(
                getattr(back, name), getattr(state, name), rtol=0.0, atol=1e-15, err_msg=name
            )


def test_free_joint_angular_velocity_is_in_the_body_frame(
    mj: tuple[mujoco.MjModel, mujoco.MjData, MjLayout],
) -> None:
    mjm, mjd, layout = mj
    quat_xyzw = ref.quat_xyzw_about_axis(np.array([1.0, 2.0, 2.0]) / 3.0, np.radians(70.0))
    omega_orbit_radps = np.array([0.01, -0.02, 0.03])
    vel_orbit_mps = np.array([0.1, 0.2, -0.3])
    state = State(
        joints_rad=np.radians([10.0, -20.0, 30.0, 40.0, -50.0, 60.0]),
        quat_orbit_from_base_xyzw=quat_xyzw,
        pos_base_orbit_m=np.array([1.0, -2.0, 0.5]),
        vel_base_orbit_mps=vel_orbit_mps,
        omega_base_orbit_radps=omega_orbit_radps,
    )
    rot_orbit_from_base = ref.matrix_from_quat_xyzw(quat_xyzw)
    omega_base_radps = rot_orbit_from_base.T @ omega_orbit_radps
    # The attitude is far enough from identity that the two frames are told apart.
    assert np.linalg.norm(omega_base_radps - omega_orbit_radps) > 0.01
    write_state(mjd, layout, state)
    np.testing.assert_allclose(mjd.qvel[3:6], omega_base_radps, rtol=0.0, atol=1e-15)
    mujoco.mj_forward(mjm, mjd)
    base = layout.base_body
    world_rot_lin = np.zeros(6)
    mujoco.mj_objectVelocity(mjm, mjd, mujoco.mjtObj.mjOBJ_BODY, base, world_rot_lin, 0)
    # mj_objectVelocity: (angular, linear) at the body origin (the base CoM), world = orbit.
    np.testing.assert_allclose(world_rot_lin[:3], omega_orbit_radps, rtol=0.0, atol=1e-15)
    np.testing.assert_allclose(world_rot_lin[3:], vel_orbit_mps, rtol=0.0, atol=1e-15)
    # cvel's angular part is the world-frame angular velocity as well.
    np.testing.assert_allclose(mjd.cvel[base][:3], omega_orbit_radps, rtol=0.0, atol=1e-15)
