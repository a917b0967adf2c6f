"""A URDF document parsed and checked as a tree (links, joints, inertials, origins).

Works on the file's bytes (``planner.description.files`` reads them); DTDs and entity
declarations are refused before parsing. :mod:`planner.description.build` turns the tree
into a :class:`~planner.model.RobotModel`.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from planner.description.checks import Checker

__all__ = ["Frame", "Inertial", "Urdf", "rpy_matrix"]

Array = NDArray[np.float64]


def rpy_matrix(rpy: Array) -> Array:
    """URDF's fixed-axis roll, pitch, yaw: ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    cr, sr = math.cos(rpy[0]), math.sin(rpy[0])
    cp, sp = math.cos(rpy[1]), math.sin(rpy[1])
    cy, sy = math.cos(rpy[2]), math.sin(rpy[2])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return np.asarray(rz @ ry @ rx)


class Frame:
    """A rotation and a position; the exact identity rotation is carried without arithmetic
    so that frames without rotations pass numbers through unrounded."""

    def __init__(self, rot: Array | None, pos: Array) -> None:
        self.rot = rot  # None: exactly the identity
        self.pos = pos

    def apply(self, v: Array) -> Array:
        """A direction of the child frame in the parent's axes."""
        return v.copy() if self.rot is None else np.asarray(self.rot @ v)

    def then(self, rot: Array | None, pos: Array) -> Frame:
        """This frame followed by a child origin ``(rot, pos)`` given in this frame."""
        new_pos = self.pos + self.apply(pos)
        if rot is None:
            return Frame(self.rot, new_pos)
        return Frame(rot if self.rot is None else np.asarray(self.rot @ rot), new_pos)

    def rotate_tensor(self, tensor: Array) -> Array:
        return tensor.copy() if self.rot is None else np.asarray(self.rot @ tensor @ self.rot.T)

    @property
    def rot_matrix(self) -> Array:
        return np.eye(3) if self.rot is None else self.rot


# --- the URDF -----------------------------------------------------------------------------


@dataclass
class Inertial:
    mass_kg: float
    origin: tuple[Array | None, Array]  # rotation (None: identity), position in the link
    inertia_kgm2: Array  # in the inertial frame


class Urdf:
    def __init__(self, path: Path, data: bytes) -> None:
        self.c = Checker(path)
        if b"<!DOCTYPE" in data or b"<!ENTITY" in data:
            raise self.c.fail("document", "DTDs and entity declarations are refused")
        try:
            self.text = data.decode("utf-8")
        except UnicodeDecodeError:
            raise self.c.fail("document", "not UTF-8 text") from None
        try:
            root = ET.fromstring(data)
        except ET.ParseError as exc:
            raise self.c.fail("document", f"not well-formed XML: {exc}") from None
        if root.tag != "robot":
            raise self.c.fail(f"<{root.tag}>", "the root element must be <robot>")
        self.root = root
        self.links: dict[str, ET.Element] = {}
        for elem in root.findall("link"):
            name = elem.get("name")
            if not name:
                raise self.c.fail("<link>", "a link without a name")
            if name in self.links:
                raise self.c.fail(f"link {name!r}", "defined twice")
            self.links[name] = elem
        self.joints: dict[str, ET.Element] = {}
        self.parent_joint: dict[str, ET.Element] = {}
        for elem in root.findall("joint"):
            name = elem.get("name")
            if not name:
                raise self.c.fail("<joint>", "a joint without a name")
            if name in self.joints:
                raise self.c.fail(f"joint {name!r}", "defined twice")
            self.joints[name] = elem
            parent, child = self.link_ref(elem, "parent"), self.link_ref(elem, "child")
            if child in self.parent_joint:
                other = self.parent_joint[child].get("name")
                raise self.c.fail(
                    f"link {child!r}",
                    f"has two parents (joints {other!r} and {name!r}): a URDF is a tree",
                )
            if parent == child:
                raise self.c.fail(f"joint {name!r}", f"joins link {parent!r} to itself (a loop)")
            self.parent_joint[child] = elem

    def link_ref(self, joint: ET.Element, which: str) -> str:
        elem = joint.find(which)
        name = None if elem is None else elem.get("link")
        where = f"joint {joint.get('name')!r} <{which}>"
        if not name:
            raise self.c.fail(where, "missing (or without a link attribute)")
        if name not in self.links:
            raise self.c.fail(where, f"names the unknown link {name!r}")
        return name

    def parent_of(self, link: str) -> str | None:
        joint = self.parent_joint.get(link)
        return None if joint is None else self.link_ref(joint, "parent")

    def check_tree(self, base_link: str) -> None:
        rooted: set[str] = set()  # links whose parent chain is known to end at a root
        for start in self.links:
            seen = [start]
            on_path = {start}
            link: str | None = self.parent_of(start)
            while link is not None and link not in rooted:
                if link in on_path:
                    cycle = " -> ".join([*seen[seen.index(link) :], link])
                    raise self.c.fail(f"link {link!r}", f"is in a loop of joints: {cycle}")
                seen.append(link)
                on_path.add(link)
                link = self.parent_of(link)
            rooted.update(seen)
        if base_link not in self.links:
            raise self.c.fail(
                f"link {base_link!r}",
                f"the description's base_link is not in the URDF (links: {sorted(self.links)})",
            )
        if base_link in self.parent_joint:
            raise self.c.fail(
                f"link {base_link!r}",
                f"is the child of joint {self.parent_joint[base_link].get('name')!r}: the "
                "free-floating base must be the URDF's root",
            )
        roots = sorted(n for n in self.links if n not in self.parent_joint and n != base_link)
        if roots:
            raise self.c.fail(
                f"link {roots[0]!r}",
                f"not connected to the base link {base_link!r} (the tree is disconnected; "
                f"other roots: {roots})",
            )

    def floats(self, element: str, text: str | None, count: int, default: str) -> Array:
        raw = default if text is None else text
        try:
            values = [float(x) for x in raw.split()]
        except ValueError:
            raise self.c.fail(element, f"not {count} numbers: {raw!r}") from None
        if len(values) != count or not all(math.isfinite(v) for v in values):
            raise self.c.fail(element, f"not {count} finite numbers: {raw!r}")
        return np.array(values)

    def origin(self, elem: ET.Element, where: str) -> tuple[Array | None, Array]:
        origin = elem.find("origin")
        if origin is None:
            return None, np.zeros(3)
        xyz = self.floats(f"{where} <origin xyz>", origin.get("xyz"), 3, "0 0 0")
        rpy = self.floats(f"{where} <origin rpy>", origin.get("rpy"), 3, "0 0 0")
        return (None if not np.any(rpy) else rpy_matrix(rpy)), xyz

    def attr_float(self, elem: ET.Element, key: str, where: str) -> float:
        text = elem.get(key)
        if text is None:
            raise self.c.fail(where, f"missing attribute {key!r}")
        return float(self.floats(f"{where} {key}", text, 1, "")[0])

    def box_size(self, link: str) -> tuple[float, float, float] | None:
        """The size of the link's first box visual, if it has one."""
        box = self.links[link].find("visual/geometry/box")
        if box is None:
            return None
        where = f"link {link!r} <visual> <box size>"
        size = self.floats(where, box.get("size"), 3, "")
        if np.any(size <= 0.0):
            raise self.c.fail(where, f"must be 3 positive numbers, got {box.get('size')!r}")
        return (float(size[0]), float(size[1]), float(size[2]))

    def inertial(self, link: str) -> Inertial | None:
        """The link's inertial, or None for a massless frame (no inertial, or mass 0)."""
        where = f"link {link!r} <inertial>"
        elem = self.links[link].find("inertial")
        if elem is None:
            return None
        mass_elem = elem.find("mass")
        if mass_elem is None:
            raise self.c.fail(where, "missing <mass>")
        mass = self.attr_float(mass_elem, "value", f"{where} <mass>")
        if mass < 0.0:
            raise self.c.fail(f"{where} <mass>", f"negative mass {mass!r}")
        if mass == 0.0:
            return None
        inertia = elem.find("inertia")
        if inertia is None:
            raise self.c.fail(where, "missing <inertia> (a body with mass needs one)")
        i = {
            k: self.attr_float(inertia, k, f"{where} <inertia>")
            for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
        }
        tensor = np.array(
            [
                [i["ixx"], i["ixy"], i["ixz"]],
                [i["ixy"], i["iyy"], i["iyz"]],
                [i["ixz"], i["iyz"], i["izz"]],
            ]
        )
        smallest = float(np.linalg.eigvalsh(tensor)[0])
        if smallest <= 0.0:
            raise self.c.fail(
                f"{where} <inertia>",
                f"not positive definite (smallest principal moment {smallest:.6g} kg m^2)",
            )
        # The triangle inequality is not required: ETS-VII's identified links break it
        # (docs/model.md); planner.mjcf compiles such inertias exactly.
        return Inertial(mass, self.origin(elem, where), tensor)
