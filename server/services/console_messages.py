"""The console's server -> console messages (docs/console.md), one pydantic model each.

Every message the hub and the replays send is built as one of these models and encoded by
:meth:`ServerMsg.encode`: the fields in declaration order, compact JSON, so the text is
what the protocol has always sent. A field made with :func:`omitted_if_none` is left out of
the message when it is None (``pass_id`` of a subscription to a topic without passes, an
event's ``id`` when the event has none); every other field is always sent.

The web console's types are generated from these models' JSON Schema
(``python -m server.webtypes`` writes ``web/src/protocol.gen.ts``; a test holds the
committed file to it).
"""

from __future__ import annotations

import dataclasses
import json
from typing import Annotated, Any, ClassVar, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    RootModel,
    SerializerFunctionWrapHandler,
    WithJsonSchema,
    model_serializer,
)

from server.services._console_limits import canonical_pass
from server.services._console_protocol import (
    AsFastAsPossibleSpec,
    RealTimeSpec,
    StepSpec,
)
from server.services.event_log import Recorded
from server.services.link import LinkStatus
from telemetry.alarm import AlarmPublic
from telemetry.layout import DEFAULT_LAYOUT

__all__ = [
    "OMIT_IF_NONE",
    "SERVER_MESSAGES",
    "AlarmMsg",
    "ConsoleEvent",
    "ConsoleRole",
    "ErrorMsg",
    "EventMsg",
    "EventTopic",
    "FrameColumns",
    "LagMsg",
    "LinkMsg",
    "PongMsg",
    "ReplayClosedMsg",
    "ReplayCommand",
    "ReplayCommandsMsg",
    "ReplayOpenedMsg",
    "ReplaySpeed",
    "ReplayStateMsg",
    "ReplayTelemetryMsg",
    "ResyncMsg",
    "ServerMsg",
    "SubscribedMsg",
    "TelemetryMsg",
    "UnsubscribedMsg",
    "WelcomeLimits",
    "WelcomeMsg",
    "console_event",
    "omitted_if_none",
]

#: The JSON Schema key that marks a property left out of a message when it is None.
OMIT_IF_NONE = "omitIfNone"

#: A number sent as given: an int stays an int (``5``, not ``5.0``).
Number = int | float
EventTopic = Literal["commands", "passes", "events"]
ConsoleRole = Literal["viewer", "operator"]
ReplaySpeed = Annotated[RealTimeSpec | AsFastAsPossibleSpec | StepSpec, Field(discriminator="mode")]


def omitted_if_none() -> Any:
    """A field (default None) left out of the message when it is None."""
    return Field(default=None, json_schema_extra={OMIT_IF_NONE: True})


class _Doc(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")
    #: Fields made with :func:`omitted_if_none` (filled in per class).
    _omit: ClassVar[tuple[str, ...]] = ()

    @classmethod
    def __pydantic_init_subclass__(cls, **kwargs: Any) -> None:
        super().__pydantic_init_subclass__(**kwargs)
        cls._omit = tuple(
            name
            for name, info in cls.model_fields.items()
            if isinstance(info.json_schema_extra, dict) and info.json_schema_extra.get(OMIT_IF_NONE)
        )

    @model_serializer(mode="wrap")
    def _drop_omitted(self, handler: SerializerFunctionWrapHandler) -> Any:
        doc = handler(self)
        for name in self._omit:
            if doc.get(name, 0) is None:
                del doc[name]
        return doc

    def _shallow(self) -> dict[str, Any]:
        """:meth:`model_dump`'s document one level deep, the values as they are (the
        encoder walks into them: frames' columns are not copied on the ingest path)."""
        doc = {name: getattr(self, name) for name in type(self).model_fields}
        for name in self._omit:
            if doc[name] is None:
                del doc[name]
        return doc


def _plain(value: Any) -> Any:
    """What the JSON encoder writes for a value it does not know (see :meth:`ServerMsg.encode`)."""
    if isinstance(value, _Doc):
        return value._shallow()
    if isinstance(value, RootModel):
        return value.root
    if isinstance(value, BaseModel):
        return {name: getattr(value, name) for name in type(value).model_fields}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return dataclasses.asdict(value)
    raise TypeError(f"{type(value).__name__} is not a console message's value")


def _frame_columns_schema() -> dict[str, Any]:
    """The JSON Schema of frames as columns (:class:`FrameColumns`), from the layout: the
    float vectors are numbers; the other columns are these."""
    layout = DEFAULT_LAYOUT
    kinds: dict[str, Any] = {
        "seq": "integer",
        "generation_time_ns": "integer",
        "acs_mode": "string",
        "acs_feedforward": "boolean",
        "buffer_queued": "integer",
        "buffer_next_execute_time_ns": ["integer", "null"],  # null: nothing queued
        "buffer_last_executed_seq": "integer",
        "reception_time_ns": "integer",
    }
    assert list(kinds) == [c for c in layout.columns if c not in layout.float_fields]
    return {
        "type": "object",
        "properties": {name: {"type": "array", "items": {"type": t}} for name, t in kinds.items()},
        # every other column is a float vector's (j1..jn, t1..tn, qx.., ws1..wsk, ...)
        "additionalProperties": {"type": "array", "items": {"type": "number"}},
        # the three sent whatever the fields asked for
        "required": ["seq", "generation_time_ns", "reception_time_ns"],
    }


class FrameColumns(
    RootModel[Annotated[dict[str, list[Any]], WithJsonSchema(_frame_columns_schema())]]
):
    """Frames as columns, ready for a plotting library: one list per field (the pass's
    layout's, or those asked for), one entry per frame, in generation-time order."""


class ServerMsg(_Doc):
    """A message of the server to a console (``v`` first, ``type`` names it)."""

    v: Literal[1] = 1  # _console_protocol.PROTOCOL_VERSION

    def encode(self) -> str:
        """The message as sent: compact JSON, fields in declaration order (the text of
        :meth:`model_dump`'s document, written without copying it first)."""
        return json.dumps(self, default=_plain, separators=(",", ":"), allow_nan=False)


# --- stream data ---------------------------------------------------------------------------


class TelemetryMsg(ServerMsg):
    """The frames of one batch archived for a pass (topic ``telemetry``)."""

    topic: Literal["telemetry"] = "telemetry"
    type: Literal["telemetry"] = "telemetry"
    pass_id: str
    seq: int
    count: int
    columns: FrameColumns


class LinkMsg(ServerMsg):
    """The link status (``GET /api/link/status``'s document), on change and as a heartbeat."""

    topic: Literal["link"] = "link"
    type: Literal["link"] = "link"
    seq: int
    ground_time_ns: int
    status: LinkStatus


class ConsoleEvent(_Doc):
    """A committed event as the publisher delivers it (``pass_id`` in canonical form)."""

    kind: str
    actor: str
    detail: dict[str, Any]
    pass_id: str | None
    time_ns: int
    id: int | None = omitted_if_none()


def console_event(recorded: Recorded) -> ConsoleEvent:
    """A committed event (typed, as the publisher hands it) as consoles get it."""
    return ConsoleEvent(
        kind=recorded.kind,
        actor=recorded.actor,
        detail=recorded.event.detail(),
        pass_id=canonical_pass(recorded.pass_id),
        time_ns=recorded.time_ns,
        id=recorded.id,
    )


class EventMsg(ServerMsg):
    """An event of the ``commands``, ``passes`` or ``events`` topic."""

    topic: EventTopic
    type: Literal["event"] = "event"
    seq: int
    event: ConsoleEvent


class AlarmMsg(ServerMsg):
    """An alarm raised, changed band, cleared or acknowledged (topic ``alarms``; while it
    stays in its band, at most once per second). Not replayed from the database: a console
    that is told ``resync`` reloads ``GET /api/alarms``."""

    topic: Literal["alarms"] = "alarms"
    type: Literal["alarm"] = "alarm"
    seq: int
    alarm: AlarmPublic


# --- control -------------------------------------------------------------------------------


class WelcomeLimits(_Doc):
    queue_bytes: int
    ring_size: int
    max_replay: int
    max_subscriptions: int
    max_message_bytes: int
    link_heartbeat_s: Number
    behind_report_s: Number
    behind_resync_s: Number
    behind_drop_s: Number
    ack_window_s: Number
    max_replays_per_console: int
    max_replay_factor: Number
    max_replay_batch_frames: int


class WelcomeMsg(ServerMsg):
    """The first message once authenticated: this process's ``epoch`` and the limits."""

    type: Literal["welcome"] = "welcome"
    epoch: str
    actor: str
    role: ConsoleRole
    topics: list[str]
    limits: WelcomeLimits


class _StreamControl(ServerMsg):
    """A message about one stream: its topic and, for telemetry, its pass."""

    type: str
    topic: str
    pass_id: str | None = omitted_if_none()


class SubscribedMsg(_StreamControl):
    """A subscription is in place; ``seq`` is the stream's last seq when it was made."""

    type: Literal["subscribed"] = "subscribed"
    epoch: str
    seq: int


class ResyncMsg(_StreamControl):
    """Nothing up to ``seq`` will be replayed (``reason`` says why): reload from REST."""

    type: Literal["resync"] = "resync"
    epoch: str
    seq: int
    reason: str


class UnsubscribedMsg(_StreamControl):
    """A subscription ended: ``requested``, or dropped (``overflow: ...``) at ``seq``."""

    type: Literal["unsubscribed"] = "unsubscribed"
    seq: int
    reason: str


class LagMsg(ServerMsg):
    """How far behind the console is: ``behind_s``, the age (server clock) of its oldest
    unsent message, ``queued`` of them; sent ahead of the data while it is behind, and once
    with ``behind_s: 0`` when it has caught up. Past ``resync_s`` its bulk data is dropped
    and each such stream told ``resync``. ``time_ns``: the ground time it was measured."""

    type: Literal["lag"] = "lag"
    behind_s: Number
    queued: int
    resync_s: Number
    time_ns: int


class PongMsg(ServerMsg):
    """The answer to ``ping``: its ``id`` and the ground time."""

    type: Literal["pong"] = "pong"
    id: int | str | None
    time_ns: int


class ErrorMsg(ServerMsg):
    """A client message that could not be understood or served (``ref_type``: its type)."""

    type: Literal["error"] = "error"
    reason: str
    ref_type: str | None


# --- replay of a recorded pass -------------------------------------------------------------


class _ReplayState(ServerMsg):
    type: str
    replay_id: str
    pass_id: str
    seq: int
    reason: str
    playing: bool
    finished: bool
    speed: ReplaySpeed
    position: int
    frames: int
    next_generation_time_ns: int | None
    playhead_ns: int
    playhead_t_s: float


class ReplayStateMsg(_ReplayState):
    """Where a replay is: after every request, while frames flow, at its end."""

    type: Literal["replay_state"] = "replay_state"


class ReplayOpenedMsg(_ReplayState):
    """A replay is open: its state and what the recording holds."""

    type: Literal["replay_opened"] = "replay_opened"
    name: str
    epoch_ns: int
    commands: int
    first_generation_time_ns: int
    last_generation_time_ns: int
    plan_duration_s: Number
    columns: list[str]


class ReplayClosedMsg(ServerMsg):
    """A replay ended: ``requested`` or ``failed: ...``."""

    type: Literal["replay_closed"] = "replay_closed"
    replay_id: str
    seq: int
    reason: str


class ReplayTelemetryMsg(ServerMsg):
    """Frames of a replay (the live message's ``columns``; ``row``: the first frame's index)."""

    topic: Literal["replay"] = "replay"
    replay_id: str
    pass_id: str
    type: Literal["telemetry"] = "telemetry"
    seq: int
    row: int
    count: int
    columns: FrameColumns


class ReplayCommand(_Doc):
    """A command of the recording, as it ended up."""

    seq: int
    kind: str
    execute_time_ns: int
    stage: str
    reject_reason: str | None
    stage_times_ns: dict[str, int | None]
    payload: dict[str, Any]


class ReplayCommandsMsg(ServerMsg):
    """The commands whose tags the replay passed."""

    topic: Literal["replay"] = "replay"
    replay_id: str
    pass_id: str
    type: Literal["commands"] = "commands"
    seq: int
    commands: list[ReplayCommand]


#: Every message the server sends a console.
SERVER_MESSAGES: tuple[type[ServerMsg], ...] = (
    WelcomeMsg,
    SubscribedMsg,
    ResyncMsg,
    UnsubscribedMsg,
    LagMsg,
    PongMsg,
    ErrorMsg,
    TelemetryMsg,
    LinkMsg,
    EventMsg,
    AlarmMsg,
    ReplayOpenedMsg,
    ReplayStateMsg,
    ReplayClosedMsg,
    ReplayTelemetryMsg,
    ReplayCommandsMsg,
)
