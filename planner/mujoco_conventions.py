"""The one place that talks MuJoCo's conventions (tests in tests/planner pin them).

MuJoCo stores a free joint as ``qpos = (x, y, z, qw, qx, qy, qz)`` (scalar-first quaternion,
world from body) and ``qvel = (v, w)`` with ``v`` the body-origin linear velocity in the
*world* frame and ``w`` the angular velocity in the *body* frame. The project uses scalar-last
quaternions and the base angular velocity in the *orbit* (world) frame, so

    qvel_mujoco = T @ qvel_ours,  T = blockdiag(I3, R^T, I),  R = rot_orbit_from_base

and matrices that multiply velocities convert as ``M_ours = T^T M_mujoco T`` and
``J_ours = J_mujoco T``. The base body's origin is the base centre of mass, so ``v`` is
the base CoM velocity.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from numpy.typing import NDArray

from planner.frames import matrix_from_quat_xyzw
from planner.state import State

__all__ = [
    "MjLayout",
    "quat_wxyz_from_xyzw",
    "quat_xyzw_from_wxyz",
    "read_state",
    "velocity_matrix_to_ours",
    "write_state",
]

Array = NDArray[np.float64]


def quat_wxyz_from_xyzw(quat_xyzw: Array) -> Array:
    return np.array([quat_xyzw[3], quat_xyzw[0], quat_xyzw[1], quat_xyzw[2]])


def quat_xyzw_from_wxyz(quat_wxyz: Array) -> Array:
    return np.array([quat_wxyz[1], quat_wxyz[2], quat_wxyz[3], quat_wxyz[0]])


@dataclass(frozen=True)
class MjLayout:
    """Where base, joints and wheels sit in a compiled model's qpos/qvel and body list.

    qvel is ordered as our generalised velocities: base (6), joints (n), wheels (3).
    """

    base_body: int
    hand_site: int
    link_bodies: tuple[int, ...]
    joint_qpos: slice
    joint_qvel: slice
    wheel_qpos: slice
    wheel_qvel: slice
    n_joints: int

    @classmethod
    def of(cls, mjm: mujoco.MjModel, n_joints: int, n_wheels: int) -> MjLayout:
        def jid(name: str) -> int:
            return int(mujoco.mj_name2id(mjm, mujoco.mjtObj.mjOBJ_JOINT, name))

        root = jid("base_free")
        if mjm.jnt_qposadr[root] != 0 or mjm.jnt_dofadr[root] != 0:
            raise ValueError("the base free joint must come first in qpos and qvel")
        j1, w1 = jid("joint1"), jid("wheel_x")
        qp, qv = int(mjm.jnt_qposadr[j1]), int(mjm.jnt_dofadr[j1])
        wp, wv = int(mjm.jnt_qposadr[w1]), int(mjm.jnt_dofadr[w1])
        if (qp, qv, wp, wv) != (7, 6, 7 + n_joints, 6 + n_joints):
            raise ValueError("qpos/qvel must be ordered base, joints, wheels (planner.state)")
        return cls(
            base_body=int(mujoco.mj_name2id(mjm, mujoco.mjtObj.mjOBJ_BODY, "base")),
            hand_site=int(mujoco.mj_name2id(mjm, mujoco.mjtObj.mjOBJ_SITE, "hand")),
            link_bodies=tuple(
                int(mujoco.mj_name2id(mjm, mujoco.mjtObj.mjOBJ_BODY, f"link{i + 1}"))
                for i in range(n_joints)
            ),
            joint_qpos=slice(qp, qp + n_joints),
            joint_qvel=slice(qv, qv + n_joints),
            wheel_qpos=slice(wp, wp + n_wheels),
            wheel_qvel=slice(wv, wv + n_wheels),
            n_joints=n_joints,
        )


def write_state(mjd: mujoco.MjData, layout: MjLayout, state: State) -> None:
    """Set qpos/qvel from a :class:`State` (wheel angles are left as they are)."""
    x, y, z, w = state.quat_orbit_from_base_xyzw
    mjd.qpos[0:3] = state.pos_base_orbit_m
    mjd.qpos[3:7] = (w, x, y, z)
    mjd.qpos[layout.joint_qpos] = state.joints_rad
    mjd.qvel[0:3] = state.vel_base_orbit_mps
    # body-frame rate: rotate the orbit-frame one by the conjugate quaternion
    omega_body = np.empty(3)
    mujoco.mju_rotVecQuat(omega_body, state.omega_base_orbit_radps, np.array([w, -x, -y, -z]))
    mjd.qvel[3:6] = omega_body
    mjd.qvel[layout.joint_qvel] = state.joint_rates_radps
    mjd.qvel[layout.wheel_qvel] = state.wheel_rates_radps


def read_state(mjd: mujoco.MjData, layout: MjLayout) -> State:
    """The :class:`State` that MuJoCo's qpos/qvel hold."""
    quat_xyzw = quat_xyzw_from_wxyz(mjd.qpos[3:7])
    rot = matrix_from_quat_xyzw(quat_xyzw)
    return State(
        joints_rad=mjd.qpos[layout.joint_qpos].copy(),
        quat_orbit_from_base_xyzw=quat_xyzw,
        pos_base_orbit_m=mjd.qpos[0:3].copy(),
        vel_base_orbit_mps=mjd.qvel[0:3].copy(),
        omega_base_orbit_radps=rot @ mjd.qvel[3:6],
        joint_rates_radps=mjd.qvel[layout.joint_qvel].copy(),
        wheel_rates_radps=mjd.qvel[layout.wheel_qvel].copy(),
    )


def velocity_matrix_to_ours(mat_mj: Array, rot_orbit_from_base: Array, *, rows: bool) -> Array:
    """Convert a matrix acting on MuJoCo's qvel (its columns) to one acting on ours.

    ``rows=True`` also converts the rows (for the mass matrix, ``T^T M T``); ``rows=False``
    only the columns (for Jacobians, ``J T``).
    """
    out = np.array(mat_mj, dtype=np.float64)
    out[:, 3:6] = out[:, 3:6] @ rot_orbit_from_base.T
    if rows:
        out[3:6, :] = rot_orbit_from_base @ out[3:6, :]
    return out
