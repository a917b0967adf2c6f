"""``/api/model``: the robot as the ground models it (viewer).

``GET /api/model/urdf``: the URDF generated from the canonical model (SPEC 1.1, 6, 7) with
ETS-VII's keep-out equipment drawn (``server.services.robots.robot_urdf``), the document the
console's 3D view draws (the MCAP recordings attach the model's export alone).
"""

from __future__ import annotations

from functools import cache

from fastapi import APIRouter
from fastapi.responses import Response

from planner.description import default_robot
from server.api.deps import ViewerDep
from server.api.openapi import file_content
from server.schemas import ERROR_RESPONSES
from server.services import robots as service

__all__ = ["router"]

router = APIRouter(prefix="/api/model", tags=["model"], responses=ERROR_RESPONSES)


@cache
def _urdf() -> str:
    return service.robot_urdf(default_robot())


@router.get(
    "/urdf",
    response_class=Response,
    responses={
        200: {
            "content": file_content("application/xml", text=True),
            "description": "The URDF document",
        }
    },
)
def get_urdf(_: ViewerDep) -> Response:
    return Response(_urdf(), media_type="application/xml")
