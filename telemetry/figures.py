"""Figures of the post-pass analyses (paper Figs. 5, 6, 8, 9, 11 and predicted-vs-flown) and
of a pass's alarms (their timeline), as PNG bytes.

Each function draws one :mod:`telemetry.analysis` result on a fresh
:class:`matplotlib.figure.Figure` with the Agg canvas and returns the PNG. Figures are built
without :mod:`matplotlib.pyplot`, so nothing is registered globally and nothing is left open.
"""

from __future__ import annotations

import io
import math
from collections.abc import Callable, Sequence
from typing import Any

import matplotlib
import matplotlib.patches

matplotlib.use("Agg")

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from planner.limits import Severity
from telemetry.alarm import AlarmPublic
from telemetry.analysis import (
    EndpointAnalysis,
    HandAttitudeAnalysis,
    JointTrackingAnalysis,
    PassAnalysis,
    PhasePlaneAnalysis,
    PredictedVsFlown,
    ReactionAnalysis,
)
from telemetry.analysis.paper import FLIGHT_FASTEST_SETTLING, FLIGHT_RANGE_ORDER, ordered

__all__ = [
    "alarm_timeline_figure",
    "endpoint_figure",
    "hand_attitude_figure",
    "joint_tracking_figure",
    "pass_figures",
    "phase_plane_figure",
    "predicted_vs_flown_figure",
    "quantity_across_figure",
    "reaction_figure",
]

_RPY = ("roll", "pitch", "yaw")
_DPI = 100


def _png(draw: Callable[[Figure], None], size_in: tuple[float, float]) -> bytes:
    fig = Figure(figsize=size_in, dpi=_DPI, layout="constrained")
    FigureCanvasAgg(fig)
    draw(fig)
    buffer = io.BytesIO()
    # Fixed metadata: the same analysis gives the same bytes.
    fig.savefig(buffer, format="png", metadata={"Software": None})
    return buffer.getvalue()


def _shade(ax: Axes, spans: list[tuple[float, float]]) -> None:
    for a, b in spans:
        ax.axvspan(a, b, color="0.9", zorder=0)


def reaction_figure(result: ReactionAnalysis) -> bytes:
    """Fig. 5: hand speed, reaction momentum and base attitude against time. The middle panel
    is the magnitude ``|H~bm phi'|`` on a log scale, so the
    reactionless legs' few 0.01 N m s show beside the PTP's few N m s, each motion labelled
    with its RMS."""

    def draw(fig: Figure) -> None:
        axes = fig.subplots(3, 1, sharex=True)
        spans = [(m.t_start_s, m.t_end_s) for m in result.motions]
        for ax in axes:
            _shade(ax, spans)
        axes[0].plot(result.t_s, result.hand_speed_mps)
        axes[0].set_ylabel("hand speed (m/s)")
        momentum = np.linalg.norm(result.reaction_momentum_orbit_nms, axis=1)
        axes[1].plot(result.t_s, momentum, color="k", lw=0.8)
        axes[1].set_yscale("log")
        axes[1].set_ylim(1e-3, 30.0)
        axes[1].set_ylabel("|H~bm phi'| (N m s, log)")
        for m in result.motions:
            if m.rms_reaction_momentum_nms is not None:
                speed = (
                    "" if m.peak_hand_speed_mps is None else f"{m.peak_hand_speed_mps:.4f} m/s\n"
                )
                axes[1].annotate(
                    f"{speed}RMS {m.rms_reaction_momentum_nms:.3g} N m s",
                    ((m.t_start_s + m.t_end_s) / 2, 0.97),
                    xycoords=("data", "axes fraction"),
                    ha="center",
                    va="top",
                    fontsize="x-small",
                    bbox={"facecolor": "white", "edgecolor": "none", "alpha": 0.8},
                )
        for i, name in enumerate(_RPY):
            axes[2].plot(result.t_s, result.rpy_base_deg[:, i], label=name)
        axes[2].set_ylabel("base attitude (deg)")
        axes[2].set_xlabel("t (s)")
        axes[2].legend(loc="upper right", fontsize="small")
        for m in result.motions:
            if m.settling_time_s is not None and m.settling_time_s > 0:
                axes[2].axvline(m.t_end_s + m.settling_time_s, color="k", ls=":", lw=0.8)
        legs = sorted(
            (m for m in result.motion("reactionless") if m.peak_hand_speed_mps is not None),
            key=lambda m: -(m.peak_hand_speed_mps or 0.0),
        )
        order = ""
        fast, slow = (legs[0], legs[-1]) if len(legs) > 1 else (None, None)
        if fast and slow and fast.rms_reaction_momentum_nms and slow.rms_reaction_momentum_nms:
            holds = fast.rms_reaction_momentum_nms > slow.rms_reaction_momentum_nms
            order = (
                f"\nthe faster leg, the larger reaction (flight): "
                f"{'holds' if holds else 'does not hold'} on RMS |H~bm phi'| "
                f"({fast.rms_reaction_momentum_nms:.3g} against "
                f"{slow.rms_reaction_momentum_nms:.3g} N m s)"
            )
        fig.suptitle(
            f"PTP and reactionless motion (settling band {result.settle_band_deg} deg){order}"
        )

    return _png(draw, (8, 7))


def joint_tracking_figure(
    result: JointTrackingAnalysis, kind: str | None = "reactionless"
) -> bytes:
    """Fig. 6: commanded and measured joint angles and their error, for segments of ``kind``
    (all analysed segments when ``None`` or when there are none of that kind)."""
    chosen = [i for i, s in enumerate(result.segments) if kind is None or s.kind == kind]
    if not chosen:
        chosen = list(range(len(result.segments)))
    rows = np.isin(result.segment_index, chosen)

    def draw(fig: Figure) -> None:
        axes = fig.subplots(2, 1, sharex=True)
        t = result.t_s[rows]
        for j in range(result.commanded_deg.shape[1]):
            (line,) = axes[0].plot(t, result.measured_deg[rows, j], ".", ms=1.5)
            axes[0].plot(t, result.commanded_deg[rows, j], "-", lw=0.8, color=line.get_color())
            axes[1].plot(t, result.error_deg[rows, j], ".", ms=1.5, label=f"joint {j + 1}")
        axes[0].set_ylabel("joint angle (deg)\nline: commanded, dots: measured")
        axes[1].set_ylabel("measured - commanded (deg)")
        axes[1].set_xlabel("t (s)")
        axes[1].legend(loc="upper right", fontsize="small", ncols=3, markerscale=5)
        fig.suptitle(f"Joint tracking ({kind or 'all motions'}); worst joint {result.worst_joint}")

    return _png(draw, (8, 6))


def hand_attitude_figure(result: HandAttitudeAnalysis) -> bytes:
    """Fig. 8: hand and base attitude (orbit frame) against time and the pointing plot."""

    def draw(fig: Figure) -> None:
        subfigures = fig.subfigures(1, 2, width_ratios=[2, 1])
        assert isinstance(subfigures, np.ndarray)
        left, right = subfigures[0], subfigures[1]
        axes = left.subplots(2, 1, sharex=True)
        rel = result.rpy_hand_orbit_deg - (result.rpy_hand_orbit_deg[:1] if result.t_s.size else 0)
        for i, name in enumerate(_RPY):
            axes[0].plot(result.t_s, rel[:, i], label=f"hand {name}")
            axes[1].plot(result.t_s, result.rpy_base_deg[:, i], label=f"base {name}")
        axes[0].set_ylabel("hand attitude change,\norbit frame (deg)")
        axes[1].set_ylabel("base attitude (deg)")
        axes[1].set_xlabel("t (s)")
        for ax in axes:
            ax.legend(loc="upper right", fontsize="small")
        ax = right.subplots()
        ax.plot(result.pointing_yaw_deg, result.pointing_pitch_deg, ".", ms=2, label="flown")
        pred = result.predicted_rpy_hand_orbit_deg
        ax.plot(pred[:, 2], pred[:, 1], "-", lw=0.8, color="k", label="predicted")
        ax.set_xlabel("approach-axis yaw (deg)")
        ax.set_ylabel("approach-axis pitch (deg)")
        ax.legend(fontsize="small")
        fig.suptitle("Hand attitude in the orbit frame (GJM)")

    return _png(draw, (10, 5))


def phase_plane_figure(result: PhasePlaneAnalysis) -> bytes:
    """Fig. 9: pitch against pitch rate for each attitude-control variant, side by side on
    shared axes, the first dip (forward leg's lowest pitch) and the peak marked, and the
    ordering of ranges and settling times against the flight's."""

    def draw(fig: Figure) -> None:
        axes = np.atleast_1d(fig.subplots(1, len(result.variants), sharex=True, sharey=True))
        for ax, v in zip(axes, result.variants, strict=True):
            ax.plot(v.pitch_deg, v.pitch_rate_degps, lw=0.8)
            ax.axhline(0.0, color="0.6", lw=0.5)
            ax.axvline(0.0, color="0.6", lw=0.5)
            for t_mark, marker, name in (
                (v.first_dip_t_s, "v", "first dip"),
                (v.peak_t_s, "^", "peak"),
            ):
                if t_mark is not None and v.t_s.size:
                    k = int(np.argmin(np.abs(v.t_s - t_mark)))
                    ax.plot(
                        v.pitch_deg[k],
                        v.pitch_rate_degps[k],
                        marker,
                        color="C3",
                        label=f"{name} {v.pitch_deg[k]:+.2f}",
                    )
            if v.first_dip_t_s is not None or v.peak_t_s is not None:
                ax.legend(loc="lower right", fontsize="x-small")
            rng = "n/a" if v.pitch_range_deg is None else f"{v.pitch_range_deg:.2f} deg"
            rank = v.settling_rank_s
            if rank is None:
                settle = "n/a"
            else:
                settle = f"{rank:.0f} s" if math.isfinite(rank) else "not by its window's end"
            ax.set_title(f"{v.label} {v.variant}\nrange {rng}, settles {settle}", fontsize=9)
            ax.set_xlabel("pitch (deg)")
        axes[0].set_ylabel("pitch rate (deg/s)")
        ranges = {v.label: v.pitch_range_deg for v in result.variants}
        settles = {v.label: v.settling_rank_s for v in result.variants}
        fig.suptitle(
            f"Base pitch phase plane. Range: {ordered(ranges, 'deg')} "
            f"(flight: {' < '.join(FLIGHT_RANGE_ORDER)}); settling: "
            f"{ordered(settles, 's', digits=0)} (flight: {FLIGHT_FASTEST_SETTLING} fastest)",
            fontsize=9,
        )

    return _png(draw, (4 * max(1, len(result.variants)), 4.3))


def endpoint_figure(result: EndpointAnalysis) -> bytes:
    """Fig. 11: joints and base attitude through the non-holonomic motion, with prediction."""

    def draw(fig: Figure) -> None:
        axes = fig.subplots(2, 1, sharex=True)
        for ax in axes:
            _shade(ax, [(result.motion_start_s, result.motion_end_s)])
        for j in range(result.joints_deg.shape[1]):
            (line,) = axes[0].plot(result.t_s, result.joints_deg[:, j], label=f"joint {j + 1}")
            axes[0].plot(
                result.predicted_t_s, result.predicted_joints_deg[:, j], "--", lw=0.8,
                color=line.get_color(),
            )  # fmt: skip
        for i, name in enumerate(_RPY):
            (line,) = axes[1].plot(result.t_s, result.rpy_base_deg[:, i], label=name)
            axes[1].plot(
                result.predicted_t_s, result.predicted_rpy_base_deg[:, i], "--", lw=0.8,
                color=line.get_color(),
            )  # fmt: skip
        axes[0].set_ylabel("joint angle (deg)")
        axes[1].set_ylabel("base attitude (deg)")
        axes[1].set_xlabel("t (s); dashed: predicted")
        axes[0].legend(loc="upper right", fontsize="small", ncols=2)
        axes[1].legend(loc="upper right", fontsize="small")
        err = result.attitude_change_error_deg
        text = "n/a" if err is None else ", ".join(f"{v:+.3f}" for v in err)
        fig.suptitle(f"Non-holonomic motion; attitude change error (r, p, y) {text} deg")

    return _png(draw, (8, 6))


def predicted_vs_flown_figure(result: PredictedVsFlown) -> bytes:
    """Predicted against flown base attitude, and the attitude and joint differences."""

    def draw(fig: Figure) -> None:
        axes = fig.subplots(3, 1, sharex=True)
        for i, name in enumerate(_RPY):
            (line,) = axes[0].plot(result.t_s, result.rpy_base_flown_deg[:, i], lw=0.8, label=name)
            axes[0].plot(
                result.t_s, result.rpy_base_predicted_deg[:, i], "--", lw=0.8,
                color=line.get_color(),
            )  # fmt: skip
        axes[0].set_ylabel("base attitude (deg)\ndashed: predicted")
        axes[0].legend(loc="upper right", fontsize="small")
        axes[1].plot(result.t_s, result.attitude_difference_deg, lw=0.8)
        axes[1].set_ylabel("attitude difference (deg)")
        for j in range(result.joint_difference_deg.shape[1]):
            axes[2].plot(result.t_s, result.joint_difference_deg[:, j], lw=0.8, label=f"{j + 1}")
        axes[2].set_ylabel("joint difference (deg)")
        axes[2].set_xlabel("t (s)")
        axes[2].legend(loc="upper right", fontsize="small", ncols=3, title="joint")
        fig.suptitle("Predicted against flown")

    return _png(draw, (9, 7))


def pass_figures(analysis: PassAnalysis) -> dict[str, bytes]:
    """Every figure that applies to ``analysis``, by name (its part of ``analysis``)."""
    figures: dict[str, Callable[[Any], bytes]] = {
        "reaction": reaction_figure,
        "joint_tracking": joint_tracking_figure,
        "hand_attitude": hand_attitude_figure,
        "phase_plane": phase_plane_figure,
        "endpoint": endpoint_figure,
        "predicted_vs_flown": predicted_vs_flown_figure,
    }
    parts = {name: getattr(analysis, name) for name in figures}
    return {name: figures[name](part) for name, part in parts.items() if part is not None}


#: Band colours of the alarm timeline, lowest severity first (Yamcs's five levels).
_SEVERITY_COLOURS = {
    Severity.WATCH: "#9ecae1",
    Severity.WARNING: "#fdd835",
    Severity.DISTRESS: "#fb8c00",
    Severity.CRITICAL: "#e53935",
    Severity.SEVERE: "#6a1b9a",
}


def alarm_timeline_figure(alarms: Sequence[AlarmPublic], epoch_ns: int, end_t_s: float) -> bytes:
    """One row per alarm (its quantity and channel), coloured by the band it was in over the
    plan's clock (s from ``t = 0``; onboard times of its frames). A band lasts until the
    alarm's next change, or ``end_t_s`` when none came; ground-timed changes (the link's
    health) are left out. Acknowledgements are not on the onboard clock: the table lists
    them."""
    rows = []
    for alarm in alarms:
        spans = []
        timeline = [
            (e.generation_time_ns, e.severity) for e in alarm.timeline if e.generation_time_ns
        ]
        for k, (gen, severity) in enumerate(timeline):
            if severity is None:
                continue
            t0 = (gen - epoch_ns) / 1e9
            t1 = end_t_s if k + 1 == len(timeline) else (timeline[k + 1][0] - epoch_ns) / 1e9
            spans.append((t0, max(t1 - t0, 0.0), severity))
        rows.append((f"{alarm.quantity}{' ' + alarm.channel if alarm.channel else ''}", spans))

    def draw(fig: Figure) -> None:
        ax = fig.subplots()
        for i, (_, spans) in enumerate(rows):
            for t0, width, severity in spans:
                ax.broken_barh(
                    [(t0, width)], (i - 0.4, 0.8), color=_SEVERITY_COLOURS.get(severity, "0.5")
                )
        ax.set_yticks(range(len(rows)), [label for label, _ in rows], fontsize="small")
        ax.set_ylim(-0.6, len(rows) - 0.4)
        ax.invert_yaxis()
        ax.set_xlabel("t (s, plan clock)")
        handles = [
            matplotlib.patches.Patch(color=colour, label=name)
            for name, colour in _SEVERITY_COLOURS.items()
        ]
        fig.legend(handles=handles, loc="outside lower center", fontsize="small", ncols=5)
        ax.grid(axis="x", color="0.9")
        fig.suptitle("Alarms: the band of each alarm over the pass")

    return _png(draw, (9, 1.8 + 0.35 * max(len(rows), 1)))


def quantity_across_figure(
    field: str,
    unit: str,
    series: Sequence[
        tuple[str, Sequence[float], Sequence[float], Sequence[float], Sequence[float]]
    ],
) -> bytes:
    """One quantity across passes: per pass ``(label, t_s, mean, min, max)``, the mean as a
    line over the band between min and max, each on its own time from its first frame."""

    def draw(fig: Figure) -> None:
        ax = fig.add_subplot()
        for label, t_s, mean, low, high in series:
            (line,) = ax.plot(t_s, mean, label=label, linewidth=1.2)
            ax.fill_between(t_s, low, high, color=line.get_color(), alpha=0.2, linewidth=0)
        ax.set_xlabel("time from the pass's first frame (s)")
        ax.set_ylabel(f"{field} ({unit})" if unit else field)
        ax.set_title(f"{field} across {len(series)} passes (mean, band: min to max)")
        ax.grid(True, alpha=0.3)
        if series:
            ax.legend(loc="best", fontsize="small")

    return _png(draw, (8.0, 4.0))
