"""Pass control and link status.

- ``POST /api/passes/{pass_id}/start`` (operator), body ``{"confirm": "START <pass name>"}``
- ``POST /api/passes/{pass_id}/abort`` (operator), body
  ``{"confirm": "ABORT <pass name>", "reason": "..."}``
- ``POST /api/vehicle/safe-exit`` (operator), body ``{"confirm": "EXIT SAFE <vehicle>"}``:
  the ``safe_exit`` telecommand that takes the vehicle out of on-board safing (202 with the
  request's id; sent again until the vehicle reports it left SAFE, which the link status
  and the ``vehicle_safe_exited`` event show). 409 ``vehicle_not_safe`` when it is not in
  SAFE, 503 ``link_down`` without a link (nothing can reach the vehicle; ``Retry-After``),
  422 ``confirmation_mismatch`` (audited, ``pass_control_refused``).
- ``GET /api/link/status`` (viewer): from the link's memory on the event loop, no thread
  and no database (the live lane, server/api/lanes.py), so that no load delays it

A start is refused 409 ``vehicle_safe`` while the vehicle is in SAFE.

A start is refused 409 ``outside_window`` before the pass's window opens or after it closed,
409 ``plan_exceeds_window`` when its plan's last command would fall after the window's end,
and 409 ``flight_rule_violation`` when the pass's plan fails a flight rule (the failing rows
in the error's detail), before the runner is asked (:mod:`server.operations.start_gate`):
the pass stays ``scheduled``, nothing is uplinked. A plan stored without a report is
refused ``flight_rules_unchecked``, naming the check route.

The confirmation must spell the action and the pass's exact name, so a stale console tab
or a copied request cannot start or abort the wrong pass. Missing: 422 ``invalid_request``;
wrong: 422 ``confirmation_mismatch`` naming the expected text. Both actions are audited
(``pass_state`` events with the caller's name as actor, and ``pass_control_refused`` for a
refused confirmation).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Annotated, Any

from fastapi import APIRouter, Depends
from pydantic import BaseModel, ConfigDict, Field
from sqlalchemy.orm import Session

from server.api.deps import (
    ClockDep,
    DatabaseDep,
    IdPath,
    LinkDep,
    OperatorDep,
    RunnerDep,
    SettingsDep,
    ViewerDep,
    WorkersDep,
)
from server.operations.start_gate import start_gate_job
from server.operations.windows import start_lead_s, window_time
from server.schemas import ERROR_RESPONSES, SafeText
from server.schemas.passes import PassControlPublic
from server.services.clock import Clock
from server.services.dbworker import Database
from server.services.errors import ConflictError, InvalidRequestError, UnavailableError
from server.services.events import PassControlRefused, Recorded, event_job
from server.services.link import GroundLink, LinkUnavailable, SafeExitRefused
from server.services.passes import check_confirmation, control_state
from server.services.runner import PassRunner
from server.services.workers import WorkerPool
from server.settings import Settings

__all__ = ["router"]

router = APIRouter(tags=["control"], responses=ERROR_RESPONSES)

#: Retry-After (s) of a safe exit refused for want of a link.
SAFE_EXIT_RETRY_S = 5.0


class StartRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    confirm: SafeText = Field(max_length=200, description='"START <pass name>"')


class SafeExitRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    confirm: SafeText = Field(max_length=200, description='"EXIT SAFE <vehicle name>"')


class SafeExitAccepted(BaseModel):
    request_id: int = Field(description="the safe_exit telecommand's id")
    vehicle: str | None
    message: str


class AbortRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    confirm: SafeText = Field(max_length=200, description='"ABORT <pass name>"')
    reason: SafeText = Field(default="operator abort", min_length=1, max_length=300)


def _confirmation_job(
    pass_id: str, action: str, confirm: str, actor: str, clock: Clock
) -> Callable[[Session], tuple[str, str | None, list[Recorded]]]:
    """A DB job: the pass's id, and the expected text when ``confirm`` is wrong (then the
    refusal is written to the audit log: its event to publish)."""

    def job(session: Session) -> tuple[str, str | None, list[Recorded]]:
        return check_confirmation(
            session=session,
            pass_id=pass_id,
            action=action,
            confirm=confirm,
            actor=actor,
            time_ns=clock.time_ns(),
        )

    return job


async def _confirmed(ground: _Ground, pass_id: str, action: str, confirm: str, actor: str) -> str:
    # Through the command path's database worker (no blocking database call in the event
    # loop, and its own connections: readers cannot hold it up), ahead of its queue.
    job = _confirmation_job(pass_id, action, confirm, actor, ground.clock)
    key, expected, _ = await ground.db.run(job, control=True)  # its refusal published on commit
    if expected is not None:
        raise InvalidRequestError(
            "confirmation_mismatch", f"confirm must be exactly {expected!r}, got {confirm!r}"
        )
    return key


async def _public(db: Database, pass_id: str) -> PassControlPublic:
    def job(session: Session) -> PassControlPublic:
        return control_state(session=session, pass_id=pass_id)

    return await db.run(job, control=True)


@dataclass(frozen=True)
class _Ground:
    """What pass control needs of the command path."""

    db: Database
    clock: Clock
    runner: PassRunner
    settings: Settings
    workers: WorkerPool
    link: GroundLink


def _ground(
    db: DatabaseDep,
    clock: ClockDep,
    runner: RunnerDep,
    settings: SettingsDep,
    workers: WorkersDep,
    link: LinkDep,
) -> _Ground:
    return _Ground(db, clock, runner, settings, workers, link)


async def _may_start(ground: _Ground, pass_id: str, actor: str) -> None:
    """Refuse (409, audited) a start outside the pass's window, too late in it for its
    plan, or whose plan fails a flight rule or was never checked
    (server.operations.start_gate); a database job of the command path, no computation.
    The window is read on the ground's injected clock, the lead at the link's time scale."""
    link = ground.link
    lead_s = start_lead_s(ground.settings, link.time_scale if link.connected else 1.0)
    at = window_time(ground.settings, ground.clock.time_ns(), link)
    job = start_gate_job(pass_id=pass_id, actor=actor, clock=ground.clock, lead_s=lead_s, at=at)
    gate = await ground.db.run(job, control=True)  # its refusal published on commit
    if gate.refusal is not None:
        raise gate.refusal.error()


GroundDep = Annotated[_Ground, Depends(_ground)]


@router.post("/api/passes/{pass_id}/start")
async def start_pass(
    pass_id: IdPath, body: StartRequest, who: OperatorDep, ground: GroundDep
) -> PassControlPublic:
    key = await _confirmed(ground, pass_id, "START", body.confirm, who.name)
    await _may_start(ground, key, who.name)
    try:
        await ground.runner.start(key, who.name)
    except LinkUnavailable as exc:
        raise ConflictError("link_down", str(exc)) from None
    return await _public(ground.db, key)


@router.post("/api/passes/{pass_id}/abort")
async def abort_pass(
    pass_id: IdPath, body: AbortRequest, who: OperatorDep, ground: GroundDep
) -> PassControlPublic:
    key = await _confirmed(ground, pass_id, "ABORT", body.confirm, who.name)
    await ground.runner.abort(key, who.name, body.reason)
    return await _public(ground.db, key)


@router.post("/api/vehicle/safe-exit", status_code=202)
async def safe_exit(
    body: SafeExitRequest, who: OperatorDep, link: LinkDep, ground: GroundDep
) -> SafeExitAccepted:
    try:
        request_id = await link.request_safe_exit(who.name, body.confirm)
    except LinkUnavailable as exc:
        # nothing can reach the vehicle now: retry once it is back (ping period)
        raise UnavailableError(str(exc), SAFE_EXIT_RETRY_S, "link_down") from None
    except SafeExitRefused as exc:
        if exc.code == "confirmation_mismatch":
            refused = PassControlRefused(
                actor=who.name, pass_id=None, action="EXIT SAFE", confirm=body.confirm
            )
            await ground.db.write(event_job(refused, ground.clock), control=True)
            raise InvalidRequestError(exc.code, str(exc)) from None
        raise ConflictError(exc.code, str(exc)) from None
    return SafeExitAccepted(
        request_id=request_id,
        vehicle=link.vehicle,
        message="safe_exit sent; it is sent again until the vehicle reports it left SAFE",
    )


@router.get("/api/link/status")
async def link_status(_: ViewerDep, link: LinkDep, runner: RunnerDep) -> dict[str, Any]:
    return {**asdict(link.status()), "active_pass_id": runner.active_pass_id}
