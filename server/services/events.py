"""Every event of the ground, as a frozen class, importable from here: the typed link
events the link hands the runner and the command trackers (:data:`LinkEvent`, in memory,
defined here), and every event it writes to its audit log, re-exported: the link's, the
command stages' and on-board safing's (:mod:`server.services.events_link`), the passes',
the alarms', the plans', the analyses' and the audit's (:mod:`server.services.events_passes`).

An audit-log event is written in one way, :func:`record`, and published in one way: typed
(a :class:`Recorded`), once its transaction commits, by the hook on the session factory
(:func:`publish_on_commit`); all of it, with the :class:`Event` base class, is in
:mod:`server.services.event_log`.
"""

from __future__ import annotations

from dataclasses import dataclass

from server.services.event_log import (
    Event,
    Recorded,
    event_job,
    on_commit,
    publish_on_commit,
    record,
    with_written,
    written,
)
from server.services.events_link import (
    CommandAckUnknown,
    CommandDeferred,
    CommandsCancelled,
    CommandStage,
    LinkClosedMalformed,
    LinkConnected,
    LinkDisconnected,
    LinkErrorReceived,
    LinkErrorReplied,
    LinkHello,
    LinkTakeover,
    RetransmitRequested,
    VehicleSafed,
    VehicleSafeExited,
    VehicleSafeExitRequested,
    VehicleSafeExitUnverified,
)
from server.services.events_passes import (
    AlarmAcknowledged,
    AlarmCleared,
    AlarmRaised,
    AnalysesRun,
    AuthBlocked,
    GroundStopped,
    PassControlRefused,
    PassImported,
    PassResumed,
    PassScheduled,
    PassStartRefused,
    PassStartRefusedFlightRules,
    PassStartRefusedWindow,
    PassState,
    PlanChecked,
    PlanCreated,
    ScheduleDeleted,
    ScheduleDeleteUnverified,
)
from telemetry.wire import Hello, Safing, Verification

__all__ = [
    "AlarmAcknowledged",
    "AlarmCleared",
    "AlarmRaised",
    "AnalysesRun",
    "AuthBlocked",
    "CommandAckUnknown",
    "CommandAcked",
    "CommandDeferred",
    "CommandStage",
    "CommandsCancelled",
    "CommandsUnknown",
    "Event",
    "GroundStopped",
    "LinkClosedMalformed",
    "LinkConnected",
    "LinkDisconnected",
    "LinkDown",
    "LinkErrorReceived",
    "LinkErrorReplied",
    "LinkEvent",
    "LinkHello",
    "LinkTakeover",
    "LinkUp",
    "PassControlRefused",
    "PassImported",
    "PassResumed",
    "PassScheduled",
    "PassStartRefused",
    "PassStartRefusedFlightRules",
    "PassStartRefusedWindow",
    "PassState",
    "PlanChecked",
    "PlanCreated",
    "Recorded",
    "RequestVerified",
    "RetransmitRequested",
    "SafingReported",
    "ScheduleDeleteUnverified",
    "ScheduleDeleted",
    "VehicleSafeExitRequested",
    "VehicleSafeExitUnverified",
    "VehicleSafeExited",
    "VehicleSafed",
    "event_job",
    "on_commit",
    "publish_on_commit",
    "record",
    "with_written",
    "written",
]


# --- the link's typed events to the runner (in memory: the link files them first) ---------


@dataclass(frozen=True)
class CommandAcked:
    """The vehicle's word on one command, read off the socket at ``read_mono``."""

    seq: int
    stage: str  # received | executed | rejected
    reason: str | None
    onboard_time_ns: int
    read_mono: float


@dataclass(frozen=True)
class CommandsUnknown:
    """The vehicle never received these commands (answer to ``command_query``)."""

    seqs: tuple[int, ...]
    onboard_time_ns: int


@dataclass(frozen=True)
class RequestVerified:
    """A ``verification``: the report on a ``schedule_delete``."""

    report: Verification
    read_mono: float


@dataclass(frozen=True)
class LinkUp:
    hello: Hello


@dataclass(frozen=True)
class LinkDown:
    reason: str


@dataclass(frozen=True)
class SafingReported:
    """A ``safing`` report of the vehicle, read at ``read_mono``: ``entered`` on the first
    report of a SAFE episode (the 1 s repeats are not), ``exited`` on the report that ends
    one (:mod:`server.services.safing`)."""

    report: Safing
    entered: bool
    exited: bool
    read_mono: float


LinkEvent = CommandAcked | CommandsUnknown | RequestVerified | LinkUp | LinkDown | SafingReported
