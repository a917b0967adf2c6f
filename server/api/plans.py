"""``/api/plans``: plan an experiment or store a plan document (operator), validate a
request, read plans (viewer).

Planning (``POST /api/plans``, ``POST /api/plans/validate``) runs in a worker process
(:mod:`server.services.workers`): never in the server's threads, where it would hold the
GIL the link's event loop needs. At most ``worker_processes`` at once, each killed past
``plan_deadline_s`` or when its client goes away; a full pool answers 503 ``busy`` at once.
The parameters are checked first, in the server (milliseconds): a refused request never
takes a worker. A plan document (``POST /api/plans/documents``) is read whole, within
``max_plan_document_bytes``, and read and checked in a worker. The reads are plain
functions (FastAPI's threadpool).
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, Request, Response

from planner.errors import PlannerError
from server.api.deps import IdPath, OperatorDep, SessionDep, SettingsDep, ViewerDep, WorkersDep
from server.api.edge_checks import request_too_large
from server.api.jobs import JobsDep
from server.operations import plans as operations
from server.operations.plan_documents import document_schema
from server.schemas import ERROR_RESPONSES, ErrorPublic, SafeLine
from server.schemas.plans import PlanCreate, PlanPublic, PlansPublic, PlanValidation
from server.services import plans as service
from server.services.errors import DomainError
from server.services.robots import resolve_robot

__all__ = ["router"]

router = APIRouter(prefix="/api/plans", tags=["plans"], responses=ERROR_RESPONSES)


@router.post("", status_code=201, response_model=PlanPublic)
async def create_plan(request: PlanCreate, who: OperatorDep, jobs: JobsDep) -> PlanPublic:
    """Plan ``experiment`` with ``parameters`` for ``robot`` (a robot's name the server
    knows: shipped under ``examples/robots/`` or given at its start; none: ETS-VII) and store
    the plan; 422 with the planner's message when the experiment or a parameter is refused,
    422 ``unknown_robot`` for a robot the server does not know; 503 ``busy``
    (``Retry-After``) when every worker is taken; 504 past ``plan_deadline_s``."""
    service.check_parameters(request)
    robot_path = resolve_robot(jobs.settings, request.robot)
    return await jobs.written(
        operations.create_plan,
        request=request,
        actor=who.name,
        robot_path=None if robot_path is None else str(robot_path),
        deadline_s=jobs.settings.plan_deadline_s,
        what=f"planning {request.experiment}",
    )


_DOCUMENT = {"application/json": {"schema": document_schema()}}


@router.post(
    "/documents",
    status_code=201,
    response_model=PlanPublic,
    openapi_extra={"requestBody": {"required": True, "content": _DOCUMENT}},
    responses={413: {"model": ErrorPublic, "description": "Over max_plan_document_bytes"}},
)
async def upload_plan_document(http: Request, who: OperatorDep, jobs: JobsDep) -> PlanPublic:
    """Store a plan document (the body: the file ``hikoboshi plan ... --out FILE`` wrote,
    ``hikoboshi plan upload FILE`` sends it) exactly as its commands are: a pass of it flies
    them. Its robot is the one its ``robot_hash`` names (422 ``unknown_robot`` when the
    server has no such description); the document's own prediction and flight-rules
    report are never trusted: the ground predicts the plan again from its commands (422
    ``invalid_plan_document`` naming the quantity, the time and both values when the
    document's prediction differs by more than 1e-6; within it, the ground's is stored),
    checks it and stores its own report (a failing plan is stored, and a pass of it will not
    start). A document that is not a plan is refused with 422 ``invalid_plan_document`` and
    the reason, nothing stored; 413 over
    ``max_plan_document_bytes``; 503 ``busy`` and 504 as planning."""
    settings = jobs.settings
    limit = settings.max_plan_document_bytes
    declared = http.headers.get("content-length", "")
    if declared.isdigit() and int(declared) > limit:
        raise request_too_large(int(declared), limit)
    chunks: list[bytes] = []
    size = 0
    async for chunk in http.stream():
        size += len(chunk)
        if size > limit:
            raise request_too_large(size, limit)
        chunks.append(chunk)
    return await jobs.written(
        operations.upload_document,
        data=b"".join(chunks),
        actor=who.name,
        robot_files=jobs.robot_files,
        max_bytes=limit,
        max_depth=settings.max_json_depth,
        deadline_s=settings.plan_deadline_s,
        what="checking an uploaded plan document",
    )


@router.post("/validate", response_model=PlanValidation)
async def validate_plan(
    request: PlanCreate,
    http: Request,
    settings: SettingsDep,
    _: OperatorDep,
    workers: WorkersDep,
) -> PlanValidation:
    """Plan the request without storing it: ``valid`` with the summary, or the errors
    (as ``POST /api/plans``: 503 ``busy`` when every worker is taken, 504 past the
    deadline)."""
    try:
        service.check_parameters(request)
        robot_path = resolve_robot(settings, request.robot)
    except (PlannerError, DomainError) as exc:
        return service.invalid(exc)
    return await workers.run(
        operations.validate,
        request,
        None if robot_path is None else str(robot_path),
        deadline_s=settings.plan_deadline_s,
        what=f"planning {request.experiment}",
        client=http,
    )


@router.post("/{plan_id}/check", response_model=PlanPublic)
async def check_plan(plan_id: IdPath, who: OperatorDep, jobs: JobsDep) -> PlanPublic:
    """Check a stored plan against its robot's flight rules and store the report (for a plan
    stored before the rules, or imported: a pass's start refuses a plan the ground has not
    checked, ``flight_rules_unchecked``); the plan with its ``flight_rules``, audited as
    ``plan_checked``. 404 for an unknown plan, 409 ``robot_unknown`` when the server has no
    description of its robot, 422 ``no_collision_geometry``; 503 ``busy`` as planning."""
    return await jobs.written(
        operations.check_stored_plan,
        plan_id=plan_id,
        actor=who.name,
        robot_files=jobs.robot_files,
        deadline_s=jobs.settings.plan_deadline_s,
        what=f"checking the flight rules of plan {plan_id}",
    )


@router.get("", response_model=PlansPublic)
def list_plans(
    session: SessionDep,
    _: ViewerDep,
    experiment: Annotated[SafeLine | None, Query(max_length=64)] = None,
    offset: Annotated[int, Query(ge=0, le=1_000_000_000)] = 0,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
) -> PlansPublic:
    """Plans, newest first (summaries without metrics or segments)."""
    return service.list_plans(session=session, experiment=experiment, offset=offset, limit=limit)


@router.get("/{plan_id}", response_model=PlanPublic)
def get_plan(plan_id: IdPath, session: SessionDep, _: ViewerDep) -> PlanPublic:
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
def get_plan_document(plan_id: IdPath, session: SessionDep, _: ViewerDep) -> Response:
    document = service.get_plan_document(session=session, plan_id=plan_id)
    return Response(content=document, media_type="application/json")
