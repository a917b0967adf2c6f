"""A scaffold's experiments, planned and checked against the flight rules
(``hikoboshi robot init``, :mod:`planner.description.scaffold`).

The experiments' defaults are PTP A -> B, reactionless from B along the chosen direction,
GJM from A with the chosen hand pitch, coordination's line, and the non-holonomic motion from
an offset of A back to A. The offset is the first of :func:`nonholonomic_candidates`
(ETS-VII's offsets as they are, reversed, with the other sign patterns, then halved and
halved again) whose plan passes the flight rules: each candidate's meeting is first found
coarsely and its paths' clearance sampled (a screen, a fraction of a second), and only those
that keep the clearance are planned and checked in full
(:meth:`RobotDescription.check_plan`; :func:`choose_nonholonomic`).

Every experiment as written (:data:`EXPERIMENTS`) is then planned and checked
(:func:`check_experiments`); the verdicts are in the report and, for an experiment that
fails, on the command line's stderr.
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.catalogue import plan_experiment, resolve
from planner.clearance_sampling import sampled_clearance
from planner.collision import body_poses
from planner.dynamics import DynamicsWorkspace
from planner.errors import PlannerError
from planner.nonholonomic import find_meeting
from planner.parameters import parameters_from_values
from planner.robot import RobotDescription

__all__ = [
    "EXPERIMENTS",
    "NONHOLONOMIC_SCALES",
    "check_experiments",
    "choose_nonholonomic",
    "experiment_row",
    "nonholonomic_candidates",
]

Array = NDArray[np.float64]

#: The non-holonomic motion's start: pose A offset by ETS-VII's (deg), clipped to the limits.
NONHOLONOMIC_OFFSET_DEG = (9.6, -2.0, 2.0, 0.0, -13.6, 0.0, 0.0)
#: The offsets' scales tried, nearest ETS-VII's first.
NONHOLONOMIC_SCALES = (1.0, 0.5, 0.25, 0.125)
#: At most this many candidates whose screened paths keep the clearance are planned in full.
NONHOLONOMIC_FULL_CHECKS = 4
#: The screen: the meeting found with these RK4 steps and this attitude tolerance (rad), every
#: this many of its path samples checked for clearance.
SCREEN_PATH_STEPS = 16
SCREEN_TOLERANCE_RAD = 1e-5
SCREEN_STRIDE = 4
#: The experiments a scaffold writes, each planned as written and checked.
EXPERIMENTS = ("ptp", "reactionless", "gjm", "coordination", "nonholonomic")


def nonholonomic_candidates(n: int) -> list[tuple[str, Array]]:
    """The non-holonomic start offsets from A tried, in order (label, offsets in deg, (n,)):
    at each of :data:`NONHOLONOMIC_SCALES`, ETS-VII's offsets (:data:`NONHOLONOMIC_OFFSET_DEG`,
    cut or padded with zeros to ``n`` joints) as they are, reversed, then every other sign
    pattern of their non-zero entries."""
    base = np.zeros(n)
    given = np.array(NONHOLONOMIC_OFFSET_DEG)[:n]
    base[: given.size] = given
    moved = np.flatnonzero(base)
    joints = ", ".join(str(i + 1) for i in moved)
    patterns: list[tuple[str, Array]] = [
        ("ETS-VII's offsets", np.ones(moved.size)),
        ("reversed", -np.ones(moved.size)),
    ]
    for pattern in itertools.product((1.0, -1.0), repeat=moved.size):
        if len(set(pattern)) == 2:
            mark = "".join("+" if v > 0 else "-" for v in pattern)
            patterns.append((f"signs {mark} on joints {joints}", np.array(pattern)))
    out = []
    for scale in NONHOLONOMIC_SCALES:
        for label, signs in patterns:
            offset = base.copy()
            offset[moved] *= signs * scale
            out.append((f"{label} x{scale:g}", offset))
    return out


def _nonholonomic_params(description: RobotDescription, phi_init: Array, **extra: Any) -> Any:
    values = {"phi_init_deg": [float(v) for v in np.degrees(phi_init)], **extra}
    return parameters_from_values(
        resolve("nonholonomic")[0], values, defaults=description.experiment_defaults("nonholonomic")
    )


def _screened_clearance(
    description: RobotDescription, ws: DynamicsWorkspace, phi_init: Array
) -> float:
    """The least distance over every pair the flight rules check (the arm against the base
    and against itself) along the coarse meeting's paths (m; -inf when the paths do not meet
    inside the limits)."""
    params = _nonholonomic_params(
        description,
        phi_init,
        path_steps=SCREEN_PATH_STEPS,
        attitude_tolerance_rad=SCREEN_TOLERANCE_RAD,
    )
    try:
        meeting = find_meeting(ws, params)
    except PlannerError:
        return -math.inf
    path = np.vstack(
        [meeting.forward_joints_rad[::SCREEN_STRIDE], meeting.backward_joints_rad[::-SCREEN_STRIDE]]
    )
    collision = description.collision
    assert collision is not None  # the scaffold writes generated collision bodies
    rots, trans = body_poses(ws.model, path)
    found = sampled_clearance(
        collision, list(collision.pairs), rots, trans, np.abs(np.diff(path, axis=0)), ws.model
    )
    return found.worst_m


def experiment_row(description: RobotDescription, experiment: str, params: Any) -> dict[str, Any]:
    """``experiment`` planned with ``params`` for ``description`` and checked: the verdict, the
    clearances (m: the arm against the base, the arm against itself), the failing rules, the
    end attitude error (deg; None for an experiment without one)."""
    try:
        plan = plan_experiment(experiment, params, robot=description)
    except PlannerError as exc:
        return {
            "passed": False,
            "clearance_m": None,
            "self_clearance_m": None,
            "failing": [],
            "error": str(exc),
        }
    report = description.check_plan(plan)
    values = {row.rule: row.value for row in report.rows}
    return {
        "passed": report.passed,
        "clearance_m": values.get("clearance"),  # None: no pair of the kind to check
        "self_clearance_m": values.get("self_clearance"),
        "failing": [
            f"{row.rule} {row.value:.4g} {row.unit} (limit {row.limit:.4g})"
            for row in report.failing
        ],
        "end_attitude_error_deg": plan.metrics.get("predicted_end_attitude_error_deg"),
    }


def choose_nonholonomic(
    description: RobotDescription, qa: Array, lo: Array, hi: Array
) -> dict[str, Any]:
    """The first of :func:`nonholonomic_candidates` whose plan passes the flight rules (or,
    when none does, the one that came nearest), and what was tried."""
    ws = DynamicsWorkspace(description.model)
    min_clearance = description.flight_rules.min_clearance_m
    tried: list[dict[str, Any]] = []
    seen: list[Array] = []
    chosen: dict[str, Any] | None = None
    full = 0
    for label, offset in nonholonomic_candidates(description.model.n_joints):
        phi_init = np.clip(qa + np.radians(offset), lo, hi)
        if any(np.allclose(phi_init, other) for other in seen):
            continue  # the limits made it another candidate's start
        seen.append(phi_init)
        screened = _screened_clearance(description, ws, phi_init)
        entry: dict[str, Any] = {
            "candidate": label,
            "offset_deg": [float(v) for v in offset],
            "phi_init_deg": [round(float(v), 3) for v in np.degrees(phi_init)],
            # None: the paths met only beyond the joint limits, or did not meet
            "screened_clearance_m": screened if math.isfinite(screened) else None,
        }
        tried.append(entry)
        if screened < min_clearance:
            continue
        full += 1
        # the start as it will be written (3 decimals of a degree)
        params = parameters_from_values(
            resolve("nonholonomic")[0],
            {"phi_init_deg": entry["phi_init_deg"]},
            defaults=description.experiment_defaults("nonholonomic"),
        )
        entry.update(experiment_row(description, "nonholonomic", params))
        if entry["passed"]:
            chosen = entry
            break
        if full >= NONHOLONOMIC_FULL_CHECKS:
            break
    screens = [e["screened_clearance_m"] for e in tried if e["screened_clearance_m"] is not None]
    if chosen is None:  # none passes: the nearest (as checked in full where it was)
        nearest: dict[str, Any] = max(tried, key=_nearness)
        chosen = {
            "passed": False,
            "clearance_m": None,
            "self_clearance_m": None,
            "failing": [],
            "end_attitude_error_deg": None,
            **nearest,
        }
    return {
        **chosen,
        "candidates_tried": len(tried),
        "fully_checked": full,
        "best_screened_clearance_m": max(screens) if screens else None,
        "tried": tried,
    }


def _nearness(entry: dict[str, Any]) -> tuple[bool, float]:
    """Checked in full before screened only, then by clearance."""
    flown, screened = entry.get("clearance_m"), entry["screened_clearance_m"]
    if flown is not None:
        return True, flown
    return False, screened if screened is not None else -math.inf


def check_experiments(description: RobotDescription) -> dict[str, dict[str, Any]]:
    """Each of :data:`EXPERIMENTS` planned with ``description``'s defaults (as written) and
    checked: :func:`experiment_row`'s verdict, by experiment."""
    return {
        experiment: experiment_row(
            description,
            experiment,
            parameters_from_values(
                resolve(experiment)[0], {}, defaults=description.experiment_defaults(experiment)
            ),
        )
        for experiment in EXPERIMENTS
    }
