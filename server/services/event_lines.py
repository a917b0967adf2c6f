"""One log line for each committed event an operator follows in the ground's log
(docs/operations.md, "Logs"): every pass state change, the vehicle's safing and its exit,
each alarm raised, cleared and acknowledged, and each refused start or control. A
subscriber of the publisher (:mod:`server.services.publisher`): a line is written once the
event has committed, in the service's log format (text or JSON, ``server.logs``), with the
pass id and the event's kind among the JSON fields. Lines the services write as they act
(a pass started, an abort, the lease) stay theirs."""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from planner.limits import Severity

__all__ = ["ALARM_LEVELS", "LOGGED_KINDS", "log_event"]

log = logging.getLogger("hikoboshi.ground.events")

#: An alarm's severity (planner.limits.Severity, Yamcs's five) as the level of its raise's
#: line: watch is information, warning a warning, distress and worse errors.
_BELOW_ERROR = {Severity.WATCH: logging.INFO, Severity.WARNING: logging.WARNING}
ALARM_LEVELS: dict[str, int] = {s.value: _BELOW_ERROR.get(s, logging.ERROR) for s in Severity}


def _value(value: Any) -> str:
    return "-" if value is None else f"{value:.6g}" if isinstance(value, float) else str(value)


def _pass_state(d: dict[str, Any]) -> tuple[int, str]:
    level = logging.WARNING if d["to"] in ("aborted", "safed") else logging.INFO
    return level, f"{d['from']} -> {d['to']}: {d['reason']}"


def _safed(d: dict[str, Any]) -> tuple[int, str]:
    trigger = d.get("trigger") or {}
    what = f"{trigger.get('quantity', '?')} {trigger.get('channel', '')}".rstrip()
    at = f"{_value(trigger.get('value'))} against {_value(trigger.get('limit'))}"
    return logging.ERROR, (
        f"vehicle SAFE (on-board safing): {what} {at}; {d.get('cancelled', 0)} commands "
        "dropped from its schedule"
    )


def _alarm_raised(d: dict[str, Any]) -> tuple[int, str]:
    again = " again" if d.get("reopened") else ""
    return ALARM_LEVELS.get(d["severity"], logging.WARNING), (
        f"alarm {d['severity'].upper()}{again}: {d['quantity']} {d['channel']}".rstrip()
        + f" = {_value(d.get('value'))} (limit {_value(d.get('limit'))})"
    )


def _alarm(verb: str) -> Callable[[dict[str, Any]], tuple[int, str]]:
    def line(d: dict[str, Any]) -> tuple[int, str]:
        what = f"{d['severity'].upper()} {d['quantity']} {d['channel']}".rstrip()
        said = f" = {_value(d['value'])}" if "value" in d else ""
        note = f": {d['comment']}" if d.get("comment") else ""
        return logging.INFO, f"alarm {verb}: {what}{said}{note}"

    return line


def _text(level: int, template: str) -> Callable[[dict[str, Any]], tuple[int, str]]:
    return lambda d: (level, template.format_map(d))


#: kind -> the line of an event of that kind (level, text; the actor and pass added).
_LINES: dict[str, Callable[[dict[str, Any]], tuple[int, str]]] = {
    "pass_state": _pass_state,
    "vehicle_safed": _safed,
    "vehicle_safe_exit_requested": _text(logging.INFO, "safe exit {request_id} sent"),
    "vehicle_safe_exited": _text(logging.WARNING, "vehicle left SAFE (safe exit {request_id})"),
    "vehicle_safe_exit_unverified": _text(
        logging.WARNING, "safe exit {request_id} not confirmed after {transmissions} copies"
    ),
    "alarm_raised": _alarm_raised,
    "alarm_cleared": _alarm("cleared"),
    "alarm_acknowledged": _alarm("acknowledged"),
    "pass_start_refused": _text(logging.WARNING, "start refused ({reason}): {message}"),
    "pass_control_refused": _text(
        logging.WARNING, "{action} refused: the confirmation {confirm!r} does not match"
    ),
}
#: The kinds of events that get a line.
LOGGED_KINDS = frozenset(_LINES)


def log_event(event: dict[str, Any]) -> None:
    """The line of a committed event (as published), if its kind gets one."""
    make = _LINES.get(event["kind"])
    if make is None:
        return
    detail: dict[str, Any] = event.get("detail") or {}
    level, text = make(detail)
    pass_id = event.get("pass_id")  # the line's pass, as every format shows it (server.logs)
    log.log(
        level,
        "%s (%s)",
        text,
        event.get("actor") or "ground",
        extra={"pass_id": pass_id, "fields": {"event": event["kind"], "event_id": event.get("id")}},
    )
