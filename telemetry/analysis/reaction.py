"""Experiment 1, PTP against reactionless motion (paper Fig. 5).

Series over the experiment's frames: hand speed, the arm's reaction momentum ``H~_bm phi'``
(:mod:`telemetry.analysis.momentum`, orbit frame) and the base attitude (roll, pitch, yaw).

Per motion (each ``ptp`` or ``reactionless`` segment of the experiment), from the base
attitude **smoothed** by a centred ``smooth_s`` moving average (the 0.005 deg attitude-sensor
noise would otherwise set the peak of a reactionless leg) and taken relative to the mean
attitude over the ``smooth_s`` before the motion starts:

- ``peak_excursion_deg``: the largest rotation angle from that pre-motion attitude, from the
  motion's start to the end of its observation window (the next motion's start anywhere in
  the plan, or the last frame);
- ``settling_time_s``: after the motion ends, until the attitude stays within
  ``settle_band_deg`` of its **final value** (the mean over the window's last ``final_s``);
  ``None`` when the window ends before it has stayed inside for ``final_s``;
- ``peak_residual_deg``: the same smoothed attitude taken against the plan's prediction
  (ideal tracking, which includes the wheels' recovery from earlier motions): the largest
  change of that difference within any ``residual_span_s`` (5 s), from the motion's start
  to the end of its window. What the motion did that the plan did not foresee, on the time
  scale of its cause: for a reactionless leg the servo lag. The joints trail the path by
  ``L phi'`` (``L`` their lags); a lag common to all joints keeps them on the null space,
  the rest turns the base by about ``-H~_b^-1 H~_bm (L - l) phi'`` (``l`` that common
  part), which follows the hand speed within the servos' second or so: it steps in when a
  leg starts and out when it stops, in proportion to the speed. The wheels' correction of
  it builds over tens of seconds and is left out: it integrates an offset proportional to
  the speed over a time inversely proportional to it, so it is the same for both legs, and
  the slow leg would otherwise carry the fast leg's correction, still unwinding, as its
  own. Measured on the demo pass: the peak change from the pre-leg value is 0.0052 deg fast
  against 0.0045 slow noise-free (the slow one 49 s into its 51 s, the wheels' work) and
  0.0067 against 0.0079 with the sensor noise; within 5 s, 0.0071 against 0.0032, and
  0.0099 against 0.0074;
- ``rms_reaction_momentum_nms``: RMS of ``|H~_bm phi'|`` over the motion (rates over
  ``rate_window_s``, default 3 s here: the reactionless residual is a few 0.01 N m s and
  the encoder noise floor over a 3 s fit about 0.005 N m s).

A peak excursion is not a residual: a motion that starts while the wheels still recover
from the previous one inherits that recovery (in the demo pass, the PTP's tail is most of
the first reactionless leg's excursion).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.coordination import REPORT_SETTLE_BAND_DEG
from planner.dynamics import DynamicsWorkspace
from planner.plan import Segment
from telemetry.analysis._common import (
    MOTION_KINDS,
    Array,
    deviation_rad,
    experiment_segments,
    json_array,
    json_number,
    mean_quat_xyzw,
    moving_average,
    relative_rotvec,
    rms,
    rpy_rad,
    settling_time_s,
    window_mask,
)
from telemetry.analysis._interp import predicted_at
from telemetry.analysis.momentum import arm_reaction
from telemetry.analysis.rates import RATE_METHOD
from telemetry.recording import PassRecording

__all__ = ["MotionSettling", "ReactionAnalysis", "analyse_reaction"]

EXPERIMENTS = ("ptp", "reactionless")


@dataclass(frozen=True)
class MotionSettling:
    segment: str
    kind: str
    t_start_s: float
    t_end_s: float
    window_end_s: float
    frames: int
    peak_excursion_deg: float | None
    #: the signed extreme of the deviation about each base axis x, y, z (deg; for these
    #: sub-degree deviations, roll, pitch and yaw)
    peak_deviation_base_deg: tuple[float, float, float] | None
    final_offset_deg: float | None
    settling_time_s: float | None
    peak_hand_speed_mps: float | None
    peak_reaction_momentum_nms: float | None
    rms_reaction_momentum_nms: float | None = None
    peak_residual_deg: float | None = None
    note: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "segment": self.segment,
            "kind": self.kind,
            "t_start_s": json_number(self.t_start_s),
            "t_end_s": json_number(self.t_end_s),
            "window_end_s": json_number(self.window_end_s),
            "frames": self.frames,
            "peak_excursion_deg": json_number(self.peak_excursion_deg),
            "peak_deviation_base_deg": None
            if self.peak_deviation_base_deg is None
            else json_array(self.peak_deviation_base_deg),
            "final_offset_deg": json_number(self.final_offset_deg),
            "settling_time_s": json_number(self.settling_time_s),
            "settled": self.settling_time_s is not None,
            "peak_hand_speed_mps": json_number(self.peak_hand_speed_mps),
            "peak_reaction_momentum_nms": json_number(self.peak_reaction_momentum_nms),
            "rms_reaction_momentum_nms": json_number(self.rms_reaction_momentum_nms),
            "peak_residual_deg": json_number(self.peak_residual_deg),
            "note": self.note,
        }


@dataclass(frozen=True, eq=False)
class ReactionAnalysis:
    settle_band_deg: float
    smooth_s: float
    final_s: float
    rate_window_s: float
    motions: tuple[MotionSettling, ...]
    t_s: Array
    hand_speed_mps: Array
    reaction_momentum_orbit_nms: Array
    rpy_base_deg: Array
    missing: tuple[str, ...] = ()
    residual_span_s: float = 5.0

    def motion(self, kind: str) -> tuple[MotionSettling, ...]:
        return tuple(m for m in self.motions if m.kind == kind)

    def to_dict(self) -> dict[str, Any]:
        return {
            "settle_band_deg": self.settle_band_deg,
            "smooth_s": self.smooth_s,
            "final_s": self.final_s,
            "rate_window_s": self.rate_window_s,
            "residual_span_s": self.residual_span_s,
            "rate_method": RATE_METHOD,
            "motions": [m.to_dict() for m in self.motions],
            "series": {
                "t_s": json_array(self.t_s),
                "hand_speed_mps": json_array(self.hand_speed_mps),
                "reaction_momentum_orbit_nms": json_array(self.reaction_momentum_orbit_nms),
                "rpy_base_deg": json_array(self.rpy_base_deg),
            },
            "missing": list(self.missing),
        }


def _next_motion_start(recording: PassRecording, segment: Segment) -> float:
    later = [
        s.t_start_s
        for s in recording.plan.segments
        if s.kind in MOTION_KINDS and s.t_start_s >= segment.t_end_s and s is not segment
    ]
    return min(later) if later else math.inf


def analyse_reaction(
    recording: PassRecording,
    workspace: DynamicsWorkspace,
    *,
    settle_band_deg: float = REPORT_SETTLE_BAND_DEG,
    smooth_s: float = 2.0,
    final_s: float = 5.0,
    rate_window_s: float = 3.0,
    residual_span_s: float = 5.0,
) -> ReactionAnalysis | None:
    """Experiment 1's analysis, or ``None`` when the plan has neither PTP nor reactionless
    segments of experiment 1."""
    segments = [s for e in EXPERIMENTS for s in experiment_segments(recording.plan, e)]
    motions = [s for s in segments if s.kind in EXPERIMENTS]
    if not motions:
        return None
    t_all = recording.t_s()
    frames = recording.frames
    t0 = min(s.t_start_s for s in segments)
    t1 = max(s.t_end_s for s in segments)
    mask = window_mask(t_all, t0, t1)
    t = t_all[mask]
    quats = frames.quat_orbit_from_base_xyzw[mask]
    reaction = arm_reaction(
        workspace,
        t,
        frames.joints_rad[mask],
        quats,
        frames.omega_base_in_base_radps[mask],
        rate_window_s=rate_window_s,
    )
    missing: list[str] = []
    results = []
    for seg in motions:
        end = min(_next_motion_start(recording, seg), t1)
        results.append(
            _motion(
                recording,
                seg,
                end,
                settle_band_rad=math.radians(settle_band_deg),
                smooth_s=smooth_s,
                final_s=final_s,
                residual_span_s=residual_span_s,
                t_window=t,
                speed=reaction.hand_speed_mps,
                momentum=reaction.reaction_momentum_orbit_nms,
            )
        )
        if results[-1].note:
            missing.append(f"{seg.name}: {results[-1].note}")
    return ReactionAnalysis(
        settle_band_deg=settle_band_deg,
        smooth_s=smooth_s,
        final_s=final_s,
        rate_window_s=rate_window_s,
        motions=tuple(results),
        t_s=t,
        hand_speed_mps=reaction.hand_speed_mps,
        reaction_momentum_orbit_nms=reaction.reaction_momentum_orbit_nms,
        rpy_base_deg=np.degrees(rpy_rad(quats)),
        missing=tuple(missing),
        residual_span_s=residual_span_s,
    )


def _motion(
    recording: PassRecording,
    seg: Segment,
    window_end_s: float,
    *,
    settle_band_rad: float,
    smooth_s: float,
    final_s: float,
    residual_span_s: float,
    t_window: Array,
    speed: Array,
    momentum: Array,
) -> MotionSettling:
    t_all = recording.t_s()
    quats_all = recording.frames.quat_orbit_from_base_xyzw
    rows = window_mask(t_all, seg.t_start_s, window_end_s)
    t = t_all[rows]
    empty = MotionSettling(
        seg.name, seg.kind, seg.t_start_s, seg.t_end_s, window_end_s, int(t.size),
        None, None, None, None, None, None,
    )  # fmt: skip
    if t.size < 2:
        return _with_note(empty, "no telemetry in the motion's window")
    before = window_mask(t_all, seg.t_start_s - smooth_s, seg.t_start_s)
    ref = mean_quat_xyzw(quats_all[before] if np.any(before) else quats_all[rows][:1])
    dev = moving_average(t, deviation_rad(quats_all[rows], ref), smooth_s)
    residual = _residual(recording, seg.t_start_s, window_end_s, smooth_s, residual_span_s)
    angle = np.linalg.norm(dev, axis=1)
    peak_rows = np.argmax(np.abs(dev), axis=0)
    settle, final = settling_time_s(
        t, dev, motion_end_s=seg.t_end_s, band_rad=settle_band_rad, final_s=final_s
    )
    in_motion = window_mask(t_window, seg.t_start_s, seg.t_end_s)
    note = None
    if t[-1] < window_end_s - 1.0 or t[0] > seg.t_start_s + 1.0:
        note = f"telemetry covers only {t[0]:.1f} s to {t[-1]:.1f} s of the window"
    if settle is None:
        note = (note + "; " if note else "") + "not settled within the window"
    return MotionSettling(
        segment=seg.name,
        kind=seg.kind,
        t_start_s=seg.t_start_s,
        t_end_s=seg.t_end_s,
        window_end_s=window_end_s,
        frames=int(t.size),
        peak_excursion_deg=math.degrees(float(np.max(angle))),
        peak_deviation_base_deg=(
            math.degrees(float(dev[peak_rows[0], 0])),
            math.degrees(float(dev[peak_rows[1], 1])),
            math.degrees(float(dev[peak_rows[2], 2])),
        ),
        final_offset_deg=math.degrees(float(np.linalg.norm(final))),
        settling_time_s=settle,
        peak_hand_speed_mps=float(np.max(speed[in_motion])) if np.any(in_motion) else None,
        peak_reaction_momentum_nms=(
            float(np.max(np.linalg.norm(momentum[in_motion], axis=1)))
            if np.any(in_motion)
            else None
        ),
        rms_reaction_momentum_nms=(
            float(rms(np.linalg.norm(momentum[in_motion], axis=1))) if np.any(in_motion) else None
        ),
        peak_residual_deg=residual,
        note=note,
    )


def _residual(
    recording: PassRecording,
    t_start_s: float,
    window_end_s: float,
    smooth_s: float,
    span_s: float,
) -> float | None:
    """Largest change of the smoothed flown-against-predicted attitude within ``span_s``,
    over spans ending from ``t_start_s`` to ``window_end_s`` (deg; the module doc says why)."""
    t_all = recording.t_s()
    rows = window_mask(t_all, t_start_s - smooth_s - span_s, window_end_s)
    t = t_all[rows]
    if t.size < 2:
        return None
    _, predicted = predicted_at(recording.plan.prediction, t)
    flown = recording.frames.quat_orbit_from_base_xyzw[rows]
    diff = moving_average(t, relative_rotvec(predicted, flown), smooth_s)
    # For each row from the motion's start, the row span_s earlier (or the window's first).
    earlier = np.searchsorted(t, t - span_s + 1e-9)
    later = np.flatnonzero(t >= t_start_s)
    if later.size == 0:
        return None
    change = np.linalg.norm(diff[later] - diff[earlier[later]], axis=1)
    return math.degrees(float(np.max(change)))


def _with_note(m: MotionSettling, note: str) -> MotionSettling:
    from dataclasses import replace

    return replace(m, note=note)
