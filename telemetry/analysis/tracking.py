"""Commanded against measured joint angles, and their error, per joint (paper Fig. 6).

"Commanded" is the onboard servo target in each frame (``joint_targets_rad``: the 4 Hz
commands interpolated linearly, as the servo saw them); "measured" the encoders
(``joints_rad``). The error is measured minus commanded; a lagging joint has an error of the
opposite sign to its rate. Statistics are per motion segment and over all of them; the joint
that lags most is the one with the largest RMS error (its peak error is reported too).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from telemetry.analysis._common import (
    MOTION_KINDS,
    Array,
    json_array,
    rms,
    window_mask,
)
from telemetry.recording import PassRecording

__all__ = ["JointTrackingAnalysis", "SegmentTracking", "analyse_joint_tracking"]

IntArray = NDArray[np.intp]


@dataclass(frozen=True)
class SegmentTracking:
    segment: str
    kind: str
    frames: int
    rms_error_deg: tuple[float, ...]  # per joint
    peak_error_deg: tuple[float, ...]  # per joint, largest |error|
    #: 1-based joint number with the largest RMS error
    worst_joint: int

    def to_dict(self) -> dict[str, Any]:
        return {
            "segment": self.segment,
            "kind": self.kind,
            "frames": self.frames,
            "rms_error_deg": json_array(self.rms_error_deg),
            "peak_error_deg": json_array(self.peak_error_deg),
            "worst_joint": self.worst_joint,
        }


@dataclass(frozen=True, eq=False)
class JointTrackingAnalysis:
    kinds: tuple[str, ...]
    segments: tuple[SegmentTracking, ...]
    #: over every selected segment's frames
    rms_error_deg: tuple[float, ...]
    peak_error_deg: tuple[float, ...]
    worst_joint: int
    #: series: frames inside the selected segments; ``segment_index`` into ``segments``
    t_s: Array
    segment_index: Array
    commanded_deg: Array
    measured_deg: Array
    missing: tuple[str, ...] = ()

    @property
    def error_deg(self) -> Array:
        return np.asarray(self.measured_deg - self.commanded_deg)

    def to_dict(self) -> dict[str, Any]:
        return {
            "kinds": list(self.kinds),
            "commanded_source": "joint_targets_rad (onboard servo target)",
            "segments": [s.to_dict() for s in self.segments],
            "rms_error_deg": json_array(self.rms_error_deg),
            "peak_error_deg": json_array(self.peak_error_deg),
            "worst_joint": self.worst_joint,
            "series": {
                "t_s": json_array(self.t_s),
                "segment_index": [int(i) for i in self.segment_index],
                "commanded_deg": json_array(self.commanded_deg),
                "measured_deg": json_array(self.measured_deg),
            },
            "missing": list(self.missing),
        }


def _stats(error_rad: Array) -> tuple[tuple[float, ...], tuple[float, ...], int]:
    rms_deg = tuple(math.degrees(float(v)) for v in rms(error_rad, axis=0))
    peak_deg = tuple(math.degrees(float(v)) for v in np.max(np.abs(error_rad), axis=0))
    return rms_deg, peak_deg, int(np.argmax(rms_deg)) + 1


def analyse_joint_tracking(
    recording: PassRecording, *, kinds: tuple[str, ...] = MOTION_KINDS
) -> JointTrackingAnalysis | None:
    """Tracking statistics for the plan's segments of ``kinds``; ``None`` when the plan has
    none of them or no frame falls in any."""
    t_all = recording.t_s()
    frames = recording.frames
    selected = [s for s in recording.plan.segments if s.kind in kinds]
    if not selected:
        return None
    results: list[SegmentTracking] = []
    rows: list[IntArray] = []
    index: list[IntArray] = []
    missing: list[str] = []
    for seg in selected:
        mask = window_mask(t_all, seg.t_start_s, seg.t_end_s)
        if not np.any(mask):
            missing.append(f"{seg.name}: no telemetry")
            continue
        error = frames.joints_rad[mask] - frames.joint_targets_rad[mask]
        rms_deg, peak_deg, worst = _stats(error)
        results.append(
            SegmentTracking(seg.name, seg.kind, int(mask.sum()), rms_deg, peak_deg, worst)
        )
        picked = np.flatnonzero(mask)
        rows.append(picked)
        index.append(np.full(picked.size, len(results) - 1))
    if not results:
        return None
    all_rows = np.concatenate(rows)
    all_error = frames.joints_rad[all_rows] - frames.joint_targets_rad[all_rows]
    rms_deg, peak_deg, worst = _stats(all_error)
    return JointTrackingAnalysis(
        kinds=tuple(kinds),
        segments=tuple(results),
        rms_error_deg=rms_deg,
        peak_error_deg=peak_deg,
        worst_joint=worst,
        t_s=t_all[all_rows],
        segment_index=np.concatenate(index).astype(np.float64),
        commanded_deg=np.degrees(frames.joint_targets_rad[all_rows]),
        measured_deg=np.degrees(frames.joints_rad[all_rows]),
        missing=tuple(missing),
    )
