"""Every event of the ground, as a frozen class: the typed link events the link hands the
runner and the command trackers (:data:`LinkEvent`, in memory), and every event it writes to
its audit log: the link's, the command stages', the passes', the alarms', the plans', the
analyses' and the audit's.

An event is written in one way, :func:`record` (the row stamped by the injected
:class:`~server.services.clock.Clock` of its writer, never by the process's own clock), and
published to the consoles in one way, the dict :func:`record` returns (``kind, actor, detail,
pass_id, time_ns, id``, the console protocol's ``event``): through the command path's
:class:`~server.services.dbworker.Database` once its transaction commits, or, for the REST
side's own transactions, by the route through the publisher once the route's service has
committed (:func:`written`; :func:`with_written` for a job of a worker process).

``detail`` is each class's fields but ``actor`` and ``pass_id``, named as the stored and
published detail has always named them (``from`` for :class:`PassState`'s ``from_state``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar, TypeVar

from sqlalchemy.orm import Session

from server.services.clock import Clock
from server.storage import repository as repo
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
    "PassState",
    "PlanChecked",
    "PlanCreated",
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
    "published",
    "record",
    "with_written",
    "written",
]

T = TypeVar("T")
#: ``Session.info`` key of the events recorded on it.
_WRITTEN = "hikoboshi.events"
#: Fields that are not part of ``detail``.
_ENVELOPE = ("actor", "pass_id")


@dataclass(frozen=True, kw_only=True)
class Event:
    """One audit-log event: who (``actor``), about which pass (if any), and its detail."""

    kind: ClassVar[str]
    #: field name -> the detail's key, where they differ
    keys: ClassVar[Mapping[str, str]] = {}
    #: fields left out of the detail when None
    optional: ClassVar[tuple[str, ...]] = ()

    actor: str
    pass_id: str | None = None

    def detail(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for f in fields(self):
            if f.name in _ENVELOPE:
                continue
            value = getattr(self, f.name)
            if value is None and f.name in self.optional:
                continue
            out[self.keys.get(f.name, f.name)] = value
        return out


def published(event: Event, time_ns: int, event_id: int) -> dict[str, Any]:
    """The dict the consoles get for a stored event."""
    return {
        "kind": event.kind,
        "actor": event.actor,
        "detail": event.detail(),
        "pass_id": event.pass_id,
        "time_ns": time_ns,
        "id": event_id,
    }


def record(session: Session, event: Event, time_ns: int) -> dict[str, Any]:
    """Add ``event``'s row stamped ``time_ns`` (read off the writer's injected clock: the
    command path's when it writes, the request's when a route took it), and return it as the
    dict to publish once the transaction commits (kept on the session too:
    :func:`written`)."""
    row = repo.add_event(
        session=session,
        time_ns=time_ns,
        kind=event.kind,
        actor=event.actor,
        detail=event.detail(),
        pass_id=event.pass_id,
    )
    out = published(event, time_ns, row.id)
    session.info.setdefault(_WRITTEN, []).append(out)
    return out


def event_job(event: Event, clock: Clock) -> Callable[[Session], list[dict[str, Any]]]:
    """A database job (:class:`~server.services.dbworker.Database`) that records ``event``,
    stamped when it runs."""
    return lambda session: [record(session, event, clock.time_ns())]


def written(session: Session) -> list[dict[str, Any]]:
    """The events :func:`record` wrote on ``session`` since the last call (to publish once
    it has committed)."""
    events: list[dict[str, Any]] = session.info.pop(_WRITTEN, [])
    return events


def with_written(
    fn: Callable[..., T], /, *, session: Session, **kwargs: Any
) -> tuple[T, list[dict[str, Any]]]:
    """``fn(session=session, **kwargs)`` and the events it wrote (for a job a worker process
    runs: ``partial(with_written, fn)`` goes there, the server publishes what comes back)."""
    return fn(session=session, **kwargs), written(session)


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


# --- passes ------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class PassState(Event):
    kind = "pass_state"
    keys: ClassVar[Mapping[str, str]] = {"from_state": "from"}
    optional: ClassVar[tuple[str, ...]] = ("epoch_ns",)
    from_state: str
    to: str
    reason: str
    version: int
    epoch_ns: int | None = None


@dataclass(frozen=True, kw_only=True)
class PassStartRefused(Event):
    """A start refused: the plan's robot is not the vehicle's."""

    kind = "pass_start_refused"
    reason: str
    message: str
    plan_id: str
    plan_robot: str | None
    plan_robot_hash: str | None
    plan_n_joints: int | None
    vehicle_robot: str | None
    vehicle_robot_hash: str | None
    vehicle_n_joints: int | None


@dataclass(frozen=True, kw_only=True)
class PassStartRefusedFlightRules(Event):
    """A start refused because the plan fails a flight rule (``reason``
    ``flight_rule_violation``: ``rows`` are the failing rows, the ``fits_pass`` row taken
    with the pass's own ``window_s``) or because it could not be checked (``reason`` the
    error's code, ``rows`` empty). The same kind as a robot mismatch's refusal: one kind for
    every refused start, told apart by ``reason``."""

    kind = "pass_start_refused"
    reason: str
    message: str
    plan_id: str
    rows: list[dict[str, Any]]
    window_s: float


@dataclass(frozen=True, kw_only=True)
class PassResumed(Event):
    kind = "pass_resumed"
    state: str
    pending: int
    commands: int


@dataclass(frozen=True, kw_only=True)
class GroundStopped(Event):
    """The ground service stopped (a graceful stop) with the pass in flight: the pass is
    handed to the vehicle, not aborted (``reason`` says so, with the onboard time). Left in
    ``state`` for the next process to resume; ``loaded``: commands sent and not final (on
    board, or on their way), ``unsent``: never sent; the vehicle's ``los_policy`` applies."""

    kind = "ground_stopped"
    state: str
    reason: str
    onboard_time_ns: int | None
    loaded: int
    unsent: int
    los_policy: str


@dataclass(frozen=True, kw_only=True)
class ScheduleDeleted(Event):
    kind = "schedule_deleted"
    request_id: int
    from_time_ns: int
    deleted: int
    executed_after_from: int
    copies_sent: int


@dataclass(frozen=True, kw_only=True)
class ScheduleDeleteUnverified(Event):
    kind = "schedule_delete_unverified"
    request_id: int | None


@dataclass(frozen=True, kw_only=True)
class PassScheduled(Event):
    kind = "pass_scheduled"
    plan_id: str
    name: str
    aos_time_ns: int
    los_time_ns: int
    relay: str


@dataclass(frozen=True, kw_only=True)
class PassImported(Event):
    kind = "pass_imported"
    source: str
    original_pass_id: str | None
    frames: int
    commands: int
    events: int
    extra: Mapping[str, Any] = field(default_factory=dict)

    def detail(self) -> dict[str, Any]:
        out = {k: v for k, v in super().detail().items() if k != "extra"}
        return {**out, **self.extra}


# --- alarms ------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class AlarmRaised(Event):
    """An alarm raised (or ``reopened``: its channel entered a band again while the alarm,
    cleared, was still listed): docs/alarms.md."""

    kind = "alarm_raised"
    alarm_id: str
    source: str
    quantity: str
    channel: str
    severity: str
    value: float | None
    limit: float | None
    frame_seq: int | None
    generation_time_ns: int | None
    reopened: bool = False
    detail_text: str | None = None
    keys: ClassVar[Mapping[str, str]] = {"detail_text": "detail"}
    optional: ClassVar[tuple[str, ...]] = ("detail_text",)


@dataclass(frozen=True, kw_only=True)
class AlarmCleared(Event):
    """An alarm's channel back within limits (or no longer watched: ``detail``)."""

    kind = "alarm_cleared"
    alarm_id: str
    quantity: str
    channel: str
    severity: str
    value: float | None
    generation_time_ns: int | None


@dataclass(frozen=True, kw_only=True)
class AlarmAcknowledged(Event):
    """An operator (the actor) acknowledged an alarm, with an optional comment."""

    kind = "alarm_acknowledged"
    alarm_id: str
    quantity: str
    channel: str
    severity: str
    state: str
    comment: str | None


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


# --- plans, analyses ---------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class PlanCreated(Event):
    kind = "plan_created"
    plan_id: str
    experiment: str
    robot: str
    robot_hash: str


@dataclass(frozen=True, kw_only=True)
class PlanChecked(Event):
    """A stored plan checked against the flight rules on request (``POST
    /api/plans/{id}/check``: one stored before the rules existed, or imported); the ground's
    report is now in its document."""

    kind = "plan_checked"
    plan_id: str
    robot: str
    passed: bool
    failing: list[str]


@dataclass(frozen=True, kw_only=True)
class AnalysesRun(Event):
    """Analyses computed: each kind's status."""

    kind = "analyses_run"
    statuses: Mapping[str, str]

    def detail(self) -> dict[str, Any]:
        return dict(self.statuses)


# --- the audit ---------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class AuthBlocked(Event):
    """An address blocked for failed authentications."""

    kind = "auth_blocked"
    address: str
    failures: int
    blocked_s: float


@dataclass(frozen=True, kw_only=True)
class PassControlRefused(Event):
    """A start, an abort or a safe exit whose confirmation did not match."""

    kind = "pass_control_refused"
    action: str
    confirm: str
