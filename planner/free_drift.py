"""Base attitude predicted from commanded arm motion in free drift, SPEC eq. (9)-(10).

With zero momentum and ideal joint tracking the base turns at
``w_b = -H~_b^-1 H~_bm phi'`` (eq. 9); its integral is the attitude change the arm causes
(eq. 10). Joint targets move linearly between consecutive commands, as on board, so
``phi'`` is constant on each command interval; the attitude is integrated with RK4 on the
unit quaternion, ``sub_steps`` per interval.

Both quantities depend only on the joint angles when expressed in the base frame, so the
reaction map is evaluated once at the base's nominal attitude and rotated.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from planner.dynamics import DynamicsWorkspace
from planner.errors import InvalidInput
from planner.frames import IDENTITY_QUAT_XYZW

__all__ = ["predict_base_attitude", "quat_multiply_xyzw"]

Array = NDArray[np.float64]


def quat_multiply_xyzw(a: Array | Sequence[float], b: Array | Sequence[float]) -> Array:
    """Hamilton product ``a * b`` of scalar-last quaternions."""
    # as Python floats: the same IEEE arithmetic as numpy's scalars, at a fraction of the cost
    ax, ay, az, aw = np.asarray(a, dtype=np.float64).tolist()
    bx, by, bz, bw = np.asarray(b, dtype=np.float64).tolist()
    return np.array(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ]
    )


def _omega_base(ws: DynamicsWorkspace, joints: Array, rates: Array) -> Array:
    """Eq. (9) in the base frame."""
    h_b, h_bm = ws.momentum_blocks(joints)
    return np.asarray(-np.linalg.solve(h_b, h_bm @ rates))


def predict_base_attitude(
    ws: DynamicsWorkspace,
    command_times_s: Array,
    command_joints_rad: Array,
    *,
    initial_quat_orbit_from_base_xyzw: Array | None = None,
    sub_steps: int = 4,
) -> tuple[Array, Array]:
    """Base attitude at each command time and the base angular velocity (base frame) on each
    interval's midpoint, for ideal tracking of linearly interpolated commands at zero momentum.

    Returns ``quat_orbit_from_base_xyzw`` (k, 4) and ``omega_base_radps`` (k - 1, 3).
    """
    times = np.asarray(command_times_s, dtype=np.float64)
    joints = np.asarray(command_joints_rad, dtype=np.float64)
    if times.ndim != 1 or joints.shape != (times.size, ws.model.n_joints) or times.size < 1:
        raise InvalidInput("command times (k,) and joints (k, n) do not match")
    if np.any(np.diff(times) <= 0.0):
        raise InvalidInput("command times must increase")
    quat = (
        IDENTITY_QUAT_XYZW.copy()
        if initial_quat_orbit_from_base_xyzw is None
        else np.asarray(initial_quat_orbit_from_base_xyzw, dtype=np.float64)
    )
    quats = [quat]
    omegas = []
    for k in range(times.size - 1):
        dt = (times[k + 1] - times[k]) / sub_steps
        rate = (joints[k + 1] - joints[k]) / (times[k + 1] - times[k])

        def deriv(quat_now: Array, tau: float, k: int = k, rate: Array = rate) -> Array:
            w = _omega_base(ws, joints[k] + rate * tau, rate)
            return 0.5 * quat_multiply_xyzw(quat_now, np.array([w[0], w[1], w[2], 0.0]))

        for j in range(sub_steps):
            tau = j * dt
            k1 = deriv(quat, tau)
            k2 = deriv(quat + 0.5 * dt * k1, tau + 0.5 * dt)
            k3 = deriv(quat + 0.5 * dt * k2, tau + 0.5 * dt)
            k4 = deriv(quat + dt * k3, tau + dt)
            quat = quat + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            quat = quat / np.linalg.norm(quat)
        quats.append(quat)
        mid = 0.5 * (times[k + 1] - times[k])
        omegas.append(_omega_base(ws, joints[k] + rate * mid, rate))
    return np.array(quats), np.array(omegas).reshape(-1, 3)
