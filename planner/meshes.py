"""A vendor URDF's visual meshes placed on the model's bodies, for viewers to draw.

Each ``<visual>`` whose geometry is a ``<mesh>`` the description can reach (a path beside the
URDF, or a ``package://`` URI whose folder ``[packages]`` names) becomes a :class:`MeshVisual`:
the mesh file's key (what ``GET /api/robots/{name}/meshes/{key}`` serves), the body that
carries it (``joint`` 0: the base and what is fixed on it, else the arm joint that moves it)
and its frame at the all-zero pose in the robot frame, placed as the collision shapes are
(:mod:`planner.collision`). The export (:func:`planner.urdf.urdf_xml`) draws each on its
body's link in place of that link's primitive. docs/robots.md, "Meshes".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from planner.model import RobotModel

__all__ = ["MESH_MEDIA_TYPES", "MeshVisual", "mesh_key", "mesh_link_pose", "mesh_media_type"]

Array = NDArray[np.float64]

#: A mesh file's media type by its extension (what the server answers, what viewers load).
MESH_MEDIA_TYPES = {
    ".stl": "model/stl",
    ".dae": "model/vnd.collada+xml",
    ".obj": "model/obj",
}


def mesh_media_type(filename: str) -> str | None:
    """The media type of a mesh file by its extension (None: not one viewers load)."""
    dot = filename.rfind(".")
    return MESH_MEDIA_TYPES.get(filename[dot:].lower()) if dot >= 0 else None


def mesh_key(index: int, filename: str) -> str:
    """The served name of the ``index``-th mesh file a URDF names: ``3/base.dae`` (the
    number keeps two files of one name apart, the name keeps the extension loaders read)."""
    return f"{index}/{filename.rstrip('/').rsplit('/', 1)[-1]}"


@dataclass(frozen=True, eq=False)
class MeshVisual:
    """One visual mesh at the all-zero pose, robot frame (a point ``x`` of the mesh file is at
    ``rot_robot_from_mesh @ (scale * x) + pos_robot_m``)."""

    link: str  # the URDF link that holds the <visual>
    joint: int  # 0: rigid with the base; k: moved by arm joint k (1-based)
    uri: str  # the <mesh filename> as written
    key: str  # the served name (mesh_key)
    rot_robot_from_mesh: Array
    pos_robot_m: Array
    scale: tuple[float, float, float]
    rgba: tuple[float, float, float, float] | None  # the <visual>'s inline colour, if any


def mesh_link_pose(model: RobotModel, mesh: MeshVisual) -> tuple[str, Array, Array]:
    """The link of the export (:func:`planner.urdf.urdf_xml`) that carries ``mesh`` and the
    mesh's position and rotation in that link's frame: ``base_link`` (the base frame) for a
    mesh rigid with the base, else arm link k's frame (on joint k, robot axes at zero)."""
    if mesh.joint == 0:
        return "base_link", mesh.pos_robot_m + model.pos_base_from_robot_m, mesh.rot_robot_from_mesh
    link = model.links[mesh.joint - 1]
    return link.name, mesh.pos_robot_m - link.joint_pos_robot_m, mesh.rot_robot_from_mesh
