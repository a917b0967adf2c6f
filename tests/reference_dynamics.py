"""Independent plain-NumPy reference for the free-floating robot's dynamics (SPEC 1, 2, 7).

Written apart from ``planner/`` and importing nothing from it, so that
``tests/planner/test_dynamics_reference.py`` can hold the MuJoCo-based
:mod:`planner.dynamics` against it. The SPEC tables (Table 1 and the section 7 joint table)
are re-typed below; only the wheels' spin inertia comes in as an argument.

Conventions (the project's, so that results compare entry by entry):

- generalised velocities ``(v_b, w_b, phi')``: the base CoM velocity and the base angular
  velocity, both in the orbit frame, then the joint rates; linear rows before angular rows;
- quaternions scalar-last ``(x, y, z, w)``; ``rot_a_from_b`` maps b coordinates into a;
- base frame origin at the base CoM; the robot frame is parallel to the base frame with its
  origin at :data:`POS_BASE_FROM_ROBOT_M`; every link frame and the hand frame are parallel to
  the robot frame at the all-zero pose;
- Table 1's products of inertia enter the matrix as written,
  ``[[Ixx, Ixy, Ixz], [Ixy, Iyy, Iyz], [Ixz, Iyz, Izz]]``;
- the wheels' rigid inertia is inside Table 1's base numbers (the locked base is Table 1);
  only each rotor's spin relative to the base adds ``I_w * rate`` along its axis.

Methods, deliberately unlike MuJoCo's recursive body tree:

- forward kinematics as a product of exponentials in the robot frame,
  ``g_i = exp(xi_1 q_1) ... exp(xi_i q_i)`` applied to the all-zero-pose geometry;
- the inertia matrix of eq. (1) twice: by the composite rigid body method (subtree
  composites) and as ``sum_i J_i^T M_i J_i`` over the bodies' CoM Jacobians;
- momentum (eq. 2-3) directly from every body's velocity.

Any robot: every function takes a :class:`RobotData` (default :data:`ETS7`, built from the
tables re-typed below). :func:`robot_from_description` reads a robot description (the TOML
and its URDF, ``docs/robots.md``) with its own small reader, homogeneous transforms and
``tomllib``, not with ``planner.description``.
"""

from __future__ import annotations

import tomllib
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "BASE_MASS_KG",
    "ETS7",
    "HAND_POS_ROBOT_M",
    "MU_M3PS2",
    "N_JOINTS",
    "ORBIT_RADIUS_M",
    "TOTAL_MASS_KG",
    "Kinematics",
    "Reference",
    "RobotData",
    "evaluate",
    "forward_kinematics",
    "gravity_gradient_torque_base_nm",
    "hand_jacobians",
    "inertia_matrix_crb",
    "inertia_matrix_jacobian_sum",
    "matrix_from_quat_xyzw",
    "quat_multiply_xyzw",
    "quat_xyzw_about_axis",
    "robot_from_description",
    "vee",
]

Array = NDArray[np.float64]

# --- SPEC tables, re-typed ---------------------------------------------------------------


def _table_inertia(ixx: float, iyy: float, izz: float, ixy: float, ixz: float, iyz: float) -> Array:
    """Table 1's six numbers as a matrix, products of inertia as written (SPEC 1.1)."""
    return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])


# Table 1, base (wheels included), about the base CoM, base frame.
BASE_MASS_KG = 2550.0
BASE_INERTIA_KGM2 = _table_inertia(6200.0, 3540.0, 7090.0, 48.2, 120.0, -29.2)

# Table 1, links 1-6: m, Ixx, Iyy, Izz, Ixy, Ixz, Iyz about the link CoM, link inertia frame.
_LINK_ROWS = (
    (35.0, 0.25, 0.25, 1.69, 0.0, 0.0, 0.0),
    (22.5, 0.10, 1.31, 3.75, 0.0, 0.0, 0.0),
    (21.9, 0.10, 0.71, 2.53, 0.0, 0.0, 0.0),
    (16.5, 0.15, 0.15, 0.07, 0.0, 0.0, 0.0),
    (26.0, 0.15, 0.15, 0.13, 0.0, 0.0, 0.0),
    (18.5, 0.97, 0.97, 0.26, 0.0, 0.0, 0.0),
)
LINK_MASS_KG = np.array([row[0] for row in _LINK_ROWS])
_LINK_INERTIA_TABLE_KGM2 = np.array([_table_inertia(*row[1:]) for row in _LINK_ROWS])

# SPEC section 7: joints at the all-zero pose, robot frame (m), right-handed unit axes.
JOINT_POS_ROBOT_M = np.array(
    [
        [0.0, 0.0, 0.0],
        [0.0, -0.275, 0.350],
        [0.0, -0.275, 1.220],
        [0.630, -0.550, 1.220],
        [0.630, -0.267, 1.220],
        [0.630, -0.267, 1.497],
    ]
)
JOINT_AXIS_ROBOT = np.array(
    [
        [0.0, 0.0, 1.0],
        [0.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
        [1.0, 0.0, 0.0],
    ]
)
HAND_POS_ROBOT_M = np.array([1.162, -0.267, 1.497])  # pose A
POS_BASE_FROM_ROBOT_M = np.array([-0.785, -0.295, 1.000])  # joint 1 in the base frame
N_JOINTS = 6

TOTAL_MASS_KG = BASE_MASS_KG + float(LINK_MASS_KG.sum())

# SPEC section 2 (our choice): circular orbit at 550 km.
MU_M3PS2 = 3.986004418e14
ORBIT_RADIUS_M = 6378.137e3 + 550e3

# --- small rotation helpers ---------------------------------------------------------------


def skew(v: Array) -> Array:
    """``skew(a) @ b == a x b``."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def vee(m: Array) -> Array:
    """The vector of the skew-symmetric part of ``m`` (inverse of :func:`skew`)."""
    return 0.5 * np.array([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]])


def _parallel_axis(d: Array) -> Array:
    """Steiner term per unit mass for an offset ``d``: ``|d|^2 I - d d^T`` (= -skew(d)^2)."""
    return float(d @ d) * np.eye(3) - np.outer(d, d)


def rot_about_axis(axis: Array, angle_rad: float) -> Array:
    """Rodrigues: right-handed rotation by ``angle_rad`` about the unit vector ``axis``."""
    k = skew(axis)
    return np.asarray(np.eye(3) + np.sin(angle_rad) * k + (1.0 - np.cos(angle_rad)) * (k @ k))


def matrix_from_quat_xyzw(quat_xyzw: Array) -> Array:
    """``R = (w^2 - |u|^2) I + 2 u u^T + 2 w [u]x`` of the normalised quaternion ``(u, w)``."""
    quat = np.asarray(quat_xyzw, dtype=np.float64)
    quat = quat / np.linalg.norm(quat)
    u, w = quat[:3], quat[3]
    return np.asarray((w * w - u @ u) * np.eye(3) + 2.0 * np.outer(u, u) + 2.0 * w * skew(u))


def quat_multiply_xyzw(a_xyzw: Array, b_xyzw: Array) -> Array:
    """Hamilton product ``a * b``: its matrix is ``matrix(a) @ matrix(b)``."""
    ua, wa = np.asarray(a_xyzw[:3]), float(a_xyzw[3])
    ub, wb = np.asarray(b_xyzw[:3]), float(b_xyzw[3])
    return np.concatenate([wa * ub + wb * ua + np.cross(ua, ub), [wa * wb - ua @ ub]])


def quat_xyzw_about_axis(axis: Array, angle_rad: float) -> Array:
    """Unit quaternion of a right-handed rotation by ``angle_rad`` about unit ``axis``."""
    return np.concatenate([np.sin(0.5 * angle_rad) * np.asarray(axis), [np.cos(0.5 * angle_rad)]])


# --- link geometry at the all-zero pose ---------------------------------------------------

# Each link ends at the next joint; link 6 ends at the hand point.
_LINK_END_ROBOT_M = np.vstack([JOINT_POS_ROBOT_M[1:], HAND_POS_ROBOT_M])
LINK_COM_ROBOT_M = 0.5 * (JOINT_POS_ROBOT_M + _LINK_END_ROBOT_M)


def _rot_robot_from_inertia_frame(i: int) -> Array:
    """Link i's Table 1 frame (SPEC 7): z on the joint axis, x the part of joint i -> i+1
    perpendicular to z. Where that part vanishes, Table 1 must be symmetric about z (checked)
    and any perpendicular x gives the same matrix."""
    z = JOINT_AXIS_ROBOT[i]
    along = _LINK_END_ROBOT_M[i] - JOINT_POS_ROBOT_M[i]
    perp = along - (along @ z) * z
    if np.linalg.norm(perp) < 1e-12:
        table = _LINK_INERTIA_TABLE_KGM2[i]
        if table[0, 0] != table[1, 1] or np.any(table[:2, 2] != 0.0) or table[0, 1] != 0.0:
            raise ValueError(f"link {i + 1}: no x axis defined and Table 1 is not symmetric")
        perp = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
    x = perp / np.linalg.norm(perp)
    return np.column_stack([x, np.cross(z, x), z])


def _inertia_zero_pose_robot_kgm2(i: int) -> Array:
    """Link i's Table 1 inertia (about its CoM) with robot-frame axes at the all-zero pose."""
    rot_robot_from_inertia = _rot_robot_from_inertia_frame(i)
    return np.asarray(
        rot_robot_from_inertia @ _LINK_INERTIA_TABLE_KGM2[i] @ rot_robot_from_inertia.T
    )


LINK_INERTIA_ZERO_POSE_ROBOT_KGM2 = np.array(
    [_inertia_zero_pose_robot_kgm2(i) for i in range(N_JOINTS)]
)


@dataclass(frozen=True, eq=False)
class RobotData:
    """A serial arm on a free-floating base, at the all-zero pose (robot frame = base axes,
    origin on joint 1; every link frame parallel to it at the all-zero pose)."""

    base_mass_kg: float
    base_inertia_kgm2: Array  # locked base (wheels included), about its CoM, base axes
    pos_base_from_robot_m: Array
    joint_pos_robot_m: Array  # (n, 3) a point on each joint axis
    joint_axis_robot: Array  # (n, 3) unit
    link_mass_kg: Array  # (n,)
    link_com_robot_m: Array  # (n, 3)
    link_inertia_zero_pose_robot_kgm2: Array  # (n, 3, 3) about each link's CoM
    hand_pos_robot_m: Array
    wheel_axes_base: Array = field(default_factory=lambda: np.eye(3))  # row k: rotor k's axis

    @property
    def n_joints(self) -> int:
        return int(self.link_mass_kg.shape[0])

    @property
    def total_mass_kg(self) -> float:
        return self.base_mass_kg + float(self.link_mass_kg.sum())


ETS7 = RobotData(
    base_mass_kg=BASE_MASS_KG,
    base_inertia_kgm2=BASE_INERTIA_KGM2,
    pos_base_from_robot_m=POS_BASE_FROM_ROBOT_M,
    joint_pos_robot_m=JOINT_POS_ROBOT_M,
    joint_axis_robot=JOINT_AXIS_ROBOT,
    link_mass_kg=LINK_MASS_KG,
    link_com_robot_m=LINK_COM_ROBOT_M,
    link_inertia_zero_pose_robot_kgm2=LINK_INERTIA_ZERO_POSE_ROBOT_KGM2,
    hand_pos_robot_m=HAND_POS_ROBOT_M,
)

# --- a robot description, read independently ----------------------------------------------


def _urdf_floats(elem: ET.Element | None, key: str, default: str) -> Array:
    text = default if elem is None else elem.get(key, default)
    return np.array([float(x) for x in text.split()])


def _urdf_rpy(rpy: Array) -> Array:
    """URDF's fixed-axis roll, pitch, yaw as a product of axis rotations."""
    return np.asarray(
        rot_about_axis(np.array([0.0, 0.0, 1.0]), rpy[2])
        @ rot_about_axis(np.array([0.0, 1.0, 0.0]), rpy[1])
        @ rot_about_axis(np.array([1.0, 0.0, 0.0]), rpy[0])
    )


def _urdf_origin(elem: ET.Element) -> Array:
    """4x4 transform of ``elem``'s ``<origin>``."""
    origin = elem.find("origin")
    g = np.eye(4)
    g[:3, :3] = _urdf_rpy(_urdf_floats(origin, "rpy", "0 0 0"))
    g[:3, 3] = _urdf_floats(origin, "xyz", "0 0 0")
    return g


def robot_from_description(toml_path: Path | str) -> RobotData:
    """The robot of a description file: its TOML's ``urdf``, ``base_link`` and ``[[wheels]]``
    and the URDF's chain from the base link to the link ``hand``."""
    toml_path = Path(toml_path)
    doc = tomllib.loads(toml_path.read_text())
    root = ET.fromstring((toml_path.parent / doc["urdf"]).read_text())
    links = {e.get("name"): e for e in root.findall("link")}
    joint_to = {}
    for joint in root.findall("joint"):
        child = joint.find("child")
        assert child is not None
        joint_to[child.get("link")] = joint
    chain = []  # joints from the base link to the hand
    link = "hand"
    while link != doc["base_link"]:
        chain.insert(0, joint_to[link])
        parent = joint_to[link].find("parent")
        assert parent is not None
        link = parent.get("link")

    def inertial(name: str) -> tuple[float, Array, Array]:
        """Mass, CoM transform within the link, inertia in that CoM frame."""
        elem = links[name].find("inertial")
        assert elem is not None
        i = {
            k: float(_urdf_floats(elem.find("inertia"), k, "nan")[0])
            for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
        }
        tensor = _table_inertia(i["ixx"], i["iyy"], i["izz"], i["ixy"], i["ixz"], i["iyz"])
        return float(_urdf_floats(elem.find("mass"), "value", "nan")[0]), _urdf_origin(elem), tensor

    base_mass, base_com, base_tensor = inertial(doc["base_link"])
    world = np.eye(4)  # base frame from base link frame: origin at the CoM, the link's axes
    world[:3, 3] = -base_com[:3, 3]
    base_inertia = base_com[:3, :3] @ base_tensor @ base_com[:3, :3].T
    g = world  # base frame from the current link frame
    joints, axes, masses, coms, inertias = [], [], [], [], []
    for joint in chain:
        g = g @ _urdf_origin(joint)
        if joint.get("type") == "fixed":
            continue
        axis = _urdf_floats(joint.find("axis"), "xyz", "1 0 0")
        joints.append(g[:3, 3].copy())
        axes.append(g[:3, :3] @ axis / np.linalg.norm(axis))
        child = joint.find("child")
        assert child is not None
        mass, com, tensor = inertial(child.get("link", ""))
        g_com = g @ com
        masses.append(mass)
        coms.append(g_com[:3, 3].copy())
        inertias.append(g_com[:3, :3] @ tensor @ g_com[:3, :3].T)
    origin = joints[0]
    return RobotData(
        base_mass_kg=base_mass,
        base_inertia_kgm2=base_inertia,
        pos_base_from_robot_m=origin,
        joint_pos_robot_m=np.array(joints) - origin,
        joint_axis_robot=np.array(axes),
        link_mass_kg=np.array(masses),
        link_com_robot_m=np.array(coms) - origin,
        link_inertia_zero_pose_robot_kgm2=np.array(inertias),
        hand_pos_robot_m=g[:3, 3] - origin,
        wheel_axes_base=np.array(
            [np.array(w["axis"]) / np.linalg.norm(w["axis"]) for w in doc["wheels"]]
        ),
    )


# --- kinematics ---------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Kinematics:
    """Positions of every body at one configuration. Bodies: 0 = base, 1-6 = links 1-6."""

    rot_orbit_from_base: Array  # (3, 3)
    pos_base_orbit_m: Array  # (3,) base CoM = base frame origin
    joint_pos_orbit_m: Array  # (6, 3) a point on each joint axis (the table's joint point)
    joint_axis_orbit: Array  # (6, 3)
    body_mass_kg: Array  # (7,)
    body_com_orbit_m: Array  # (7, 3)
    body_inertia_com_orbit_kgm2: Array  # (7, 3, 3) about each body's own CoM
    hand_pos_robot_m: Array
    rot_robot_from_hand: Array
    hand_pos_base_m: Array
    rot_base_from_hand: Array
    hand_pos_orbit_m: Array
    rot_orbit_from_hand: Array

    @property
    def n_joints(self) -> int:
        return int(self.body_mass_kg.shape[0]) - 1


def _twist_exponential(axis: Array, point: Array, angle_rad: float) -> Array:
    """4x4 rigid motion: rotation by ``angle_rad`` about the line through ``point``."""
    rot = rot_about_axis(axis, angle_rad)
    g = np.eye(4)
    g[:3, :3] = rot
    g[:3, 3] = (np.eye(3) - rot) @ point
    return g


def forward_kinematics(
    joints_rad: Array,
    quat_orbit_from_base_xyzw: Array,
    pos_base_orbit_m: Array,
    robot: RobotData = ETS7,
) -> Kinematics:
    """Every link frame and the hand by the product of exponentials (robot frame), then
    robot -> base (a translation, the frames are parallel) -> orbit."""
    joints = np.asarray(joints_rad, dtype=np.float64)
    n = robot.n_joints
    assert joints.shape == (n,), f"{n} joint angles expected, got shape {joints.shape}"
    joint_pos_robot = np.zeros((n, 3))
    joint_axis_robot = np.zeros((n, 3))
    com_robot = np.zeros((n, 3))
    rot_robot_from_link = np.zeros((n, 3, 3))
    g = np.eye(4)  # robot-frame motion of link i from its all-zero pose
    for i in range(n):
        # Joint i's point and axis are carried by joints 1 .. i-1 only.
        joint_pos_robot[i] = g[:3, :3] @ robot.joint_pos_robot_m[i] + g[:3, 3]
        joint_axis_robot[i] = g[:3, :3] @ robot.joint_axis_robot[i]
        g = g @ _twist_exponential(robot.joint_axis_robot[i], robot.joint_pos_robot_m[i], joints[i])
        rot_robot_from_link[i] = g[:3, :3]
        com_robot[i] = g[:3, :3] @ robot.link_com_robot_m[i] + g[:3, 3]
    hand_pos_robot = g[:3, :3] @ robot.hand_pos_robot_m + g[:3, 3]
    rot_robot_from_hand = g[:3, :3]  # the hand frame is parallel to the robot frame at zero

    rot_ob = matrix_from_quat_xyzw(quat_orbit_from_base_xyzw)
    pos_b = np.asarray(pos_base_orbit_m, dtype=np.float64)

    def robot_to_orbit(pos_robot_m: Array) -> Array:
        return pos_b + rot_ob @ (robot.pos_base_from_robot_m + pos_robot_m)

    link_inertia_orbit = [
        rot_ob @ r @ inertia @ r.T @ rot_ob.T
        for r, inertia in zip(
            rot_robot_from_link, robot.link_inertia_zero_pose_robot_kgm2, strict=True
        )
    ]
    return Kinematics(
        rot_orbit_from_base=rot_ob,
        pos_base_orbit_m=pos_b,
        joint_pos_orbit_m=np.array([robot_to_orbit(p) for p in joint_pos_robot]),
        joint_axis_orbit=joint_axis_robot @ rot_ob.T,
        body_mass_kg=np.concatenate([[robot.base_mass_kg], robot.link_mass_kg]),
        body_com_orbit_m=np.vstack([pos_b, [robot_to_orbit(c) for c in com_robot]]),
        body_inertia_com_orbit_kgm2=np.array(
            [rot_ob @ robot.base_inertia_kgm2 @ rot_ob.T, *link_inertia_orbit]
        ),
        hand_pos_robot_m=hand_pos_robot,
        rot_robot_from_hand=rot_robot_from_hand,
        hand_pos_base_m=robot.pos_base_from_robot_m + hand_pos_robot,
        rot_base_from_hand=rot_robot_from_hand,
        hand_pos_orbit_m=robot_to_orbit(hand_pos_robot),
        rot_orbit_from_hand=rot_ob @ rot_robot_from_hand,
    )


# --- composites and the inertia matrix, eq. (1) -------------------------------------------


@dataclass(frozen=True, eq=False)
class Composite:
    """Mass, CoM and inertia about that CoM (orbit frame) of a set of rigidly held bodies."""

    mass_kg: float
    com_orbit_m: Array
    inertia_com_orbit_kgm2: Array


def _merge(bodies: list[Composite]) -> Composite:
    mass = sum(b.mass_kg for b in bodies)
    com = sum(b.mass_kg * b.com_orbit_m for b in bodies) / mass
    inertia = sum(
        b.inertia_com_orbit_kgm2 + b.mass_kg * _parallel_axis(b.com_orbit_m - com) for b in bodies
    )
    return Composite(float(mass), np.asarray(com), np.asarray(inertia))


def _body(kin: Kinematics, b: int) -> Composite:
    return Composite(
        float(kin.body_mass_kg[b]), kin.body_com_orbit_m[b], kin.body_inertia_com_orbit_kgm2[b]
    )


def subtree_composites(kin: Kinematics) -> tuple[Composite, list[Composite]]:
    """The whole system, and for each joint j the composite of the links it moves (j .. 6),
    built from the hand inwards."""
    subtrees: list[Composite] = []
    outer: Composite | None = None
    for j in reversed(range(kin.n_joints)):
        link = _body(kin, j + 1)
        outer = link if outer is None else _merge([link, outer])
        subtrees.insert(0, outer)
    return _merge([_body(kin, 0), subtrees[0]]), subtrees


def _subtree_angular_momentum(
    sub: Composite, omega: Array, pivot_orbit_m: Array, about_orbit_m: Array
) -> Array:
    """Angular momentum about ``about`` of a composite spinning at ``omega`` about an axis
    through ``pivot`` (its CoM moves at ``omega x (c - pivot)``)."""
    vel = np.cross(omega, sub.com_orbit_m - pivot_orbit_m)
    return sub.inertia_com_orbit_kgm2 @ omega + sub.mass_kg * np.cross(
        sub.com_orbit_m - about_orbit_m, vel
    )


def inertia_matrix_crb(kin: Kinematics) -> Array:
    """Eq. (1)'s ``[[H_b, H_bm], [H_bm^T, H_m]]`` (12, 12) by the composite rigid body method.

    Entry (a, b) pairs the momentum that unit rate a gives the bodies moved by b with b's
    unit velocity field. Base columns move the whole system (translation; rotation about the
    base CoM); joint j moves its subtree about its axis, so for a <= j
    ``H_m[a, j] = k_j . L_a(subtree j, about joint j)``.
    """
    system, subtrees = subtree_composites(kin)
    p_b = kin.pos_base_orbit_m
    r = system.com_orbit_m - p_b
    m = system.mass_kg
    H = np.zeros((6 + kin.n_joints, 6 + kin.n_joints))
    H[:3, :3] = m * np.eye(3)
    H[:3, 3:6] = -m * skew(r)
    H[3:6, :3] = m * skew(r)
    H[3:6, 3:6] = system.inertia_com_orbit_kgm2 + m * _parallel_axis(r)
    k, o = kin.joint_axis_orbit, kin.joint_pos_orbit_m
    for j, sub in enumerate(subtrees):
        H[:3, 6 + j] = sub.mass_kg * np.cross(k[j], sub.com_orbit_m - o[j])
        H[3:6, 6 + j] = _subtree_angular_momentum(sub, k[j], o[j], p_b)
        for a in range(j + 1):
            H[6 + a, 6 + j] = k[j] @ _subtree_angular_momentum(sub, k[a], o[a], o[j])
    upper = np.triu(H)
    return upper + np.triu(H, 1).T


def _body_jacobians(kin: Kinematics, b: int) -> tuple[Array, Array]:
    """CoM linear (3, 12) and angular (3, 12) Jacobians of body ``b`` (0 = base)."""
    jac_lin = np.zeros((3, 6 + kin.n_joints))
    jac_ang = np.zeros((3, 6 + kin.n_joints))
    com = kin.body_com_orbit_m[b]
    jac_lin[:, :3] = np.eye(3)
    jac_lin[:, 3:6] = -skew(com - kin.pos_base_orbit_m)
    jac_ang[:, 3:6] = np.eye(3)
    for j in range(b):  # link b is moved by joints 1 .. b
        jac_lin[:, 6 + j] = np.cross(kin.joint_axis_orbit[j], com - kin.joint_pos_orbit_m[j])
        jac_ang[:, 6 + j] = kin.joint_axis_orbit[j]
    return jac_lin, jac_ang


def inertia_matrix_jacobian_sum(kin: Kinematics) -> Array:
    """Eq. (1)'s inertia matrix (12, 12) as ``sum_i m_i J_Ti^T J_Ti + J_Ri^T I_i J_Ri``."""
    H = np.zeros((6 + kin.n_joints, 6 + kin.n_joints))
    for b in range(kin.n_joints + 1):
        jac_lin, jac_ang = _body_jacobians(kin, b)
        H += kin.body_mass_kg[b] * jac_lin.T @ jac_lin
        H += jac_ang.T @ kin.body_inertia_com_orbit_kgm2[b] @ jac_ang
    return H


def hand_jacobians(kin: Kinematics) -> tuple[Array, Array]:
    """Eq. (6): ``J_b`` (6, 6) and ``J_m`` (6, 6); rows: hand-point velocity, hand angular
    velocity, orbit frame."""
    d = kin.hand_pos_orbit_m - kin.pos_base_orbit_m
    J_b = np.eye(6)
    J_b[:3, 3:6] = -skew(d)
    J_m = np.zeros((6, kin.n_joints))
    for j in range(kin.n_joints):
        k = kin.joint_axis_orbit[j]
        J_m[:3, j] = np.cross(k, kin.hand_pos_orbit_m - kin.joint_pos_orbit_m[j])
        J_m[3:, j] = k
    return J_b, J_m


# --- momentum, eq. (2)-(3) ----------------------------------------------------------------


def momenta(
    kin: Kinematics,
    vel_base_orbit_mps: Array,
    omega_base_orbit_radps: Array,
    joint_rates_radps: Array,
    wheel_rates_radps: Array,
    wheel_spin_inertia_kgm2: Array,
    wheel_axes_base: Array | None = None,
) -> tuple[Array, Array]:
    """Linear momentum and angular momentum about the system CoM (orbit frame), summed body
    by body from each body's own velocity, plus the rotors' spin relative to the base."""
    masses = kin.body_mass_kg
    n = kin.n_joints
    vel = np.zeros((n + 1, 3))
    omega = np.zeros((n + 1, 3))
    for b in range(n + 1):
        com = kin.body_com_orbit_m[b]
        omega[b] = omega_base_orbit_radps
        vel[b] = vel_base_orbit_mps + np.cross(omega_base_orbit_radps, com - kin.pos_base_orbit_m)
        for j in range(b):
            spin = kin.joint_axis_orbit[j] * joint_rates_radps[j]
            omega[b] += spin
            vel[b] += np.cross(spin, com - kin.joint_pos_orbit_m[j])
    linear = masses @ vel
    com_sys = masses @ kin.body_com_orbit_m / masses.sum()
    vel_sys = linear / masses.sum()
    angular = np.zeros(3)
    for b in range(n + 1):
        angular += kin.body_inertia_com_orbit_kgm2[b] @ omega[b]
        angular += masses[b] * np.cross(kin.body_com_orbit_m[b] - com_sys, vel[b] - vel_sys)
    # Rotor k spins along its axis (row k; default base axis k); its locked (rigid) part is
    # already in the base.
    axes_base = np.eye(3) if wheel_axes_base is None else np.asarray(wheel_axes_base)
    axes_orbit = kin.rot_orbit_from_base @ axes_base.T  # column k = rotor k's axis, orbit
    angular += axes_orbit @ (np.asarray(wheel_spin_inertia_kgm2) * wheel_rates_radps)
    return linear, angular


# --- gravity gradient, eq. (11) -----------------------------------------------------------


def gravity_gradient_torque_base_nm(
    inertia_com_base_kgm2: Array, rot_orbit_from_base: Array
) -> Array:
    """Eq. (11) ``N = 3 mu / R^5 r x (H_c r)`` in the base frame; ``r`` from the Earth's centre
    to the spacecraft, ``-R z_orbit`` (the orbit z axis is nadir)."""
    r_base_m = rot_orbit_from_base.T @ np.array([0.0, 0.0, -ORBIT_RADIUS_M])
    return 3.0 * MU_M3PS2 / ORBIT_RADIUS_M**5 * np.cross(r_base_m, inertia_com_base_kgm2 @ r_base_m)


# --- everything at one state --------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Reference:
    """The reference counterparts of :class:`planner.dynamics.Quantities` (orbit frame
    unless a name says otherwise), plus the second inertia matrix for the cross-check."""

    kinematics: Kinematics
    total_mass_kg: float
    com_orbit_m: Array
    J_b: Array
    J_m: Array
    H_crb: Array  # (12, 12) composite rigid body
    H_jacobian_sum: Array  # (12, 12) sum over bodies
    H_b: Array
    H_bm: Array
    H_m: Array
    linear_momentum_nms: Array
    angular_momentum_nms: Array
    H_b_tilde: Array
    H_bm_tilde: Array
    reaction_map: Array
    J_g: Array
    rns_projector: Array
    inertia_com_base_kgm2: Array
    gravity_gradient_torque_base_nm: Array


def evaluate(
    *,
    joints_rad: Array,
    quat_orbit_from_base_xyzw: Array,
    pos_base_orbit_m: Array,
    vel_base_orbit_mps: Array,
    omega_base_orbit_radps: Array,
    joint_rates_radps: Array,
    wheel_rates_radps: Array,
    wheel_spin_inertia_kgm2: Array,
    robot: RobotData = ETS7,
) -> Reference:
    """All reference quantities of ``robot`` at one state (SPEC eq. (1)-(3), (5), (8), (9),
    (11))."""
    kin = forward_kinematics(joints_rad, quat_orbit_from_base_xyzw, pos_base_orbit_m, robot)
    system, subtrees = subtree_composites(kin)
    H = inertia_matrix_crb(kin)
    H_b, H_bm, H_m = H[:6, :6], H[:6, 6:], H[6:, 6:]
    J_b, J_m = hand_jacobians(kin)
    linear, angular = momenta(
        kin,
        np.asarray(vel_base_orbit_mps),
        np.asarray(omega_base_orbit_radps),
        np.asarray(joint_rates_radps),
        np.asarray(wheel_rates_radps),
        np.asarray(wheel_spin_inertia_kgm2),
        robot.wheel_axes_base,
    )
    # Eq. (3): L about the system CoM. A base rotation turns the whole system rigidly
    # (H~_b = H_c); joint j turns its subtree about its axis.
    com = system.com_orbit_m
    H_b_tilde = system.inertia_com_orbit_kgm2
    H_bm_tilde = np.column_stack(
        [
            _subtree_angular_momentum(sub, kin.joint_axis_orbit[j], kin.joint_pos_orbit_m[j], com)
            for j, sub in enumerate(subtrees)
        ]
    )
    # Eq. (5): the projector onto the null space of H~_bm.
    rns_projector = np.eye(kin.n_joints) - np.linalg.pinv(H_bm_tilde) @ H_bm_tilde
    rot = kin.rot_orbit_from_base
    inertia_com_base = rot.T @ H_b_tilde @ rot
    return Reference(
        kinematics=kin,
        total_mass_kg=system.mass_kg,
        com_orbit_m=com,
        J_b=J_b,
        J_m=J_m,
        H_crb=H,
        H_jacobian_sum=inertia_matrix_jacobian_sum(kin),
        H_b=H_b,
        H_bm=H_bm,
        H_m=H_m,
        linear_momentum_nms=linear,
        angular_momentum_nms=angular,
        H_b_tilde=H_b_tilde,
        H_bm_tilde=H_bm_tilde,
        reaction_map=-np.linalg.inv(H_b_tilde) @ H_bm_tilde,  # eq. (9)
        J_g=J_m - J_b @ np.linalg.inv(H_b) @ H_bm,  # eq. (8)
        rns_projector=rns_projector,
        inertia_com_base_kgm2=inertia_com_base,
        gravity_gradient_torque_base_nm=gravity_gradient_torque_base_nm(inertia_com_base, rot),
    )
