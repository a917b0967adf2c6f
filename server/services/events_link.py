"""The audit log's event kinds of the link, the commands and on-board safing: what the
command path writes as the vehicle speaks (connections, takeovers, malformed traffic,
``hello``, retransmissions; command stages, deferrals and cancellations; the vehicle safing
itself and the ground's ``safe_exit``). Each is a frozen
:class:`~server.services.event_log.Event` written by
:func:`~server.services.event_log.record`; :mod:`server.services.events` re-exports them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

from server.services.event_log import Event

__all__ = [
    "CommandAckUnknown",
    "CommandDeferred",
    "CommandStage",
    "CommandsCancelled",
    "LinkClosedMalformed",
    "LinkConnected",
    "LinkDisconnected",
    "LinkErrorReceived",
    "LinkErrorReplied",
    "LinkHello",
    "LinkTakeover",
    "RetransmitRequested",
    "VehicleSafeExitRequested",
    "VehicleSafeExitUnverified",
    "VehicleSafeExited",
    "VehicleSafed",
]


# --- the link ----------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class LinkConnected(Event):
    kind = "link_connected"
    connection: int


@dataclass(frozen=True, kw_only=True)
class LinkDisconnected(Event):
    kind = "link_disconnected"
    connection: int
    reason: str


@dataclass(frozen=True, kw_only=True)
class LinkTakeover(Event):
    """A second spacecraft connection superseded the one holding the link (the older is
    closed): both connections as :meth:`server.services.link.Connection.described` names
    them (``connection``, ``actor``, ``peer``, ``user_agent``, ``connected_ns``)."""

    kind = "link_takeover"
    previous: dict[str, Any]
    current: dict[str, Any]


@dataclass(frozen=True, kw_only=True)
class LinkErrorReceived(Event):
    """``error`` messages from the vehicle (never answered) of one kind within one interval
    (server/services/malformed.py): how many, the first's reason (``code`` ``received``,
    or ``unreadable`` for an ``error`` that did not decode)."""

    kind = "link_error_received"
    reason: str
    ref_type: str | None
    code: str = "received"
    count: int = 1
    first_time_ns: int | None = None
    last_time_ns: int | None = None


@dataclass(frozen=True, kw_only=True)
class LinkErrorReplied(Event):
    """Messages that did not decode, of one kind (the type they claim, the class of the
    refusal) within one interval (server/services/malformed.py): how many, how many were
    answered with ``error`` (at a bounded rate), the first's reason."""

    kind = "link_error_replied"
    reason: str
    ref_type: str | None
    code: str = "invalid"
    count: int = 1
    replied: int = 1
    first_time_ns: int | None = None
    last_time_ns: int | None = None


@dataclass(frozen=True, kw_only=True)
class LinkClosedMalformed(Event):
    """The ground closed the spacecraft's connection (1008): its stream was unusable, a run
    of ``count`` malformed messages and nothing readable for ``unreadable_s`` (at least the
    policy's ``interval_s``; server/services/malformed.py)."""

    kind = "link_closed_malformed"
    connection: int
    reason: str
    count: int
    interval_s: float
    unreadable_s: float


@dataclass(frozen=True, kw_only=True)
class LinkHello(Event):
    """The vehicle's ``hello`` (its fields but ``v`` and ``type``)."""

    kind = "link_hello"
    hello: Mapping[str, Any]

    def detail(self) -> dict[str, Any]:
        return dict(self.hello)


@dataclass(frozen=True, kw_only=True)
class RetransmitRequested(Event):
    kind = "retransmit_requested"
    ranges: list[tuple[int, int]]
    frames: int


# --- commands ----------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class CommandDeferred(Event):
    """A ``schedule_full`` refusal: transient, the runner sends the command again."""

    kind = "command_deferred"
    keys: ClassVar[Mapping[str, str]] = {"detail_text": "detail"}
    seq: int
    reason: str | None
    detail_text: str | None


@dataclass(frozen=True, kw_only=True)
class CommandAckUnknown(Event):
    """An acknowledgement of a seq no pass holds."""

    kind = "command_ack_unknown"
    seq: int
    stage: str


@dataclass(frozen=True, kw_only=True)
class CommandStage(Event):
    kind = "command_stage"
    keys: ClassVar[Mapping[str, str]] = {"from_stage": "from", "detail_text": "detail"}
    optional: ClassVar[tuple[str, ...]] = ("reason", "detail_text")
    seq: int
    from_stage: str
    stage: str
    time_ns: int
    reason: str | None = None
    detail_text: str | None = None


@dataclass(frozen=True, kw_only=True)
class CommandsCancelled(Event):
    """Commands cancelled at once (an abort): one event, with the count and the seq range."""

    kind = "commands_cancelled"
    count: int
    first_seq: int
    last_seq: int
    from_time_ns: int | None
    reason: str


# --- on-board safing ---------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class VehicleSafed(Event):
    """The vehicle reported it safed itself (its first report of the episode): the trigger
    and the onboard time it entered SAFE; ``pass_id`` the pass that was running, if any."""

    kind = "vehicle_safed"
    since_time_ns: int | None
    trigger: dict[str, Any] | None
    cancelled: int
    #: the report's own onboard time (its first copy the ground read)
    onboard_time_ns: int | None = None


@dataclass(frozen=True, kw_only=True)
class VehicleSafeExitRequested(Event):
    """An operator (the actor) sent the ``safe_exit`` telecommand."""

    kind = "vehicle_safe_exit_requested"
    request_id: int
    vehicle: str | None


@dataclass(frozen=True, kw_only=True)
class VehicleSafeExited(Event):
    """The vehicle reported it left SAFE (``request_id`` the telecommand that ended it)."""

    kind = "vehicle_safe_exited"
    request_id: int | None
    since_time_ns: int | None
    onboard_time_ns: int


@dataclass(frozen=True, kw_only=True)
class VehicleSafeExitUnverified(Event):
    """No report of the vehicle leaving SAFE after every copy of a ``safe_exit``."""

    kind = "vehicle_safe_exit_unverified"
    request_id: int
    transmissions: int
