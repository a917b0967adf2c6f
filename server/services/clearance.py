"""The clearance actually flown: the least distance between any two bodies that may not
touch, computed from the MEASURED joints of a pass's telemetry, beside the one the plan's
flight rules predicted (docs/robots.md).

At every frame of the pass, the exact minimum over every checked pair of the robot's
description (``description.collision.pairs``), by the planner's own
:func:`planner.clearance_sampling.sampled_clearance` on the bodies posed at the measured joints
(a pair is asked again only when the path its bodies may have travelled since its last
exact distance could have brought it below the best found at that frame, each joint's path
being what it measured between the two frames): the same geometry, poses and coal queries as
the flight rules and the live watch (:class:`planner.clearance_watch.ClearanceWatch`), whose
value at a frame at or below its threshold is this one's. Every frame, not a decimation:
the demo pass's 15 473 frames take about 0.3 s, and a minimum between two frames taken could
be missed by the arm's motion in between.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.clearance_sampling import sampled_clearance
from planner.collision import body_poses
from planner.errors import InvalidInput
from planner.flight_rules import FlightRulesReport
from planner.robot import RobotDescription
from telemetry.recording import PassRecording

__all__ = ["FlownClearance", "flown_clearance"]

Array = NDArray[np.float64]


@dataclass(frozen=True)
class FlownClearance:
    """The least flown clearance (m), when (plan clock, s) and between which bodies; the
    limit; the predicted row's numbers from the plan's report (None: the plan has none)."""

    value_m: float
    t_s: float
    bodies: tuple[str, str]
    limit_m: float
    n_frames: int
    n_frames_total: int
    n_pairs: int
    n_queries: int
    predicted_m: float | None
    predicted_t_s: float | None
    predicted_bodies: tuple[str, str] | None

    @property
    def passed(self) -> bool:
        return self.value_m >= self.limit_m

    def to_dict(self) -> dict[str, Any]:
        return {
            "flown": {
                "value_m": self.value_m,
                "t_s": self.t_s,
                "bodies": list(self.bodies),
                "verdict": "pass" if self.passed else "fail",
            },
            "predicted": None
            if self.predicted_m is None
            else {
                "value_m": self.predicted_m,
                "t_s": self.predicted_t_s,
                "bodies": None if self.predicted_bodies is None else list(self.predicted_bodies),
            },
            "limit_m": self.limit_m,
            "n_frames": self.n_frames,
            "n_frames_total": self.n_frames_total,
            "n_pairs": self.n_pairs,
            "n_queries": self.n_queries,
        }


def flown_clearance(recording: PassRecording, description: RobotDescription) -> FlownClearance:
    """The least clearance over the pass's measured joints (module doc), over every checked
    pair (the arm against the spacecraft and against itself)."""
    collision = description.collision
    if collision is None or not collision.pairs:
        raise InvalidInput(
            f"robot {description.name!r} has no collision shapes: the clearance flown "
            "cannot be computed"
        )
    total = len(recording.frames)
    if total == 0:
        raise InvalidInput("the pass has no telemetry frames: no clearance was measured")
    model = description.model
    joints = np.asarray(recording.frames.joints_rad, dtype=np.float64)
    times = recording.t_s()
    R, t = body_poses(model, joints)
    # the path of each joint between two frames taken: what the measured joints moved
    found = sampled_clearance(
        collision, collision.pairs, R, t, np.abs(np.diff(joints, axis=0)), model
    )
    a, b = found.worst_pair
    predicted = _predicted(recording)
    return FlownClearance(
        value_m=found.worst_m,
        t_s=float(times[found.worst_sample]),
        bodies=(collision.bodies[a].name, collision.bodies[b].name),
        limit_m=description.flight_rules.min_clearance_m,
        n_frames=total,
        n_frames_total=total,
        n_pairs=len(collision.pairs),
        n_queries=found.queries,
        predicted_m=None if predicted is None else predicted[0],
        predicted_t_s=None if predicted is None else predicted[1],
        predicted_bodies=None if predicted is None else predicted[2],
    )


def _predicted(
    recording: PassRecording,
) -> tuple[float, float | None, tuple[str, str] | None] | None:
    """The plan's predicted least clearance over every checked pair (value, time, bodies):
    the nearer of its ``clearance`` and ``self_clearance`` rows; None without a report."""
    if recording.plan.flight_rules is None:
        return None
    report = FlightRulesReport.from_dict(recording.plan.flight_rules)
    rows = [r for r in report.rows if r.rule in ("clearance", "self_clearance")]
    if not rows:
        return None
    row = min(rows, key=lambda r: r.value)
    return row.value, row.t_s, row.bodies
