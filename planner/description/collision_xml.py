"""A URDF's ``<collision>`` shapes and a description's ``[flight_rules]``, checked into
:class:`planner.collision.CollisionModel` and :class:`planner.flight_rules.FlightRules`.

Works on the parsed URDF and TOML; a mesh's points come in already read
(:func:`planner.description.files.read_mesh_points`): a mesh is taken as its convex hull.
Every shape is placed at the all-zero pose in the robot frame (origin at the first arm
joint, base axes), and its body is tied to the arm joint that moves it (0: the base).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from planner.collision import AllowedContact, CollisionBody, CollisionModel, CollisionShape
from planner.description.checks import Checker, frozen
from planner.description.urdf_xml import Frame, Urdf
from planner.errors import InvalidInput
from planner.flight_rules import FlightRules
from planner.meshes import MeshVisual

__all__ = [
    "collision_model_from",
    "flight_rules_from",
    "mesh_filenames",
    "visual_meshes_from",
]

Array = NDArray[np.float64]

_RULE_KEYS = frozenset(
    {
        "min_clearance_m",
        "max_attitude_excursion_deg",
        "max_wheel_momentum_fraction",
        "joint_limit_margin_deg",
        "max_hand_speed_mps",
        "pass_window_s",
        "allowed_contact",
        "generated_allowed_contact",
    }
)
_CONTACT_KEYS = frozenset({"bodies", "reason"})
_MODES = ("feedback", "free_drift")


def mesh_filenames(urdf: Urdf, element: str = "collision") -> list[str]:
    """Every mesh file a ``<collision>`` (or ``<visual>``) names, in order of appearance."""
    out: list[str] = []
    for elem in urdf.root.iter(element):
        mesh = elem.find("geometry/mesh")
        if mesh is not None:
            name = mesh.get("filename")
            if not name:
                raise urdf.c.fail(f"<{element}> <mesh>", "missing filename")
            if name not in out:
                out.append(name)
    return out


def _zero_pose_frames(urdf: Urdf, base_link: str) -> dict[str, Frame]:
    """Every link's frame at the all-zero pose, in the base link's frame."""
    frames: dict[str, Frame] = {base_link: Frame(None, np.zeros(3))}

    def frame_of(link: str) -> Frame:
        if link in frames:
            return frames[link]
        joint = urdf.parent_joint[link]
        parent = urdf.link_ref(joint, "parent")
        frame = frame_of(parent).then(*urdf.origin(joint, f"joint {joint.get('name')!r}"))
        frames[link] = frame
        return frame

    for link in urdf.links:
        frame_of(link)
    return frames


def _moving_joint(urdf: Urdf, link: str, arm_joints: Sequence[str]) -> int:
    """The arm joint (1-based) that moves ``link``: its nearest movable ancestor, 0 for the
    base and what is fixed on it."""
    while True:
        joint = urdf.parent_joint.get(link)
        if joint is None:
            return 0
        name = joint.get("name", "")
        if name in arm_joints:
            return list(arm_joints).index(name) + 1
        link = urdf.link_ref(joint, "parent")


def _shape(
    urdf: Urdf,
    elem: ET.Element,
    where: str,
    frame: Frame,
    robot_origin: Array,
    meshes: Mapping[str, Array],
) -> CollisionShape:
    c = urdf.c
    geometry = elem.find("geometry")
    if geometry is None or len(geometry) != 1:
        raise c.fail(where, "needs one <geometry> with one shape")
    g = geometry[0]
    rot, pos = urdf.origin(elem, where)
    placed = frame.then(rot, pos)
    vertices = None

    def positive(key: str) -> float:
        value = urdf.attr_float(g, key, f"{where} <{g.tag}>")
        if not value > 0.0:
            raise c.fail(f"{where} <{g.tag} {key}>", f"must be > 0, got {value!r}")
        return value

    if g.tag == "box":
        size = urdf.floats(f"{where} <box size>", g.get("size"), 3, "")
        if np.any(size <= 0.0):
            raise c.fail(
                f"{where} <box size>", f"must be 3 positive numbers, got {g.get('size')!r}"
            )
        kind, dims = "box", tuple(float(v) for v in size)
    elif g.tag == "sphere":
        kind, dims = "sphere", (positive("radius"),)
    elif g.tag in ("cylinder", "capsule"):
        kind, dims = g.tag, (positive("radius"), positive("length"))
    elif g.tag == "mesh":
        name = g.get("filename", "")
        scale = urdf.floats(f"{where} <mesh scale>", g.get("scale"), 3, "1 1 1")
        points = meshes.get(name)
        if points is None:
            raise c.fail(f"{where} <mesh>", f"the mesh {name!r} was not read")
        kind, dims, vertices = "convex", (), frozen(np.asarray(points) * scale)
    else:
        raise c.fail(
            f"{where} <{g.tag}>",
            "not a collision shape: box, cylinder, capsule, sphere or mesh (its convex hull)",
        )
    try:
        return CollisionShape(
            kind=kind,
            dims=dims,
            rot_robot_from_shape=frozen(placed.rot_matrix),
            pos_robot_m=frozen(placed.pos - robot_origin),
            vertices_m=vertices,
        )
    except InvalidInput as exc:
        raise c.fail(where, str(exc)) from None


def collision_model_from(
    urdf: Urdf,
    base_link: str,
    arm_joints: Sequence[str],
    first_link: str,
    allowed: Sequence[AllowedContact],
    meshes: Mapping[str, Array],
    toml: Checker,
    *,
    frames: Mapping[str, Frame] | None = None,
    mount_box: tuple[tuple[float, float, float], Array] | None = None,
) -> CollisionModel | None:
    """The URDF's collision bodies (None when it has no ``<collision>`` at all: the rules
    step refuses such a robot, :func:`planner.collision.check_collision_model`). ``frames``:
    every link's frame at the reference, tool joints locked (default: the all-zero pose, in
    the base link's frame). ``mount_box``: the ``[base]`` cube (size, centre in the robot
    frame), a box of the base link's body (the spacecraft the arm must keep clear of)."""
    frames = _zero_pose_frames(urdf, base_link) if frames is None else frames
    robot_origin = frames[first_link].pos  # joint 1's position: its child link's origin
    bodies = []
    for name, link in urdf.links.items():
        elems = link.findall("collision")
        if not elems:
            continue
        shapes = tuple(
            _shape(
                urdf,
                elem,
                f"link {name!r} <collision {elem.get('name', '')}>".replace(" >", ">"),
                frames[name],
                robot_origin,
                meshes,
            )
            for elem in elems
        )
        bodies.append(CollisionBody(name, _moving_joint(urdf, name, arm_joints), shapes))
    if bodies and mount_box is not None:
        size, centre = mount_box
        box = CollisionShape("box", size, frozen(np.eye(3)), frozen(centre))
        names = [b.name for b in bodies]
        if base_link in names:
            k = names.index(base_link)
            bodies[k] = CollisionBody(base_link, 0, (*bodies[k].shapes, box))
        else:
            bodies.insert(0, CollisionBody(base_link, 0, (box,)))
    if not bodies:
        if allowed:
            raise toml.fail(
                "[[flight_rules.allowed_contact]]", "names bodies, but the URDF has no <collision>"
            )
        return None
    try:
        return CollisionModel(tuple(bodies), tuple(allowed))
    except InvalidInput as exc:
        raise toml.fail("[[flight_rules.allowed_contact]]", str(exc)) from None


def visual_meshes_from(
    urdf: Urdf,
    base_link: str,
    arm_joints: Sequence[str],
    first_link: str,
    keys: Mapping[str, str],
    *,
    frames: Mapping[str, Frame] | None = None,
) -> tuple[MeshVisual, ...]:
    """Every ``<visual>`` mesh whose file was found (``keys``: its filename -> served key),
    placed at the all-zero pose in the robot frame like the collision shapes."""
    frames = _zero_pose_frames(urdf, base_link) if frames is None else frames
    robot_origin = frames[first_link].pos
    out = []
    for name, link in urdf.links.items():
        if name not in frames:  # not on the tree the model was built from
            continue
        for elem in link.findall("visual"):
            mesh = elem.find("geometry/mesh")
            filename = "" if mesh is None else mesh.get("filename", "")
            if mesh is None or filename not in keys:
                continue
            where = f"link {name!r} <visual>"
            rot, pos = urdf.origin(elem, where)
            placed = frames[name].then(rot, pos)
            scale = urdf.floats(f"{where} <mesh scale>", mesh.get("scale"), 3, "1 1 1")
            color = elem.find("material/color")
            rgba = None
            if color is not None and color.get("rgba"):
                values = urdf.floats(f"{where} <color rgba>", color.get("rgba"), 4, "")
                rgba = (float(values[0]), float(values[1]), float(values[2]), float(values[3]))
            out.append(
                MeshVisual(
                    link=name,
                    joint=_moving_joint(urdf, name, arm_joints),
                    uri=filename,
                    key=keys[filename],
                    rot_robot_from_mesh=frozen(placed.rot_matrix),
                    pos_robot_m=frozen(placed.pos - robot_origin),
                    scale=(float(scale[0]), float(scale[1]), float(scale[2])),
                    rgba=rgba,
                )
            )
    return tuple(out)


def flight_rules_from(c: Checker, value: object) -> tuple[FlightRules, tuple[AllowedContact, ...]]:
    """``[flight_rules]`` (SPEC 8's numbers where a key is left out) and its allowed
    contacts."""
    table = c.table("[flight_rules]", value)
    c.keys("[flight_rules]", table, _RULE_KEYS)
    kwargs: dict[str, object] = {}
    for key in (
        "min_clearance_m",
        "max_wheel_momentum_fraction",
        "max_hand_speed_mps",
        "pass_window_s",
    ):
        if key in table:
            kwargs[key] = c.number(f"[flight_rules] {key}", table[key], positive=True)
    if "joint_limit_margin_deg" in table:
        kwargs["joint_limit_margin_deg"] = c.non_negative(
            "[flight_rules] joint_limit_margin_deg", table["joint_limit_margin_deg"]
        )
    if "max_attitude_excursion_deg" in table:
        raw = table["max_attitude_excursion_deg"]
        where = "[flight_rules] max_attitude_excursion_deg"
        if isinstance(raw, Mapping):
            c.keys(where, raw, frozenset(_MODES))
            missing = [m for m in _MODES if m not in raw]
            if missing:
                raise c.fail(
                    where, f"give a limit for every mode {list(_MODES)}; missing {missing}"
                )
            kwargs["max_attitude_excursion_deg"] = {
                m: c.number(f"{where}.{m}", raw[m], positive=True) for m in _MODES
            }
        else:
            limit = c.number(where, raw, positive=True)
            kwargs["max_attitude_excursion_deg"] = dict.fromkeys(_MODES, limit)
    contacts = []
    raw_contacts = table.get("allowed_contact", [])
    if not isinstance(raw_contacts, list):
        raise c.fail("[[flight_rules.allowed_contact]]", "must be an array of tables")
    for i, entry in enumerate(raw_contacts):
        where = f"[[flight_rules.allowed_contact]] #{i + 1}"
        entry = c.table(where, entry)
        c.keys(where, entry, _CONTACT_KEYS)
        bodies = entry.get("bodies")
        if (
            not isinstance(bodies, list)
            or len(bodies) != 2
            or not all(isinstance(b, str) and b for b in bodies)
            or bodies[0] == bodies[1]
        ):
            raise c.fail(f"{where} bodies", f"must be two different link names, got {bodies!r}")
        contacts.append(
            AllowedContact(
                (bodies[0], bodies[1]), c.text(f"{where} reason", entry.get("reason", ""))
            )
        )
    try:
        rules = FlightRules(**kwargs)  # type: ignore[arg-type]
    except InvalidInput as exc:
        raise c.fail("[flight_rules]", str(exc)) from None
    if not all(math.isfinite(v) for v in rules.max_attitude_excursion_deg.values()):
        raise c.fail("[flight_rules] max_attitude_excursion_deg", "must be finite")
    return rules, tuple(contacts)
