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
from fastapi.responses import JSONResponse
from pydantic import BaseModel

from server.api.errors import error_body
from server.schemas import ErrorPublic
from server.services.readiness import ReadinessProbe

__all__ = ["router"]

router = APIRouter(tags=["service"])


class ReadyPublic(BaseModel):
    status: Literal["ready"]
    #: The head migration the database is at.
    migration: list[str]


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
        return JSONResponse(
            error_body("starting", "the service is not started"),
            status_code=503,
            headers={"Retry-After": "2"},
        )
    answer = await probe.check()
    if answer.ready:
        return ReadyPublic(status="ready", migration=answer.detail["migration"])
    return JSONResponse(
        error_body(answer.code, answer.message, answer.detail or None),
        status_code=503,
        headers={"Retry-After": "5"},
    )
