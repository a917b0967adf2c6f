"""Where a scaffold puts its poses: A, B and C chosen on the vendor's arm by sampling
(``hikoboshi robot init``, :mod:`planner.description.scaffold`).

:data:`POSE_SAMPLES` poses drawn inside the mission limits (a fixed seed) are ranked by the
smallest singular value of the generalised Jacobian ``J_g`` (eq. 8; its angular rows scaled
by the arm's reach so that metres and radians weigh alike), among those whose generated
collision bodies keep :data:`POSE_CLEARANCE_M` apart (pairs that touch in nearly every
sample are the design's and do not count; :func:`sample_poses`). A is the best one whose
hand can also hold the GJM approach's orientation (pitch about robot y) at the same point
and move :data:`COORDINATION_DISTANCE_M` along robot +x and back (coordination's line) with
``J_m`` well conditioned (:func:`choose_a`); B the best one at a moderate joint distance
from A from which a reactionless line runs with the least lateral wander (over the six axis
directions); C the end of that line (:func:`choose_b`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from planner.collision import CollisionModel, ShapeSet, body_poses
from planner.collision_segments import segment_collision_model
from planner.description.checks import Checker
from planner.dynamics import DynamicsWorkspace
from planner.errors import PlannerError
from planner.frames import matrix_from_rpy
from planner.ik import solve_ik
from planner.model import RobotModel
from planner.parameters import MIN_SPEED_MPS
from planner.reactionless import ReactionlessPath, reactionless_line
from planner.state import State

__all__ = [
    "DIRECTIONS",
    "Clearance",
    "SampledPoses",
    "choose_a",
    "choose_b",
    "sample_poses",
    "scaled_sigma",
]

Array = NDArray[np.float64]

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
#: GJM hand pitches tried (deg), the hand parallel to the robot frame first.
GJM_PITCHES_DEG = (0.0, -23.0, 23.0, -45.0, 45.0, -67.0, 67.0, -90.0, 90.0)
#: The reactionless line's directions tried (robot frame), by the label the report gives.
DIRECTIONS = {
    "+x": (1.0, 0.0, 0.0),
    "-x": (-1.0, 0.0, 0.0),
    "+y": (0.0, 1.0, 0.0),
    "-y": (0.0, -1.0, 0.0),
    "+z": (0.0, 0.0, 1.0),
    "-z": (0.0, 0.0, -1.0),
}


def scaled_sigma(J: Array, reach_m: float) -> float:
    scaled = J.copy()
    scaled[3:] *= reach_m
    return float(np.linalg.svd(scaled, compute_uv=False)[-1])


class Clearance:
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
        return self.shapes.pair_distances_m(self.pairs, rots[0], trans[0])

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
    clearance: Clearance,
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
        worst = min(worst, scaled_sigma(J_m, reach_m))
        if np.max(np.abs(e)) > 1e-4 or np.any(q < lo) or np.any(q > hi):
            return False, worst, q
        if k % 5 == 0 and clearance.clear(q, exempt) < PATH_CLEARANCE_M:
            return False, worst, q
    return True, worst, q


@dataclass
class SampledPoses:
    """The poses drawn inside the limits and what they showed."""

    rng: np.random.Generator  # drawn from again for B
    lo: Array  # the range drawn from: the limits less POSE_LIMIT_MARGIN_DEG (a quarter at most)
    hi: Array
    samples: Array  # (POSE_SAMPLES, n)
    hands_robot: Array  # each sample's hand position (robot frame)
    reach_m: float  # the farthest of them
    sigma: Array  # each sample's scaled sigma of J_g
    clearance: Clearance  # its ``ignored`` pairs: those touching in nearly every sample
    order: list[int]  # the samples that keep POSE_CLEARANCE_M, by decreasing sigma
    reaction_bound_nms: float  # |H~_bm|_2 |phi'_max| over the samples


def sample_poses(
    c: Checker,
    model: RobotModel,
    ws: DynamicsWorkspace,
    limits: Array,
    rates: Array,
    *,
    root: str,
    base_size_m: float,
    pos_j1_m: Array,
) -> SampledPoses:
    """:data:`POSE_SAMPLES` poses inside ``limits`` (the mission limits), ranked (the module
    docstring); the collision bodies are generated for the base link ``root``, a cube of
    ``base_size_m`` whose centre is ``-pos_j1_m`` in the robot frame. Refused (``c``) when
    none keeps its links apart."""
    n = model.n_joints
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
    sigma = np.array([scaled_sigma(quant.J_g, reach_m) for quant in quantities])
    clearance = Clearance(model, root, base_size_m, pos_j1_m)
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
    return SampledPoses(
        rng=rng,
        lo=lo,
        hi=hi,
        samples=samples,
        hands_robot=hands_robot,
        reach_m=reach_m,
        sigma=sigma,
        clearance=clearance,
        order=order,
        reaction_bound_nms=reaction_bound_nms,
    )


def choose_a(c: Checker, ws: DynamicsWorkspace, sampled: SampledPoses) -> tuple[Array, float]:
    """Pose A's joints and the GJM hand pitch (deg) it holds (the module docstring)."""
    order, hands_robot = sampled.order, sampled.hands_robot
    samples, sigma, reach_m = sampled.samples, sampled.sigma, sampled.reach_m
    lo, hi, clearance = sampled.lo, sampled.hi, sampled.clearance
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
        s = scaled_sigma(ws.evaluate(State(joints_rad=qa)).J_g, reach_m)
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
    return qa, pitch


def choose_b(
    c: Checker, ws: DynamicsWorkspace, sampled: SampledPoses, qa: Array, rates: Array
) -> tuple[Array, str, float, ReactionlessPath, float]:
    """Pose B's joints, the reactionless line's direction (a key of :data:`DIRECTIONS`),
    length and outbound speed, and the line's path from B (to C): the module docstring.
    ``rates``: the joints' mission rates."""
    rng, lo, hi = sampled.rng, sampled.lo, sampled.hi
    reach_m, clearance = sampled.reach_m, sampled.clearance
    n = qa.size
    best_b: tuple[float, Array, str, float, ReactionlessPath, float] | None = None
    tried = 0
    joined = clearance.joined_at(qa)
    near = qa + rng.uniform(-1.0, 1.0, size=(POSE_SAMPLES, n)) * math.radians(B_MAX_DEG)
    near = near[np.all((near >= lo) & (near <= hi), axis=1)]
    gaps = np.degrees(np.max(np.abs(near - qa), axis=1))
    near = near[gaps >= B_MIN_DEG]
    near_sigma = np.array(
        [scaled_sigma(ws.evaluate(State(joints_rad=q)).J_g, reach_m) for q in near]
    )
    for k in np.argsort(-near_sigma):
        qb = near[k]
        path_clear = min(clearance.clear(qa + s * (qb - qa), joined) for s in np.linspace(0, 1, 9))
        if path_clear < PATH_CLEARANCE_M or clearance.clear(qb) < POSE_CLEARANCE_M:
            continue
        tried += 1
        for label, direction in DIRECTIONS.items():
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
    return qb, direction_label, distance, rpath, speed
