"""Experiment 2: the hand's attitude seen from the orbit (inertial) frame (paper Fig. 8).

At every frame of the GJM experiment the hand's orientation in the orbit frame is
``rot_orbit_from_hand = rot_orbit_from_base(measured) @ rot_base_from_hand(measured joints)``
(:meth:`planner.dynamics.DynamicsWorkspace.hand_pose`). The pointing plot is the approach
axis (hand x) in the orbit frame as yaw and pitch, the same angles as the hand's roll, pitch,
yaw of ``Rz(yaw) Ry(pitch) Rx(roll)``: ``x_hand = (cos y cos p, sin y cos p, -sin p)``.

Per GJM leg (``approach``, ``retreat``) and over the legs' whole window (legs and the pause
between), with both attitudes smoothed by a centred ``smooth_s`` moving average and taken
relative to their mean over the ``smooth_s`` before the window starts:
``hand_change_max_deg`` and ``base_change_max_deg`` are the largest rotation angles from that
reference, and ``hold_ratio`` is their quotient (0: the hand held perfectly while the base
turned). The pause in free drift also shows the gravity-gradient drift, which turns hand and
base together.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.dynamics import DynamicsWorkspace
from planner.frames import quat_xyzw_from_matrix
from planner.state import State
from telemetry.analysis._common import (
    Array,
    deviation_rad,
    experiment_segments,
    json_array,
    json_array_or_none,
    json_number,
    mean_quat_xyzw,
    moving_average,
    rpy_rad,
    window_mask,
)
from telemetry.recording import PassRecording

__all__ = ["HandAttitudeAnalysis", "HandHold", "analyse_hand_attitude"]


@dataclass(frozen=True)
class HandHold:
    """How well the hand's orbit-frame attitude was held over one span."""

    span: str
    t_start_s: float
    t_end_s: float
    frames: int
    hand_change_max_deg: float | None
    base_change_max_deg: float | None
    hand_pitch_change_range_deg: tuple[float, float] | None
    base_pitch_change_range_deg: tuple[float, float] | None

    @property
    def hold_ratio(self) -> float | None:
        if self.hand_change_max_deg is None or not self.base_change_max_deg:
            return None
        return self.hand_change_max_deg / self.base_change_max_deg

    def to_dict(self) -> dict[str, Any]:
        return {
            "span": self.span,
            "t_start_s": json_number(self.t_start_s),
            "t_end_s": json_number(self.t_end_s),
            "frames": self.frames,
            "hand_change_max_deg": json_number(self.hand_change_max_deg),
            "base_change_max_deg": json_number(self.base_change_max_deg),
            "hold_ratio": json_number(self.hold_ratio),
            "hand_pitch_change_range_deg": json_array_or_none(self.hand_pitch_change_range_deg),
            "base_pitch_change_range_deg": json_array_or_none(self.base_pitch_change_range_deg),
        }


@dataclass(frozen=True, eq=False)
class HandAttitudeAnalysis:
    smooth_s: float
    holds: tuple[HandHold, ...]
    #: series over the experiment's segments
    t_s: Array
    rpy_hand_orbit_deg: Array
    rpy_base_deg: Array
    pointing_yaw_deg: Array
    pointing_pitch_deg: Array
    predicted_t_s: Array
    predicted_rpy_hand_orbit_deg: Array
    missing: tuple[str, ...] = ()

    def hold(self, span: str) -> HandHold:
        for h in self.holds:
            if h.span == span:
                return h
        raise KeyError(span)

    def to_dict(self) -> dict[str, Any]:
        return {
            "smooth_s": self.smooth_s,
            "holds": [h.to_dict() for h in self.holds],
            "series": {
                "t_s": json_array(self.t_s),
                "rpy_hand_orbit_deg": json_array(self.rpy_hand_orbit_deg),
                "rpy_base_deg": json_array(self.rpy_base_deg),
                "pointing_yaw_deg": json_array(self.pointing_yaw_deg),
                "pointing_pitch_deg": json_array(self.pointing_pitch_deg),
                "predicted_t_s": json_array(self.predicted_t_s),
                "predicted_rpy_hand_orbit_deg": json_array(self.predicted_rpy_hand_orbit_deg),
            },
            "missing": list(self.missing),
        }


def hand_quats_orbit_xyzw(
    ws: DynamicsWorkspace, joints_rad: Array, quats_orbit_from_base_xyzw: Array
) -> Array:
    """``quat_orbit_from_hand`` (n, 4) for each row of measured joints and base attitude."""
    out = np.zeros((len(joints_rad), 4))
    for k in range(len(joints_rad)):
        pose = ws.hand_pose(
            State(joints_rad=joints_rad[k], quat_orbit_from_base_xyzw=quats_orbit_from_base_xyzw[k])
        )
        out[k] = quat_xyzw_from_matrix(pose.rot_orbit_from_hand)
    return out


def analyse_hand_attitude(
    recording: PassRecording, workspace: DynamicsWorkspace, *, smooth_s: float = 2.0
) -> HandAttitudeAnalysis | None:
    """Experiment 2's analysis, or ``None`` when the plan has no GJM leg."""
    segments = experiment_segments(recording.plan, "gjm")
    legs = [s for s in segments if s.kind == "gjm"]
    if not legs:
        return None
    t_all = recording.t_s()
    frames = recording.frames
    mask = window_mask(t_all, segments[0].t_start_s, segments[-1].t_end_s)
    t = t_all[mask]
    base_q = frames.quat_orbit_from_base_xyzw[mask]
    hand_q = hand_quats_orbit_xyzw(workspace, frames.joints_rad[mask], base_q)
    rpy_hand = rpy_rad(hand_q) if t.size else np.zeros((0, 3))
    pred = recording.plan.prediction
    pmask = window_mask(pred.t_s, segments[0].t_start_s, segments[-1].t_end_s)
    spans = [(short, s.t_start_s, s.t_end_s) for s in legs for short in [_short(s.name)]]
    spans.append(("legs", legs[0].t_start_s, legs[-1].t_end_s))
    holds = [_hold(name, a, b, t, hand_q, base_q, smooth_s) for name, a, b in spans]
    missing = [f"gjm {h.span}: no telemetry" for h in holds if h.frames < 2]
    return HandAttitudeAnalysis(
        smooth_s=smooth_s,
        holds=tuple(holds),
        t_s=t,
        rpy_hand_orbit_deg=np.degrees(rpy_hand),
        rpy_base_deg=np.degrees(rpy_rad(base_q)),
        pointing_yaw_deg=np.degrees(rpy_hand[:, 2]),
        pointing_pitch_deg=np.degrees(rpy_hand[:, 1]),
        predicted_t_s=pred.t_s[pmask],
        predicted_rpy_hand_orbit_deg=np.degrees(rpy_rad(pred.quat_orbit_from_hand_xyzw[pmask])),
        missing=tuple(missing),
    )


def _short(name: str) -> str:
    return name.split(": ", 1)[1] if name.startswith("gjm: ") else name


def _hold(
    span: str,
    t0: float,
    t1: float,
    t: Array,
    hand_q: Array,
    base_q: Array,
    smooth_s: float,
) -> HandHold:
    rows = window_mask(t, t0, t1)
    if int(rows.sum()) < 2:
        return HandHold(span, t0, t1, int(rows.sum()), None, None, None, None)
    before = window_mask(t, t0 - smooth_s, t0)
    ref_rows = before if np.any(before) else np.flatnonzero(rows)[:1]
    hand_dev = moving_average(
        t[rows], deviation_rad(hand_q[rows], mean_quat_xyzw(hand_q[ref_rows])), smooth_s
    )
    base_dev = moving_average(
        t[rows], deviation_rad(base_q[rows], mean_quat_xyzw(base_q[ref_rows])), smooth_s
    )
    # Pitch changes: hand pitch about the orbit-frame-aligned hand axis is not the base's y;
    # compare the hand's orbit-frame pitch angle with its reference instead.
    hand_pitch = rpy_rad(hand_q[rows])[:, 1] - rpy_rad(mean_quat_xyzw(hand_q[ref_rows])[None])[0, 1]
    base_pitch = rpy_rad(base_q[rows])[:, 1] - rpy_rad(mean_quat_xyzw(base_q[ref_rows])[None])[0, 1]
    hand_pitch = moving_average(t[rows], hand_pitch, smooth_s)
    base_pitch = moving_average(t[rows], base_pitch, smooth_s)
    return HandHold(
        span=span,
        t_start_s=t0,
        t_end_s=t1,
        frames=int(rows.sum()),
        hand_change_max_deg=math.degrees(float(np.max(np.linalg.norm(hand_dev, axis=1)))),
        base_change_max_deg=math.degrees(float(np.max(np.linalg.norm(base_dev, axis=1)))),
        hand_pitch_change_range_deg=(
            math.degrees(float(np.min(hand_pitch))),
            math.degrees(float(np.max(hand_pitch))),
        ),
        base_pitch_change_range_deg=(
            math.degrees(float(np.min(base_pitch))),
            math.degrees(float(np.max(base_pitch))),
        ),
    )
