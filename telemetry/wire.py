"""The space-ground wire protocol, version 2: the codec of what crosses the relay link.

The messages themselves (the pydantic models each way and the protocol's constants) are in
:mod:`telemetry.wire_messages`; this module re-exports every one of their names, so
``telemetry.wire`` stays the one place both ends import the protocol from. The full
description, with the sequencing and acknowledgement rules, is ``docs/protocol.md``. Version
1 (each command sent once, just in time) is not served: its messages get an ``error`` reply
naming the version this end speaks.

:func:`decode_ground` and :func:`decode_spacecraft` accept only well-formed messages of this
version and raise :class:`WireError` (with a reason fit for an ``error`` reply) for anything
else. Before any model sees it, a message is refused when it is larger than
:data:`MAX_MESSAGE_BYTES`, nested deeper than :data:`MAX_DEPTH`, or holds a control
character (C0 with tab, newline and carriage return, DEL, C1) or a lone surrogate in any
string, keys included: no protocol message has a legitimate use for one, and the text a
receiver stores must read the same on every database (PostgreSQL refuses NUL). An ``error``
message alone is not refused for its text: it must never be answered with an ``error``, so
the control characters of its string values are escaped instead (NUL becomes the four
characters ``\x00``) and it is delivered. A telemetry frame beyond the physical bounds
(:data:`MAX_JOINT_ABS_RAD` and the others) is refused ``unphysical``. :func:`encode` is the
way out.

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
from typing import TYPE_CHECKING, Annotated, Any

from pydantic import Field, TypeAdapter, ValidationError

from telemetry.wire_messages import (
    DEFAULT_SCHEDULE_CAPACITY,
    MAX_FRAMES_PER_MESSAGE,
    MAX_JOINTS,
    MAX_WHEELS,
    PROTOCOL_VERSION,
    SPACECRAFT_TYPES,
    AcsCommandMsg,
    AcsModeName,
    BufferState,
    CommandAck,
    CommandQuery,
    CommandStage,
    CommandUnknown,
    ErrorMsg,
    GroundMessage,
    GroundMessageT,
    Hello,
    JointCommandMsg,
    Ping,
    Pong,
    RejectReason,
    Retransmit,
    SafeExit,
    Safing,
    SafingTrigger,
    ScheduleDelete,
    SpacecraftMessage,
    SpacecraftMessageT,
    TelemetryAck,
    TelemetryFrame,
    TelemetryMsg,
    Verification,
    _Obj,
)

if TYPE_CHECKING:
    from telemetry.layout import FrameLayout

__all__ = [
    "DEFAULT_SCHEDULE_CAPACITY",
    "MAX_BASE_RATE_RADPS",
    "MAX_DEPTH",
    "MAX_FRAMES_PER_MESSAGE",
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
    "GroundMessageT",
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
    "SpacecraftMessageT",
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

#: Larger messages are refused unread (a backlog dump is split into smaller batches).
MAX_MESSAGE_BYTES = 256 * 1024
#: Deeper messages are refused before validation. The deepest real one is 4 levels
#: (``telemetry`` > ``frames`` > a frame > ``joints_rad`` or ``buffer``); 16 leaves room for
#: later versions and still keeps hostile nesting away from the recursive validators.
MAX_DEPTH = 16
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


_COMMAND = TypeAdapter(Annotated[JointCommandMsg | AcsCommandMsg, Field(discriminator="kind")])
_GROUND_OTHER = TypeAdapter(
    Annotated[
        ScheduleDelete | TelemetryAck | Retransmit | Ping | CommandQuery | SafeExit,
        Field(discriminator="type"),
    ]
)
_SPACECRAFT = TypeAdapter(SpacecraftMessage)


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
