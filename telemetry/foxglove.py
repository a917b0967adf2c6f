"""Foxglove well-known schemas (JSON encoding) and the robot's frame transforms for them.

``foxglove.FrameTransforms`` is Foxglove's published schema (field names exactly as in
foxglove-sdk ``schemas/jsonschema/FrameTransforms.json``): ``transforms[]`` of
``timestamp{sec, nsec}``, ``parent_frame_id``, ``child_frame_id``, ``translation{x, y, z}``
and ``rotation{x, y, z, w}``, where translation and rotation place the child frame in the
parent frame (a point in the child maps to ``rotation * p + translation`` in the parent).

:func:`frame_transforms` gives one such message per telemetry frame: the base in the orbit
frame (:data:`ORBIT_FRAME`, the root) from the recorded attitude, then every link of the URDF
of :func:`planner.urdf.urdf_xml` relative to its URDF parent, at the measured joint angles.
Link poses come from the model's own MuJoCo kinematics (:func:`planner.mjcf.compile_model`),
so they are the planner's, not a second derivation. The base's position in the orbit frame is
not telemetered: its translation is zero (the base centre of mass at the orbit origin).

:func:`mesh_scene_update` gives a vendor robot's visual meshes as one ``foxglove.SceneUpdate``
(field names as foxglove-sdk ``schemas/jsonschema/SceneUpdate.json``): one entity per mesh,
on the frame of the export's link that carries it (``/tf`` moves it), the file embedded as
a ``foxglove.ModelPrimitive``'s ``data`` (base64 in JSON) with its media type, lifetime 0
(for ever). Embedded rather than named by URL: an MCAP is opened away from the ground, and
the ground's mesh route needs a token no viewer of a file has.
"""

from __future__ import annotations

import base64
import json
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from typing import Any

import mujoco
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from planner.meshes import MeshVisual, mesh_link_pose, mesh_media_type
from planner.mjcf import compile_model
from planner.model import RobotModel
from planner.mujoco_conventions import MjLayout

__all__ = [
    "FRAME_TRANSFORMS_SCHEMA",
    "FRAME_TRANSFORMS_SCHEMA_NAME",
    "LOG_LEVELS",
    "LOG_SCHEMA",
    "LOG_SCHEMA_NAME",
    "ORBIT_FRAME",
    "SCENE_UPDATE_SCHEMA",
    "SCENE_UPDATE_SCHEMA_NAME",
    "STRING_SCHEMA",
    "STRING_SCHEMA_NAME",
    "FrameTransformer",
    "event_level",
    "event_log",
    "frame_transforms",
    "link_poses_base",
    "mesh_scene_update",
    "urdf_tree",
]

Array = NDArray[np.float64]

ORBIT_FRAME = "orbit"
FRAME_TRANSFORMS_SCHEMA_NAME = "foxglove.FrameTransforms"
#: A message with one string field ``data`` (ROS ``std_msgs/String``), for the URDF topic.
STRING_SCHEMA_NAME = "std_msgs/String"

_XYZ = ("x", "y", "z")
_XYZW = ("x", "y", "z", "w")


def _object(
    title: str, properties: dict[str, Any], description: str | None = None
) -> dict[str, Any]:
    """A schema object of ``properties``, every one required."""
    head = {"title": title} if description is None else {"title": title, "description": description}
    return {**head, "type": "object", "properties": properties, "required": list(properties)}


def _numbers_object(title: str, keys: tuple[str, ...]) -> dict[str, Any]:
    return _object(title, {k: {"type": "number"} for k in keys})


_TIME: dict[str, Any] = {
    "type": "object",
    "properties": {
        "sec": {"type": "integer", "minimum": 0},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999},
    },
}
_TITLED_TIME: dict[str, Any] = {"title": "time", **_TIME}

FRAME_TRANSFORMS_SCHEMA: dict[str, Any] = _object(
    FRAME_TRANSFORMS_SCHEMA_NAME,
    {
        "transforms": {
            "type": "array",
            "items": _object(
                "foxglove.FrameTransform",
                {
                    "timestamp": _TITLED_TIME,
                    "parent_frame_id": {"type": "string"},
                    "child_frame_id": {"type": "string"},
                    "translation": _numbers_object("foxglove.Vector3", _XYZ),
                    "rotation": _numbers_object("foxglove.Quaternion", _XYZW),
                },
                "The pose of a child frame in a parent frame",
            ),
        }
    },
    "An array of FrameTransform messages",
)

#: ``foxglove.Log`` (foxglove-sdk ``schemas/jsonschema/Log.json``): what Foxglove's Log panel
#: shows. ``level`` is ``foxglove.LogLevel``: these names, 0 to 5.
LOG_SCHEMA_NAME = "foxglove.Log"
LOG_LEVELS = {"UNKNOWN": 0, "DEBUG": 1, "INFO": 2, "WARNING": 3, "ERROR": 4, "FATAL": 5}
LOG_SCHEMA: dict[str, Any] = _object(
    LOG_SCHEMA_NAME,
    {
        "timestamp": {**_TITLED_TIME, "description": "Timestamp of log message"},
        "level": {
            "title": "foxglove.LogLevel",
            "description": "Log level",
            "oneOf": [{"title": name, "const": value} for name, value in LOG_LEVELS.items()],
        },
        "message": {"type": "string", "description": "Log message"},
        "name": {"type": "string", "description": "Process or node name"},
        "file": {"type": "string", "description": "Filename"},
        "line": {"type": "integer", "minimum": 0, "description": "Line number in the file"},
    },
    "A log message",
)

STRING_SCHEMA: dict[str, Any] = _object(STRING_SCHEMA_NAME, {"data": {"type": "string"}})


def urdf_tree(urdf: str) -> list[tuple[str, str]]:
    """``(parent, child)`` link names of every joint of a URDF document, in document order."""
    root = ET.fromstring(urdf)
    tree = []
    for joint in root.iter("joint"):
        parent, child = joint.find("parent"), joint.find("child")
        if parent is None or child is None:
            raise ValueError(f"URDF joint {joint.get('name')!r} lacks a parent or a child")
        tree.append((str(parent.get("link")), str(child.get("link"))))
    return tree


class _Kinematics:
    """The model compiled once, its data and the ids of the bodies and sites the URDF names
    (MuJoCo's ``base`` body is URDF's ``base_link``, its ``robot_origin`` site
    ``robot_base``, its ``hand`` site ``hand``; link bodies share their URDF names)."""

    def __init__(self, model: RobotModel, mjm: mujoco.MjModel | None = None) -> None:
        self.n_joints = model.n_joints
        self.mjm = compile_model(model) if mjm is None else mjm
        self.mjd = mujoco.MjData(self.mjm)
        self.layout = MjLayout.of(self.mjm, model.n_joints, len(model.wheels))
        robot_site = int(mujoco.mj_name2id(self.mjm, mujoco.mjtObj.mjOBJ_SITE, "robot_origin"))
        bodies = {"base_link": self.layout.base_body} | {
            link.name: body for link, body in zip(model.links, self.layout.link_bodies, strict=True)
        }
        sites = {"robot_base": robot_site, "hand": self.layout.hand_site}
        self.names = [*bodies, *sites]
        self.body_ids = list(bodies.values())
        self.site_ids = list(sites.values())

    def poses(self, joints_rad: Array) -> dict[str, tuple[Array, Array]]:
        mjm, mjd, layout = self.mjm, self.mjd, self.layout
        q = np.asarray(joints_rad, dtype=np.float64).reshape(-1, self.n_joints)
        pos = np.empty((len(self.names), len(q), 3))
        rot = np.empty((len(self.names), len(q), 3, 3))
        body_ids, site_ids = self.body_ids, self.site_ids
        nb = len(body_ids)
        for k, row in enumerate(q):
            mjd.qpos[:] = mjm.qpos0  # base at the origin, identity attitude
            mjd.qpos[layout.joint_qpos] = row
            mujoco.mj_kinematics(mjm, mjd)
            pos[:nb, k] = mjd.xpos[body_ids]
            rot[:nb, k] = mjd.xmat[body_ids].reshape(-1, 3, 3)
            pos[nb:, k] = mjd.site_xpos[site_ids]
            rot[nb:, k] = mjd.site_xmat[site_ids].reshape(-1, 3, 3)
        return {name: (pos[i], rot[i]) for i, name in enumerate(self.names)}


def link_poses_base(
    model: RobotModel, joints_rad: Array, mjm: mujoco.MjModel | None = None
) -> dict[str, tuple[Array, Array]]:
    """URDF link name -> ``(pos_base_m (N, 3), rot_base_from_link (N, 3, 3))`` for each row
    of ``joints_rad`` (N, n), from the model's MuJoCo kinematics with the base at identity.
    ``mjm``: ``model`` compiled already (:func:`planner.mjcf.compile_model`), else compiled here.

    MuJoCo's ``base`` body is URDF's ``base_link``, its ``robot_origin`` site ``robot_base``,
    its ``hand`` site ``hand``; link bodies share their URDF names.
    """
    return _Kinematics(model, mjm).poses(joints_rad)


def _quat_xyzw(rot: Array) -> Array:
    """Scalar-last unit quaternions of (N, 3, 3) matrices, ``w >= 0`` (planner.frames)."""
    quat = np.asarray(Rotation.from_matrix(rot).as_quat(), dtype=np.float64).reshape(-1, 4)
    return np.where(quat[:, 3:4] < 0.0, -quat, quat)


def _json_str(text: str) -> str:
    """A JSON string literal safe inside a %-format template."""
    return json.dumps(text).replace("%", "%%")


_Fixed = list[tuple[str, str, Array, Array]]  # parent, child, offset, rotation


def _fixed_joints(urdf: str) -> _Fixed:
    """The ``fixed`` joints of a URDF: (parent, child, origin offset, origin rotation)."""
    fixed = []
    for joint in ET.fromstring(urdf).iter("joint"):
        parent_el, child_el = joint.find("parent"), joint.find("child")
        if joint.get("type") == "fixed" and parent_el is not None and child_el is not None:
            origin = joint.find("origin")
            xyz = "0 0 0" if origin is None else origin.get("xyz", "0 0 0")
            rpy = "0 0 0" if origin is None else origin.get("rpy", "0 0 0")
            offset = np.array([float(v) for v in xyz.split()])
            rot = Rotation.from_euler("xyz", [float(v) for v in rpy.split()]).as_matrix()
            fixed.append((str(parent_el.get("link")), str(child_el.get("link")), offset, rot))
    return fixed


def _add_fixed_links(fixed: _Fixed, poses: dict[str, tuple[Array, Array]]) -> None:
    """The poses of links the MuJoCo model does not have but which a ``fixed`` joint holds to
    one it has (the keep-out equipment drawn on the base, :func:`planner.urdf.urdf_xml`):
    the parent's pose composed with the joint's origin."""
    added = True
    while added:
        added = False
        for parent, child, offset, rot in fixed:
            if child in poses or parent not in poses:
                continue
            pos_p, rot_p = poses[parent]
            poses[child] = (pos_p + np.einsum("nij,j->ni", rot_p, offset), rot_p @ rot)
            added = True


class FrameTransformer:
    """``foxglove.FrameTransforms`` messages of one robot, batch after batch: the model is
    compiled and the URDF's tree read once (the live view calls it for every telemetry
    message; :func:`frame_transforms` for a whole recording)."""

    def __init__(self, model: RobotModel, urdf: str) -> None:
        self.model = model
        self.urdf = urdf
        self.tree = urdf_tree(urdf)
        roots = {p for p, _ in self.tree} - {c for _, c in self.tree}
        if roots != {"base_link"}:
            raise ValueError(f"URDF tree must be rooted at base_link, found roots {sorted(roots)}")
        self._kinematics = _Kinematics(model)
        self._fixed = _fixed_joints(urdf)
        self._template = "".join(
            [
                '{"transforms":[',
                ",".join(
                    '{"timestamp":{"sec":%d,"nsec":%d},'
                    f'"parent_frame_id":{_json_str(parent)},"child_frame_id":{_json_str(child)},'
                    '"translation":{"x":%r,"y":%r,"z":%r},'
                    '"rotation":{"x":%r,"y":%r,"z":%r,"w":%r}}'
                    for parent, child in [(ORBIT_FRAME, "base_link"), *self.tree]
                ),
                "]}",
            ]
        )

    def link_poses(self, joints_rad: Array) -> dict[str, tuple[Array, Array]]:
        """:func:`link_poses_base` of every URDF link (fixed ones too) at ``joints_rad``."""
        poses = self._kinematics.poses(joints_rad)
        _add_fixed_links(self._fixed, poses)
        return poses

    def __call__(
        self,
        generation_time_ns: NDArray[np.int64],
        quat_orbit_from_base_xyzw: Array,
        joints_rad: Array,
    ) -> list[bytes]:
        """One message (JSON, UTF-8) per row (see :func:`frame_transforms`)."""
        tree = self.tree
        poses = self.link_poses(joints_rad)
        unknown = sorted({name for edge in tree for name in edge} - set(poses))
        if unknown:
            raise ValueError(f"URDF links {unknown} have no pose in the MuJoCo model")
        n = len(generation_time_ns)
        # Columns per row: sec, nsec, then (x, y, z, qx, qy, qz, qw) per edge, base first.
        base = np.hstack([np.zeros((n, 3)), np.asarray(quat_orbit_from_base_xyzw, np.float64)])
        positions, rotations = [], []
        for parent, child in tree:
            pos_p, rot_p = poses[parent]
            pos_c, rot_c = poses[child]
            # child in parent: R_p^T (p_c - p_p), R_p^T R_c
            positions.append(np.einsum("nji,nj->ni", rot_p, pos_c - pos_p))
            rotations.append(np.einsum("nji,njk->nik", rot_p, rot_c))
        blocks = [base]
        if tree:  # every edge's quaternions in one call (scipy's overhead is per call)
            quats = _quat_xyzw(np.concatenate(rotations)).reshape(len(tree), n, 4)
            blocks += [np.hstack([p, q]) for p, q in zip(positions, quats, strict=True)]
        values = np.hstack(blocks).tolist()  # Python floats: %r is repr, exact in JSON
        sec, nsec = np.divmod(np.asarray(generation_time_ns, dtype=np.int64), 1_000_000_000)
        n_edges = len(tree) + 1
        out = []
        for s, ns, row in zip(sec.tolist(), nsec.tolist(), values, strict=True):
            args: list[Any] = []
            for e in range(n_edges):
                args += [s, ns, *row[7 * e : 7 * e + 7]]
            out.append((self._template % tuple(args)).encode())
        return out


def frame_transforms(
    model: RobotModel,
    urdf: str,
    generation_time_ns: NDArray[np.int64],
    quat_orbit_from_base_xyzw: Array,
    joints_rad: Array,
) -> list[bytes]:
    """One ``foxglove.FrameTransforms`` message (JSON, UTF-8) per row: ``orbit -> base_link``
    with the recorded attitude as is, then each joint of ``urdf`` (parent -> child) at the
    row's joint angles. Timestamps are the generation times (onboard clock). Every input must
    be finite and every time non-negative."""
    return FrameTransformer(model, urdf)(generation_time_ns, quat_orbit_from_base_xyzw, joints_rad)


#: Event kinds Foxglove's Log panel shows as errors and as warnings (the rest: INFO).
_ERROR_KINDS = frozenset({"vehicle_safed", "link_closed_malformed", "ground_stopped"})
_WARNING_KINDS = frozenset(
    {
        "alarm_raised",
        "auth_blocked",
        "command_ack_unknown",
        "commands_cancelled",
        "link_disconnected",
        "link_error_received",
        "link_error_replied",
        "link_takeover",
        "pass_control_refused",
        "pass_start_refused",
        "retransmit_requested",
        "schedule_delete_unverified",
        "vehicle_safe_exit_unverified",
    }
)


def event_level(kind: str, detail: Mapping[str, Any]) -> int:
    """The ``foxglove.LogLevel`` of an audit event: ERROR for a safing, a pass that ended
    aborted or safed, a link closed for malformed input and a ground stopped mid-pass;
    WARNING for refusals, losses and alarms; INFO otherwise."""
    state = detail.get("to") if kind == "pass_state" else None
    if kind in _ERROR_KINDS or state in ("aborted", "safed"):
        return LOG_LEVELS["ERROR"]
    if kind in _WARNING_KINDS or (kind == "command_stage" and detail.get("stage") == "rejected"):
        return LOG_LEVELS["WARNING"]
    return LOG_LEVELS["INFO"]


def event_log(time_ns: int, kind: str, actor: str, detail: Mapping[str, Any]) -> dict[str, Any]:
    """An audit event as a ``foxglove.Log`` message: its ground time, :func:`event_level`,
    ``"<kind>: <detail as JSON>"`` as the message and the actor as the name (Foxglove's Log
    panel filters by name). ``file`` and ``line`` say nothing here: empty and 0."""
    sec, nsec = divmod(int(time_ns), 1_000_000_000)
    text = json.dumps(dict(detail), separators=(", ", ": "), sort_keys=True, default=str)
    return {
        "timestamp": {"sec": sec, "nsec": nsec},
        "level": event_level(kind, detail),
        "message": f"{kind}: {text}",
        "name": actor,
        "file": "",
        "line": 0,
    }


SCENE_UPDATE_SCHEMA_NAME = "foxglove.SceneUpdate"
_VEC3: dict[str, Any] = {"type": "object", "properties": {k: {"type": "number"} for k in _XYZ}}
_QUAT: dict[str, Any] = {"type": "object", "properties": {k: {"type": "number"} for k in _XYZW}}
_COLOR: dict[str, Any] = {
    "type": "object",
    "properties": {k: {"type": "number"} for k in ("r", "g", "b", "a")},
}
_LISTS = ("arrows", "cubes", "spheres", "cylinders", "lines", "triangles", "texts", "models")
#: ``foxglove.SceneUpdate`` restated for what :func:`mesh_scene_update` writes (its entities'
#: other primitive lists are written empty).
SCENE_UPDATE_SCHEMA: dict[str, Any] = {
    "title": SCENE_UPDATE_SCHEMA_NAME,
    "description": "An update to the entities displayed in a 3D scene",
    "type": "object",
    "properties": {
        "deletions": {"type": "array", "items": {"type": "object"}},
        "entities": {
            "type": "array",
            "items": {
                "title": "foxglove.SceneEntity",
                "type": "object",
                "properties": {
                    "timestamp": _TIME,
                    "frame_id": {"type": "string"},
                    "id": {"type": "string"},
                    "lifetime": _TIME,
                    "frame_locked": {"type": "boolean"},
                    "metadata": {"type": "array", "items": {"type": "object"}},
                    **{k: {"type": "array", "items": {"type": "object"}} for k in _LISTS[:-1]},
                    "models": {
                        "type": "array",
                        "items": {
                            "title": "foxglove.ModelPrimitive",
                            "type": "object",
                            "properties": {
                                "pose": {
                                    "type": "object",
                                    "properties": {"position": _VEC3, "orientation": _QUAT},
                                },
                                "scale": _VEC3,
                                "color": _COLOR,
                                "override_color": {"type": "boolean"},
                                "url": {"type": "string"},
                                "media_type": {"type": "string"},
                                "data": {"type": "string", "contentEncoding": "base64"},
                            },
                        },
                    },
                },
            },
        },
    },
    "required": ["deletions", "entities"],
}


def mesh_scene_update(
    model: RobotModel, meshes: Sequence[tuple[MeshVisual, bytes]], time_ns: int
) -> dict[str, Any]:
    """One ``foxglove.SceneUpdate`` holding every mesh (its file's bytes given), each on its
    export link's frame at its zero-pose offset (see the module doc)."""
    stamp = {"sec": time_ns // 1_000_000_000, "nsec": time_ns % 1_000_000_000}
    entities = []
    for k, (mesh, data) in enumerate(meshes):
        frame, xyz, rot = mesh_link_pose(model, mesh)
        quat = _quat_xyzw(rot)[0]
        rgba = mesh.rgba or (0.8, 0.8, 0.85, 1.0)
        entity: dict[str, Any] = {
            "timestamp": stamp,
            "frame_id": frame,
            "id": f"mesh/{k}/{mesh.link}",
            "lifetime": {"sec": 0, "nsec": 0},
            "frame_locked": True,
            "metadata": [{"key": "uri", "value": mesh.uri}],
            **{name: [] for name in _LISTS},
        }
        entity["models"] = [
            {
                "pose": {
                    "position": dict(zip(_XYZ, (float(v) for v in xyz), strict=True)),
                    "orientation": dict(zip(_XYZW, (float(v) for v in quat), strict=True)),
                },
                "scale": dict(zip(_XYZ, mesh.scale, strict=True)),
                "color": dict(zip(("r", "g", "b", "a"), rgba, strict=True)),
                "override_color": mesh.rgba is not None,
                "url": "",
                "media_type": mesh_media_type(mesh.uri) or "application/octet-stream",
                "data": base64.b64encode(data).decode("ascii"),
            }
        ]
        entities.append(entity)
    return {"deletions": [], "entities": entities}
