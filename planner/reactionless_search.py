"""Searches for a reactionless path to a goal hand pose (beyond the paper).

Experiment 1 moves the hand along a line in the reaction null space (RNS,
:mod:`planner.reactionless`); these search for a reactionless joint path that brings the hand
to a given pose instead, with the base held still by construction:

- :func:`search_reactionless_path` (local) descends the weighted pose error point by point,
  each step the null-space motion that most reduces it, until the goal, a joint limit or a
  local minimum of the reachable set;
- :func:`search_reactionless_global` (global) shoots on the endpoint map of the RNS flow
  ``phi' = P(phi) u`` (:func:`reactionless_flow`): piecewise-constant controls moved all at
  once by Levenberg-Marquardt, from seeded random restarts, so that the Lie brackets of the
  null space (looping routes) reach what the descent cannot.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from planner.dynamics import DynamicsWorkspace
from planner.errors import InvalidInput
from planner.frames import rotvec_from_matrix
from planner.reactionless import ORIENTATION_WEIGHT_M, dls, rns_basis
from planner.state import State

__all__ = [
    "GlobalReactionlessSearch",
    "ReactionlessSearch",
    "reactionless_flow",
    "search_reactionless_global",
    "search_reactionless_path",
]

Array = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class ReactionlessSearch:
    """Outcome of :func:`search_reactionless_path` (beyond the paper)."""

    joints_rad: Array  # the reactionless path found, rows every step
    reached: bool
    position_error_m: float  # remaining distance to the goal position
    orientation_error_rad: float  # remaining orientation error
    best_position_error_m: float  # closest approach along the path
    reason: str


def search_reactionless_path(
    ws: DynamicsWorkspace,
    start_joints_rad: Array,
    goal_pos_robot_m: Array,
    goal_rot_robot_from_hand: Array,
    *,
    orientation_weight_m: float = ORIENTATION_WEIGHT_M,
    step_rad: float = 0.005,
    max_steps: int = 4000,
    tol_m: float = 1e-3,
) -> ReactionlessSearch:
    """Descend the hand-pose error toward a goal while staying exactly in the RNS.

    Each step moves the joints by at most ``step_rad`` along ``N zeta``, the null-space motion
    that most reduces the weighted pose error. It stops at the goal, at a joint limit, or when
    the null space no longer reduces the error (a local minimum of the reachable set: the
    reaction constraint being non-holonomic, a different route could still exist).
    """
    model = ws.model
    q = model.check_joints(start_joints_rad).copy()
    lo, hi = model.joint_limit_rad[:, 0], model.joint_limit_rad[:, 1]
    path = [q.copy()]
    best = np.inf
    reason = f"step budget of {max_steps} exhausted"

    def errors(phi: Array) -> tuple[Array, Array, Array]:
        hand, _, J_m = ws.hand_jacobian(State(joints_rad=phi))
        e_pos = goal_pos_robot_m - hand.pos_robot_m
        e_rot = Rotation.from_matrix(goal_rot_robot_from_hand @ hand.rot_robot_from_hand.T)
        err = np.concatenate([e_pos, orientation_weight_m * e_rot.as_rotvec()])
        jac = np.vstack([J_m[:3], orientation_weight_m * J_m[3:]])
        return err, jac, e_pos

    stalled = 0
    for _ in range(max_steps):
        err, jac, e_pos = errors(q)
        best = min(best, float(np.linalg.norm(e_pos)))
        if np.linalg.norm(e_pos) < tol_m and np.linalg.norm(err[3:]) < tol_m:
            reason = "goal reached"
            break
        basis, _ = rns_basis(ws, q)
        step = basis @ dls(jac @ basis, err)
        norm = float(np.linalg.norm(step))
        if norm > step_rad:
            step *= step_rad / norm
        q_new = q + step
        if np.any((q_new < lo) | (q_new > hi)):
            joint = int(np.flatnonzero((q_new < lo) | (q_new > hi))[0]) + 1
            reason = f"joint {joint} reached its limit"
            break
        new_err, _, _ = errors(q_new)
        if np.linalg.norm(new_err) >= np.linalg.norm(err) - 1e-7:
            stalled += 1
            if stalled >= 20:
                reason = "the reaction null space no longer reduces the pose error"
                break
        else:
            stalled = 0
        q = q_new
        path.append(q.copy())
    err, _, e_pos = errors(q)
    return ReactionlessSearch(
        joints_rad=np.array(path),
        reached=reason == "goal reached",
        position_error_m=float(np.linalg.norm(e_pos)),
        orientation_error_rad=float(np.linalg.norm(err[3:]) / orientation_weight_m),
        best_position_error_m=float(best),
        reason=reason,
    )


# --- global search: shooting on the endpoint map of the reactionless flow -------------------

_LIMIT_SOFT_MARGIN_RAD = np.radians(10.0)  # joints inside this band of a limit are penalised
_LIMIT_HARD_MARGIN_RAD = np.radians(1.0)  # and never come closer than this to it
_LIMIT_WEIGHT = 3.0  # residual per radian of intrusion into the soft band
_FD_STEP = 1e-6  # rad, finite-difference step on the controls


@dataclass(frozen=True, eq=False)
class GlobalReactionlessSearch:
    """Outcome of :func:`search_reactionless_global` (beyond the paper).

    The path is the flow of ``phi' = P(phi) u_k`` for ``k = 0..pieces-1`` (``P`` the RNS
    projector ``I - H~_bm^+ H~_bm``, each piece one unit of path parameter), sampled at
    ``joints_rad`` (RK4 nodes, ``steps_per_piece`` per piece).
    """

    start_joints_rad: Array
    controls: Array  # (pieces, n): u_k of the best path
    joints_rad: Array  # (pieces * steps_per_piece + 1, n)
    reached: bool
    position_error_m: float  # of the best path's end
    orientation_error_rad: float
    restarts: int  # restarts run
    iterations: int  # Levenberg-Marquardt iterations run over all restarts
    seconds: float
    reason: str
    history: tuple[tuple[int, int, float, float], ...]  # (restart, iteration, pos m, rot rad)


def _rns_rate(ws: DynamicsWorkspace, phi: Array, u: Array) -> Array:
    """``P(phi) u``: ``u`` without its part that would carry angular momentum."""
    _, h_bm = ws.momentum_blocks(phi)
    return np.asarray(u - h_bm.T @ np.linalg.solve(h_bm @ h_bm.T, h_bm @ u))


def _flow(ws: DynamicsWorkspace, start: Array, controls: Array, steps: int) -> Array:
    """RK4 nodes (pieces * steps + 1, n) of ``phi' = P(phi) u_k``, one unit per piece."""
    h = 1.0 / steps
    q = np.asarray(start, dtype=np.float64).copy()
    nodes = [q.copy()]
    for u in controls:
        for _ in range(steps):
            k1 = _rns_rate(ws, q, u)
            k2 = _rns_rate(ws, q + 0.5 * h * k1, u)
            k3 = _rns_rate(ws, q + 0.5 * h * k2, u)
            k4 = _rns_rate(ws, q + h * k3, u)
            q = q + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            nodes.append(q.copy())
    return np.array(nodes)


def reactionless_flow(
    ws: DynamicsWorkspace, start_joints_rad: Array, controls: Array, *, steps_per_piece: int
) -> Array:
    """The joint path (RK4 nodes) of the piecewise-constant RNS controls ``controls``."""
    controls = np.asarray(controls, dtype=np.float64)
    if controls.ndim != 2 or controls.shape[1] != ws.model.n_joints:
        raise InvalidInput(f"controls must be (pieces, {ws.model.n_joints}), got {controls.shape}")
    return _flow(ws, ws.model.check_joints(start_joints_rad), controls, steps_per_piece)


def _pose_residual(
    ws: DynamicsWorkspace, phi: Array, goal_pos: Array, goal_rot: Array, weight_m: float
) -> tuple[Array, float, float]:
    hand = ws.hand_pose(State(joints_rad=phi))
    e_pos = goal_pos - hand.pos_robot_m
    e_rot = rotvec_from_matrix(goal_rot @ hand.rot_robot_from_hand.T)
    res = np.concatenate([e_pos, weight_m * e_rot])
    return res, float(np.linalg.norm(e_pos)), float(np.linalg.norm(e_rot))


def search_reactionless_global(
    ws: DynamicsWorkspace,
    start_joints_rad: Array,
    goal_pos_robot_m: Array,
    goal_rot_robot_from_hand: Array,
    *,
    seed: int = 0,
    pieces: int = 16,
    steps_per_piece: int = 8,
    initial_scale_rad: float = 0.4,
    max_restarts: int = 8,
    max_iterations: int = 60,
    time_budget_s: float | None = None,
    orientation_weight_m: float = ORIENTATION_WEIGHT_M,
    tol_m: float = 1e-4,
    tol_rad: float = 1e-4,
    progress: Callable[[int, int, float, float], None] | None = None,
) -> GlobalReactionlessSearch:
    """Search for a reactionless joint path whose hand ends at the goal pose (global).

    The reaction constraint is non-holonomic: the RNS has n - 3 of the n joint dimensions, but
    its Lie brackets (the net motion of small cycles in the null space) supply the others, so
    a goal the null-space descent of :func:`search_reactionless_path` cannot approach may
    still be reachable by a longer, looping route. This is a shooting method on the endpoint
    map: the path is ``pieces`` constant controls ``u_k`` of the flow ``phi' = P(phi) u``
    (exactly reactionless at every point, up to the RK4 error), and Levenberg-Marquardt moves
    all ``n * pieces`` controls at once to drive the hand-pose error at the end to zero (the
    endpoint map of a bracket-generating system has full rank at generic, non-zero controls,
    so cycles are part of every step; at zero controls it has rank 3 only, hence random
    starts). Joints are kept ``_LIMIT_HARD_MARGIN_RAD`` inside their limits (a trial that
    crosses is refused) and penalised inside a 10 deg band. Restarts from seeded random
    controls explore globally until the goal (within ``tol_m`` and ``tol_rad``), the restart
    and iteration budget, or ``time_budget_s`` (which makes the result machine-dependent;
    without it the result depends on ``seed`` only).

    The goal is the hand pose (position and orientation in the robot frame, the base held):
    any arm configuration that puts the hand there counts.
    """
    import time

    model = ws.model
    start = model.check_joints(start_joints_rad).copy()
    goal_pos = np.asarray(goal_pos_robot_m, dtype=np.float64)
    goal_rot = np.asarray(goal_rot_robot_from_hand, dtype=np.float64)
    if pieces < 2 or steps_per_piece < 1 or max_restarts < 1 or max_iterations < 0:
        raise InvalidInput("pieces >= 2, steps_per_piece >= 1, max_restarts >= 1 needed")
    lo, hi = model.joint_limit_rad[:, 0], model.joint_limit_rad[:, 1]
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    n = model.n_joints
    per_piece = steps_per_piece

    def limit_rows(nodes: Array) -> Array:
        over = np.maximum(nodes - (hi - _LIMIT_SOFT_MARGIN_RAD), 0.0) + np.maximum(
            (lo + _LIMIT_SOFT_MARGIN_RAD) - nodes, 0.0
        )
        return np.asarray(_LIMIT_WEIGHT * np.sqrt(np.sum(over**2, axis=0) / nodes.shape[0]))

    def inside(nodes: Array) -> bool:
        return bool(
            np.all(nodes <= hi - _LIMIT_HARD_MARGIN_RAD)
            and np.all(nodes >= lo + _LIMIT_HARD_MARGIN_RAD)
        )

    def evaluate(nodes: Array) -> tuple[Array, float, float]:
        pose, e_pos, e_rot = _pose_residual(ws, nodes[-1], goal_pos, goal_rot, orientation_weight_m)
        return np.concatenate([pose, limit_rows(nodes)]), e_pos, e_rot

    def jacobian(x: Array, nodes: Array, r: Array) -> Array:
        jac = np.empty((r.size, x.size))
        for k in range(pieces):
            q_k = nodes[k * per_piece]
            head = nodes[: k * per_piece]
            for j in range(n):
                xp = x.copy()
                xp[k, j] += _FD_STEP
                tail = _flow(ws, q_k, xp[k:], per_piece)
                jac[:, k * n + j] = (evaluate(np.vstack([head, tail]))[0] - r) / _FD_STEP
        return jac

    history: list[tuple[int, int, float, float]] = []
    best: tuple[float, Array, Array, float, float] | None = None
    total_iterations = 0
    restarts = 0
    reason = f"budget of {max_restarts} restarts x {max_iterations} iterations exhausted"
    done = False
    for restart in range(max_restarts):
        restarts = restart + 1
        # Random controls; retried until the path stays inside the limits.
        for _ in range(50):
            x = rng.normal(0.0, initial_scale_rad, size=(pieces, n))
            nodes = _flow(ws, start, x, per_piece)
            if inside(nodes):
                break
            initial_scale_rad *= 0.8
        r, e_pos, e_rot = evaluate(nodes)
        cost = float(r @ r)
        mu = 1e-3
        for it in range(max_iterations + 1):
            history.append((restart, it, e_pos, e_rot))
            if progress is not None:
                progress(restart, it, e_pos, e_rot)
            score = e_pos + orientation_weight_m * e_rot
            if best is None or score < best[0]:
                best = (score, x.copy(), nodes.copy(), e_pos, e_rot)
            if e_pos < tol_m and e_rot < tol_rad:
                reason = "goal reached"
                done = True
                break
            if it == max_iterations:
                break
            if time_budget_s is not None and time.perf_counter() - t0 > time_budget_s:
                reason = f"time budget of {time_budget_s:g} s exhausted"
                done = True
                break
            jac = jacobian(x, nodes, r)
            jjt = jac @ jac.T
            scale = float(np.trace(jjt)) / jjt.shape[0]
            accepted = False
            for _ in range(10):
                step = -jac.T @ np.linalg.solve(jjt + mu * scale * np.eye(r.size), r)
                trial = x + step.reshape(pieces, n)
                trial_nodes = _flow(ws, start, trial, per_piece)
                if inside(trial_nodes):
                    r_t, ep_t, er_t = evaluate(trial_nodes)
                    if float(r_t @ r_t) < cost:
                        x, nodes, r, e_pos, e_rot = trial, trial_nodes, r_t, ep_t, er_t
                        cost = float(r @ r)
                        mu = max(mu / 3.0, 1e-9)
                        accepted = True
                        break
                mu *= 4.0
            total_iterations += 1
            if not accepted:
                break  # stalled: a local minimum of this restart
        if done:
            break
    assert best is not None
    _, controls, nodes, e_pos, e_rot = best
    return GlobalReactionlessSearch(
        start_joints_rad=start,
        controls=controls,
        joints_rad=nodes,
        reached=e_pos < tol_m and e_rot < tol_rad,
        position_error_m=e_pos,
        orientation_error_rad=e_rot,
        restarts=restarts,
        iterations=total_iterations,
        seconds=time.perf_counter() - t0,
        reason=reason,
        history=tuple(history),
    )
