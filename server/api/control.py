"""Pass control and link status.

- ``POST /api/passes/{pass_id}/start`` (operator), body ``{"confirm": "START <pass name>"}``
- ``POST /api/passes/{pass_id}/abort`` (operator), body
  ``{"confirm": "ABORT <pass name>", "reason": "..."}``
- ``GET /api/link/status`` (viewer)

The confirmation must spell the action and the pass's exact name, so a stale console tab
or a copied request cannot start or abort the wrong pass. Missing: 422 ``invalid_request``;
wrong: 422 ``confirmation_mismatch`` naming the expected text. Both actions are audited
(``pass_state`` events with the caller's name as actor, and ``pass_control_refused`` for a
refused confirmation).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict
from typing import Any

from fastapi import APIRouter, Request
from pydantic import BaseModel, ConfigDict, Field
from sqlalchemy.orm import Session

from server.api.deps import OperatorDep, ViewerDep
from server.schemas import ERROR_RESPONSES, PassControlPublic
from server.services.errors import ConflictError, InvalidRequestError
from server.services.link import GroundLink, LinkUnavailable
from server.services.passes import check_confirmation, control_state
from server.services.runner import PassRunner

__all__ = ["router"]

router = APIRouter(tags=["control"], responses=ERROR_RESPONSES)


class StartRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    confirm: str = Field(max_length=200, description='"START <pass name>"')


class AbortRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    confirm: str = Field(max_length=200, description='"ABORT <pass name>"')
    reason: str = Field(default="operator abort", min_length=1, max_length=300)


def _confirmation_job(
    pass_id: str, action: str, confirm: str, actor: str
) -> Callable[[Session], tuple[str, str | None]]:
    """A DB job: the pass's id, and the expected text when ``confirm`` is wrong (then the
    refusal is written to the audit log)."""

    def job(session: Session) -> tuple[str, str | None]:
        return check_confirmation(
            session=session, pass_id=pass_id, action=action, confirm=confirm, actor=actor
        )

    return job


async def _confirmed(link: GroundLink, pass_id: str, action: str, confirm: str, actor: str) -> str:
    # Through the link's database worker (no blocking database call in the event loop, and
    # the command path's own connections: readers cannot hold it up), ahead of its queue.
    key, expected = await link.db.run(
        _confirmation_job(pass_id, action, confirm, actor), control=True
    )
    if expected is not None:
        raise InvalidRequestError(
            "confirmation_mismatch", f"confirm must be exactly {expected!r}, got {confirm!r}"
        )
    return key


async def _public(link: GroundLink, pass_id: str) -> PassControlPublic:
    def job(session: Session) -> PassControlPublic:
        return control_state(session=session, pass_id=pass_id)

    return await link.db.run(job, control=True)


@router.post("/api/passes/{pass_id}/start")
async def start_pass(
    pass_id: str, body: StartRequest, who: OperatorDep, request: Request
) -> PassControlPublic:
    link: GroundLink = request.app.state.link
    runner: PassRunner = request.app.state.runner
    key = await _confirmed(link, pass_id, "START", body.confirm, who.name)
    try:
        await runner.start(key, who.name)
    except LinkUnavailable as exc:
        raise ConflictError("link_down", str(exc)) from None
    return await _public(link, key)


@router.post("/api/passes/{pass_id}/abort")
async def abort_pass(
    pass_id: str, body: AbortRequest, who: OperatorDep, request: Request
) -> PassControlPublic:
    link: GroundLink = request.app.state.link
    runner: PassRunner = request.app.state.runner
    key = await _confirmed(link, pass_id, "ABORT", body.confirm, who.name)
    await runner.abort(key, who.name, body.reason)
    return await _public(link, key)


@router.get("/api/link/status")
def link_status(_: ViewerDep, request: Request) -> dict[str, Any]:
    link: GroundLink = request.app.state.link
    runner: PassRunner = request.app.state.runner
    return {**asdict(link.status()), "active_pass_id": runner.active_pass_id}
