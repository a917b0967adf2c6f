"""``/api/missions``: the missions the ground computes contact windows for (viewer;
docs/missions.md).

``GET /api/missions``: each mission by name (what ``GET /api/windows`` and a pass naming a
window take), with its vehicle, relays, margins and the span its elements reach; a file
that does not load is listed apart with its reason. The console's timeline offers them.
"""

from __future__ import annotations

from fastapi import APIRouter

from server.api.deps import SettingsDep, ViewerDep
from server.schemas import ERROR_RESPONSES
from server.schemas.passes import MissionsPublic
from server.services import missions as service

__all__ = ["router"]

router = APIRouter(prefix="/api/missions", tags=["windows"], responses=ERROR_RESPONSES)


@router.get("", response_model=MissionsPublic)
def list_missions(settings: SettingsDep, _: ViewerDep) -> MissionsPublic:
    """The missions by name, and the files that do not load with their reasons."""
    return service.list_missions(settings)
