"""The joint servos as the flight rules fly them.

Each joint's PD servo on its own inertia at the reference pose, ``H_ii q'' = kp (q_c - q) -
kd q'`` (the vehicle's servo law, decoupled), driven by the commands linear between their
times (as on board), solved exactly on a fine grid (:func:`servo_response`, scipy's ``lsim``
with first-order hold). A robot's :class:`ServoModel` is
:meth:`planner.robot.RobotDescription.servo_model`; :func:`planner.flight_check.check_plan`
checks the motion it gives.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["ServoModel", "servo_response"]

Array = NDArray[np.float64]


@dataclass(frozen=True)
class ServoModel:
    """Each joint's servo as a decoupled second-order system: ``q'' = a (q_c - q) - b q'``
    with ``a = kp / H_ii`` and ``b = kd / H_ii`` (H at the reference pose)."""

    stiffness: Array  # a, 1/s^2
    damping: Array  # b, 1/s

    @property
    def rate_overshoot(self) -> Array:
        """How far each joint's rate may exceed its commanded rate (a fraction): the step
        response's overshoot of the rate loop at its damping ratio (0 when over-damped)."""
        zeta = self.damping / (2.0 * np.sqrt(self.stiffness))
        under = zeta < 1.0
        out = np.zeros_like(zeta)
        z = zeta[under]
        out[under] = np.exp(-math.pi * z / np.sqrt(1.0 - z * z))
        return out


def servo_response(
    servo: ServoModel,
    command_times_s: Array,
    command_joints_rad: Array,
    initial_joints_rad: Array,
    sample_times_s: Array,
) -> tuple[Array, Array]:
    """Joint angles and rates ``(S, n)`` at ``sample_times_s`` (which hold every command
    time): the servos, at rest at ``initial_joints_rad`` at time 0, driven by the commands
    linear between their times (held before the first and after the last)."""
    from scipy import signal  # 0.8 s to import: only where a plan is checked

    n = command_joints_rad.shape[1]
    a = np.asarray(servo.stiffness, dtype=np.float64)
    b = np.asarray(servo.damping, dtype=np.float64)
    A = np.zeros((2 * n, 2 * n))
    B = np.zeros((2 * n, n))
    for k in range(n):
        A[2 * k, 2 * k + 1] = 1.0
        A[2 * k + 1, 2 * k] = -a[k]
        A[2 * k + 1, 2 * k + 1] = -b[k]
        B[2 * k + 1, k] = a[k]
    C = np.eye(2 * n)
    D = np.zeros((2 * n, n))
    inputs = np.column_stack(
        [np.interp(sample_times_s, command_times_s, command_joints_rad[:, k]) for k in range(n)]
    )
    x0 = np.zeros(2 * n)
    x0[0::2] = initial_joints_rad
    _, y, _ = signal.lsim((A, B, C, D), inputs, sample_times_s, X0=x0, interp=True)
    y = np.atleast_2d(y)
    return np.asarray(y[:, 0::2]), np.asarray(y[:, 1::2])
