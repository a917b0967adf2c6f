"""``GET /api/ready``: readiness (:mod:`server.services.readiness`). 200
``{"status": "ready", "migration": [...]}`` when the database answers at the head migration;
else 503 in the error shape, its code the reason (``database_unavailable``,
``database_timeout``, ``schema_not_at_head``), with ``Retry-After``. Public, like
``/api/health`` (docs/security.md "Public routes"): an orchestrator's probe holds no token,
and the answer holds no data.
"""

from __future__ import annotations

from typing import Any, Literal

from fastapi import APIRouter, Request
from pydantic import BaseModel

from server.api.errors import ProblemResponse, problem
from server.schemas import ErrorPublic
from server.services.readiness import ReadinessProbe

__all__ = ["router"]

router = APIRouter(tags=["service"])


class ReadyPublic(BaseModel):
    status: Literal["ready"]
    #: The head migration the database is at.
    migration: list[str]
    #: ``holder``: this ground commands the vehicle; ``standby``: it serves reads and
    #: consoles and takes over when the holder is gone (docs/operations.md "One ground in
    #: command"). A load balancer that must reach the holder asks ``/api/command``.
    command: Literal["holder", "standby"]


@router.get(
    "/api/ready",
    response_model=ReadyPublic,
    responses={503: {"model": ErrorPublic, "description": "Not ready, and why (Retry-After)"}},
)
async def ready(request: Request) -> Any:
    """Readiness: 200 when the database answers and its schema is at the head migration,
    503 with the reason otherwise (``/api/health`` is liveness and touches nothing)."""
    probe: ReadinessProbe | None = getattr(request.app.state, "readiness", None)
    if probe is None:  # the application has not started (or has stopped)
        return ProblemResponse(
            problem(503, "starting", "the service is not started"),
            status_code=503,
            headers={"Retry-After": "2"},
        )
    answer = await probe.check()
    if answer.ready:
        role = request.app.state.authority.status()["role"]
        return ReadyPublic(status="ready", migration=answer.detail["migration"], command=role)
    return ProblemResponse(
        problem(503, answer.code, answer.message, answer.detail or None),
        status_code=503,
        headers={"Retry-After": "5"},
    )


class CommandLeasePublic(BaseModel):
    #: always ``holder`` in a 200 answer
    role: Literal["holder"]
    ground: str
    lease: str
    token: int


@router.get(
    "/api/command",
    response_model=CommandLeasePublic,
    responses={503: {"model": ErrorPublic, "description": "A standby, and who holds the lease"}},
)
async def command(request: Request) -> Any:
    """Whether this ground commands the vehicle: 200 for the holder of the command lease,
    503 for a standby (or a holder whose lease is lapsing), with the holder's name. A load
    balancer in front of several grounds routes the spacecraft's link by it (docker-compose's
    ``replicas`` profile); public, like ``/api/ready``."""
    authority = getattr(request.app.state, "authority", None)
    if authority is None:
        return ProblemResponse(
            problem(503, "starting", "the service is not started"),
            status_code=503,
            headers={"Retry-After": "2"},
        )
    refusal = authority.refusal()
    if refusal is not None:
        return ProblemResponse(
            problem(503, refusal.code, refusal.message, refusal.detail),
            status_code=503,
            headers={"Retry-After": "1"},
        )
    status = authority.status()
    return CommandLeasePublic(
        role="holder", ground=status["ground"], lease=status["lease"], token=status["token"]
    )
