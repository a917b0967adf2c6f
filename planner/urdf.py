"""URDF export of the canonical :class:`~planner.model.RobotModel`, for RViz, Foxglove and
URDF-based tools (pinocchio, KDL).

Tree and frames (the same frame choices as :mod:`planner.mjcf`, SPEC section 7)::

    base_link --robot_base_joint (fixed)--> robot_base
      --joint1--> link1 --joint2--> link2 ... --joint6--> link6 --hand_joint (fixed)--> hand

- ``base_link``: the base frame, origin at the base centre of mass. Its ``<inertial>`` is the
  *locked* base, exactly ``model.base_mass_kg`` and ``model.base_inertia_kgm2`` (Table 1).
  The reaction-wheel rotors are internal to it and are **not** exported as joints: their
  masses are already in Table 1's base numbers, and URDF tools have no use for their spin.
  A URDF consumer therefore sees the satellite with its wheels locked.
- ``robot_base``: a massless frame at ``model.pos_base_from_robot_m``, axes parallel to the
  base frame (the robot frame, origin on joint 1).
- ``link i``: origin on joint i, axes parallel to the robot frame at the all-zero pose; joint i
  is ``revolute`` about ``link.joint_axis_robot``. Each joint's origin is joint i's position
  relative to joint i-1's (to the robot origin for joint 1) at the all-zero pose, with rpy 0.
  The link's ``<inertial>`` sits at its CoM, ``link.com_robot_m - link.joint_pos_robot_m``,
  with rpy 0 and the full tensor ``link.inertia_com_robot_kgm2`` (robot-frame axes at the
  all-zero pose, so link-frame axes at any pose).
- ``hand``: a massless frame at the hand point, on link n (ETS-VII: 6), parallel to it.

Inertia entries are written as the matrix entries themselves (URDF's ``ixy`` is ``I[0, 1]``),
so the sign convention is the one chosen once in :data:`planner.model.INERTIA_PRODUCT_SIGN`.
Joint limits and rates come from the model; the effort limit, which no source publishes, is
200 N m on every joint **(our choice)**: a display/bookkeeping value for URDF tools,
not something the simulation enforces. Numbers are written with ``repr`` (shortest string that
round-trips), so a parser gets back exactly the model's floats.

Visuals are for display only: a box for the base (2.4 x 2.0 x 2.0 m unless told), a
cylinder along each link's segment from its joint to the next joint (the hand point for the
last link), a sphere at the hand. ``equipment`` (a description's keep-out bodies,
:class:`planner.collision.CollisionBody` fixed on the base) adds one massless link per body,
fixed on ``base_link`` at its origin, with a visual per shape (a capsule drawn as a cylinder
of its whole length; a convex hull is not drawn), so that viewers show what the flight rules
keep the arm away from.

``meshes`` (a vendor description's visual meshes, :class:`planner.meshes.MeshVisual`) with
``mesh_uri`` (the address a viewer fetches each from, by its key): each becomes a ``<visual>``
``<mesh>`` on the link of the body that carries it, placed at its zero-pose frame; a link
that has one draws no cylinder (the last link no hand sphere), the vendor's shape standing
for it. Without ``mesh_uri`` no mesh is written and the primitives are drawn as before.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from planner.collision import CollisionBody
from planner.frames import rpy_from_matrix
from planner.meshes import MeshVisual, mesh_link_pose
from planner.model import RobotModel

__all__ = ["urdf_xml"]

Array = NDArray[np.float64]

# SPEC publishes no joint torque; URDF requires an effort limit.
_JOINT_EFFORT_LIMIT_NM = 200.0

_BASE_BOX_SIZE_M = (2.4, 2.0, 2.0)
_LINK_RADIUS_M = 0.06
_HAND_RADIUS_M = 0.08
_MIN_SEGMENT_M = 1e-9  # a shorter segment gets no cylinder (its direction is undefined)

_BASE_RGBA = (0.85, 0.7, 0.3, 1.0)
_LINK_RGBA = (0.8, 0.8, 0.85, 1.0)
_HAND_RGBA = (0.9, 0.3, 0.2, 1.0)
_EQUIPMENT_RGBA = (0.55, 0.6, 0.7, 1.0)


def _num(x: float) -> str:
    return repr(float(x))


def _vec(a: Array | tuple[float, ...]) -> str:
    return " ".join(_num(x) for x in np.asarray(a, dtype=np.float64))


def _origin(parent: ET.Element, xyz: Array, rpy: Array | None = None) -> None:
    ET.SubElement(parent, "origin", xyz=_vec(xyz), rpy=_vec(np.zeros(3) if rpy is None else rpy))


def _inertial(link: ET.Element, mass_kg: float, com_m: Array, inertia_kgm2: Array) -> None:
    inertial = ET.SubElement(link, "inertial")
    _origin(inertial, com_m)
    ET.SubElement(inertial, "mass", value=_num(mass_kg))
    i = inertia_kgm2
    ET.SubElement(
        inertial,
        "inertia",
        ixx=_num(i[0, 0]),
        ixy=_num(i[0, 1]),
        ixz=_num(i[0, 2]),
        iyy=_num(i[1, 1]),
        iyz=_num(i[1, 2]),
        izz=_num(i[2, 2]),
    )


def _visual(
    link: ET.Element,
    name: str,
    xyz: Array,
    rpy: Array,
    shape: str,
    rgba: tuple[float, ...],
    **size: str,
) -> None:
    visual = ET.SubElement(link, "visual", name=name)
    _origin(visual, xyz, rpy)
    ET.SubElement(ET.SubElement(visual, "geometry"), shape, attrib=size)
    # Inline colour on every visual: each URDF parser resolves it without a global table.
    material = ET.SubElement(visual, "material", name=f"{name}_material")
    ET.SubElement(material, "color", rgba=_vec(rgba))


def _rpy_z_along(direction: Array) -> Array:
    """``(roll, pitch, yaw)`` whose ``Rz(yaw) Ry(pitch) Rx(roll)`` maps +z onto ``direction``.

    With roll 0, the rotated z axis is ``(cos yaw sin pitch, sin yaw sin pitch, cos pitch)``.
    """
    d = direction / np.linalg.norm(direction)
    pitch = float(np.arctan2(np.hypot(d[0], d[1]), d[2]))
    yaw = float(np.arctan2(d[1], d[0]))
    return np.array([0.0, pitch, yaw])


def _joint(
    robot: ET.Element, name: str, kind: str, parent: str, child: str, xyz: Array
) -> ET.Element:
    joint = ET.SubElement(robot, "joint", name=name, type=kind)
    _origin(joint, xyz)
    ET.SubElement(joint, "parent", link=parent)
    ET.SubElement(joint, "child", link=child)
    return joint


def _equipment(robot: ET.Element, body: CollisionBody, pos_base_from_robot_m: Array) -> None:
    """One keep-out body as a massless link fixed on the base (its shapes' zero-pose robot
    frame positions moved into the base frame)."""
    link = ET.SubElement(robot, "link", name=body.name)
    for k, shape in enumerate(body.shapes):
        xyz = shape.pos_robot_m + pos_base_from_robot_m
        rpy = rpy_from_matrix(shape.rot_robot_from_shape)
        name = f"{body.name}_{k}"
        if shape.kind == "box":
            _visual(link, name, xyz, rpy, "box", _EQUIPMENT_RGBA, size=_vec(shape.dims))
        elif shape.kind == "sphere":
            _visual(link, name, xyz, rpy, "sphere", _EQUIPMENT_RGBA, radius=_num(shape.dims[0]))
        elif shape.kind in ("cylinder", "capsule"):
            radius, length = shape.dims
            whole = length + (2.0 * radius if shape.kind == "capsule" else 0.0)
            _visual(
                link,
                name,
                xyz,
                rpy,
                "cylinder",
                _EQUIPMENT_RGBA,
                radius=_num(radius),
                length=_num(whole),
            )
    _joint(robot, f"{body.name}_joint", "fixed", "base_link", body.name, np.zeros(3))


def urdf_xml(
    model: RobotModel,
    *,
    name: str = "ets7",
    base_box_size_m: tuple[float, float, float] = _BASE_BOX_SIZE_M,
    equipment: Sequence[CollisionBody] = (),
    meshes: Sequence[MeshVisual] = (),
    mesh_uri: Callable[[str], str] | None = None,
) -> str:
    """The URDF document of ``model`` (frames as in the module docstring), as a string.
    ``base_box_size_m``: the base's display box (ETS-VII's by default); ``equipment``: the
    keep-out bodies fixed on the base to draw (none by default); ``meshes`` and ``mesh_uri``
    (key -> address): the vendor's visual meshes (none unless both are given)."""
    robot = ET.Element("robot", name=name)
    drawn = list(meshes) if mesh_uri is not None else []
    meshed = {m.joint for m in drawn}

    base = ET.SubElement(robot, "link", name="base_link")
    _inertial(base, model.base_mass_kg, np.zeros(3), model.base_inertia_kgm2)
    _visual(
        base,
        "base_box",
        np.zeros(3),
        np.zeros(3),
        "box",
        _BASE_RGBA,
        size=_vec(base_box_size_m),
    )
    ET.SubElement(robot, "link", name="robot_base")
    _joint(
        robot, "robot_base_joint", "fixed", "base_link", "robot_base", model.pos_base_from_robot_m
    )

    parent_name, parent_pos_robot_m = "robot_base", np.zeros(3)
    for i, spec in enumerate(model.links):
        end_robot_m = (
            model.links[i + 1].joint_pos_robot_m
            if i + 1 < model.n_joints
            else model.hand_pos_robot_m
        )
        link = ET.SubElement(robot, "link", name=spec.name)
        _inertial(
            link,
            spec.mass_kg,
            spec.com_robot_m - spec.joint_pos_robot_m,
            spec.inertia_com_robot_kgm2,
        )
        segment_m = end_robot_m - spec.joint_pos_robot_m
        length_m = float(np.linalg.norm(segment_m))
        if length_m > _MIN_SEGMENT_M and i + 1 not in meshed:
            _visual(
                link,
                f"{spec.name}_segment",
                0.5 * segment_m,
                _rpy_z_along(segment_m),
                "cylinder",
                _LINK_RGBA,
                radius=_num(_LINK_RADIUS_M),
                length=_num(length_m),
            )

        joint = _joint(
            robot,
            f"joint{i + 1}",
            "revolute",
            parent_name,
            spec.name,
            spec.joint_pos_robot_m - parent_pos_robot_m,
        )
        ET.SubElement(joint, "axis", xyz=_vec(spec.joint_axis_robot))
        lo, hi = model.joint_limit_rad[i]
        ET.SubElement(
            joint,
            "limit",
            lower=_num(lo),
            upper=_num(hi),
            effort=_num(_JOINT_EFFORT_LIMIT_NM),
            velocity=_num(model.joint_rate_limit_radps[i]),
        )
        parent_name, parent_pos_robot_m = spec.name, spec.joint_pos_robot_m

    hand = ET.SubElement(robot, "link", name="hand")
    if model.n_joints not in meshed:
        _visual(
            hand,
            "hand_sphere",
            np.zeros(3),
            np.zeros(3),
            "sphere",
            _HAND_RGBA,
            radius=_num(_HAND_RADIUS_M),
        )
    hand_joint = _joint(
        robot,
        "hand_joint",
        "fixed",
        parent_name,
        "hand",
        model.hand_pos_robot_m - parent_pos_robot_m,
    )
    if model.rot_robot_from_hand is not None:  # a turned hand frame (a vendor's flange)
        origin = hand_joint.find("origin")
        assert origin is not None
        origin.set("rpy", _vec(rpy_from_matrix(model.rot_robot_from_hand)))

    for body in equipment:
        _equipment(robot, body, model.pos_base_from_robot_m)
    links = {link.get("name"): link for link in robot.iter("link")}
    for k, mesh in enumerate(drawn):
        assert mesh_uri is not None
        owner, xyz, rot = mesh_link_pose(model, mesh)
        visual = ET.SubElement(links[owner], "visual", name=f"{mesh.link}_mesh_{k}")
        _origin(visual, xyz, rpy_from_matrix(rot))
        ET.SubElement(
            ET.SubElement(visual, "geometry"),
            "mesh",
            filename=mesh_uri(mesh.key),
            scale=_vec(mesh.scale),
        )
        if mesh.rgba is not None:
            material = ET.SubElement(visual, "material", name=f"{mesh.link}_mesh_{k}_material")
            ET.SubElement(material, "color", rgba=_vec(mesh.rgba))

    ET.indent(robot, space="  ")
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"
