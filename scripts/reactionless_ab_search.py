"""Search globally for a reactionless path from pose A to pose B (issue #13 part 5).

Runs :func:`planner.reactionless_search.search_reactionless_global` from A (all joints zero) to
pose B's hand pose with the given seed and budget, prints its progress, and then explains
the closest approach: at the best path's end it compares the joint motion the hand still
needs with what the reaction null space (RNS) and its first Lie brackets can supply (the
singular values of the fields ``P e_i`` and ``[P e_i, P e_j]``; a loop enclosing ``a`` rad^2
in the plane of two RNS fields moves the joints by about ``a`` times their bracket).

    .venv/bin/python scripts/reactionless_ab_search.py --seed 0 --pieces 24 \
        --restarts 6 --iterations 40

Prints one JSON object at the end (the numbers docs/planning.md quotes).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
from scipy.spatial.transform import Rotation

from planner.dynamics import DynamicsWorkspace
from planner.experiments import POSE_B_POS_ROBOT_M, POSE_B_RPY_DEG, joints_at_pose_b
from planner.frames import matrix_from_rpy
from planner.model import default_model
from planner.prediction import predict
from planner.reactionless_search import (
    reactionless_flow,
    search_reactionless_global,
    search_reactionless_path,
)
from planner.state import State


def _projector(ws: DynamicsWorkspace, q: np.ndarray) -> np.ndarray:
    _, h = ws.momentum_blocks(q)
    return np.asarray(np.eye(6) - h.T @ np.linalg.solve(h @ h.T, h))


def _fields(ws: DynamicsWorkspace, q: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """Rows: the RNS fields ``P e_i`` and their brackets ``[P e_i, P e_j]`` at ``q``."""
    p = _projector(ws, q)
    d = np.array(
        [(_projector(ws, q + eps * e) - _projector(ws, q - eps * e)) / (2 * eps) for e in np.eye(6)]
    )  # d[k] = dP / dq_k
    rows = [p[:, i] for i in range(6)]
    for i in range(6):
        for j in range(i + 1, 6):
            rows.append(d[:, :, j].T @ p[:, i] - d[:, :, i].T @ p[:, j])
    return np.array(rows)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--pieces", type=int, default=24)
    ap.add_argument("--steps-per-piece", type=int, default=8)
    ap.add_argument("--restarts", type=int, default=6)
    ap.add_argument("--iterations", type=int, default=40)
    ap.add_argument("--time-budget-s", type=float, default=None)
    args = ap.parse_args()

    ws = DynamicsWorkspace(default_model())
    goal_pos = np.array(POSE_B_POS_ROBOT_M)
    goal_rot = matrix_from_rpy(np.radians(POSE_B_RPY_DEG))
    t0 = time.perf_counter()

    def progress(restart: int, iteration: int, pos: float, rot: float) -> None:
        print(
            f"{time.perf_counter() - t0:7.1f} s  restart {restart}  iteration {iteration:3d}  "
            f"{pos:.4f} m  {np.degrees(rot):7.3f} deg",
            file=sys.stderr,
            flush=True,
        )

    result = search_reactionless_global(
        ws,
        np.zeros(6),
        goal_pos,
        goal_rot,
        seed=args.seed,
        pieces=args.pieces,
        steps_per_piece=args.steps_per_piece,
        max_restarts=args.restarts,
        max_iterations=args.iterations,
        time_budget_s=args.time_budget_s,
        progress=progress,
    )
    local = search_reactionless_path(ws, np.zeros(6), goal_pos, goal_rot)

    # The best path flown: fine integration, commands 0.25 s apart, free drift.
    fine = reactionless_flow(ws, np.zeros(6), result.controls, steps_per_piece=64)
    free = predict(ws, np.arange(fine.shape[0], dtype=np.float64) * 0.25, fine)
    base_deg = float(
        np.max(np.degrees(Rotation.from_quat(free.quat_orbit_from_base_xyzw).magnitude()))
    )
    rate_limit = ws.model.joint_rate_limit_radps
    travel_s = float(np.sum(np.max(np.abs(np.diff(fine, axis=0)) / rate_limit, axis=1)))

    # What bounds the closest approach: the joint motion the hand still needs, in the
    # singular directions of the RNS fields and their first brackets.
    q = result.joints_rad[-1]
    hand, _, jac = ws.hand_jacobian(State(joints_rad=q))
    e_rot = Rotation.from_matrix(goal_rot @ hand.rot_robot_from_hand.T).as_rotvec()
    needed = np.linalg.solve(jac, np.concatenate([goal_pos - hand.pos_robot_m, e_rot]))
    _, sing, vt = np.linalg.svd(_fields(ws, q))
    q_b = joints_at_pose_b(ws)
    summary = {
        "seed": args.seed,
        "pieces": args.pieces,
        "steps_per_piece": args.steps_per_piece,
        "restarts": result.restarts,
        "iterations": result.iterations,
        "seconds": round(result.seconds, 1),
        "reason": result.reason,
        "reached": result.reached,
        "position_error_m": result.position_error_m,
        "orientation_error_deg": float(np.degrees(result.orientation_error_rad)),
        "local_search_position_error_m": local.position_error_m,
        "local_search_orientation_error_deg": float(np.degrees(local.orientation_error_rad)),
        "closest_joints_deg": np.degrees(q).round(2).tolist(),
        "max_abs_joint_deg": np.degrees(np.max(np.abs(fine), axis=0)).round(1).tolist(),
        "path_at_full_rate_s": round(travel_s, 1),
        "base_motion_ideal_tracking_deg": base_deg,
        "bracket_singular_values": sing.tolist(),
        "needed_joint_motion_rad": float(np.linalg.norm(needed)),
        "needed_in_singular_directions_rad": (vt @ needed).tolist(),
        "needed_outside_rns_rad": float(np.linalg.norm(needed - _projector(ws, q) @ needed)),
        "bracket_singular_values_at_b_joints": np.linalg.svd(
            _fields(ws, q_b), compute_uv=False
        ).tolist(),
    }
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
