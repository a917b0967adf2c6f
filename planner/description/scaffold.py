"""A description scaffold for a vendor's arm: ``hikoboshi robot init`` (docs/robots.md,
"Starting from a vendor's URDF").

From a URDF (read unchanged), the hand frame's link and a cube the arm is mounted on, this
module chooses what a description needs and a URDF cannot say, and writes it as TOML text:

- **the base**: a uniform cube of ``base_mass_kg`` and ``base_size_m``, the URDF's root on
  the centre of its +z face;
- **mission limits** inside the vendor's: each joint's range shrunk by
  :data:`LIMIT_MARGIN_DEG` and cut to +-:data:`MAX_MISSION_DEG` (no wrap-around), where that
  leaves a range; every joint at :data:`MISSION_RATE_DEGPS` or the vendor's rate if slower
  (a space arm's rates, not a factory arm's);
- **named poses** A (the reference pose), B and C, away from singularities: ``POSE_SAMPLES``
  poses drawn inside the mission limits (a fixed seed) are ranked by the smallest singular
  value of the generalised Jacobian ``J_g`` (eq. 8; its angular rows scaled by the arm's
  reach so that metres and radians weigh alike), among those whose generated collision
  bodies keep :data:`POSE_CLEARANCE_M` apart (pairs that touch in nearly every sample are
  the design's and do not count). A is the best one whose hand can also hold the GJM
  approach's orientation (pitch about robot y) at the same point and move
  ``COORDINATION_DISTANCE_M`` along robot +x and back (coordination's line) with ``J_m``
  well conditioned; B the best one at a moderate joint distance from A from which a
  reactionless line runs with the least lateral wander (over the six axis directions); C
  the end of that line;
- **servos** that the integrator holds: the fastest servo mode (:mod:`planner.servo_check`)
  is linear in ``lag * bandwidth^2``, so it is computed once at unit gains over the poses
  and the seeded samples and the bandwidth and lag chosen so that it stays under
  :data:`SERVO_MARGIN` of the bound, keeping the damping ratio at the reference at least
  :data:`SERVO_DAMPING` while the lag stays under :data:`MAX_SERVO_LAG_S`;
- **wheels** sized from the arm's reaction momentum: the bound
  ``max |H~_bm| |phi'_max|`` (operator norm over the sampled poses, every joint at its
  mission rate), times :data:`WHEEL_MARGIN`; the torque limit fills that capacity in
  :data:`WHEEL_FILL_S` (the shipped robots' ratio), the rotors spin at
  :data:`WHEEL_SPEED_RADPS` at capacity;
- the memoryless PD **attitude law** of the shipped small robot (Orihime's);
- the **experiments' defaults**: PTP A -> B, reactionless from B along the chosen direction,
  GJM from A with the chosen hand pitch, coordination's line length, the non-holonomic
  motion from an offset of A back to A. The offset is the first of
  :func:`nonholonomic_candidates` (ETS-VII's offsets as they are, reversed, with the other
  sign patterns, then halved and halved again) whose plan passes the flight rules: each
  candidate's meeting is first found coarsely and its paths' clearance sampled (a screen,
  a fraction of a second), and only those that keep the clearance are planned and checked
  in full (:meth:`RobotDescription.check_plan`);
- **every experiment as written** is then planned and checked against the flight rules; the
  verdicts are in the report (``experiments``) and, for an experiment that fails, on the
  command line's stderr.

Everything is computed on the model the description will load to; the text is then built
by :func:`planner.description.build.build_robot` from its own parse, so a scaffold that does
not load is never returned. Our choices, not a vendor's; each is written as a comment beside
its key.
"""

from __future__ import annotations

import itertools
import math
import tomllib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.catalogue import plan_experiment, resolve
from planner.clearance_sampling import sampled_clearance
from planner.collision import CollisionModel, ShapeSet, body_poses
from planner.collision_segments import segment_collision_model
from planner.description.build import build_robot, model_from_urdf
from planner.description.checks import NAME, Checker
from planner.description.files import read_limited
from planner.description.reduce import Mount
from planner.description.tables import head_from
from planner.description.urdf_xml import Urdf
from planner.dynamics import DynamicsWorkspace
from planner.errors import PlannerError
from planner.frames import matrix_from_rpy
from planner.ik import solve_ik
from planner.model import RobotModel, WheelSpec
from planner.nonholonomic import find_meeting
from planner.parameters import MIN_SPEED_MPS, parameters_from_values
from planner.ptp import ptp_commands
from planner.reactionless import reactionless_line
from planner.robot import RobotDescription
from planner.servo_check import servo_modes
from planner.simulation import default_servo_gains
from planner.state import State

__all__ = [
    "DEFAULT_BASE_MASS_KG",
    "DEFAULT_BASE_SIZE_M",
    "EXPERIMENTS",
    "Scaffold",
    "nonholonomic_candidates",
    "scaffold_description",
]

Array = NDArray[np.float64]

#: The cube the arm sits on where the user gives none: 300 kg, 1 m a side, our choice (the
#: mount the vendor arms' tests use, tests/planner/vendor/*.toml).
DEFAULT_BASE_MASS_KG = 300.0
DEFAULT_BASE_SIZE_M = 1.0
#: Mission limits: the vendor's range less this on each side, inside +-MAX_MISSION_DEG.
LIMIT_MARGIN_DEG = 5.0
MAX_MISSION_DEG = 175.0
#: The planners' joint rate (ETS-VII's limit, SPEC 7), or the vendor's if slower.
MISSION_RATE_DEGPS = 3.0
#: Poses: samples drawn inside the limits (fixed seed), the clearance they must keep, how far
#: inside the limits they stay.
POSE_SAMPLES = 400
POSE_SEED = 28
POSE_CLEARANCE_M = 0.08
POSE_LIMIT_MARGIN_DEG = 30.0
#: Along the experiments' lines: the flight rules' clearance and a margin for the free base.
PATH_CLEARANCE_M = 0.06
#: Generated collision geometry (the shipped vendor tests' sizes) and the flight rules'
#: clearance for it.
CAPSULE_RADIUS_M = 0.06
HAND_RADIUS_M = 0.08
MIN_CLEARANCE_M = 0.05
#: Experiments' lengths: coordination's line, GJM's approach, the reactionless line.
COORDINATION_DISTANCE_M = 0.15
GJM_DISTANCE_M = 0.15
REACTIONLESS_DISTANCES_M = (0.15, 0.1, 0.05)
#: The reactionless line's wander a scaffold accepts: off the line at most this fraction of
#: its length, the hand turning at most this much.
MAX_LATERAL_FRACTION = 0.25
MAX_TURN_DEG = 25.0
#: The reactionless outbound speed (ETS-VII's), lowered until the joints keep within 0.9 of
#: their mission rate; the return at half of it.
REACTIONLESS_SPEED_MPS = 0.015
#: B: this far (largest joint difference) from A, at least and at most.
B_MIN_DEG, B_MAX_DEG = 20.0, 50.0
#: Servos: the bound's fraction the fastest mode may reach, the damping ratio kept at the
#: reference, the largest lag (tracking error = lag x rate: 1.5 deg at 3 deg/s, under the
#: default live limits' 2.25 deg watch band) and bandwidth.
SERVO_MARGIN = 0.8
SERVO_DAMPING = 0.6
MAX_SERVO_LAG_S = 0.5
MAX_SERVO_BANDWIDTH_RADPS = 4.0
#: Wheels: capacity over the reaction-momentum bound, seconds to fill it at the torque limit
#: (ETS-VII 20 N m s / 0.3 N m = 67 s, Orihime 12 / 0.2 = 60 s), rotor speed at capacity
#: (Orihime's, 2292 rpm) and radius (thin disc).
WHEEL_MARGIN = 2.5
WHEEL_FILL_S = 60.0
WHEEL_SPEED_RADPS = 240.0
WHEEL_RADIUS_M = 0.15
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
#: GJM hand pitches tried (deg), the hand parallel to the robot frame first.
GJM_PITCHES_DEG = (0.0, -23.0, 23.0, -45.0, 45.0, -67.0, 67.0, -90.0, 90.0)
_DIRECTIONS = {
    "+x": (1.0, 0.0, 0.0),
    "-x": (-1.0, 0.0, 0.0),
    "+y": (0.0, 1.0, 0.0),
    "-y": (0.0, -1.0, 0.0),
    "+z": (0.0, 0.0, 1.0),
    "-z": (0.0, 0.0, -1.0),
}


@dataclass(frozen=True)
class Scaffold:
    """The description's text and what was chosen (``report``: JSON-able)."""

    toml: str
    report: dict[str, Any]
    description: RobotDescription


def _root_link(urdf: Urdf) -> str:
    roots = [name for name in urdf.links if name not in urdf.parent_joint]
    if len(roots) != 1:
        raise urdf.c.fail("document", f"a URDF is one tree with one root link, found {roots}")
    return roots[0]


def _mission_limits(vendor: Array, vendor_rate: Array) -> tuple[Array, Array]:
    out = np.empty_like(vendor)
    margin = math.radians(LIMIT_MARGIN_DEG)
    cap = math.radians(MAX_MISSION_DEG)
    for i, (lo, hi) in enumerate(vendor):
        a, b = lo + margin, hi - margin
        if b - a < 2 * margin:  # a narrow joint: keep its middle half
            mid, half = 0.5 * (lo + hi), 0.25 * (hi - lo)
            a, b = mid - half, mid + half
        ca, cb = max(a, -cap), min(b, cap)
        out[i] = (ca, cb) if cb - ca >= 2 * margin else (a, b)
    rate = np.minimum(vendor_rate, math.radians(MISSION_RATE_DEGPS))
    return out, rate


def _scaled_sigma(J: Array, reach_m: float) -> float:
    scaled = J.copy()
    scaled[3:] *= reach_m
    return float(np.linalg.svd(scaled, compute_uv=False)[-1])


class _Clearance:
    """Distances between the generated collision bodies that are not joined by a joint."""

    def __init__(self, model: RobotModel, base_name: str, size_m: float, pos_j1_m: Array) -> None:
        collision = segment_collision_model(
            model,
            base_name=base_name,
            radius_m=CAPSULE_RADIUS_M,
            hand_radius_m=HAND_RADIUS_M,
            clearance_m=-math.inf,  # every pair but a joint's two bodies
            base_box_size_m=(size_m, size_m, size_m),
            base_box_centre_robot_m=-pos_j1_m,
        )
        self.collision: CollisionModel = collision
        self.shapes = ShapeSet(collision)
        self.model = model
        self.pairs = list(collision.pairs)
        self.ignored: set[tuple[int, int]] = set()

    def distances(self, q: Array) -> Array:
        rots, trans = body_poses(self.model, q)
        bodies = self.collision.bodies
        out = np.empty(len(self.pairs))
        for k, (i, j) in enumerate(self.pairs):
            a, b = bodies[i].joint, bodies[j].joint
            d = self.shapes.distance(i, j, rots[0, a], trans[0, a], rots[0, b], trans[0, b])
            out[k] = d.distance_m
        return out

    def joined_at(self, q: Array) -> set[tuple[int, int]]:
        """The pairs the flight rules join at reference pose ``q`` (nearer than their
        clearance: the design's, planner.collision_segments)."""
        d = self.distances(q)
        return {p for k, p in enumerate(self.pairs) if d[k] < MIN_CLEARANCE_M}

    def clear(self, q: Array, exempt: set[tuple[int, int]] | None = None) -> float:
        """The least distance over the pairs not ``exempt`` (default: those that touch in
        nearly every sampled pose)."""
        skip = self.ignored if exempt is None else exempt
        d = self.distances(q)
        keep = [k for k, p in enumerate(self.pairs) if p not in skip]
        return float(np.min(d[keep])) if keep else math.inf


def _line_ok(
    ws: DynamicsWorkspace,
    q: Array,
    direction: Array,
    distance_m: float,
    reach_m: float,
    clearance: _Clearance,
    exempt: set[tuple[int, int]],
) -> tuple[bool, float, Array]:
    """Fixed-base resolved rates along a robot-frame line, orientation held: ok (inside the
    limits, the bodies :data:`PATH_CLEARANCE_M` apart), the worst scaled sigma of J_m on
    the way, the end joints."""
    steps = 30
    q = q.copy()
    hand0 = ws.hand_pose(State(joints_rad=q))
    worst = math.inf
    lo, hi = ws.model.joint_limit_rad[:, 0], ws.model.joint_limit_rad[:, 1]
    for k in range(1, steps + 1):
        target = hand0.pos_robot_m + direction * distance_m * k / steps
        for _ in range(6):
            hand, _, J_m = ws.hand_jacobian(State(joints_rad=q))
            e_pos = target - hand.pos_robot_m
            rot_err = hand0.rot_robot_from_hand @ hand.rot_robot_from_hand.T
            e_rot = 0.5 * np.array(
                [rot_err[2, 1] - rot_err[1, 2], rot_err[0, 2] - rot_err[2, 0],
                 rot_err[1, 0] - rot_err[0, 1]]
            )  # fmt: skip
            e = np.concatenate([e_pos, e_rot])
            q = q + J_m.T @ np.linalg.solve(J_m @ J_m.T + 1e-8 * np.eye(6), e)
            if np.max(np.abs(e)) < 1e-9:
                break
        worst = min(worst, _scaled_sigma(J_m, reach_m))
        if np.max(np.abs(e)) > 1e-4 or np.any(q < lo) or np.any(q > hi):
            return False, worst, q
        if k % 5 == 0 and clearance.clear(q, exempt) < PATH_CLEARANCE_M:
            return False, worst, q
    return True, worst, q


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


def _experiment_row(description: RobotDescription, experiment: str, params: Any) -> dict[str, Any]:
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


def _choose_nonholonomic(
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
        entry.update(_experiment_row(description, "nonholonomic", params))
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


def scaffold_description(
    urdf_path: Path,
    hand: str,
    *,
    out_path: Path,
    urdf_name: str,
    name: str | None = None,
    base_mass_kg: float = DEFAULT_BASE_MASS_KG,
    base_size_m: float = DEFAULT_BASE_SIZE_M,
) -> Scaffold:
    """The description of the arm in ``urdf_path`` on a cube (see the module doc), as the
    text of ``out_path`` naming the URDF ``urdf_name`` beside it. Raises
    :class:`InvalidRobotDescription` naming the file and the element when the URDF cannot
    be loaded or no pose fits."""
    c = Checker(out_path)
    if not (math.isfinite(base_mass_kg) and base_mass_kg > 0):
        raise c.fail("--base-mass", f"must be a positive mass in kg, got {base_mass_kg}")
    if not (math.isfinite(base_size_m) and base_size_m > 0):
        raise c.fail("--base-size", f"must be a positive length in m, got {base_size_m}")
    robot_name = name if name is not None else out_path.stem
    if not NAME.match(robot_name):
        raise c.fail("name", f"{robot_name!r}: letters, digits, '_', '-' or '.' (up to 64)")
    urdf = Urdf(urdf_path, read_limited(urdf_path, "URDF"))
    root = _root_link(urdf)
    urdf.check_tree(root)
    if hand not in urdf.links:
        raise urdf.c.fail(f"link {hand!r}", f"--hand names no link of the URDF ({root!r} ...)")
    mount = Mount(
        mass_kg=base_mass_kg,
        size_m=(base_size_m,) * 3,
        rot_base_from_root=None,
        pos_base_from_root_m=np.array([0.0, 0.0, 0.5 * base_size_m]),
    )
    placeholder = tuple(
        WheelSpec(name=f"wheel_{a}", axis_base=np.eye(3)[k], spin_inertia_kgm2=0.01, mass_kg=1e-3)
        for k, a in enumerate("xyz")
    )
    model, red = model_from_urdf(urdf, root, placeholder, hand=hand, mount=mount)
    limits, rates = _mission_limits(red.vendor_limit_rad, red.vendor_rate_radps)
    n = model.n_joints
    model = replace(model, joint_limit_rad=limits, joint_rate_limit_radps=rates)
    ws = DynamicsWorkspace(model)

    # --- sampled poses --------------------------------------------------------------------
    rng = np.random.default_rng(POSE_SEED)
    pm = math.radians(POSE_LIMIT_MARGIN_DEG)
    lo = limits[:, 0] + np.minimum(pm, 0.25 * (limits[:, 1] - limits[:, 0]))
    hi = limits[:, 1] - np.minimum(pm, 0.25 * (limits[:, 1] - limits[:, 0]))
    samples = rng.uniform(lo, hi, size=(POSE_SAMPLES, n))
    reach_m = 0.0
    quantities = []
    for q in samples:
        quant = ws.evaluate(State(joints_rad=q))
        reach_m = max(reach_m, float(np.linalg.norm(quant.hand.pos_orbit_m)))
        quantities.append(quant)
    hands_robot = np.array([ws.hand_pose(State(joints_rad=q)).pos_robot_m for q in samples])
    reach_m = float(np.max(np.linalg.norm(hands_robot, axis=1)))
    sigma = np.array([_scaled_sigma(quant.J_g, reach_m) for quant in quantities])
    clearance = _Clearance(model, root, base_size_m, red.pos_j1_m)
    dist = np.array([clearance.distances(q) for q in samples])
    touching = np.mean(dist < POSE_CLEARANCE_M, axis=0)
    clearance.ignored = {p for k, p in enumerate(clearance.pairs) if touching[k] > 0.9}
    keep = [k for k, p in enumerate(clearance.pairs) if p not in clearance.ignored]
    clear = np.min(dist[:, keep], axis=1) if keep else np.full(len(samples), np.inf)
    # reaction momentum bound: |H~_bm|_2 |phi'_max| over the samples
    coupling = max(float(np.linalg.norm(quant.H_bm_tilde, 2)) for quant in quantities)
    reaction_bound_nms = coupling * float(np.linalg.norm(rates))

    order = [int(k) for k in np.argsort(-sigma) if clear[k] >= POSE_CLEARANCE_M]
    if not order:
        raise c.fail("[poses]", f"none of {POSE_SAMPLES} sampled poses keeps its links "
                     f"{POSE_CLEARANCE_M} m apart")  # fmt: skip

    # --- A: the reference pose ------------------------------------------------------------
    chosen_a: tuple[Array, float, float] | None = None  # joints, pitch, sigma
    # pitch 0 first (the hand parallel to the robot frame at A: GJM's start whether its
    # pitch turns the robot frame or pose A's own hand), then the others
    for pitch, k in [(p, k) for p in GJM_PITCHES_DEG for k in order[:25]]:
        pos = hands_robot[k]
        rot = matrix_from_rpy(np.radians([0.0, pitch, 0.0]))
        try:
            q = solve_ik(ws, pos, rot, reference_joints_rad=samples[k], n_starts=2)[0]
        except PlannerError:
            continue
        qa = q.joints_rad
        if np.any(qa < lo) or np.any(qa > hi) or clearance.clear(qa) < POSE_CLEARANCE_M:
            continue
        s = _scaled_sigma(ws.evaluate(State(joints_rad=qa)).J_g, reach_m)
        if s < 0.5 * sigma[k]:
            continue
        axis = rot[:, 0]
        x = np.array([1.0, 0.0, 0.0])
        joined = clearance.joined_at(qa)
        ok_c, _, mid = _line_ok(ws, qa, x, COORDINATION_DISTANCE_M, reach_m, clearance, joined)
        if not ok_c:
            continue
        ok_back, _, _ = _line_ok(ws, mid, -x, COORDINATION_DISTANCE_M, reach_m, clearance, joined)
        ok_g, _, _ = _line_ok(ws, qa, axis, GJM_DISTANCE_M, reach_m, clearance, joined)
        if ok_back and ok_g:
            chosen_a = (qa, pitch, s)
            break
    if chosen_a is None:
        raise c.fail("[poses.A]", "no sampled pose lets the hand move along robot +x")
    qa, pitch, _sigma_a = chosen_a

    # --- B and the reactionless direction ---------------------------------------------------
    best_b: tuple[float, Array, str, float, Any, float] | None = None
    tried = 0
    joined = clearance.joined_at(qa)
    near = qa + rng.uniform(-1.0, 1.0, size=(POSE_SAMPLES, n)) * math.radians(B_MAX_DEG)
    near = near[np.all((near >= lo) & (near <= hi), axis=1)]
    gaps = np.degrees(np.max(np.abs(near - qa), axis=1))
    near = near[gaps >= B_MIN_DEG]
    near_sigma = np.array(
        [_scaled_sigma(ws.evaluate(State(joints_rad=q)).J_g, reach_m) for q in near]
    )
    for k in np.argsort(-near_sigma):
        qb = near[k]
        path_clear = min(clearance.clear(qa + s * (qb - qa), joined) for s in np.linspace(0, 1, 9))
        if path_clear < PATH_CLEARANCE_M or clearance.clear(qb) < POSE_CLEARANCE_M:
            continue
        tried += 1
        for label, direction in _DIRECTIONS.items():
            for distance in REACTIONLESS_DISTANCES_M:
                try:
                    path = reactionless_line(
                        ws, qb, direction_robot=np.array(direction), distance_m=distance,
                        speed_mps=0.015, dt_s=0.2,
                    )  # fmt: skip
                except PlannerError:
                    continue
                rows = path.joints_rad[:: max(1, len(path.joints_rad) // 10)]
                if min(clearance.clear(q, joined) for q in rows) < PATH_CLEARANCE_M:
                    continue
                peak = np.max(np.abs(np.diff(path.joints_rad, axis=0)) / np.diff(path.t_s)[:, None]
                              / rates)  # fmt: skip
                speed = min(REACTIONLESS_SPEED_MPS, 0.9 * REACTIONLESS_SPEED_MPS / peak)
                if speed < 2 * MIN_SPEED_MPS:
                    continue
                moved = path.hand_pos_robot_m - path.hand_pos_robot_m[0]
                travel = float(moved[-1] @ np.array(direction))
                lateral = moved - np.outer(moved @ np.array(direction), direction)
                wander = float(np.max(np.linalg.norm(lateral, axis=1)))
                turned = math.degrees(float(np.max(path.hand_orientation_change_rad)))
                if wander > MAX_LATERAL_FRACTION * distance or turned > MAX_TURN_DEG:
                    continue
                score = travel - 2.0 * wander
                if best_b is None or score > best_b[0]:
                    best_b = (score, qb, label, distance, path, speed)
                break  # the longest distance that holds
        if tried >= 20 or (best_b is not None and tried >= 6):
            break
    if best_b is None:
        raise c.fail("[poses.B]", "no sampled pose starts a reactionless line")
    _, qb, direction_label, distance, rpath, speed = best_b
    qc = rpath.joints_rad[-1]
    model = replace(model, reference_joints_rad=qa)
    ws = DynamicsWorkspace(model)
    poses = {"A": qa, "B": qb, "C": qc}

    # --- servos ------------------------------------------------------------------------------
    unit = default_servo_gains(model, bandwidth_radps=1.0, lag_s=1.0)
    unit_modes = servo_modes(ws, unit, poses=poses)
    allowed = SERVO_MARGIN * unit_modes.limit_per_s / unit_modes.fastest_per_s  # lag wn^2
    bandwidth = min(MAX_SERVO_BANDWIDTH_RADPS, allowed / (2.0 * SERVO_DAMPING))
    lag = 2.0 * SERVO_DAMPING / bandwidth
    if lag > MAX_SERVO_LAG_S:
        lag = MAX_SERVO_LAG_S
        bandwidth = math.sqrt(allowed / lag)
    bandwidth, lag = _round_down(bandwidth), _round_down(lag)
    modes = servo_modes(ws, default_servo_gains(model, bandwidth_radps=bandwidth, lag_s=lag),
                        poses=poses)  # fmt: skip

    # --- wheels ------------------------------------------------------------------------------
    times, joints = ptp_commands(model, qa, qb, rate_fraction=0.9)
    rates_ptp = np.gradient(joints, times, axis=0)
    momentum = np.array(
        [ws.evaluate(State(joints_rad=q)).H_bm_tilde @ r for q, r in zip(joints, rates_ptp,
                                                                          strict=True)]
    )  # fmt: skip
    ptp_peak_nms = float(np.max(np.linalg.norm(momentum, axis=1)))
    ptp_torque_nm = float(np.max(np.linalg.norm(np.gradient(momentum, times, axis=0), axis=1)))
    capacity = _round_up(WHEEL_MARGIN * reaction_bound_nms)
    torque = _round_up(max(capacity / WHEEL_FILL_S, WHEEL_MARGIN * ptp_torque_nm))
    spin = _round_up(capacity / WHEEL_SPEED_RADPS)
    rotor = _round_up(2.0 * spin / WHEEL_RADIUS_M**2)

    # --- experiments ---------------------------------------------------------------------------
    phi_init = np.clip(qa + np.radians(nonholonomic_candidates(n)[0][1]), lo, hi)
    choice = {
        "reach_m": reach_m,
        "pose_samples": POSE_SAMPLES,
        "sigma_min_Jg": {
            k: _scaled_sigma(ws.evaluate(State(joints_rad=q)).J_g, reach_m)
            for k, q in poses.items()
        },
        "clearance_m": {k: clearance.clear(q, joined) for k, q in poses.items()},
        "gjm_hand_pitch_deg": pitch,
        "reactionless_direction": direction_label,
        "reactionless_distance_m": distance,
        "reactionless_speed_mps": speed,
        "reaction_momentum_bound_nms": reaction_bound_nms,
        "ptp_reaction_momentum_peak_nms": ptp_peak_nms,
        "ptp_reaction_torque_peak_nm": ptp_torque_nm,
        "servo_unit_fastest_per_s": unit_modes.fastest_per_s,
        "servo_fastest_per_s": modes.fastest_per_s,
        "servo_limit_per_s": modes.limit_per_s,
    }
    written = dict(
        name=robot_name,
        urdf_name=urdf_name,
        root=root,
        hand=hand,
        base_mass_kg=base_mass_kg,
        base_size_m=base_size_m,
        joint_names=red.joint_names,
        vendor=red.vendor_limit_rad,
        vendor_rate=red.vendor_rate_radps,
        limits=limits,
        rates=rates,
        poses=poses,
        bandwidth=bandwidth,
        lag=lag,
        capacity=capacity,
        torque=torque,
        spin=spin,
        rotor=rotor,
        choice=choice,
    )
    # a first description (ETS-VII's offsets) to plan the non-holonomic candidates on; the
    # model and the flight rules are the final description's
    doc = tomllib.loads(_render(**written, phi_init=phi_init))
    head = head_from(c, doc, lambda _name: urdf_path)
    description = build_robot(c, doc, head, urdf, {})
    nonholonomic = _choose_nonholonomic(description, qa, lo, hi)
    phi_init = np.radians(nonholonomic["phi_init_deg"])
    doc = tomllib.loads(_render(**written, phi_init=phi_init, nonholonomic=nonholonomic))
    head = head_from(c, doc, lambda _name: urdf_path)
    description = build_robot(c, doc, head, urdf, {})
    checked = {
        experiment: _experiment_row(
            description,
            experiment,
            parameters_from_values(
                resolve(experiment)[0], {}, defaults=description.experiment_defaults(experiment)
            ),
        )
        for experiment in EXPERIMENTS
    }
    # the verdicts go into comments only: the values, and so the description, are unchanged
    text = _render(**written, phi_init=phi_init, nonholonomic=nonholonomic, checked=checked)
    if tomllib.loads(text) != doc:
        raise c.fail("document", "the scaffold's text changed between its check and its writing")
    report = {
        "robot": robot_name,
        "file": str(out_path),
        "urdf": urdf_name,
        "base_link": root,
        "hand": hand,
        "n_joints": n,
        "poses_deg": {k: np.degrees(q).tolist() for k, q in poses.items()},
        "servo": {"bandwidth_radps": bandwidth, "lag_s": lag},
        "wheels": {
            "momentum_limit_nms": capacity,
            "torque_limit_nm": torque,
            "spin_inertia_kgm2": spin,
            "rotor_mass_kg": rotor,
        },
        **choice,
        "nonholonomic": {k: v for k, v in nonholonomic.items() if k != "tried"},
        "nonholonomic_tried": nonholonomic["tried"],
        "experiments": checked,
        "failing_experiments": [e for e, row in checked.items() if not row["passed"]],
    }
    return Scaffold(toml=text, report=report, description=description)


def _round_down(value: float) -> float:
    """Down to 3 significant digits (a gain rounded down keeps its mode under the bound)."""
    scale = 10.0 ** (math.floor(math.log10(value)) - 2)
    return float(f"{math.floor(value / scale + 1e-9) * scale:.3g}")


def _round_up(value: float) -> float:
    """Up to 2 significant digits (a limit rounded up stays a bound)."""
    if value <= 0:
        return value
    scale = 10.0 ** (math.floor(math.log10(value)) - 1)
    return float(f"{math.ceil(value / scale - 1e-9) * scale:.2g}")


def _num(x: float) -> str:
    return repr(float(f"{x:.6g}"))


def _nums(values: Any, digits: int = 3) -> str:
    return "[" + ", ".join(repr(round(float(v), digits)) for v in values) + "]"


def _render(**k: Any) -> str:
    """The TOML text, each choice commented."""
    ch = k["choice"]
    lines = [
        f"# {k['name']}: a description written by `hikoboshi robot init` (docs/robots.md,",
        "# \"Starting from a vendor's URDF\"): the vendor's URDF unchanged on a cube. Every value",
        "# below is the scaffold's choice, with the reason beside it; edit freely.",
        f'name = "{k["name"]}"',
        f'description = "{k["name"]} (vendor URDF) on a {_num(k["base_mass_kg"])} kg cube, '
        'scaffolded by hikoboshi robot init"',
        f'urdf = "{k["urdf_name"]}"',
        f'base_link = "{k["root"]}"',
        f'hand = "{k["hand"]}"',
        'reference_pose = "A"',
        "urdf_collision = false  # the vendor's collision meshes are package:// files",
        "",
        f"# Capsules of {CAPSULE_RADIUS_M} m along the links, a {HAND_RADIUS_M} m hand sphere "
        "and the cube.",
        "[generated_collision]",
        f"radius_m = {CAPSULE_RADIUS_M}",
        f"hand_radius_m = {HAND_RADIUS_M}",
        "",
        "# The cube (uniform), the URDF's root on the centre of its +z face.",
        "[base]",
        f"mass_kg = {_num(k['base_mass_kg'])}",
        f"size_m = {_nums([k['base_size_m']] * 3, 6)}",
        f"mount_xyz_m = {_nums([0.0, 0.0, 0.5 * k['base_size_m']], 6)}",
        "",
        f"# Mission limits: the vendor's range less {LIMIT_MARGIN_DEG:g} deg a side, within "
        f"+-{MAX_MISSION_DEG:g} deg;",
        f"# {MISSION_RATE_DEGPS:g} deg/s (a space arm's rate, ETS-VII's) or the vendor's if "
        "slower.",
        "[mission_limits]",
        f"rate_degps = {_nums(np.degrees(k['rates']), 4)}",
        "angle_deg = { "
        + ", ".join(
            f"{name} = {_nums(np.degrees(k['limits'][i]), 3)}"
            for i, name in enumerate(k["joint_names"])
        )
        + " }",
        "",
    ]
    lines += [
        f"# Wheels sized from the arm's reaction momentum: |H~bm phi'| is at most "
        f"{ch['reaction_momentum_bound_nms']:.3g} N m s",
        f"# ({k['choice']['pose_samples']} sampled poses, every joint at its mission rate); "
        f"capacity {WHEEL_MARGIN:g} x that. PTP A->B peaks",
        f"# at {ch['ptp_reaction_momentum_peak_nms']:.3g} N m s and "
        f"{ch['ptp_reaction_torque_peak_nm']:.3g} N m; torque {WHEEL_MARGIN:g} x that, at "
        f"least capacity / {WHEEL_FILL_S:g} s.",
        f"# Rotors: {WHEEL_SPEED_RADPS:g} rad/s at capacity, thin discs of "
        f"{WHEEL_RADIUS_M:g} m radius.",
    ]
    for axis in ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)):
        lines += [
            "[[wheels]]",
            f"axis = {_nums(axis, 1)}",
            f"spin_inertia_kgm2 = {_num(k['spin'])}",
            f"rotor_mass_kg = {_num(k['rotor'])}",
            f"torque_limit_nm = {_num(k['torque'])}",
            f"momentum_limit_nms = {_num(k['capacity'])}",
            "",
        ]
    lines += [
        "# The memoryless PD law of the shipped small robot (Orihime).",
        "[acs]",
        "bandwidth_radps = 0.1",
        "damping_ratio = 0.7",
        "rate_filter_tau_s = 0.0",
        "dead_band_deg = 0.0",
        "",
        f"# Fastest servo mode {ch['servo_fastest_per_s']:.4g} 1/s over the poses and the "
        f"sampled range (the integrator holds {ch['servo_limit_per_s']:.4g});",
        f"# chosen for at most {SERVO_MARGIN:g} of that, damping ratio {SERVO_DAMPING:g} at "
        f"A where the lag stays under {MAX_SERVO_LAG_S:g} s.",
        "[servo]",
        f"bandwidth_radps = {_num(k['bandwidth'])}",
        f"lag_s = {_num(k['lag'])}",
        "",
        f"# Poses away from singularities: smallest singular value of J_g (angular rows x "
        f"{ch['reach_m']:.3g} m,",
        "# the reach) "
        + ", ".join(f"{p} {v:.3g}" for p, v in ch["sigma_min_Jg"].items())
        + "; clearance of the generated bodies "
        + ", ".join(f"{p} {v:.3g} m" for p, v in ch["clearance_m"].items())
        + ".",
    ]
    notes = {
        "A": "the reference pose: servo design, IK seed, the vehicle's start, coordination's "
        "and GJM's start",
        "B": "PTP's goal, the reactionless start",
        "C": f"B + {ch['reactionless_distance_m']:g} m toward robot "
        f"{ch['reactionless_direction']} by the reactionless path",
    }
    for name, q in k["poses"].items():
        lines += [
            f"[poses.{name}]",
            f'description = "{notes[name]}"',
            f"joints_deg = {_nums(np.degrees(q), 3)}",
            "",
        ]
    direction = _DIRECTIONS[ch["reactionless_direction"]]
    checked = k.get("checked")
    if checked is not None:
        verdicts = [
            f"{e} {'passes' if row['passed'] else 'FAILS'}"
            + ("" if row["clearance_m"] is None else f" ({row['clearance_m']:.3g} m)")
            for e, row in checked.items()
        ]
        lines += _wrapped(
            "Each experiment below, planned as written, against the flight rules (clearance "
            "of the arm from the base): " + ", ".join(verdicts) + "."
        )
    lines += [
        "[experiments.ptp]",
        f"start_joints_deg = {_nums(np.degrees(k['poses']['A']), 3)}",
        "",
        "# The direction and length with the least lateral wander of the six axes tried; the",
        "# speed keeps the joints within 0.9 of their rate.",
        "[experiments.reactionless]",
        f"direction_robot = {_nums(direction, 1)}",
        f"distance_m = {_num(ch['reactionless_distance_m'])}",
        f"out_speed_mps = {_num(ch['reactionless_speed_mps'])}",
        f"back_speed_mps = {_num(0.5 * ch['reactionless_speed_mps'])}",
        "",
        "# A holds this hand pitch (about robot y); the approach runs along the hand's x.",
        "[experiments.gjm]",
        f"hand_pitch_deg = {_num(ch['gjm_hand_pitch_deg'])}",
        f"approach_distance_m = {GJM_DISTANCE_M}",
        "",
        "# Along robot +x from A and back, checked well conditioned.",
        "[experiments.coordination]",
        f"distance_m = {COORDINATION_DISTANCE_M}",
        "",
        *_nonholonomic_comment(k.get("nonholonomic")),
        "[experiments.nonholonomic]",
        f"phi_init_deg = {_nums(np.degrees(k['phi_init']), 3)}",
        f"phi_end_deg = {_nums(np.degrees(k['poses']['A']), 3)}",
        "",
        f"# Generated bodies: {MIN_CLEARANCE_M} m apart (the pairs nearer at A are joined).",
        "[flight_rules]",
        f"min_clearance_m = {MIN_CLEARANCE_M}",
        "",
    ]
    return "\n".join(lines)


def _wrapped(text: str, width: int = 92) -> list[str]:
    """``text`` as comment lines of at most ``width`` characters."""
    lines: list[str] = []
    line = "#"
    for word in text.split():
        if len(line) + 1 + len(word) > width and line != "#":
            lines.append(line)
            line = "#"
        line += " " + word
    return [*lines, line]


def _metres(value: float | None) -> str:
    return "none to check" if value is None else f"{value:.4g} m"


def _nonholonomic_comment(nh: dict[str, Any] | None) -> list[str]:
    """What was tried for the non-holonomic start and why this one (None: the first
    description's, ETS-VII's offsets)."""
    if nh is None:
        return ["# From A offset by ETS-VII's offsets (clipped to the limits) back to A."]
    offsets = ", ".join(f"{v:g}" for v in nh["offset_deg"])
    scales = ", ".join(f"x{v:g}" for v in NONHOLONOMIC_SCALES)
    tried = (
        f"{nh['candidates_tried']} tried (ETS-VII's offsets as they are, reversed, the other "
        f"sign patterns; at {scales}): the meeting's paths found coarsely and sampled for "
        f"clearance, {nh['fully_checked']} of them planned and checked in full"
    )
    best = nh["best_screened_clearance_m"]
    if nh["passed"]:
        text = (
            f"From A offset by {nh['candidate']} ({offsets} deg, clipped to the limits) back "
            f"to A: the first candidate whose plan passes the flight rules, clearance "
            f"{_metres(nh['clearance_m'])} from the base and {_metres(nh['self_clearance_m'])} "
            f"between the links (at least {MIN_CLEARANCE_M} m), end attitude error "
            f"{nh['end_attitude_error_deg']:.2g} deg. {tried}."
        )
    elif nh.get("clearance_m") is not None:
        text = (
            f"NO candidate passes the flight rules: written is the nearest, A offset by "
            f"{nh['candidate']} ({offsets} deg): {'; '.join(nh['failing'])}. {tried}. "
            "Choose phi_init_deg (and phi_end_deg) yourself."
        )
    else:
        text = (
            f"NO candidate passes the flight rules: written is the nearest, A offset by "
            f"{nh['candidate']} ({offsets} deg), whose coarse paths come nearest: "
            f"{'no meeting inside the limits' if best is None else _metres(best)} (at least "
            f"{MIN_CLEARANCE_M} m). {tried}. Choose phi_init_deg (and phi_end_deg) yourself."
        )
    return _wrapped(text)
