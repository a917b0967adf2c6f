"""Shared helpers of the post-pass analyses: segments, windows, smoothing, JSON numbers.

Conventions for every analysis in this package:

- Time is the plan's clock (:meth:`PassRecording.t_s`), seconds.
- Attitude deviations are rotation vectors of ``R_ref^T R`` (base frame, rad): for the
  sub-degree motions of these experiments they add like small angles (error of order
  ``angle^2 / 2``, below 1e-4 of the value at 1 deg).
- Degrees appear only in the names and values that leave an analysis (``_deg``).
- ``to_dict`` writes plain ``float``/``int``/``str``/``bool``/``None``/``list``; a number that
  is not finite is written as ``None``.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from planner.plan import Plan, Segment

Array = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: Segment kinds during which the arm moves on purpose.
MOTION_KINDS = ("ptp", "reactionless", "gjm", "coordination", "nonholonomic")

#: A frame interval longer than this many telemetry periods counts as a gap.
GAP_FACTOR = 1.5


def json_number(value: float | np.floating[Any] | None) -> float | None:
    """A plain float, or ``None`` for a missing or non-finite value."""
    if value is None:
        return None
    v = float(value)
    return v if math.isfinite(v) else None


def json_array(values: Array | Sequence[float]) -> list[Any]:
    """Nested lists of plain floats (``None`` where not finite)."""
    arr = np.asarray(values, dtype=np.float64)
    if bool(np.all(np.isfinite(arr))):
        out: list[Any] = arr.tolist()
        return out
    if arr.ndim == 0:
        return [json_number(float(arr))]
    return [json_array(row) if arr.ndim > 1 else json_number(float(row)) for row in arr]


def json_array_or_none(values: Array | Sequence[float] | None) -> list[Any] | None:
    """:func:`json_array`, or ``None`` for a value that is missing."""
    return None if values is None else json_array(values)


def experiment_segments(plan: Plan, experiment: str) -> tuple[Segment, ...]:
    """The segments of ``experiment``: all of a single-experiment plan's, or those a pass
    schedule named ``"<experiment>: ..."`` (planner.schedule)."""
    if plan.experiment == experiment:
        return plan.segments
    prefix = f"{experiment}: "
    return tuple(s for s in plan.segments if s.name.startswith(prefix))


def short_name(plan: Plan, segment: Segment) -> str:
    """The segment's name without the pass schedule's ``"<experiment>: "`` prefix."""
    head, sep, tail = segment.name.partition(": ")
    if sep and plan.experiment == "pass" and head in MOTION_KINDS:
        return tail
    return segment.name


def window_mask(t_s: Array, t0_s: float, t1_s: float) -> BoolArray:
    """Rows with ``t0 <= t <= t1``."""
    mask: BoolArray = (t_s >= t0_s) & (t_s <= t1_s)
    return mask


def nominal_period_s(t_s: Array) -> float:
    """The telemetry period: the median frame interval (0.1 s when there are too few)."""
    if t_s.size < 2:
        return 0.1
    return float(np.median(np.diff(t_s)))


def runs(t_s: Array, period_s: float | None = None) -> list[slice]:
    """Contiguous runs of frames (no interval above ``GAP_FACTOR`` periods)."""
    if t_s.size == 0:
        return []
    period = nominal_period_s(t_s) if period_s is None else period_s
    breaks = np.flatnonzero(np.diff(t_s) > GAP_FACTOR * period) + 1
    edges = [0, *breaks.tolist(), int(t_s.size)]
    return [slice(a, b) for a, b in itertools.pairwise(edges)]


def moving_average(t_s: Array, values: Array, window_s: float) -> Array:
    """Centred moving average over ``window_s`` within each contiguous run (the window
    shrinks at the run's edges). ``values`` is (n,) or (n, m)."""
    vals = np.asarray(values, dtype=np.float64)
    if window_s <= 0.0 or t_s.size == 0:
        return vals.copy()
    out = np.empty_like(vals)
    period = nominal_period_s(t_s)
    half = max(0, round(0.5 * window_s / period))
    for run in runs(t_s, period):
        block = vals[run]
        n = block.shape[0]
        csum = np.concatenate([np.zeros((1, *block.shape[1:])), np.cumsum(block, axis=0)])
        lo = np.clip(np.arange(n) - half, 0, n)
        hi = np.clip(np.arange(n) + half + 1, 0, n)
        count = (hi - lo).reshape((n,) + (1,) * (block.ndim - 1))
        out[run] = (csum[hi] - csum[lo]) / count
    return out


def rpy_rad(quats_xyzw: Array) -> Array:
    """``(roll, pitch, yaw)`` rows of ``Rz(yaw) Ry(pitch) Rx(roll)`` (planner.frames)."""
    if len(quats_xyzw) == 0:
        return np.zeros((0, 3))
    zyx = Rotation.from_quat(quats_xyzw).as_euler("ZYX")
    return np.asarray(zyx[:, ::-1], dtype=np.float64)


def deviation_rad(quats_xyzw: Array, ref_quat_xyzw: Array) -> Array:
    """Rotation vectors of ``R_ref^T R`` for each row (the body frame of ``R``), rad."""
    if len(quats_xyzw) == 0:
        return np.zeros((0, 3))
    rel = Rotation.from_quat(ref_quat_xyzw).inv() * Rotation.from_quat(quats_xyzw)
    return np.asarray(rel.as_rotvec(), dtype=np.float64)


def relative_rotvec(ref_quats_xyzw: Array, quats_xyzw: Array) -> Array:
    """Rotation vectors of ``R_ref_k^T R_k`` row by row (the body frame of ``R_k``), rad."""
    if len(quats_xyzw) == 0:
        return np.zeros((0, 3))
    rel = Rotation.from_quat(ref_quats_xyzw).inv() * Rotation.from_quat(quats_xyzw)
    return np.asarray(rel.as_rotvec(), dtype=np.float64)


def mean_quat_xyzw(quats_xyzw: Array) -> Array:
    """The mean attitude of a few nearby rows."""
    return np.asarray(Rotation.from_quat(quats_xyzw).mean().as_quat(), dtype=np.float64)


def settling_time_s(
    t_s: Array,
    deviation: Array,
    *,
    motion_end_s: float,
    band_rad: float,
    final_s: float,
    reference: Array | None = None,
) -> tuple[float | None, Array]:
    """Settling after ``motion_end_s`` to within ``band_rad`` of the final value.

    The final value is ``reference`` (3,) when given (the attitude the loop is commanded to,
    which a wait that ends early has not reached yet), else the mean of ``deviation`` (n, 3)
    over the last ``final_s`` of the rows; the settling time is the last time a row after
    ``motion_end_s`` lies outside the band, minus ``motion_end_s`` (0 if none). ``None`` when
    the rows end before they had stayed inside for ``final_s`` (not settled within the
    window). Returns it and the final value.
    """
    if t_s.size == 0:
        return None, np.full(3, np.nan)
    tail = t_s >= t_s[-1] - final_s
    if reference is not None:
        final = np.asarray(reference, dtype=np.float64).reshape(3)
    else:
        final = np.asarray(np.mean(deviation[tail], axis=0), dtype=np.float64)
    after = t_s > motion_end_s
    outside = after & (np.linalg.norm(deviation - final, axis=1) > band_rad)
    if not bool(np.any(outside)):
        return 0.0, final
    last = float(t_s[np.flatnonzero(outside)[-1]])
    if last > t_s[-1] - final_s:
        return None, final
    return last - motion_end_s, final


def rms(values: Array, axis: int | None = None) -> Any:
    return np.sqrt(np.mean(np.square(values), axis=axis))


def names(segments: Iterable[Segment]) -> list[str]:
    return [s.name for s in segments]
