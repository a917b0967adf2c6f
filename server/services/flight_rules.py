"""The flight rules at a pass's start: no plan that fails one is uplinked (the
rules: docs/robots.md, SPEC 8).

``POST /api/passes/{id}/start`` asks :func:`start_gate_job` (a short database job of the
command path) before the runner starts the pass. It reads the report the plan's document
carries (:mod:`server.services.plans` stores every plan with one), takes the ``fits_pass``
row again with the pass's own window (``los - aos`` less the start lead,
:func:`server.services.passes.start_lead_s`), and refuses the start when any row fails:
the conflict ``flight_rule_violation``, its detail the failing rows, audited as
``pass_start_refused`` (:class:`~server.services.events.PassStartRefusedFlightRules`). The
pass stays ``scheduled`` and nothing reaches the link. There is no override.

The start never computes: it compares numbers the ground stored. A plan stored without a
report (before the rules existed, or imported from a recording, whose report is not the
ground's word) is refused with ``flight_rules_unchecked``, saying how to check it:
``POST /api/plans/{id}/check`` (:func:`check_stored_plan`, in a worker process as planning
is), which stores the ground's report in the plan's document (``plan_checked``). So an
operator's start never waits for a worker that viewers may be keeping busy.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sqlalchemy.orm import Session

from planner.errors import PlannerError
from planner.flight_rules import FlightRulesReport, fits_pass_row
from planner.plan import Plan
from server.schemas.plans import PlanPublic
from server.services.clock import Clock
from server.services.errors import ConflictError
from server.services.events import PassStartRefusedFlightRules, PlanChecked, Recorded
from server.services.events import record as record_event
from server.services.plans import (
    FLIGHT_RULE_VIOLATION,
    check_flight_rules,
    get_plan,
    violation_message,
)
from server.services.robots import description_for_plan
from server.storage import repository as repo
from server.storage.models import PassRecord

__all__ = [
    "FLIGHT_RULES_UNCHECKED",
    "Refusal",
    "StartGate",
    "check_stored_plan",
    "pass_window_s",
    "start_gate_job",
]

#: The start's refusal of a plan the ground has not checked.
FLIGHT_RULES_UNCHECKED = "flight_rules_unchecked"


@dataclass(frozen=True)
class Refusal:
    """Why a start is refused: the conflict's code, message and detail."""

    code: str
    message: str
    detail: dict[str, Any]


@dataclass(frozen=True)
class StartGate:
    """The gate's answer: the pass's plan, and why the start is refused (None: it may
    start); the events written."""

    plan_id: str
    refusal: Refusal | None = None
    events: list[Recorded] = field(default_factory=list)


def pass_window_s(record: PassRecord, lead_s: float) -> float:
    """The time the pass's window leaves its plan: ``los - aos`` less the start lead."""
    return (record.los_time_ns - record.aos_time_ns) / 1e9 - lead_s


def _refusal_event(
    actor: str, pass_id: str, plan_id: str, refusal: Refusal, window_s: float
) -> PassStartRefusedFlightRules:
    return PassStartRefusedFlightRules(
        actor=actor,
        pass_id=pass_id,
        reason=refusal.code,
        message=refusal.message,
        plan_id=plan_id,
        rows=list(refusal.detail.get("rows", [])),
        window_s=window_s,
    )


def start_gate_job(
    *, pass_id: str, actor: str, clock: Clock, lead_s: float
) -> Callable[[Session], StartGate]:
    """A database job: may the pass's plan start (module doc)? A pass that is not
    ``scheduled`` is let through: the start transaction refuses it with its own reason."""

    def job(session: Session) -> StartGate:
        record = repo.get_pass(session=session, pass_id=pass_id, refresh=True)
        if record.state != "scheduled":
            return StartGate(record.plan_id)
        plan = repo.get_plan(session=session, plan_id=record.plan_id)
        stored = json.loads(plan.document).get("flight_rules")
        window_s = pass_window_s(record, lead_s)
        if stored is None:
            refusal = Refusal(
                FLIGHT_RULES_UNCHECKED,
                f"pass {record.name!r} will not start: its plan {record.plan_id} has never been "
                "checked against the flight rules (stored before them, or imported): check it "
                f"with POST /api/plans/{record.plan_id}/check, then start the pass",
                {"rows": []},
            )
            event = _refusal_event(actor, record.id, record.plan_id, refusal, window_s)
            written = record_event(session, event, clock.time_ns())
            return StartGate(record.plan_id, refusal=refusal, events=[written])
        report = FlightRulesReport.from_dict(stored).with_row(
            fits_pass_row(plan.duration_s, window_s)
        )
        if report.passed:
            return StartGate(record.plan_id)
        refusal = Refusal(
            FLIGHT_RULE_VIOLATION,
            f"pass {record.name!r} will not start: {violation_message(report)}",
            {"rows": [row.to_dict() for row in report.failing]},
        )
        event = _refusal_event(actor, record.id, record.plan_id, refusal, window_s)
        written = record_event(session, event, clock.time_ns())
        return StartGate(record.plan_id, refusal=refusal, events=[written])

    return job


def check_stored_plan(
    *,
    session: Session,
    plan_id: str,
    actor: str,
    now_ns: int,
    robot_files: Sequence[str] = (),
) -> PlanPublic:
    """Check stored plan ``plan_id`` against its robot's flight rules (the robot found by the
    plan's description hash among those the server knows), store the report in its document
    and audit ``plan_checked``; the plan as ``GET /api/plans/{id}`` gives it. A plan that
    cannot be checked raises the reason (``robot_unknown``, ``no_collision_geometry``). A
    worker process's job: it holds no transaction while it computes."""
    plan = Plan.from_json(repo.get_plan(session=session, plan_id=plan_id).document)
    session.rollback()  # no transaction (no SQLite write lock) while the plan is checked
    try:
        description = description_for_plan(plan, [Path(p) for p in robot_files])
        checked, report = check_flight_rules(description, plan)
    except PlannerError as exc:
        raise ConflictError("plan_cannot_be_checked", str(exc)) from exc
    try:
        repo.set_plan_document(session=session, plan_id=plan_id, plan=checked)
        checked_event = PlanChecked(
            actor=actor,
            plan_id=plan_id,
            robot=description.name,
            passed=report.passed,
            failing=[row.rule for row in report.failing],
        )
        record_event(session, checked_event, now_ns)
        session.commit()
    except BaseException:
        session.rollback()
        raise
    return get_plan(session=session, plan_id=plan_id)
