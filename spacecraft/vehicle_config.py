"""What the flight segment is: :class:`VehicleConfig` (the model, the truth simulation, the
attitude-control law, the periods, the schedule's capacity, the LOS policy, safing and
faults), checked as it is built, and :func:`vehicle_config_for` a robot description.

:class:`spacecraft.vehicle.Vehicle` flies one (docs/spacecraft.md lists the fields and their
defaults). A bad configuration raises :class:`VehicleError`; commands never do (they are
acknowledged).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, replace
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from planner.attitude_control import AcsGains, acs_gains_from_config
from planner.collision import CollisionModel
from planner.dynamics import DynamicsWorkspace
from planner.errors import PlannerError
from planner.limits import Limits
from planner.model import RobotModel, default_model
from planner.simulation import SimConfig
from spacecraft._sensors import SensorNoise
from spacecraft.faults import Fault, FaultSpecError, check_faults
from telemetry.wire import DEFAULT_SCHEDULE_CAPACITY, AcsModeName

if TYPE_CHECKING:
    from planner.robot import RobotDescription

__all__ = [
    "IDENTITY_QUAT_XYZW",
    "MAX_LOS_HOLD_AFTER_S",
    "MAX_SCHEDULE_CAPACITY",
    "MAX_TELEMETRY_PERIOD_S",
    "QUAT_NORM_TOLERANCE",
    "SensorNoise",
    "VehicleConfig",
    "VehicleError",
    "grid_ns",
    "vehicle_config_for",
]

#: SPEC 6: telemetry at least 4 Hz.
MAX_TELEMETRY_PERIOD_S = 0.25
#: An attitude target is a rotation if its norm is 1 within this.
QUAT_NORM_TOLERANCE = 1e-3
#: The identity attitude (x, y, z, w): the default initial attitude and attitude target.
IDENTITY_QUAT_XYZW = (0.0, 0.0, 0.0, 1.0)
#: What ``hello`` can announce (telemetry.wire.Hello).
MAX_SCHEDULE_CAPACITY = 1_000_000
MAX_LOS_HOLD_AFTER_S = 86_400.0


class VehicleError(ValueError):
    """A bad vehicle configuration. (Commands are never raised on: they are acknowledged.)"""


def _default_sim() -> SimConfig:
    return SimConfig(gravity_gradient=True)


def grid_ns(name: str, value_s: float, step_ns: int) -> int:
    """``value_s`` (the setting ``name``) in whole ns, a positive multiple of ``step_ns``;
    :class:`VehicleError` otherwise."""
    value_ns = round(value_s * 1e9)
    if not (math.isfinite(value_s) and value_ns > 0 and value_ns % step_ns == 0):
        raise VehicleError(
            f"{name} = {value_s!r} s must be a positive multiple of the {step_ns / 1e6:g} ms "
            "simulation step"
        )
    if abs(value_ns / 1e9 - value_s) > 1e-12:
        raise VehicleError(f"{name} = {value_s!r} s is not a whole number of nanoseconds")
    return value_ns


@dataclass(frozen=True, eq=False)
class VehicleConfig:
    """What the flight segment is. ``acs_gains`` is the attitude-control law (PD gains, and
    optionally an integral term, a rate-estimate filter and a dead band:
    :class:`planner.attitude_control.AcsGains`; a TOML file gives one with
    :func:`planner.description.load_acs_config`); ``None`` means the calibrated PD defaults
    (:func:`planner.attitude_control.default_acs_gains`). Its torque and momentum limits are
    the wheels' limits in the truth simulation. A plan predicted with the same law
    (``gains=`` of the planners) predicts what this vehicle flies."""

    model: RobotModel = field(default_factory=default_model)
    sim: SimConfig = field(default_factory=_default_sim)
    acs_gains: AcsGains | None = None
    telemetry_period_s: float = 0.1
    control_period_s: float = 0.1
    command_period_s: float = 0.25
    noise: SensorNoise = field(default_factory=SensorNoise)
    initial_joints_rad: tuple[float, ...] = (0.0,) * 6
    initial_quat_orbit_from_base_xyzw: tuple[float, float, float, float] = IDENTITY_QUAT_XYZW
    initial_acs_mode: AcsModeName = AcsModeName.FEEDBACK  # target identity, no feedforward
    vehicle_name: str = "ETS-VII"
    #: Commands the onboard schedule holds (joint and attitude); more are ``schedule_full``.
    schedule_capacity: int = DEFAULT_SCHEDULE_CAPACITY
    #: Silence from the ground: ``continue`` the loaded schedule, or ``hold`` the arm (refuse
    #: the queued joint commands) once nothing has arrived for ``los_hold_after_s``.
    los_policy: Literal["continue", "hold"] = "continue"
    los_hold_after_s: float | None = None
    #: The robot description flown (:func:`vehicle_config_for`): its name and content hash,
    #: announced in ``hello`` with the joint count. None: the built-in ETS-VII, and ``hello``
    #: says nothing of the robot (the ground takes that for ETS-VII).
    robot: str | None = None
    robot_hash: str | None = None
    #: On-board safing (:mod:`spacecraft.safing`): on a red limit of a safing quantity the
    #: vehicle makes itself safe; ``False`` flies without that protection. ``limits``: the
    #: bands whose red thresholds it keeps (None: the built-in ETS-VII description's);
    #: ``collision``: the shapes of the live clearance (None: ETS-VII's when ``robot`` is
    #: None, else no live clearance).
    safing: bool = True
    limits: Limits | None = None
    collision: CollisionModel | None = None
    #: Faults injected into the truth simulation (:mod:`spacecraft.faults`), never told to
    #: the ground.
    faults: tuple[Fault, ...] = ()

    def __post_init__(self) -> None:
        step_ns = self.step_ns
        grid_ns("telemetry_period_s", self.telemetry_period_s, step_ns)
        if self.telemetry_period_s > MAX_TELEMETRY_PERIOD_S:
            raise VehicleError(
                f"telemetry_period_s = {self.telemetry_period_s} s is slower than 4 Hz "
                f"(at most {MAX_TELEMETRY_PERIOD_S} s)"
            )
        grid_ns("control_period_s", self.control_period_s, step_ns)
        grid_ns("command_period_s", self.command_period_s, step_ns)
        if not self.sim.servo_enabled:
            raise VehicleError("the vehicle needs the joint servos (sim.servo_enabled)")
        if len(self.initial_joints_rad) != self.model.n_joints:
            raise VehicleError(
                f"initial_joints_rad has {len(self.initial_joints_rad)} angles, "
                f"the arm {self.model.n_joints} joints"
            )
        try:
            self.model.check_joints(np.array(self.initial_joints_rad))
        except PlannerError as exc:
            raise VehicleError(f"initial joints: {exc}") from None
        norm = float(np.linalg.norm(self.initial_quat_orbit_from_base_xyzw))
        if not abs(norm - 1.0) <= QUAT_NORM_TOLERANCE:
            raise VehicleError(f"initial attitude quaternion has norm {norm:.6g}, not 1")
        if (self.robot is None) != (self.robot_hash is None):
            raise VehicleError("robot and robot_hash are given together or not at all")
        if self.robot is not None and not 0 < len(self.robot) <= 64:
            raise VehicleError(f"robot {self.robot!r} must have 1 to 64 characters")
        if self.robot_hash is not None and not 0 < len(self.robot_hash) <= 128:
            raise VehicleError(f"robot_hash {self.robot_hash!r} must have 1 to 128 characters")
        if not 0 < len(self.vehicle_name) <= 64:
            raise VehicleError(f"vehicle_name {self.vehicle_name!r} must have 1 to 64 characters")
        capacity = self.schedule_capacity
        if (
            not isinstance(capacity, int)
            or isinstance(capacity, bool)
            or not 1 <= capacity <= MAX_SCHEDULE_CAPACITY
        ):
            raise VehicleError(
                f"schedule_capacity = {capacity!r} must be a whole number of commands in "
                f"[1, {MAX_SCHEDULE_CAPACITY}]"
            )
        if self.los_policy not in ("continue", "hold"):
            raise VehicleError(f"los_policy = {self.los_policy!r} must be 'continue' or 'hold'")
        hold_s = self.los_hold_after_s
        if self.los_policy == "hold":
            if hold_s is None or not (math.isfinite(hold_s) and 0 < hold_s <= MAX_LOS_HOLD_AFTER_S):
                raise VehicleError(
                    f"los_policy 'hold' needs los_hold_after_s > 0 (at most "
                    f"{MAX_LOS_HOLD_AFTER_S:g} s), got {hold_s!r}"
                )
        elif hold_s is not None:
            raise VehicleError(
                f"los_hold_after_s = {hold_s!r} applies only with los_policy 'hold' "
                f"(los_policy is {self.los_policy!r})"
            )
        try:
            check_faults(self.faults, n_joints=self.model.n_joints, n_wheels=len(self.model.wheels))
        except FaultSpecError as exc:
            raise VehicleError(str(exc)) from None

    @property
    def step_ns(self) -> int:
        step_ns = round(self.sim.timestep_s * 1e9)
        if step_ns <= 0 or abs(step_ns / 1e9 - self.sim.timestep_s) > 1e-15:
            raise VehicleError(
                f"sim.timestep_s = {self.sim.timestep_s!r} s is not a whole number of ns"
            )
        return step_ns


def vehicle_config_for(
    description: RobotDescription,
    *,
    acs_overrides: Mapping[str, object] | None = None,
    **fields: Any,
) -> VehicleConfig:
    """The vehicle of a robot description (``planner.description.load_robot``): its model,
    joint servos, attitude-control law (the ``[acs]`` table with the wheels' torque and
    momentum limits, which the truth simulation enforces), sensor noise, its live limits and
    collision shapes (on-board safing's red limits and live clearance), the reference pose as
    the initial pose (all zeros unless the description names one) and its name, hash and
    joint count for ``hello``. ``acs_overrides`` (an ``[acs]`` table, e.g. of
    ``--acs-config``) replaces keys of the description's law; ``fields`` set
    any other :class:`VehicleConfig` field (telemetry period, LOS policy, faults, ...)."""
    sim = fields.pop("sim", None) or _default_sim()
    sim = replace(sim, servo=description.servo_gains())
    model = description.model
    table: dict[str, object] = {
        **description.acs_config,
        "torque_limit_nm": description.wheel_torque_limit_nm,
        "momentum_limit_nms": description.wheel_momentum_limit_nms,
        **(acs_overrides or {}),
    }
    try:
        gains = acs_gains_from_config(DynamicsWorkspace(model, sim.orbit), table)
    except PlannerError as exc:
        raise VehicleError(f"{description.path}: attitude control: {exc}") from None
    values: dict[str, Any] = {
        "model": model,
        "sim": sim,
        "acs_gains": gains,
        "noise": SensorNoise(**asdict(description.sensor_noise)),
        "initial_joints_rad": tuple(float(x) for x in model.reference_joints),
        "vehicle_name": description.name,
        "robot": description.name,
        "robot_hash": description.content_sha256,
        "limits": description.limits,
        "collision": description.collision,
    }
    values.update(fields)
    return VehicleConfig(**values)
