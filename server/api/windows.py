"""``/api/windows``: a mission's contact windows over a span (viewer; docs/missions.md).

``GET /api/windows?mission=NAME&start=ISO&hours=H``: the windows whose acquisition falls in
``[start, start + hours)``, computed in a worker process (skyfield and sgp4, nothing
downloaded). ``hours`` is capped at ``MAX_WINDOW_HOURS`` (a week). 404 ``unknown_mission``
naming the known ones; 422 for a start without its UTC offset, hours out of range, a
mission file that does not load, or a span too far from the elements' epoch; 503 ``busy``
when every worker is taken.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, Request
from pydantic import AwareDatetime

from server.api.deps import SettingsDep, ViewerDep, WorkersDep
from server.schemas import ERROR_RESPONSES, NAME_PATTERN
from server.schemas.passes import WindowsPublic
from server.services import missions as service

__all__ = ["router"]

router = APIRouter(prefix="/api/windows", tags=["windows"], responses=ERROR_RESPONSES)


@router.get("", response_model=WindowsPublic)
async def list_windows(
    http: Request,
    settings: SettingsDep,
    _: ViewerDep,
    workers: WorkersDep,
    mission: Annotated[
        str, Query(min_length=1, max_length=64, pattern=NAME_PATTERN, examples=["ets7-1999"])
    ],
    start: Annotated[AwareDatetime, Query(examples=["1999-09-30T00:00:00Z"])],
    hours: Annotated[float, Query(gt=0, le=service.MAX_WINDOW_HOURS, examples=[24.0])] = 24.0,
) -> WindowsPublic:
    """The mission's windows with AOS in ``[start, start + hours)``, by AOS."""
    path = service.resolve_mission(settings, mission)
    return await workers.run(
        service.windows_job,
        str(path),
        start,
        hours,
        deadline_s=settings.read_deadline_s,
        what=f"windows of {mission}",
        client=http,
    )
