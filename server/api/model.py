"""``/api/model``: the robot as the ground models it (viewer).

``GET /api/model/urdf``: the URDF generated from the canonical model (SPEC 1.1, 6, 7), the
same document the MCAP recordings attach and the console's 3D view draws.
"""

from __future__ import annotations

from functools import cache

from fastapi import APIRouter
from fastapi.responses import Response

from planner.model import default_model
from planner.urdf import urdf_xml
from server.api.deps import ViewerDep
from server.schemas import ERROR_RESPONSES

__all__ = ["router"]

router = APIRouter(prefix="/api/model", tags=["model"], responses=ERROR_RESPONSES)


@cache
def _urdf() -> str:
    return urdf_xml(default_model())


@router.get(
    "/urdf",
    response_class=Response,
    responses={200: {"content": {"application/xml": {}}, "description": "The URDF document"}},
)
def get_urdf(_: ViewerDep) -> Response:
    return Response(_urdf(), media_type="application/xml")
