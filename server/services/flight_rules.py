"""Checking a stored plan against its robot's flight rules (docs/robots.md, SPEC 8):
:func:`check_stored_plan`, ``POST /api/plans/{id}/check``, in a worker process as planning
is. The start gate that reads the stored report is :mod:`server.operations.start_gate`.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from sqlalchemy.orm import Session

from planner.errors import PlannerError
from planner.plan import Plan
from server.schemas.plans import PlanPublic
from server.services.errors import ConflictError
from server.services.events import PlanChecked
from server.services.events import record as record_event
from server.services.plans import (
    check_flight_rules,
    get_plan,
)
from server.services.robots import description_for_plan
from server.storage import repository as repo

__all__ = ["check_stored_plan"]


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
