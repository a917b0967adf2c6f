"""Plans: run the planner on a request, check it against its robot's flight rules, store
the result, read plans back.

Every plan is checked after planning (``RobotDescription.checked``: its predicted motion
against the robot's ``[flight_rules]``, docs/robots.md) and carries the report in its
document (``"flight_rules"``). A plan that fails a rule is still stored, so that the user can
look at it (a pass of it will not start: :mod:`server.services.flight_rules`); validation
calls it invalid (``flight_rule_violation``) and returns the table. A robot without
collision shapes cannot be shown clear: validation says so (``no_collision_geometry``) and
creation refuses it.

Planning takes seconds of CPU and touches no database: it runs before the transaction
opens, so no lock (SQLite takes the write lock at ``BEGIN``) is held while it runs. The API
runs :func:`create_plan` and :func:`validate` in a worker process
(:mod:`server.services.workers`), never in the server's own threads.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from sqlalchemy.orm import Session

from planner.catalogue import parameters_from_values, plan_experiment, resolve
from planner.collision import check_collision_model
from planner.description import RobotDescription, default_robot, load_robot
from planner.errors import InvalidInput, PlannerError
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
from server.services.errors import DomainError, InvalidRequestError
from server.services.events import PlanCreated
from server.services.events import record as record_event
from server.storage import repository as repo
from server.storage.models import PlanRecord

__all__ = [
    "FLIGHT_RULE_VIOLATION",
    "NO_COLLISION_GEOMETRY",
    "check_parameters",
    "create_plan",
    "flight_rules_public",
    "get_plan",
    "get_plan_document",
    "invalid",
    "list_plans",
    "plan",
    "validate",
    "violation_message",
]


#: The error code of a plan that fails a flight rule (validation, and a refused start).
FLIGHT_RULE_VIOLATION = "flight_rule_violation"
#: The error code of a robot whose description gives no collision shapes to check with.
NO_COLLISION_GEOMETRY = "no_collision_geometry"


def flight_rules_public(report: Mapping[str, Any] | None) -> FlightRulesPublic | None:
    """A plan document's ``flight_rules`` as the API types it (None: never checked)."""
    return None if report is None else FlightRulesPublic.model_validate(report)


def violation_message(report: FlightRulesReport) -> str:
    """The failing rows of ``report``, each described on one line (``RuleRow.describe``)."""
    failing = report.failing
    head = f"the plan fails {len(failing)} flight rule{'s' if len(failing) != 1 else ''}"
    return head + ": " + "; ".join(row.describe() for row in failing)


def check_flight_rules(
    description: RobotDescription, result: Plan, window_s: float | None = None
) -> tuple[Plan, FlightRulesReport]:
    """``result`` carrying its flight-rules report, and the report. A robot without
    collision shapes is the invalid request ``no_collision_geometry`` (its plans cannot
    be shown clear of the spacecraft); any other refusal of the check is the planner's."""
    try:
        check_collision_model(description.collision, description.name)
    except InvalidInput as exc:
        raise InvalidRequestError(NO_COLLISION_GEOMETRY, str(exc)) from None
    return description.checked(result, window_s=window_s)


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


def plan(request: PlanCreate, robot_path: str | None = None) -> tuple[Plan, str]:
    """The plan for ``request``, checked against its robot's flight rules (its document
    carries the report, passing or not), and its JSON document; planner errors propagate.
    ``robot_path`` is the description of the robot the request names, as the server
    resolved it (:func:`server.services.robots.resolve_robot`; None: ETS-VII): its model,
    poses and ``[experiments.*]`` defaults, and the plan records its name and hash.

    A numerical failure other than the planner's own errors (a singular matrix, an
    overflow) is still caused by the parameters sent: the invalid request
    ``planning_failed``, not an unexpected error. A robot without collision shapes: the
    invalid request ``no_collision_geometry`` (:func:`check_flight_rules`).
    """
    params_type, _ = resolve(request.experiment)
    robot = None if robot_path is None else load_robot(Path(robot_path))
    defaults = None if robot is None else robot.experiment_defaults(request.experiment)
    params = parameters_from_values(params_type, request.parameters, defaults=defaults)
    try:
        result = plan_experiment(request.experiment, params, robot=robot)
        result, _ = check_flight_rules(robot or default_robot(), result)
        document = result.to_json()  # refuses NaN and infinity
    except (PlannerError, DomainError):
        raise
    except (ValueError, ArithmeticError) as exc:
        raise InvalidRequestError(
            "planning_failed", f"{request.experiment} could not be planned: {exc}"
        ) from exc
    return result, document


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


def validate(request: PlanCreate, robot_path: str | None = None) -> PlanValidation:
    """The checks of :func:`create_plan`, planning included, without storing anything."""
    try:
        result, _ = plan(request, robot_path)
    except (PlannerError, DomainError) as exc:
        return invalid(exc)
    assert result.flight_rules is not None  # plan() checks every plan
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


def create_plan(
    *,
    session: Session,
    request: PlanCreate,
    actor: str,
    now_ns: int,
    robot_path: str | None = None,
) -> PlanPublic:
    """Plan and check it (:func:`plan`), then store the plan, its flight-rules report in its
    document whether it passes or not, and an audit event ``plan_created`` in one
    transaction."""
    result, document = plan(request, robot_path)
    try:
        record = repo.add_plan(session=session, plan=result, created_at_ns=now_ns)
        created = PlanCreated(
            actor=actor,
            plan_id=record.id,
            experiment=record.experiment,
            robot=result.robot,
            robot_hash=result.robot_hash,
        )
        record_event(session, created, now_ns)
        session.commit()
    except BaseException:
        session.rollback()
        raise
    return _public(record, json.loads(document))


def get_plan(*, session: Session, plan_id: str) -> PlanPublic:
    record = repo.get_plan(session=session, plan_id=plan_id)
    return _public(record, json.loads(record.document))


def get_plan_document(*, session: Session, plan_id: str) -> str:
    """The plan's JSON document as stored (``Plan.from_json`` reads it back)."""
    return repo.get_plan(session=session, plan_id=plan_id).document


def list_plans(*, session: Session, experiment: str | None, offset: int, limit: int) -> PlansPublic:
    page = repo.list_plans(session=session, experiment=experiment, offset=offset, limit=limit)
    return PlansPublic(data=[_brief(r) for r in page.items], count=page.count)
