"""Servo-lag compensation (beyond the paper): pre-shape joint commands so that the lagging
joint servos follow the planned path, and with it the reaction null space.

Each servo is a PD law without rate feed-forward (:mod:`planner.simulation`),
``tau = kp (r - q) - kd q'``, with its own gains: the joints lag by different times
(ETS-VII: ``planner.simulation.ETS7_SERVO_LAG_S``), and the shaping below uses each joint's
``kp`` and ``kd``. The arm on its free-floating base obeys
``H* q'' + c = tau`` with ``H* = H_m - H_bm^T H_b^-1 H_bm`` the arm's inertia with the base
free to react (eq. 1 with ``x_b''`` eliminated). For the joints to follow ``q_d(t)`` the
command must therefore be

    r = q_d + kp^-1 (kd q_d' + H*(q_d) q_d'')

(the velocity terms ``c`` are left out: quadratic in the slow joint rates). The diagonal of
``H*`` alone is not enough: at the reactionless path's start and stop the joints' coupling
through ``H*`` is what bends the lagging path off the null space. Derivatives come from the
4 Hz commands by central differences.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from planner.dynamics import DynamicsWorkspace
from planner.mjcf import ServoGains
from planner.state import State

__all__ = ["compensate_servo_lag"]

Array = NDArray[np.float64]


def compensate_servo_lag(
    ws: DynamicsWorkspace, gains: ServoGains, command_times_s: Array, desired_joints_rad: Array
) -> Array:
    """Commands (k, n) that make the servos track ``desired_joints_rad`` (k, n).

    The result is clipped to the joint limits (the onboard limit would clip it anyway).
    """
    times = np.asarray(command_times_s, dtype=np.float64)
    desired = np.asarray(desired_joints_rad, dtype=np.float64)
    if desired.shape[0] < 3:
        return desired.copy()
    rate = np.gradient(desired, times, axis=0)
    accel = np.gradient(rate, times, axis=0)
    shaped = desired.copy()
    for k, q in enumerate(desired):
        if not (np.any(rate[k]) or np.any(accel[k])):
            continue  # holding still: nothing to compensate
        quantities = ws.evaluate(State(joints_rad=q))
        h_star = quantities.H_m - quantities.H_bm.T @ np.linalg.solve(
            quantities.H_b, quantities.H_bm
        )
        torque = gains.kd_nms_per_rad * rate[k] + h_star @ accel[k]
        shaped[k] = q + torque / gains.kp_nm_per_rad
    lo, hi = ws.model.joint_limit_rad[:, 0], ws.model.joint_limit_rad[:, 1]
    return np.asarray(np.clip(shaped, lo, hi))
