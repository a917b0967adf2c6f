"""Predicted (the plan's ``prediction``, ideal tracking) against flown (telemetry), per segment.

The prediction is sampled at the frame times (:mod:`telemetry.analysis._interp`: joints
linear between the 4 Hz commands, attitude slerped). Per segment, over its frames:

- joint difference, flown minus predicted, per joint: RMS and peak |.| (deg); the flown
  joints lag the commands by the servo lag, so this is mostly the tracking error;
- attitude difference, the angle of ``R_predicted^T R_flown`` (deg): RMS and peak, and the
  peak of each base-axis small angle (roll, pitch, yaw).

The prediction has no sensor noise, no servo lag and, in a pass plan, no gravity gradient:
each shows up here. A flown pass identical to the prediction gives zero everywhere.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from telemetry.analysis._common import (
    Array,
    json_array,
    json_array_or_none,
    json_number,
    relative_rotvec,
    rms,
    rpy_rad,
    window_mask,
)
from telemetry.analysis._interp import predicted_at
from telemetry.recording import PassRecording

__all__ = ["PredictedVsFlown", "SegmentDifference", "analyse_predicted_vs_flown"]


@dataclass(frozen=True)
class SegmentDifference:
    segment: str
    kind: str
    frames: int
    joint_rms_deg: tuple[float, ...] | None
    joint_peak_deg: tuple[float, ...] | None
    attitude_rms_deg: float | None
    attitude_peak_deg: float | None
    #: the largest |small angle| about base x, y, z (roll, pitch, yaw), deg
    attitude_axis_peak_deg: tuple[float, float, float] | None

    @property
    def joint_peak_max_deg(self) -> float | None:
        return None if self.joint_peak_deg is None else max(self.joint_peak_deg)

    def to_dict(self) -> dict[str, Any]:
        return {
            "segment": self.segment,
            "kind": self.kind,
            "frames": self.frames,
            "joint_rms_deg": json_array_or_none(self.joint_rms_deg),
            "joint_peak_deg": json_array_or_none(self.joint_peak_deg),
            "joint_peak_max_deg": json_number(self.joint_peak_max_deg),
            "attitude_rms_deg": json_number(self.attitude_rms_deg),
            "attitude_peak_deg": json_number(self.attitude_peak_deg),
            "attitude_axis_peak_deg": json_array_or_none(self.attitude_axis_peak_deg),
        }


@dataclass(frozen=True, eq=False)
class PredictedVsFlown:
    segments: tuple[SegmentDifference, ...]
    #: series over every frame within the plan
    t_s: Array
    attitude_difference_deg: Array
    joint_difference_deg: Array  # (n, joints)
    rpy_base_flown_deg: Array
    rpy_base_predicted_deg: Array
    missing: tuple[str, ...] = ()

    def segment(self, name: str) -> SegmentDifference:
        for s in self.segments:
            if s.segment == name:
                return s
        raise KeyError(name)

    def to_dict(self) -> dict[str, Any]:
        return {
            "segments": [s.to_dict() for s in self.segments],
            "series": {
                "t_s": json_array(self.t_s),
                "attitude_difference_deg": json_array(self.attitude_difference_deg),
                "joint_difference_deg": json_array(self.joint_difference_deg),
                "rpy_base_flown_deg": json_array(self.rpy_base_flown_deg),
                "rpy_base_predicted_deg": json_array(self.rpy_base_predicted_deg),
            },
            "missing": list(self.missing),
        }


def analyse_predicted_vs_flown(recording: PassRecording) -> PredictedVsFlown:
    """Differences for every segment of the plan (a segment without frames is listed in
    ``missing`` and has ``None`` statistics)."""
    plan = recording.plan
    pred = plan.prediction
    t_all = recording.t_s()
    frames = recording.frames
    inside = window_mask(t_all, float(pred.t_s[0]), float(pred.t_s[-1]))
    t = t_all[inside]
    joints_p, quats_p = predicted_at(pred, t)
    joint_diff = frames.joints_rad[inside] - joints_p
    att = relative_rotvec(quats_p, frames.quat_orbit_from_base_xyzw[inside])
    angle = np.linalg.norm(att, axis=1)
    results = []
    missing = []
    for seg in plan.segments:
        rows = window_mask(t, seg.t_start_s, seg.t_end_s)
        if not np.any(rows):
            missing.append(f"{seg.name}: no telemetry")
            results.append(SegmentDifference(seg.name, seg.kind, 0, None, None, None, None, None))
            continue
        jd, ad = joint_diff[rows], att[rows]
        peak_axis = np.max(np.abs(ad), axis=0)
        results.append(
            SegmentDifference(
                segment=seg.name,
                kind=seg.kind,
                frames=int(rows.sum()),
                joint_rms_deg=tuple(math.degrees(float(v)) for v in rms(jd, axis=0)),
                joint_peak_deg=tuple(math.degrees(float(v)) for v in np.max(np.abs(jd), axis=0)),
                attitude_rms_deg=math.degrees(float(rms(angle[rows]))),
                attitude_peak_deg=math.degrees(float(np.max(angle[rows]))),
                attitude_axis_peak_deg=(
                    math.degrees(float(peak_axis[0])),
                    math.degrees(float(peak_axis[1])),
                    math.degrees(float(peak_axis[2])),
                ),
            )
        )
    return PredictedVsFlown(
        segments=tuple(results),
        t_s=t,
        attitude_difference_deg=np.degrees(angle),
        joint_difference_deg=np.degrees(joint_diff),
        rpy_base_flown_deg=np.degrees(rpy_rad(frames.quat_orbit_from_base_xyzw[inside])),
        rpy_base_predicted_deg=np.degrees(rpy_rad(quats_p)),
        missing=tuple(missing),
    )
