"""``/api/passes``: schedule a pass (operator); read passes and their commands (viewer)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from server.api.deps import (
    ClockDep,
    DownlinkDep,
    IdPath,
    OperatorDep,
    SessionDep,
    SettingsDep,
    ViewerDep,
)
from server.operations.scheduling import schedule_pass as schedule
from server.schemas import (
    ERROR_RESPONSES,
    MAX_NS,
    CommandKind,
    CommandsPublic,
    CommandStage,
    PassState,
)
from server.schemas.passes import (
    PassCreate,
    PassCreateFromWindow,
    PassesPublic,
    PassPublic,
    PassSummaryPublic,
)
from server.services import passes as service
from server.services.summary import pass_summary

__all__ = ["router"]

router = APIRouter(prefix="/api/passes", tags=["passes"], responses=ERROR_RESPONSES)


@router.post("", status_code=201, response_model=PassPublic)
def schedule_pass(
    request: PassCreate | PassCreateFromWindow,
    session: SessionDep,
    settings: SettingsDep,
    who: OperatorDep,
    clock: ClockDep,
) -> PassPublic:
    """Schedule a pass of a stored plan in a window given by hand (``aos_time``,
    ``los_time``) or named (``window``: mission, relay, AOS time; the pass then runs in the
    window's net time, and the window is stored with it). The window must hold the plan and
    the start lead: 409 ``plan_exceeds_window`` (either kind, docs/missions.md); 404
    ``unknown_mission``, ``unknown_relay``, ``no_such_window``."""
    # its event goes to the consoles when the service commits (the sessions' hook)
    return schedule(
        session=session, settings=settings, request=request, actor=who.name, now_ns=clock.time_ns()
    )


@router.get("", response_model=PassesPublic)
def list_passes(
    session: SessionDep,
    _: ViewerDep,
    state: Annotated[list[PassState] | None, Query()] = None,
    offset: Annotated[int, Query(ge=0, le=1_000_000_000)] = 0,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
) -> PassesPublic:
    """Passes in AOS order, only those in ``state`` (repeatable) if given."""
    return service.list_passes(session=session, states=state, offset=offset, limit=limit)


@router.get("/{pass_id}", response_model=PassPublic)
def get_pass(pass_id: IdPath, session: SessionDep, _: ViewerDep) -> PassPublic:
    return service.get_pass(session=session, pass_id=pass_id)


@router.get("/{pass_id}/commands", response_model=CommandsPublic)
def list_commands(
    pass_id: IdPath,
    session: SessionDep,
    _: ViewerDep,
    stage: Annotated[list[CommandStage] | None, Query()] = None,
    offset: Annotated[int, Query(ge=0, le=1_000_000_000)] = 0,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
    kind: Annotated[list[CommandKind] | None, Query()] = None,
    t0: Annotated[
        int | None, Query(ge=0, le=MAX_NS, description="time tags from, ns (onboard clock)")
    ] = None,
    t1: Annotated[int | None, Query(ge=0, le=MAX_NS, description="until, ns, excluded")] = None,
) -> CommandsPublic:
    """The pass's commands by time tag: only those at ``stage`` and of ``kind`` (each
    repeatable), with a time tag in ``[t0, t1)``, where given (422 ``empty_range`` when
    ``t1 <= t0``)."""
    return service.list_commands(
        session=session,
        pass_id=pass_id,
        stages=stage,
        kinds=kind,
        t0_ns=t0,
        t1_ns=t1,
        offset=offset,
        limit=limit,
    )


@router.get("/{pass_id}/summary", response_model=PassSummaryPublic)
def get_summary(
    pass_id: IdPath, session: SessionDep, _: ViewerDep, downlink: DownlinkDep
) -> PassSummaryPublic:
    """Frames expected, stored and missing in the pass's telemetry window; its commands by
    outcome (rejected by reason); duplicates dropped and stored."""
    dropped = downlink.duplicates_by_pass.get(pass_id, 0)
    return pass_summary(session=session, pass_id=pass_id, duplicates_dropped=dropped)
