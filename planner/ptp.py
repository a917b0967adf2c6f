"""Conventional point-to-point (PTP) joint-interpolated motion on the 4 Hz command grid.

All joints move on one quintic time scaling ``s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5``
(zero velocity and acceleration at both ends). Its peak rate is ``15/8 |dq| / T``, so the
duration is the smallest multiple of the command period that keeps every joint within its
rate limit.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from planner.errors import InvalidInput
from planner.model import RobotModel

__all__ = ["COMMAND_PERIOD_S", "QUINTIC_PEAK_RATE_FACTOR", "ptp_commands", "quintic"]

Array = NDArray[np.float64]

#: SPEC section 5: isochronous commands at 4 Hz.
COMMAND_PERIOD_S = 0.25
#: Peak of ds/dtau for the quintic scaling.
QUINTIC_PEAK_RATE_FACTOR = 15.0 / 8.0


def quintic(tau: Array) -> Array:
    """Quintic time scaling on ``tau`` in [0, 1] (clipped outside)."""
    t = np.clip(tau, 0.0, 1.0)
    return np.asarray(t**3 * (10.0 - 15.0 * t + 6.0 * t * t))


def ptp_commands(
    model: RobotModel,
    start_rad: Array,
    goal_rad: Array,
    *,
    rate_fraction: float = 0.9,
    period_s: float = COMMAND_PERIOD_S,
) -> tuple[Array, Array]:
    """Command times (s from the motion's start) and joint targets (k, n) from start to goal.

    ``rate_fraction`` of each joint's rate limit is the most any joint reaches; the first
    command is the start pose, the last the goal.
    """
    start = model.check_joints(start_rad)
    goal = model.check_joints(goal_rad)
    if not 0.0 < rate_fraction <= 1.0:
        raise InvalidInput(f"rate_fraction {rate_fraction} must lie in (0, 1]")
    delta = goal - start
    durations = (
        QUINTIC_PEAK_RATE_FACTOR * np.abs(delta) / (rate_fraction * model.joint_rate_limit_radps)
    )
    n_periods = max(1, math.ceil(float(np.max(durations)) / period_s - 1e-9))
    t = np.arange(n_periods + 1, dtype=np.float64) * period_s
    s = quintic(t / t[-1])
    return t, start + s[:, None] * delta
