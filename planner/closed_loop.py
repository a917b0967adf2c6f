"""A plan flown in the truth simulation with the attitude-control law in the loop.

The same ingredients the spacecraft uses on board: lagging joint servos that follow the
4 Hz commands (linear between them), the wheel law of :mod:`planner.attitude_control` run at
the sample rate with the active attitude-control command (one
:class:`~planner.attitude_law.AttitudeController`, its state advancing sample to sample),
the feedforward's eq. (9) reaction rate computed from the commanded motion, wheel torque
and momentum limits (the spacecraft adds sensor noise and gravity gradient).
Planners use it to evaluate and optimise against the closed loop.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from planner.attitude_control import AcsGains, AcsMode, reaction_rate_radps
from planner.attitude_law import AttitudeController
from planner.dynamics import DynamicsWorkspace
from planner.frames import IDENTITY_QUAT_XYZW
from planner.plan import AcsCommand
from planner.simulation import FreeFloatingSimulator, SimConfig, Trajectory, follow_commands
from planner.state import State

__all__ = ["fly"]

Array = NDArray[np.float64]


def fly(
    ws: DynamicsWorkspace,
    command_times_s: Array,
    command_joints_rad: Array,
    *,
    acs_commands: Sequence[AcsCommand],
    acs_gains: AcsGains,
    initial_quat_orbit_from_base_xyzw: Array | None = None,
    end_time_s: float | None = None,
    sim_config: SimConfig | None = None,
    sample_period_s: float = 0.1,
) -> Trajectory:
    """Simulate the commands with the attitude-control commands in force (see module doc)."""
    times = np.asarray(command_times_s, dtype=np.float64)
    joints = np.asarray(command_joints_rad, dtype=np.float64)
    base_config = sim_config or SimConfig()
    config = dataclasses.replace(
        base_config,
        wheel_torque_limit_nm=acs_gains.torque_limit_nm,
        wheel_momentum_limit_nms=acs_gains.momentum_limit_nms,
    )
    quat0 = (
        IDENTITY_QUAT_XYZW
        if initial_quat_orbit_from_base_xyzw is None
        else np.asarray(initial_quat_orbit_from_base_xyzw, dtype=np.float64)
    )
    sim = FreeFloatingSimulator(
        ws.model,
        State(joints_rad=joints[0], quat_orbit_from_base_xyzw=quat0),
        config,
    )
    ordered = sorted(acs_commands, key=lambda c: c.t_s)
    command_t = np.array([c.t_s for c in ordered])

    def commanded_reaction_rate(t_s: float) -> Array:
        # The servo target and its rate at t_s: linear between consecutive commands.
        i = int(np.searchsorted(times, t_s + 1e-9, side="right")) - 1
        if i < 0 or i + 1 >= times.size:
            return np.zeros(3)
        rate = (joints[i + 1] - joints[i]) / (times[i + 1] - times[i])
        return reaction_rate_radps(ws, joints[i] + rate * (t_s - times[i]), rate)

    law = AttitudeController(acs_gains)

    def controller(t_s: float, state: State) -> Array:
        k = int(np.searchsorted(command_t, t_s + 1e-9, side="right")) - 1
        if k < 0 or ordered[k].mode is AcsMode.FREE_DRIFT:
            return law.torque(t_s, AcsMode.FREE_DRIFT)
        acs = ordered[k]
        return law.torque(
            t_s,
            acs.mode,
            target_quat_xyzw=acs.target_quat_orbit_from_base_xyzw,
            quat_orbit_from_base_xyzw=state.quat_orbit_from_base_xyzw,
            omega_base_radps=state.rot_orbit_from_base.T @ state.omega_base_orbit_radps,
            reaction_rate_radps=commanded_reaction_rate(t_s) if acs.feedforward else None,
        )

    return follow_commands(
        sim,
        times,
        joints,
        end_time_s=float(times[-1] if end_time_s is None else end_time_s),
        sample_period_s=sample_period_s,
        wheel_controller=controller,
    )
