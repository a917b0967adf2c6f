"""Dynamics quantities of the free-flying robot at one state (SPEC section 2).

All quantities come from one MuJoCo evaluation (kinematics and composite rigid body) and
are converted to the project's conventions (:mod:`planner.state`): base twist
``x_b' = (v_b, w_b)`` in the orbit frame, linear rows before angular rows, hand velocity of
the hand point in the orbit frame.

A :class:`DynamicsWorkspace` owns MuJoCo scratch memory; it is cheap to call repeatedly and
must not be shared between threads (make one per thread, as with pinocchio's ``Data``).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from numpy.typing import NDArray
from scipy.linalg import lapack

from planner.errors import DidNotConverge
from planner.gravity_gradient import Orbit, gravity_gradient_torque_base_nm
from planner.mjcf import compile_model
from planner.model import RobotModel
from planner.mujoco_conventions import MjLayout, velocity_matrix_to_ours, write_state
from planner.state import State

__all__ = ["DynamicsWorkspace", "HandPose", "Quantities", "solve_small"]

Array = NDArray[np.float64]


def solve_small(a: Array, b: Array) -> Array:
    """``np.linalg.solve(a, b)`` of a small system: LAPACK's dgesv, which numpy calls (the
    same numbers), without numpy's wrapper, a fifth of its cost (the predictions call it at
    every Runge-Kutta stage). A singular ``a`` goes to numpy, to raise its error."""
    _, _, x, info = lapack.dgesv(a, b)
    if info != 0:
        return np.asarray(np.linalg.solve(a, b))
    return np.asarray(x)


@dataclass(frozen=True, eq=False)
class HandPose:
    """Hand point and orientation in the robot, base and orbit frames."""

    pos_robot_m: Array
    rot_robot_from_hand: Array
    pos_base_m: Array
    rot_base_from_hand: Array
    pos_orbit_m: Array
    rot_orbit_from_hand: Array


@dataclass(frozen=True, eq=False)
class Quantities:
    """Everything the planners need at one state. Orbit frame unless a name says otherwise.

    Shapes for n joints: ``J_b`` (6, 6), ``J_m`` (6, n), ``H_b`` (6, 6), ``H_bm`` (6, n),
    ``H_m`` (n, n), ``H_b_tilde`` (3, 3), ``H_bm_tilde`` (3, n), ``reaction_map`` (3, n),
    ``J_g`` (6, n), ``rns_projector`` (n, n), ``rns_basis`` (n, n - 3).
    """

    hand: HandPose
    total_mass_kg: float
    com_orbit_m: Array
    #: eq. (6): hand twist ``x_h' = J_b x_b' + J_m phi'``.
    J_b: Array
    J_m: Array
    #: eq. (1): inertia blocks for ``(x_b', phi')``, wheels locked (part of the base).
    H_b: Array
    H_bm: Array
    H_m: Array
    #: eq. (2): linear momentum (kg m/s).
    linear_momentum_nms: Array
    #: eq. (3) plus wheels: angular momentum about the system CoM (N m s).
    angular_momentum_nms: Array
    #: wheel rotors' momentum relative to the base, ``I_w * rate`` along each axis (N m s).
    wheel_momentum_nms: Array
    #: eq. (3): ``L = H~_b w_b + H~_bm phi' + h_w`` about the system CoM.
    H_b_tilde: Array
    H_bm_tilde: Array
    #: eq. (9): ``w_b = reaction_map @ phi'`` at zero momentum, ``-H~_b^-1 H~_bm``.
    reaction_map: Array
    #: eq. (8): ``J_g = J_m - J_b H_b^-1 H_bm``.
    J_g: Array
    #: eq. (5): ``I - H~_bm^+ H~_bm`` and an orthonormal basis of its range.
    rns_projector: Array
    rns_basis: Array
    #: smallest singular value of ``H~_bm`` (kg m^2); near 0 the RNS gains a dimension.
    coupling_min_singular_kgm2: float
    #: H_c, the whole system's inertia about its CoM (equal to ``H_b_tilde``), base frame.
    inertia_com_base_kgm2: Array
    #: eq. (11), base frame (N m).
    gravity_gradient_torque_base_nm: Array

    @property
    def inertia_com_orbit_kgm2(self) -> Array:
        """H_c in the orbit frame (the same matrix as ``H_b_tilde``)."""
        return self.H_b_tilde


class DynamicsWorkspace:
    """Evaluates :class:`Quantities` of ``model`` at any :class:`State`."""

    def __init__(self, model: RobotModel, orbit: Orbit | None = None) -> None:
        self.model = model
        self.orbit = orbit or Orbit()
        self._mjm = compile_model(model)
        self._mjd = mujoco.MjData(self._mjm)
        self._layout = MjLayout.of(self._mjm, model.n_joints, len(model.wheels))
        n = model.n_joints
        nv = self._mjm.nv
        self._full_m = np.zeros((nv, nv))
        self._jac = np.zeros((6, nv))
        self._spin_inertia_kgm2 = np.array([w.spin_inertia_kgm2 for w in model.wheels])
        self._n = n
        self._total_mass_kg = float(mujoco.mj_getTotalmass(self._mjm))

    # -- evaluation ----------------------------------------------------------------------

    def _load(self, state: State) -> Array:
        write_state(self._mjd, self._layout, state)
        mujoco.mj_kinematics(self._mjm, self._mjd)
        mujoco.mj_comPos(self._mjm, self._mjd)
        return np.asarray(self._mjd.xmat[self._layout.base_body].reshape(3, 3))

    def _hand_pose(self, state: State, rot_orbit_from_base: Array) -> HandPose:
        d, site = self._mjd, self._layout.hand_site
        pos_orbit = d.site_xpos[site].copy()
        rot_orbit_from_hand = d.site_xmat[site].reshape(3, 3).copy()
        pos_base = (pos_orbit - state.pos_base_orbit_m) @ rot_orbit_from_base
        rot_base_from_hand = rot_orbit_from_base.T @ rot_orbit_from_hand
        # The robot frame is parallel to the base frame.
        return HandPose(
            pos_robot_m=pos_base - self.model.pos_base_from_robot_m,
            rot_robot_from_hand=rot_base_from_hand,
            pos_base_m=pos_base,
            rot_base_from_hand=rot_base_from_hand,
            pos_orbit_m=pos_orbit,
            rot_orbit_from_hand=rot_orbit_from_hand,
        )

    def hand_pose(self, state: State) -> HandPose:
        """Forward kinematics only."""
        rot = self._load(state)
        return self._hand_pose(state, rot)

    def com_orbit_m(self, state: State) -> Array:
        """The system's centre of mass, orbit frame: the kinematics only (the same numbers
        as :meth:`evaluate`'s ``com_orbit_m``, without the inertia and the solves)."""
        self._load(state)
        com: Array = self._mjd.subtree_com[self._layout.base_body].copy()
        return com

    def hand_jacobian(self, state: State) -> tuple[HandPose, Array, Array]:
        """Hand pose with ``J_b`` (6, 6) and ``J_m`` (6, n), eq. (6)."""
        rot = self._load(state)
        return self._hand_pose(state, rot), *self._jacobians(rot)

    def _jacobians(self, rot: Array) -> tuple[Array, Array]:
        jac = self._jac
        mujoco.mj_jacSite(self._mjm, self._mjd, jac[:3], jac[3:], self._layout.hand_site)
        jac = velocity_matrix_to_ours(jac, rot, rows=False)
        return jac[:, :6], jac[:, 6 : 6 + self._n]

    def momentum_blocks(self, joints_rad: Array) -> tuple[Array, Array]:
        """``H~_b`` (3, 3) and ``H~_bm`` (3, n) in the **base** frame at these joints (eq. 3).

        The fast path for integrating eq. (9)-(10): in the base frame both depend on the
        joint angles only. ``reaction_map = -solve(H~_b, H~_bm)``.
        """
        self._load_nominal(joints_rad)
        return self._momentum_blocks_loaded()

    def hand_and_coupling(self, joints_rad: Array) -> tuple[Array, Array, Array, Array]:
        """The base at its nominal pose (at the origin, the orbit frame's attitude):
        the hand's position (m) and orientation in the robot frame, ``J_m`` (6, n) and
        ``H~_bm`` (3, n), the numbers of :meth:`hand_jacobian` (a :class:`State` of these
        joints) and :meth:`momentum_blocks` from one kinematics pass and without a State's
        checks (the reactionless line's inner loop)."""
        d, site = self._load_nominal(joints_rad), self._layout.hand_site
        # the robot frame is the base's, the base's the orbit's (as _hand_pose at identity)
        pos = d.site_xpos[site] - self.model.pos_base_from_robot_m
        rot = d.site_xmat[site].reshape(3, 3).copy()
        mujoco.mj_jacSite(self._mjm, d, self._jac[:3], self._jac[3:], site)
        J_m = self._jac[:, 6 : 6 + self._n].copy()  # the joints' columns: no conversion
        return pos, rot, J_m, self._momentum_blocks_loaded()[1]

    def _load_nominal(self, joints_rad: Array) -> mujoco.MjData:
        d = self._mjd
        d.qpos[:] = self._mjm.qpos0
        d.qpos[self._layout.joint_qpos] = joints_rad
        mujoco.mj_kinematics(self._mjm, d)
        mujoco.mj_comPos(self._mjm, d)
        return d

    def _momentum_blocks_loaded(self) -> tuple[Array, Array]:
        mujoco.mj_crb(self._mjm, self._mjd)
        mujoco.mj_fullM(self._mjm, self._mjd, self._full_m)
        big_m = self._full_m  # base at identity: MuJoCo's coordinates are ours
        n = self._n
        tilde = big_m[3:6, 3 : 6 + n] - big_m[3:6, :3] @ big_m[:3, 3 : 6 + n] / (
            self._total_mass_kg
        )
        return tilde[:, :3].copy(), tilde[:, 3:].copy()

    def evaluate(self, state: State) -> Quantities:
        """All quantities at ``state``."""
        n = self._n
        rot = self._load(state)
        mujoco.mj_crb(self._mjm, self._mjd)
        mujoco.mj_fullM(self._mjm, self._mjd, self._full_m)
        big_m = velocity_matrix_to_ours(self._full_m, rot, rows=True)
        hand = self._hand_pose(state, rot)
        J_b, J_m = self._jacobians(rot)

        H_b = big_m[:6, :6]
        H_bm = big_m[:6, 6 : 6 + n]
        H_m = big_m[6 : 6 + n, 6 : 6 + n]
        mass = self._total_mass_kg
        com = self._mjd.subtree_com[self._layout.base_body].copy()
        # Schur complement of the linear block: eliminating v_b with eq. (2) gives eq. (3).
        # Row block for (w_b, phi', wheel rates) about the system CoM:
        tilde = big_m[3:6, 3:] - big_m[3:6, :3] @ big_m[:3, 3:] / mass
        H_b_tilde = tilde[:, :3]
        H_bm_tilde = tilde[:, 3 : 3 + n]

        qvel = np.concatenate(
            [
                state.vel_base_orbit_mps,
                state.omega_base_orbit_radps,
                state.joint_rates_radps,
                state.wheel_rates_radps,
            ]
        )
        linear_momentum = big_m[:3] @ qvel
        angular_momentum = tilde @ qvel[3:]

        # One 3x3 solve serves eq. (9) and eq. (8): with X = H_b^-1 H_bm split into its
        # linear and angular rows, X_w = H~_b^-1 H~_bm and X_v = (H_vm - H_vw X_w) / m.
        _, _, x_w, info = lapack.dgesv(H_b_tilde, H_bm_tilde)
        if info != 0:
            raise DidNotConverge(f"H~_b is singular (LAPACK dgesv info {info})")
        x_v = (H_bm[:3, :] - H_b[:3, 3:] @ x_w) / mass
        J_g = J_m - J_b[:, :3] @ x_v - J_b[:, 3:] @ x_w
        reaction_map = -x_w
        _, sing, vt, info = lapack.dgesdd(H_bm_tilde)
        if info != 0:
            raise DidNotConverge(f"SVD of H~_bm failed (LAPACK dgesdd info {info})")
        rns_basis = vt[3:].T
        inertia_base = rot.T @ H_b_tilde @ rot
        return Quantities(
            hand=hand,
            total_mass_kg=mass,
            com_orbit_m=com,
            J_b=J_b,
            J_m=J_m,
            H_b=H_b,
            H_bm=H_bm,
            H_m=H_m,
            linear_momentum_nms=linear_momentum,
            angular_momentum_nms=angular_momentum,
            wheel_momentum_nms=self._spin_inertia_kgm2 * state.wheel_rates_radps,
            H_b_tilde=H_b_tilde,
            H_bm_tilde=H_bm_tilde,
            reaction_map=reaction_map,
            J_g=J_g,
            rns_projector=rns_basis @ rns_basis.T,
            rns_basis=rns_basis,
            coupling_min_singular_kgm2=float(sing[-1]),
            inertia_com_base_kgm2=inertia_base,
            gravity_gradient_torque_base_nm=gravity_gradient_torque_base_nm(
                inertia_base, rot, self.orbit
            ),
        )
