"""Robot description files: any free-floating robot, with ETS-VII as one example.

A description is a TOML file (format: ``docs/robots.md``) that names a URDF beside it for the
base and the arm, and adds what a URDF cannot say: which link is the free-floating base, the
reaction wheels, the attitude-control law's parameters, the joint servos, the sensor noise,
named poses and the experiments' default parameters.

    load_robot(path) -> RobotDescription      parse, validate, build (a pure function)
    RobotDescription.model                     the RobotModel every planner takes
    RobotDescription.acs_gains(ws)             the attitude-control law (planner.attitude_control)
    RobotDescription.servo_gains()             the joint servos' PD gains (planner.mjcf)
    RobotDescription.sensor_noise              1-sigma noise, radians (spacecraft.SensorNoise's
                                               field names and units)
    RobotDescription.poses / pose_joints_rad   named poses (A, B, C for ETS-VII)
    RobotDescription.experiments               default parameters per experiment (raw values
                                               for planner.catalogue.parameters_from_values)
    RobotDescription.content_sha256            hash of the canonical TOML and URDF content

Every fault raises one :class:`InvalidRobotDescription` whose message names the file, the
element and what is wrong; nothing is cached or changed by a failing (or a passing) load.

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

import functools
import hashlib
import json
import math
import re
import tomllib
import xml.etree.ElementTree as ET
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from planner.errors import InvalidInput
from planner.model import LinkSpec, RobotModel, WheelSpec, base_body_inertial

if TYPE_CHECKING:
    from planner.attitude_control import AcsGains
    from planner.dynamics import DynamicsWorkspace
    from planner.mjcf import ServoGains

__all__ = [
    "ETS7_DESCRIPTION",
    "EXAMPLES_DIR",
    "MAX_FILE_BYTES",
    "MIN_ARM_JOINTS",
    "InvalidRobotDescription",
    "NamedPose",
    "RobotDescription",
    "SensorNoiseSpec",
    "ServoSpec",
    "VehicleTables",
    "WheelLimits",
    "default_robot",
    "load_robot",
    "load_vehicle_tables",
    "servo_gains_of",
]

Array = NDArray[np.float64]

#: Neither the TOML nor the URDF may be larger (checked by size before reading).
MAX_FILE_BYTES = 16 * 1024 * 1024
#: A reaction null space (n - 3 dimensions) needs at least 4 arm joints.
MIN_ARM_JOINTS = 4
#: The shipped descriptions (a source checkout; not installed with the package).
EXAMPLES_DIR = Path(__file__).resolve().parents[1] / "examples" / "robots"
ETS7_DESCRIPTION = EXAMPLES_DIR / "ets7" / "ets7.toml"

#: Continuous joints get these limits (rad): a turn each way, so that check_joints has a range.
CONTINUOUS_LIMIT_RAD = 2.0 * math.pi
#: Defaults where a description leaves a value out (the values ETS-VII uses, except the
#: servos': one lag and bandwidth for every joint, where ETS-VII's file gives one per joint).
DEFAULT_ROTOR_MASS_KG = 1e-3
DEFAULT_SERVO_BANDWIDTH_RADPS = 6.0
DEFAULT_SERVO_LAG_S = 0.3
DEFAULT_NOISE_DEG = {"attitude_deg": 0.005, "rate_degps": 0.0005, "joint_deg": 0.005}
#: A pose given both as joints and as a hand pose must agree this well.
POSE_CHECK_M = 0.01
POSE_CHECK_DEG = 1.0
#: Three wheel axes must span space: |det| of the unit axes at least this.
MIN_WHEEL_AXES_DET = 0.1

_NAME = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")
_TOP_KEYS = frozenset(
    {
        "name",
        "description",
        "urdf",
        "base_link",
        "wheels",
        "acs",
        "servo",
        "sensor_noise",
        "poses",
        "experiments",
    }
)
_WHEEL_KEYS = frozenset(
    {"axis", "spin_inertia_kgm2", "rotor_mass_kg", "torque_limit_nm", "momentum_limit_nms"}
)
_WHEEL_NAMES = ("wheel_x", "wheel_y", "wheel_z")  # the MuJoCo names planner.state expects
_POSE_KEYS = frozenset({"description", "joints_deg", "hand_pos_robot_m", "hand_rpy_deg"})
_SERVO_KEYS = frozenset({"bandwidth_radps", "lag_s", "kp_nm_per_rad", "kd_nms_per_rad"})
_ARM_JOINT_TYPES = frozenset({"revolute", "continuous"})
_HAND = "hand"


class InvalidRobotDescription(InvalidInput):
    """A robot description (TOML or URDF) that cannot be loaded: ``file: element: problem``."""

    def __init__(self, path: Path | str, element: str, problem: str) -> None:
        self.path = str(path)
        self.element = element
        self.problem = problem
        super().__init__(f"{path}: {element}: {problem}")


# --- the loaded description ---------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class WheelLimits:
    """What the attitude-control law may ask of one wheel."""

    torque_limit_nm: float
    momentum_limit_nms: float


@dataclass(frozen=True, eq=False)
class ServoSpec:
    """The joint servos: either the PD design of :func:`planner.simulation.default_servo_gains`
    (``bandwidth_radps``, ``lag_s``: one number for every joint, or an array of one per joint)
    or explicit per-joint gains (both arrays, shape (n,))."""

    bandwidth_radps: float | Array = DEFAULT_SERVO_BANDWIDTH_RADPS
    lag_s: float | Array = DEFAULT_SERVO_LAG_S
    kp_nm_per_rad: Array | None = None
    kd_nms_per_rad: Array | None = None


@dataclass(frozen=True)
class SensorNoiseSpec:
    """1-sigma sensor noise in radians; the field names of ``spacecraft.SensorNoise``, so
    ``SensorNoise(**dataclasses.asdict(spec))`` builds the vehicle's."""

    attitude_rad: float
    rate_radps: float
    joint_rad: float


@dataclass(frozen=True, eq=False)
class NamedPose:
    """A pose by joint angles, by hand pose (robot frame), or by both (checked to agree)."""

    name: str
    description: str = ""
    joints_rad: Array | None = None
    hand_pos_robot_m: Array | None = None
    hand_rpy_deg: Array | None = None  # roll, pitch, yaw: Rz(yaw) Ry(pitch) Rx(roll)

    @property
    def rot_robot_from_hand(self) -> Array | None:
        from planner.frames import matrix_from_rpy

        return None if self.hand_rpy_deg is None else matrix_from_rpy(np.radians(self.hand_rpy_deg))


@dataclass(frozen=True, eq=False)
class RobotDescription:
    """A loaded, validated robot description. ``model`` is what every planner takes."""

    name: str
    description: str
    path: Path  # the TOML
    urdf_path: Path
    content_sha256: str  # canonical TOML (without the URDF's file name) + canonical URDF
    base_link: str
    model: RobotModel
    wheel_limits: tuple[WheelLimits, ...]  # one per model.wheels entry
    acs_config: Mapping[str, object]  # the [acs] table as written (planner.attitude_control)
    servo: ServoSpec
    sensor_noise: SensorNoiseSpec
    poses: Mapping[str, NamedPose]
    experiments: Mapping[str, Mapping[str, object]] = field(
        default_factory=lambda: MappingProxyType({})
    )
    #: the base link's first box visual (display only; planner.urdf.urdf_xml draws it)
    base_box_size_m: tuple[float, float, float] | None = None

    @property
    def n_joints(self) -> int:
        return self.model.n_joints

    @property
    def wheel_torque_limit_nm(self) -> float:
        """The law's one torque limit: the smallest wheel's."""
        return min(w.torque_limit_nm for w in self.wheel_limits)

    @property
    def wheel_momentum_limit_nms(self) -> float:
        """The law's one momentum limit: the smallest wheel's."""
        return min(w.momentum_limit_nms for w in self.wheel_limits)

    def acs_gains(self, ws: DynamicsWorkspace | None = None) -> AcsGains:
        """The attitude-control law: the ``[acs]`` table read by
        :func:`planner.attitude_control.acs_gains_from_config`, with the wheels' limits."""
        from planner.attitude_control import acs_gains_from_config
        from planner.dynamics import DynamicsWorkspace

        workspace = ws if ws is not None else DynamicsWorkspace(self.model)
        config = {
            **self.acs_config,
            "torque_limit_nm": self.wheel_torque_limit_nm,
            "momentum_limit_nms": self.wheel_momentum_limit_nms,
        }
        return acs_gains_from_config(workspace, config)

    def servo_gains(self) -> ServoGains:
        """The joint servos' PD gains (``planner.mjcf.ServoGains``): explicit, or the design
        (``kp = H_m[i, i] wn^2`` at the all-zero pose, ``kd = lag kp``), per joint."""
        return servo_gains_of(self.servo, self.model)

    def pose_joints_rad(self, name: str, ws: DynamicsWorkspace | None = None) -> Array:
        """Joint angles of the named pose: as written, or the IK solution of its hand pose
        nearest the all-zero pose (:func:`planner.ik.solve_ik`)."""
        if name not in self.poses:
            raise InvalidInput(
                f"robot {self.name!r} has no pose {name!r}; it has {sorted(self.poses)}"
            )
        pose = self.poses[name]
        if pose.joints_rad is not None:
            return pose.joints_rad.copy()
        from planner.dynamics import DynamicsWorkspace
        from planner.ik import solve_ik

        assert pose.hand_pos_robot_m is not None and pose.rot_robot_from_hand is not None
        workspace = ws if ws is not None else DynamicsWorkspace(self.model)
        return solve_ik(workspace, pose.hand_pos_robot_m, pose.rot_robot_from_hand)[0].joints_rad

    def target_joints_rad(self, name: str, ws: DynamicsWorkspace, *, experiment: str) -> Array:
        """Joint angles for the named pose as an experiment's start or goal.

        A pose with a hand pose is that hand pose exactly: the IK solution nearest the pose's
        written joints (nearest the all-zero pose when none are written), so ETS-VII's B is
        the grapple approach of SPEC 1.2, not the paper's joints rounded to 0.1 deg, and a
        redundant arm keeps the configuration its joints name. A pose of joints alone is
        those joints. Refused (:class:`~planner.errors.InvalidInput`) with the reason when
        the robot has no such pose, or its hand pose cannot be reached within the limits.
        """
        from planner.errors import PlannerError
        from planner.ik import solve_ik

        if name not in self.poses:
            raise InvalidInput(
                f"{experiment}: robot {self.name!r} has no pose {name!r}, which the experiment "
                f"needs (its poses: {sorted(self.poses) or 'none'}); add [poses.{name}] to its "
                "description or give the joints as parameters"
            )
        pose = self.poses[name]
        if pose.hand_pos_robot_m is None or pose.rot_robot_from_hand is None:
            assert pose.joints_rad is not None
            return self.model.check_joints(pose.joints_rad).copy()
        try:
            solutions = solve_ik(
                ws,
                pose.hand_pos_robot_m,
                pose.rot_robot_from_hand,
                reference_joints_rad=pose.joints_rad,
            )
        except PlannerError as exc:
            raise InvalidInput(
                f"{experiment}: robot {self.name!r}'s pose {name!r} cannot be reached: {exc}"
            ) from exc
        return solutions[0].joints_rad

    def experiment_defaults(self, experiment: str) -> Mapping[str, object]:
        """The ``[experiments.NAME]`` table (raw values), empty when the file has none."""
        return self.experiments.get(experiment, MappingProxyType({}))


@functools.cache
def default_robot() -> RobotDescription:
    """ETS-VII's description (``ETS7_DESCRIPTION``), loaded once: the robot every planner
    plans for when it is given none."""
    return load_robot(ETS7_DESCRIPTION)


# --- reading files ------------------------------------------------------------------------


def _read_limited(path: Path, what: str) -> bytes:
    """The file's bytes; refused by its size before reading anything when too large."""
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise InvalidRobotDescription(path, what, "no such file") from None
    except OSError as exc:
        raise InvalidRobotDescription(path, what, f"cannot read it: {exc.strerror}") from None
    if not path.is_file():
        raise InvalidRobotDescription(path, what, "not a regular file")
    if size > MAX_FILE_BYTES:
        raise InvalidRobotDescription(
            path, what, f"the file is {size} bytes, over the {MAX_FILE_BYTES} byte limit"
        )
    try:
        with path.open("rb") as f:
            data = f.read(MAX_FILE_BYTES + 1)  # the file may have grown since stat
    except OSError as exc:
        raise InvalidRobotDescription(path, what, f"cannot read it: {exc.strerror}") from None
    if len(data) > MAX_FILE_BYTES:
        raise InvalidRobotDescription(path, what, f"over the {MAX_FILE_BYTES} byte limit")
    return data


def _canonical_xml(root: ET.Element) -> bytes:
    """The parsed document (comments already dropped) as JSON events: each element's tag,
    sorted attributes and stripped text, its children, then its stripped tail. Iterative, so
    a deeply nested file cannot exhaust the stack, and linear (C14N in Python is not)."""
    out: list[object] = []
    stack: list[tuple[ET.Element, Iterator[ET.Element]]] = []

    def start(elem: ET.Element) -> None:
        out.append([elem.tag, sorted(elem.attrib.items()), (elem.text or "").strip()])
        stack.append((elem, iter(elem)))

    start(root)
    while stack:
        elem, children = stack[-1]
        child = next(children, None)
        if child is None:
            stack.pop()
            out.append(["/", (elem.tail or "").strip() if stack else ""])
        else:
            start(child)
    return json.dumps(out, separators=(",", ":"), ensure_ascii=False).encode()


def _canonical_toml(doc: Mapping[str, Any]) -> bytes:
    def other(value: object) -> object:
        if hasattr(value, "isoformat"):
            return {"toml-datetime": value.isoformat()}
        raise TypeError(type(value).__name__)

    content = {k: v for k, v in doc.items() if k != "urdf"}  # content, not the file's name
    return json.dumps(
        content, sort_keys=True, separators=(",", ":"), ensure_ascii=False, default=other
    ).encode()


# --- small validators ---------------------------------------------------------------------


class _Checker:
    """Raises :class:`InvalidRobotDescription` for one file."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def fail(self, element: str, problem: str) -> InvalidRobotDescription:
        return InvalidRobotDescription(self.path, element, problem)

    def number(self, element: str, value: object, *, positive: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(element, f"must be a number, got {value!r}")
        out = float(value)
        if not math.isfinite(out):
            raise self.fail(element, f"must be finite, got {value!r}")
        if positive and out <= 0.0:
            raise self.fail(element, f"must be > 0, got {value!r}")
        return out

    def non_negative(self, element: str, value: object) -> float:
        out = self.number(element, value)
        if out < 0.0:
            raise self.fail(element, f"must be >= 0, got {value!r}")
        return out

    def numbers(self, element: str, value: object, count: int) -> Array:
        if not isinstance(value, list) or len(value) != count:
            raise self.fail(element, f"must be a list of {count} numbers, got {value!r}")
        return np.array([self.number(f"{element}[{i}]", v) for i, v in enumerate(value)])

    def table(self, element: str, value: object) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.fail(element, f"must be a table, got {value!r}")
        return value

    def keys(self, element: str, table: Mapping[str, object], known: frozenset[str]) -> None:
        unknown = sorted(set(table) - known)
        if unknown:
            raise self.fail(
                element, f"unknown key(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}"
            )

    def text(self, element: str, value: object) -> str:
        if not isinstance(value, str):
            raise self.fail(element, f"must be a string, got {value!r}")
        return value


def _frozen(a: Array) -> Array:
    out = np.array(a, dtype=np.float64)
    out.setflags(write=False)
    return out


def _rpy_matrix(rpy: Array) -> Array:
    """URDF's fixed-axis roll, pitch, yaw: ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    cr, sr = math.cos(rpy[0]), math.sin(rpy[0])
    cp, sp = math.cos(rpy[1]), math.sin(rpy[1])
    cy, sy = math.cos(rpy[2]), math.sin(rpy[2])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return np.asarray(rz @ ry @ rx)


class _Frame:
    """A rotation and a position; the exact identity rotation is carried without arithmetic
    so that frames without rotations pass numbers through unrounded."""

    def __init__(self, rot: Array | None, pos: Array) -> None:
        self.rot = rot  # None: exactly the identity
        self.pos = pos

    def apply(self, v: Array) -> Array:
        """A direction of the child frame in the parent's axes."""
        return v.copy() if self.rot is None else np.asarray(self.rot @ v)

    def then(self, rot: Array | None, pos: Array) -> _Frame:
        """This frame followed by a child origin ``(rot, pos)`` given in this frame."""
        new_pos = self.pos + self.apply(pos)
        if rot is None:
            return _Frame(self.rot, new_pos)
        return _Frame(rot if self.rot is None else np.asarray(self.rot @ rot), new_pos)

    def rotate_tensor(self, tensor: Array) -> Array:
        return tensor.copy() if self.rot is None else np.asarray(self.rot @ tensor @ self.rot.T)

    @property
    def rot_matrix(self) -> Array:
        return np.eye(3) if self.rot is None else self.rot


# --- the URDF -----------------------------------------------------------------------------


@dataclass
class _Inertial:
    mass_kg: float
    origin: tuple[Array | None, Array]  # rotation (None: identity), position in the link
    inertia_kgm2: Array  # in the inertial frame


class _Urdf:
    def __init__(self, path: Path, data: bytes) -> None:
        self.c = _Checker(path)
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
        return (None if not np.any(rpy) else _rpy_matrix(rpy)), xyz

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

    def inertial(self, link: str) -> _Inertial | None:
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
        return _Inertial(mass, self.origin(elem, where), tensor)


def _arm_chain(urdf: _Urdf, base_link: str) -> list[ET.Element]:
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


def _model_from_urdf(urdf: _Urdf, base_link: str, wheels: tuple[WheelSpec, ...]) -> RobotModel:
    c = urdf.c
    chain = _arm_chain(urdf, base_link)
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
    base_inertia = _Frame(base_rot, np.zeros(3)).rotate_tensor(base.inertia_kgm2)

    # Base link frame -> the first arm joint's frame.
    frame = _Frame(None, np.zeros(3))
    for joint in chain[:first]:
        frame = frame.then(*urdf.origin(joint, f"joint {joint.get('name')!r}"))
    j1_rot, j1_pos = urdf.origin(chain[first], f"joint {chain[first].get('name')!r}")
    frame = frame.then(j1_rot, j1_pos)
    pos_base_from_robot = frame.pos - base_com
    # From here on positions are relative to the robot origin (joint 1), base axes.
    frame = _Frame(frame.rot, np.zeros(3))

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
        if not _NAME.match(child):
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
                joint_pos_robot_m=_frozen(frame.pos),
                joint_axis_robot=_frozen(axis),
                mass_kg=inertial.mass_kg,
                com_robot_m=_frozen(inertia_frame.pos),
                inertia_com_inertia_frame_kgm2=_frozen(inertial.inertia_kgm2),
                rot_robot_from_inertia=_frozen(inertia_frame.rot_matrix),
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
    reserved = {*_WHEEL_NAMES, "base"}  # the MuJoCo model's own bodies
    if reserved & set(names):
        raise c.fail(
            f"link {sorted(reserved & set(names))[0]!r}",
            f"arm links may not be called {sorted(reserved)} (the MuJoCo model's own bodies)",
        )
    return RobotModel(
        base_mass_kg=base.mass_kg,
        base_inertia_kgm2=_frozen(base_inertia),
        pos_base_from_robot_m=_frozen(pos_base_from_robot),
        links=tuple(links),
        hand_pos_robot_m=_frozen(frame.pos),
        wheels=wheels,
        joint_limit_rad=_frozen(np.array(limits)),
        joint_rate_limit_radps=_frozen(np.array(rates)),
    )


# --- the TOML's tables --------------------------------------------------------------------


def _wheels(c: _Checker, value: object) -> tuple[tuple[WheelSpec, ...], tuple[WheelLimits, ...]]:
    if not isinstance(value, list) or len(value) != len(_WHEEL_NAMES):
        raise c.fail("[[wheels]]", f"exactly {len(_WHEEL_NAMES)} wheels are needed")
    specs, limits, axes = [], [], []
    for k, item in enumerate(value):
        where = f"[[wheels]] {k + 1}"
        table = c.table(where, item)
        c.keys(where, table, _WHEEL_KEYS)
        for key in ("axis", "spin_inertia_kgm2", "torque_limit_nm", "momentum_limit_nms"):
            if key not in table:
                raise c.fail(where, f"missing {key}")
        axis = c.numbers(f"{where} axis", table["axis"], 3)
        norm = float(np.linalg.norm(axis))
        if norm == 0.0:
            raise c.fail(f"{where} axis", "must not be zero")
        axes.append(axis / norm)
        specs.append(
            WheelSpec(
                name=_WHEEL_NAMES[k],
                axis_base=_frozen(axis / norm),
                spin_inertia_kgm2=c.number(
                    f"{where} spin_inertia_kgm2", table["spin_inertia_kgm2"], positive=True
                ),
                mass_kg=c.number(
                    f"{where} rotor_mass_kg",
                    table.get("rotor_mass_kg", DEFAULT_ROTOR_MASS_KG),
                    positive=True,
                ),
            )
        )
        limits.append(
            WheelLimits(
                torque_limit_nm=c.number(
                    f"{where} torque_limit_nm", table["torque_limit_nm"], positive=True
                ),
                momentum_limit_nms=c.number(
                    f"{where} momentum_limit_nms", table["momentum_limit_nms"], positive=True
                ),
            )
        )
    det = abs(float(np.linalg.det(np.array(axes))))
    if det < MIN_WHEEL_AXES_DET:
        raise c.fail(
            "[[wheels]] axis",
            f"the three axes must span space (|det| of the unit axes is {det:.3g}, "
            f"at least {MIN_WHEEL_AXES_DET} needed)",
        )
    return tuple(specs), tuple(limits)


def _servo(c: _Checker, value: object, n: int) -> ServoSpec:
    table = c.table("[servo]", value)
    c.keys("[servo]", table, _SERVO_KEYS)
    explicit = {"kp_nm_per_rad", "kd_nms_per_rad"} & set(table)
    if explicit and (len(explicit) == 1 or {"bandwidth_radps", "lag_s"} & set(table)):
        raise c.fail(
            "[servo]", "give either bandwidth_radps/lag_s or both kp_nm_per_rad and kd_nms_per_rad"
        )
    if explicit:
        kp = c.numbers("[servo] kp_nm_per_rad", table["kp_nm_per_rad"], n)
        kd = c.numbers("[servo] kd_nms_per_rad", table["kd_nms_per_rad"], n)
        if np.any(kp <= 0.0) or np.any(kd < 0.0):
            raise c.fail("[servo]", "kp must be > 0 and kd >= 0 on every joint")
        return ServoSpec(kp_nm_per_rad=_frozen(kp), kd_nms_per_rad=_frozen(kd))
    return ServoSpec(
        bandwidth_radps=_per_joint(
            c,
            "[servo] bandwidth_radps",
            table.get("bandwidth_radps", DEFAULT_SERVO_BANDWIDTH_RADPS),
            n,
            positive=True,
        ),
        lag_s=_per_joint(c, "[servo] lag_s", table.get("lag_s", DEFAULT_SERVO_LAG_S), n),
    )


def _per_joint(
    c: _Checker, element: str, value: object, n: int, *, positive: bool = False
) -> float | Array:
    """One number for every joint, or a list of one per joint (``> 0`` if ``positive``,
    else ``>= 0``)."""

    def check(where: str, v: object) -> float:
        return c.number(where, v, positive=True) if positive else c.non_negative(where, v)

    if isinstance(value, list):
        if len(value) != n:
            raise c.fail(
                element, f"needs one number or a list of {n} (one per joint), got {len(value)}"
            )
        return _frozen(np.array([check(f"{element}[{i}]", v) for i, v in enumerate(value)]))
    return check(element, value)


def _sensor_noise(c: _Checker, value: object) -> SensorNoiseSpec:
    table = c.table("[sensor_noise]", value)
    c.keys("[sensor_noise]", table, frozenset(DEFAULT_NOISE_DEG))
    deg = {
        key: c.non_negative(f"[sensor_noise] {key}", table.get(key, default))
        for key, default in DEFAULT_NOISE_DEG.items()
    }
    return SensorNoiseSpec(
        attitude_rad=math.radians(deg["attitude_deg"]),
        rate_radps=math.radians(deg["rate_degps"]),
        joint_rad=math.radians(deg["joint_deg"]),
    )


def _poses(c: _Checker, value: object, ws: DynamicsWorkspace) -> dict[str, NamedPose]:
    model = ws.model
    poses: dict[str, NamedPose] = {}
    for name, item in c.table("[poses]", value).items():
        where = f"[poses.{name}]"
        if not _NAME.match(name):
            raise c.fail(where, "a pose name is letters, digits, '_', '-' or '.' (up to 64)")
        table = c.table(where, item)
        c.keys(where, table, _POSE_KEYS)
        joints = None
        if "joints_deg" in table:
            joints = np.radians(
                c.numbers(f"{where} joints_deg", table["joints_deg"], model.n_joints)
            )
            for i, (angle, (lo, hi)) in enumerate(zip(joints, model.joint_limit_rad, strict=True)):
                if not lo <= angle <= hi:
                    raise c.fail(
                        f"{where} joints_deg[{i}]",
                        f"{math.degrees(angle):.6g} deg is outside joint {i + 1}'s limits "
                        f"[{math.degrees(lo):.6g}, {math.degrees(hi):.6g}] deg",
                    )
        hand = [k for k in ("hand_pos_robot_m", "hand_rpy_deg") if k in table]
        if len(hand) == 1:
            raise c.fail(where, "give both hand_pos_robot_m and hand_rpy_deg, or neither")
        if joints is None and not hand:
            raise c.fail(
                where, "give joints_deg, a hand pose (hand_pos_robot_m, hand_rpy_deg), or both"
            )
        pose = NamedPose(
            name=name,
            description=c.text(f"{where} description", table.get("description", "")),
            joints_rad=None if joints is None else _frozen(joints),
            hand_pos_robot_m=(
                _frozen(c.numbers(f"{where} hand_pos_robot_m", table["hand_pos_robot_m"], 3))
                if hand
                else None
            ),
            hand_rpy_deg=(
                _frozen(c.numbers(f"{where} hand_rpy_deg", table["hand_rpy_deg"], 3))
                if hand
                else None
            ),
        )
        if joints is not None and hand:
            _check_pose(c, where, pose, ws)
        poses[name] = pose
    return poses


def _check_pose(c: _Checker, where: str, pose: NamedPose, ws: DynamicsWorkspace) -> None:
    from planner.state import State

    assert pose.joints_rad is not None and pose.hand_pos_robot_m is not None
    rot = pose.rot_robot_from_hand
    assert rot is not None
    n = ws.model.n_joints
    hand = ws.hand_pose(State(joints_rad=pose.joints_rad, joint_rates_radps=np.zeros(n)))
    off_m = float(np.linalg.norm(hand.pos_robot_m - pose.hand_pos_robot_m))
    cos = (float(np.trace(rot.T @ hand.rot_robot_from_hand)) - 1.0) / 2.0
    off_deg = math.degrees(math.acos(min(1.0, max(-1.0, cos))))
    if off_m > POSE_CHECK_M or off_deg > POSE_CHECK_DEG:
        raise c.fail(
            where,
            f"joints_deg put the hand {off_m:.4g} m and {off_deg:.4g} deg from hand_pos_robot_m/"
            f"hand_rpy_deg (at most {POSE_CHECK_M} m and {POSE_CHECK_DEG} deg allowed)",
        )


def _experiments(c: _Checker, value: object, n: int) -> dict[str, Mapping[str, object]]:
    from planner.catalogue import experiments, parameters_from_values

    known = experiments()
    out: dict[str, Mapping[str, object]] = {}
    for name, item in c.table("[experiments]", value).items():
        where = f"[experiments.{name}]"
        if name not in known:
            raise c.fail(where, f"unknown experiment; known: {sorted(known)}")
        table = c.table(where, item)
        for key, values in table.items():
            per_joint = key.endswith("joints_deg") or (
                key.startswith("phi_") and key.endswith("_deg")
            )
            if per_joint and isinstance(values, list) and len(values) != n:
                raise c.fail(
                    f"{where} {key}", f"needs {n} values (one per joint), got {len(values)}"
                )
        try:
            parameters_from_values(known[name][0], table)
        except InvalidInput as exc:
            raise c.fail(where, str(exc)) from None
        out[name] = MappingProxyType(dict(table))
    return out


# --- loading ------------------------------------------------------------------------------


@dataclass(frozen=True)
class VehicleTables:
    """A vehicle file's ``[servo]`` and ``[sensor_noise]`` (``None`` where absent)."""

    servo: ServoSpec | None
    sensor_noise: SensorNoiseSpec | None


def _read_toml(toml_path: Path, what: str) -> tuple[_Checker, dict[str, Any]]:
    """The TOML document at ``toml_path`` (a ``what``, size-limited) and its checker; a file
    that is not UTF-8 TOML raises one :class:`InvalidRobotDescription`."""
    c = _Checker(toml_path)
    raw = _read_limited(toml_path, what)
    try:
        return c, tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise c.fail("document", "not UTF-8 text") from None
    except tomllib.TOMLDecodeError as exc:
        raise c.fail("document", f"not valid TOML: {exc}") from None


def load_vehicle_tables(path: str | Path, n_joints: int) -> VehicleTables:
    """The ``[servo]`` and ``[sensor_noise]`` tables of a TOML file (``hikoboshi calibrate
    --vehicle-out`` writes one; ``hikoboshi spacecraft --vehicle-config`` reads it), checked
    as a robot description's for an arm of ``n_joints``; any other table is refused. Every
    fault raises one :class:`InvalidRobotDescription`."""
    c, doc = _read_toml(Path(path), "vehicle configuration")
    c.keys("document", doc, frozenset({"servo", "sensor_noise"}))
    if not doc:
        raise c.fail("document", "give a [servo] or a [sensor_noise] table")
    return VehicleTables(
        servo=_servo(c, doc["servo"], n_joints) if "servo" in doc else None,
        sensor_noise=_sensor_noise(c, doc["sensor_noise"]) if "sensor_noise" in doc else None,
    )


def servo_gains_of(spec: ServoSpec, model: RobotModel) -> ServoGains:
    """A ``[servo]`` table's PD gains on ``model`` (explicit, or the design)."""
    from planner.mjcf import ServoGains
    from planner.simulation import default_servo_gains

    if spec.kp_nm_per_rad is not None and spec.kd_nms_per_rad is not None:
        return ServoGains(kp_nm_per_rad=spec.kp_nm_per_rad, kd_nms_per_rad=spec.kd_nms_per_rad)
    return default_servo_gains(model, bandwidth_radps=spec.bandwidth_radps, lag_s=spec.lag_s)


def load_robot(path: str | Path) -> RobotDescription:
    """Load and validate the robot description at ``path`` (a TOML file; ``docs/robots.md``).

    Raises :class:`InvalidRobotDescription` (an :class:`~planner.errors.InvalidInput`) for
    any fault, naming the file, the element and what is wrong.
    """
    from planner.dynamics import DynamicsWorkspace

    toml_path = Path(path)
    c, doc = _read_toml(toml_path, "description")
    c.keys("document", doc, _TOP_KEYS)
    for key in ("name", "urdf", "base_link", "wheels"):
        if key not in doc:
            raise c.fail(key, "missing")
    name = c.text("name", doc["name"])
    if not _NAME.match(name):
        raise c.fail("name", f"{name!r}: letters, digits, '_', '-' or '.' (up to 64)")
    urdf_name = c.text("urdf", doc["urdf"])
    if not urdf_name or Path(urdf_name).is_absolute():
        raise c.fail("urdf", f"{urdf_name!r} must be a path relative to the description")
    urdf_path = toml_path.parent / urdf_name
    try:
        inside = urdf_path.resolve().is_relative_to(toml_path.parent.resolve())
    except (OSError, RuntimeError):  # a symlink loop
        inside = False
    if not inside:
        raise c.fail("urdf", f"{urdf_name!r} must stay inside the description's folder")
    base_link = c.text("base_link", doc["base_link"])
    wheels, wheel_limits = _wheels(c, doc["wheels"])

    urdf_bytes = _read_limited(urdf_path, "URDF")
    urdf = _Urdf(urdf_path, urdf_bytes)
    urdf.check_tree(base_link)
    model = _model_from_urdf(urdf, base_link, wheels)

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
        name=name,
        description=c.text("description", doc.get("description", "")),
        path=toml_path,
        urdf_path=urdf_path,
        content_sha256=hashlib.sha256(
            b"hikoboshi-robot/1\0" + _canonical_toml(doc) + b"\0" + _canonical_xml(urdf.root)
        ).hexdigest(),
        base_link=base_link,
        model=model,
        wheel_limits=wheel_limits,
        acs_config=MappingProxyType(dict(acs)),
        servo=_servo(c, doc.get("servo", {}), model.n_joints),
        sensor_noise=_sensor_noise(c, doc.get("sensor_noise", {})),
        poses=MappingProxyType(_poses(c, doc.get("poses", {}), ws)),
        experiments=MappingProxyType(_experiments(c, doc.get("experiments", {}), model.n_joints)),
        base_box_size_m=urdf.box_size(base_link),
    )
    try:
        description.acs_gains(ws)
    except InvalidInput as exc:
        raise c.fail("[acs]", str(exc)) from None
    return description
