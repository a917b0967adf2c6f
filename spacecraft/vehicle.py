"""The flight segment: onboard computer and truth simulation, driven by onboard time.

Deterministic and free of I/O: the spacecraft process (``spacecraft.process``) owns the
sockets and the clock and calls :meth:`Vehicle.receive` with each uplinked command,
:meth:`Vehicle.delete_schedule` with each ``schedule_delete``,
:meth:`Vehicle.heard_from_ground` on every message the uplink delivers, and
:meth:`Vehicle.advance_to` with the onboard time it has reached. Onboard rules (SPEC section
6, docs/spacecraft.md):

- **Time.** The onboard clock starts at ``epoch_ns`` and moves on the truth simulation's
  step grid (10 ms); :meth:`~Vehicle.advance_to` stops on the last grid point at or before the
  time it is given and never goes back.
- **Retransmission.** The ground sends each command until it is acknowledged, so copies
  arrive, also out of order. A seq received before *with identical content* is answered with
  that command's latest acknowledgement (:meth:`~Vehicle.outcome`: received, executed or
  rejected) and has no other effect; a different command under a seq already used is
  ``duplicate`` and has no effect either.
- **Acceptance** (:meth:`~Vehicle.receive`, in this order): a command that a
  ``schedule_delete`` barrier covers (tag at or after its ``from_time_ns``, seq at most its
  ``max_seq``) is ``cancelled``; a tag off the step grid, an attitude target whose
  norm is not 1 (within 1e-3), or a joint command for a tag that a queued joint command
  already holds is ``malformed`` (attitude commands may share a tag: they execute in seq
  order); a tag at or before the onboard time is ``late`` (never executed); a joint
  angle beyond +-170 deg, or a move faster than 3 deg/s from the queued joint command
  before it (or, with none, from the current servo target, starting now) or to the queued
  one after it, is ``out_of_limits``; a command that passes all this while the schedule holds
  ``schedule_capacity`` commands is ``schedule_full``. That refusal alone is transient: the
  seq is not recorded, and a later copy is checked afresh.
- **Execution.** The truth simulation is stepped exactly to each tag and the command executes
  there. A joint command sets the servo target to its joints; from there the target moves
  linearly to the next queued joint command, reaching it at that command's tag (rate =
  difference / tag difference: between consecutive 4 Hz commands, difference / 0.25 s);
  with none queued it holds. A joint command that arrives while the target holds (or that
  becomes the next one, ahead of the command being ramped to) is ramped to from where the
  target stands. The target therefore never steps and never moves faster than the checked
  rate limit: across a gap left by a lost command it keeps moving toward the next one
  instead of holding and then jumping. An attitude-control command switches mode, target
  and feedforward at its tag.
- **Schedule delete** (:meth:`~Vehicle.delete_schedule`, PUS 11): every queued command (joint
  and attitude) tagged at or after ``from_time_ns`` with seq at most ``max_seq`` is deleted
  (its outcome becomes ``cancelled``), and a barrier refuses such commands arriving later.
  The target then ramps to the first joint command left, or holds where it stands. A
  repeated ``request_id`` is answered with the first report and does nothing.
- **Attitude control** runs every ``control_period_s`` (and at each attitude command's tag) on
  the *measured* (noisy) attitude and rate with the law of ``acs_gains``
  (:class:`planner.attitude_law.AttitudeController`, the planner's prediction's law: its
  integral and rate filter, if any, restart on entering feedback and on a new target); its
  feedforward is eq. (9) of the commanded motion (the servo target and its ramp rate).
  Wheel torque and momentum are limited in the simulator.
- **Telemetry**: a frame every ``telemetry_period_s`` on the epoch grid, seq from 0, with the
  schedule's summary (queued count, first and last tag, capacity, last executed seq).
- **Loss of signal** (``los_policy``): with ``continue`` (the default) silence from the
  ground changes nothing: the loaded schedule executes. With ``hold``, once nothing has
  arrived from the ground for ``los_hold_after_s`` (the first grid point at or after that),
  every queued joint command is refused (``link_lost``, acks returned by ``advance_to``) and
  the arm holds the target it has reached; attitude control carries on in its mode (queued
  attitude commands still execute at their tags). :meth:`~Vehicle.link_lost` does the same
  at once.
- **On-board safing** (:mod:`spacecraft.safing`; ``safing=False`` flies without it): at each
  control tick, before the commands due then, the red limits of the safing quantities are
  checked on the measured sample. On one the vehicle is SAFE at that tick: the frame of that
  sample goes down as it stood (the ground sees the value), every queued command is dropped
  and acknowledged ``rejected`` ``safing`` (acks returned by ``advance_to``), the servo
  targets hold the measured joints, attitude control holds the measured attitude in feedback
  without feedforward, and a ``safing`` report is queued (:meth:`~Vehicle.take_safing_reports`;
  again every onboard second while safe). Commands are refused ``safing`` until
  :meth:`~Vehicle.safe_exit`.
- **Faults** (:mod:`spacecraft.faults`) change the truth simulation at their onset: what the
  servos' hardware applies (the software's target, in telemetry, is unchanged), the wheel
  torques, the attitude sensor, the base's momentum. Their onsets and SAFE's entries and exits
  are the truth log's records (:meth:`~Vehicle.take_truth_events`), never sent down.
- **A diverged simulation** (servos the integrator cannot hold, docs/robots.md "Servo
  stability"): after every step of the truth, MuJoCo's instability warnings (it found the
  state non-finite or huge and reset it) and the state itself against the wire's bounds
  (``telemetry.wire``'s ``MAX_*``). On the first sign the vehicle is SAFE with the trigger
  ``simulation_diverged`` (even when it flies without safing), the schedule dropped as
  above, and from then on it generates **no telemetry frame**: nonsense is never streamed.
  The truth log records the divergence.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, replace
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from numpy.typing import NDArray

from planner.attitude_control import (
    AcsGains,
    AcsMode,
    acs_gains_from_config,
    default_acs_gains,
    reaction_rate_radps,
)
from planner.attitude_law import AttitudeController
from planner.collision import CollisionModel
from planner.dynamics import DynamicsWorkspace
from planner.errors import PlannerError
from planner.limits import Limits
from planner.model import RobotModel, default_model
from planner.simulation import FreeFloatingSimulator, SimConfig
from planner.state import State
from spacecraft._buffer import CommandBuffer
from spacecraft._sensors import Measurement, SensorNoise, measure
from spacecraft.faults import Fault, FaultInjector, FaultSpecError, check_faults
from spacecraft.safing import OnboardSafing, monitor_for
from telemetry.wire import (
    DEFAULT_SCHEDULE_CAPACITY,
    MAX_BASE_RATE_RADPS,
    MAX_JOINT_ABS_RAD,
    MAX_WHEEL_SPEED_RADPS,
    AcsCommandMsg,
    AcsModeName,
    BufferState,
    CommandAck,
    CommandStage,
    JointCommandMsg,
    RejectReason,
    SafeExit,
    Safing,
    SafingTrigger,
    ScheduleDelete,
    TelemetryFrame,
    Verification,
)

if TYPE_CHECKING:
    from planner.robot import RobotDescription

__all__ = ["SensorNoise", "Vehicle", "VehicleConfig", "VehicleError", "vehicle_config_for"]

Array = NDArray[np.float64]

#: SPEC 6: telemetry at least 4 Hz.
MAX_TELEMETRY_PERIOD_S = 0.25
#: An attitude target is a rotation if its norm is 1 within this.
QUAT_NORM_TOLERANCE = 1e-3
# Rates are compared with the limit with this relative slack (plans sit at 0.9 of it; the
# slack only absorbs rounding).
_RATE_SLACK = 1e-9
_IDENTITY = (0.0, 0.0, 0.0, 1.0)
#: What ``hello`` can announce (telemetry.wire.Hello).
MAX_SCHEDULE_CAPACITY = 1_000_000
MAX_LOS_HOLD_AFTER_S = 86_400.0
#: At most this many seq ranges in a ``verification`` (telemetry.wire.Verification).
_MAX_RANGES = 1000


class VehicleError(ValueError):
    """A bad vehicle configuration. (Commands are never raised on: they are acknowledged.)"""


def _default_sim() -> SimConfig:
    return SimConfig(gravity_gradient=True)


def _grid_ns(name: str, value_s: float, step_ns: int) -> int:
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
    initial_quat_orbit_from_base_xyzw: tuple[float, float, float, float] = _IDENTITY
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
        _grid_ns("telemetry_period_s", self.telemetry_period_s, step_ns)
        if self.telemetry_period_s > MAX_TELEMETRY_PERIOD_S:
            raise VehicleError(
                f"telemetry_period_s = {self.telemetry_period_s} s is slower than 4 Hz "
                f"(at most {MAX_TELEMETRY_PERIOD_S} s)"
            )
        _grid_ns("control_period_s", self.control_period_s, step_ns)
        _grid_ns("command_period_s", self.command_period_s, step_ns)
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


class Vehicle:
    """The spacecraft's onboard computer around its truth simulation (see the module doc)."""

    def __init__(self, config: VehicleConfig, *, epoch_ns: int, seed: int) -> None:
        if epoch_ns < 0:
            raise VehicleError(f"epoch_ns = {epoch_ns} must not be negative")
        self.config = config
        model = config.model
        self._ws = DynamicsWorkspace(model, config.sim.orbit)
        self._gains = config.acs_gains or default_acs_gains(self._ws)
        q0 = np.array(config.initial_joints_rad, dtype=np.float64)
        self._sim = FreeFloatingSimulator(
            model,
            State(
                joints_rad=q0,
                quat_orbit_from_base_xyzw=np.array(config.initial_quat_orbit_from_base_xyzw),
                joint_rates_radps=np.zeros_like(q0),
            ),
            replace(
                config.sim,
                wheel_torque_limit_nm=self._gains.torque_limit_nm,
                wheel_momentum_limit_nms=self._gains.momentum_limit_nms,
            ),
        )
        self._epoch_ns = epoch_ns
        self._step_ns = config.step_ns
        self._timestep_s = config.sim.timestep_s
        self._telemetry_ns = _grid_ns("telemetry_period_s", config.telemetry_period_s, 1)
        self._control_ns = _grid_ns("control_period_s", config.control_period_s, 1)
        self._rng = np.random.default_rng(seed)
        self._spin_inertia = np.array([w.spin_inertia_kgm2 for w in model.wheels])

        self._buffer = CommandBuffer()
        #: seq -> the command first received under it (any refusal but ``schedule_full``
        #: records it): a copy is recognised by its content.
        self._received: dict[int, JointCommandMsg | AcsCommandMsg] = {}
        #: seq -> the latest acknowledgement of every command received (a duplicate's
        #: rejection never replaces its original's), for ``command_query`` and copies.
        self._outcomes: dict[int, CommandAck] = {}
        #: request_id -> the report of every ``schedule_delete`` carried out, and the
        #: barriers they left: (from_time_ns, max_seq, request_id).
        self._deletions: dict[int, Verification] = {}
        self._barriers: list[tuple[int, int, int]] = []
        # LOS policy: the onboard time of the last message from the ground, and how long
        # the silence may last before the arm holds (None: policy "continue").
        self._last_heard_ns = epoch_ns
        self._los_hold_ns = (
            round(config.los_hold_after_s * 1e9)
            if config.los_policy == "hold" and config.los_hold_after_s is not None
            else None
        )
        self._last_command_seq = -1
        self._last_executed_seq = -1
        self._next_frame_seq = 0
        self._next_frame_ns = epoch_ns
        self._next_control_ns = epoch_ns
        # The servo target moves at `_target_rate` toward the earliest queued joint command
        # (its tag is `_ramp_to_ns`), or holds (None).
        self._target_rate = np.zeros(model.n_joints)
        self._ramp_to_ns: int | None = None

        self._acs_mode = AcsMode(config.initial_acs_mode.value)
        self._acs_target = np.array(_IDENTITY)
        self._acs_feedforward = False
        self._wheel_torque = np.zeros(3)
        self._law = AttitudeController(self._gains)
        self._sample: tuple[int, State, Measurement] | None = None
        #: the truth state at a step count (the divergence check, control and telemetry at
        #: one instant read it once); cleared where the state changes without a step
        self._truth_state: tuple[int, State] | None = None
        # The onboard software's servo target: `_target` at `_target_ns`, moving at
        # `_target_rate`; the joint servos' hardware applies it through the faults.
        self._target = q0.copy()
        self._target_ns = epoch_ns
        self._lo, self._hi = model.joint_limit_rad[:, 0], model.joint_limit_rad[:, 1]
        self._faults = FaultInjector(config.faults, epoch_ns=epoch_ns, step_ns=self._step_ns)
        self._truth: list[dict[str, Any]] = []
        self._safing = OnboardSafing(epoch_ns=epoch_ns)
        #: onboard ns of the divergence of the truth simulation (None: it holds)
        self._diverged_ns: int | None = None
        self._monitor = (
            monitor_for(
                config.model,
                limits=config.limits,
                collision=config.collision,
                builtin=config.robot is None,
                momentum_limit_nms=self._gains.momentum_limit_nms,
            )
            if config.safing
            else None
        )

    # -- clock and counters -------------------------------------------------------------

    @property
    def epoch_ns(self) -> int:
        return self._epoch_ns

    @property
    def onboard_time_ns(self) -> int:
        return self._epoch_ns + self._sim.step_count * self._step_ns

    @property
    def next_telemetry_seq(self) -> int:
        """The seq the next telemetry frame will carry (= frames generated so far)."""
        return self._next_frame_seq

    @property
    def last_command_seq(self) -> int:
        """The highest command seq received, accepted or not (-1 before the first)."""
        return self._last_command_seq

    # -- state for tests and tools ------------------------------------------------------

    @property
    def gains(self) -> AcsGains:
        return self._gains

    @property
    def acs_mode(self) -> AcsModeName:
        return AcsModeName(self._acs_mode.value)

    @property
    def acs_target_quat_xyzw(self) -> Array:
        return self._acs_target.copy()

    @property
    def acs_feedforward(self) -> bool:
        return self._acs_feedforward

    @property
    def queued(self) -> int:
        return len(self._buffer)

    @property
    def last_heard_ns(self) -> int:
        """The onboard time of the last message from the ground (the epoch before any)."""
        return self._last_heard_ns

    def true_state(self) -> State:
        return self._sim.state()

    def joint_target_rad(self) -> Array:
        """The onboard software's servo target now (the commanded joints exactly at each
        command's tag; a joint fault changes what the hardware applies, not this)."""
        return self._software_target(self.onboard_time_ns)

    # -- on-board safing and faults ------------------------------------------------------

    @property
    def safe(self) -> bool:
        """The vehicle is in SAFE (on-board safing) until a ``safe_exit``."""
        return self._safing.safe

    @property
    def onboard_safing(self) -> OnboardSafing:
        """The SAFE state (when, why, how many commands it dropped), for tests and tools."""
        return self._safing

    def safe_exit(self, req: SafeExit) -> Safing:
        """Leave SAFE (the arm keeps holding, attitude control keeps its feedback hold,
        commands are accepted again): the ``safing`` report ``nominal`` with this
        ``request_id``. Idempotent by ``request_id``; answered ``nominal`` when not safe."""
        self.heard_from_ground()
        report, _ = self._safing.exit(req.request_id, self.onboard_time_ns)
        return report

    def safing_report(self) -> Safing | None:
        """The ``safing`` report of the SAFE state now (None when not safe): what a safe
        vehicle sends right after ``hello``."""
        return self._safing.report(self.onboard_time_ns) if self._safing.safe else None

    def take_safing_reports(self) -> list[Safing]:
        """The ``safing`` reports made since the last call (entry, then every onboard
        second while safe), for the downlink."""
        return self._safing.take_reports()

    def take_truth_events(self) -> list[dict[str, Any]]:
        """The truth log's records since the last call, in time order: each fault's onset,
        each entry into SAFE and exit from it (never sent to the ground)."""
        out = sorted(self._truth + self._safing.take_truth(), key=lambda r: r["onboard_time_ns"])
        self._truth = []
        return out

    def wheel_momentum_nms(self) -> Array:
        """Rotor momentum relative to the base, ``I_w * speed`` (N m s, base frame)."""
        return self._sim.wheel_momentum_nms()

    def wheel_torque_command_nm(self) -> Array:
        """The wheel motor torque the attitude controller commands (clipped at the torque
        limit; the simulator also stops a wheel at its momentum capacity)."""
        return self._wheel_torque.copy()

    # -- uplink ---------------------------------------------------------------------------

    def heard_from_ground(self) -> None:
        """A message from the ground arrived now (any message: the LOS policy's clock)."""
        self._last_heard_ns = max(self._last_heard_ns, self.onboard_time_ns)

    def receive(self, cmd: JointCommandMsg | AcsCommandMsg) -> CommandAck:
        """Check a command against the onboard rules and queue it: ``received``, or
        ``rejected`` with the reason and a detail that names the value and the limit. A copy
        of a command received before is answered with its latest acknowledgement."""
        self.heard_from_ground()
        now = self.onboard_time_ns
        first = self._received.get(cmd.seq)
        if first is not None:
            if first.model_dump() == cmd.model_dump():
                return self._outcomes[cmd.seq]  # a retransmission: "you already have it"
            return self._reject(
                cmd.seq,
                now,
                RejectReason.DUPLICATE,
                f"seq {cmd.seq} was received before with other content; the first one stands",
            )
        self._last_command_seq = max(self._last_command_seq, cmd.seq)
        ack = self._accept(cmd, now)
        if ack.reason is not RejectReason.SCHEDULE_FULL:  # transient: not recorded
            self._received[cmd.seq] = cmd
            self._outcomes[cmd.seq] = ack
        return ack

    def outcome(self, seq: int) -> CommandAck | None:
        """The latest acknowledgement of command ``seq`` (None: never received)."""
        return self._outcomes.get(seq)

    def _accept(self, cmd: JointCommandMsg | AcsCommandMsg, now: int) -> CommandAck:
        if self._safing.safe:
            trigger = self._safing.trigger
            why = f" ({trigger.quantity} {trigger.channel})" if trigger is not None else ""
            return self._reject(
                cmd.seq,
                now,
                RejectReason.SAFING,
                f"the vehicle is safe since {self._safing.since_ns}{why}: no command is "
                "accepted until safe_exit",
            )
        for from_ns, max_seq, request_id in self._barriers:
            if cmd.seq <= max_seq and cmd.execute_time_ns >= from_ns:
                return self._reject(
                    cmd.seq,
                    now,
                    RejectReason.CANCELLED,
                    f"deleted by schedule_delete request {request_id} (tags from {from_ns}, "
                    f"seqs up to {max_seq})",
                )
        if isinstance(cmd, AcsCommandMsg):
            quat = np.array(cmd.target_quat_orbit_from_base_xyzw, dtype=np.float64)
            norm = float(np.linalg.norm(quat))
            if not abs(norm - 1.0) <= QUAT_NORM_TOLERANCE:
                return self._reject(
                    cmd.seq,
                    now,
                    RejectReason.MALFORMED,
                    f"target quaternion has norm {norm:.6g}, not 1 (tolerance "
                    f"{QUAT_NORM_TOLERANCE:g})",
                )
            cmd = cmd.model_copy(update={"target_quat_orbit_from_base_xyzw": list(quat / norm)})
        rejection = self._check_time(cmd, now)
        if rejection is None and isinstance(cmd, JointCommandMsg):
            rejection = self._check_joints(cmd, now)
        if rejection is not None:
            return self._reject(cmd.seq, now, *rejection)
        capacity = self.config.schedule_capacity
        if len(self._buffer) >= capacity:
            return self._reject(
                cmd.seq,
                now,
                RejectReason.SCHEDULE_FULL,
                f"the schedule holds {len(self._buffer)} commands, its capacity {capacity}; "
                "send it again when commands have executed",
            )
        self._buffer.add(cmd)
        if isinstance(cmd, JointCommandMsg) and (
            self._ramp_to_ns is None or cmd.execute_time_ns < self._ramp_to_ns
        ):
            self._ramp_to_next(now)  # it is the next one now: head for it from here
        return CommandAck(seq=cmd.seq, stage=CommandStage.RECEIVED, onboard_time_ns=now)

    def _check_time(
        self, cmd: JointCommandMsg | AcsCommandMsg, now: int
    ) -> tuple[RejectReason, str] | None:
        tag = cmd.execute_time_ns
        off = (tag - self._epoch_ns) % self._step_ns
        if off:
            return RejectReason.MALFORMED, (
                f"execute_time_ns {tag} is {off} ns off the onboard "
                f"{self._step_ns / 1e6:g} ms step grid (epoch {self._epoch_ns})"
            )
        if tag <= now:
            return RejectReason.LATE, (
                f"execute_time_ns {tag} is {(now - tag) / 1e9:.3f} s at or before "
                f"onboard time {now}"
            )
        other = self._buffer.joint_taken_by(tag) if isinstance(cmd, JointCommandMsg) else None
        if other is not None:
            return RejectReason.MALFORMED, (
                f"execute_time_ns {tag} already holds joint command seq {other.seq}"
            )
        return None

    def _check_joints(self, cmd: JointCommandMsg, now: int) -> tuple[RejectReason, str] | None:
        model = self.config.model
        if len(cmd.joints_rad) != model.n_joints:
            # The wire takes any joint count (1..MAX_JOINTS): this robot's is checked here.
            return RejectReason.MALFORMED, (
                f"joints_rad has {len(cmd.joints_rad)} values, this robot has "
                f"{model.n_joints} joints"
            )
        q = np.array(cmd.joints_rad, dtype=np.float64)
        for i, (angle, (lo, hi)) in enumerate(zip(q, model.joint_limit_rad, strict=True)):
            if angle < lo or angle > hi:
                limit = hi if angle > hi else lo
                return RejectReason.OUT_OF_LIMITS, (
                    f"joint {i + 1} at {math.degrees(angle):.3f} deg exceeds limit "
                    f"{math.degrees(limit):.3f} deg"
                )
        tag = cmd.execute_time_ns
        before, after = self._buffer.joint_neighbours(tag)
        steps: list[tuple[Array, int, str]] = []
        if before is not None:
            prev = np.array(before.joints_rad)
            steps.append((prev, tag - before.execute_time_ns, f"from seq {before.seq}"))
        else:  # it will be ramped to from where the target stands now
            steps.append((self._software_target(now), tag - now, "from the current target"))
        if after is not None:
            steps.append(
                (np.array(after.joints_rad), after.execute_time_ns - tag, f"to seq {after.seq}")
            )
        limits = model.joint_rate_limit_radps
        for other, dt_ns, relation in steps:
            rates = np.abs(q - other) / (dt_ns / 1e9)
            worst = int(np.argmax(rates / limits))
            if rates[worst] > limits[worst] * (1.0 + _RATE_SLACK):
                return RejectReason.OUT_OF_LIMITS, (
                    f"joint {worst + 1} moves {math.degrees(abs(q[worst] - other[worst])):.3f} "
                    f"deg in {dt_ns / 1e9:.3f} s {relation}: "
                    f"{math.degrees(rates[worst]):.3f} deg/s exceeds limit "
                    f"{math.degrees(limits[worst]):.3f} deg/s"
                )
        return None

    def _reject(self, seq: int, now: int, reason: RejectReason, detail: str) -> CommandAck:
        return CommandAck(
            seq=seq,
            stage=CommandStage.REJECTED,
            reason=reason,
            detail=detail[:300],
            onboard_time_ns=now,
        )

    def link_lost(self) -> list[CommandAck]:
        """SPEC 6 safe state now (what the ``hold`` LOS policy does after its silence):
        refuse every queued joint command (``link_lost``) and hold the servo target where it
        stands; attitude control carries on in its mode."""
        return self._hold_arm(self.onboard_time_ns, "link lost: the arm holds its target")

    def _hold_arm(self, now: int, detail: str) -> list[CommandAck]:
        acks = [
            self._reject(cmd.seq, now, RejectReason.LINK_LOST, detail)
            for cmd in self._buffer.pop_joints()
        ]
        self._outcomes.update((ack.seq, ack) for ack in acks)
        self._ramp_to_next(now)  # nothing queued: hold
        return acks

    def _los_deadline_ns(self) -> int | None:
        """When the ``hold`` LOS policy holds the arm (the first grid point at or after
        the allowed silence), if it has joint commands to refuse."""
        if self._los_hold_ns is None or not self._buffer.joints_queued:
            return None
        t = self._last_heard_ns + self._los_hold_ns
        steps = -((self._epoch_ns - t) // self._step_ns)  # ceil
        return self._epoch_ns + steps * self._step_ns

    def delete_schedule(self, req: ScheduleDelete) -> Verification:
        """PUS 11 delete by time range: every queued command tagged at or after
        ``req.from_time_ns`` with seq at most ``req.max_seq`` is deleted (outcome
        ``cancelled``), and such commands arriving later are refused ``cancelled``. The
        report counts the deleted commands, lists their seqs and counts those of the range
        that had executed already. Idempotent by ``request_id``."""
        self.heard_from_ground()
        done = self._deletions.get(req.request_id)
        if done is not None:
            return done
        now = self.onboard_time_ns
        from_ns, max_seq = req.from_time_ns, req.max_seq
        executed = sum(
            1
            for ack in self._outcomes.values()
            # an executed ack's time is the command's tag
            if ack.stage is CommandStage.EXECUTED
            and ack.seq <= max_seq
            and ack.onboard_time_ns >= from_ns
        )
        deleted = self._buffer.pop_where(
            lambda c: c.seq <= max_seq and c.execute_time_ns >= from_ns
        )
        why = f"deleted by schedule_delete request {req.request_id}"
        for cmd in deleted:
            self._outcomes[cmd.seq] = self._reject(cmd.seq, now, RejectReason.CANCELLED, why)
        self._barriers.append((from_ns, max_seq, req.request_id))
        nxt = self._buffer.first_joint()
        if (nxt.execute_time_ns if nxt is not None else None) != self._ramp_to_ns:
            self._ramp_to_next(now)  # the command ramped to is gone: the next one, or hold
        ranges = _ranges(sorted(cmd.seq for cmd in deleted))
        notes = []
        if from_ns <= now:
            notes.append(
                f"from_time_ns {from_ns} is at or before onboard time {now}: every queued "
                f"command up to seq {max_seq} deleted"
            )
        if len(ranges) > _MAX_RANGES:
            notes.append(f"{len(ranges)} seq ranges, the first {_MAX_RANGES} listed")
            ranges = ranges[:_MAX_RANGES]
        report = Verification(
            request_id=req.request_id,
            stage="completed",
            deleted=len(deleted),
            deleted_ranges=ranges,
            executed_after_from=executed,
            detail="; ".join(notes)[:300] or None,
            onboard_time_ns=now,
        )
        self._deletions[req.request_id] = report
        return report

    # -- time ---------------------------------------------------------------------------

    def advance_to(self, time_ns: int) -> tuple[list[CommandAck], list[TelemetryFrame]]:
        """Run the vehicle to ``time_ns`` (onboard clock; down to the step grid). Returns the
        ``executed`` acks and the telemetry frames generated on the way, in time order."""
        acks: list[CommandAck] = []
        frames: list[TelemetryFrame] = []
        if time_ns < self.onboard_time_ns:
            return acks, frames
        end = self._epoch_ns + (time_ns - self._epoch_ns) // self._step_ns * self._step_ns
        while True:
            tag = self._buffer.next_tag_ns()
            los = self._los_deadline_ns()
            fault = self._faults.next_onset_ns
            report = self._safing.next_report_ns
            t = min(
                x
                for x in (self._next_control_ns, self._next_frame_ns, tag, los, fault, report)
                if x is not None
            )
            if t > end:
                break
            self._step_to(t)
            if self._diverged_ns is None:
                diverged = self._divergence(t)
                if diverged is not None:
                    acks += self._enter_diverged(t, diverged)
            if fault == t:  # the truth changes first: what is measured at t shows it
                self._truth += self._faults.begin(t, self._sim)
                self._truth_state = None  # a bump changed the velocities
                self._apply_servo(t)
            trigger = self._check_safing(t) if t == self._next_control_ns else None
            if trigger is not None:  # before the commands due at t: none executes
                # the frame of the sample that tripped, as it stood (the ground sees the
                # value), then SAFE: the regular frame at t, if any, is this one
                if self._diverged_ns is None:
                    frames.append(self._frame(t))
                if t == self._next_frame_ns:
                    self._next_frame_ns += self._telemetry_ns
                acks += self._enter_safe(t, trigger)
            if los == t:  # the silence lasted: no joint command executes from now on
                silent_s = (t - self._last_heard_ns) / 1e9
                acks += self._hold_arm(
                    t,
                    f"nothing from the ground for {silent_s:.3f} s (LOS policy hold after "
                    f"{self.config.los_hold_after_s:g} s): the arm holds its target",
                )
            if tag == t:  # commands first: control and telemetry at t see their effect
                acks += self._execute(t)
            if t == self._next_control_ns:
                self._control(t)
                self._next_control_ns += self._control_ns
            if report == t:
                self._safing.tick(t)
            if t == self._next_frame_ns:
                if self._diverged_ns is None:  # a diverged truth is never streamed
                    frames.append(self._frame(t))
                self._next_frame_ns += self._telemetry_ns
        self._step_to(end)
        if self._diverged_ns is None:
            diverged = self._divergence(end)
            if diverged is not None:
                acks += self._enter_diverged(end, diverged)
        return acks, frames

    @property
    def diverged_ns(self) -> int | None:
        """When the truth simulation diverged (onboard ns), None while it holds."""
        return self._diverged_ns

    def _divergence(self, t: int) -> SafingTrigger | None:
        """The sign that the truth simulation has diverged by ``t``, or None."""
        warnings = self._sim.instability_warnings
        if warnings:
            return SafingTrigger(
                quantity="simulation_diverged",
                channel="",
                value=float(warnings),
                limit=0.0,
                detail=f"the truth simulation diverged by onboard {t}: MuJoCo reset its "
                f"non-finite or huge state {warnings} time(s) (servos faster than the "
                "integrator holds?)",
            )
        state = self._state()
        checks = (
            ("joints", np.abs(state.joints_rad), MAX_JOINT_ABS_RAD, "rad"),
            ("base rate", np.abs(state.omega_base_orbit_radps), MAX_BASE_RATE_RADPS, "rad/s"),
            ("wheel speed", np.abs(state.wheel_rates_radps), MAX_WHEEL_SPEED_RADPS, "rad/s"),
        )
        for name, values, bound, unit in checks:
            if values.size == 0 or values.max() <= bound:  # finite and within (NaN: false)
                continue
            bad = ~np.isfinite(values) | (np.nan_to_num(values, nan=np.inf) > bound)
            if np.any(bad):
                worst = float(values[int(np.argmax(bad))])
                return SafingTrigger(
                    quantity="simulation_diverged",
                    channel=name.replace(" ", "_"),
                    value=worst if math.isfinite(worst) else 1e308,
                    limit=bound,
                    detail=f"the truth simulation diverged by onboard {t}: {name} {worst:.6g} "
                    f"{unit} (beyond {bound:g} {unit} or not finite)",
                )
        return None

    def _enter_diverged(self, t: int, trigger: SafingTrigger) -> list[CommandAck]:
        """The truth has diverged at ``t``: SAFE with that trigger (already SAFE: the
        divergence is logged), and no frame from now on."""
        self._diverged_ns = t
        self._truth.append(
            {
                "event": "simulation_diverged",
                "onboard_time_ns": t,
                "onboard_s": (t - self._epoch_ns) / 1e9,
                **trigger.model_dump(),
            }
        )
        if self._safing.safe:
            return []
        return self._enter_safe(t, trigger)

    def _step_to(self, t: int) -> None:
        steps = (t - self.onboard_time_ns) // self._step_ns
        if steps > 0:
            torque = self._faults.wheel_torque(self._wheel_torque)
            self._sim.advance(steps * self._timestep_s, wheel_torque_nm=torque)

    def _execute(self, t: int) -> list[CommandAck]:
        acks = []
        for cmd in self._buffer.pop_due(t):
            if isinstance(cmd, JointCommandMsg):
                self._set_target(np.array(cmd.joints_rad, dtype=np.float64), None, t)
                self._ramp_to_next(t)
            else:
                self._acs_mode = AcsMode(cmd.mode.value)
                self._acs_target = np.array(cmd.target_quat_orbit_from_base_xyzw)
                self._acs_feedforward = cmd.feedforward
                self._control(t)  # the switch takes effect at the tag, not at the next tick
            self._last_executed_seq = cmd.seq
            ack = CommandAck(seq=cmd.seq, stage=CommandStage.EXECUTED, onboard_time_ns=t)
            self._outcomes[cmd.seq] = ack
            acks.append(ack)
        return acks

    def _ramp_to_next(self, now: int) -> None:
        """Move the servo target from where it stands now to the earliest queued joint
        command, reaching it at its tag; hold if there is none."""
        target = self._software_target(now)
        nxt = self._buffer.first_joint()
        if nxt is None:
            rate, self._ramp_to_ns = np.zeros_like(target), None
        else:
            duration_s = (nxt.execute_time_ns - now) / 1e9
            rate = (np.array(nxt.joints_rad) - target) / duration_s
            self._ramp_to_ns = nxt.execute_time_ns
        self._set_target(target, rate, now)

    def _software_target(self, t: int) -> Array:
        """The onboard software's servo target at ``t`` (it saturates at the joint limits)."""
        target = self._target + self._target_rate * ((t - self._target_ns) / 1e9)
        return np.clip(target, self._lo, self._hi)

    def _set_target(self, target: Array, rate: Array | None, now: int) -> None:
        """The software's servo target from ``now`` (moving at ``rate``; None: holding),
        applied by the servos' hardware."""
        self._target = np.clip(target, self._lo, self._hi)
        self._target_ns = now
        self._target_rate = np.zeros_like(self._target) if rate is None else rate
        self._apply_servo(now)

    def _apply_servo(self, now: int) -> None:
        """The software's target through the joint faults to the servos."""
        target, rate = self._faults.servo(self._software_target(now), self._target_rate, now)
        self._sim.set_joint_target(target, rate)

    def _check_safing(self, t: int) -> SafingTrigger | None:
        """The red limit crossed by the measured sample at ``t`` (None: none, or the vehicle
        is safe already, or flies without safing)."""
        if self._monitor is None or self._safing.safe:
            return None
        state, m = self._measure(t)
        return self._monitor.check(
            joint_targets_rad=self._software_target(t),
            joints_rad=m.joints_rad,
            quat_orbit_from_base_xyzw=m.quat_orbit_from_base_xyzw,
            acs_target_quat_xyzw=self._acs_target,
            wheel_speeds_radps=state.wheel_rates_radps,
        )

    def _enter_safe(self, t: int, trigger: SafingTrigger) -> list[CommandAck]:
        """SAFE at ``t``: every queued command dropped (acknowledged ``rejected``
        ``safing``), the arm held where it is measured, attitude control to feedback on the
        measured attitude, the entry report queued."""
        _, m = self._measure(t)
        channel = f" {trigger.channel}" if trigger.channel else ""
        detail = (
            f"on-board safing at {t}: {trigger.quantity}{channel} {trigger.value:.4g} "
            f"beyond its red limit {trigger.limit:g}"
        )
        dropped = self._buffer.pop_where(lambda _: True)
        acks = [self._reject(cmd.seq, t, RejectReason.SAFING, detail) for cmd in dropped]
        self._outcomes.update((ack.seq, ack) for ack in acks)
        # hold the arm where it is measured, and the attitude where it is measured
        self._ramp_to_ns = None
        self._set_target(m.joints_rad, None, t)
        self._acs_mode = AcsMode.FEEDBACK
        self._acs_target = m.quat_orbit_from_base_xyzw.copy()
        self._acs_feedforward = False
        self._safing.enter(t, trigger, len(dropped))
        return acks

    # -- onboard attitude control and telemetry -------------------------------------------

    def _state(self) -> State:
        """The truth state now, read once per step count (shared, read only)."""
        steps = self._sim.step_count
        if self._truth_state is None or self._truth_state[0] != steps:
            self._truth_state = (steps, self._sim.state())
        return self._truth_state[1]

    def _measure(self, t: int) -> tuple[State, Measurement]:
        """The sensor sample at ``t`` (one per instant: control and telemetry share it)."""
        if self._sample is None or self._sample[0] != t:
            state = self._state()
            sample = self._faults.sense(measure(state, self.config.noise, self._rng))
            self._sample = (t, state, sample)
        return self._sample[1], self._sample[2]

    def _control(self, t: int) -> None:
        t_s = (t - self._epoch_ns) / 1e9
        if self._acs_mode is AcsMode.FREE_DRIFT:
            self._wheel_torque = self._law.torque(t_s, AcsMode.FREE_DRIFT)
            return
        _, m = self._measure(t)
        reaction = (
            reaction_rate_radps(self._ws, self._software_target(t), self._target_rate)
            if self._acs_feedforward
            else None
        )
        self._wheel_torque = self._law.torque(
            t_s,
            self._acs_mode,
            target_quat_xyzw=self._acs_target,
            quat_orbit_from_base_xyzw=m.quat_orbit_from_base_xyzw,
            omega_base_radps=m.omega_base_in_base_radps,
            reaction_rate_radps=reaction,
        )

    def _frame(self, t: int) -> TelemetryFrame:
        state, m = self._measure(t)
        frame = TelemetryFrame(
            seq=self._next_frame_seq,
            generation_time_ns=t,
            joints_rad=m.joints_rad.tolist(),
            joint_targets_rad=self._software_target(t).tolist(),
            quat_orbit_from_base_xyzw=m.quat_orbit_from_base_xyzw.tolist(),
            omega_base_in_base_radps=m.omega_base_in_base_radps.tolist(),
            wheel_speeds_radps=state.wheel_rates_radps.tolist(),
            wheel_momentum_nms=(self._spin_inertia * state.wheel_rates_radps).tolist(),
            acs_mode=self.acs_mode,
            acs_target_quat_xyzw=self._acs_target.tolist(),
            acs_feedforward=self._acs_feedforward,
            buffer=BufferState(
                queued=len(self._buffer),
                next_execute_time_ns=self._buffer.next_tag_ns(),
                last_executed_seq=self._last_executed_seq,
                last_queued_time_ns=self._buffer.last_tag_ns(),
                capacity=self.config.schedule_capacity,
            ),
        )
        self._next_frame_seq += 1
        return frame


def _ranges(seqs: list[int]) -> list[tuple[int, int]]:
    """Sorted seqs as inclusive ranges of consecutive seqs."""
    out: list[tuple[int, int]] = []
    for seq in seqs:
        if out and seq == out[-1][1] + 1:
            out[-1] = (out[-1][0], seq)
        else:
            out.append((seq, seq))
    return out
