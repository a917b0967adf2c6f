"""On-board safing: the vehicle's own protection against a red limit (docs/spacecraft.md,
"On-board safing"; docs/protocol.md, "On-board safing").

At every control tick the vehicle hands :class:`SafingMonitor` its own measured sample; the
monitor evaluates the *safing* quantities of :data:`planner.limits.QUANTITIES` against their
red thresholds (:meth:`planner.limits.Limits.safing_limits`), as the ground evaluates a frame
(:mod:`telemetry.limits`), except for the tracking error, which is the onboard software's
servo target less the measured joints (the vehicle knows no plan):

- ``attitude_error_deg`` (``x``, ``y``, ``z``): the rotation vector from the ACS target to the
  measured attitude (:func:`attitude_error_deg`, the ground's
  :func:`telemetry.limits.attitude_error_deg` for one sample), in every ACS mode;
- ``wheel_momentum_fraction`` (``wheel1..k``): ``|I_w speed|`` over the momentum limit the
  truth simulation enforces on the wheels;
- ``joint_tracking_error_deg`` (``joint1..n``): ``|servo target - measured|``;
- ``clearance_m``: :class:`~planner.clearance_watch.ClearanceWatch` on the measured joints.

The first quantity in that order with a channel at or beyond its red threshold is the
trigger (its worst channel). :class:`OnboardSafing` is the SAFE state the vehicle keeps: when
it was entered and why, the ``safing`` reports waiting to go down (on entry, then every
second onboard while safe), the answers to each ``safe_exit``
``request_id`` (a copy gets the same report), and the records for the truth log. The vehicle
(:mod:`spacecraft.vehicle`) does what SAFE means: hold the joints, drop the schedule, ACS to
feedback hold, refuse commands.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.clearance_watch import ClearanceWatch
from planner.collision import CollisionModel
from planner.errors import InvalidInput
from planner.limits import DEFAULT_LIMITS, Limits
from planner.model import RobotModel
from telemetry.wire import Safing, SafingTrigger

__all__ = [
    "REPORT_PERIOD_NS",
    "OnboardSafing",
    "SafingMonitor",
    "attitude_error_deg",
    "monitor_for",
]

Array = NDArray[np.float64]

#: While safe, a ``safing`` report goes down this often (onboard): it may be lost on the relay.
REPORT_PERIOD_NS = 1_000_000_000
_AXES = ("x", "y", "z")


def attitude_error_deg(quat_xyzw: Array, target_xyzw: Array) -> tuple[float, float, float]:
    """The rotation vector of ``conj(target) * q`` in degrees (the short way round): what
    :func:`telemetry.limits.attitude_error_deg` computes for a batch of frames, for one
    sample in plain floats (a tenth of the cost at each control tick)."""
    x, y, z, w = (float(v) for v in quat_xyzw)
    tx, ty, tz, tw = (float(v) for v in target_xyzw)
    ex = tw * x - tx * w - ty * z + tz * y
    ey = tw * y + tx * z - ty * w - tz * x
    ez = tw * z - tx * y + ty * x - tz * w
    ew = tw * w + tx * x + ty * y + tz * z
    if ew < 0.0:
        ex, ey, ez, ew = -ex, -ey, -ez, -ew
    s = math.sqrt(ex * ex + ey * ey + ez * ez)
    scale = 2.0 if s < 1e-12 else 2.0 * math.atan2(s, ew) / s
    k = math.degrees(scale)
    return ex * k, ey * k, ez * k


class SafingMonitor:
    """The red limits of the safing quantities, checked on one measured sample at a time.
    ``model``: the wheels (and joint count); ``momentum_limit_nms``: the wheels' momentum
    limit in force; ``clearance_shapes``: the kinematics and collision shapes of the live
    clearance (None: not watched)."""

    def __init__(
        self,
        limits: Limits,
        *,
        model: RobotModel,
        momentum_limit_nms: float,
        clearance_shapes: tuple[RobotModel, CollisionModel] | None = None,
    ) -> None:
        self.red = limits.safing_limits()
        self.n_joints = model.n_joints
        self._spin_inertia = np.array([w.spin_inertia_kgm2 for w in model.wheels])
        self._momentum_limit_nms = float(momentum_limit_nms)
        self.clearance: ClearanceWatch | None = None
        if "clearance_m" in self.red and clearance_shapes is not None:
            try:
                self.clearance = ClearanceWatch(clearance_shapes, self.red["clearance_m"])
            except InvalidInput:  # shapes that cannot show the arm clear: not watched
                self.clearance = None

    def check(
        self,
        *,
        joint_targets_rad: Array,
        joints_rad: Array,
        quat_orbit_from_base_xyzw: Array,
        acs_target_quat_xyzw: Array,
        wheel_speeds_radps: Array,
    ) -> SafingTrigger | None:
        """The first red limit crossed (module docstring), None when every safing quantity
        is within its red limit."""
        red = self.red
        limit = red.get("attitude_error_deg")
        if limit is not None:
            rotvec = attitude_error_deg(quat_orbit_from_base_xyzw, acs_target_quat_xyzw)
            axes = [abs(e) for e in rotvec]
            i = max(range(3), key=axes.__getitem__)
            if axes[i] >= limit:
                return SafingTrigger(
                    quantity="attitude_error_deg",
                    channel=_AXES[i],
                    value=axes[i],
                    limit=limit,
                    detail=f"attitude error about base {_AXES[i]} {axes[i]:.3f} deg from the "
                    f"ACS target, red limit {limit:g} deg",
                )
        limit = red.get("wheel_momentum_fraction")
        if limit is not None and self._spin_inertia.size:
            fraction = np.abs(self._spin_inertia * wheel_speeds_radps) / self._momentum_limit_nms
            i = int(np.argmax(fraction))
            if fraction[i] >= limit:
                return SafingTrigger(
                    quantity="wheel_momentum_fraction",
                    channel=f"wheel{i + 1}",
                    value=float(fraction[i]),
                    limit=limit,
                    detail=f"wheel {i + 1} holds {fraction[i]:.3f} of its "
                    f"{self._momentum_limit_nms:g} N m s, red limit {limit:g}",
                )
        limit = red.get("joint_tracking_error_deg")
        if limit is not None:
            error = np.degrees(np.abs(joint_targets_rad - joints_rad))
            i = int(np.argmax(error))
            if error[i] >= limit:
                return SafingTrigger(
                    quantity="joint_tracking_error_deg",
                    channel=f"joint{i + 1}",
                    value=float(error[i]),
                    limit=limit,
                    detail=f"joint {i + 1} at {math.degrees(joints_rad[i]):.3f} deg, its "
                    f"servo target {math.degrees(joint_targets_rad[i]):.3f} deg: "
                    f"{error[i]:.3f} deg apart, red limit {limit:g} deg",
                )
        limit = red.get("clearance_m")
        if limit is not None and self.clearance is not None:
            # exact at or below the red limit; above it a bound the watch keeps cheap
            clearance = self.clearance.clearance_m(joints_rad)
            if clearance <= limit:
                return SafingTrigger(
                    quantity="clearance_m",
                    channel="",
                    value=clearance,
                    limit=limit,
                    detail=f"clearance {clearance:.4f} m at the measured joints, red limit "
                    f"{limit:g} m",
                )
        return None


def monitor_for(
    model: RobotModel,
    *,
    limits: Limits | None,
    collision: CollisionModel | None,
    builtin: bool,
    momentum_limit_nms: float,
) -> SafingMonitor:
    """The monitor of a vehicle flying ``model``. ``builtin`` (a vehicle of no robot
    description, the built-in ETS-VII): the ETS-VII description's limits and collision
    shapes where ``limits`` or ``collision`` is None; otherwise :data:`DEFAULT_LIMITS`, and
    no live clearance without ``collision``."""
    shapes = None if collision is None else (model, collision)
    if builtin and (limits is None or collision is None):
        from planner.description import default_robot

        robot = default_robot()
        limits = limits or robot.limits
        fits = robot.model.n_joints == model.n_joints
        if collision is None and robot.collision is not None and fits:
            shapes = (robot.model, robot.collision)
    return SafingMonitor(
        limits or DEFAULT_LIMITS,
        model=model,
        momentum_limit_nms=momentum_limit_nms,
        clearance_shapes=shapes,
    )


class OnboardSafing:
    """The SAFE state and its reports (module docstring). Times are onboard ns."""

    def __init__(self, *, epoch_ns: int) -> None:
        self._epoch_ns = epoch_ns
        self.safe = False
        self.since_ns: int | None = None
        self.trigger: SafingTrigger | None = None
        self.cancelled = 0
        #: when the next periodic report is due (None: not safe)
        self.next_report_ns: int | None = None
        self._reports: list[Safing] = []
        self._exits: dict[int, Safing] = {}
        self._truth: list[dict[str, Any]] = []
        #: how many times SAFE was entered
        self.entries = 0

    def enter(self, now_ns: int, trigger: SafingTrigger, cancelled: int) -> None:
        """SAFE from ``now_ns`` (the vehicle has dropped ``cancelled`` commands): the entry
        report is queued, the next one due a period later."""
        self.safe = True
        self.since_ns = now_ns
        self.trigger = trigger
        self.cancelled = cancelled
        self.entries += 1
        self.next_report_ns = now_ns + REPORT_PERIOD_NS
        self._reports.append(self.report(now_ns))
        self._truth.append(
            {
                "event": "safing_entry",
                "onboard_time_ns": now_ns,
                "onboard_s": (now_ns - self._epoch_ns) / 1e9,
                **trigger.model_dump(),
                "cancelled": cancelled,
            }
        )

    def tick(self, now_ns: int) -> None:
        """The periodic report, if one is due at ``now_ns``."""
        if self.safe and self.next_report_ns is not None and now_ns >= self.next_report_ns:
            self._reports.append(self.report(now_ns))
            self.next_report_ns = now_ns + REPORT_PERIOD_NS

    def exit(self, request_id: int, now_ns: int) -> tuple[Safing, bool]:
        """The answer to ``safe_exit`` ``request_id`` and whether it left SAFE now (a copy of
        a request gets the first answer and does nothing; when not safe the answer is
        ``nominal`` and nothing changes)."""
        done = self._exits.get(request_id)
        if done is not None:
            return done, False
        left = self.safe
        answer = Safing(
            state="nominal",
            since_time_ns=self.since_ns if left else None,
            trigger=self.trigger if left else None,
            cancelled=self.cancelled if left else 0,
            exit_request_id=request_id,
            onboard_time_ns=now_ns,
        )
        if left:
            self._truth.append(
                {
                    "event": "safing_exit",
                    "onboard_time_ns": now_ns,
                    "onboard_s": (now_ns - self._epoch_ns) / 1e9,
                    "request_id": request_id,
                    "since_time_ns": self.since_ns,
                }
            )
            self.safe = False
            self.next_report_ns = None
        self._exits[request_id] = answer
        return answer, left

    def report(self, now_ns: int) -> Safing:
        """The report of the SAFE state now (the vehicle must be safe)."""
        return Safing(
            state="safe",
            since_time_ns=self.since_ns,
            trigger=self.trigger,
            cancelled=self.cancelled,
            onboard_time_ns=now_ns,
        )

    def take_reports(self) -> list[Safing]:
        """The reports queued since the last call, oldest first."""
        out, self._reports = self._reports, []
        return out

    def take_truth(self) -> list[dict[str, Any]]:
        """The truth-log records made since the last call."""
        out, self._truth = self._truth, []
        return out
