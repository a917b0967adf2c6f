"""The clearance actually flown: the least distance between any two bodies that may not
touch, computed from the MEASURED joints of a pass's telemetry, beside the one the plan's
flight rules predicted (issue #24, docs/robots.md).

The pass's frames are taken at most :data:`MAX_FRAMES` of them, evenly spread (the demo
pass has about 12 000); at each the exact minimum over every checked pair of the robot's
description (``description.collision.pairs``, coal's distances via
:class:`planner.collision.ShapeSet`, the bodies posed by :func:`planner.collision.body_poses`
at the measured joints). A pair is asked again only when the path its bodies may have
travelled since its last exact distance (joint by joint, ``|dq_k|`` times the reach bound
``rho``) could have brought it below the best found at that frame: the minimum is exact at
every frame taken, at a fraction of the queries.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.collision import CollisionModel, ShapeSet, body_poses, reach_bounds
from planner.errors import InvalidInput
from planner.flight_rules import FlightRulesReport
from planner.model import RobotModel
from planner.robot import RobotDescription
from telemetry.recording import PassRecording

__all__ = ["MAX_FRAMES", "FlownClearance", "flown_clearance"]

Array = NDArray[np.float64]

#: The most telemetry frames the flown clearance is computed at.
MAX_FRAMES = 2000


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


def _pair_coefficients(collision: CollisionModel, model: RobotModel) -> Array:
    """``C[p, k]``: how far pair p's bodies can move relative to each other per radian of
    joint k (the reach of joint k to the body it moves; 0 for joints that move both or
    neither)."""
    rho = reach_bounds(model, collision)
    out = np.zeros((len(collision.pairs), model.n_joints))
    for p, (a, b) in enumerate(collision.pairs):
        ja, jb = collision.bodies[a].joint, collision.bodies[b].joint
        lo, hi, moving = (ja, jb, b) if ja < jb else (jb, ja, a)
        out[p, lo:hi] = rho[lo:hi, moving]
    return out


def flown_clearance(
    recording: PassRecording, description: RobotDescription, max_frames: int = MAX_FRAMES
) -> FlownClearance:
    """The least clearance over the pass's measured joints (module doc)."""
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
    rows = np.unique(np.linspace(0, total - 1, min(total, max_frames)).round().astype(np.int64))
    joints = np.asarray(recording.frames.joints_rad, dtype=np.float64)[rows]
    times = recording.t_s()[rows]
    R, t = body_poses(model, joints)
    shapes = ShapeSet(collision)
    pairs = collision.pairs
    frame_of = [body.joint for body in collision.bodies]
    drift_per_step = np.abs(np.diff(joints, axis=0)) @ _pair_coefficients(collision, model).T

    def exact(p: int, s: int) -> float:
        a, b = pairs[p]
        ja, jb = frame_of[a], frame_of[b]
        return shapes.distance(a, b, R[s, ja], t[s, ja], R[s, jb], t[s, jb]).distance_m

    last = np.array([exact(p, 0) for p in range(len(pairs))])
    drift = np.zeros(len(pairs))
    best_p = int(np.argmin(last))
    worst = (float(last[best_p]), 0, best_p)
    for s in range(1, len(rows)):
        drift += drift_per_step[s - 1]
        bounds = last - drift
        best, best_p = math.inf, -1
        for p in np.argsort(bounds):
            if bounds[p] >= best:
                break
            d = exact(int(p), s)
            last[p], drift[p] = d, 0.0
            if d < best:
                best, best_p = d, int(p)
        if best < worst[0]:
            worst = (best, s, best_p)
    value, s_worst, p_worst = worst
    a, b = pairs[p_worst]
    predicted = _predicted(recording)
    return FlownClearance(
        value_m=value,
        t_s=float(times[s_worst]),
        bodies=(collision.bodies[a].name, collision.bodies[b].name),
        limit_m=description.flight_rules.min_clearance_m,
        n_frames=len(rows),
        n_frames_total=total,
        n_pairs=len(pairs),
        n_queries=shapes.queries,
        predicted_m=None if predicted is None else predicted[0],
        predicted_t_s=None if predicted is None else predicted[1],
        predicted_bodies=None if predicted is None else predicted[2],
    )


def _predicted(
    recording: PassRecording,
) -> tuple[float, float | None, tuple[str, str] | None] | None:
    """The plan's predicted clearance row (value, time, bodies); None without a report."""
    if recording.plan.flight_rules is None:
        return None
    row = FlightRulesReport.from_dict(recording.plan.flight_rules).row("clearance")
    return row.value, row.t_s, row.bodies
