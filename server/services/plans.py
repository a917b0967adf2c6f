"""Plans as the ground stores them: a checked plan stored with its audit event, plans read
back, and the shapes the API gives them.

Planning and checking are :mod:`server.operations.planning`'s (one checked planning call for
every caller); the jobs that plan or check and then store are :mod:`server.operations.plans`'s.
Every stored plan carries the ground's flight-rules report in its document
(``"flight_rules"``, docs/robots.md). A plan that fails a rule is still stored, so that the
user can look at it (a pass of it will not start: :mod:`server.operations.start_gate`);
validation calls it invalid (``flight_rule_violation``) and returns the table.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

from sqlalchemy.orm import Session

from planner.catalogue import parameters_from_values, resolve
from planner.errors import PlannerError
from planner.flight_rules import FlightRulesReport
from planner.plan import Plan
from server.schemas import iso_from_ns
from server.schemas.plans import (
    FlightRulesPublic,
    PlanBrief,
    PlanCreate,
    PlanPublic,
    PlansPublic,
    PlanSummary,
    PlanValidation,
    SegmentPublic,
    ValidationIssue,
)
from server.services.errors import DomainError
from server.services.events import PlanCreated
from server.services.events import record as record_event
from server.storage import repository as repo
from server.storage.models import PlanRecord

__all__ = [
    "FLIGHT_RULE_VIOLATION",
    "check_parameters",
    "flight_rules_public",
    "get_plan",
    "get_plan_document",
    "invalid",
    "list_plans",
    "store_plan",
    "validation",
    "violation_message",
]


#: The error code of a plan that fails a flight rule (validation, and a refused start).
FLIGHT_RULE_VIOLATION = "flight_rule_violation"


def flight_rules_public(report: Mapping[str, Any] | None) -> FlightRulesPublic | None:
    """A plan document's ``flight_rules`` as the API types it (None: never checked)."""
    return None if report is None else FlightRulesPublic.model_validate(report)


def violation_message(report: FlightRulesReport) -> str:
    """The failing rows of ``report``, each described on one line (``RuleRow.describe``)."""
    failing = report.failing
    head = f"the plan fails {len(failing)} flight rule{'s' if len(failing) != 1 else ''}"
    return head + ": " + "; ".join(row.describe() for row in failing)


def check_parameters(request: PlanCreate) -> None:
    """The experiment and its parameters checked, without planning (milliseconds): the
    server refuses a bad request before it takes a worker process. A request for a
    robot (whose description supplies the defaults) has its names checked only: the
    worker loads the description and checks the rest."""
    params_type, _ = resolve(request.experiment)
    if request.robot is None:
        parameters_from_values(params_type, request.parameters)


def invalid(exc: PlannerError | DomainError) -> PlanValidation:
    """What ``POST /api/plans/validate`` answers for a refused request."""
    if isinstance(exc, DomainError):
        return PlanValidation(
            valid=False, errors=[ValidationIssue(code=exc.code, message=exc.message)]
        )
    return PlanValidation(
        valid=False, errors=[ValidationIssue(code=type(exc).__name__, message=str(exc))]
    )


def _summary(result: Plan) -> PlanSummary:
    return PlanSummary(
        experiment=result.experiment,
        parameters=json.loads(json.dumps(dict(result.parameters))),
        duration_s=result.duration_s,
        n_commands=len(result.command_times_s) + len(result.acs_commands),
        metrics=dict(result.metrics),
        segments=[
            SegmentPublic(name=s.name, kind=s.kind, t_start_s=s.t_start_s, t_end_s=s.t_end_s)
            for s in result.segments
        ],
    )


def validation(result: Plan) -> PlanValidation:
    """What ``POST /api/plans/validate`` answers for a checked plan (``result`` carries the
    ground's report): valid when every rule passes, else ``flight_rule_violation``."""
    assert result.flight_rules is not None  # checked plans only
    report = FlightRulesReport.from_dict(result.flight_rules)
    errors = (
        []
        if report.passed
        else [ValidationIssue(code=FLIGHT_RULE_VIOLATION, message=violation_message(report))]
    )
    return PlanValidation(
        valid=report.passed,
        errors=errors,
        summary=_summary(result),
        flight_rules=flight_rules_public(result.flight_rules),
    )


def _brief(record: PlanRecord) -> PlanBrief:
    return PlanBrief(
        id=record.id,
        experiment=record.experiment,
        parameters=record.parameters,
        duration_s=record.duration_s,
        n_commands=record.n_commands,
        created_at=iso_from_ns(record.created_at_ns),
    )


def _public(record: PlanRecord, document: Mapping[str, Any]) -> PlanPublic:
    return PlanPublic(
        **_brief(record).model_dump(),
        metrics=document["metrics"],
        segments=[SegmentPublic(**s) for s in document["segments"]],
        flight_rules=flight_rules_public(document.get("flight_rules")),
    )


def store_plan(*, session: Session, plan: Plan, actor: str, now_ns: int) -> PlanPublic:
    """Store ``plan`` (checked: its document carries the ground's report, passing or not)
    and an audit event ``plan_created`` in one transaction; the plan as the API gives it.
    Nothing is written when any part fails."""
    try:
        record = repo.add_plan(session=session, plan=plan, created_at_ns=now_ns)
        created = PlanCreated(
            actor=actor,
            plan_id=record.id,
            experiment=record.experiment,
            robot=plan.robot,
            robot_hash=plan.robot_hash,
        )
        record_event(session, created, now_ns)
        session.commit()
    except BaseException:
        session.rollback()
        raise
    return _public(record, json.loads(record.document))


def get_plan(*, session: Session, plan_id: str) -> PlanPublic:
    record = repo.get_plan(session=session, plan_id=plan_id)
    return _public(record, json.loads(record.document))


def get_plan_document(*, session: Session, plan_id: str) -> str:
    """The plan's JSON document as stored (``Plan.from_json`` reads it back)."""
    return repo.get_plan(session=session, plan_id=plan_id).document


def list_plans(*, session: Session, experiment: str | None, offset: int, limit: int) -> PlansPublic:
    page = repo.list_plans(session=session, experiment=experiment, offset=offset, limit=limit)
    return PlansPublic(data=[_brief(r) for r in page.items], count=page.count)
