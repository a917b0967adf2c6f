"""The clearance of a moving arm, sampled so that nothing between the samples is missed.

* **A fine grid.** The step ``h`` divides the 0.25 s command period so that no point of the
  arm moves more than half the minimum clearance between two samples at the joints' rate
  limits: ``h * sum_k rate_k * rho_k <= min_clearance / 2``, ``rho_k`` a bound on the
  distance from joint k to any point of the bodies it moves (:func:`planner.collision.
  reach_bounds`). Any instant is within ``h / 2`` of a sample, so the clearance flown is at
  least the smallest sampled clearance less ``min_clearance / 4``: a plan that passes never
  brings two bodies closer than three quarters of the minimum clearance, and never into
  contact. (The commands are checked against the rate limits first; a servo overshoots its
  command's rate by no more than its damping allows, counted in the per-step bounds below:
  :func:`joint_paths`.)
* **Every sample's exact minimum, cheaply.** A pair's distance can shrink between two samples
  by no more than the path its bodies travel relative to each other (``sum_k |dq_k| rho_k``
  over the joints between them). Each pair keeps its last exact distance less the path since
  (a lower bound); at each sample coal is asked only for pairs whose bound is below the best
  exact distance found so far, nearest bound first. While the arm holds still nothing is
  asked at all.

:func:`planner.flight_check.check_plan` samples a plan's servo response this way; the
scaffold (:mod:`planner.description.scaffold`) and the ground's clearance service sample
other joint paths.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from planner.collision import CollisionModel, PairDistance, ShapeSet, reach_bounds
from planner.errors import InvalidInput
from planner.model import RobotModel
from planner.plan import Plan
from planner.ptp import COMMAND_PERIOD_S
from planner.servo_response import ServoModel

__all__ = [
    "MAX_SAMPLES_PER_PERIOD",
    "SampledClearance",
    "joint_paths",
    "pair_motion_coefficients",
    "sample_step_s",
    "sampled_clearance",
]

Array = NDArray[np.float64]

#: The most samples per command period (a robot so fast or so large that more would be
#: needed is refused: its rates or its clearance should be looked at).
MAX_SAMPLES_PER_PERIOD = 64


def sample_step_s(model: RobotModel, collision: CollisionModel, min_clearance_m: float) -> float:
    """The fine grid's step: the 0.25 s command period divided so that, at the joints' rate
    limits, no point of the arm moves more than ``min_clearance_m / 2`` in one step."""
    rho = reach_bounds(model, collision)
    reach = rho.max(axis=1) if rho.size else np.zeros(model.n_joints)
    speed = float(np.sum(model.joint_rate_limit_radps * reach))
    per_period = max(1, math.ceil(speed * COMMAND_PERIOD_S / (0.5 * min_clearance_m) - 1e-12))
    if per_period > MAX_SAMPLES_PER_PERIOD:
        raise InvalidInput(
            f"the arm's points may move {speed:.3g} m/s at the joints' rate limits: checking "
            f"{min_clearance_m} m of clearance would need {per_period} samples per command "
            f"period (at most {MAX_SAMPLES_PER_PERIOD})"
        )
    return COMMAND_PERIOD_S / per_period


def pair_motion_coefficients(
    collision: CollisionModel, model: RobotModel, pairs: Sequence[tuple[int, int]]
) -> Array:
    """``C[p, k]``: how far one body of pair p can move relative to the other per radian of
    joint k (``rho[k, b]``, the reach of joint k to the body b that the joints between them
    move; 0 for the joints that move both or neither). The live clearance
    (:class:`planner.clearance_watch.ClearanceWatch`) bounds its pairs with it too."""
    rho = reach_bounds(model, collision)
    coefficients = np.zeros((len(pairs), model.n_joints))
    for p, (a, b) in enumerate(pairs):
        ja, jb = collision.bodies[a].joint, collision.bodies[b].joint
        lo, hi, moving = (ja, jb, b) if ja < jb else (jb, ja, a)
        coefficients[p, lo:hi] = rho[lo:hi, moving]
    return coefficients


@dataclass(frozen=True)
class SampledClearance:
    """The exact least distance over ``pairs`` at every sample, and the worst of them."""

    per_sample_m: Array
    worst_m: float
    worst_sample: int
    worst_pair: tuple[int, int]
    nearest: PairDistance
    queries: int


def sampled_clearance(
    collision: CollisionModel,
    pairs: Sequence[tuple[int, int]],
    R: Array,
    t: Array,
    path_rad: Array,
    model: RobotModel,
) -> SampledClearance:
    """The least distance over ``pairs`` at each sample of the body frames ``(R, t)``
    (:func:`planner.collision.body_poses`), exact at every sample, asking coal only for the
    pairs whose lower bound (last exact distance less the relative path since,
    ``path_rad[s]`` being each joint's path from sample s to s + 1) is below the best found
    at that sample (the module docstring)."""
    shapes = ShapeSet(collision)
    frame_of = [body.joint for body in collision.bodies]
    drift_per_step = path_rad @ pair_motion_coefficients(collision, model, pairs).T

    def exact(p: int, s: int) -> PairDistance:
        a, b = pairs[p]
        ja, jb = frame_of[a], frame_of[b]
        return shapes.distance(a, b, R[s, ja], t[s, ja], R[s, jb], t[s, jb], frames_key=s)

    last = [exact(p, 0) for p in range(len(pairs))]
    last_d = np.array([d.distance_m for d in last])
    drift = np.zeros(len(pairs))
    best_p = int(np.argmin(last_d))
    per_sample = np.empty(R.shape[0])
    per_sample[0] = last_d[best_p]
    worst = (float(last_d[best_p]), 0, best_p, last[best_p])
    for s in range(1, R.shape[0]):
        step_drift = drift_per_step[s - 1]
        if not step_drift.any():
            per_sample[s] = per_sample[s - 1]
            continue
        drift += step_drift
        bounds = last_d - drift
        best = math.inf
        for p in np.argsort(bounds):
            if bounds[p] >= best:
                break
            found = exact(int(p), s)
            last[p] = found
            last_d[p] = found.distance_m
            drift[p] = 0.0
            if found.distance_m < best:
                best, best_p = found.distance_m, int(p)
        per_sample[s] = best
        if best < worst[0]:
            worst = (best, s, best_p, last[best_p])
    value, s_worst, p_worst, nearest = worst
    return SampledClearance(per_sample, value, s_worst, pairs[p_worst], nearest, shapes.queries)


def joint_paths(servo: ServoModel, plan: Plan, step: float, joints: Array, rates: Array) -> Array:
    """Each joint's path in each step, bounded: the larger of its rates at the two ends and
    its commanded rate, with the servo's overshoot allowed for, times the step (and never
    less than the change between the samples)."""
    commanded = np.abs(np.diff(plan.command_joints_rad, axis=0)) / COMMAND_PERIOD_S
    per_period = max(1, round(COMMAND_PERIOD_S / step))
    commanded_per_step = np.repeat(commanded, per_period, axis=0)
    ends = np.maximum(np.abs(rates[:-1]), np.abs(rates[1:]))
    path = np.maximum(ends, commanded_per_step[: ends.shape[0]]) * (1.0 + servo.rate_overshoot)
    out: Array = np.maximum(path * step, np.abs(np.diff(joints, axis=0)))
    return out
