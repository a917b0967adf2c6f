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

import time
from collections.abc import Callable
from dataclasses import asdict
from typing import Any

from fastapi import APIRouter
from pydantic import BaseModel, ConfigDict, Field
from sqlalchemy.orm import Session

from server.api.deps import DatabaseDep, LinkDep, OperatorDep, RunnerDep, ViewerDep
from server.errors import ServiceError
from server.schemas import ERROR_RESPONSES
from server.services.dbworker import Database
from server.services.link import LinkUnavailable
from server.storage import repository as repo

__all__ = ["router"]

router = APIRouter(tags=["control"], responses=ERROR_RESPONSES)


class StartRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    confirm: str = Field(max_length=200, description='"START <pass name>"')


class AbortRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    confirm: str = Field(max_length=200, description='"ABORT <pass name>"')
    reason: str = Field(default="operator abort", min_length=1, max_length=300)


class PassControlPublic(BaseModel):
    pass_id: str
    name: str
    state: str
    state_reason: str | None
    version: int
    epoch_ns: int | None


def _confirmation_job(
    pass_id: str, action: str, confirm: str, actor: str
) -> Callable[[Session], tuple[str, str | None]]:
    """A DB job: the pass's id, and the expected text when ``confirm`` is wrong (then the
    refusal is written to the audit log)."""

    def job(session: Session) -> tuple[str, str | None]:
        record = repo.get_pass(session=session, pass_id=pass_id)
        expected = f"{action} {record.name}"
        if confirm == expected:
            return record.id, None
        repo.add_event(
            session=session,
            time_ns=time.time_ns(),
            kind="pass_control_refused",
            actor=actor,
            detail={"action": action.lower(), "confirm": confirm},
            pass_id=record.id,
        )
        return record.id, expected

    return job


async def _confirmed(db: Database, pass_id: str, action: str, confirm: str, actor: str) -> str:
    # Through the command path's database worker (no blocking database call in the event
    # loop, and its own connections: readers cannot hold it up), ahead of its queue.
    key, expected = await db.run(_confirmation_job(pass_id, action, confirm, actor), control=True)
    if expected is not None:
        raise ServiceError(
            422, "confirmation_mismatch", f"confirm must be exactly {expected!r}, got {confirm!r}"
        )
    return key


async def _public(db: Database, pass_id: str) -> PassControlPublic:
    def job(session: Session) -> PassControlPublic:
        record = repo.get_pass(session=session, pass_id=pass_id, refresh=True)
        return PassControlPublic(
            pass_id=record.id,
            name=record.name,
            state=record.state,
            state_reason=record.state_reason,
            version=record.version,
            epoch_ns=record.epoch_ns,
        )

    return await db.run(job, control=True)


@router.post("/api/passes/{pass_id}/start")
async def start_pass(
    pass_id: str, body: StartRequest, who: OperatorDep, db: DatabaseDep, runner: RunnerDep
) -> PassControlPublic:
    key = await _confirmed(db, pass_id, "START", body.confirm, who.name)
    try:
        await runner.start(key, who.name)
    except LinkUnavailable as exc:
        raise ServiceError(409, "link_down", str(exc)) from None
    return await _public(db, key)


@router.post("/api/passes/{pass_id}/abort")
async def abort_pass(
    pass_id: str, body: AbortRequest, who: OperatorDep, db: DatabaseDep, runner: RunnerDep
) -> PassControlPublic:
    key = await _confirmed(db, pass_id, "ABORT", body.confirm, who.name)
    await runner.abort(key, who.name, body.reason)
    return await _public(db, key)


@router.get("/api/link/status")
def link_status(_: ViewerDep, link: LinkDep, runner: RunnerDep) -> dict[str, Any]:
    return {**asdict(link.status()), "active_pass_id": runner.active_pass_id}
