"""What part of a pass the telemetry covers: gaps, an early end, frames per segment."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.plan import Segment
from telemetry.analysis._common import GAP_FACTOR, Array, json_number, nominal_period_s, runs
from telemetry.recording import PassRecording

__all__ = ["Coverage", "SegmentCoverage", "coverage", "segment_coverage"]


@dataclass(frozen=True)
class SegmentCoverage:
    """Frames seen in one segment against the frames a full telemetry stream would give."""

    segment: str
    frames: int
    expected_frames: int
    #: the largest interval without a frame inside the segment (edges included), s
    longest_gap_s: float

    @property
    def fraction(self) -> float:
        return self.frames / self.expected_frames if self.expected_frames else 1.0

    def to_dict(self) -> dict[str, Any]:
        return {
            "segment": self.segment,
            "frames": self.frames,
            "expected_frames": self.expected_frames,
            "fraction": json_number(self.fraction),
            "longest_gap_s": json_number(self.longest_gap_s),
        }


def segment_coverage(t_s: Array, segment: Segment, period_s: float) -> SegmentCoverage:
    inside = t_s[(t_s >= segment.t_start_s) & (t_s <= segment.t_end_s)]
    span = segment.t_end_s - segment.t_start_s
    expected = int(np.floor(span / period_s + 1e-9)) + 1
    edges = np.concatenate([[segment.t_start_s], inside, [segment.t_end_s]])
    return SegmentCoverage(
        segment=segment.name,
        frames=int(inside.size),
        expected_frames=expected,
        longest_gap_s=float(np.max(np.diff(edges))) if edges.size > 1 else 0.0,
    )


@dataclass(frozen=True)
class Coverage:
    """Telemetry against the plan: the frame span, the gaps and whether the pass ended early."""

    frames: int
    period_s: float
    first_t_s: float | None
    last_t_s: float | None
    plan_end_s: float
    #: (start, end) of each interval without frames longer than ``GAP_FACTOR`` periods, s
    gaps_s: tuple[tuple[float, float], ...]
    #: telemetry stops before the plan's last command (aborted, or not yet dumped)
    ends_early: bool

    def to_dict(self) -> dict[str, Any]:
        return {
            "frames": self.frames,
            "period_s": json_number(self.period_s),
            "first_t_s": json_number(self.first_t_s),
            "last_t_s": json_number(self.last_t_s),
            "plan_end_s": json_number(self.plan_end_s),
            "gaps_s": [[json_number(a), json_number(b)] for a, b in self.gaps_s],
            "ends_early": self.ends_early,
        }


def coverage(recording: PassRecording) -> Coverage:
    t = recording.t_s()
    plan_end = float(recording.plan.command_times_s[-1])
    period = nominal_period_s(t)
    gaps = tuple(
        (float(t[a.stop - 1]), float(t[b.start]))
        for a, b in zip(runs(t, period)[:-1], runs(t, period)[1:], strict=True)
    )
    last = float(t[-1]) if t.size else None
    return Coverage(
        frames=int(t.size),
        period_s=period,
        first_t_s=float(t[0]) if t.size else None,
        last_t_s=last,
        plan_end_s=plan_end,
        gaps_s=gaps,
        ends_early=last is None or last < plan_end - GAP_FACTOR * period,
    )
