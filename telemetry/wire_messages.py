"""The space-ground wire protocol's messages, version 2: the pydantic models of what
crosses the relay link, each way, and the protocol's constants they are built on.

Every message is one JSON object in one websocket text frame, with ``"v"`` (the protocol
version) and ``"type"``. Times are integer nanoseconds of the **onboard clock**
(``*_time_ns``); angles in radians, rates in rad/s, momentum in N m s. The full description,
with the sequencing and acknowledgement rules, is ``docs/protocol.md``.

Ground -> spacecraft: ``command`` (``joints`` or ``acs``), ``schedule_delete``,
``telemetry_ack``, ``retransmit``, ``ping``, ``command_query``, ``safe_exit``. Spacecraft ->
ground: ``hello``, ``command_ack``, ``verification``, ``telemetry``, ``pong``,
``command_unknown``, ``safing``, ``error``. The messages are shaped after the ECSS PUS
services they mirror (11 time-based schedule: ``command``, ``schedule_delete`` and the
schedule summary in every frame's ``buffer``; 1 request verification: ``command_ack``,
``verification``; 3 housekeeping: ``telemetry``; 17 test: ``ping``/``pong``), so that a
binary CCSDS Space Packet encoding is only another codec.

The models check each field's shape and range; the codec (:mod:`telemetry.wire`: the
decoders, their cheap refusals before any model sees a message, the physical bounds of a
frame, and :func:`~telemetry.wire.encode`) is the way in and out, and re-exports every name
of this module: its ``__all__`` lists them, once (this module has none of its own).
"""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

PROTOCOL_VERSION = 2
#: Commands the onboard schedule holds unless ``hello`` announces otherwise.
DEFAULT_SCHEDULE_CAPACITY = 1024
#: At most this many frames in one telemetry message.
MAX_FRAMES_PER_MESSAGE = 200
#: The most joints (and reaction wheels) a robot may have on the wire; how many a session's
#: robot has is its :class:`telemetry.layout.FrameLayout` (ETS-VII: 6 joints, 3 wheels).
MAX_JOINTS = 32
MAX_WHEELS = 16


class _Obj(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class _Msg(_Obj):
    v: Literal[2] = 2


Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
#: One value per joint (or wheel): the length is the robot's, checked against its layout
#: where the receiver knows it (:func:`telemetry.wire.decode_ground`, ``decode_spacecraft``).
JointVec = Annotated[list[float], Field(min_length=1, max_length=MAX_JOINTS)]
WheelVec = Annotated[list[float], Field(min_length=1, max_length=MAX_WHEELS)]
Quat = Annotated[list[float], Field(min_length=4, max_length=4)]
Seq = Annotated[int, Field(ge=0, lt=2**53)]
TimeNs = Annotated[int, Field(ge=0, lt=2**63)]


class AcsModeName(StrEnum):
    FEEDBACK = "feedback"
    FREE_DRIFT = "free_drift"


# --- ground -> spacecraft ----------------------------------------------------------------


class JointCommandMsg(_Msg):
    """Joint targets to reach at ``execute_time_ns``; between consecutive joint commands
    (tags one command period apart) the target moves linearly."""

    type: Literal["command"] = "command"
    kind: Literal["joints"] = "joints"
    seq: Seq
    execute_time_ns: TimeNs
    joints_rad: JointVec


class AcsCommandMsg(_Msg):
    """Attitude-control mode, target and momentum feedforward from ``execute_time_ns``."""

    type: Literal["command"] = "command"
    kind: Literal["acs"] = "acs"
    seq: Seq
    execute_time_ns: TimeNs
    mode: AcsModeName
    target_quat_orbit_from_base_xyzw: Quat = Field(default_factory=lambda: [0.0, 0.0, 0.0, 1.0])
    feedforward: bool = False


class TelemetryAck(_Msg):
    """Every frame with ``seq <= through_seq`` arrived, and those in ``ranges`` (inclusive)."""

    type: Literal["telemetry_ack"] = "telemetry_ack"
    through_seq: Annotated[int, Field(ge=-1, lt=2**53)]
    ranges: Annotated[list[tuple[Seq, Seq]], Field(max_length=1000)] = Field(default_factory=list)


class Retransmit(_Msg):
    """Send these frames again (inclusive ranges), oldest first."""

    type: Literal["retransmit"] = "retransmit"
    ranges: Annotated[list[tuple[Seq, Seq]], Field(min_length=1, max_length=1000)]


class ScheduleDelete(_Msg):
    """Delete from the onboard schedule every command tagged at or after ``from_time_ns``
    whose seq is at most ``max_seq`` (PUS 11, delete time-tagged activities by time range),
    and refuse (``cancelled``) any such command that arrives later: copies still in the
    relay must not refill what was deleted. Commands of a later plan (seq above
    ``max_seq``) are not touched. Idempotent by ``request_id``: a repeat is answered with the
    first report and changes nothing. The arm holds at the last joint target left."""

    type: Literal["schedule_delete"] = "schedule_delete"
    request_id: Seq
    from_time_ns: TimeNs
    max_seq: Seq


class Ping(_Msg):
    type: Literal["ping"] = "ping"
    ping_id: Seq
    ground_time_ns: TimeNs


class CommandQuery(_Msg):
    """Ask what became of these commands (their acknowledgements may have been lost): the
    spacecraft answers each seq it knows with its latest ``command_ack`` again, and the
    others with one ``command_unknown``."""

    type: Literal["command_query"] = "command_query"
    seqs: Annotated[list[Seq], Field(min_length=1, max_length=1000)]


# --- spacecraft -> ground ----------------------------------------------------------------


class Hello(_Msg):
    """First message after (re)connecting: who is there and what its clock says."""

    type: Literal["hello"] = "hello"
    vehicle: str = Field(max_length=64)
    onboard_time_ns: TimeNs
    time_scale: Annotated[float, Field(gt=0, le=1000)]
    next_telemetry_seq: Seq
    last_command_seq: Annotated[int, Field(ge=-1)] = -1
    #: Commands the onboard schedule can hold; more are refused ``schedule_full``.
    schedule_capacity: Annotated[int, Field(ge=1, le=1_000_000)] = DEFAULT_SCHEDULE_CAPACITY
    #: What the vehicle does when it hears nothing from the ground: ``continue`` the
    #: loaded schedule, or ``hold`` (delete the joint commands) after ``los_hold_after_s``.
    los_policy: Literal["continue", "hold"] = "continue"
    los_hold_after_s: Annotated[float, Field(gt=0, le=86_400)] | None = None
    #: The robot flown (its description's name), a hash of its description, and its joint
    #: count: absent from a peer that predates them (ETS-VII, 6 joints, is then assumed).
    #: Left out of the encoded message when None, so such a ``hello`` reads as before.
    robot: str | None = Field(default=None, min_length=1, max_length=64)
    robot_hash: str | None = Field(default=None, min_length=1, max_length=128)
    n_joints: Annotated[int, Field(ge=1, le=MAX_JOINTS)] | None = None


class CommandStage(StrEnum):
    RECEIVED = "received"
    EXECUTED = "executed"
    REJECTED = "rejected"


class RejectReason(StrEnum):
    LATE = "late"  # arrived at or after its tag; never executed late
    OUT_OF_LIMITS = "out_of_limits"  # joint angle or rate beyond its limit
    MALFORMED = "malformed"  # tag off the onboard grid, not a rotation, ...
    DUPLICATE = "duplicate"  # this seq was seen before; the first one stands
    LINK_LOST = "link_lost"  # deleted by the LOS policy (no word from the ground): arm holds
    CANCELLED = "cancelled"  # deleted from the schedule by a ``schedule_delete`` (abort)
    SCHEDULE_FULL = "schedule_full"  # the onboard schedule holds its capacity already
    SAFING = "safing"  # dropped or refused because the vehicle is in SAFE (on-board safing)


class CommandAck(_Msg):
    type: Literal["command_ack"] = "command_ack"
    seq: Seq
    stage: CommandStage
    reason: RejectReason | None = None
    detail: str | None = Field(default=None, max_length=300)
    onboard_time_ns: TimeNs


class BufferState(_Obj):
    """The onboard schedule's summary (PUS 11): how many commands it holds, the first and
    last tag, its capacity, and the last command executed."""

    queued: Annotated[int, Field(ge=0)]
    next_execute_time_ns: TimeNs | None = None
    last_executed_seq: Annotated[int, Field(ge=-1)] = -1
    #: the last tag the schedule holds (``next_execute_time_ns`` is the first)
    last_queued_time_ns: TimeNs | None = None
    capacity: Annotated[int, Field(ge=1)] | None = None


class TelemetryFrame(_Obj):
    """One sample of the vehicle (SPEC section 6), measured with sensor noise."""

    seq: Seq
    generation_time_ns: TimeNs
    joints_rad: JointVec
    joint_targets_rad: JointVec
    quat_orbit_from_base_xyzw: Quat
    omega_base_in_base_radps: Vec3  # gyro: base rate in the base frame
    wheel_speeds_radps: WheelVec  # relative to the base, one per wheel
    wheel_momentum_nms: Vec3  # I_w * speed, base frame
    acs_mode: AcsModeName
    acs_target_quat_xyzw: Quat
    acs_feedforward: bool
    buffer: BufferState


class TelemetryMsg(_Msg):
    type: Literal["telemetry"] = "telemetry"
    frames: Annotated[list[TelemetryFrame], Field(min_length=1, max_length=MAX_FRAMES_PER_MESSAGE)]
    retransmission: bool = False


class Pong(_Msg):
    type: Literal["pong"] = "pong"
    ping_id: Seq
    ground_time_ns: TimeNs
    onboard_time_ns: TimeNs


class CommandUnknown(_Msg):
    """The reply to ``command_query`` for seqs the vehicle never received."""

    type: Literal["command_unknown"] = "command_unknown"
    seqs: Annotated[list[Seq], Field(min_length=1, max_length=1000)]
    onboard_time_ns: TimeNs


class Verification(_Msg):
    """The report on a request that is not a command (PUS 1): ``completed`` with what it
    did, or ``failed`` with the reason. For ``schedule_delete``: how many commands were
    deleted, their seqs as inclusive ranges, and how many of the range had already executed
    (the request arrived after their tag)."""

    type: Literal["verification"] = "verification"
    request_id: Seq
    request_type: Literal["schedule_delete"] = "schedule_delete"
    stage: Literal["completed", "failed"]
    deleted: Annotated[int, Field(ge=0)] = 0
    deleted_ranges: Annotated[list[tuple[Seq, Seq]], Field(max_length=1000)] = Field(
        default_factory=list
    )
    executed_after_from: Annotated[int, Field(ge=0)] = 0
    detail: str | None = Field(default=None, max_length=300)
    onboard_time_ns: TimeNs


class SafeExit(_Msg):
    """The telecommand that takes the vehicle out of SAFE (on-board safing): only the ground
    ends it. Answered by a ``safing`` report (``state`` ``nominal``, this ``request_id``);
    idempotent by ``request_id``, and harmless when the vehicle is not safe."""

    type: Literal["safe_exit"] = "safe_exit"
    request_id: Seq


class SafingTrigger(_Obj):
    """What made the vehicle safe itself: the monitored quantity (``planner.limits``'s
    name), its channel (``joint3``, ``x``, ``wheel2``, empty for a scalar), the value it
    measured and the red limit it crossed."""

    quantity: str = Field(min_length=1, max_length=64)
    channel: str = Field(default="", max_length=32)
    value: float
    limit: float
    detail: str | None = Field(default=None, max_length=300)


class Safing(_Msg):
    """The vehicle's on-board safing state (docs/protocol.md, "On-board safing"): sent when
    it enters SAFE, again every second (onboard) while it stays, and when a ``safe_exit``
    takes it out (``state`` ``nominal`` with that ``exit_request_id``; a copy of the
    telecommand gets the same report)."""

    type: Literal["safing"] = "safing"
    state: Literal["safe", "nominal"]
    #: onboard time SAFE was entered (the one being reported, or left)
    since_time_ns: TimeNs | None = None
    trigger: SafingTrigger | None = None
    #: commands dropped from the schedule on entry (each acknowledged ``rejected``
    #: ``safing``)
    cancelled: Annotated[int, Field(ge=0)] = 0
    exit_request_id: Seq | None = None
    onboard_time_ns: TimeNs


class ErrorMsg(_Msg):
    """The reply to a message that could not be understood; the process carries on."""

    type: Literal["error"] = "error"
    reason: str = Field(max_length=500)
    ref_type: str | None = Field(default=None, max_length=64)


#: The messages each way, as plain unions (what the decoders return).
GroundMessageT = (
    JointCommandMsg
    | AcsCommandMsg
    | ScheduleDelete
    | TelemetryAck
    | Retransmit
    | Ping
    | CommandQuery
    | SafeExit
)
SpacecraftMessageT = (
    Hello | CommandAck | Verification | TelemetryMsg | Pong | CommandUnknown | Safing | ErrorMsg
)
GroundMessage = Annotated[GroundMessageT, Field(discriminator="type")]
SpacecraftMessage = Annotated[SpacecraftMessageT, Field(discriminator="type")]
#: The ``type`` of every spacecraft -> ground message.
SPACECRAFT_TYPES = frozenset(
    str(m.model_fields["type"].default) for m in SpacecraftMessageT.__args__
)
