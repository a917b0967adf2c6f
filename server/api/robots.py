"""``/api/robots``: the robots the ground plans for, and their URDFs (viewer).

``GET /api/robots``: each robot the server knows (shipped under ``examples/robots/``, or given
at its start: :mod:`server.services.robots`) with its joint count, hash, joint limits, named
poses and experiment defaults (its description's, and the effective ones a plan takes with
those the tool derives marked): what the console's planning page offers.
``GET /api/robots/{name}/urdf``: a robot's URDF by name (``hikoboshi model urdf --robot
FILE``); ``GET /api/robots/by-hash/{robot_hash}/urdf``: the URDF of the robot a plan was
made for, by the plan's ``robot_hash`` (a plan records the description's hash, and the robot
may have been given to the server by file). An unknown robot is 404 ``unknown_robot`` with the
known ones. ``GET /api/model/urdf`` stays ETS-VII's (server/api/model.py).
``GET /api/robots/{name}/meshes/{index}/{filename}``: a visual mesh the robot's URDF names
(a vendor's STL, DAE or OBJ; the URDFs above point their ``<mesh>`` here): only the files
its description names and loading found, looked up by key, never a path made from the
request; 404 ``unknown_mesh`` with the robot's meshes otherwise.
"""

from __future__ import annotations

import threading
from typing import Annotated, Any

import numpy as np
from fastapi import APIRouter, Path
from fastapi.responses import FileResponse, Response

from planner.catalogue import experiments
from planner.description import RobotDescription
from planner.dynamics import DynamicsWorkspace
from planner.errors import PlannerError
from planner.meshes import mesh_media_type
from planner.plan import ETS7_ROBOT_NAME
from server.api.deps import SettingsDep, ViewerDep
from server.api.openapi import file_content
from server.schemas import ERROR_RESPONSES
from server.schemas.plans import RobotPosePublic, RobotPublic, RobotsPublic
from server.services import robots as service

__all__ = ["router"]

router = APIRouter(prefix="/api/robots", tags=["robots"], responses=ERROR_RESPONSES)

_URDF_RESPONSE: dict[int | str, dict[str, Any]] = {
    200: {"content": file_content("application/xml", text=True), "description": "The URDF document"}
}
RobotName = Annotated[str, Path(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.\-]+$")]
RobotHash = Annotated[str, Path(pattern=r"^[0-9a-f]{64}$")]

#: (name, hash) -> the robot as listed; a description is solved (its poses' IK) once.
_PUBLIC: dict[tuple[str, str], RobotPublic] = {}
_URDF: dict[tuple[str, str], str] = {}
_LOCK = threading.Lock()


def _deg(values: np.ndarray | None) -> list[float] | None:
    return None if values is None else [float(v) for v in np.degrees(values)]


def _pose_joints_deg(robot: RobotDescription, name: str, ws: DynamicsWorkspace) -> list[float]:
    try:
        return _deg(robot.target_joints_rad(name, ws, experiment="console")) or []
    except PlannerError:
        written = robot.poses[name].joints_rad
        return _deg(written) or []


def _public(robot: RobotDescription) -> RobotPublic:
    key = (robot.name, robot.content_sha256)
    with _LOCK:
        if key in _PUBLIC:
            return _PUBLIC[key]
        ws = DynamicsWorkspace(robot.model)
        poses = []
        for name, pose in robot.poses.items():
            joints = _pose_joints_deg(robot, name, ws)
            poses.append(
                RobotPosePublic(
                    name=name,
                    description=pose.description,
                    joints_deg=joints or None,
                    hand_pos_robot_m=None
                    if pose.hand_pos_robot_m is None
                    else [float(v) for v in pose.hand_pos_robot_m],
                    hand_rpy_deg=None
                    if pose.hand_rpy_deg is None
                    else [float(v) for v in pose.hand_rpy_deg],
                )
            )
        effective = {name: dict(robot.experiment_defaults(name)) for name in experiments()}
        public = RobotPublic(
            name=robot.name,
            description=robot.description,
            n_joints=robot.n_joints,
            robot_hash=robot.content_sha256,
            default=robot.name == ETS7_ROBOT_NAME,
            joint_limits_deg=[
                [float(lo), float(hi)] for lo, hi in np.degrees(robot.model.joint_limit_rad)
            ],
            poses=poses,
            experiments={k: dict(v) for k, v in robot.experiments.items()},
            experiment_defaults=effective,
            derived_defaults={
                name: sorted(set(values) - set(robot.experiments.get(name, {})))
                for name, values in effective.items()
            },
            urdf_url=f"/api/robots/{robot.name}/urdf",
        )
        _PUBLIC[key] = public
        return public


def _urdf(robot: RobotDescription) -> Response:
    key = (robot.name, robot.content_sha256)
    with _LOCK:
        if key not in _URDF:
            _URDF[key] = service.robot_urdf(robot, mesh_base=f"/api/robots/{robot.name}/meshes/")
        text = _URDF[key]
    return Response(text, media_type="application/xml")


@router.get("", response_model=RobotsPublic)
def list_robots(settings: SettingsDep, _: ViewerDep) -> RobotsPublic:
    """The robots this server plans for, by name: ETS-VII (``default``) and the others."""
    robots = service.robot_descriptions(settings)
    data = [_public(robots[name]) for name in sorted(robots)]
    return RobotsPublic(data=data, count=len(data))


@router.get("/{name}/urdf", response_class=Response, responses=_URDF_RESPONSE)
def get_robot_urdf(name: RobotName, settings: SettingsDep, _: ViewerDep) -> Response:
    """The robot's URDF (``hikoboshi model urdf --robot FILE``); 404 ``unknown_robot``."""
    return _urdf(service.description_named(settings, name))


@router.get("/by-hash/{robot_hash}/urdf", response_class=Response, responses=_URDF_RESPONSE)
def get_robot_urdf_by_hash(robot_hash: RobotHash, settings: SettingsDep, _: ViewerDep) -> Response:
    """The URDF of the robot whose description hash is ``robot_hash`` (a plan's
    ``robot_hash``: ``GET /api/plans/{id}/document``); 404 ``unknown_robot`` when the server
    has no such description."""
    return _urdf(service.description_by_hash(settings, robot_hash))


_MESH_RESPONSE: dict[int | str, dict[str, Any]] = {
    200: {
        "content": file_content("model/stl", "model/vnd.collada+xml", "model/obj"),
        "description": "The mesh file as the vendor wrote it",
    }
}
MeshIndex = Annotated[int, Path(ge=0, le=9999)]
MeshFile = Annotated[str, Path(min_length=1, max_length=255, pattern=r"^[A-Za-z0-9_.\-]+$")]


@router.get(
    "/{name}/meshes/{index}/{filename}", response_class=FileResponse, responses=_MESH_RESPONSE
)
def get_robot_mesh(
    name: RobotName, index: MeshIndex, filename: MeshFile, settings: SettingsDep, _: ViewerDep
) -> FileResponse:
    """A visual mesh the robot's URDF names (``GET /api/robots/{name}/urdf`` points its
    ``<mesh>`` elements here); 404 ``unknown_robot`` or ``unknown_mesh`` with the reason."""
    robot = service.description_named(settings, name)
    path = service.mesh_file(robot, f"{index}/{filename}")
    return FileResponse(
        path,
        media_type=mesh_media_type(filename) or "application/octet-stream",
        headers={"Cache-Control": "private, max-age=3600"},
    )
