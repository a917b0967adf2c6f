"""The plan jobs the API runs in a worker process: plan and store, validate, store an
uploaded plan document, check a stored plan. Each plans or checks through
:mod:`server.operations.planning` (the one checked planning call) and stores through
:mod:`server.services.plans`.

Planning and checking take seconds of CPU and touch no database: they run before the
transaction opens, so no lock (SQLite takes the write lock at ``BEGIN``) is held meanwhile.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from sqlalchemy.orm import Session

from planner.description import load_robot
from planner.errors import PlannerError
from planner.plan import Plan
from server.operations.plan_documents import (
    INVALID_PLAN_DOCUMENT,
    description_for_document,
    read_document,
    with_ground_prediction,
)
from server.operations.planning import check as check_plan
from server.operations.planning import experiment_parameters, plan_checked
from server.schemas.plans import PlanCreate, PlanPublic, PlanValidation
from server.services.errors import ConflictError, DomainError, InvalidRequestError
from server.services.events import PlanChecked
from server.services.events import record as record_event
from server.services.plans import get_plan, invalid, store_plan, validation
from server.services.robots import description_for_plan
from server.storage import repository as repo

__all__ = ["check_stored_plan", "create_plan", "plan_request", "upload_document", "validate"]


def plan_request(request: PlanCreate, robot_path: str | None = None) -> Plan:
    """The plan for ``request``, checked (its document carries the ground's report, passing
    or not); planner errors propagate. ``robot_path``: the description of the robot the
    request names, as the server resolved it (:func:`server.services.robots.resolve_robot`;
    None: ETS-VII)."""
    robot = None if robot_path is None else load_robot(Path(robot_path))
    params = experiment_parameters(request.experiment, robot, values=request.parameters)
    return plan_checked(request.experiment, params, robot=robot).plan


def create_plan(
    *,
    session: Session,
    request: PlanCreate,
    actor: str,
    now_ns: int,
    robot_path: str | None = None,
) -> PlanPublic:
    """Plan and check ``request`` (:func:`plan_request`), then store it and ``plan_created``."""
    result = plan_request(request, robot_path)
    return store_plan(session=session, plan=result, actor=actor, now_ns=now_ns)


def validate(request: PlanCreate, robot_path: str | None = None) -> PlanValidation:
    """The checks of :func:`create_plan`, planning included, without storing anything."""
    try:
        return validation(plan_request(request, robot_path))
    except (PlannerError, DomainError) as exc:
        return invalid(exc)


def upload_document(
    *,
    session: Session,
    data: bytes,
    actor: str,
    now_ns: int,
    robot_files: Sequence[str] = (),
    max_bytes: int,
    max_depth: int,
) -> PlanPublic:
    """Store the plan document ``data`` (``hikoboshi plan ... --out`` wrote it) exactly as
    its commands are, with the ground's prediction and flight-rules report in place of its
    own: refused with ``invalid_plan_document`` (a prediction that is not the ground's among
    the reasons) or ``unknown_robot`` (module :mod:`server.operations.plan_documents`)
    before anything is written."""
    session.rollback()  # no transaction (no SQLite write lock) while the plan is checked
    plan = read_document(data, max_bytes=max_bytes, max_depth=max_depth)
    description = description_for_document(plan, [Path(p) for p in robot_files])
    plan = with_ground_prediction(plan, description)
    try:
        checked = check_plan(plan, description)
    except (PlannerError, ValueError, ArithmeticError, IndexError) as exc:
        # the planner's refusal (its joints are not the robot's), or numbers it cannot fly
        raise InvalidRequestError(INVALID_PLAN_DOCUMENT, f"the plan document: {exc}") from None
    return store_plan(session=session, plan=checked.plan, actor=actor, now_ns=now_ns)


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
    cannot be checked raises the reason (``robot_unknown``, ``no_collision_geometry``)."""
    plan = Plan.from_json(repo.get_plan(session=session, plan_id=plan_id).document)
    session.rollback()  # no transaction (no SQLite write lock) while the plan is checked
    try:
        description = description_for_plan(plan, [Path(p) for p in robot_files])
        checked = check_plan(plan, description)
    except PlannerError as exc:
        raise ConflictError("plan_cannot_be_checked", str(exc)) from exc
    try:
        repo.set_plan_document(session=session, plan_id=plan_id, plan=checked.plan)
        checked_event = PlanChecked(
            actor=actor,
            plan_id=plan_id,
            robot=description.name,
            passed=checked.passed,
            failing=[row.rule for row in checked.report.failing],
        )
        record_event(session, checked_event, now_ns)
        session.commit()
    except BaseException:
        session.rollback()
        raise
    return get_plan(session=session, plan_id=plan_id)
