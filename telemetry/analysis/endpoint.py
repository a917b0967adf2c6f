"""Experiment 4: end-point errors of non-holonomic (bi-directional) control (paper Fig. 11).

The flown end state is the mean over the last ``final_s`` of the segment after the motion
when it is a hold (the ``tail``; else the ``final_s`` after the motion's end), so that the
servos have caught up with the last command. The target is the plan's prediction over the
same frames (the joints of the last command, ``phi_end``; the attitude the prediction holds
there: the planner's goal, which in a pass keeps turning slowly in free drift when the wheels
carry momentum from earlier experiments).

Reported: joint errors (flown minus target, deg, per joint), the attitude error
``R_target^T R_flown`` as base-axis small angles and as one angle (deg), and the same for the
flown *change* of attitude (``R_start^T R_end``) against the predicted change, which separates
what the motion did from where the free drift began (in a pass the base starts wherever the
wheels left it, so the plan's end attitude is that start carried through the motion), and
the flown end attitude against the nominal (0, 0, 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.frames import IDENTITY_QUAT_XYZW
from telemetry.analysis._common import (
    Array,
    deviation_rad,
    experiment_segments,
    json_array,
    json_array_or_none,
    json_number,
    mean_quat_xyzw,
    rpy_rad,
    window_mask,
)
from telemetry.analysis._interp import predicted_at
from telemetry.recording import PassRecording

__all__ = ["EndpointAnalysis", "analyse_endpoint"]


@dataclass(frozen=True, eq=False)
class EndpointAnalysis:
    motion_start_s: float
    motion_end_s: float
    final_window_s: tuple[float, float]
    final_frames: int
    target_joints_deg: tuple[float, ...]
    target_rpy_deg: tuple[float, float, float]
    joint_error_deg: tuple[float, ...] | None
    #: small angles about base x, y, z (roll, pitch, yaw), deg
    attitude_error_deg: tuple[float, float, float] | None
    attitude_error_angle_deg: float | None
    attitude_change_error_deg: tuple[float, float, float] | None
    #: the flown end attitude against the nominal (0, 0, 0) of SPEC 3.4, small angles, deg
    attitude_error_nominal_deg: tuple[float, float, float] | None
    #: series from the lead's start to the tail's end, with the prediction's for overlay
    t_s: Array
    joints_deg: Array
    rpy_base_deg: Array
    predicted_t_s: Array
    predicted_joints_deg: Array
    predicted_rpy_base_deg: Array
    missing: tuple[str, ...] = ()

    @property
    def max_joint_error_deg(self) -> float | None:
        if self.joint_error_deg is None:
            return None
        return max(abs(v) for v in self.joint_error_deg)

    def to_dict(self) -> dict[str, Any]:
        return {
            "motion_start_s": json_number(self.motion_start_s),
            "motion_end_s": json_number(self.motion_end_s),
            "final_window_s": json_array(self.final_window_s),
            "final_frames": self.final_frames,
            "target_joints_deg": json_array(self.target_joints_deg),
            "target_rpy_deg": json_array(self.target_rpy_deg),
            "joint_error_deg": json_array_or_none(self.joint_error_deg),
            "max_joint_error_deg": json_number(self.max_joint_error_deg),
            "attitude_error_deg": json_array_or_none(self.attitude_error_deg),
            "attitude_error_angle_deg": json_number(self.attitude_error_angle_deg),
            "attitude_change_error_deg": json_array_or_none(self.attitude_change_error_deg),
            "attitude_error_nominal_deg": json_array_or_none(self.attitude_error_nominal_deg),
            "series": {
                "t_s": json_array(self.t_s),
                "joints_deg": json_array(self.joints_deg),
                "rpy_base_deg": json_array(self.rpy_base_deg),
                "predicted_t_s": json_array(self.predicted_t_s),
                "predicted_joints_deg": json_array(self.predicted_joints_deg),
                "predicted_rpy_base_deg": json_array(self.predicted_rpy_base_deg),
            },
            "missing": list(self.missing),
        }


def _deg3(v: Array) -> tuple[float, float, float]:
    return (math.degrees(float(v[0])), math.degrees(float(v[1])), math.degrees(float(v[2])))


def analyse_endpoint(recording: PassRecording, *, final_s: float = 2.0) -> EndpointAnalysis | None:
    """Experiment 4's analysis, or ``None`` when the plan has no non-holonomic motion."""
    plan = recording.plan
    segments = experiment_segments(plan, "nonholonomic")
    motion = [s for s in segments if s.kind == "nonholonomic"]
    if not motion:
        return None
    t0, t1 = motion[0].t_start_s, motion[-1].t_end_s
    after = [s for s in segments if s.t_start_s >= t1 - 1e-9 and s.kind == "hold"]
    hold_end = after[0].t_end_s if after else t1 + final_s
    final_window = (max(t1, hold_end - final_s), hold_end)
    pred = plan.prediction
    _, start_quat = predicted_at(pred, np.array([t0]))
    t_all = recording.t_s()
    frames = recording.frames
    span = window_mask(t_all, segments[0].t_start_s, segments[-1].t_end_s)
    pspan = window_mask(pred.t_s, segments[0].t_start_s, segments[-1].t_end_s)
    final_rows = window_mask(t_all, *final_window)
    before = window_mask(t_all, t0 - final_s, t0)
    missing: list[str] = []
    joint_error = attitude_error = change_error = nominal_error = None
    angle = None
    final_t = t_all[final_rows] if np.any(final_rows) else np.array([final_window[1]])
    joints_p, quats_p = predicted_at(pred, final_t)
    target_joints = np.mean(joints_p, axis=0)[None]
    target_quat = mean_quat_xyzw(quats_p)[None]
    if np.any(final_rows):
        joints_end = np.mean(frames.joints_rad[final_rows], axis=0)
        quat_end = mean_quat_xyzw(frames.quat_orbit_from_base_xyzw[final_rows])
        joint_error = tuple(math.degrees(float(v)) for v in joints_end - target_joints[0])
        err = deviation_rad(quat_end[None], target_quat[0])[0]
        attitude_error, angle = _deg3(err), math.degrees(float(np.linalg.norm(err)))
        nominal_error = _deg3(deviation_rad(quat_end[None], IDENTITY_QUAT_XYZW)[0])
        if np.any(before):
            quat_start = mean_quat_xyzw(frames.quat_orbit_from_base_xyzw[before])
            flown = deviation_rad(quat_end[None], quat_start)[0]
            predicted = deviation_rad(target_quat, start_quat[0])[0]
            change_error = _deg3(flown - predicted)
        else:
            missing.append("nonholonomic: no telemetry just before the motion")
    else:
        missing.append(
            f"nonholonomic: no telemetry in the end window {final_window[0]:.1f}-"
            f"{final_window[1]:.1f} s (pass ended or gap)"
        )
    return EndpointAnalysis(
        motion_start_s=t0,
        motion_end_s=t1,
        final_window_s=final_window,
        final_frames=int(final_rows.sum()),
        target_joints_deg=tuple(math.degrees(float(v)) for v in target_joints[0]),
        target_rpy_deg=_deg3(rpy_rad(target_quat)[0]),
        joint_error_deg=joint_error,
        attitude_error_deg=attitude_error,
        attitude_error_angle_deg=angle,
        attitude_change_error_deg=change_error,
        attitude_error_nominal_deg=nominal_error,
        t_s=t_all[span],
        joints_deg=np.degrees(frames.joints_rad[span]),
        rpy_base_deg=np.degrees(rpy_rad(frames.quat_orbit_from_base_xyzw[span])),
        predicted_t_s=pred.t_s[pspan],
        predicted_joints_deg=np.degrees(pred.joints_rad[pspan]),
        predicted_rpy_base_deg=np.degrees(pred.rpy_base_rad[pspan]),
        missing=tuple(missing),
    )
