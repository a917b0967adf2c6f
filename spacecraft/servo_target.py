"""The onboard software's servo target: where it stands at an onboard time, and its ramp to
the next queued joint command (SPEC section 6, docs/spacecraft.md).

A joint command sets the target to its joints at its tag; from there the target moves
linearly to the next queued joint command, reaching it at that command's tag (rate =
difference / tag difference: between consecutive 4 Hz commands, difference / 0.25 s); with
none queued it holds. A joint command that arrives while the target holds (or that becomes
the next one, ahead of the command being ramped to) is ramped to from where the target
stands. The target therefore never steps and never moves faster than the checked rate
limit: across a gap left by a lost command it keeps moving toward the next one instead of
holding and then jumping. It saturates at the joint limits.

:class:`spacecraft.vehicle.Vehicle` owns one and hands it to the joint servos' hardware
(through the faults, :meth:`spacecraft.truth_sim.TruthSimulation.servo`) whenever it
changes; a joint fault changes what the hardware applies, not this target (which telemetry
reports).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from telemetry.wire import JointCommandMsg

__all__ = ["ServoTarget"]

Array = NDArray[np.float64]


class ServoTarget:
    """The target: ``joints_rad`` at onboard ``now``, holding, within ``joint_limit_rad``
    (per joint: lower, upper)."""

    def __init__(self, joints_rad: Array, joint_limit_rad: Array, now: int) -> None:
        # `_target` at `_target_ns`, moving at `rate`
        self._target = joints_rad.copy()
        self._target_ns = now
        self._lo, self._hi = joint_limit_rad[:, 0], joint_limit_rad[:, 1]
        #: rad/s per joint toward the earliest queued joint command (zeros: holding)
        self.rate = np.zeros(len(joints_rad))
        #: the tag of the joint command ramped to (None: holding)
        self.ramp_to_ns: int | None = None

    def at(self, t: int) -> Array:
        """The target at onboard ``t`` (it saturates at the joint limits)."""
        target = self._target + self.rate * ((t - self._target_ns) / 1e9)
        return np.clip(target, self._lo, self._hi)

    def set(self, target: Array, rate: Array | None, now: int) -> None:
        """The target from ``now``: ``target`` moving at ``rate`` (None: holding)."""
        self._target = np.clip(target, self._lo, self._hi)
        self._target_ns = now
        self.rate = np.zeros_like(self._target) if rate is None else rate

    def hold(self, target: Array, now: int) -> None:
        """Hold ``target`` from ``now``, ramping to no command."""
        self.ramp_to_ns = None
        self.set(target, None, now)

    def ramp(self, nxt: JointCommandMsg | None, now: int) -> None:
        """From where the target stands at ``now`` to the joint command ``nxt``, reaching it
        at its tag; hold if there is none."""
        target = self.at(now)
        if nxt is None:
            rate, self.ramp_to_ns = np.zeros_like(target), None
        else:
            duration_s = (nxt.execute_time_ns - now) / 1e9
            rate = (np.array(nxt.joints_rad) - target) / duration_s
            self.ramp_to_ns = nxt.execute_time_ns
        self.set(target, rate, now)
