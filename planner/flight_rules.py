"""Flight rules: a plan may leave the ground only when its predicted motion keeps every rule.

The paper's arm motions were "verified collision-free by simulator before uplink" (3.1).
:func:`check_plan` evaluates a plan against a robot description's ``[flight_rules]``
(:class:`FlightRules`, docs/robots.md) and gives one :class:`RuleRow` per rule: the worst
value, the limit, the verdict and when the worst value happens (for clearance, the two
bodies and their nearest points).

What is checked is what the vehicle will fly, not only the 4 Hz commands:

* **The joints as the servos follow them.** Each joint's PD servo on its own inertia at the
  reference pose, ``H_ii q'' = kp (q_c - q) - kd q'`` (the vehicle's servo law, decoupled),
  driven by the commands linear between their times (as on board), solved exactly on a
  fine grid (:func:`servo_response`, scipy's ``lsim`` with first-order hold).
* **A fine grid.** The step ``h`` divides the 0.25 s command period so that no point of the
  arm moves more than half the minimum clearance between two samples at the joints' rate
  limits: ``h * sum_k rate_k * rho_k <= min_clearance / 2``, ``rho_k`` a bound on the
  distance from joint k to any point of the bodies it moves (:func:`planner.collision.
  reach_bounds`). Any instant is within ``h / 2`` of a sample, so the clearance flown is at
  least the smallest sampled clearance less ``min_clearance / 4``: a plan that passes never
  brings two bodies closer than three quarters of the minimum clearance, and never into
  contact. (The commands are checked against the rate limits first; a servo overshoots its
  command's rate by no more than its damping allows, counted in the per-step bounds below.)
* **Every sample's exact minimum, cheaply.** A pair's distance can shrink between two samples
  by no more than the path its bodies travel relative to each other (``sum_k |dq_k| rho_k``
  over the joints between them). Each pair keeps its last exact distance less the path since
  (a lower bound); at each sample coal is asked only for pairs whose bound is below the best
  exact distance found so far, nearest bound first. While the arm holds still nothing is
  asked at all.

The other rules read the plan's prediction (planner.prediction: attitude, wheel momentum, at
the command times) and the servo response (joint-limit margin and hand speed, relative to
the base, on the fine grid).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.attitude_control import AcsMode
from planner.collision import (
    CollisionModel,
    PairDistance,
    ShapeSet,
    body_poses,
    check_collision_model,
    reach_bounds,
)
from planner.errors import InvalidInput
from planner.frames import matrix_from_quat_xyzw
from planner.model import RobotModel
from planner.plan import Plan
from planner.ptp import COMMAND_PERIOD_S

__all__ = [
    "RULE_NAMES",
    "ClearanceTrace",
    "FlightRules",
    "FlightRulesReport",
    "RuleRow",
    "SampledClearance",
    "ServoModel",
    "check_plan",
    "fits_pass_row",
    "sample_step_s",
    "sampled_clearance",
    "servo_response",
]

Array = NDArray[np.float64]

#: Every rule a report may hold, in the order of its rows.
RULE_NAMES = (
    "clearance",
    "self_clearance",
    "attitude_excursion_feedback",
    "attitude_excursion_free_drift",
    "wheel_momentum",
    "joint_limit_margin",
    "hand_speed",
    "fits_pass",
)

#: The most samples per command period (a robot so fast or so large that more would be
#: needed is refused: its rates or its clearance should be looked at).
MAX_SAMPLES_PER_PERIOD = 64


@dataclass(frozen=True)
class FlightRules:
    """A description's ``[flight_rules]`` (docs/robots.md); SPEC 8's numbers by default."""

    min_clearance_m: float = 0.10
    max_attitude_excursion_deg: Mapping[str, float] = field(
        default_factory=lambda: {"feedback": 2.0, "free_drift": 2.0}
    )
    max_wheel_momentum_fraction: float = 0.8
    joint_limit_margin_deg: float = 2.0
    max_hand_speed_mps: float = 0.10
    pass_window_s: float | None = None

    def __post_init__(self) -> None:
        for name in ("min_clearance_m", "max_wheel_momentum_fraction", "max_hand_speed_mps"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise InvalidInput(f"flight rule {name} must be > 0, got {value!r}")
        if not (math.isfinite(self.joint_limit_margin_deg) and self.joint_limit_margin_deg >= 0):
            raise InvalidInput(
                "flight rule joint_limit_margin_deg must be >= 0, got "
                f"{self.joint_limit_margin_deg!r}"
            )
        modes = {m.value for m in AcsMode}
        if set(self.max_attitude_excursion_deg) != modes:
            raise InvalidInput(
                "flight rule max_attitude_excursion_deg needs a limit for each mode "
                f"{sorted(modes)}, got {sorted(self.max_attitude_excursion_deg)}"
            )
        for mode, value in self.max_attitude_excursion_deg.items():
            if not (math.isfinite(value) and value > 0.0):
                raise InvalidInput(
                    f"flight rule max_attitude_excursion_deg.{mode} must be > 0, got {value!r}"
                )
        if self.pass_window_s is not None and not (
            math.isfinite(self.pass_window_s) and self.pass_window_s > 0.0
        ):
            raise InvalidInput(f"flight rule pass_window_s must be > 0, got {self.pass_window_s!r}")

    def to_dict(self) -> dict[str, Any]:
        return {
            "min_clearance_m": self.min_clearance_m,
            "max_attitude_excursion_deg": dict(self.max_attitude_excursion_deg),
            "max_wheel_momentum_fraction": self.max_wheel_momentum_fraction,
            "joint_limit_margin_deg": self.joint_limit_margin_deg,
            "max_hand_speed_mps": self.max_hand_speed_mps,
            "pass_window_s": self.pass_window_s,
        }


@dataclass(frozen=True)
class RuleRow:
    """One rule on one plan. ``bound`` "min": the value must be at least ``limit``; "max": at
    most. ``t_s``: when the worst value happens (s from the plan's start; None where the rule
    has no time). Clearance only: ``bodies`` and the nearest ``points_robot_m`` (robot frame:
    origin at joint 1, base axes)."""

    rule: str
    value: float
    limit: float
    unit: str
    bound: str
    passed: bool
    t_s: float | None = None
    bodies: tuple[str, str] | None = None
    points_robot_m: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    detail: str = ""

    @property
    def verdict(self) -> str:
        return "pass" if self.passed else "fail"

    def to_dict(self) -> dict[str, Any]:
        return {
            "rule": self.rule,
            "value": self.value,
            "limit": self.limit,
            "unit": self.unit,
            "bound": self.bound,
            "verdict": self.verdict,
            "t_s": self.t_s,
            "bodies": None if self.bodies is None else list(self.bodies),
            "points_robot_m": None
            if self.points_robot_m is None
            else [list(p) for p in self.points_robot_m],
            "detail": self.detail,
        }

    @classmethod
    def from_dict(cls, doc: Mapping[str, Any]) -> RuleRow:
        bodies = doc.get("bodies")
        points = doc.get("points_robot_m")
        return cls(
            rule=str(doc["rule"]),
            value=float(doc["value"]),
            limit=float(doc["limit"]),
            unit=str(doc["unit"]),
            bound=str(doc["bound"]),
            passed=doc["verdict"] == "pass",
            t_s=None if doc.get("t_s") is None else float(doc["t_s"]),
            bodies=None if bodies is None else (str(bodies[0]), str(bodies[1])),
            points_robot_m=None
            if points is None
            else (
                (float(points[0][0]), float(points[0][1]), float(points[0][2])),
                (float(points[1][0]), float(points[1][1]), float(points[1][2])),
            ),
            detail=str(doc.get("detail", "")),
        )

    def describe(self) -> str:
        """One line for an error message."""
        where = "" if self.t_s is None else f" at t = {self.t_s:.2f} s"
        pair = "" if self.bodies is None else f" between {self.bodies[0]} and {self.bodies[1]}"
        relation = ">=" if self.bound == "min" else "<="
        return (
            f"{self.rule}: {self.value:.4g} {self.unit}{pair}{where}, must be {relation} "
            f"{self.limit:.4g} {self.unit}"
        )


@dataclass(frozen=True)
class ClearanceTrace:
    """The smallest clearance over every checked pair, per command period: ``min_m[k]`` is
    the least over the fine samples in ``(t_s[k-1], t_s[k]]`` (``t_s[0]``: that instant)."""

    t_s: tuple[float, ...]
    min_m: tuple[float, ...]

    def to_dict(self) -> dict[str, Any]:
        return {"t_s": list(self.t_s), "min_m": list(self.min_m)}

    @classmethod
    def from_dict(cls, doc: Mapping[str, Any]) -> ClearanceTrace:
        return cls(
            t_s=tuple(float(v) for v in doc["t_s"]), min_m=tuple(float(v) for v in doc["min_m"])
        )


@dataclass(frozen=True)
class FlightRulesReport:
    """Every rule's row on one plan, how it was checked, and the clearance over time."""

    rows: tuple[RuleRow, ...]
    step_s: float
    n_samples: int
    n_pairs: int
    n_queries: int
    clearance: ClearanceTrace
    robot: str = ""

    @property
    def passed(self) -> bool:
        return all(row.passed for row in self.rows)

    @property
    def failing(self) -> tuple[RuleRow, ...]:
        return tuple(row for row in self.rows if not row.passed)

    def row(self, rule: str) -> RuleRow:
        for row in self.rows:
            if row.rule == rule:
                return row
        raise KeyError(rule)

    def with_row(self, new: RuleRow) -> FlightRulesReport:
        """This report with ``new`` in place of the row of its rule (added when absent)."""
        rows = [new if row.rule == new.rule else row for row in self.rows]
        if new.rule not in {row.rule for row in self.rows}:
            rows.append(new)
        order = {name: i for i, name in enumerate(RULE_NAMES)}
        rows.sort(key=lambda r: order.get(r.rule, len(order)))
        return FlightRulesReport(
            tuple(rows),
            self.step_s,
            self.n_samples,
            self.n_pairs,
            self.n_queries,
            self.clearance,
            self.robot,
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "passed": self.passed,
            "robot": self.robot,
            "rows": [row.to_dict() for row in self.rows],
            "step_s": self.step_s,
            "n_samples": self.n_samples,
            "n_pairs": self.n_pairs,
            "n_queries": self.n_queries,
            "clearance": self.clearance.to_dict(),
        }

    @classmethod
    def from_dict(cls, doc: Mapping[str, Any]) -> FlightRulesReport:
        try:
            return cls(
                rows=tuple(RuleRow.from_dict(r) for r in doc["rows"]),
                step_s=float(doc["step_s"]),
                n_samples=int(doc["n_samples"]),
                n_pairs=int(doc["n_pairs"]),
                n_queries=int(doc["n_queries"]),
                clearance=ClearanceTrace.from_dict(doc["clearance"]),
                robot=str(doc.get("robot", "")),
            )
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise InvalidInput(f"malformed flight-rules report: {exc!r}") from exc


def sample_step_s(model: RobotModel, collision: CollisionModel, min_clearance_m: float) -> float:
    """The fine grid's step: the 0.25 s command period divided so that, at the joints' rate
    limits, no point of the arm moves more than ``min_clearance_m / 2`` in one step."""
    rho = reach_bounds(model, collision)
    reach = rho.max(axis=1) if rho.size else np.zeros(model.n_joints)
    speed = float(np.sum(model.joint_rate_limit_radps * reach))
    per_period = max(1, math.ceil(speed * COMMAND_PERIOD_S / (0.5 * min_clearance_m) - 1e-12))
    if per_period > MAX_SAMPLES_PER_PERIOD:
        raise InvalidInput(
            f"the arm's points may move {speed:.3g} m/s at the joints' rate limits: checking "
            f"{min_clearance_m} m of clearance would need {per_period} samples per command "
            f"period (at most {MAX_SAMPLES_PER_PERIOD})"
        )
    return COMMAND_PERIOD_S / per_period


@dataclass(frozen=True)
class ServoModel:
    """Each joint's servo as a decoupled second-order system: ``q'' = a (q_c - q) - b q'``
    with ``a = kp / H_ii`` and ``b = kd / H_ii`` (H at the reference pose)."""

    stiffness: Array  # a, 1/s^2
    damping: Array  # b, 1/s

    @property
    def rate_overshoot(self) -> Array:
        """How far each joint's rate may exceed its commanded rate (a fraction): the step
        response's overshoot of the rate loop at its damping ratio (0 when over-damped)."""
        zeta = self.damping / (2.0 * np.sqrt(self.stiffness))
        under = zeta < 1.0
        out = np.zeros_like(zeta)
        z = zeta[under]
        out[under] = np.exp(-math.pi * z / np.sqrt(1.0 - z * z))
        return out


def servo_response(
    servo: ServoModel,
    command_times_s: Array,
    command_joints_rad: Array,
    initial_joints_rad: Array,
    sample_times_s: Array,
) -> tuple[Array, Array]:
    """Joint angles and rates ``(S, n)`` at ``sample_times_s`` (which hold every command
    time): the servos, at rest at ``initial_joints_rad`` at time 0, driven by the commands
    linear between their times (held before the first and after the last)."""
    from scipy import signal  # 0.8 s to import: only where a plan is checked

    n = command_joints_rad.shape[1]
    a = np.asarray(servo.stiffness, dtype=np.float64)
    b = np.asarray(servo.damping, dtype=np.float64)
    A = np.zeros((2 * n, 2 * n))
    B = np.zeros((2 * n, n))
    for k in range(n):
        A[2 * k, 2 * k + 1] = 1.0
        A[2 * k + 1, 2 * k] = -a[k]
        A[2 * k + 1, 2 * k + 1] = -b[k]
        B[2 * k + 1, k] = a[k]
    C = np.eye(2 * n)
    D = np.zeros((2 * n, n))
    inputs = np.column_stack(
        [np.interp(sample_times_s, command_times_s, command_joints_rad[:, k]) for k in range(n)]
    )
    x0 = np.zeros(2 * n)
    x0[0::2] = initial_joints_rad
    _, y, _ = signal.lsim((A, B, C, D), inputs, sample_times_s, X0=x0, interp=True)
    y = np.atleast_2d(y)
    return np.asarray(y[:, 0::2]), np.asarray(y[:, 1::2])


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

    path = _joint_paths(servo, plan, step, joints, rates)
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


def fits_pass_row(duration_s: float, window_s: float) -> RuleRow:
    """The plan's duration against the window of its pass."""
    return RuleRow(
        rule="fits_pass",
        value=duration_s,
        limit=window_s,
        unit="s",
        bound="max",
        passed=duration_s <= window_s,
        detail="duration within the window",
    )


def _pair_motion_coefficients(
    collision: CollisionModel, model: RobotModel, pairs: Sequence[tuple[int, int]]
) -> Array:
    """``C[p, k]``: how far one body of pair p can move relative to the other per radian of
    joint k (``rho[k, b]`` for the joints between them, 0 for the others)."""
    rho = reach_bounds(model, collision)
    coefficients = np.zeros((len(pairs), model.n_joints))
    for p, (a, b) in enumerate(pairs):
        ja, jb = collision.bodies[a].joint, collision.bodies[b].joint
        lo, hi, moving = (ja, jb, b) if ja < jb else (jb, ja, a)
        coefficients[p, lo:hi] = rho[lo:hi, moving]
    return coefficients


@dataclass(frozen=True)
class SampledClearance:
    """The exact least distance over ``pairs`` at every sample, and the worst of them."""

    per_sample_m: Array
    worst_m: float
    worst_sample: int
    worst_pair: tuple[int, int]
    nearest: PairDistance
    queries: int


def sampled_clearance(
    collision: CollisionModel,
    pairs: Sequence[tuple[int, int]],
    R: Array,
    t: Array,
    path_rad: Array,
    model: RobotModel,
) -> SampledClearance:
    """The least distance over ``pairs`` at each sample of the body frames ``(R, t)``
    (:func:`planner.collision.body_poses`), exact at every sample, asking coal only for the
    pairs whose lower bound (last exact distance less the relative path since,
    ``path_rad[s]`` being each joint's path from sample s to s + 1) is below the best found
    at that sample (the module docstring)."""
    shapes = ShapeSet(collision)
    frame_of = [body.joint for body in collision.bodies]
    drift_per_step = path_rad @ _pair_motion_coefficients(collision, model, pairs).T

    def exact(p: int, s: int) -> PairDistance:
        a, b = pairs[p]
        ja, jb = frame_of[a], frame_of[b]
        return shapes.distance(a, b, R[s, ja], t[s, ja], R[s, jb], t[s, jb])

    last = [exact(p, 0) for p in range(len(pairs))]
    last_d = np.array([d.distance_m for d in last])
    drift = np.zeros(len(pairs))
    best_p = int(np.argmin(last_d))
    per_sample = np.empty(R.shape[0])
    per_sample[0] = last_d[best_p]
    worst = (float(last_d[best_p]), 0, best_p, last[best_p])
    for s in range(1, R.shape[0]):
        step_drift = drift_per_step[s - 1]
        if not step_drift.any():
            per_sample[s] = per_sample[s - 1]
            continue
        drift += step_drift
        bounds = last_d - drift
        best = math.inf
        for p in np.argsort(bounds):
            if bounds[p] >= best:
                break
            found = exact(int(p), s)
            last[p] = found
            last_d[p] = found.distance_m
            drift[p] = 0.0
            if found.distance_m < best:
                best, best_p = found.distance_m, int(p)
        per_sample[s] = best
        if best < worst[0]:
            worst = (best, s, best_p, last[best_p])
    value, s_worst, p_worst, nearest = worst
    return SampledClearance(per_sample, value, s_worst, pairs[p_worst], nearest, shapes.queries)


def _joint_paths(servo: ServoModel, plan: Plan, step: float, joints: Array, rates: Array) -> Array:
    """Each joint's path in each step, bounded: the larger of its rates at the two ends and
    its commanded rate, with the servo's overshoot allowed for, times the step (and never
    less than the change between the samples)."""
    commanded = np.abs(np.diff(plan.command_joints_rad, axis=0)) / COMMAND_PERIOD_S
    per_period = max(1, round(COMMAND_PERIOD_S / step))
    commanded_per_step = np.repeat(commanded, per_period, axis=0)
    ends = np.maximum(np.abs(rates[:-1]), np.abs(rates[1:]))
    path = np.maximum(ends, commanded_per_step[: ends.shape[0]]) * (1.0 + servo.rate_overshoot)
    out: Array = np.maximum(path * step, np.abs(np.diff(joints, axis=0)))
    return out


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
