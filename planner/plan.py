"""A plan: what the ground uplinks and what it expects to see (pure data, JSON round trip).

A plan holds joint commands exactly one command period (0.25 s, 4 Hz) apart, time-tagged in
seconds from the plan's start; attitude-control commands at their own times; named segments
that locate each phase; the prediction under ideal tracking; and summary metrics.

JSON: floats are written with ``repr`` precision, so ``Plan.from_json(plan.to_json())``
reproduces every number exactly.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from planner.attitude_control import AcsMode
from planner.errors import InvalidInput, JointLimitExceeded
from planner.model import RobotModel
from planner.ptp import COMMAND_PERIOD_S


class Described(Protocol):
    """What a plan takes from its robot's description (planner.robot.RobotDescription)."""

    @property
    def name(self) -> str: ...

    @property
    def content_sha256(self) -> str: ...


__all__ = [
    "DOCUMENT_KEYS",
    "ETS7_ROBOT_HASH",
    "ETS7_ROBOT_NAME",
    "SEGMENT_KINDS",
    "AcsCommand",
    "Plan",
    "Prediction",
    "Segment",
    "check_plan_limits",
    "plan_for_robot",
]

Array = NDArray[np.float64]

_SHA256 = re.compile(r"^[0-9a-f]{64}$")

SEGMENT_KINDS = (
    "ptp",
    "reactionless",
    "gjm",
    "hold",
    "settle",
    "coordination",
    "nonholonomic",
)

PLAN_FORMAT_VERSION = 1
#: The keys of a plan document (:meth:`Plan.to_dict`; ``flight_rules`` once checked).
DOCUMENT_KEYS = (
    "format_version",
    "experiment",
    "robot",
    "robot_hash",
    "parameters",
    "initial_joints_rad",
    "initial_quat_orbit_from_base_xyzw",
    "commands",
    "acs_commands",
    "segments",
    "prediction",
    "metrics",
    "flight_rules",
)

#: The robot a plan is for when a document does not say (documents without a robot field):
#: ETS-VII, ``examples/robots/ets7/ets7.toml``'s name, and that description's
#: ``content_sha256``. A constant, so that no planner module reads a file: a test loads the
#: file and checks the two agree (tests/planner/test_plan_robot.py), so a change to the file
#: (its [acs] calibration, say) fails there until this constant follows it.
ETS7_ROBOT_NAME = "ets7"
ETS7_ROBOT_HASH = "25ff6eb70cf40c5a1d73340136cec83be3c1f44b2bb50b2d22c3019cccb4fd61"


@dataclass(frozen=True)
class Segment:
    name: str
    kind: str
    t_start_s: float
    t_end_s: float

    def __post_init__(self) -> None:
        if self.kind not in SEGMENT_KINDS:
            raise InvalidInput(f"segment kind {self.kind!r} is not one of {SEGMENT_KINDS}")
        if not self.t_end_s >= self.t_start_s:
            raise InvalidInput(
                f"segment {self.name!r} ends at {self.t_end_s} s before it starts at "
                f"{self.t_start_s} s"
            )


@dataclass(frozen=True, eq=False)
class AcsCommand:
    """An attitude-control command, executed at ``t_s`` (s from the plan's start)."""

    t_s: float
    mode: AcsMode
    target_quat_orbit_from_base_xyzw: Array = field(
        default_factory=lambda: np.array([0.0, 0.0, 0.0, 1.0])
    )
    feedforward: bool = False

    def to_dict(self) -> dict[str, Any]:
        return {
            "t_s": self.t_s,
            "mode": self.mode.value,
            "target_quat_orbit_from_base_xyzw": [
                float(v) for v in self.target_quat_orbit_from_base_xyzw
            ],
            "feedforward": self.feedforward,
        }

    @classmethod
    def from_dict(cls, doc: Mapping[str, Any]) -> AcsCommand:
        return cls(
            t_s=float(doc["t_s"]),
            mode=AcsMode(doc["mode"]),
            target_quat_orbit_from_base_xyzw=np.array(
                doc["target_quat_orbit_from_base_xyzw"], dtype=np.float64
            ),
            feedforward=bool(doc["feedforward"]),
        )


_PREDICTION_COLUMNS = {
    "t_s": 1,
    "joints_rad": 2,
    "quat_orbit_from_base_xyzw": 2,
    "rpy_base_rad": 2,
    "omega_base_orbit_radps": 2,
    "hand_pos_orbit_m": 2,
    "quat_orbit_from_hand_xyzw": 2,
    "reaction_momentum_orbit_nms": 2,
    "wheel_momentum_nms": 2,
}


@dataclass(frozen=True, eq=False)
class Prediction:
    """States under ideal tracking, row k at ``t_s[k]`` (orbit frame unless named).

    ``reaction_momentum_orbit_nms`` is ``H~_bm phi'`` (eq. 3), the momentum the arm's motion
    carries; ``wheel_momentum_nms`` the rotors' momentum relative to the base, base frame.
    """

    t_s: Array
    joints_rad: Array
    quat_orbit_from_base_xyzw: Array
    rpy_base_rad: Array
    omega_base_orbit_radps: Array
    hand_pos_orbit_m: Array
    quat_orbit_from_hand_xyzw: Array
    reaction_momentum_orbit_nms: Array
    wheel_momentum_nms: Array

    def to_dict(self) -> dict[str, Any]:
        return {name: np.asarray(getattr(self, name)).tolist() for name in _PREDICTION_COLUMNS}

    @classmethod
    def from_dict(cls, doc: Mapping[str, Any]) -> Prediction:
        return cls(**{name: np.array(doc[name], dtype=np.float64) for name in _PREDICTION_COLUMNS})


@dataclass(frozen=True, eq=False)
class Plan:
    """A plan for one robot: ``robot`` is its description's name and ``robot_hash`` the
    description's ``content_sha256`` (planner.description), ETS-VII's unless a planner was
    given another description; the ground refuses to fly a plan on another robot."""

    experiment: str
    parameters: Mapping[str, Any]
    initial_joints_rad: Array
    command_times_s: Array  # (k,), from 0, exactly COMMAND_PERIOD_S apart
    command_joints_rad: Array  # (k, n)
    segments: tuple[Segment, ...]
    prediction: Prediction
    metrics: Mapping[str, float]
    acs_commands: tuple[AcsCommand, ...] = ()
    initial_quat_orbit_from_base_xyzw: Array = field(
        default_factory=lambda: np.array([0.0, 0.0, 0.0, 1.0])
    )
    robot: str = ETS7_ROBOT_NAME
    robot_hash: str = ETS7_ROBOT_HASH
    #: the flight-rules report on this plan (``planner.flight_rules.FlightRulesReport.
    #: to_dict()``), None until the plan has been checked; a plan that fails a rule keeps it,
    #: so that whoever opens the file sees why
    flight_rules: Mapping[str, Any] | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.robot, str) or not self.robot:
            raise InvalidInput(f"plan robot must be a non-empty name, got {self.robot!r}")
        if not isinstance(self.robot_hash, str) or not _SHA256.match(self.robot_hash):
            raise InvalidInput(
                f"plan robot_hash must be 64 lowercase hex digits (SHA-256), got "
                f"{self.robot_hash!r}"
            )
        times = np.asarray(self.command_times_s, dtype=np.float64)
        joints = np.asarray(self.command_joints_rad, dtype=np.float64)
        if times.ndim != 1 or times.size == 0 or joints.shape[:1] != times.shape:
            raise InvalidInput(f"plan commands: times {times.shape} and joints {joints.shape}")
        expected = np.arange(times.size) * COMMAND_PERIOD_S + times[0]
        if not np.array_equal(times, expected):
            raise InvalidInput(f"plan commands must be exactly {COMMAND_PERIOD_S} s apart")
        if not (np.all(np.isfinite(joints)) and np.all(np.isfinite(times))):
            raise InvalidInput("plan commands must be finite")
        object.__setattr__(self, "command_times_s", times)
        object.__setattr__(self, "command_joints_rad", joints)

    def check_consistent(self) -> None:
        """The checks of a plan read from outside (a file, an upload), beyond the ones every
        plan passes when made: its commands start on the 4 Hz grid, its attitude commands are
        finite, in time order and within the plan, its prediction has a finite row for every
        command in the widths its columns take, its quaternions are unit and its metrics and
        segments finite. :class:`InvalidInput` naming the first part that disagrees."""
        times = self.command_times_s
        n = self.command_joints_rad.shape[1] if self.command_joints_rad.ndim == 2 else -1
        if n < 1:
            raise InvalidInput("plan commands must each hold one angle per joint")
        if float(times[0]) % COMMAND_PERIOD_S != 0.0:
            raise InvalidInput(
                f"plan commands start at {float(times[0])!r} s, off the {COMMAND_PERIOD_S} s grid"
            )
        _check_vector(self.initial_joints_rad, (n,), "initial_joints_rad")
        _check_vector(self.initial_quat_orbit_from_base_xyzw, (4,), "initial quaternion", unit=True)
        last = -math.inf
        for i, c in enumerate(self.acs_commands):
            if not (math.isfinite(c.t_s) and times[0] <= c.t_s <= times[-1] and c.t_s >= last):
                raise InvalidInput(
                    f"acs_commands[{i}] at {c.t_s!r} s is out of time order or outside the "
                    f"plan's {float(times[0])}..{float(times[-1])} s"
                )
            last = c.t_s
            _check_vector(c.target_quat_orbit_from_base_xyzw, (4,), f"acs_commands[{i}]", unit=True)
        wheels = np.shape(self.prediction.wheel_momentum_nms)
        widths = {
            "joints_rad": n,
            "quat_orbit_from_base_xyzw": 4,
            "quat_orbit_from_hand_xyzw": 4,
            "wheel_momentum_nms": wheels[1] if len(wheels) == 2 and wheels[1] > 0 else 3,
        }
        for name, ndim in _PREDICTION_COLUMNS.items():
            shape = (times.size,) if ndim == 1 else (times.size, widths.get(name, 3))
            _check_vector(getattr(self.prediction, name), shape, f"prediction {name}")
        if not np.allclose(self.prediction.t_s, times, rtol=0.0, atol=1e-9):
            raise InvalidInput("the prediction's times are not the commands' times")
        for name, value in self.metrics.items():
            if not math.isfinite(value):
                raise InvalidInput(f"metric {name!r} is not finite: {value!r}")
        for seg in self.segments:
            if not (math.isfinite(seg.t_start_s) and math.isfinite(seg.t_end_s)):
                raise InvalidInput(f"segment {seg.name!r} has a time that is not finite")

    @property
    def duration_s(self) -> float:
        return float(self.command_times_s[-1] - self.command_times_s[0])

    def segment(self, name: str) -> Segment:
        for seg in self.segments:
            if seg.name == name:
                return seg
        raise KeyError(name)

    def to_dict(self) -> dict[str, Any]:
        return {
            "format_version": PLAN_FORMAT_VERSION,
            "experiment": self.experiment,
            "robot": self.robot,
            "robot_hash": self.robot_hash,
            "parameters": dict(self.parameters),
            "initial_joints_rad": [float(v) for v in self.initial_joints_rad],
            "initial_quat_orbit_from_base_xyzw": [
                float(v) for v in self.initial_quat_orbit_from_base_xyzw
            ],
            "commands": [
                {"t_s": float(t), "joints_rad": [float(v) for v in q]}
                for t, q in zip(self.command_times_s, self.command_joints_rad, strict=True)
            ],
            "acs_commands": [c.to_dict() for c in self.acs_commands],
            "segments": [
                {"name": s.name, "kind": s.kind, "t_start_s": s.t_start_s, "t_end_s": s.t_end_s}
                for s in self.segments
            ],
            "prediction": self.prediction.to_dict(),
            "metrics": dict(self.metrics),
            **({} if self.flight_rules is None else {"flight_rules": dict(self.flight_rules)}),
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), allow_nan=False)

    @classmethod
    def from_dict(cls, doc: Mapping[str, Any]) -> Plan:
        try:
            if doc.get("format_version") != PLAN_FORMAT_VERSION:
                raise InvalidInput(
                    f"plan format_version {doc.get('format_version')!r} is not "
                    f"{PLAN_FORMAT_VERSION}"
                )
            commands = doc["commands"]
            return cls(
                experiment=str(doc["experiment"]),
                parameters=dict(doc["parameters"]),
                initial_joints_rad=np.array(doc["initial_joints_rad"], dtype=np.float64),
                initial_quat_orbit_from_base_xyzw=np.array(
                    doc["initial_quat_orbit_from_base_xyzw"], dtype=np.float64
                ),
                command_times_s=np.array([c["t_s"] for c in commands], dtype=np.float64),
                command_joints_rad=np.array([c["joints_rad"] for c in commands], dtype=np.float64),
                acs_commands=tuple(AcsCommand.from_dict(c) for c in doc["acs_commands"]),
                segments=tuple(Segment(**s) for s in doc["segments"]),
                prediction=Prediction.from_dict(doc["prediction"]),
                metrics={str(k): float(v) for k, v in doc["metrics"].items()},
                # a document without a robot field is an ETS-VII plan
                robot=doc.get("robot", ETS7_ROBOT_NAME),
                robot_hash=doc.get("robot_hash", ETS7_ROBOT_HASH),
                flight_rules=_rules_doc(doc.get("flight_rules")),
            )
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, InvalidInput):
                raise
            raise InvalidInput(f"malformed plan document: {exc!r}") from exc

    @classmethod
    def from_json(cls, text: str) -> Plan:
        try:
            doc = json.loads(text)
        except json.JSONDecodeError as exc:
            raise InvalidInput(f"plan is not JSON: {exc}") from exc
        if not isinstance(doc, dict):
            raise InvalidInput("plan JSON must be an object")
        return cls.from_dict(doc)


def _check_vector(value: Array, shape: tuple[int, ...], what: str, *, unit: bool = False) -> None:
    array = np.asarray(value)
    if array.shape != shape or not np.all(np.isfinite(array)):
        raise InvalidInput(f"plan {what}: shape {array.shape}, expected {shape}, all finite")
    if unit and abs(float(np.linalg.norm(array)) - 1.0) > 1e-6:
        raise InvalidInput(f"plan {what}: a quaternion of norm {float(np.linalg.norm(array))!r}")


def _rules_doc(value: object) -> Mapping[str, Any] | None:
    if value is None:
        return None
    if not isinstance(value, dict) or not isinstance(value.get("rows"), list):
        raise InvalidInput("plan flight_rules must be a report object with its rows")
    return value


def check_plan_limits(model: RobotModel, plan: Plan, *, rate_tolerance: float = 1e-9) -> None:
    """Every commanded joint within its angle limit and every step within its rate limit.

    Raises :class:`JointLimitExceeded` naming the joint, the value, the limit and when
    (the command's time and its segment).
    """
    for k, q in enumerate(plan.command_joints_rad):
        try:
            model.check_joints(q)
        except JointLimitExceeded as angle_exc:
            angle_exc.args = (f"{angle_exc.args[0]} {_when(plan, k)}",)
            raise
    if plan.command_times_s.size < 2:
        return
    rates = np.abs(np.diff(plan.command_joints_rad, axis=0)) / COMMAND_PERIOD_S
    worst = np.max(rates, axis=0)
    for i, (rate, limit) in enumerate(zip(worst, model.joint_rate_limit_radps, strict=True)):
        if rate > limit * (1.0 + rate_tolerance):
            exc = JointLimitExceeded(
                i + 1, math.degrees(rate), math.degrees(limit), "deg/s", what="moves at"
            )
            exc.args = (f"{exc.args[0]} {_when(plan, int(np.argmax(rates[:, i])) + 1)}",)
            raise exc


def _when(plan: Plan, k: int) -> str:
    """``at t = ... s`` of command ``k``, with the segment it belongs to."""
    t_s = float(plan.command_times_s[k])
    names = [s.name for s in plan.segments if s.t_start_s < t_s <= s.t_end_s]
    return f"at t = {t_s:.2f} s" + (f" (segment {names[0]!r})" if names else "")


def plan_for_robot(plan: Plan, robot: Described | None) -> Plan:
    """``plan`` stamped with the robot it was made for (``None``: ETS-VII, the default)."""
    if robot is None:
        return replace(plan, robot=ETS7_ROBOT_NAME, robot_hash=ETS7_ROBOT_HASH)
    return replace(plan, robot=robot.name, robot_hash=robot.content_sha256)
