"""Inertial manipulation with the generalised Jacobian in free drift (SPEC experiment 2).

Attitude control is off and the system's momentum is zero, so eq. (2) ties the base to the
arm: the system centre of mass stays where it is and the base turns at eq. (9),
``w_b = -H~_b^-1 H~_bm phi'``. The hand twist in the orbit frame (treated as inertial,
linear rows first, hand point velocity in m/s, angular velocity in rad/s) is

    x_h' = J_b x_b' + J_m phi'                       eq. (6)
    x_b' = -H_b^-1 H_bm phi'                         eq. (7), from eq. (2) with zero momentum
    x_h' = J_g phi',  J_g = J_m - J_b H_b^-1 H_bm    eq. (8)

and resolving the hand's motion through ``J_g`` (6 x n; its pseudo-inverse, damped near a
singularity, for a redundant arm) moves the hand along a line fixed in
the orbit frame while its orientation stays fixed there, whatever the base does.

The motion (our layout of the flight's): from pose A's hand point with the hand pitched
``hand_pitch_deg`` about the robot's y axis from pose A's orientation (ETS-VII: rpy (0, pitch,
0) in the robot frame, by :func:`planner.ik.solve_ik` near pose A's joints), a hold, then the
hand approaches a virtual target fixed in the orbit frame on its approach axis
(``approach_axis_hand``, hand x by default) at ``approach_distance_m``, on the quintic time
scaling of :func:`planner.ptp.quintic`; a pause; the retreat back along the same line; a hold.
Where the line cannot be followed (a singularity, the end of the reach), the failure says how
far along it the hand got.

Commands are solved on the prediction's own discrete model, so that
:func:`planner.prediction.predict` (joints linear between the 4 Hz commands, base attitude by
RK4 of eq. (9)) meets the hand pose exactly at every command time: for each command
``phi[k+1]`` a Newton iteration ``phi[k+1] += J_g^+ e`` (damped least squares near a
singularity) drives the orbit-frame pose error ``e`` of the hand at ``t[k+1]`` (position with
the system centre of mass fixed, orientation as a rotation vector) to zero, with the base
attitude at ``t[k+1]`` integrated by ``predict`` over the interval from ``phi[k]``. ``J_g`` is
evaluated at the predicted state: in the orbit frame it depends on the base attitude. Every
command aims at the absolute pose, so no error accumulates. The commands are planned at zero
momentum, as in flight; ``gravity_gradient`` adds eq. (11) to the prediction only, which then
shows the slow drift that the flight saw.

Default approach distance (our choice; the paper does not publish it): 0.22 m. It gives a
predicted base pitch excursion of -0.61 deg (flight: about -0.6 deg, SPEC 3.2) at a peak joint
rate of 2.72 deg/s (joint 3, the elbow), within the 3 deg/s limit (0.215 m gives -0.596 deg).
At 0.24 m the 20 s approach exceeds the rate limit; the elbow straightens at about 0.47 m.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from planner.attitude_control import AcsMode
from planner.dynamics import DynamicsWorkspace, Quantities
from planner.errors import DidNotConverge, InfeasibleGoal, InvalidInput, JointLimitExceeded
from planner.frames import IDENTITY_QUAT_XYZW, matrix_from_rpy, rotvec_from_matrix
from planner.gravity_gradient import Orbit
from planner.ik import solve_ik
from planner.model import arm_reach_m, default_model
from planner.plan import AcsCommand, Plan, Prediction, Segment, check_plan_limits, plan_for_robot
from planner.prediction import predict
from planner.ptp import COMMAND_PERIOD_S, quintic
from planner.state import State

if TYPE_CHECKING:
    from planner.robot import RobotDescription

__all__ = ["MAX_APPROACH_DISTANCE_M", "GjmParams", "hand_positions_orbit_m", "plan_gjm"]

Array = NDArray[np.float64]

#: A sanity bound on the parameter; the real reach (about 0.47 m from the flight's start
#: pose) is found by the planner, which raises :class:`InfeasibleGoal` beyond it.
MAX_APPROACH_DISTANCE_M = 1.0
_MAX_HAND_PITCH_DEG = 90.0

# Newton on each command: stop below 1e-11 (m and rad); fail above 1e-7 after the last try.
# The acceptance and the damping threshold are ETS-VII's, scaled for another arm by its reach
# over ETS-VII's (:func:`_robot_scale`): J_g's position rows and the hand's errors scale with it.
_NEWTON_TOL = 1e-11
_NEWTON_ACCEPT = 1e-7
_NEWTON_MAX_ITER = 8
# Damped least squares: damping grows from 0 as the smallest singular value of J_g (m or
# m/rad, mixed rows) falls below the threshold (0.29 at the default target).
_SINGULAR_THRESHOLD = 0.05
_MAX_DAMPING = 0.05


@functools.cache
def _ets7_reach_m() -> float:
    return arm_reach_m(default_model())


def _robot_scale(ws: DynamicsWorkspace) -> float:
    """The arm's reach over ETS-VII's (exactly 1 for ETS-VII)."""
    return arm_reach_m(ws.model) / _ets7_reach_m()


@dataclass(frozen=True)
class GjmParams:
    """Experiment 2's parameters; the defaults reproduce the flight (SPEC 3.2).

    Durations are in seconds and whole multiples of the 0.25 s command period; the flight
    approached at t = 680 s and retreated at t = 745 s (approach 20 s + pause 45 s).
    """

    hand_pitch_deg: float = -23.0
    approach_distance_m: float = 0.22
    approach_s: float = 20.0
    pause_s: float = 45.0
    retreat_s: float = 20.0
    lead_s: float = 5.0
    tail_s: float = 10.0
    gravity_gradient: bool = False
    #: the approach direction in the hand frame (ETS-VII's: hand x; a vendor tool's
    #: approach is usually its z)
    approach_axis_hand: tuple[float, float, float] = (1.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        axis = np.asarray(self.approach_axis_hand, dtype=np.float64)
        if axis.shape != (3,) or not np.all(np.isfinite(axis)) or not np.linalg.norm(axis) > 0:
            raise InvalidInput(
                f"approach_axis_hand must be a non-zero 3-vector, got {self.approach_axis_hand!r}"
            )
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name == "approach_axis_hand":
                continue
            if f.name == "gravity_gradient":
                if not isinstance(value, bool):
                    raise InvalidInput(f"gravity_gradient must be a bool, got {value!r}")
                continue
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise InvalidInput(f"{f.name} must be a number, got {value!r}")
            if not math.isfinite(value):
                raise InvalidInput(f"{f.name} must be finite, got {value!r}")
            if f.name.endswith("_s"):
                may_be_zero = f.name in ("lead_s", "pause_s", "tail_s")
                if value < 0.0 or (value == 0.0 and not may_be_zero):
                    least = "at least" if may_be_zero else "more than"
                    raise InvalidInput(f"{f.name} = {value} s must be {least} 0 s")
                periods = value / COMMAND_PERIOD_S
                if abs(periods - round(periods)) > 1e-9:
                    raise InvalidInput(
                        f"{f.name} = {value} s is not a multiple of the "
                        f"{COMMAND_PERIOD_S} s command period"
                    )
        if abs(self.hand_pitch_deg) > _MAX_HAND_PITCH_DEG:
            raise InvalidInput(
                f"hand_pitch_deg = {self.hand_pitch_deg} deg exceeds the limit "
                f"+-{_MAX_HAND_PITCH_DEG} deg"
            )
        if not 0.0 < self.approach_distance_m <= MAX_APPROACH_DISTANCE_M:
            raise InvalidInput(
                f"approach_distance_m = {self.approach_distance_m} m must lie in "
                f"(0, {MAX_APPROACH_DISTANCE_M}] m"
            )

    def to_dict(self) -> dict[str, Any]:
        out = dataclasses.asdict(self)
        out["approach_axis_hand"] = list(self.approach_axis_hand)
        return out


def _periods(duration_s: float) -> int:
    return round(duration_s / COMMAND_PERIOD_S)


def _hand_error(
    ws: DynamicsWorkspace, q: Array, quat: Array, pos_goal: Array, rot_goal: Array, com0: Array
) -> tuple[Array, Quantities]:
    """Orbit-frame pose error (m, rad) of the hand with the system CoM held at ``com0``."""
    quant = ws.evaluate(State(joints_rad=q, quat_orbit_from_base_xyzw=quat))
    # Eq. (2) with P = 0: the whole system shifts so that its CoM stays at com0.
    pos = quant.hand.pos_orbit_m + com0 - quant.com_orbit_m
    rot_err = rotvec_from_matrix(rot_goal @ quant.hand.rot_orbit_from_hand.T)
    return np.concatenate([pos_goal - pos, rot_err]), quant


def _dls_step(J: Array, e: Array, scale: float = 1.0) -> tuple[Array, float]:
    """``J^+ e`` by damped least squares, and J's smallest singular value (``scale``: the
    arm's reach over ETS-VII's)."""
    u, sing, vt = np.linalg.svd(J)
    sigma = float(sing[-1])
    ratio = min(sigma / (_SINGULAR_THRESHOLD * scale), 1.0)
    damping2 = (_MAX_DAMPING * scale) ** 2 * (1.0 - ratio**2)
    # J is 6 x n: for a redundant arm (n > 6) the minimum-norm step, rows of vt past the
    # sixth (J's null space) do not take part.
    return vt[: sing.size].T @ (sing / (sing**2 + damping2) * (u.T @ e)), sigma


def _rate_exceeded(ws: DynamicsWorkspace, step: Array, where: str) -> JointLimitExceeded | None:
    rate = np.abs(step) / COMMAND_PERIOD_S
    limit = ws.model.joint_rate_limit_radps
    over = np.flatnonzero(rate > limit * (1.0 + 1e-9))
    if over.size == 0:
        return None
    i = int(over[0])
    exc = JointLimitExceeded(
        i + 1, math.degrees(rate[i]), math.degrees(limit[i]), "deg/s", what="moves at"
    )
    # JointLimitExceeded formats its own message; say where and what to change after it.
    exc.args = (
        f"gjm: {exc.args[0]} {where}: shorten approach_distance_m or lengthen approach_s and "
        "retreat_s",
    )
    return exc


def _follow_line(
    ws: DynamicsWorkspace,
    q: Array,
    quat: Array,
    goals_orbit_m: Array,
    rot_goal: Array,
    com0: Array,
    t0_s: float,
    name: str,
) -> tuple[list[Array], list[Array]]:
    """Commands (and predicted base attitudes) that put the hand at ``goals_orbit_m[k]`` with
    orientation ``rot_goal`` at each command after the current one."""
    scale = _robot_scale(ws)
    tol, accept = _NEWTON_TOL, _NEWTON_ACCEPT * scale
    line_start = goals_orbit_m[0] if name == "approach" else goals_orbit_m[-1]
    joints, quats = [], []
    goal_prev = goal_prev_ok = goals_orbit_m[0]
    e, quant = _hand_error(ws, q, quat, goal_prev, rot_goal, com0)
    pair = np.zeros((2, ws.model.n_joints))
    for k, goal in enumerate(goals_orbit_m):
        t_s = t0_s + (k + 1) * COMMAND_PERIOD_S
        e[:3] += goal - goal_prev  # the current pose measured against the next goal
        goal_prev = goal
        q_next = q.copy()
        for _ in range(_NEWTON_MAX_ITER):
            step, sigma = _dls_step(quant.J_g, e, scale)
            q_next = q_next + step
            pair[0], pair[1] = q, q_next
            # The base attitude at t[k+1] exactly as predict() integrates it (eq. 9).
            quat_next = predict(
                ws, np.array([0.0, COMMAND_PERIOD_S]), pair, initial_quat_orbit_from_base_xyzw=quat
            ).quat_orbit_from_base_xyzw[1]
            e, quant = _hand_error(ws, q_next, quat_next, goal, rot_goal, com0)
            if np.max(np.abs(e)) < tol:
                break
        where = f"during the {name} at t = {t_s:.2f} s"
        if np.max(np.abs(e)) > accept:
            reached = float(np.linalg.norm(goal_prev_ok - line_start))
            raise InfeasibleGoal(
                f"gjm: {where}, the hand cannot follow its line: pose error "
                f"{np.max(np.abs(e)):.2e} (m, rad) exceeds {accept:.3g}; smallest singular "
                f"value of J_g {sigma:.3g} (damped below {_SINGULAR_THRESHOLD * scale:.3g}: a "
                f"singularity or the end of the arm's reach); the line is followed for "
                f"{reached:.3f} m from pose A: set approach_distance_m below that, or change "
                "hand_pitch_deg, approach_axis_hand or pose A"
            )
        try:
            ws.model.check_joints(q_next)
        except JointLimitExceeded as limit_exc:
            limit_exc.args = (
                f"gjm: {limit_exc.args[0]} {where}: shorten approach_distance_m or move pose A",
            )
            raise
        exc = _rate_exceeded(ws, q_next - q, where)
        if exc is not None:
            raise exc
        q, quat = q_next, quat_next
        goal_prev_ok = goal
        joints.append(q)
        quats.append(quat)
    return joints, quats


def hand_positions_orbit_m(ws: DynamicsWorkspace, prediction: Prediction) -> Array:
    """Hand point (k, 3) in the orbit frame at each predicted row with the system CoM fixed
    where it is at row 0 (eq. 2, zero momentum) and the base CoM at the origin at row 0.

    ``Prediction.hand_pos_orbit_m`` keeps the base CoM at the origin instead; in free drift
    the base translates as the arm moves (about a centimetre here).
    """
    rows = []
    com0 = np.zeros(3)
    for k, (q, quat) in enumerate(
        zip(prediction.joints_rad, prediction.quat_orbit_from_base_xyzw, strict=True)
    ):
        quant = ws.evaluate(State(joints_rad=q, quat_orbit_from_base_xyzw=quat))
        if k == 0:
            com0 = quant.com_orbit_m
        rows.append(quant.hand.pos_orbit_m + com0 - quant.com_orbit_m)
    return np.array(rows)


def _start_joints(
    ws: DynamicsWorkspace, params: GjmParams, robot: RobotDescription | None = None
) -> Array:
    """Pose A's hand point with the hand pitched: ETS-VII's all-zero pose, or ``robot``'s A.

    The hand is turned by ``hand_pitch_deg`` about the robot's y axis from pose A's
    orientation (its written ``hand_rpy_deg``, else where its joints put the hand): ETS-VII's
    and Orihime's pose A hold the hand parallel to the robot frame, so for them this is the
    hand at rpy (0, pitch, 0).
    """
    pitch = matrix_from_rpy(np.radians([0.0, params.hand_pitch_deg, 0.0]))
    if robot is None:
        hand_pos, reference = ws.model.hand_pos_robot_m, np.zeros(ws.model.n_joints)
        rot = pitch
    else:
        reference = robot.target_joints_rad("A", ws, experiment="gjm")
        hand = ws.hand_pose(State(joints_rad=reference))
        hand_pos = hand.pos_robot_m
        written = robot.poses["A"].rot_robot_from_hand
        rot = pitch @ (hand.rot_robot_from_hand if written is None else written)
    try:
        solutions = solve_ik(ws, hand_pos, rot, reference_joints_rad=reference, n_starts=4)
    except DidNotConverge as exc:
        raise InfeasibleGoal(
            f"gjm: at t = 0 s, no joint angles within limits put the hand at pose A pitched "
            f"{params.hand_pitch_deg} deg: change hand_pitch_deg or pose A"
        ) from exc
    return solutions[0].joints_rad


def _metrics(
    ws: DynamicsWorkspace, params: GjmParams, prediction: Prediction, joints: Array
) -> dict[str, float]:
    rot_base = Rotation.from_quat(prediction.quat_orbit_from_base_xyzw)
    rot_hand = Rotation.from_quat(prediction.quat_orbit_from_hand_xyzw)
    pitch = prediction.rpy_base_rad[:, 1] - prediction.rpy_base_rad[0, 1]
    pos = hand_positions_orbit_m(ws, prediction)
    approach_hand = np.asarray(params.approach_axis_hand, dtype=np.float64)
    axis = rot_hand[0].as_matrix() @ (approach_hand / np.linalg.norm(approach_hand))
    along = (pos - pos[0]) @ axis
    off_line = pos - pos[0] - np.outer(along, axis)
    rates = np.abs(np.diff(joints, axis=0)) / COMMAND_PERIOD_S
    return {
        "base_pitch_change_deg": math.degrees(float(pitch[np.argmax(np.abs(pitch))])),
        "base_attitude_change_deg": math.degrees(
            float(np.max((rot_base[0].inv() * rot_base).magnitude()))
        ),
        "hand_orientation_max_deviation_deg": math.degrees(
            float(np.max((rot_hand[0].inv() * rot_hand).magnitude()))
        ),
        "hand_line_max_deviation_m": float(np.max(np.linalg.norm(off_line, axis=1))),
        "hand_max_travel_m": float(np.max(along)),
        "approach_distance_m": params.approach_distance_m,
        "max_joint_rate_degps": math.degrees(float(np.max(rates))) if rates.size else 0.0,
    }


def plan_gjm(
    ws: DynamicsWorkspace,
    params: GjmParams = GjmParams(),
    *,
    robot: RobotDescription | None = None,
) -> Plan:
    """Experiment 2's plan (see the module docstring): 4 Hz commands from t = 0, segments
    ``lead``, ``approach``, ``pause``, ``retreat``, ``tail``, the free-drift prediction and
    metrics (degrees and metres at this edge).

    Raises :class:`JointLimitExceeded` when a joint would leave its angle or rate limit and
    :class:`InfeasibleGoal` when the hand cannot follow its line (out of reach, singular).
    The start is pose A of ``robot`` (``None``: ETS-VII's) with the hand pitched.
    """
    if robot is not None and robot.model.n_joints != ws.model.n_joints:
        raise InvalidInput(
            f"the workspace's model has {ws.model.n_joints} joints, robot {robot.name!r} "
            f"{robot.model.n_joints}"
        )
    q0 = _start_joints(ws, params, robot)
    start = ws.evaluate(State(joints_rad=q0))
    rot_goal = start.hand.rot_orbit_from_hand
    approach_hand = np.asarray(params.approach_axis_hand, dtype=np.float64)
    pos0 = start.hand.pos_orbit_m
    axis = rot_goal @ (approach_hand / np.linalg.norm(approach_hand))
    layout = (
        ("lead", "hold", params.lead_s),
        ("approach", "gjm", params.approach_s),
        ("pause", "hold", params.pause_s),
        ("retreat", "gjm", params.retreat_s),
        ("tail", "hold", params.tail_s),
    )
    joints, quats = [q0], [IDENTITY_QUAT_XYZW.copy()]
    segments = []
    t_s = 0.0
    for name, kind, duration_s in layout:
        n = _periods(duration_s)
        if kind == "hold":
            # Zero momentum and still joints: the base stays still too.
            joints += [joints[-1]] * n
            quats += [quats[-1]] * n
        else:
            s = quintic(np.arange(1, n + 1) / n)
            travel = s if name == "approach" else 1.0 - s
            goals = pos0 + np.outer(travel * params.approach_distance_m, axis)
            more_q, more_quat = _follow_line(
                ws, joints[-1], quats[-1], goals, rot_goal, start.com_orbit_m, t_s, name
            )
            joints += more_q
            quats += more_quat
        segments.append(Segment(name, kind, t_s, t_s + n * COMMAND_PERIOD_S))
        t_s += n * COMMAND_PERIOD_S
    command_joints = np.array(joints)
    times = np.asarray(np.arange(len(joints)) * COMMAND_PERIOD_S, dtype=np.float64)
    acs = (AcsCommand(0.0, AcsMode.FREE_DRIFT),)
    prediction = predict(
        ws,
        times,
        command_joints,
        acs_commands=acs,
        orbit=Orbit() if params.gravity_gradient else None,
    )
    plan = Plan(
        experiment="gjm",
        parameters=params.to_dict(),
        initial_joints_rad=q0,
        command_times_s=times,
        command_joints_rad=command_joints,
        segments=tuple(segments),
        prediction=prediction,
        metrics=_metrics(ws, params, prediction, command_joints),
        acs_commands=acs,
    )
    check_plan_limits(ws.model, plan)
    return plan_for_robot(plan, robot)
