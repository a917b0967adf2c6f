"""A robot description, loaded: the value every planner takes for a robot other than ETS-VII.

This module holds the loaded description and what follows from it by computation alone
(the attitude-control law, the servos' gains, poses solved by IK); it reads no file.
Reading, parsing and checking a description's TOML and URDF is :mod:`planner.description`'s
(the edge): ``planner.description.load_robot(path) -> RobotDescription``.

    RobotDescription.model                     the RobotModel every planner takes
    RobotDescription.acs_gains(ws)             the attitude-control law (planner.attitude_control)
    RobotDescription.servo_gains()             the joint servos' PD gains (planner.mjcf)
    RobotDescription.sensor_noise              1-sigma noise, radians (spacecraft.SensorNoise's
                                               field names and units)
    RobotDescription.poses / pose_joints_rad   named poses (A, B, C for ETS-VII)
    RobotDescription.experiments               default parameters per experiment (raw values
                                               for planner.parameters.parameters_from_values)
    RobotDescription.limits                    live limits' bands (planner.limits; the [limits]
                                               table over the built-in defaults)
    RobotDescription.content_sha256            hash of the canonical TOML and URDF content
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import MappingProxyType

import numpy as np
from numpy.typing import NDArray

from planner.attitude_control import AcsGains, acs_gains_from_config
from planner.collision import CollisionModel
from planner.dynamics import DynamicsWorkspace
from planner.errors import InvalidInput, PlannerError
from planner.flight_check import check_plan
from planner.flight_rules import FlightRules, FlightRulesReport
from planner.frames import matrix_from_rpy
from planner.ik import solve_ik
from planner.limits import DEFAULT_LIMITS, Limits
from planner.meshes import MeshVisual
from planner.mjcf import ServoGains
from planner.model import RobotModel, arm_reach_m, default_model
from planner.plan import Plan
from planner.servo_response import ServoModel
from planner.simulation import default_servo_gains
from planner.state import State

__all__ = [
    "DEFAULT_SERVO_BANDWIDTH_RADPS",
    "DEFAULT_SERVO_LAG_S",
    "NONHOLONOMIC_MAX_CORRECTIONS",
    "NONHOLONOMIC_START_OFFSET_DEG",
    "NamedPose",
    "RobotDescription",
    "SensorNoiseSpec",
    "ServoSpec",
    "WheelLimits",
    "derived_experiment_defaults",
    "servo_gains_of",
]

Array = NDArray[np.float64]

#: The servos' design where a description leaves it out: one lag and bandwidth for every
#: joint (ETS-VII's file gives one per joint).
DEFAULT_SERVO_BANDWIDTH_RADPS = 6.0
DEFAULT_SERVO_LAG_S = 0.3


@dataclass(frozen=True, eq=False)
class WheelLimits:
    """What the attitude-control law may ask of one wheel."""

    torque_limit_nm: float
    momentum_limit_nms: float


@dataclass(frozen=True, eq=False)
class ServoSpec:
    """The joint servos: either the PD design of :func:`planner.simulation.default_servo_gains`
    (``bandwidth_radps``, ``lag_s``: one number for every joint, or an array of one per joint)
    or explicit per-joint gains (both arrays, shape (n,))."""

    bandwidth_radps: float | Array = DEFAULT_SERVO_BANDWIDTH_RADPS
    lag_s: float | Array = DEFAULT_SERVO_LAG_S
    kp_nm_per_rad: Array | None = None
    kd_nms_per_rad: Array | None = None


@dataclass(frozen=True)
class SensorNoiseSpec:
    """1-sigma sensor noise in radians; the field names of ``spacecraft.SensorNoise``, so
    ``SensorNoise(**dataclasses.asdict(spec))`` builds the vehicle's."""

    attitude_rad: float
    rate_radps: float
    joint_rad: float


@dataclass(frozen=True, eq=False)
class NamedPose:
    """A pose by joint angles, by hand pose (robot frame), or by both (checked to agree)."""

    name: str
    description: str = ""
    joints_rad: Array | None = None
    hand_pos_robot_m: Array | None = None
    hand_rpy_deg: Array | None = None  # roll, pitch, yaw: Rz(yaw) Ry(pitch) Rx(roll)

    @property
    def rot_robot_from_hand(self) -> Array | None:
        return None if self.hand_rpy_deg is None else matrix_from_rpy(np.radians(self.hand_rpy_deg))


@dataclass(frozen=True, eq=False)
class RobotDescription:
    """A loaded, validated robot description. ``model`` is what every planner takes."""

    name: str
    description: str
    path: Path  # the TOML
    urdf_path: Path
    content_sha256: str  # canonical TOML (without the URDF's file name) + canonical URDF
    base_link: str
    model: RobotModel
    wheel_limits: tuple[WheelLimits, ...]  # one per model.wheels entry
    acs_config: Mapping[str, object]  # the [acs] table as written (planner.attitude_control)
    servo: ServoSpec
    sensor_noise: SensorNoiseSpec
    poses: Mapping[str, NamedPose]
    experiments: Mapping[str, Mapping[str, object]] = field(
        default_factory=lambda: MappingProxyType({})
    )
    #: the base link's first box visual (display only; planner.urdf.urdf_xml draws it)
    base_box_size_m: tuple[float, float, float] | None = None
    #: the URDF's <collision> shapes (None: it has none, and no plan can be shown clear)
    collision: CollisionModel | None = None
    #: the [flight_rules] table (SPEC 8's numbers where it leaves a key out)
    flight_rules: FlightRules = field(default_factory=FlightRules)
    #: the live limits: the [limits] table over planner.limits.DEFAULT_LIMITS
    limits: Limits = DEFAULT_LIMITS
    #: the URDF's joint limits (model.joint_limit_rad and its rates are the mission's,
    #: inside these; the same where [mission_limits] leaves a joint out)
    vendor_joint_limit_rad: Array | None = None
    vendor_joint_rate_limit_radps: Array | None = None
    #: the arm joints' URDF names, the hand frame's link and the reference pose's name
    joint_names: tuple[str, ...] = ()
    hand_link: str = "hand"
    reference_pose: str | None = None
    #: what loading did to the URDF's tree (planner.description.reduce): links lumped into a
    #: body (link, body), tool joints locked (joint, type, position in m or rad), arm links
    #: renamed (link, name)
    lumped: tuple[tuple[str, str], ...] = ()
    locked: tuple[tuple[str, str, float], ...] = ()
    renamed: tuple[tuple[str, str], ...] = ()
    #: the URDF's visual meshes the description reaches (planner.meshes), and their files by
    #: served key (what GET /api/robots/{name}/meshes/{key} may answer, and nothing else)
    visual_meshes: tuple[MeshVisual, ...] = ()
    mesh_files: Mapping[str, Path] = field(default_factory=lambda: MappingProxyType({}))

    @property
    def n_joints(self) -> int:
        return self.model.n_joints

    @property
    def wheel_torque_limit_nm(self) -> float:
        """The law's one torque limit: the smallest wheel's."""
        return min(w.torque_limit_nm for w in self.wheel_limits)

    @property
    def wheel_momentum_limit_nms(self) -> float:
        """The law's one momentum limit: the smallest wheel's."""
        return min(w.momentum_limit_nms for w in self.wheel_limits)

    def acs_gains(self, ws: DynamicsWorkspace | None = None) -> AcsGains:
        """The attitude-control law: the ``[acs]`` table read by
        :func:`planner.attitude_control.acs_gains_from_config`, with the wheels' limits."""
        workspace = ws if ws is not None else DynamicsWorkspace(self.model)
        config = {
            **self.acs_config,
            "torque_limit_nm": self.wheel_torque_limit_nm,
            "momentum_limit_nms": self.wheel_momentum_limit_nms,
        }
        return acs_gains_from_config(workspace, config)

    def servo_gains(self) -> ServoGains:
        """The joint servos' PD gains (``planner.mjcf.ServoGains``): explicit, or the design
        (``kp = H_m[i, i] wn^2`` at the reference pose, ``kd = lag kp``), per joint."""
        return servo_gains_of(self.servo, self.model)

    def servo_model(self, ws: DynamicsWorkspace | None = None) -> ServoModel:
        """The servos as the flight rules model them: each joint's PD gains on its own
        inertia ``H_m[i, i]`` at the reference pose (:class:`planner.servo_response.ServoModel`)."""
        workspace = ws if ws is not None else DynamicsWorkspace(self.model)
        zeros = np.zeros(self.n_joints)
        reference = self.model.reference_joints
        inertia = np.diag(workspace.evaluate(State(reference, joint_rates_radps=zeros)).H_m)
        gains = self.servo_gains()
        return ServoModel(
            stiffness=np.asarray(gains.kp_nm_per_rad) / inertia,
            damping=np.asarray(gains.kd_nms_per_rad) / inertia,
        )

    def check_plan(
        self, plan: Plan, *, window_s: float | None = None, ws: DynamicsWorkspace | None = None
    ) -> FlightRulesReport:
        """``plan`` against this robot's flight rules (:func:`planner.flight_check.
        check_plan`); ``window_s``: its pass's window (None: ``[flight_rules]
        pass_window_s``). Refused (:class:`InvalidInput`) for a plan made for another robot
        or a robot without collision shapes."""
        if plan.robot_hash != self.content_sha256:
            raise InvalidInput(
                f"the plan is for robot {plan.robot!r} (description {plan.robot_hash[:12]}), "
                f"not {self.name!r} ({self.content_sha256[:12]})"
            )
        return check_plan(
            plan,
            self.model,
            self.collision,
            self.flight_rules,
            servo=self.servo_model(ws),
            wheel_momentum_limits_nms=[w.momentum_limit_nms for w in self.wheel_limits],
            window_s=window_s,
            robot=self.name,
        )

    def checked(
        self, plan: Plan, *, window_s: float | None = None, ws: DynamicsWorkspace | None = None
    ) -> tuple[Plan, FlightRulesReport]:
        """``plan`` carrying its flight-rules report (:meth:`check_plan`), and the report."""
        report = self.check_plan(plan, window_s=window_s, ws=ws)
        return replace(plan, flight_rules=report.to_dict()), report

    def pose_joints_rad(self, name: str, ws: DynamicsWorkspace | None = None) -> Array:
        """Joint angles of the named pose: as written, or the IK solution of its hand pose
        nearest the reference pose (:func:`planner.ik.solve_ik`)."""
        if name not in self.poses:
            raise InvalidInput(
                f"robot {self.name!r} has no pose {name!r}; it has {sorted(self.poses)}"
            )
        pose = self.poses[name]
        if pose.joints_rad is not None:
            return pose.joints_rad.copy()
        assert pose.hand_pos_robot_m is not None and pose.rot_robot_from_hand is not None
        workspace = ws if ws is not None else DynamicsWorkspace(self.model)
        return solve_ik(workspace, pose.hand_pos_robot_m, pose.rot_robot_from_hand)[0].joints_rad

    def target_joints_rad(self, name: str, ws: DynamicsWorkspace, *, experiment: str) -> Array:
        """Joint angles for the named pose as an experiment's start or goal.

        A pose with a hand pose is that hand pose exactly: the IK solution nearest the pose's
        written joints (nearest the reference pose when none are written), so ETS-VII's B is
        the grapple approach of SPEC 1.2, not the paper's joints rounded to 0.1 deg, and a
        redundant arm keeps the configuration its joints name. A pose of joints alone is
        those joints. Refused (:class:`~planner.errors.InvalidInput`) with the reason when
        the robot has no such pose, or its hand pose cannot be reached within the limits.
        """
        if name not in self.poses:
            raise InvalidInput(
                f"{experiment}: robot {self.name!r} has no pose {name!r}, which the experiment "
                f"needs (its poses: {sorted(self.poses) or 'none'}); add [poses.{name}] to its "
                "description or give the joints as parameters"
            )
        pose = self.poses[name]
        if pose.hand_pos_robot_m is None or pose.rot_robot_from_hand is None:
            assert pose.joints_rad is not None
            return self.model.check_joints(pose.joints_rad).copy()
        try:
            solutions = solve_ik(
                ws,
                pose.hand_pos_robot_m,
                pose.rot_robot_from_hand,
                reference_joints_rad=pose.joints_rad,
            )
        except PlannerError as exc:
            raise InvalidInput(
                f"{experiment}: robot {self.name!r}'s pose {name!r} cannot be reached: {exc}"
            ) from exc
        return solutions[0].joints_rad

    def experiment_defaults(self, experiment: str) -> Mapping[str, object]:
        """The experiment's defaults for this robot: its ``[experiments.NAME]`` table (raw
        values) over what :func:`derived_experiment_defaults` finds for the keys the table
        leaves out (the planners' own defaults are ETS-VII's numbers)."""
        own = self.experiments.get(experiment, MappingProxyType({}))
        derived = derived_experiment_defaults(self, experiment, given=own)
        return MappingProxyType({**derived, **own}) if derived else own

    @property
    def reach_ratio(self) -> float:
        """This arm's reach over ETS-VII's (:func:`planner.model.arm_reach_m`): the scale of the
        experiments' distances where the description gives none."""
        return arm_reach_m(self.model) / _ets7_reach_m()


@functools.cache
def _ets7_reach_m() -> float:
    return arm_reach_m(default_model())


#: Experiment 4's start as an offset from its goal (deg, joints 1-6; 0 beyond): ETS-VII's
#: flight case (SPEC 3, item 4), whose goal is its pose A (all zero).
NONHOLONOMIC_START_OFFSET_DEG = (9.6, -2.0, 2.0, 0.0, -13.6, 0.0)
#: Experiment 4's corrections of the 4 Hz commands for another arm (ETS-VII needs 1 of its
#: default 5; an arm with few commands per path needs more).
NONHOLONOMIC_MAX_CORRECTIONS = 12
#: ETS-VII's lengths (m) and speeds (m/s), scaled by :attr:`RobotDescription.reach_ratio`
#: for another arm: each experiment's scale key first, the rest scaled only with it (a table
#: that gives the scale key has chosen the motion's size, and keeps the planners' defaults).
_SCALED = {
    "gjm": {"approach_distance_m": 0.22},
    "reactionless": {
        "distance_m": 0.35,
        "out_speed_mps": 0.015,
        "back_speed_mps": 0.0075,
        "orientation_weight_m": 0.3,
    },
    "coordination": {"distance_m": 0.2},
}
#: The slowest speed a scaled default may take (planner.parameters.MIN_SPEED_MPS).
_MIN_SCALED_SPEED_MPS = 0.003


def derived_experiment_defaults(
    robot: RobotDescription, experiment: str, *, given: Mapping[str, object] = MappingProxyType({})
) -> dict[str, object]:
    """What the tool picks for the keys of ``[experiments.NAME]`` that ``given`` (the
    description's table) leaves out, where the planners' own defaults (ETS-VII's numbers) do
    not fit another arm (docs/robots.md, "Experiment defaults"):

    - ``ptp``: ``start_joints_deg`` none: pose A (ETS-VII's all-zero pose is stretched and
      singular for a vendor arm);
    - ``nonholonomic``: ``phi_end_deg`` pose A's joints, ``phi_init_deg`` pose A plus
      ETS-VII's flight offset (:data:`NONHOLONOMIC_START_OFFSET_DEG`), clipped 1 deg inside
      the limits, and ``max_corrections`` :data:`NONHOLONOMIC_MAX_CORRECTIONS` unless the
      table gives ``phi_end_deg``;
    - sizes (``gjm`` ``approach_distance_m``; ``reactionless`` ``distance_m``, its speeds
      and ``orientation_weight_m``; ``coordination`` ``distance_m``): ETS-VII's scaled by
      the arm's reach over ETS-VII's, to the mm (speeds at least 3 mm/s), unless the table
      gives the experiment's distance (ETS-VII itself: its own numbers).
    """
    out: dict[str, object] = {}
    if experiment == "ptp" and "start_joints_deg" not in given:
        out["start_joints_deg"] = None
    if experiment == "nonholonomic" and not {"phi_init_deg", "phi_end_deg"} <= set(given):
        try:
            goal = robot.pose_joints_rad("A")
        except PlannerError:
            goal = robot.model.reference_joints
        offset = np.zeros(robot.n_joints)
        k = min(robot.n_joints, len(NONHOLONOMIC_START_OFFSET_DEG))
        offset[:k] = np.radians(NONHOLONOMIC_START_OFFSET_DEG[:k])
        margin = np.radians(1.0)
        lo, hi = robot.model.joint_limit_rad[:, 0], robot.model.joint_limit_rad[:, 1]
        start = np.clip(goal + offset, lo + margin, hi - margin)
        if "phi_end_deg" not in given:
            out["phi_end_deg"] = [round(float(v), 6) for v in np.degrees(goal)]
        if "phi_init_deg" not in given:
            out["phi_init_deg"] = [round(float(v), 6) for v in np.degrees(start)]
    if experiment == "nonholonomic" and not {"phi_end_deg", "max_corrections"} & set(given):
        out["max_corrections"] = NONHOLONOMIC_MAX_CORRECTIONS
    scaled = _SCALED.get(experiment, {})
    if scaled and next(iter(scaled)) not in given:
        for key, value in scaled.items():
            if key not in given:
                size = round(value * robot.reach_ratio, 3)
                out[key] = max(size, _MIN_SCALED_SPEED_MPS) if key.endswith("_mps") else size
    return out


def servo_gains_of(spec: ServoSpec, model: RobotModel) -> ServoGains:
    """A ``[servo]`` table's PD gains on ``model`` (explicit, or the design)."""
    if spec.kp_nm_per_rad is not None and spec.kd_nms_per_rad is not None:
        return ServoGains(kp_nm_per_rad=spec.kp_nm_per_rad, kd_nms_per_rad=spec.kd_nms_per_rad)
    return default_servo_gains(model, bandwidth_radps=spec.bandwidth_radps, lag_s=spec.lag_s)
