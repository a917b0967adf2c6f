"""The console's client messages (docs/console.md): parsed strictly, every fault a
:class:`ProtocolError` whose message names it (the hub answers it with ``error``)."""

from __future__ import annotations

import json
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError

__all__ = [
    "PROTOCOL_VERSION",
    "REPLAY_TYPES",
    "AckMsg",
    "AsFastAsPossibleSpec",
    "AuthMsg",
    "ClientMsg",
    "PingMsg",
    "ProtocolError",
    "RealTimeSpec",
    "ReplayCloseMsg",
    "ReplayMsg",
    "ReplayOpenMsg",
    "ReplayPauseMsg",
    "ReplayPlayMsg",
    "ReplaySeekMsg",
    "ReplaySpeedMsg",
    "ReplayStepMsg",
    "SpeedSpec",
    "StepSpec",
    "SubscribeMsg",
    "UnsubscribeMsg",
    "decode_client",
    "encode",
]

PROTOCOL_VERSION = 1


class ProtocolError(Exception):
    """A client message that cannot be understood or served; answered with ``error``
    (with ``ref_type``, the type of the message at fault, when it could be read)."""

    def __init__(self, message: str, *, ref_type: str | None = None) -> None:
        super().__init__(message)
        self.ref_type = ref_type


class _ClientMsg(BaseModel):
    # strict: "3" is not a seq (a console that sends one has a bug worth hearing about)
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)
    v: Literal[1]


class SubscribeMsg(_ClientMsg):
    type: Literal["subscribe"]
    topic: str = Field(max_length=32)
    pass_id: str | None = Field(default=None, max_length=64)
    since_seq: Annotated[int, Field(ge=0, le=2**62)] | None = None
    epoch: str | None = Field(default=None, max_length=64)
    max_rate_hz: Annotated[float, Field(gt=0, allow_inf_nan=False)] | None = None
    fields: Annotated[list[str], Field(min_length=1, max_length=64)] | None = None


class UnsubscribeMsg(_ClientMsg):
    type: Literal["unsubscribe"]
    topic: str = Field(max_length=32)
    pass_id: str | None = Field(default=None, max_length=64)


_PingId = Annotated[int, Field(ge=-(2**53), le=2**53)] | Annotated[str, Field(max_length=64)]


class PingMsg(_ClientMsg):
    type: Literal["ping"]
    id: _PingId | None = None


class AckMsg(_ClientMsg):
    """How many messages the console has read on this socket (all of them, every type):
    from the first, the server keeps what the console has not read within the
    acknowledgement window in its own queues, where control messages can jump the bulk
    data and a backlog can be dropped for a resync."""

    type: Literal["ack"]
    received: Annotated[int, Field(ge=0, le=2**62)]


class AuthMsg(_ClientMsg):
    type: Literal["auth"]
    token: str = Field(max_length=512)


# --- replay of a recorded pass -------------------------------------------------------------


class _Spec(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)


class RealTimeSpec(_Spec):
    """Onboard time runs ``factor`` times as fast as the wall clock."""

    mode: Literal["real_time"]
    factor: Annotated[float, Field(gt=0, allow_inf_nan=False)] = 1.0


class AsFastAsPossibleSpec(_Spec):
    """As fast as the console takes it, ``batch_frames`` frames a message."""

    mode: Literal["as_fast_as_possible"]
    batch_frames: Annotated[int, Field(ge=1)] = 100


class StepSpec(_Spec):
    """Nothing moves by itself: ``replay_step`` delivers one frame."""

    mode: Literal["step"]


SpeedSpec = Annotated[RealTimeSpec | AsFastAsPossibleSpec | StepSpec, Field(discriminator="mode")]
_ReplayId = Annotated[str, Field(min_length=1, max_length=64)]


class ReplayOpenMsg(_ClientMsg):
    type: Literal["replay_open"]
    pass_id: str = Field(max_length=64)
    speed: SpeedSpec | None = None
    paused: bool = False
    fields: Annotated[list[str], Field(min_length=1, max_length=64)] | None = None


class ReplayPlayMsg(_ClientMsg):
    type: Literal["replay_play"]
    replay_id: _ReplayId


class ReplayPauseMsg(_ClientMsg):
    type: Literal["replay_pause"]
    replay_id: _ReplayId


class ReplayStepMsg(_ClientMsg):
    type: Literal["replay_step"]
    replay_id: _ReplayId


class ReplaySpeedMsg(_ClientMsg):
    type: Literal["replay_speed"]
    replay_id: _ReplayId
    speed: SpeedSpec


class ReplaySeekMsg(_ClientMsg):
    """To an onboard time or a time on the plan's clock (exactly one of them)."""

    type: Literal["replay_seek"]
    replay_id: _ReplayId
    onboard_time_ns: Annotated[int, Field(ge=-(2**62), le=2**62)] | None = None
    plan_t_s: Annotated[float, Field(allow_inf_nan=False, ge=-1e9, le=1e9)] | None = None


class ReplayCloseMsg(_ClientMsg):
    type: Literal["replay_close"]
    replay_id: _ReplayId


ReplayMsg = (
    ReplayOpenMsg
    | ReplayPlayMsg
    | ReplayPauseMsg
    | ReplayStepMsg
    | ReplaySpeedMsg
    | ReplaySeekMsg
    | ReplayCloseMsg
)
REPLAY_TYPES = (
    "replay_open",
    "replay_play",
    "replay_pause",
    "replay_step",
    "replay_speed",
    "replay_seek",
    "replay_close",
)

ClientMsg = SubscribeMsg | UnsubscribeMsg | PingMsg | AckMsg | AuthMsg | ReplayMsg
_CLIENT: TypeAdapter[ClientMsg] = TypeAdapter(Annotated[ClientMsg, Field(discriminator="type")])


def decode_client(raw: str | bytes, max_bytes: int) -> ClientMsg:
    """One console -> server message, or :class:`ProtocolError` naming what is wrong."""
    if isinstance(raw, bytes):
        raise ProtocolError("binary frames are not understood: send JSON text")
    if len(raw) > max_bytes:
        raise ProtocolError(f"message of {len(raw)} characters exceeds {max_bytes}")
    try:
        doc = json.loads(raw)
    except (ValueError, RecursionError) as exc:
        raise ProtocolError(f"not JSON: {str(exc)[:200]}") from None
    if not isinstance(doc, dict):
        raise ProtocolError("a message is one JSON object")
    if doc.get("v") != PROTOCOL_VERSION:
        raise ProtocolError(f"version {doc.get('v')!r} is not supported (v: {PROTOCOL_VERSION})")
    kind = doc.get("type")
    if kind not in ("subscribe", "unsubscribe", "ping", "ack", "auth", *REPLAY_TYPES):
        raise ProtocolError(f"unknown message type {str(kind)[:64]!r}")
    try:
        return _CLIENT.validate_python(doc)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"][1:])
        raise ProtocolError(f"invalid {kind}: {where}: {first['msg']}", ref_type=kind) from None


def encode(doc: dict[str, Any]) -> str:
    return json.dumps(doc, separators=(",", ":"), allow_nan=False)
