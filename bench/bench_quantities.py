"""Time to evaluate every planning quantity at one pose, against the MuJoCo calls alone.

``DynamicsWorkspace.evaluate`` computes hand pose in three frames, J_b, J_m, H_b, H_bm, H_m,
momentum, H~_b, H~_bm, the reaction map, J_g, the RNS projector and basis, H_c and the
gravity-gradient torque. The baseline is the MuJoCo work it cannot avoid (kinematics,
CoM, CRB, dense mass matrix, hand Jacobian). Also timed: forward kinematics alone, IK to
pose B, and the eq. (10) prediction of the PTP A -> B motion.

Target (foundation issue): <= 50 us for all quantities.
"""

from __future__ import annotations

import timeit

import mujoco
import numpy as np
from _common import best_of, emit

from planner.dynamics import DynamicsWorkspace
from planner.frames import matrix_from_rpy
from planner.free_drift import predict_base_attitude
from planner.ik import solve_ik
from planner.model import default_model
from planner.ptp import ptp_commands
from planner.state import State

JOINTS_B_RAD = np.radians([31.6, 21.4, -8.8, 77.4, 0.0, 68.6])


def per_call_us(fn: object, number: int = 5000) -> float:
    times = timeit.repeat(fn, number=number, repeat=5)  # type: ignore[arg-type]
    return min(times) / number * 1e6


def main() -> None:
    model = default_model()
    ws = DynamicsWorkspace(model)
    state = State(
        joints_rad=JOINTS_B_RAD,
        quat_orbit_from_base_xyzw=np.array([0.01, -0.02, 0.03, 1.0]),
        omega_base_orbit_radps=np.array([1e-3, -2e-3, 5e-4]),
        joint_rates_radps=np.radians([0.5, -0.3, 0.2, 0.1, 0.0, 0.4]),
    )
    mjm = ws._mjm
    d = mujoco.MjData(mjm)
    d.qpos[3] = 1.0
    full_m = np.zeros((mjm.nv, mjm.nv))
    jac = np.zeros((6, mjm.nv))
    site = mujoco.mj_name2id(mjm, mujoco.mjtObj.mjOBJ_SITE, "hand")

    def raw_mujoco() -> None:
        mujoco.mj_kinematics(mjm, d)
        mujoco.mj_comPos(mjm, d)
        mujoco.mj_crb(mjm, d)
        mujoco.mj_fullM(mjm, d, full_m)
        mujoco.mj_jacSite(mjm, d, jac[:3], jac[3:], site)

    all_us = per_call_us(lambda: ws.evaluate(state))
    t_cmd, q_cmd = ptp_commands(model, np.zeros(6), JOINTS_B_RAD)
    rot_b = matrix_from_rpy(np.radians([0.0, 90.0, -37.0]))
    figures = {
        "all_quantities_us": all_us,
        "raw_mujoco_calls_us": per_call_us(raw_mujoco),
        "hand_pose_us": per_call_us(lambda: ws.hand_pose(state)),
        "ik_pose_b_ms": best_of(
            lambda: solve_ik(ws, np.array([1.170, 0.407, 0.490]), rot_b), repeat=3
        )
        * 1e3,
        "eq10_prediction_ptp_a_to_b_ms": best_of(
            lambda: predict_base_attitude(ws, t_cmd, q_cmd), repeat=3
        )
        * 1e3,
        "ptp_a_to_b_commands": int(t_cmd.size),
    }
    emit("planning_quantities", figures, {"all_quantities_le_50us": all_us <= 50.0})


if __name__ == "__main__":
    main()
