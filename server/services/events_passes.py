"""The audit log's event kinds of passes, alarms, plans and analyses, and the edge's
audit: a pass's states, refused starts, resumption, graceful stops and abort deletes; passes
scheduled and imported; alarms raised, cleared and acknowledged; plans created and checked;
analyses run; addresses blocked and refused confirmations. Each is a frozen
:class:`~server.services.event_log.Event` written by
:func:`~server.services.event_log.record`; :mod:`server.services.events` re-exports them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

from server.services.event_log import Event

__all__ = [
    "AlarmAcknowledged",
    "AlarmCleared",
    "AlarmRaised",
    "AnalysesRun",
    "AuthBlocked",
    "GroundStopped",
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
    "ScheduleDeleteUnverified",
    "ScheduleDeleted",
]


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
class PassStartRefusedWindow(Event):
    """A start refused by the pass's window (server.operations.windows): ``reason``
    ``outside_window`` (before its usable part opens or after it closed) or
    ``plan_exceeds_window`` (too late in it for the plan's last command); ``window`` is the
    refusal's detail: the window's AOS and LOS, its usable start and end, and the ground's
    time it was judged at. The kind of every refused start."""

    kind = "pass_start_refused"
    reason: str
    message: str
    plan_id: str
    window: dict[str, Any]


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
