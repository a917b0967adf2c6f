"""Onboard attitude control: its mode, attitude target and feedforward, and the wheel torque
its law commands (SPEC section 6, docs/spacecraft.md).

It runs every ``control_period_s`` (and at each attitude command's tag) on the *measured*
(noisy) attitude and rate with the law of ``acs_gains``
(:class:`planner.attitude_law.AttitudeController`, the planner's prediction's law: its
integral and rate filter, if any, restart on entering feedback and on a new target); its
feedforward is eq. (9) of the commanded motion (the servo target and its ramp rate). Wheel
torque and momentum are limited in the simulator. An attitude-control command switches
mode, target and feedforward at its tag; SAFE holds the measured attitude in feedback
without feedforward. :class:`spacecraft.vehicle.Vehicle` owns one.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from planner.attitude_control import AcsGains, AcsMode, reaction_rate_radps
from planner.attitude_law import AttitudeController
from planner.dynamics import DynamicsWorkspace
from planner.state import State
from spacecraft._sensors import Measurement
from spacecraft.servo_target import ServoTarget
from spacecraft.vehicle_config import IDENTITY_QUAT_XYZW
from telemetry.wire import AcsCommandMsg, AcsModeName

__all__ = ["OnboardAcs"]

Array = NDArray[np.float64]


class OnboardAcs:
    """Attitude control with the law of ``gains`` for the robot of ``ws``, starting in
    ``mode`` with the identity as target and no feedforward; times from onboard
    ``epoch_ns``."""

    def __init__(
        self, gains: AcsGains, ws: DynamicsWorkspace, mode: AcsModeName, *, epoch_ns: int
    ) -> None:
        self._ws = ws
        self._epoch_ns = epoch_ns
        self._law = AttitudeController(gains)
        self.mode = AcsMode(mode.value)
        self.target = np.array(IDENTITY_QUAT_XYZW)
        self.feedforward = False
        #: the wheel motor torque commanded (N m; clipped at the law's torque limit)
        self.wheel_torque_nm = np.zeros(3)

    def command(self, cmd: AcsCommandMsg) -> None:
        """An attitude-control command's mode, target and feedforward, from now."""
        self.mode = AcsMode(cmd.mode.value)
        self.target = np.array(cmd.target_quat_orbit_from_base_xyzw)
        self.feedforward = cmd.feedforward

    def hold(self, quat_orbit_from_base_xyzw: Array) -> None:
        """Feedback on this attitude, without feedforward (SAFE)."""
        self.mode = AcsMode.FEEDBACK
        self.target = quat_orbit_from_base_xyzw.copy()
        self.feedforward = False

    def control(
        self,
        t: int,
        measure: Callable[[int], tuple[State, Measurement]],
        servo: ServoTarget,
    ) -> None:
        """The law at onboard ``t``: on the sensor sample ``measure`` gives (not read in
        free drift), with the feedforward of the servo target's motion."""
        t_s = (t - self._epoch_ns) / 1e9
        if self.mode is AcsMode.FREE_DRIFT:
            self.wheel_torque_nm = self._law.torque(t_s, AcsMode.FREE_DRIFT)
            return
        _, m = measure(t)
        reaction = (
            reaction_rate_radps(self._ws, servo.at(t), servo.rate) if self.feedforward else None
        )
        self.wheel_torque_nm = self._law.torque(
            t_s,
            self.mode,
            target_quat_xyzw=self.target,
            quat_orbit_from_base_xyzw=m.quat_orbit_from_base_xyzw,
            omega_base_radps=m.omega_base_in_base_radps,
            reaction_rate_radps=reaction,
        )
