"""One log line for each committed event an operator follows in the ground's log
(docs/operations.md, "Logs"): every pass state change, the vehicle's safing and its exit,
each alarm raised, cleared and acknowledged, and each refused start or control. A
subscriber of the publisher (:mod:`server.services.publisher`), matching on the event's
type and fields: a line is written once the event has committed, in the service's log
format (text or JSON, ``server.logs``), with the pass id and the event's kind among the
JSON fields. Lines the services write as they act (a pass started, an abort, the lease)
stay theirs."""

from __future__ import annotations

import logging
from typing import Any

from planner.limits import Severity
from server.services import events as ev
from server.services.event_log import Event, Recorded

__all__ = ["ALARM_LEVELS", "LOGGED", "LOGGED_KINDS", "log_event"]

log = logging.getLogger("hikoboshi.ground.events")

#: An alarm's severity (planner.limits.Severity, Yamcs's five) as the level of its raise's
#: line: watch is information, warning a warning, distress and worse errors.
_BELOW_ERROR = {Severity.WATCH: logging.INFO, Severity.WARNING: logging.WARNING}
ALARM_LEVELS: dict[str, int] = {s.value: _BELOW_ERROR.get(s, logging.ERROR) for s in Severity}


def _value(value: Any) -> str:
    return "-" if value is None else f"{value:.6g}" if isinstance(value, float) else str(value)


def _pass_state(e: ev.PassState) -> tuple[int, str]:
    level = logging.WARNING if e.to in ("aborted", "safed") else logging.INFO
    return level, f"{e.from_state} -> {e.to}: {e.reason}"


def _safed(e: ev.VehicleSafed) -> tuple[int, str]:
    trigger = e.trigger or {}
    what = f"{trigger.get('quantity', '?')} {trigger.get('channel', '')}".rstrip()
    at = f"{_value(trigger.get('value'))} against {_value(trigger.get('limit'))}"
    return logging.ERROR, (
        f"vehicle SAFE (on-board safing): {what} {at}; {e.cancelled} commands "
        "dropped from its schedule"
    )


def _alarm_raised(e: ev.AlarmRaised) -> tuple[int, str]:
    again = " again" if e.reopened else ""
    return ALARM_LEVELS.get(e.severity, logging.WARNING), (
        f"alarm {e.severity.upper()}{again}: {e.quantity} {e.channel}".rstrip()
        + f" = {_value(e.value)} (limit {_value(e.limit)})"
    )


def _alarm_cleared(e: ev.AlarmCleared) -> tuple[int, str]:
    what = f"{e.severity.upper()} {e.quantity} {e.channel}".rstrip()
    return logging.INFO, f"alarm cleared: {what} = {_value(e.value)}"


def _alarm_acknowledged(e: ev.AlarmAcknowledged) -> tuple[int, str]:
    what = f"{e.severity.upper()} {e.quantity} {e.channel}".rstrip()
    return logging.INFO, f"alarm acknowledged: {what}" + (f": {e.comment}" if e.comment else "")


def _start_refused(
    e: ev.PassStartRefused | ev.PassStartRefusedFlightRules | ev.PassStartRefusedWindow,
) -> tuple[int, str]:
    return logging.WARNING, f"start refused ({e.reason}): {e.message}"


def _line(event: Event) -> tuple[int, str] | None:
    """The level and text of an event's line (the actor and pass added), None: no line."""
    match event:
        case ev.PassState():
            return _pass_state(event)
        case ev.VehicleSafed():
            return _safed(event)
        case ev.VehicleSafeExitRequested(request_id=request):
            return logging.INFO, f"safe exit {request} sent"
        case ev.VehicleSafeExited(request_id=request):
            return logging.WARNING, f"vehicle left SAFE (safe exit {request})"
        case ev.VehicleSafeExitUnverified(request_id=request, transmissions=n):
            return logging.WARNING, f"safe exit {request} not confirmed after {n} copies"
        case ev.AlarmRaised():
            return _alarm_raised(event)
        case ev.AlarmCleared():
            return _alarm_cleared(event)
        case ev.AlarmAcknowledged():
            return _alarm_acknowledged(event)
        case ev.PassStartRefused() | ev.PassStartRefusedFlightRules() | ev.PassStartRefusedWindow():
            return _start_refused(event)
        case ev.PassControlRefused(action=action, confirm=confirm):
            return logging.WARNING, f"{action} refused: the confirmation {confirm!r} does not match"
    return None


#: The events that get a line.
LOGGED: tuple[type[Event], ...] = (
    ev.PassState,
    ev.VehicleSafed,
    ev.VehicleSafeExitRequested,
    ev.VehicleSafeExited,
    ev.VehicleSafeExitUnverified,
    ev.AlarmRaised,
    ev.AlarmCleared,
    ev.AlarmAcknowledged,
    ev.PassStartRefused,
    ev.PassStartRefusedFlightRules,
    ev.PassStartRefusedWindow,
    ev.PassControlRefused,
)
#: The kinds of events that get a line.
LOGGED_KINDS = frozenset(cls.kind for cls in LOGGED)


def log_event(recorded: Recorded) -> None:
    """The line of a committed event (typed, as the publisher hands it), if it gets one."""
    made = _line(recorded.event)
    if made is None:
        return
    level, text = made
    log.log(
        level,
        "%s (%s)",
        text,
        recorded.actor or "ground",
        # the line's pass, as every format shows it (server.logs)
        extra={
            "pass_id": recorded.pass_id,
            "fields": {"event": recorded.kind, "event_id": recorded.id},
        },
    )
