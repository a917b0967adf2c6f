"""A plan checked against the flight rules: :func:`check_plan` gives one
:class:`~planner.flight_rules.RuleRow` per rule of :class:`~planner.flight_rules.FlightRules`.

What is checked is what the vehicle will fly, not only the 4 Hz commands: the joints as the
servos follow them (:func:`planner.servo_response.servo_response`), on a fine grid whose
every sample's clearance is exact (:mod:`planner.clearance_sampling`, which says why nothing
between the samples is missed). Clearance is two rules: the arm against the base and its
equipment, and the arm's links against each other.

The other rules read the plan's prediction (planner.prediction: attitude, wheel momentum, at
the command times) and the servo response (joint-limit margin and hand speed, relative to
the base, on the fine grid).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from planner.attitude_control import AcsMode
from planner.clearance_sampling import (
    SampledClearance,
    joint_paths,
    sample_step_s,
    sampled_clearance,
)
from planner.collision import CollisionModel, body_poses, check_collision_model
from planner.errors import InvalidInput
from planner.flight_rules import (
    ClearanceTrace,
    FlightRules,
    FlightRulesReport,
    RuleRow,
    fits_pass_row,
)
from planner.frames import matrix_from_quat_xyzw
from planner.model import RobotModel
from planner.plan import Plan
from planner.ptp import COMMAND_PERIOD_S
from planner.servo_response import ServoModel, servo_response

__all__ = ["check_plan"]

Array = NDArray[np.float64]


def check_plan(
    plan: Plan,
    model: RobotModel,
    collision: CollisionModel | None,
    rules: FlightRules,
    *,
    servo: ServoModel,
    wheel_momentum_limits_nms: Sequence[float],
    window_s: float | None = None,
    robot: str = "",
) -> FlightRulesReport:
    """Every rule's row on ``plan``'s predicted motion (module docstring). ``window_s``: the
    window of the pass the plan is for (None: the rules' ``pass_window_s``; no
    ``fits_pass`` row when neither is known). Raises :class:`InvalidInput` when the robot
    has no collision geometry to show the plan clear with."""
    collision = check_collision_model(collision, robot or plan.robot)
    n = model.n_joints
    if plan.command_joints_rad.shape[1] != n:
        raise InvalidInput(
            f"the plan has {plan.command_joints_rad.shape[1]} joints; robot {robot!r} has {n}"
        )
    step = sample_step_s(model, collision, rules.min_clearance_m)
    per_period = round(COMMAND_PERIOD_S / step)
    t0 = float(plan.command_times_s[0])
    count = (plan.command_times_s.size - 1) * per_period + 1
    times: Array = t0 + np.arange(count, dtype=np.float64) * step
    joints, rates = servo_response(
        servo, plan.command_times_s, plan.command_joints_rad, plan.initial_joints_rad, times
    )
    R, t = body_poses(model, joints)

    path = joint_paths(servo, plan, step, joints, rates)
    rows: list[RuleRow] = []
    per_sample = np.full(count, np.inf)
    queries = 0
    groups = (
        ("clearance", "the arm against the base and its equipment", True),
        ("self_clearance", "arm links against each other", False),
    )
    for rule, what, spacecraft in groups:
        pairs = [
            p
            for p in collision.pairs
            if (collision.bodies[p[0]].is_equipment or collision.bodies[p[1]].is_equipment)
            == spacecraft
        ]
        if not pairs:
            continue
        found = sampled_clearance(collision, pairs, R, t, path, model)
        rows.append(_clearance_row(rule, collision, found, times, rules.min_clearance_m, what))
        per_sample = np.minimum(per_sample, found.per_sample_m)
        queries += found.queries
    k = plan.command_times_s.size
    trace = [float(per_sample[0])]
    for i in range(1, k):
        trace.append(float(per_sample[(i - 1) * per_period + 1 : i * per_period + 1].min()))
    rows += [
        *_attitude_rows(plan, rules),
        _wheel_row(plan, model, wheel_momentum_limits_nms, rules),
        _joint_margin_row(model, times, joints, rules),
        _hand_speed_row(model, times, R, t, rules),
    ]
    window = window_s if window_s is not None else rules.pass_window_s
    if window is not None:
        rows.append(fits_pass_row(plan.duration_s, window))
    return FlightRulesReport(
        rows=tuple(rows),
        step_s=step,
        n_samples=count,
        n_pairs=len(collision.pairs),
        n_queries=queries,
        clearance=ClearanceTrace(tuple(float(v) for v in plan.command_times_s), tuple(trace)),
        robot=robot or plan.robot,
    )


def _clearance_row(
    rule: str,
    collision: CollisionModel,
    found: SampledClearance,
    times: Array,
    limit_m: float,
    what: str,
) -> RuleRow:
    a, b = found.worst_pair
    n_pairs = sum(
        1
        for p in collision.pairs
        if (collision.bodies[p[0]].is_equipment or collision.bodies[p[1]].is_equipment)
        == (rule == "clearance")
    )
    return RuleRow(
        rule=rule,
        value=found.worst_m,
        limit=limit_m,
        unit="m",
        bound="min",
        passed=found.worst_m >= limit_m,
        t_s=float(times[found.worst_sample]),
        bodies=(collision.bodies[a].name, collision.bodies[b].name),
        points_robot_m=(found.nearest.point_a_robot_m, found.nearest.point_b_robot_m),
        detail=f"{what}: {n_pairs} pairs",
    )


def _attitude_rows(plan: Plan, rules: FlightRules) -> list[RuleRow]:
    """The largest predicted rotation of the base, per attitude mode: from the plan's
    initial attitude in free drift, from the commanded target in feedback."""
    prediction = plan.prediction
    commands = sorted(plan.acs_commands, key=lambda c: c.t_s)
    initial = matrix_from_quat_xyzw(plan.initial_quat_orbit_from_base_xyzw)
    worst: dict[str, tuple[float, float]] = {}
    for t_s, quat in zip(prediction.t_s, prediction.quat_orbit_from_base_xyzw, strict=True):
        mode, reference = AcsMode.FREE_DRIFT.value, initial
        for c in commands:
            if c.t_s <= t_s + 1e-9:
                mode = c.mode.value
                reference = (
                    initial
                    if c.mode is AcsMode.FREE_DRIFT
                    else matrix_from_quat_xyzw(c.target_quat_orbit_from_base_xyzw)
                )
        relative = reference.T @ matrix_from_quat_xyzw(quat)
        cos = (float(np.trace(relative)) - 1.0) / 2.0
        angle = math.degrees(math.acos(min(1.0, max(-1.0, cos))))
        if mode not in worst or angle > worst[mode][0]:
            worst[mode] = (angle, float(t_s))
    rows = []
    for mode in (AcsMode.FEEDBACK.value, AcsMode.FREE_DRIFT.value):
        if mode not in worst:
            continue
        angle, when = worst[mode]
        limit = rules.max_attitude_excursion_deg[mode]
        rows.append(
            RuleRow(
                rule=f"attitude_excursion_{mode}",
                value=angle,
                limit=limit,
                unit="deg",
                bound="max",
                passed=angle <= limit,
                t_s=when,
                detail="from the target" if mode == AcsMode.FEEDBACK.value else "from the start",
            )
        )
    return rows


def _wheel_row(
    plan: Plan, model: RobotModel, limits_nms: Sequence[float], rules: FlightRules
) -> RuleRow:
    h = np.asarray(plan.prediction.wheel_momentum_nms, dtype=np.float64)
    axes = np.array([w.axis_base for w in model.wheels]) if model.wheels else np.zeros((0, 3))
    if axes.shape[0] == 0 or h.size == 0:
        fraction, when, wheel = 0.0, None, -1
    else:
        per_wheel = np.abs(h @ axes.T) / np.asarray(limits_nms, dtype=np.float64)
        k, w = np.unravel_index(int(np.argmax(per_wheel)), per_wheel.shape)
        wheel = int(w)
        fraction, when = float(per_wheel[k, wheel]), float(plan.prediction.t_s[k])
    return RuleRow(
        rule="wheel_momentum",
        value=fraction,
        limit=rules.max_wheel_momentum_fraction,
        unit="of limit",
        bound="max",
        passed=fraction <= rules.max_wheel_momentum_fraction,
        t_s=when,
        detail="" if wheel < 0 else f"wheel {int(wheel) + 1}",
    )


def _joint_margin_row(
    model: RobotModel, times: Array, joints: Array, rules: FlightRules
) -> RuleRow:
    lo, hi = model.joint_limit_rad[:, 0], model.joint_limit_rad[:, 1]
    margin = np.degrees(np.minimum(joints - lo, hi - joints))
    s, k = np.unravel_index(int(np.argmin(margin)), margin.shape)
    value = float(margin[s, k])
    return RuleRow(
        rule="joint_limit_margin",
        value=value,
        limit=rules.joint_limit_margin_deg,
        unit="deg",
        bound="min",
        passed=value >= rules.joint_limit_margin_deg,
        t_s=float(times[s]),
        detail=f"joint {int(k) + 1}",
    )


def _hand_speed_row(
    model: RobotModel, times: Array, R: Array, t: Array, rules: FlightRules
) -> RuleRow:
    hand = np.einsum("sab,b->sa", R[:, -1], model.hand_pos_robot_m) + t[:, -1]
    if times.size < 2:
        value, when = 0.0, float(times[0])
    else:
        speed = np.linalg.norm(np.diff(hand, axis=0), axis=1) / np.diff(times)
        k = int(np.argmax(speed))
        value, when = float(speed[k]), float(times[k + 1])
    return RuleRow(
        rule="hand_speed",
        value=value,
        limit=rules.max_hand_speed_mps,
        unit="m/s",
        bound="max",
        passed=value <= rules.max_hand_speed_mps,
        t_s=when,
        detail="relative to the base",
    )
