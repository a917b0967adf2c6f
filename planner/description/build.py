"""The pure build: a parsed, checked URDF and the wheels into a RobotModel, and a parsed
description (TOML document and URDF) into a RobotDescription. No file is read here.

The URDF is read into :class:`~planner.model.RobotModel`'s frames (``planner/model.py``):

- the *base frame* has the base link's axes and its origin at the base link's centre of mass
  (the ``<inertial>`` origin); the base inertia is turned into those axes;
- the *robot frame* has the base frame's axes and its origin on the first arm joint;
- everything else (joint points and axes, link CoMs and inertias, the hand point) is expressed
  in the robot frame at the all-zero pose, whatever rotations the URDF's origins carry;
- the hand frame must be parallel to the base frame at the all-zero pose (the planners and
  the MuJoCo model take it so).

Where the URDF's origins carry no rotation (ETS-VII's file) the numbers pass through without
a single rounding: sums of the origins' offsets only, so the model loaded from
``examples/robots/ets7`` equals :func:`planner.model.default_model` to the last bit.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.description.checks import NAME, WHEEL_NAMES, Checker, InvalidRobotDescription, frozen
from planner.description.collision_xml import collision_model_from, flight_rules_from
from planner.description.hashing import content_sha256
from planner.description.tables import (
    Header,
    experiments_from,
    limits_from,
    poses_from,
    sensor_noise_from,
    servo_from,
)
from planner.description.urdf_xml import Frame, Urdf
from planner.dynamics import DynamicsWorkspace
from planner.errors import InvalidInput
from planner.model import LinkSpec, RobotModel, WheelSpec, base_body_inertial
from planner.robot import RobotDescription

__all__ = [
    "CONTINUOUS_LIMIT_RAD",
    "MIN_ARM_JOINTS",
    "arm_chain",
    "build_robot",
    "model_from_urdf",
]

#: A reaction null space (n - 3 dimensions) needs at least 4 arm joints.
MIN_ARM_JOINTS = 4
#: Continuous joints get these limits (rad): a turn each way, so that check_joints has a range.
CONTINUOUS_LIMIT_RAD = 2.0 * math.pi
_ARM_JOINT_TYPES = frozenset({"revolute", "continuous"})
_HAND = "hand"

Array = NDArray[np.float64]


def arm_chain(urdf: Urdf, base_link: str) -> list[ET.Element]:
    """The joints from the base link to the hand, in order."""
    c = urdf.c
    if _HAND not in urdf.links:
        raise c.fail(f"link {_HAND!r}", "missing: the hand frame must be a link named 'hand'")
    chain: list[ET.Element] = []
    link = _HAND
    while link != base_link:
        joint = urdf.parent_joint[link]  # check_tree: every link but the base has one
        chain.append(joint)
        link = urdf.link_ref(joint, "parent")
    chain.reverse()
    on_chain = {base_link, *(urdf.link_ref(j, "child") for j in chain)}
    for name in urdf.links:
        if name in on_chain:
            continue
        joint = urdf.parent_joint[name]
        if joint.get("type") != "fixed" or urdf.inertial(name) is not None:
            raise c.fail(
                f"link {name!r}",
                "is off the chain from the base to the hand: only massless frames on fixed "
                "joints may branch off (a serial arm)",
            )
    return chain


def model_from_urdf(urdf: Urdf, base_link: str, wheels: tuple[WheelSpec, ...]) -> RobotModel:
    c = urdf.c
    chain = arm_chain(urdf, base_link)
    kinds = []
    for joint in chain:
        kind = joint.get("type", "")
        name = joint.get("name")
        if kind not in _ARM_JOINT_TYPES and kind != "fixed":
            raise c.fail(
                f"joint {name!r}",
                f"type {kind!r} cannot be flown: arm joints must be revolute or continuous, "
                "the base and hand attached by fixed joints",
            )
        kinds.append(kind)
    movable = [i for i, k in enumerate(kinds) if k != "fixed"]
    if len(movable) < MIN_ARM_JOINTS:
        raise c.fail(
            f"link {_HAND!r}",
            f"the chain from {base_link!r} has {len(movable)} arm joint(s); at least "
            f"{MIN_ARM_JOINTS} are needed for a reaction null space (n - 3 > 0)",
        )
    first, last = movable[0], movable[-1]
    for i in range(first, last + 1):
        if kinds[i] == "fixed":
            raise c.fail(
                f"joint {chain[i].get('name')!r}",
                "a fixed joint between arm joints is not supported: merge the two links",
            )
    for i in [*range(first), *range(last + 1, len(chain))]:
        child = urdf.link_ref(chain[i], "child")
        if urdf.inertial(child) is not None:
            raise c.fail(
                f"link {child!r}",
                "has mass but is not moved by an arm joint: only massless frames may sit "
                "between the base and joint 1 or beyond the last joint",
            )

    base = urdf.inertial(base_link)
    if base is None:
        raise c.fail(f"link {base_link!r} <inertial>", "missing: the base needs mass and inertia")
    base_rot, base_com = base.origin
    base_inertia = Frame(base_rot, np.zeros(3)).rotate_tensor(base.inertia_kgm2)

    # Base link frame -> the first arm joint's frame.
    frame = Frame(None, np.zeros(3))
    for joint in chain[:first]:
        frame = frame.then(*urdf.origin(joint, f"joint {joint.get('name')!r}"))
    j1_rot, j1_pos = urdf.origin(chain[first], f"joint {chain[first].get('name')!r}")
    frame = frame.then(j1_rot, j1_pos)
    pos_base_from_robot = frame.pos - base_com
    # From here on positions are relative to the robot origin (joint 1), base axes.
    frame = Frame(frame.rot, np.zeros(3))

    links: list[LinkSpec] = []
    limits: list[tuple[float, float]] = []
    rates: list[float] = []
    for k, i in enumerate(movable):
        joint = chain[i]
        name = joint.get("name")
        where = f"joint {name!r}"
        if k > 0:
            frame = frame.then(*urdf.origin(joint, where))
        axis_elem = joint.find("axis")
        axis_local = urdf.floats(
            f"{where} <axis xyz>", None if axis_elem is None else axis_elem.get("xyz"), 3, "1 0 0"
        )
        norm = float(np.linalg.norm(axis_local))
        if not 0.999 < norm < 1.001:
            raise c.fail(f"{where} <axis>", f"must be a unit vector, has length {norm:.6g}")
        axis = frame.apply(axis_local / norm)
        limit = joint.find("limit")
        if limit is None:
            raise c.fail(where, "missing <limit> (the planners need a rate limit)")
        velocity = urdf.attr_float(limit, "velocity", f"{where} <limit>")
        if velocity <= 0.0:
            raise c.fail(f"{where} <limit>", f"velocity must be > 0 rad/s, got {velocity!r}")
        if joint.get("type") == "continuous":
            lo, hi = -CONTINUOUS_LIMIT_RAD, CONTINUOUS_LIMIT_RAD
        else:
            lo = urdf.attr_float(limit, "lower", f"{where} <limit>")
            hi = urdf.attr_float(limit, "upper", f"{where} <limit>")
            if not lo < hi:
                raise c.fail(f"{where} <limit>", f"lower {lo!r} must be below upper {hi!r}")
            if not lo <= 0.0 <= hi:
                raise c.fail(
                    f"{where} <limit>",
                    f"[{lo!r}, {hi!r}] must contain 0 (the all-zero pose is the model's reference)",
                )
        child = urdf.link_ref(joint, "child")
        if not NAME.match(child):
            raise c.fail(
                f"link {child!r}", "an arm link's name is letters, digits, '_', '-' or '.'"
            )
        inertial = urdf.inertial(child)
        if inertial is None:
            raise c.fail(
                f"link {child!r} <inertial>", "missing: every arm link needs mass and inertia"
            )
        in_rot, in_pos = inertial.origin
        inertia_frame = frame.then(in_rot, in_pos)
        links.append(
            LinkSpec(
                name=child,
                joint_pos_robot_m=frozen(frame.pos),
                joint_axis_robot=frozen(axis),
                mass_kg=inertial.mass_kg,
                com_robot_m=frozen(inertia_frame.pos),
                inertia_com_inertia_frame_kgm2=frozen(inertial.inertia_kgm2),
                rot_robot_from_inertia=frozen(inertia_frame.rot_matrix),
            )
        )
        limits.append((lo, hi))
        rates.append(velocity)

    for joint in chain[last + 1 :]:
        frame = frame.then(*urdf.origin(joint, f"joint {joint.get('name')!r}"))
    if frame.rot is not None and not np.allclose(frame.rot, np.eye(3), rtol=0.0, atol=1e-12):
        raise c.fail(
            f"link {_HAND!r}",
            "at the all-zero pose the hand frame must be parallel to the base frame "
            "(the planners take it so); move the rotation into a frame beyond the hand",
        )
    names = [spec.name for spec in links]
    reserved = {*WHEEL_NAMES, "base"}  # the MuJoCo model's own bodies
    if reserved & set(names):
        raise c.fail(
            f"link {sorted(reserved & set(names))[0]!r}",
            f"arm links may not be called {sorted(reserved)} (the MuJoCo model's own bodies)",
        )
    return RobotModel(
        base_mass_kg=base.mass_kg,
        base_inertia_kgm2=frozen(base_inertia),
        pos_base_from_robot_m=frozen(pos_base_from_robot),
        links=tuple(links),
        hand_pos_robot_m=frozen(frame.pos),
        wheels=wheels,
        joint_limit_rad=frozen(np.array(limits)),
        joint_rate_limit_radps=frozen(np.array(rates)),
    )


def build_robot(
    c: Checker,
    doc: Mapping[str, Any],
    head: Header,
    urdf: Urdf,
    meshes: Mapping[str, Array] | None = None,
) -> RobotDescription:
    """The description from its parsed TOML document (``head`` already checked) and its
    parsed URDF (``meshes``: the points of every mesh its ``<collision>`` names, read); ``c``
    names the TOML file and ``head.urdf_path`` the URDF in messages. Reads no file:
    :func:`planner.description.load_robot` has read them."""
    urdf_path = head.urdf_path
    urdf.check_tree(head.base_link)
    model = model_from_urdf(urdf, head.base_link, head.wheels)
    chain = arm_chain(urdf, head.base_link)
    arm_joints = [j.get("name", "") for j in chain if j.get("type") in _ARM_JOINT_TYPES]
    first = next(j for j in chain if j.get("type") in _ARM_JOINT_TYPES)
    rules, allowed = flight_rules_from(c, doc.get("flight_rules", {}))
    collision = collision_model_from(
        urdf,
        head.base_link,
        arm_joints,
        urdf.link_ref(first, "child"),
        allowed,
        meshes or {},
        c,
    )

    rotor_mass, rotor_free_inertia = base_body_inertial(model)
    if rotor_mass <= 0.0 or float(np.linalg.eigvalsh(rotor_free_inertia)[0]) <= 0.0:
        raise c.fail(
            "[[wheels]]",
            "the rotors (mass, thin-disc inertia) must fit inside the base link's mass and "
            "inertia: the base less its rotors is not a positive mass with positive definite "
            "inertia",
        )
    try:
        ws = DynamicsWorkspace(model)
    except (ValueError, RuntimeError) as exc:  # MuJoCo's compiler refuses it
        raise InvalidRobotDescription(urdf_path, "model", f"MuJoCo refuses it: {exc}") from None

    acs = c.table("[acs]", doc.get("acs", {}))
    for key in ("torque_limit_nm", "momentum_limit_nms"):
        if key in acs:
            raise c.fail(f"[acs] {key}", "set the wheels' limits on each [[wheels]] entry")
    description = RobotDescription(
        name=head.name,
        description=c.text("description", doc.get("description", "")),
        path=c.path,
        urdf_path=urdf_path,
        content_sha256=content_sha256(doc, urdf.root),
        base_link=head.base_link,
        model=model,
        wheel_limits=head.wheel_limits,
        acs_config=MappingProxyType(dict(acs)),
        servo=servo_from(c, doc.get("servo", {}), model.n_joints),
        sensor_noise=sensor_noise_from(c, doc.get("sensor_noise", {})),
        poses=MappingProxyType(poses_from(c, doc.get("poses", {}), ws)),
        experiments=MappingProxyType(
            experiments_from(c, doc.get("experiments", {}), model.n_joints)
        ),
        base_box_size_m=urdf.box_size(head.base_link),
        collision=collision,
        flight_rules=rules,
        limits=limits_from(c, doc.get("limits", {})),
    )
    try:
        description.acs_gains(ws)
    except InvalidInput as exc:
        raise c.fail("[acs]", str(exc)) from None
    return description
