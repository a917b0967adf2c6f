"""``/api/plans``: plan an experiment (operator), validate a request, read plans (viewer).

Routes are plain functions: FastAPI runs them in its threadpool, so seconds of planning
never block the event loop (and the link's websocket with it).
"""

from __future__ import annotations

import time
from typing import Annotated

from fastapi import APIRouter, Query, Response

from server.api.deps import OperatorDep, SessionDep, ViewerDep
from server.schemas import ERROR_RESPONSES, PlanCreate, PlanPublic, PlansPublic, PlanValidation
from server.services import plans as service

__all__ = ["router"]

router = APIRouter(prefix="/api/plans", tags=["plans"], responses=ERROR_RESPONSES)


@router.post("", status_code=201, response_model=PlanPublic)
def create_plan(request: PlanCreate, session: SessionDep, who: OperatorDep) -> PlanPublic:
    """Plan ``experiment`` with ``parameters`` and store the plan; 422 with the planner's
    message when the experiment or a parameter is refused."""
    return service.create_plan(
        session=session, request=request, actor=who.name, now_ns=time.time_ns()
    )


@router.post("/validate", response_model=PlanValidation)
def validate_plan(request: PlanCreate, _: OperatorDep) -> PlanValidation:
    """Plan the request without storing it: ``valid`` with the summary, or the errors."""
    return service.validate(request)


@router.get("", response_model=PlansPublic)
def list_plans(
    session: SessionDep,
    _: ViewerDep,
    experiment: Annotated[str | None, Query(max_length=64)] = None,
    offset: Annotated[int, Query(ge=0, le=1_000_000_000)] = 0,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
) -> PlansPublic:
    """Plans, newest first (summaries without metrics or segments)."""
    return service.list_plans(session=session, experiment=experiment, offset=offset, limit=limit)


@router.get("/{plan_id}", response_model=PlanPublic)
def get_plan(plan_id: str, session: SessionDep, _: ViewerDep) -> PlanPublic:
    return service.get_plan(session=session, plan_id=plan_id)


@router.get(
    "/{plan_id}/document",
    response_class=Response,
    responses={
        200: {
            "description": "The plan as the planner wrote it (planner.plan.Plan.to_json)",
            "content": {"application/json": {"schema": {"type": "object"}}},
        }
    },
)
def get_plan_document(plan_id: str, session: SessionDep, _: ViewerDep) -> Response:
    document = service.get_plan_document(session=session, plan_id=plan_id)
    return Response(content=document, media_type="application/json")
