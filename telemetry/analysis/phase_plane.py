"""Experiment 3: the pitch / pitch-rate phase plane of the three attitude-control variants
(paper Fig. 9): (a) feedback, (b) momentum feedforward, (c) offset destination.

A variant's window runs from its forward leg's start to the next variant's start (or the end
of its ``settle`` segment, or the last frame). Pitch is the measured attitude's pitch
(``Rz Ry Rx``); pitch rate is the gyro's y component (base frame; for these sub-degree
attitudes the pitch rate to within 1e-4 of its value). Both are smoothed by a centred
``smooth_s`` moving average (attitude-sensor noise, 0.005 deg, would otherwise widen the range
by about three of its sigmas).

``start_pitch_deg`` is the (smoothed) pitch when the forward leg starts: the paper's variants
each start at the phase plane's origin (3.5), so a variant whose start lies outside
``settle_band_deg`` began before the one before it had settled, and its numbers carry that
one's tail. ``pitch_range_deg`` is max minus min pitch over the window; ``first_dip_deg`` is
the minimum pitch during the forward leg (the first response to the arm's start, Fig. 9's "within
-0.3 deg" of (b)) and ``peak_deg`` the maximum over the whole window (the positive overshoot;
equal to ``pitch_max_deg``), each with its time; ``settling_time_s`` runs from the
end of the back leg until the pitch stays within ``settle_band_deg`` of the pitch the loop
is commanded to hold at the window's end (the plan's attitude-control target: the phase
plane's origin, "finally converging to zero", paper 3.5), ``None`` when it has not by the
window's end (stayed inside for ``final_s``). Not the window's last pitch: the pass waits
120 s after each variant, and none has reached its final value by then, so settling measured
to where the window happens to end would depend on the wait (docs/spacecraft.md). A window
in free drift (no target) falls back to the mean over its last ``final_s``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.attitude_control import AcsMode
from planner.coordination import REPORT_SETTLE_BAND_DEG
from planner.plan import AcsCommand, Segment
from telemetry.analysis._common import (
    Array,
    experiment_segments,
    json_array,
    json_number,
    moving_average,
    rpy_rad,
    settling_time_s,
    window_mask,
)
from telemetry.recording import PassRecording

__all__ = [
    "PhasePlaneAnalysis",
    "VariantPhasePlane",
    "analyse_phase_plane",
    "attitude_target_pitch_rad",
]

_LEG = re.compile(r"\((?P<label>[a-z])\) (?P<variant>\w+): (?P<leg>forward|back)$")


@dataclass(frozen=True, eq=False)
class VariantPhasePlane:
    variant: str  # "feedback", "feedforward" or "offset"
    label: str  # "(a)", "(b)", "(c)"
    t_start_s: float
    motion_end_s: float
    window_end_s: float
    frames: int
    pitch_min_deg: float | None
    pitch_max_deg: float | None
    settling_time_s: float | None
    t_s: Array
    pitch_deg: Array
    pitch_rate_degps: Array
    note: str | None = None
    forward_end_s: float | None = None
    first_dip_deg: float | None = None
    first_dip_t_s: float | None = None
    peak_t_s: float | None = None
    start_pitch_deg: float | None = None

    @property
    def peak_deg(self) -> float | None:
        return self.pitch_max_deg

    @property
    def settling_rank_s(self) -> float | None:
        """The settling time for ordering the variants: ``inf`` when the variant was flown
        whole (frames, no note) and had not settled by its window's end, slower than any
        that had; ``None`` when not measured. (``telemetry.analysis.paper`` reads the same
        from a stored document.)"""
        if self.settling_time_s is not None:
            return self.settling_time_s
        return math.inf if self.frames and not self.note else None

    @property
    def pitch_range_deg(self) -> float | None:
        if self.pitch_min_deg is None or self.pitch_max_deg is None:
            return None
        return self.pitch_max_deg - self.pitch_min_deg

    def to_dict(self) -> dict[str, Any]:
        return {
            "variant": self.variant,
            "label": self.label,
            "t_start_s": json_number(self.t_start_s),
            "motion_end_s": json_number(self.motion_end_s),
            "window_end_s": json_number(self.window_end_s),
            "frames": self.frames,
            "pitch_min_deg": json_number(self.pitch_min_deg),
            "pitch_max_deg": json_number(self.pitch_max_deg),
            "pitch_range_deg": json_number(self.pitch_range_deg),
            "forward_end_s": json_number(self.forward_end_s),
            "first_dip_deg": json_number(self.first_dip_deg),
            "first_dip_t_s": json_number(self.first_dip_t_s),
            "peak_deg": json_number(self.peak_deg),
            "peak_t_s": json_number(self.peak_t_s),
            "start_pitch_deg": json_number(self.start_pitch_deg),
            "settling_time_s": json_number(self.settling_time_s),
            "settled": self.settling_time_s is not None,
            "note": self.note,
            "series": {
                "t_s": json_array(self.t_s),
                "pitch_deg": json_array(self.pitch_deg),
                "pitch_rate_degps": json_array(self.pitch_rate_degps),
            },
        }


@dataclass(frozen=True, eq=False)
class PhasePlaneAnalysis:
    settle_band_deg: float
    smooth_s: float
    final_s: float
    variants: tuple[VariantPhasePlane, ...]
    missing: tuple[str, ...] = ()

    def variant(self, name: str) -> VariantPhasePlane:
        for v in self.variants:
            if v.variant == name:
                return v
        raise KeyError(name)

    def to_dict(self) -> dict[str, Any]:
        return {
            "settle_band_deg": self.settle_band_deg,
            "smooth_s": self.smooth_s,
            "final_s": self.final_s,
            "variants": [v.to_dict() for v in self.variants],
            "missing": list(self.missing),
        }


def _groups(segments: tuple[Segment, ...]) -> list[tuple[str, str, list[Segment]]]:
    groups: dict[str, tuple[str, list[Segment]]] = {}
    for seg in segments:
        found = _LEG.search(seg.name)
        if seg.kind == "coordination" and found:
            label = f"({found['label']})"
            groups.setdefault(label, (found["variant"], []))[1].append(seg)
    return [(label, variant, legs) for label, (variant, legs) in groups.items()]


def attitude_target_pitch_rad(acs: tuple[AcsCommand, ...], t_s: float) -> float | None:
    """The pitch of the attitude target in force just before ``t_s`` (a window's end: a
    command at it belongs to what comes next); None in free drift or with no law."""
    in_force = [c for c in sorted(acs, key=lambda c: c.t_s) if c.t_s < t_s]
    if not in_force or in_force[-1].mode is not AcsMode.FEEDBACK:
        return None
    target = np.asarray(in_force[-1].target_quat_orbit_from_base_xyzw, dtype=np.float64)
    return float(rpy_rad(target[None])[0, 1])


def analyse_phase_plane(
    recording: PassRecording,
    *,
    settle_band_deg: float = REPORT_SETTLE_BAND_DEG,
    smooth_s: float = 1.0,
    final_s: float = 5.0,
) -> PhasePlaneAnalysis | None:
    """Experiment 3's analysis, or ``None`` when the plan has no coordination leg."""
    segments = experiment_segments(recording.plan, "coordination")
    groups = _groups(segments)
    if not groups:
        return None
    t_all = recording.t_s()
    frames = recording.frames
    exp_end = max(s.t_end_s for s in segments)
    starts = [min(s.t_start_s for s in legs) for _, _, legs in groups]
    results: list[VariantPhasePlane] = []
    missing: list[str] = []
    for i, (label, variant, legs) in enumerate(groups):
        t0 = starts[i]
        window_end = starts[i + 1] if i + 1 < len(groups) else exp_end
        motion_end = max(s.t_end_s for s in legs)
        forward = [s for s in legs if s.name.endswith(": forward")]
        forward_end = forward[0].t_end_s if forward else motion_end
        rows = window_mask(t_all, t0, window_end)
        t = t_all[rows]
        if t.size < 2:
            missing.append(f"coordination {label} {variant}: no telemetry")
            results.append(
                VariantPhasePlane(
                    variant,
                    label,
                    t0,
                    motion_end,
                    window_end,
                    int(t.size),
                    None,
                    None,
                    None,
                    t,
                    np.zeros(t.size),
                    np.zeros(t.size),
                    "no telemetry",
                )
            )
            continue
        pitch = moving_average(t, rpy_rad(frames.quat_orbit_from_base_xyzw[rows])[:, 1], smooth_s)
        rate = moving_average(t, frames.omega_base_in_base_radps[rows, 1], smooth_s)
        dev = np.column_stack([np.zeros(t.size), pitch, np.zeros(t.size)])
        target = attitude_target_pitch_rad(recording.plan.acs_commands, window_end)
        settle, _ = settling_time_s(
            t,
            dev,
            motion_end_s=motion_end,
            band_rad=math.radians(settle_band_deg),
            final_s=final_s,
            reference=None if target is None else np.array([0.0, target, 0.0]),
        )
        in_forward = t <= forward_end
        dip = int(np.argmin(np.where(in_forward, pitch, np.inf))) if np.any(in_forward) else None
        peak = int(np.argmax(pitch))
        note = None
        if t[0] > t0 + 1.0 or t[-1] < window_end - 1.0:
            note = f"telemetry covers only {t[0]:.1f} s to {t[-1]:.1f} s of the window"
            missing.append(f"coordination {label} {variant}: {note}")
        results.append(
            VariantPhasePlane(
                variant=variant,
                label=label,
                t_start_s=t0,
                motion_end_s=motion_end,
                window_end_s=window_end,
                frames=int(t.size),
                pitch_min_deg=math.degrees(float(np.min(pitch))),
                pitch_max_deg=math.degrees(float(np.max(pitch))),
                settling_time_s=settle,
                t_s=t,
                pitch_deg=np.degrees(pitch),
                pitch_rate_degps=np.degrees(rate),
                note=note,
                forward_end_s=forward_end,
                first_dip_deg=None if dip is None else math.degrees(float(pitch[dip])),
                first_dip_t_s=None if dip is None else float(t[dip]),
                peak_t_s=float(t[peak]),
                start_pitch_deg=math.degrees(float(pitch[0])) if t[0] <= t0 + 1.0 else None,
            )
        )
    return PhasePlaneAnalysis(
        settle_band_deg=settle_band_deg,
        smooth_s=smooth_s,
        final_s=final_s,
        variants=tuple(results),
        missing=tuple(missing),
    )
