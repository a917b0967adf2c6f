"""The live limits evaluated on telemetry frames: each monitored quantity's value and band.

:class:`FrameEvaluator` turns a batch of :class:`~telemetry.wire.TelemetryFrame` into the
values of every frame quantity of :data:`planner.limits.QUANTITIES` (docs/robots.md,
"Limits"), numpy across the batch (each frame's fields are read once; the quaternion
algebra is vectorised), and classifies them against a robot's :class:`~planner.limits.
Limits`:

- ``attitude_error_deg`` (``x``, ``y``, ``z``): abs of the rotation vector of
  ``conj(target) * q`` (the ACS target to the measured attitude, the short way round; about
  the base-frame error, as the vehicle's law takes it: ``planner.attitude_control.
  attitude_error_rad``), degrees;
- ``body_rate_degps``: the norm of the gyro's rate;
- ``wheel_momentum_fraction`` (``wheel1..k``): ``|I_w speed| / `` the wheel's momentum limit;
- ``wheel_speed_rpm``: ``|speed|`` (relative to the base) in rpm;
- ``joint_tracking_error_deg`` (``joint1..n``): ``|commanded - measured|``, the commanded
  target from ``commanded(generation_times_ns)`` (the ground's plan, linear between its
  joint commands) and, where it gives none (NaN rows, or no callable), the frame's own
  ``joint_targets_rad`` (the vehicle's servo target);
- ``joint_limit_distance_deg``: the measured angle's distance to the nearer limit;
- ``clearance_m``: :class:`~planner.clearance_watch.ClearanceWatch` on the measured joints (NaN, so
  never in a band, without one);
- ``schedule_occupancy``: ``buffer.queued / buffer.capacity`` (1024, the wire's default,
  where the frame does not say).

:meth:`FrameEvaluator.evaluate` keeps each channel's severity from the previous frame it
evaluated and returns, frame by frame, every channel in a band and every channel whose
severity changed (back to None included), so that an alarm list sees clears.
:func:`link_readings` classifies the two link quantities, which the ground's timer measures
rather than a frame.

The cost is measured against decoding the same frames in ``bench/bench_limits.py``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from planner.clearance_watch import ClearanceWatch
from planner.errors import InvalidInput
from planner.limits import (
    QUANTITIES,
    SEVERITIES,
    Limits,
    Severity,
    channel_names,
)

if TYPE_CHECKING:
    from planner.robot import RobotDescription
    from telemetry.wire import TelemetryFrame

__all__ = [
    "FRAME_QUANTITIES",
    "LINK_QUANTITIES",
    "CommandedFn",
    "FrameEvaluator",
    "Reading",
    "attitude_error_deg",
    "for_description",
    "interpolated_commands",
    "link_readings",
]

Array = NDArray[np.float64]
#: ``commanded(generation_times_ns)`` -> ``(m, n)`` commanded joint targets (rad), NaN rows
#: where the plan commands nothing at that time; None: none at all.
CommandedFn = Callable[[NDArray[np.int64]], Array | None]

#: What a frame gives and what the link gives, in the catalogue's order.
FRAME_QUANTITIES = tuple(name for name, q in QUANTITIES.items() if q.source == "frame")
LINK_QUANTITIES = tuple(name for name, q in QUANTITIES.items() if q.source == "link")

#: The schedule's capacity where a frame does not say (telemetry.wire's default).
_DEFAULT_CAPACITY = 1024
_RPM_PER_RADPS = 60.0 / (2.0 * math.pi)
_SEVERITY_OF_RANK: tuple[Severity | None, ...] = (None, *SEVERITIES)


@dataclass(frozen=True)
class Reading:
    """One channel's value at one frame and the band it is in (None: within limits)."""

    quantity: str
    channel: str
    value: float
    severity: Severity | None
    frame_seq: int
    generation_time_ns: int


def _conj_product() -> NDArray[np.float64]:
    """``M`` with ``(conj(t) * q)_i = M[i, j, k] t_j q_k`` (Hamilton product, scalar last)."""
    m = np.zeros((4, 4, 4))
    for i, j, k, sign in (
        (0, 3, 0, 1), (0, 0, 3, -1), (0, 1, 2, -1), (0, 2, 1, 1),
        (1, 3, 1, 1), (1, 0, 2, 1), (1, 1, 3, -1), (1, 2, 0, -1),
        (2, 3, 2, 1), (2, 0, 1, -1), (2, 1, 0, 1), (2, 2, 3, -1),
        (3, 3, 3, 1), (3, 0, 0, 1), (3, 1, 1, 1), (3, 2, 2, 1),
    ):  # fmt: skip
        m[i, j, k] = sign
    return m


_CONJ_PRODUCT = _conj_product()


def attitude_error_deg(quat_xyzw: Array, target_xyzw: Array) -> Array:
    """The rotation vector of ``conj(target) * q`` (degrees, signed), row by row: ``(m, 3)``
    from two ``(m, 4)`` arrays of scalar-last quaternions (the short way round; as
    ``planner.attitude_control.attitude_error_rad``)."""
    e = np.einsum("ijk,mj,mk->mi", _CONJ_PRODUCT, target_xyzw, quat_xyzw)
    e *= np.where(e[:, 3:] < 0.0, -1.0, 1.0)  # the short way round
    v = e[:, :3]
    s = np.sqrt(np.einsum("ij,ij->i", v, v))
    small = s < 1e-12
    # 2 atan2(s, w) / s, and its limit 2 (for w = 1) where the error is nil
    scale = 2.0 * np.arctan2(s, e[:, 3]) / np.where(small, 1.0, s)
    scale[small] = 2.0
    out: Array = np.degrees(v * scale[:, None])
    return out


class FrameEvaluator:
    """A robot's frame quantities and their bands, over batches of frames (module doc)."""

    def __init__(
        self,
        limits: Limits,
        *,
        n_joints: int,
        joint_limits_rad: Array,
        wheel_spin_inertia_kgm2: Array,
        wheel_momentum_limit_nms: Array,
        clearance: ClearanceWatch | None = None,
        commanded: CommandedFn | None = None,
    ) -> None:
        self.limits = limits
        self.n_joints = int(n_joints)
        self.joint_limits_rad = np.asarray(joint_limits_rad, dtype=np.float64).reshape(-1, 2)
        if self.joint_limits_rad.shape[0] != self.n_joints:
            raise ValueError(
                f"joint_limits_rad has {self.joint_limits_rad.shape[0]} rows for "
                f"{self.n_joints} joints"
            )
        self.wheel_spin_inertia_kgm2 = np.asarray(wheel_spin_inertia_kgm2, dtype=np.float64)
        self.wheel_momentum_limit_nms = np.asarray(wheel_momentum_limit_nms, dtype=np.float64)
        if self.wheel_spin_inertia_kgm2.shape != self.wheel_momentum_limit_nms.shape:
            raise ValueError("one spin inertia and one momentum limit per wheel")
        self.n_wheels = int(self.wheel_spin_inertia_kgm2.shape[0])
        self.clearance = clearance
        self.commanded = commanded
        #: the quantities evaluated (those of the frame with bands) and their channels
        self.quantities = tuple(q for q in FRAME_QUANTITIES if limits.get(q) is not None)
        self.channels = {
            q: channel_names(q, self.n_joints, self.n_wheels) for q in FRAME_QUANTITIES
        }
        # Every evaluated channel is a column: its quantity, its channel, and its thresholds
        # by severity (NaN where the quantity has no such band), signed so that "low"
        # quantities compare like "high" ones (in a band when sign * value >= sign * t).
        columns = [(q, c) for q in self.quantities for c in range(len(self.channels[q]))]
        self._columns = columns
        self._sign = np.array(
            [1.0 if QUANTITIES[q].direction == "high" else -1.0 for q, _ in columns]
        )
        thresholds = np.full((len(SEVERITIES), len(columns)), np.nan)
        for j, (q, _) in enumerate(columns):
            for severity, value in limits.bands[q].thresholds:
                thresholds[SEVERITIES.index(severity), j] = value
        self._signed_thresholds = thresholds * self._sign
        self._previous = np.zeros(len(columns), dtype=np.int8)

    def reset(self) -> None:
        """Forget the previous severities (a new pass: every channel within limits)."""
        self._previous[:] = 0

    def values(self, frames: Sequence[TelemetryFrame]) -> dict[str, Array]:
        """Every frame quantity's values: ``quantity -> (m, channels)``."""
        m = len(frames)
        n, k = self.n_joints, self.n_wheels
        if m == 0:
            return {q: np.zeros((0, len(self.channels[q]))) for q in FRAME_QUANTITIES}
        rows = [
            (
                *f.joints_rad,
                *f.joint_targets_rad,
                *f.quat_orbit_from_base_xyzw,
                *f.acs_target_quat_xyzw,
                *f.omega_base_in_base_radps,
                *f.wheel_speeds_radps,
                f.buffer.queued,
                f.buffer.capacity or _DEFAULT_CAPACITY,
                f.generation_time_ns,
            )
            for f in frames
        ]
        try:
            a = np.array(rows, dtype=np.float64)
        except ValueError:  # rows of different lengths
            a = np.zeros((0, 0))
        if a.ndim != 2 or a.shape[1] != 2 * n + 14 + k:
            raise ValueError(
                f"frames do not all have {n} joints and {k} wheels (the evaluator's robot)"
            )
        q = a[:, :n]
        targets = a[:, n : 2 * n]
        quat = a[:, 2 * n : 2 * n + 4]
        target_quat = a[:, 2 * n + 4 : 2 * n + 8]
        omega = a[:, 2 * n + 8 : 2 * n + 11]
        speeds = a[:, 2 * n + 11 : 2 * n + 11 + k]
        queued = a[:, -3]
        capacity = a[:, -2]

        if self.commanded is not None:
            # the times exactly (a float64 column holds ns to 2**53 only)
            times = np.fromiter((f.generation_time_ns for f in frames), np.int64, m)
            commanded = self.commanded(times)
            if commanded is not None:
                commanded = np.asarray(commanded, dtype=np.float64)
                targets = np.where(np.isnan(commanded), targets, commanded)
        lo, hi = self.joint_limits_rad[:, 0], self.joint_limits_rad[:, 1]
        clearance = (
            np.full(m, math.nan) if self.clearance is None else self.clearance.clearances_m(q)
        )
        return {
            "attitude_error_deg": np.abs(attitude_error_deg(quat, target_quat)),
            "body_rate_degps": np.degrees(np.sqrt(np.einsum("ij,ij->i", omega, omega)))[:, None],
            "wheel_momentum_fraction": np.abs(speeds * self.wheel_spin_inertia_kgm2)
            / self.wheel_momentum_limit_nms,
            "wheel_speed_rpm": np.abs(speeds) * _RPM_PER_RADPS,
            "joint_tracking_error_deg": np.degrees(np.abs(targets - q)),
            "joint_limit_distance_deg": np.degrees(np.minimum(q - lo, hi - q)),
            "clearance_m": clearance[:, None],
            "schedule_occupancy": (queued / capacity)[:, None],
        }

    def ranks(self, values: dict[str, Array]) -> tuple[Array, NDArray[np.int8]]:
        """The evaluated channels' values ``(m, columns)`` and their bands as ranks (0:
        within limits, 1 watch .. 5 severe), the columns in the catalogue's order."""
        matrix = np.concatenate([values[q] for q in self.quantities], axis=1)
        signed = matrix * self._sign
        rank = np.zeros(matrix.shape, dtype=np.int8)
        for level in range(len(SEVERITIES)):
            rank[signed >= self._signed_thresholds[level]] = level + 1  # NaN: never
        return matrix, rank

    def evaluate(self, frames: Sequence[TelemetryFrame]) -> list[Reading]:
        """Frame by frame, in order: every channel in a band, and every channel whose band
        changed since the previous frame evaluated (the clears too, severity None)."""
        if not frames:
            return []
        matrix, rank = self.ranks(self.values(frames))
        before = np.empty_like(rank)
        before[0] = self._previous
        before[1:] = rank[:-1]
        self._previous = rank[-1].copy()
        emit = (rank > 0) | (rank != before)
        out = []
        for i, j in zip(*np.nonzero(emit), strict=True):  # frame by frame, columns in order
            name, channel = self._columns[j]
            frame = frames[i]
            out.append(
                Reading(
                    quantity=name,
                    channel=self.channels[name][channel],
                    value=float(matrix[i, j]),
                    severity=_SEVERITY_OF_RANK[rank[i, j]],
                    frame_seq=frame.seq,
                    generation_time_ns=frame.generation_time_ns,
                )
            )
        return out


def interpolated_commands(execute_times_ns: NDArray[np.int64], joints_rad: Array) -> CommandedFn:
    """The ``commanded`` of a stream of joint commands (tags in increasing order, targets
    ``(c, n)``): the target linear between consecutive commands (as on board), NaN rows
    before the first tag and after the last (outside the span the frame's own target
    stands)."""
    tags = np.asarray(execute_times_ns, dtype=np.int64)
    targets = np.asarray(joints_rad, dtype=np.float64)
    if tags.ndim != 1 or targets.shape[:1] != tags.shape or np.any(np.diff(tags) <= 0):
        raise ValueError("one target row per tag, tags strictly increasing")
    base = int(tags[0]) if tags.size else 0
    x = (tags - base).astype(np.float64)

    def commanded(times_ns: NDArray[np.int64]) -> Array | None:
        if tags.size == 0:
            return None
        t = (np.asarray(times_ns, dtype=np.int64) - base).astype(np.float64)
        if tags.size == 1:
            out = np.repeat(targets, t.shape[0], axis=0)
        else:
            i = np.clip(np.searchsorted(x, t, side="right") - 1, 0, tags.size - 2)
            w = ((t - x[i]) / (x[i + 1] - x[i]))[:, None]
            out = targets[i] * (1.0 - w) + targets[i + 1] * w
        out[(t < x[0]) | (t > x[-1])] = np.nan
        return out

    return commanded


def link_readings(
    limits: Limits,
    *,
    frames_behind: int | None,
    frame_age_s: float | None,
    frame_seq: int = -1,
    generation_time_ns: int = 0,
) -> list[Reading]:
    """The link quantities the ground measures (None: not measured now), each with its band
    (None: within limits); the caller keeps their previous bands."""
    out = []
    for name, value in (("frames_behind", frames_behind), ("frame_age_s", frame_age_s)):
        bands = limits.get(name)
        if value is None or bands is None:
            continue
        out.append(
            Reading(
                quantity=name,
                channel="",
                value=float(value),
                severity=bands.classify(float(value)),
                frame_seq=frame_seq,
                generation_time_ns=generation_time_ns,
            )
        )
    return out


def for_description(
    description: RobotDescription,
    *,
    commanded: CommandedFn | None = None,
    limits: Limits | None = None,
    clearance_threshold_m: float | None = None,
) -> FrameEvaluator:
    """The evaluator of a robot description: its limits (or ``limits``), joint limits,
    wheels and (when it has collision shapes) a clearance watch, exact at or below
    ``clearance_threshold_m`` (None: the least severe clearance threshold; ``inf``: exact
    at every frame)."""
    limits = limits or description.limits
    bands = limits.get("clearance_m")
    threshold = clearance_threshold_m
    if threshold is None and bands is not None:
        threshold = bands.least
    watch = None
    if threshold is not None and description.collision is not None:
        try:
            watch = ClearanceWatch(description, threshold)
        except InvalidInput:  # shapes that cannot show the arm clear: no live clearance
            watch = None
    return FrameEvaluator(
        limits,
        n_joints=description.n_joints,
        joint_limits_rad=np.asarray(description.model.joint_limit_rad),
        wheel_spin_inertia_kgm2=np.array([w.spin_inertia_kgm2 for w in description.model.wheels]),
        wheel_momentum_limit_nms=np.array([w.momentum_limit_nms for w in description.wheel_limits]),
        clearance=watch,
        commanded=commanded,
    )
