"""The canonical description of the ETS-VII satellite and its arm (SPEC sections 1.1, 6 and 7).

Everything else is derived from :class:`RobotModel`: the MuJoCo model (:mod:`planner.mjcf`),
the URDF export (:mod:`planner.urdf`) and the dynamics quantities (:mod:`planner.dynamics`).

Frames (SPEC section 7):

- *base*: origin at the base centre of mass; x flight direction (roll), z nadir, y pitch axis.
- *robot*: origin at joint 1, at ``pos_base_from_robot_m`` in the base frame, axes parallel
  to the base frame.
- *link i*: the body moved by joint i. Its MuJoCo/URDF body frame has its origin on joint i
  and is parallel to the robot frame at the all-zero pose. Table 1 gives each link's inertia
  in its *inertia frame* (z along joint i's axis, x along the part of joint i -> joint i+1
  perpendicular to z); :attr:`LinkSpec.rot_robot_from_inertia` holds that frame.
- *hand*: origin at the hand point, parallel to the robot frame at the all-zero pose, on link 6
  (another robot's hand may be turned: :attr:`RobotModel.rot_robot_from_hand`).

Reaction wheels are three rotors at the base centre of mass with axes along base x, y, z.
Their masses are inside Table 1's base numbers: the *locked* base (wheels not spinning
relative to it) has exactly Table 1's mass and inertia. MuJoCo needs each rotor as a body of
its own, so the base body carries Table 1 minus the rotors (see :func:`base_body_inertial`).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from planner.errors import InvalidInput

__all__ = [
    "INERTIA_PRODUCT_SIGN",
    "LinkSpec",
    "RobotModel",
    "WheelSpec",
    "arm_reach_m",
    "base_body_inertial",
    "default_model",
    "inertia_matrix",
]

Array = NDArray[np.float64]

# The one place that decides how Table 1's products of inertia enter the matrix (SPEC 1.1):
# +1 puts them in as written, [[Ixx, Ixy, Ixz], [Ixy, Iyy, Iyz], [Ixz, Iyz, Izz]].
# Flip to -1 for the [[Ixx, -Ixy, ...]] convention.
INERTIA_PRODUCT_SIGN = 1.0


def inertia_matrix(
    ixx: float, iyy: float, izz: float, ixy: float = 0.0, ixz: float = 0.0, iyz: float = 0.0
) -> Array:
    """3x3 inertia matrix (kg m^2) from Table 1's six numbers, per :data:`INERTIA_PRODUCT_SIGN`."""
    s = INERTIA_PRODUCT_SIGN
    return np.array(
        [[ixx, s * ixy, s * ixz], [s * ixy, iyy, s * iyz], [s * ixz, s * iyz, izz]],
        dtype=np.float64,
    )


def _frozen(a: Array) -> Array:
    out = np.array(a, dtype=np.float64)
    out.setflags(write=False)
    return out


@dataclass(frozen=True, eq=False)
class LinkSpec:
    """One arm link and the joint that moves it, all at the all-zero pose in the robot frame."""

    name: str
    joint_pos_robot_m: Array
    joint_axis_robot: Array
    mass_kg: float
    com_robot_m: Array
    inertia_com_inertia_frame_kgm2: Array  # Table 1, about the CoM, in the inertia frame
    rot_robot_from_inertia: Array

    @property
    def inertia_com_robot_kgm2(self) -> Array:
        """Inertia about the CoM with robot-frame axes (at the all-zero pose)."""
        r = self.rot_robot_from_inertia
        return np.asarray(r @ self.inertia_com_inertia_frame_kgm2 @ r.T)


@dataclass(frozen=True, eq=False)
class WheelSpec:
    """A reaction-wheel rotor at the base centre of mass."""

    name: str
    axis_base: Array
    spin_inertia_kgm2: float
    mass_kg: float  # a token mass: MuJoCo needs one for a moving body

    @property
    def rigid_inertia_base_kgm2(self) -> Array:
        """The rotor as a rigid thin disc: spin inertia on its axis, half of it across."""
        a = self.axis_base
        i_s = self.spin_inertia_kgm2
        return np.asarray(0.5 * i_s * np.eye(3) + 0.5 * i_s * np.outer(a, a))


@dataclass(frozen=True, eq=False)
class RobotModel:
    """Fixed parameters of the satellite, its arm and its wheels (SI units)."""

    base_mass_kg: float
    base_inertia_kgm2: Array  # locked base (wheels included), about the base CoM, base frame
    pos_base_from_robot_m: Array  # robot frame origin (joint 1) in the base frame
    links: tuple[LinkSpec, ...]
    hand_pos_robot_m: Array  # hand point at the all-zero pose
    wheels: tuple[WheelSpec, ...]
    joint_limit_rad: Array  # (n, 2): lower, upper
    joint_rate_limit_radps: Array  # (n,)
    #: the hand frame's axes in the robot frame at the all-zero pose (None: parallel to it)
    rot_robot_from_hand: Array | None = None
    #: the planners' reference pose (None: all zeros); inside the joint limits
    reference_joints_rad: Array | None = None

    @property
    def n_joints(self) -> int:
        return len(self.links)

    @property
    def reference_joints(self) -> Array:
        """The planners' reference pose: ``reference_joints_rad``, or all zeros (ETS-VII's
        and every robot's whose limits contain 0 and that names no other)."""
        if self.reference_joints_rad is None:
            return np.zeros(self.n_joints)
        return np.array(self.reference_joints_rad, dtype=np.float64)

    @property
    def total_mass_kg(self) -> float:
        return float(self.base_mass_kg + sum(link.mass_kg for link in self.links))

    def with_base_inertia(self, inertia_kgm2: Array) -> RobotModel:
        """The same model with another (locked) base inertia, e.g. an identified one."""
        inertia = _frozen(inertia_kgm2)
        if inertia.shape != (3, 3) or not np.allclose(inertia, inertia.T):
            raise InvalidInput(f"base inertia must be a symmetric 3x3 matrix, got {inertia!r}")
        return replace(self, base_inertia_kgm2=inertia)

    def check_joints(self, joints_rad: Array) -> Array:
        """``joints_rad`` as a float array of shape (n,), or a domain error naming the joint."""
        from planner.errors import JointLimitExceeded

        q = np.asarray(joints_rad, dtype=np.float64)
        if q.shape != (self.n_joints,):
            raise InvalidInput(f"expected {self.n_joints} joint angles, got shape {q.shape}")
        if not np.all(np.isfinite(q)):
            raise InvalidInput(f"joint angles must be finite, got {q.tolist()}")
        for i, (angle, (lo, hi)) in enumerate(zip(q, self.joint_limit_rad, strict=True)):
            if angle < lo or angle > hi:
                limit = hi if angle > hi else lo
                raise JointLimitExceeded(i + 1, np.degrees(angle), np.degrees(limit), "deg")
        return q


def base_body_inertial(model: RobotModel) -> tuple[float, Array]:
    """Mass and inertia (about the base CoM, base frame) of the base body *without* rotors."""
    mass = model.base_mass_kg - sum(w.mass_kg for w in model.wheels)
    inertia = model.base_inertia_kgm2 - sum(
        (w.rigid_inertia_base_kgm2 for w in model.wheels), np.zeros((3, 3))
    )
    return float(mass), np.asarray(inertia)


# --- SPEC tables -----------------------------------------------------------------------

# Table 1, base: m0, Ixx, Iyy, Izz, Ixy, Ixz, Iyz
_BASE_TABLE = (2550.0, 6200.0, 3540.0, 7090.0, 48.2, 120.0, -29.2)

# Table 1, links: m, Ixx, Iyy, Izz, Ixy, Ixz, Iyz (about each link's CoM, in its inertia frame)
_LINK_TABLE = (
    (35.0, 0.25, 0.25, 1.69, 0.0, 0.0, 0.0),
    (22.5, 0.10, 1.31, 3.75, 0.0, 0.0, 0.0),
    (21.9, 0.10, 0.71, 2.53, 0.0, 0.0, 0.0),
    (16.5, 0.15, 0.15, 0.07, 0.0, 0.0, 0.0),
    (26.0, 0.15, 0.15, 0.13, 0.0, 0.0, 0.0),
    (18.5, 0.97, 0.97, 0.26, 0.0, 0.0, 0.0),
)

# SPEC section 7: joints at the all-zero pose in the robot frame.
_JOINT_POS_ROBOT_M = (
    (0.0, 0.0, 0.0),
    (0.0, -0.275, 0.350),
    (0.0, -0.275, 1.220),
    (0.630, -0.550, 1.220),
    (0.630, -0.267, 1.220),
    (0.630, -0.267, 1.497),
)
_JOINT_AXIS_ROBOT = ((0, 0, 1), (0, 1, 0), (0, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 0))
_HAND_POS_ROBOT_M = (1.162, -0.267, 1.497)
_POS_BASE_FROM_ROBOT_M = (-0.785, -0.295, 1.000)

# SPEC section 6 (our choice): +-170 deg on every joint, 3 deg/s.
_JOINT_LIMIT_DEG = 170.0
_JOINT_RATE_LIMIT_DEGPS = 3.0

# Our choice (SPEC 6 leaves wheels unpublished): 0.15 kg m^2 rotors, a 0.6 m disc of ~7 kg.
DEFAULT_WHEEL_SPIN_INERTIA_KGM2 = 0.15
_WHEEL_TOKEN_MASS_KG = 1e-3


def _inertia_frame(axis: Array, to_next: Array) -> Array:
    """``rot_robot_from_inertia``: z along the joint axis, x along the perpendicular part of
    the vector to the next joint. Where that part vanishes (links 4-6, whose Table 1 inertia
    is symmetric about z, so x does not matter) x is the robot axis least aligned with z."""
    z = axis / np.linalg.norm(axis)
    perp = to_next - np.dot(to_next, z) * z
    if np.linalg.norm(perp) < 1e-9:
        perp = np.eye(3)[int(np.argmin(np.abs(z)))]
        perp = perp - np.dot(perp, z) * z
    x = perp / np.linalg.norm(perp)
    y = np.cross(z, x)
    return np.column_stack([x, y, z])


def default_model(
    *,
    wheel_spin_inertia_kgm2: float = DEFAULT_WHEEL_SPIN_INERTIA_KGM2,
    joint_limit_deg: float = _JOINT_LIMIT_DEG,
    joint_rate_limit_degps: float = _JOINT_RATE_LIMIT_DEGPS,
) -> RobotModel:
    """ETS-VII as SPEC sections 1.1, 6 and 7 define it."""
    joint_pos = np.array(_JOINT_POS_ROBOT_M, dtype=np.float64)
    ends = np.vstack([joint_pos[1:], np.array(_HAND_POS_ROBOT_M)])
    links = []
    for i, (row, axis) in enumerate(zip(_LINK_TABLE, _JOINT_AXIS_ROBOT, strict=True)):
        mass, *inertia = row
        axis_arr = np.array(axis, dtype=np.float64)
        links.append(
            LinkSpec(
                name=f"link{i + 1}",
                joint_pos_robot_m=_frozen(joint_pos[i]),
                joint_axis_robot=_frozen(axis_arr),
                mass_kg=mass,
                com_robot_m=_frozen(0.5 * (joint_pos[i] + ends[i])),
                inertia_com_inertia_frame_kgm2=_frozen(inertia_matrix(*inertia)),
                rot_robot_from_inertia=_frozen(_inertia_frame(axis_arr, ends[i] - joint_pos[i])),
            )
        )
    wheels = tuple(
        WheelSpec(
            name=f"wheel_{name}",
            axis_base=_frozen(np.eye(3)[k]),
            spin_inertia_kgm2=wheel_spin_inertia_kgm2,
            mass_kg=_WHEEL_TOKEN_MASS_KG,
        )
        for k, name in enumerate("xyz")
    )
    m0, *base_inertia = _BASE_TABLE
    n = len(links)
    limit = np.radians(joint_limit_deg)
    return RobotModel(
        base_mass_kg=m0,
        base_inertia_kgm2=_frozen(inertia_matrix(*base_inertia)),
        pos_base_from_robot_m=_frozen(np.array(_POS_BASE_FROM_ROBOT_M)),
        links=tuple(links),
        hand_pos_robot_m=_frozen(np.array(_HAND_POS_ROBOT_M)),
        wheels=wheels,
        joint_limit_rad=_frozen(np.tile([-limit, limit], (n, 1))),
        joint_rate_limit_radps=_frozen(np.full(n, np.radians(joint_rate_limit_degps))),
    )


def arm_reach_m(model: RobotModel) -> float:
    """The arm's reach: the lengths of the segments from joint 2 to the hand point at the
    all-zero pose (as :func:`planner.ik.solve_ik` bounds a target; ETS-VII 2.649 m, the
    test UR5 1.104 m and Panda 1.090 m, as loaded from tests/planner/vendor/)."""
    points = [link.joint_pos_robot_m for link in model.links] + [model.hand_pos_robot_m]
    return sum(float(np.linalg.norm(b - a)) for a, b in itertools.pairwise(points[1:]))
