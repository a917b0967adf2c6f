"""Experiment 1 of SPEC section 3: the PTP baseline and reactionless manipulation, as plans.

- :func:`plan_ptp`: conventional joint-interpolated PTP from A to B with wheel feedback on,
  then a settling wait (the baseline with a large reaction; flight: about 100 s to settle).
- :func:`plan_reactionless`: from B, the hand about 0.35 m toward +z (robot frame) at
  0.015 m/s in the reaction null space, a pause, then back at 0.0075 m/s (the same path
  retraced), wheel feedback on. Optionally pre-shaped for the servos' lag.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from planner._builder import CommandBuilder
from planner.attitude_control import AcsGains, AcsMode, default_acs_gains
from planner.coordination import REPORT_SETTLE_BAND_DEG
from planner.dynamics import DynamicsWorkspace
from planner.errors import InfeasibleGoal, InvalidInput
from planner.frames import matrix_from_rpy
from planner.ik import solve_ik
from planner.plan import AcsCommand, Plan, plan_for_robot
from planner.prediction import predict
from planner.ptp import COMMAND_PERIOD_S, ptp_commands
from planner.reactionless import reactionless_line, retime_path
from planner.servo_compensation import compensate_servo_lag
from planner.simulation import default_servo_gains

if TYPE_CHECKING:
    from planner.robot import RobotDescription

__all__ = [
    "POSE_B_POS_ROBOT_M",
    "POSE_B_RPY_DEG",
    "PtpParams",
    "ReactionlessParams",
    "attitude_metrics",
    "check_robot",
    "joints_at_pose_b",
    "plan_ptp",
    "plan_reactionless",
]

Array = NDArray[np.float64]

#: SPEC 1.2: pose B, 0.15 m above the grapple point.
POSE_B_POS_ROBOT_M = (1.170, 0.407, 0.490)
POSE_B_RPY_DEG = (0.0, 90.0, -37.0)


def _check_period(name: str, value: float) -> None:
    n = round(value / COMMAND_PERIOD_S)
    if not np.isfinite(value) or value < 0 or abs(n * COMMAND_PERIOD_S - value) > 1e-9:
        raise InvalidInput(f"{name} = {value} s must be a non-negative multiple of 0.25 s")


def joints_at_pose_b(ws: DynamicsWorkspace) -> Array:
    """IK solution for ETS-VII's pose B nearest the all-zero pose."""
    rot = matrix_from_rpy(np.radians(POSE_B_RPY_DEG))
    return solve_ik(ws, np.array(POSE_B_POS_ROBOT_M), rot)[0].joints_rad


def check_robot(ws: DynamicsWorkspace, robot: RobotDescription | None) -> None:
    """The workspace must be the robot's model (the joint count at least)."""
    if robot is not None and ws.model.n_joints != robot.model.n_joints:
        raise InvalidInput(
            f"the workspace's model has {ws.model.n_joints} joints, robot {robot.name!r} "
            f"{robot.model.n_joints}"
        )


def _pose(
    ws: DynamicsWorkspace, robot: RobotDescription | None, name: str, experiment: str
) -> Array:
    """A named pose's joints: the robot's, or ETS-VII's built-in A (all zero) and B (IK)."""
    if robot is not None:
        return robot.target_joints_rad(name, ws, experiment=experiment)
    if name == "A":
        return np.zeros(ws.model.n_joints)
    return joints_at_pose_b(ws)


def _joints_param(ws: DynamicsWorkspace, name: str, values: tuple[float, ...]) -> Array:
    if len(values) != ws.model.n_joints:
        raise InvalidInput(
            f"parameter {name} has {len(values)} angles; the robot has {ws.model.n_joints} joints"
        )
    return ws.model.check_joints(np.radians(values))


def attitude_metrics(plan_t_s: Array, quats_xyzw: Array, *, band_deg: float) -> dict[str, float]:
    """Peak attitude excursion and the last time it was outside ``band_deg``."""
    from scipy.spatial.transform import Rotation

    angle_deg = np.degrees(Rotation.from_quat(quats_xyzw).magnitude())
    outside = np.flatnonzero(angle_deg > band_deg)
    return {
        "peak_attitude_deg": float(np.max(angle_deg)),
        "final_attitude_deg": float(angle_deg[-1]),
        "last_outside_band_s": float(plan_t_s[outside[-1]]) if outside.size else 0.0,
        "settle_band_deg": band_deg,
    }


@dataclass(frozen=True)
class PtpParams:
    #: ETS-VII's pose A; a robot of another joint count sets its own (its description's
    #: [experiments.ptp] table), or the plan is refused. None: the robot's pose A (what a
    #: description without one gets: docs/robots.md, "Experiment defaults").
    start_joints_deg: tuple[float, ...] | None = (0.0,) * 6
    goal_joints_deg: tuple[float, ...] | None = None  # None: pose B (ETS-VII: by IK)
    rate_fraction: float = 0.9
    settle_s: float = 120.0
    acs_feedback: bool = True
    settle_band_deg: float = REPORT_SETTLE_BAND_DEG


def plan_ptp(
    ws: DynamicsWorkspace,
    params: PtpParams = PtpParams(),
    gains: AcsGains | None = None,
    *,
    robot: RobotDescription | None = None,
) -> Plan:
    """Experiment 1's baseline: PTP A -> B, then a settling wait. The poses are ``robot``'s
    (``None``: ETS-VII's built-in A and B) unless the parameters give joints."""
    model = ws.model
    check_robot(ws, robot)
    _check_period("settle_s", params.settle_s)
    start = (
        _pose(ws, robot, "A", "ptp")
        if params.start_joints_deg is None
        else _joints_param(ws, "start_joints_deg", params.start_joints_deg)
    )
    goal = (
        _pose(ws, robot, "B", "ptp")
        if params.goal_joints_deg is None
        else _joints_param(ws, "goal_joints_deg", params.goal_joints_deg)
    )
    _, move = ptp_commands(model, start, goal, rate_fraction=params.rate_fraction)
    builder = CommandBuilder(start)
    t0, t1 = builder.block(move, "A->B", "ptp")
    builder.hold(params.settle_s, "settle", "settle")
    times, joints = builder.arrays()
    gains = gains or (robot.acs_gains(ws) if robot is not None else default_acs_gains(ws))
    mode = AcsMode.FEEDBACK if params.acs_feedback else AcsMode.FREE_DRIFT
    acs = (AcsCommand(0.0, mode),)
    prediction = predict(ws, times, joints, acs_commands=acs, acs_gains=gains)
    metrics = attitude_metrics(
        times, prediction.quat_orbit_from_base_xyzw, band_deg=params.settle_band_deg
    )
    metrics["settling_time_after_motion_s"] = max(0.0, metrics["last_outside_band_s"] - t1)
    metrics["motion_duration_s"] = t1 - t0
    plan = builder.plan(
        model,
        experiment="ptp",
        parameters={
            **asdict(params),
            "start_joints_deg": np.degrees(start).tolist(),
            "goal_joints_deg": np.degrees(goal).tolist(),
        },
        prediction=prediction,
        metrics=metrics,
        acs_commands=acs,
    )
    return plan_for_robot(plan, robot)


def _check_hand_on_line(
    params: ReactionlessParams, t_s: Array, off_line_m: Array, turned_rad: Array
) -> None:
    """The B -> C leg within its tolerances: the hand's distance from its line and its turn."""
    lateral_limit_m = (
        0.3 * params.distance_m if params.max_hand_lateral_m is None else params.max_hand_lateral_m
    )
    k = int(np.argmax(off_line_m))
    if off_line_m[k] > lateral_limit_m:
        raise InfeasibleGoal(
            f"reactionless: at t = {t_s[k]:.2f} s of the B->C leg the hand is "
            f"{off_line_m[k]:.3f} m off its line, more than max_hand_lateral_m = "
            f"{lateral_limit_m:.3f} m: lower orientation_weight_m (the line held tighter, the "
            "hand turned more), shorten distance_m or change direction_robot"
        )
    k = int(np.argmax(turned_rad))
    turned_deg = float(np.degrees(turned_rad[k]))
    if turned_deg > params.max_hand_orientation_change_deg:
        raise InfeasibleGoal(
            f"reactionless: at t = {t_s[k]:.2f} s of the B->C leg the hand has turned "
            f"{turned_deg:.1f} deg, more than max_hand_orientation_change_deg = "
            f"{params.max_hand_orientation_change_deg:g} deg: raise orientation_weight_m (the "
            "hand held steadier, the line looser), shorten distance_m or change direction_robot"
        )


@dataclass(frozen=True)
class ReactionlessParams:
    start_joints_deg: tuple[float, ...] | None = None  # None: pose B
    direction_robot: tuple[float, float, float] = (0.0, 0.0, 1.0)
    distance_m: float = 0.35
    out_speed_mps: float = 0.015
    back_speed_mps: float = 0.0075
    ramp_s: float = 2.0
    orientation_weight_m: float = 0.3
    pause_s: float = 10.0
    tail_s: float = 30.0
    compensate_servo_lag: bool = False
    settle_band_deg: float = REPORT_SETTLE_BAND_DEG
    #: how far the hand may leave its line (m; None: 0.3 of distance_m) and turn (deg) on
    #: the way out (ETS-VII's: 0.090 m and 14.7 deg)
    max_hand_lateral_m: float | None = None
    max_hand_orientation_change_deg: float = 30.0


def plan_reactionless(
    ws: DynamicsWorkspace,
    params: ReactionlessParams = ReactionlessParams(),
    gains: AcsGains | None = None,
    *,
    robot: RobotDescription | None = None,
) -> Plan:
    """Experiment 1: B -> C reactionless at the outbound speed, pause, C -> B retraced.
    Pose B is ``robot``'s (``None``: ETS-VII's) unless ``start_joints_deg`` is given; the
    reaction null space has n - 3 dimensions (at least one: 4 joints)."""
    model = ws.model
    check_robot(ws, robot)
    if model.n_joints < 4:
        raise InvalidInput(
            f"reactionless: a {model.n_joints}-joint arm has no reaction null space "
            "(n - 3 dimensions; at least 4 joints needed)"
        )
    for name in ("pause_s", "tail_s"):
        _check_period(name, getattr(params, name))
    if params.max_hand_lateral_m is not None and not params.max_hand_lateral_m > 0:
        raise InvalidInput(
            f"max_hand_lateral_m = {params.max_hand_lateral_m} m must be positive (or none)"
        )
    if not params.max_hand_orientation_change_deg > 0:
        raise InvalidInput(
            f"max_hand_orientation_change_deg = {params.max_hand_orientation_change_deg} deg "
            "must be positive"
        )
    if not (params.out_speed_mps > 0 and params.back_speed_mps > 0):
        raise InvalidInput(
            f"speeds must be positive, got {params.out_speed_mps} and {params.back_speed_mps} m/s"
        )
    start = (
        _pose(ws, robot, "B", "reactionless")
        if params.start_joints_deg is None
        else _joints_param(ws, "start_joints_deg", params.start_joints_deg)
    )
    path = reactionless_line(
        ws,
        start,
        direction_robot=np.array(params.direction_robot),
        distance_m=params.distance_m,
        speed_mps=params.out_speed_mps,
        ramp_s=params.ramp_s,
        orientation_weight_m=params.orientation_weight_m,
    )
    out = retime_path(path, scale=1.0)
    back = retime_path(path, scale=params.out_speed_mps / params.back_speed_mps, reverse=True)
    builder = CommandBuilder(start)
    out_t = builder.block(out, "B->C", "reactionless")
    builder.hold(params.pause_s, "pause at C")
    back_t = builder.block(back, "C->B", "reactionless")
    builder.hold(params.tail_s, "hold at B")
    times, desired = builder.arrays()
    joints = desired
    if params.compensate_servo_lag:
        servo = robot.servo_gains() if robot is not None else default_servo_gains(model)
        joints = compensate_servo_lag(ws, servo, times, desired)
    gains = gains or (robot.acs_gains(ws) if robot is not None else default_acs_gains(ws))
    acs = (AcsCommand(0.0, AcsMode.FEEDBACK),)
    prediction = predict(ws, times, desired, acs_commands=acs, acs_gains=gains)
    hand = path.hand_pos_robot_m - path.hand_pos_robot_m[0]
    direction = np.array(params.direction_robot) / np.linalg.norm(params.direction_robot)
    lateral = hand - np.outer(hand @ direction, direction)
    metrics = attitude_metrics(
        times, prediction.quat_orbit_from_base_xyzw, band_deg=params.settle_band_deg
    )
    off_line_m = np.linalg.norm(lateral, axis=1)
    _check_hand_on_line(params, path.t_s, off_line_m, path.hand_orientation_change_rad)
    metrics.update(
        {
            "hand_travel_m": float(hand[-1] @ direction),
            "hand_lateral_max_m": float(np.max(np.linalg.norm(lateral, axis=1))),
            "hand_orientation_change_max_deg": float(
                np.degrees(np.max(path.hand_orientation_change_rad))
            ),
            "min_coupling_singular_kgm2": path.min_coupling_singular_kgm2,
            "out_duration_s": out_t[1] - out_t[0],
            "back_duration_s": back_t[1] - back_t[0],
            "max_reaction_momentum_nms": float(
                np.max(np.linalg.norm(prediction.reaction_momentum_orbit_nms, axis=1))
            ),
        }
    )
    plan = builder.plan(
        model,
        experiment="reactionless",
        parameters={**asdict(params), "start_joints_deg": np.degrees(start).tolist()},
        prediction=prediction,
        metrics=metrics,
        acs_commands=acs,
        joints_rad=joints,
    )
    return plan_for_robot(plan, robot)
