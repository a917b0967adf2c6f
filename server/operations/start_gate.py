"""The start gate: may this pass start now? Its window, then its plan's flight rules.

``POST /api/passes/{id}/start`` asks :func:`start_gate_job` (a short database job of the
command path) before the runner starts the pass. Refused, in this order, each a 409 audited
as ``pass_start_refused`` (:class:`~server.services.events.PassStartRefusedWindow` with the
window, :class:`~server.services.events.PassStartRefusedFlightRules` with the failing rows;
told apart by ``reason``;
the pass stays ``scheduled`` and nothing reaches the link):

1. **The window** (:func:`server.operations.windows.start_refusal`, read on the ground's
   injected clock): ``outside_window`` before the usable window opens or after it closed,
   ``plan_exceeds_window`` when the plan's last command would be tagged after its end.
2. **The flight rules** (docs/robots.md, SPEC 8): the report the plan's document carries
   (:mod:`server.services.plans` stores every plan with one), its ``fits_pass`` row taken
   again with the pass's own window (its length in onboard s less the start lead, at the
   link's time scale): ``flight_rule_violation`` with the failing rows. There is no override.

The start never computes: it compares numbers the ground stored. A plan stored without a
report (before the rules existed, or imported from a recording, whose report is not the
ground's word) is refused with ``flight_rules_unchecked``, saying how to check it:
``POST /api/plans/{id}/check`` (:func:`server.operations.plans.check_stored_plan`).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field

from sqlalchemy.orm import Session

from planner.flight_rules import FlightRulesReport, fits_pass_row
from server.operations.windows import Refusal, WindowTime, start_refusal
from server.services.clock import Clock
from server.services.events import (
    Event,
    PassStartRefusedFlightRules,
    PassStartRefusedWindow,
    Recorded,
)
from server.services.events import record as record_event
from server.services.plans import FLIGHT_RULE_VIOLATION, violation_message
from server.storage import repository as repo
from server.storage.models import PassRecord

__all__ = ["FLIGHT_RULES_UNCHECKED", "StartGate", "pass_window_s", "start_gate_job"]

#: The start's refusal of a plan the ground has not checked.
FLIGHT_RULES_UNCHECKED = "flight_rules_unchecked"


@dataclass(frozen=True)
class StartGate:
    """The gate's answer: the pass's plan, and why the start is refused (None: it may
    start); the events written."""

    plan_id: str
    refusal: Refusal | None = None
    events: list[Recorded] = field(default_factory=list)


def pass_window_s(record: PassRecord, lead_s: float, scale: float = 1.0) -> float:
    """The onboard s the pass's window leaves its plan: ``los - aos`` (``scale`` onboard s
    per s of it) less the start lead."""
    return (record.los_time_ns - record.aos_time_ns) / 1e9 * scale - lead_s


def start_gate_job(
    *, pass_id: str, actor: str, clock: Clock, lead_s: float, at: WindowTime | None
) -> Callable[[Session], StartGate]:
    """A database job: may the pass start (module doc)? ``lead_s``: the start lead at the
    link's time scale; ``at``: now on the windows' time line (None: unknown, the window is
    not checked: the runner refuses a start without a link). A pass that is not
    ``scheduled`` is let through: the start transaction refuses it with its own reason."""

    def job(session: Session) -> StartGate:
        record = repo.get_pass(session=session, pass_id=pass_id, refresh=True)
        if record.state != "scheduled":
            return StartGate(record.plan_id)
        plan = repo.get_plan(session=session, plan_id=record.plan_id)
        window_s = pass_window_s(record, lead_s, 1.0 if at is None else at.scale)
        refusal = None
        if at is not None:
            refusal = start_refusal(record, plan_s=plan.duration_s, lead_s=lead_s, at=at)
        event: Event
        if refusal is not None:
            event = PassStartRefusedWindow(
                actor=actor,
                pass_id=record.id,
                reason=refusal.code,
                message=refusal.message,
                plan_id=record.plan_id,
                window=dict(refusal.detail),
            )
        else:
            refusal = _flight_rules_refusal(record, plan.document, plan.duration_s, window_s)
            if refusal is None:
                return StartGate(record.plan_id)
            event = PassStartRefusedFlightRules(
                actor=actor,
                pass_id=record.id,
                reason=refusal.code,
                message=refusal.message,
                plan_id=record.plan_id,
                rows=list(refusal.detail.get("rows", [])),
                window_s=window_s,
            )
        written = record_event(session, event, clock.time_ns())
        return StartGate(record.plan_id, refusal=refusal, events=[written])

    return job


def _flight_rules_refusal(
    record: PassRecord, document: str, duration_s: float, window_s: float
) -> Refusal | None:
    stored = json.loads(document).get("flight_rules")
    if stored is None:
        return Refusal(
            FLIGHT_RULES_UNCHECKED,
            f"pass {record.name!r} will not start: its plan {record.plan_id} has never been "
            "checked against the flight rules (stored before them, or imported): check it "
            f"with POST /api/plans/{record.plan_id}/check, then start the pass",
            {"rows": []},
        )
    report = FlightRulesReport.from_dict(stored).with_row(fits_pass_row(duration_s, window_s))
    if report.passed:
        return None
    return Refusal(
        FLIGHT_RULE_VIOLATION,
        f"pass {record.name!r} will not start: {violation_message(report)}",
        {"rows": [row.to_dict() for row in report.failing]},
    )
