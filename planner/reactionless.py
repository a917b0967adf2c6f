"""Reactionless manipulation in the reaction null space (RNS), SPEC experiment 1, eq. (4)-(5).

Zero reaction is the hard constraint: every joint rate is ``phi' = N zeta`` with ``N`` an
orthonormal basis of the null space of ``H~_bm`` (n - 3 dimensions: 3 for ETS-VII's 6
joints, 4 for Orihime's 7), so the arm's motion
carries no angular momentum and the base does not turn. Inside those three freedoms the hand
tasks are met by priority (damped least squares at each level, so a task that becomes
singular degrades smoothly instead of demanding huge rates):

1. progress of the hand along the motion's direction at the commanded speed;
2. the hand's lateral position on the line and its orientation (weighted, with a
   proportional correction of the errors so that nothing accumulates).

Three freedoms (ETS-VII) cannot hold six task coordinates, so the orientation drifts where the
constraint leaves no room; the plan reports by how much. The return leg is the outbound
joint path retraced at its own speed: retracing a reactionless path is reactionless, and
it returns the arm to exactly the joints it started from (a reactionless path that only aimed
the hand back would, the constraint being non-holonomic, end at other joints).

Everything is computed in the base (= robot-parallel) frame at the base's nominal attitude:
the base does not turn, by construction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import lapack
from scipy.spatial.transform import Rotation

from planner.dynamics import DynamicsWorkspace
from planner.errors import InfeasibleGoal, InvalidInput, JointLimitExceeded
from planner.frames import rotvec_from_matrix
from planner.ptp import COMMAND_PERIOD_S
from planner.state import State

__all__ = [
    "ORIENTATION_WEIGHT_M",
    "ReactionlessPath",
    "dls",
    "reactionless_line",
    "retime_path",
    "rns_basis",
]

Array = NDArray[np.float64]

_DAMPING = 1e-4  # DLS damping (squared singular-value scale) in the null-space coordinates
_LATERAL_GAIN_PS = 2.0  # 1/s, correction of the hand's distance from the line
_ORIENTATION_GAIN_PS = 1.0  # 1/s, correction of the hand's orientation
#: metres of position error worth one radian of orientation (the line's and the searches')
ORIENTATION_WEIGHT_M = 0.3


@dataclass(frozen=True, eq=False)
class ReactionlessPath:
    """A densely sampled reactionless joint path (rows at ``t_s``)."""

    t_s: Array
    joints_rad: Array
    hand_pos_robot_m: Array
    hand_orientation_change_rad: Array  # angle from the start orientation
    min_coupling_singular_kgm2: float  # smallest singular value of H~_bm along the path


def dls(a: Array, b: Array) -> Array:
    """Damped least-squares solution of ``a x = b``."""
    return np.asarray(a.T @ np.linalg.solve(a @ a.T + _DAMPING * np.eye(a.shape[0]), b))


def _row_projector(a: Array) -> Array:
    """``pinv(a) a`` of one row ``a`` (m,): ``a a^T / |a|^2``, zero where ``a`` is."""
    norm2 = float(a @ a)
    return np.outer(a, a) / norm2 if norm2 > 0.0 else np.zeros((a.size, a.size))


def _rotation(rot: Array) -> Rotation:
    """``rot``, a product of MuJoCo's frames (orthonormal to round-off), as scipy's rotation
    without its re-orthogonalisation (three quarters of the cost)."""
    return Rotation.from_matrix(rot, assume_valid=True)


def rns_basis(ws: DynamicsWorkspace, joints: Array) -> tuple[Array, float]:
    """An orthonormal basis ``N`` (n, n - 3) of the null space of ``H~_bm`` at ``joints``,
    and ``H~_bm``'s smallest singular value."""
    return _null_basis(ws.momentum_blocks(joints)[1])


def _null_basis(h_bm: Array) -> tuple[Array, float]:
    """:func:`rns_basis` of ``H~_bm``: LAPACK's dgesdd, as ``np.linalg.svd`` calls it (the
    same numbers, laid out as numpy lays them: C order, which the products with the basis
    follow to the bit) without numpy's wrapper."""
    _, sing, vt, info = lapack.dgesdd(h_bm)
    if info != 0:  # numpy's error, as before
        raise np.linalg.LinAlgError("SVD did not converge")
    return np.ascontiguousarray(vt)[3:].T, float(sing[-1])


def _speed_profile(t: Array, duration_s: float, ramp_s: float, speed: float) -> Array:
    """Trapezoidal speed with raised-cosine ramps at both ends."""
    up = np.clip(t / ramp_s, 0.0, 1.0)
    down = np.clip((duration_s - t) / ramp_s, 0.0, 1.0)
    return np.asarray(speed * 0.5 * (1.0 - np.cos(np.pi * np.minimum(up, down))))


def reactionless_line(
    ws: DynamicsWorkspace,
    start_joints_rad: Array,
    *,
    direction_robot: Array,
    distance_m: float,
    speed_mps: float,
    ramp_s: float = 2.0,
    dt_s: float = 0.05,
    orientation_weight_m: float = ORIENTATION_WEIGHT_M,
) -> ReactionlessPath:
    """Move the hand ``distance_m`` along ``direction_robot`` at ``speed_mps``, reactionless.

    ``orientation_weight_m`` trades the hand's orientation against its lateral position in
    the second priority level (metres of lateral error worth one radian): at 0.3 the B -> C
    leg keeps within 7 cm of the line and turns the hand by about 15 deg; a strictly
    straight line would turn it by about 66 deg and need more than the 3 deg/s rate limit.

    Raises :class:`JointLimitExceeded` when a joint would pass its limit and
    :class:`InfeasibleGoal` when the null space allows no progress along the direction.
    """
    model = ws.model
    q = model.check_joints(start_joints_rad).copy()
    direction = np.asarray(direction_robot, dtype=np.float64)
    if direction.shape != (3,) or not np.linalg.norm(direction) > 0:
        raise InvalidInput(f"direction_robot must be a non-zero 3-vector, got {direction}")
    direction = direction / np.linalg.norm(direction)
    if not (distance_m > 0 and speed_mps > 0 and ramp_s >= 0):
        raise InvalidInput(
            f"distance {distance_m} m, speed {speed_mps} m/s and ramp {ramp_s} s must be positive"
        )
    # Duration so that the area under the speed profile is the distance.
    duration_s = distance_m / speed_mps + ramp_s
    n_steps = int(np.ceil(duration_s / dt_s))
    dt = duration_s / n_steps
    lateral = np.eye(3) - np.outer(direction, direction)
    hand0 = ws.hand_pose(State(joints_rad=q))
    start_pos, rot0 = hand0.pos_robot_m, hand0.rot_robot_from_hand
    lo, hi = model.joint_limit_rad[:, 0], model.joint_limit_rad[:, 1]

    def joint_rate(speed: float, phi: Array) -> tuple[Array, float]:
        hand_pos, hand_rot, J_m, h_bm = ws.hand_and_coupling(phi)
        basis, sing = _null_basis(h_bm)
        a_v, a_w = J_m[:3] @ basis, J_m[3:] @ basis
        a1 = direction @ a_v
        # dls(a1[None, :], [speed]) of a single row: its 1x1 solve is a division
        zeta = a1 * (speed / (float(a1 @ a1) + _DAMPING))
        p1 = np.eye(basis.shape[1]) - _row_projector(a1)  # the RNS's n - 3 dimensions
        pos_err = lateral @ (start_pos - hand_pos)
        rot_err = rotvec_from_matrix(rot0 @ hand_rot.T, assume_valid=True)
        a2 = np.vstack([lateral @ a_v, orientation_weight_m * a_w])
        b2 = np.concatenate(
            [_LATERAL_GAIN_PS * pos_err, orientation_weight_m * _ORIENTATION_GAIN_PS * rot_err]
        )
        zeta = zeta + p1 @ dls(a2 @ p1, b2 - a2 @ zeta)
        return basis @ zeta, sing

    # The hand's speed along the line at each RK4 stage's time (k dt, k dt + dt / 2, k dt +
    # dt), the profile evaluated once for them all.
    starts = np.arange(n_steps) * dt
    speeds = _speed_profile(
        np.concatenate([starts, starts + 0.5 * dt, starts + dt]), duration_s, ramp_s, speed_mps
    ).reshape(3, n_steps)
    times = [0.0]
    path = [q.copy()]
    min_sing = np.inf
    for k in range(n_steps):
        k1, s1 = joint_rate(float(speeds[0, k]), q)
        k2, _ = joint_rate(float(speeds[1, k]), q + 0.5 * dt * k1)
        k3, _ = joint_rate(float(speeds[1, k]), q + 0.5 * dt * k2)
        k4, _ = joint_rate(float(speeds[2, k]), q + dt * k3)
        q = q + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        min_sing = min(min_sing, s1)
        for i in np.flatnonzero((q < lo) | (q > hi)):
            limit = hi[i] if q[i] > hi[i] else lo[i]
            exc = JointLimitExceeded(int(i) + 1, np.degrees(q[i]), np.degrees(limit), "deg")
            along_m = float((ws.hand_pose(State(joints_rad=q)).pos_robot_m - start_pos) @ direction)
            exc.args = (
                f"reactionless: {exc.args[0]} at t = {(k + 1) * dt:.2f} s of the B->C leg "
                f"(hand {along_m:.3f} m along its line): shorten distance_m or change "
                "direction_robot",
            )
            raise exc
        times.append((k + 1) * dt)
        path.append(q.copy())
    joints = np.array(path)
    hands = [ws.hand_pose(State(joints_rad=p)) for p in joints]
    pos = np.array([h.pos_robot_m for h in hands])
    travelled = float((pos[-1] - start_pos) @ direction)
    if travelled < 0.9 * distance_m:
        raise InfeasibleGoal(
            f"reactionless: at t = {times[-1]:.2f} s (the B->C leg's end) the reaction null "
            f"space allowed only {travelled:.3f} m of the {distance_m:.3f} m along the "
            "direction: shorten distance_m or change direction_robot"
        )
    orientation = np.array([_rotation(rot0.T @ h.rot_robot_from_hand).magnitude() for h in hands])
    return ReactionlessPath(
        t_s=np.array(times),
        joints_rad=joints,
        hand_pos_robot_m=pos,
        hand_orientation_change_rad=orientation,
        min_coupling_singular_kgm2=float(min_sing),
    )


def retime_path(path: ReactionlessPath, *, scale: float, reverse: bool = False) -> Array:
    """Joint commands on the 4 Hz grid for the path run ``scale`` times slower (and
    backwards if ``reverse``): rows at ``k * COMMAND_PERIOD_S`` from 0, the last exactly at
    the path's end (the duration is rounded up to whole periods)."""
    t = path.t_s * scale
    joints = path.joints_rad[::-1] if reverse else path.joints_rad
    n = int(np.ceil(t[-1] / COMMAND_PERIOD_S - 1e-9))
    grid = np.minimum(np.arange(n + 1) * COMMAND_PERIOD_S, t[-1])
    return np.column_stack([np.interp(grid, t, joints[:, i]) for i in range(joints.shape[1])])
