"""A URDF tree reduced to the model's bodies: the free-floating base and one body per arm
joint, the way MuJoCo's compiler (``fusestatic``) and Pinocchio's reduced models do it.

- Every link belongs to the body of the nearest arm joint above it (the base when none):
  links on fixed joints, and tool branches (a gripper's fingers) on joints that are not arm
  joints, are **lumped** into that body with their exact mass, centre of mass and inertia
  (turned into the body's axes and moved to the body's CoM by the parallel-axis theorem).
- A tool joint (off the chain from the base to the hand: revolute, continuous or prismatic)
  is **locked** at a position: the description's ``[locked_joints]``, else the joint it
  mimics (``<mimic>``), else 0 clipped into its limits.
- An arm link whose name the model cannot take (the MuJoCo model's own bodies, the export's
  ``hand`` and ``robot_base``, or a name that is not letters, digits, ``_``, ``-``, ``.``) is
  **renamed** ``link<k>``.
- An optional mount (the description's ``[base]``): a uniform box of the given mass whose
  centre is the base reference, with the URDF's root at a given pose on it; the URDF's root
  and everything fixed to it are lumped into it.

Where a body has one massive link and no mount, its numbers pass through exactly as the URDF
gives them (no sums), so ETS-VII's file still loads to the last bit. docs/robots.md, "The
tree it reduces to".
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from planner.description.checks import NAME, WHEEL_NAMES
from planner.description.urdf_xml import Frame, Urdf

__all__ = [
    "ARM_JOINT_TYPES",
    "CONTINUOUS_LIMIT_RAD",
    "TOOL_JOINT_TYPES",
    "Body",
    "Mount",
    "Reduction",
    "box_inertia",
    "reduce_tree",
]

Array = NDArray[np.float64]

ARM_JOINT_TYPES = frozenset({"revolute", "continuous"})
TOOL_JOINT_TYPES = frozenset({"revolute", "continuous", "prismatic"})
#: Continuous joints get these limits (rad): a turn each way, so that check_joints has a range.
CONTINUOUS_LIMIT_RAD = 2.0 * math.pi
#: Names an arm link may not keep: the MuJoCo model's own bodies and the export's frames.
RESERVED_NAMES = frozenset({*WHEEL_NAMES, "base", "hand", "robot_base"})


@dataclass(frozen=True)
class Mount:
    """The description's ``[base]``: a uniform box carrying the URDF's root."""

    mass_kg: float
    size_m: tuple[float, float, float]
    rot_base_from_root: Array | None  # None: the same axes
    pos_base_from_root_m: Array  # the root's origin from the box's centre


@dataclass(frozen=True)
class Body:
    """One model body: mass, CoM and the inertia about it with its axes."""

    mass_kg: float
    com_m: Array
    inertia_kgm2: Array  # about the CoM, in the axes ``rot`` gives
    rot: Array | None  # the inertia's axes in the body's coordinates (None: the same)
    links: tuple[str, ...]  # the URDF links with mass in it


@dataclass(frozen=True)
class Reduction:
    """The tree reduced: the bodies, the arm joints, and what was lumped, locked, renamed."""

    base: Body  # base reference coordinates (the mount's centre, or the base link's frame)
    arm: tuple[Body, ...]  # robot coordinates: origin on joint 1, base axes, all-zero pose
    joint_names: tuple[str, ...]  # the arm joints' URDF names
    link_names: tuple[str, ...]  # the model's arm link names (after renaming)
    joint_pos_robot_m: tuple[Array, ...]
    joint_axis_robot: tuple[Array, ...]
    vendor_limit_rad: Array  # (n, 2)
    vendor_rate_radps: Array  # (n,)
    pos_j1_m: Array  # joint 1 in base reference coordinates
    hand_pos_robot_m: Array
    rot_robot_from_hand: Array | None  # None: parallel to the robot frame
    #: every link's frame at the all-zero pose, tool joints locked: base reference
    #: coordinates (the mount's centre, or the base link's frame)
    frames: Mapping[str, Frame]
    lumped: tuple[tuple[str, str], ...]  # (URDF link, the body it was lumped into)
    locked: tuple[tuple[str, str, float], ...]  # (joint, type, position: m or rad)
    renamed: tuple[tuple[str, str], ...]  # (URDF link, model name)
    owner: Mapping[str, int]  # link -> 0 (base) or the arm joint (1-based) that moves it


def box_inertia(mass_kg: float, size_m: tuple[float, float, float]) -> Array:
    """A uniform box's inertia about its centre, its own axes."""
    x, y, z = size_m
    return np.diag([y * y + z * z, x * x + z * z, x * x + y * y]) * (mass_kg / 12.0)


def _axis_angle(axis: Array, angle: float) -> Array:
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.asarray(np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k))


def _combine(parts: list[tuple[float, Array, Array]]) -> tuple[float, Array, Array]:
    """Masses, CoMs and inertias about them (common axes) summed: the parallel-axis theorem."""
    mass = math.fsum(m for m, _, _ in parts)
    com = sum((m * c for m, c, _ in parts), np.zeros(3)) / mass
    inertia = np.zeros((3, 3))
    for m, c, tensor in parts:
        d = c - com
        inertia += tensor + m * (float(d @ d) * np.eye(3) - np.outer(d, d))
    return mass, np.asarray(com), 0.5 * (inertia + inertia.T)


def _unit_axis(urdf: Urdf, joint: ET.Element, where: str) -> Array:
    elem = joint.find("axis")
    axis = urdf.floats(f"{where} <axis xyz>", None if elem is None else elem.get("xyz"), 3, "1 0 0")
    norm = float(np.linalg.norm(axis))
    if not 0.999 < norm < 1.001:
        raise urdf.c.fail(f"{where} <axis>", f"must be a unit vector, has length {norm:.6g}")
    return np.asarray(axis / norm)


def _tool_limits(urdf: Urdf, joint: ET.Element, where: str) -> tuple[float, float]:
    if joint.get("type") == "continuous":
        return -math.inf, math.inf
    limit = joint.find("limit")
    if limit is None:
        raise urdf.c.fail(where, "missing <limit> (a revolute or prismatic joint needs one)")
    lo = urdf.attr_float(limit, "lower", f"{where} <limit>")
    hi = urdf.attr_float(limit, "upper", f"{where} <limit>")
    if not lo <= hi:
        raise urdf.c.fail(f"{where} <limit>", f"lower {lo!r} must not be above upper {hi!r}")
    return lo, hi


def reduce_tree(
    urdf: Urdf,
    base_link: str,
    hand: str,
    locked: Mapping[str, float],
    mount: Mount | None,
) -> Reduction:
    """The checked tree (:meth:`Urdf.check_tree` done) reduced to its bodies; ``locked``: the
    description's tool-joint positions (m or rad, by the joint's type)."""
    c = urdf.c
    if hand not in urdf.links:
        raise c.fail(
            f"link {hand!r}",
            "missing: the hand frame (the description's hand, default 'hand') must be a link "
            f"of the URDF (links: {sorted(urdf.links)})",
        )
    chain: list[ET.Element] = []
    link = hand
    while link != base_link:
        joint = urdf.parent_joint[link]  # check_tree: every link but the base has one
        chain.append(joint)
        link = urdf.link_ref(joint, "parent")
    chain.reverse()
    chain_names = {j.get("name", "") for j in chain}
    arm = [j for j in chain if j.get("type") in ARM_JOINT_TYPES]
    for joint in chain:
        kind = joint.get("type", "")
        if kind not in ARM_JOINT_TYPES and kind != "fixed":
            raise c.fail(
                f"joint {joint.get('name')!r}",
                f"type {kind!r} cannot be flown: the joints from the base to the hand must be "
                "revolute or continuous (arm joints) or fixed",
            )
    arm_names = [j.get("name", "") for j in arm]
    for name in locked:
        if name in chain_names:
            raise c.fail(
                f"[locked_joints.{name}]",
                "is on the chain from the base to the hand: only tool joints off it are locked",
            )
        if name not in urdf.joints:
            raise c.fail(f"[locked_joints.{name}]", "names no joint of the URDF")

    # Tool joints: their positions (explicit, mimicked, or 0 clipped into the limits).
    positions: dict[str, float] = {}
    locked_out: list[tuple[str, str, float]] = []

    def position_of(name: str, seen: tuple[str, ...] = ()) -> float:
        if name in positions:
            return positions[name]
        joint = urdf.joints[name]
        where = f"joint {name!r}"
        kind = joint.get("type", "")
        lo, hi = _tool_limits(urdf, joint, where)
        mimic = joint.find("mimic")
        if name in locked:
            value = locked[name]
            if not lo - 1e-12 <= value <= hi + 1e-12:
                # in the unit the description writes: m, or deg for a turning joint
                scale, unit = (1.0, "m") if kind == "prismatic" else (180.0 / math.pi, "deg")
                raise c.fail(
                    f"[locked_joints.{name}]",
                    f"{value * scale:.6g} {unit} is outside the joint's limits "
                    f"[{lo * scale:.6g}, {hi * scale:.6g}] {unit}",
                )
        elif mimic is not None and mimic.get("joint") in urdf.joints and name not in seen:
            other = mimic.get("joint", "")
            if urdf.joints[other].get("type") not in TOOL_JOINT_TYPES or other in chain_names:
                raise c.fail(f"{where} <mimic>", f"mimics {other!r}, which is not a tool joint")
            factor = (
                urdf.attr_float(mimic, "multiplier", f"{where} <mimic>")
                if mimic.get("multiplier") is not None
                else 1.0
            )
            offset = (
                urdf.attr_float(mimic, "offset", f"{where} <mimic>")
                if mimic.get("offset") is not None
                else 0.0
            )
            value = min(max(factor * position_of(other, (*seen, name)) + offset, lo), hi)
        else:
            value = min(max(0.0, lo), hi)
        positions[name] = value
        locked_out.append((name, kind, value))
        return value

    # Every link's frame: base reference coordinates for the base's side of joint 1, robot
    # coordinates (origin on joint 1) beyond it, arm joints at zero, tool joints locked.
    if not arm:
        raise c.fail(f"link {hand!r}", f"no arm joint between {base_link!r} and the hand")
    first = arm[0]
    root = Frame(None, np.zeros(3))
    if mount is not None:
        root = Frame(mount.rot_base_from_root, mount.pos_base_from_root_m.copy())
    frames: dict[str, Frame] = {base_link: root}
    owner: dict[str, int] = {base_link: 0}
    pos_j1 = np.zeros(3)

    def frame_of(link: str) -> Frame:
        nonlocal pos_j1
        if link in frames:
            return frames[link]
        joint = urdf.parent_joint[link]
        name = joint.get("name", "")
        where = f"joint {name!r}"
        parent = urdf.link_ref(joint, "parent")
        frame = frame_of(parent).then(*urdf.origin(joint, where))
        kind = joint.get("type", "")
        if joint is first:
            pos_j1 = frame.pos
            frame = Frame(frame.rot, np.zeros(3))
        if name in arm_names:
            owner[link] = arm_names.index(name) + 1
        else:
            owner[link] = owner[parent]
            if kind in TOOL_JOINT_TYPES:
                axis = _unit_axis(urdf, joint, where)
                value = position_of(name)
                if kind == "prismatic":
                    frame = frame.then(None, axis * value)
                elif value != 0.0:
                    frame = frame.then(_axis_angle(axis, value), np.zeros(3))
            elif kind != "fixed":
                raise c.fail(
                    where,
                    f"type {kind!r} cannot be lumped or locked: a tool joint off the arm is "
                    "revolute, continuous or prismatic, the rest fixed",
                )
        frames[link] = frame
        return frame

    for link in [*(urdf.link_ref(j, "child") for j in chain), *urdf.links]:
        frame_of(link)
    # Bodies: the massive links of each, combined.
    groups: list[list[str]] = [[] for _ in range(len(arm) + 1)]
    for link in urdf.links:
        if urdf.inertial(link) is not None:
            groups[owner[link]].append(link)
    lumped: list[tuple[str, str]] = []

    def body(k: int, name: str) -> Body:
        parts: list[tuple[float, Array, Array, Array | None]] = []
        for link in groups[k]:
            inertial = urdf.inertial(link)
            assert inertial is not None
            placed = frames[link].then(*inertial.origin)
            parts.append((inertial.mass_kg, placed.pos, inertial.inertia_kgm2, placed.rot))
        if not parts and not (k == 0 and mount is not None):
            what = "the base" if k == 0 else f"arm link {name!r}"
            raise c.fail(
                f"link {name!r} <inertial>",
                f"missing: {what} has no mass (no link with an <inertial> of mass > 0 is "
                "fixed to it)",
            )
        if len(parts) == 1 and not (k == 0 and mount is not None):
            mass, com, tensor, rot = parts[0]  # passed through unrounded
            return Body(mass, com, tensor, rot, tuple(groups[k]))
        turned = [(m, com, Frame(rot, com).rotate_tensor(t)) for m, com, t, rot in parts]
        if k == 0 and mount is not None:
            turned.append((mount.mass_kg, np.zeros(3), box_inertia(mount.mass_kg, mount.size_m)))
        if k == 0 and mount is not None:
            lumped.extend((link, "[base]") for link in groups[k])
        else:
            lumped.extend((link, name) for link in groups[k] if link != name)
        mass, com, tensor = _combine(turned)
        return Body(mass, com, tensor, None, tuple(groups[k]))

    # Arm joints, their links' names, limits.
    names: list[str] = []
    renamed: list[tuple[str, str]] = []
    taken = set(urdf.links)
    joint_pos: list[Array] = []
    joint_axis: list[Array] = []
    limits: list[tuple[float, float]] = []
    rates: list[float] = []
    for k, joint in enumerate(arm):
        name = joint.get("name", "")
        where = f"joint {name!r}"
        child = urdf.link_ref(joint, "child")
        model_name = child
        if child in RESERVED_NAMES or not NAME.match(child):
            model_name = f"link{k + 1}"
            while model_name in taken and model_name != child:
                model_name += "_"
            renamed.append((child, model_name))
            taken.add(model_name)
        names.append(model_name)
        frame = frames[child]
        joint_pos.append(frame.pos)
        joint_axis.append(frame.apply(_unit_axis(urdf, joint, where)))
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
        limits.append((lo, hi))
        rates.append(velocity)

    base_body = body(0, base_link)
    arm_bodies = tuple(body(k + 1, urdf.link_ref(j, "child")) for k, j in enumerate(arm))
    hand_frame = frames[hand]
    hand_rot = hand_frame.rot
    if hand_rot is not None and np.allclose(hand_rot, np.eye(3), rtol=0.0, atol=1e-12):
        hand_rot = None
    return Reduction(
        base=base_body,
        arm=arm_bodies,
        joint_names=tuple(arm_names),
        link_names=tuple(names),
        joint_pos_robot_m=tuple(joint_pos),
        joint_axis_robot=tuple(joint_axis),
        vendor_limit_rad=np.array(limits),
        vendor_rate_radps=np.array(rates),
        pos_j1_m=pos_j1,
        hand_pos_robot_m=hand_frame.pos,
        rot_robot_from_hand=hand_rot,
        frames={
            link: frame if owner[link] == 0 else Frame(frame.rot, frame.pos + pos_j1)
            for link, frame in frames.items()
        },
        lumped=tuple(lumped),
        locked=tuple(sorted(locked_out)),
        renamed=tuple(renamed),
        owner=owner,
    )
