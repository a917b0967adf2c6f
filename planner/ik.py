"""Inverse kinematics: hand pose in the robot frame -> joint angles within limits.

Damped least squares (Levenberg-Marquardt with an adaptive damping) from several starts:
the reference configuration first, then a fixed, seeded set spread over the joint ranges.
Converged, distinct solutions are ranked by their joint-space distance from the reference
(the least motion first), then by their margin to the joint limits.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from planner.dynamics import DynamicsWorkspace
from planner.errors import DidNotConverge, InfeasibleGoal, InvalidInput
from planner.frames import rotvec_from_matrix
from planner.state import State

__all__ = ["IKSolution", "solve_ik"]

Array = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class IKSolution:
    joints_rad: Array
    position_error_m: float
    rotation_error_rad: float
    distance_from_reference_rad: float  # Euclidean norm over joints
    limit_margin_rad: float  # smallest distance of any joint to its limit
    manipulability: float  # sqrt(det(J J^T)) of the arm Jacobian in the robot frame


def _pose_error(ws: DynamicsWorkspace, q: Array, pos: Array, rot: Array) -> tuple[Array, Array]:
    hand, _, J_m = ws.hand_jacobian(State(joints_rad=q))
    e_pos = pos - hand.pos_robot_m
    e_rot = rotvec_from_matrix(rot @ hand.rot_robot_from_hand.T)
    return np.concatenate([e_pos, e_rot]), J_m


def _descend(
    ws: DynamicsWorkspace, q0: Array, pos: Array, rot: Array, tol: float, max_iter: int
) -> Array | None:
    """Levenberg-Marquardt on the pose error with a 0.3 rad step cap; the iterate runs free
    of the joint limits (clipping stalls it at a limit) and is checked against them after."""
    q = q0.copy()
    err, J = _pose_error(ws, q, pos, rot)
    cost = float(err @ err)
    damping = 1e-2
    for _ in range(max_iter):
        if np.max(np.abs(err)) < tol:
            break
        step = J.T @ np.linalg.solve(J @ J.T + damping * np.eye(6), err)
        norm = float(np.linalg.norm(step))
        if norm > _MAX_STEP_RAD:
            step *= _MAX_STEP_RAD / norm
        q_new = q + step
        err_new, J_new = _pose_error(ws, q_new, pos, rot)
        cost_new = float(err_new @ err_new)
        if cost_new < cost:
            q, err, J, cost = q_new, err_new, J_new, cost_new
            damping = max(damping * 0.5, 1e-9)
        else:
            damping *= 4.0
            if damping > 1e8:
                return None
    if np.max(np.abs(err)) >= tol:
        return None
    q = (q + np.pi) % (2.0 * np.pi) - np.pi
    lo, hi = ws.model.joint_limit_rad[:, 0], ws.model.joint_limit_rad[:, 1]
    return q if np.all((q >= lo) & (q <= hi)) else None


_MAX_STEP_RAD = 0.3


def solve_ik(
    ws: DynamicsWorkspace,
    pos_robot_m: Array,
    rot_robot_from_hand: Array,
    *,
    reference_joints_rad: Array | None = None,
    n_starts: int = 24,
    seed: int = 0,
    tol: float = 1e-10,
    max_iter: int = 500,
) -> list[IKSolution]:
    """All distinct solutions found for the hand pose, best first (see module docstring).

    ``tol`` bounds each component of the pose error (m and rad). Raises
    :class:`InfeasibleGoal` for a pose out of reach and :class:`DidNotConverge` when no
    start converged.
    """
    model = ws.model
    pos = np.asarray(pos_robot_m, dtype=np.float64)
    rot = np.asarray(rot_robot_from_hand, dtype=np.float64)
    if pos.shape != (3,) or rot.shape != (3, 3) or not np.all(np.isfinite(pos)):
        raise InvalidInput("IK target needs a finite position (3,) and a rotation (3, 3)")
    if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6) or np.linalg.det(rot) < 0:
        raise InvalidInput("IK target orientation is not a rotation matrix")
    reference = (
        model.reference_joints
        if reference_joints_rad is None
        else model.check_joints(reference_joints_rad)
    )
    # Out of reach: farther from joint 2 than the sum of the segments that follow it.
    joints = [link.joint_pos_robot_m for link in model.links] + [model.hand_pos_robot_m]
    reach_m = sum(float(np.linalg.norm(b - a)) for a, b in itertools.pairwise(joints[1:]))
    shoulder_distance_m = float(np.linalg.norm(pos - joints[1]))
    # Joint 1 swings joint 2 on a circle about its axis (radius 0.275 m for ETS-VII, 0.15 m
    # for Orihime); 0.075 m more of margin.
    axis1 = model.links[0].joint_axis_robot
    offset = joints[1] - joints[0]
    swing_m = float(np.linalg.norm(offset - (offset @ axis1) * axis1))
    if shoulder_distance_m > reach_m + swing_m + 0.075:
        raise InfeasibleGoal(
            f"hand target {np.round(pos, 3).tolist()} m is {shoulder_distance_m:.3f} m from the "
            f"shoulder, beyond the arm's reach of {reach_m:.3f} m"
        )
    lo, hi = model.joint_limit_rad[:, 0], model.joint_limit_rad[:, 1]
    rng = np.random.default_rng(seed)
    starts = [reference, *(rng.uniform(-np.pi, np.pi, model.n_joints) for _ in range(n_starts))]
    found: list[Array] = []
    for q0 in starts:
        q = _descend(ws, q0, pos, rot, tol, max_iter)
        if q is not None and not any(np.linalg.norm(q - f) < 1e-6 for f in found):
            found.append(q)
    if not found:
        raise DidNotConverge(
            f"IK did not converge to the hand pose at {np.round(pos, 4).tolist()} m from "
            f"{len(starts)} starts (tolerance {tol:g}); it may lie outside the joint limits"
        )
    solutions = []
    for q in found:
        err, J = _pose_error(ws, q, pos, rot)
        solutions.append(
            IKSolution(
                joints_rad=q,
                position_error_m=float(np.linalg.norm(err[:3])),
                rotation_error_rad=float(np.linalg.norm(err[3:])),
                distance_from_reference_rad=float(np.linalg.norm(q - reference)),
                limit_margin_rad=float(np.min(np.minimum(q - lo, hi - q))),
                manipulability=float(np.sqrt(max(np.linalg.det(J @ J.T), 0.0))),
            )
        )
    solutions.sort(key=lambda s: (round(s.distance_from_reference_rad, 9), -s.limit_margin_rad))
    return solutions
