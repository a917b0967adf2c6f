"""The arm's reaction on the base, from measured joints: eq. (3)'s ``H~_bm phi'`` and the
hand speed, frame by frame.

Joint rates come from :func:`telemetry.analysis.rates.joint_rates_radps` (the measured joint
angles, differentiated; see that module). At each frame the dynamics quantities are evaluated
by :class:`planner.dynamics.DynamicsWorkspace` at the measured joints and base attitude, so
``H~_bm phi'`` is in the **orbit frame** (as the plan's ``reaction_momentum_orbit_nms``), and
the hand speed is ``|J_m phi'|`` (linear rows): the hand point's speed relative to the base.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner.dynamics import DynamicsWorkspace
from planner.state import State
from telemetry.analysis._common import Array
from telemetry.analysis.rates import joint_rates_radps

__all__ = ["ArmReaction", "arm_reaction"]


@dataclass(frozen=True, eq=False)
class ArmReaction:
    """Rows match the frames passed in."""

    joint_rates_radps: Array  # (n, joints)
    reaction_momentum_orbit_nms: Array  # (n, 3), H~_bm phi', orbit frame
    hand_speed_mps: Array  # (n,), relative to the base
    #: H~_b w_b with the gyro's w_b (orbit frame): the base's own momentum, for checks
    base_momentum_orbit_nms: Array  # (n, 3)


def arm_reaction(
    ws: DynamicsWorkspace,
    t_s: Array,
    joints_rad: Array,
    quats_orbit_from_base_xyzw: Array,
    omega_base_in_base_radps: Array,
    *,
    rate_window_s: float = 1.5,
) -> ArmReaction:
    """``H~_bm phi'`` and ``|J_m phi'|`` at every frame (see the module docstring)."""
    rates = joint_rates_radps(t_s, joints_rad, window_s=rate_window_s)
    n = t_s.size
    reaction = np.zeros((n, 3))
    base = np.zeros((n, 3))
    speed = np.zeros(n)
    for k in range(n):
        state = State(
            joints_rad=joints_rad[k],
            quat_orbit_from_base_xyzw=quats_orbit_from_base_xyzw[k],
            joint_rates_radps=rates[k],
        )
        q = ws.evaluate(state)
        reaction[k] = q.H_bm_tilde @ rates[k]
        base[k] = q.H_b_tilde @ (state.rot_orbit_from_base @ omega_base_in_base_radps[k])
        speed[k] = float(np.linalg.norm(q.J_m[:3] @ rates[k]))
    return ArmReaction(rates, reaction, speed, base)
