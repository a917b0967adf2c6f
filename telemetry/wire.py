"""The space-ground wire protocol, version 2: what crosses the relay link.

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
binary CCSDS Space Packet encoding is only another codec. Version 1 (each command sent once,
just in time) is not served: its messages get an ``error`` reply naming the version this end
speaks.

:func:`decode_ground` and :func:`decode_spacecraft` accept only well-formed messages of this
version and raise :class:`WireError` (with a reason fit for an ``error`` reply) for anything
else. Before any model sees it, a message is refused when it is larger than
:data:`MAX_MESSAGE_BYTES`, nested deeper than :data:`MAX_DEPTH`, or holds a control
character (C0 with tab, newline and carriage return, DEL, C1) or a lone surrogate in any
string, keys included: no protocol message has a legitimate use for one, and the text a
receiver stores must read the same on every database (PostgreSQL refuses NUL). An ``error``
message alone is not refused for its text: it must never be answered with an ``error``, so
the control characters of its string values are escaped instead (NUL becomes the four
characters ``\x00``) and it is delivered.

The cheap refusals come first, so that noise costs little more than its JSON parse: the size,
the parse, then the top-level ``v`` and ``type`` (a wrong version, no type, or, on the
spacecraft -> ground direction, a type the protocol does not have) before the walk of the
whole tree and the field validation. Their reasons show the offending value through
``repr`` (which escapes every control character and lone surrogate), cut short.
"""

from __future__ import annotations

import itertools
import json
import math
import re
from enum import StrEnum
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError

if TYPE_CHECKING:
    from telemetry.layout import FrameLayout

__all__ = [
    "DEFAULT_SCHEDULE_CAPACITY",
    "MAX_BASE_RATE_RADPS",
    "MAX_DEPTH",
    "MAX_JOINTS",
    "MAX_JOINT_ABS_RAD",
    "MAX_MESSAGE_BYTES",
    "MAX_WHEELS",
    "MAX_WHEEL_SPEED_RADPS",
    "PROTOCOL_VERSION",
    "SPACECRAFT_TYPES",
    "WIRE_ERROR_CODES",
    "AcsCommandMsg",
    "AcsModeName",
    "BufferState",
    "CommandAck",
    "CommandQuery",
    "CommandStage",
    "CommandUnknown",
    "ErrorMsg",
    "GroundMessage",
    "Hello",
    "JointCommandMsg",
    "Ping",
    "Pong",
    "RejectReason",
    "Retransmit",
    "SafeExit",
    "Safing",
    "SafingTrigger",
    "ScheduleDelete",
    "SpacecraftMessage",
    "TelemetryAck",
    "TelemetryFrame",
    "TelemetryMsg",
    "Verification",
    "WireError",
    "decode_ground",
    "decode_spacecraft",
    "encode",
    "escape_controls",
]

PROTOCOL_VERSION = 2
#: Commands the onboard schedule holds unless ``hello`` announces otherwise.
DEFAULT_SCHEDULE_CAPACITY = 1024
#: Larger messages are refused unread (a backlog dump is split into smaller batches).
MAX_MESSAGE_BYTES = 256 * 1024
#: At most this many frames in one telemetry message.
MAX_FRAMES_PER_MESSAGE = 200
#: Deeper messages are refused before validation. The deepest real one is 4 levels
#: (``telemetry`` > ``frames`` > a frame > ``joints_rad`` or ``buffer``); 16 leaves room for
#: later versions and still keeps hostile nesting away from the recursive validators.
MAX_DEPTH = 16
#: The most joints (and reaction wheels) a robot may have on the wire; how many a session's
#: robot has is its :class:`telemetry.layout.FrameLayout` (ETS-VII: 6 joints, 3 wheels).
MAX_JOINTS = 32
MAX_WHEELS = 16
#: What no telemetry frame of a real vehicle can hold (our choice, far outside every robot's
#: envelope): a frame beyond them is a diverged simulation or broken software, refused
#: ``unphysical`` and never archived. Joints: continuous joints turn +-2 pi, so 4 pi is past
#: any measured angle or target; the base: 10 rad/s (ETS-VII's attitude rates are
#: 1e-3 rad/s); wheels: 1e4 rad/s (about 95,000 rpm) and 1e4 N m s; the quaternion's norm
#: within 0.1 of 1.
MAX_JOINT_ABS_RAD = 4.0 * math.pi
MAX_BASE_RATE_RADPS = 10.0
MAX_WHEEL_SPEED_RADPS = 1e4
_MAX_WHEEL_MOMENTUM_NMS = 1e4
_QUAT_NORM_TOLERANCE = 0.1

#: What no string of a message may hold: C0 controls (tab, newline and carriage return
#: included: no field of the protocol is multi-line text), DEL, C1 controls, and lone
#: surrogates (``\ud800`` escapes; not Unicode, no database stores them).
_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f\ud800-\udfff]")
#: What in a message's text may decode to such a character: an escape, raw DEL or C1
#: (JSON itself refuses raw C0 characters in strings).
_SUSPECT = re.compile(r"[\\\x7f-\x9f]")
_SUSPECT_BYTES = re.compile(rb"[\\\x7f]|\xc2[\x80-\x9f]")


#: The classes of :class:`WireError`, in the order the decoder checks them.
WIRE_ERROR_CODES = (
    "too_large",
    "not_json",
    "too_deep",
    "not_object",
    "control_character",
    "version",
    "no_type",
    "unknown_type",
    "invalid",
    "unphysical",
)


class WireError(ValueError):
    """A message that is not a valid protocol message; the text is the reason (free of
    control characters), ``ref_type`` the message's ``type`` when it could be read (its
    control characters escaped, at most 64 characters), ``code`` the class of the refusal,
    one of :data:`WIRE_ERROR_CODES` (a receiver counts refusals by it)."""

    def __init__(self, reason: str, ref_type: str | None = None, code: str = "invalid") -> None:
        super().__init__(escape_controls(reason))
        self.ref_type = None if ref_type is None else escape_controls(ref_type)[:64]
        self.code = code


def escape_controls(text: str) -> str:
    """``text`` with every control character and lone surrogate written as a Python escape
    (NUL as the four characters ``\x00``, a surrogate as ``\ud800``); other text as is."""
    if _CONTROL.search(text) is None:
        return text
    return _CONTROL.sub(lambda m: m.group().encode("unicode_escape").decode("ascii"), text)


class _Obj(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class _Msg(_Obj):
    v: Literal[2] = 2


Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
#: One value per joint (or wheel): the length is the robot's, checked against its layout
#: where the receiver knows it (:func:`decode_ground`, :func:`decode_spacecraft`).
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

_COMMAND = TypeAdapter(Annotated[JointCommandMsg | AcsCommandMsg, Field(discriminator="kind")])
_GROUND_OTHER = TypeAdapter(
    Annotated[
        ScheduleDelete | TelemetryAck | Retransmit | Ping | CommandQuery | SafeExit,
        Field(discriminator="type"),
    ]
)
_SPACECRAFT = TypeAdapter(SpacecraftMessage)
#: The ``type`` of every spacecraft -> ground message.
SPACECRAFT_TYPES = frozenset(
    str(m.model_fields["type"].default) for m in SpacecraftMessageT.__args__
)


#: ``hello`` fields left out of the encoding when None (added after version 2 was fixed).
_HELLO_OPTIONAL = ("robot", "robot_hash", "n_joints")


def encode(message: _Obj) -> str:
    if isinstance(message, Hello):
        absent = {name for name in _HELLO_OPTIONAL if getattr(message, name) is None}
        return message.model_dump_json(exclude=absent)
    return message.model_dump_json()


def _size(text: str | bytes) -> int:
    if isinstance(text, bytes) or len(text) > MAX_MESSAGE_BYTES:
        return len(text)
    return len(text.encode("utf-8", "surrogatepass"))


#: a tuple: ``isinstance`` checks it faster than the union ``dict | list``
_CONTAINERS = (dict, list)


def _check_tree(doc: dict[str, object], strings: bool, ref_type: str | None) -> None:
    """Refuse nesting deeper than :data:`MAX_DEPTH` and, when ``strings``, control
    characters in any string (keys included); level by level, so depth costs no stack."""
    level: list[Any] = [doc]
    depth = 1
    while level:
        if depth > MAX_DEPTH:
            raise WireError(f"message nested deeper than {MAX_DEPTH} levels", ref_type, "too_deep")
        if strings:
            for node in level:
                values = node.values() if isinstance(node, dict) else node
                for text in itertools.chain(node if isinstance(node, dict) else (), values):
                    if isinstance(text, str) and _CONTROL.search(text) is not None:
                        raise WireError(_control_reason(text), ref_type, "control_character")
        level = [
            value
            for node in level
            for value in (node.values() if isinstance(node, dict) else node)
            if isinstance(value, _CONTAINERS)
        ]
        depth += 1


def _control_reason(text: str) -> str:
    match = _CONTROL.search(text)
    assert match is not None
    shown = escape_controls(text[: max(0, match.start() - 24) + 48])
    return f"control character U+{ord(match.group()):04X} in the string {shown!r}: not allowed"


def _shown(value: object) -> str:
    """A top-level value as a refusal names it: short, never a control character."""
    if value is None or isinstance(value, bool | int | float):
        return repr(value)[:32]
    if isinstance(value, str):
        return repr(value[:64])
    return f"(a JSON {'object' if isinstance(value, dict) else 'array'})"


def _load(text: str | bytes, known: frozenset[str] | None = None) -> dict[str, object]:
    """The message's object, refused with the first fault met, cheapest first; with
    ``known`` (the direction's types), a type not in it is refused before the tree walk."""
    size = _size(text)
    if size > MAX_MESSAGE_BYTES:
        raise WireError(
            f"message of {size} bytes exceeds {MAX_MESSAGE_BYTES} bytes", code="too_large"
        )
    try:
        doc = json.loads(text)
    except RecursionError:
        raise WireError(f"message nested deeper than {MAX_DEPTH} levels", code="too_deep") from None
    except ValueError as exc:  # JSONDecodeError, UnicodeDecodeError, int digits limit
        raise WireError(f"not JSON: {exc}"[:400], code="not_json") from None
    if not isinstance(doc, dict):
        raise WireError("a message must be a JSON object", code="not_object")
    kind = doc.get("type")
    ref_type = kind if isinstance(kind, str) else None
    if kind == "error":
        # Never answered with an error: its text is escaped, not refused.
        for key, value in doc.items():
            if isinstance(value, str):
                doc[key] = escape_controls(value)
    version = doc.get("v")
    if version != PROTOCOL_VERSION:
        raise WireError(
            f"protocol version {_shown(version)} is not served: this end speaks {PROTOCOL_VERSION}",
            ref_type,
            "version",
        )
    if ref_type is None:
        raise WireError("a message needs a string 'type'", code="no_type")
    if known is not None and ref_type not in known:
        raise WireError(f"unknown message type {_shown(ref_type)}", ref_type, "unknown_type")
    if isinstance(text, bytes):
        strings = _SUSPECT_BYTES.search(text) is not None
    else:
        strings = _SUSPECT.search(text) is not None
    _check_tree(doc, strings, ref_type)
    return doc


def _unphysical(frame: TelemetryFrame) -> str | None:
    """Why a frame cannot be a real vehicle's (the bounds above), or None."""
    for name in ("joints_rad", "joint_targets_rad"):
        values: list[float] = getattr(frame, name)
        worst = max(range(len(values)), key=lambda i: abs(values[i]))
        if abs(values[worst]) > MAX_JOINT_ABS_RAD:
            return (
                f"{name}[{worst}] = {values[worst]:.6g} rad is beyond "
                f"{MAX_JOINT_ABS_RAD:.6g} rad (a diverged simulation?)"
            )
    rate = math.sqrt(sum(w * w for w in frame.omega_base_in_base_radps))
    if rate > MAX_BASE_RATE_RADPS:
        return f"base rate {rate:.6g} rad/s is beyond {MAX_BASE_RATE_RADPS:g} rad/s"
    norm = math.sqrt(sum(x * x for x in frame.quat_orbit_from_base_xyzw))
    if abs(norm - 1.0) > _QUAT_NORM_TOLERANCE:
        return f"attitude quaternion of norm {norm:.6g}, not 1"
    speed = max(abs(w) for w in frame.wheel_speeds_radps)
    if speed > MAX_WHEEL_SPEED_RADPS:
        return f"wheel speed {speed:.6g} rad/s is beyond {MAX_WHEEL_SPEED_RADPS:g} rad/s"
    momentum = max(abs(h) for h in frame.wheel_momentum_nms)
    if momentum > _MAX_WHEEL_MOMENTUM_NMS:
        return f"wheel momentum {momentum:.6g} N m s is beyond {_MAX_WHEEL_MOMENTUM_NMS:g} N m s"
    return None


def _reason(exc: ValidationError) -> str:
    first = exc.errors()[0]
    where = ".".join(str(p) for p in first["loc"]) or "message"
    return f"{where}: {first['msg']}"[:400]


def decode_ground(text: str | bytes, layout: FrameLayout | None = None) -> GroundMessageT:
    """A ground -> spacecraft message, or :class:`WireError`. With ``layout`` (the
    receiver's robot), a joint command for another joint count is refused too."""
    doc = _load(text)
    kind = str(doc["type"])
    try:
        if kind == "command":
            command = _COMMAND.validate_python(doc)
            if (
                layout is not None
                and isinstance(command, JointCommandMsg)
                and len(command.joints_rad) != layout.n_joints
            ):
                raise WireError(
                    f"invalid command: joints_rad has {len(command.joints_rad)} values, "
                    f"this robot has {layout.n_joints} joints",
                    kind,
                )
            return command
        if kind in (
            "schedule_delete",
            "telemetry_ack",
            "retransmit",
            "ping",
            "command_query",
            "safe_exit",
        ):
            return _GROUND_OTHER.validate_python(doc)
    except ValidationError as exc:
        raise WireError(f"invalid {kind}: {_reason(exc)}", kind) from None
    raise WireError(f"unknown message type {kind[:64]!r}", kind, "unknown_type")


def decode_spacecraft(text: str | bytes, layout: FrameLayout | None = None) -> SpacecraftMessageT:
    """A spacecraft -> ground message, or :class:`WireError`. With ``layout`` (the robot
    of the session), a telemetry frame of another shape, or a ``hello`` announcing another
    joint count, is refused too."""
    doc = _load(text, SPACECRAFT_TYPES)
    kind = str(doc["type"])
    try:
        message = _SPACECRAFT.validate_python(doc)
    except ValidationError as exc:
        code = "invalid" if kind in SPACECRAFT_TYPES else "unknown_type"
        raise WireError(f"invalid {kind[:64]}: {_reason(exc)}", kind, code) from None
    if isinstance(message, TelemetryMsg):
        for k, frame in enumerate(message.frames):
            problem = _unphysical(frame)
            if problem is not None:
                raise WireError(
                    f"unphysical telemetry: frame {k} (seq {frame.seq}): {problem}",
                    kind,
                    "unphysical",
                )
    if layout is not None:
        if isinstance(message, TelemetryMsg):
            for frame in message.frames:
                try:
                    layout.check(frame)
                except ValueError as exc:
                    raise WireError(f"invalid telemetry: {exc}", kind) from None
        elif (
            isinstance(message, Hello)
            and message.n_joints is not None
            and message.n_joints != layout.n_joints
        ):
            raise WireError(
                f"invalid hello: n_joints {message.n_joints}, this session's robot has "
                f"{layout.n_joints} joints",
                kind,
            )
    return message
