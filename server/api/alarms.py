"""``/api/alarms``: the alarms (viewer) and their acknowledgement (operator): docs/alarms.md.

- ``GET /api/alarms?pass=<id>&active=true|false`` -> ``{"alarms": [...], "count": n}``,
  newest raised first; ``active``: triggered or not yet acknowledged (latching). An unknown
  pass is 404.
- ``POST /api/alarms/{alarm_id}/acknowledge`` body ``{"comment": str | null}`` -> the
  alarm; 404 ``alarm_not_found``, 409 ``already_acknowledged``. Through the command path's
  database worker, ahead of its queue (an operator waits), like start and abort.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from server.api.deps import AlarmsDep, IdPath, OperatorDep, SessionDep, ViewerDep
from server.schemas import ERROR_RESPONSES, SafeLine
from server.schemas.alarms import AlarmAcknowledge, AlarmPublic, AlarmsPublic
from server.services import alarms as service

__all__ = ["router"]

router = APIRouter(prefix="/api/alarms", tags=["alarms"], responses=ERROR_RESPONSES)


@router.get("", response_model=AlarmsPublic)
def list_alarms(
    session: SessionDep,
    _: ViewerDep,
    pass_id: Annotated[SafeLine | None, Query(alias="pass", max_length=64)] = None,
    active: bool | None = None,
    offset: Annotated[int, Query(ge=0, le=1_000_000_000)] = 0,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
) -> AlarmsPublic:
    """Alarms newest raised first: of one pass (``pass``), only the active ones
    (``active=true``: triggered or not acknowledged) or only the others (``false``)."""
    return service.list_alarms(
        session=session, pass_id=pass_id, active=active, offset=offset, limit=limit
    )


@router.post("/{alarm_id}/acknowledge", response_model=AlarmPublic)
async def acknowledge_alarm(
    alarm_id: IdPath,
    body: AlarmAcknowledge,
    who: OperatorDep,
    alarms: AlarmsDep,
) -> AlarmPublic:
    """Acknowledge an alarm, with an optional comment (audited: ``alarm_acknowledged``)."""
    return await alarms.acknowledge(alarm_id, who.name, body.comment)
