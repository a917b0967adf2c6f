"""A description's TOML tables ([[wheels]], [servo], [sensor_noise], [poses], [experiments],
[limits]) checked and turned into the values of :mod:`planner.robot`; works on the parsed
document."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.catalogue import experiments, parameters_from_values
from planner.description.checks import NAME, WHEEL_NAMES, Checker, frozen
from planner.dynamics import DynamicsWorkspace
from planner.errors import InvalidInput
from planner.limits import Limits
from planner.model import WheelSpec
from planner.robot import (
    DEFAULT_SERVO_BANDWIDTH_RADPS,
    DEFAULT_SERVO_LAG_S,
    NamedPose,
    SensorNoiseSpec,
    ServoSpec,
    WheelLimits,
)
from planner.state import State

__all__ = [
    "DEFAULT_NOISE_DEG",
    "DEFAULT_ROTOR_MASS_KG",
    "TOP_KEYS",
    "Header",
    "experiments_from",
    "head_from",
    "limits_from",
    "poses_from",
    "sensor_noise_from",
    "servo_from",
    "wheels_from",
]

Array = NDArray[np.float64]

#: Defaults where a description leaves a value out (the values ETS-VII uses).
DEFAULT_ROTOR_MASS_KG = 1e-3
DEFAULT_NOISE_DEG = {"attitude_deg": 0.005, "rate_degps": 0.0005, "joint_deg": 0.005}
#: A pose given both as joints and as a hand pose must agree this well.
POSE_CHECK_M = 0.01
POSE_CHECK_DEG = 1.0
#: Three wheel axes must span space: |det| of the unit axes at least this.
MIN_WHEEL_AXES_DET = 0.1

TOP_KEYS = frozenset(
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
        "flight_rules",
        "limits",
        "hand",
        "reference_pose",
        "base",
        "locked_joints",
        "mission_limits",
        "urdf_collision",
        "generated_collision",
        "packages",
    }
)
_WHEEL_KEYS = frozenset(
    {"axis", "spin_inertia_kgm2", "rotor_mass_kg", "torque_limit_nm", "momentum_limit_nms"}
)
_POSE_KEYS = frozenset({"description", "joints_deg", "hand_pos_robot_m", "hand_rpy_deg"})
_SERVO_KEYS = frozenset({"bandwidth_radps", "lag_s", "kp_nm_per_rad", "kd_nms_per_rad"})


def wheels_from(c: Checker, value: object) -> tuple[tuple[WheelSpec, ...], tuple[WheelLimits, ...]]:
    if not isinstance(value, list) or len(value) != len(WHEEL_NAMES):
        raise c.fail("[[wheels]]", f"exactly {len(WHEEL_NAMES)} wheels are needed")
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
                name=WHEEL_NAMES[k],
                axis_base=frozen(axis / norm),
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


def servo_from(c: Checker, value: object, n: int) -> ServoSpec:
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
        return ServoSpec(kp_nm_per_rad=frozen(kp), kd_nms_per_rad=frozen(kd))
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
    c: Checker, element: str, value: object, n: int, *, positive: bool = False
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
        return frozen(np.array([check(f"{element}[{i}]", v) for i, v in enumerate(value)]))
    return check(element, value)


def sensor_noise_from(c: Checker, value: object) -> SensorNoiseSpec:
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


def poses_from(c: Checker, value: object, ws: DynamicsWorkspace) -> dict[str, NamedPose]:
    model = ws.model
    poses: dict[str, NamedPose] = {}
    for name, item in c.table("[poses]", value).items():
        where = f"[poses.{name}]"
        if not NAME.match(name):
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
            joints_rad=None if joints is None else frozen(joints),
            hand_pos_robot_m=(
                frozen(c.numbers(f"{where} hand_pos_robot_m", table["hand_pos_robot_m"], 3))
                if hand
                else None
            ),
            hand_rpy_deg=(
                frozen(c.numbers(f"{where} hand_rpy_deg", table["hand_rpy_deg"], 3))
                if hand
                else None
            ),
        )
        if joints is not None and hand:
            _check_pose(c, where, pose, ws)
        poses[name] = pose
    return poses


def _check_pose(c: Checker, where: str, pose: NamedPose, ws: DynamicsWorkspace) -> None:
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


def experiments_from(c: Checker, value: object, n: int) -> dict[str, Mapping[str, object]]:
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


def limits_from(c: Checker, value: object) -> Limits:
    """The ``[limits]`` table over the built-in bands (planner.limits.DEFAULT_LIMITS for
    every quantity it leaves out)."""
    table = c.table("[limits]", value)
    try:
        return Limits.from_table(table)
    except InvalidInput as exc:
        element, _, problem = str(exc).partition(": ")
        raise c.fail(element, problem) from None


@dataclass(frozen=True)
class Header:
    """What a description must say before its URDF is read: its name, the URDF's path, the
    base link and the wheels."""

    name: str
    urdf_path: Path
    base_link: str
    wheels: tuple[WheelSpec, ...]
    wheel_limits: tuple[WheelLimits, ...]


def head_from(c: Checker, doc: Mapping[str, Any], locate: Callable[[str], Path]) -> Header:
    """The document's keys checked, and its :class:`Header`. ``urdf`` must be a relative
    path; ``locate`` turns it into the URDF's path (refusing one outside the description's
    folder: a file-system question, :func:`planner.description.files.urdf_path_of`)."""
    c.keys("document", doc, TOP_KEYS)
    for key in ("name", "urdf", "base_link", "wheels"):
        if key not in doc:
            raise c.fail(key, "missing")
    name = c.text("name", doc["name"])
    if not NAME.match(name):
        raise c.fail("name", f"{name!r}: letters, digits, '_', '-' or '.' (up to 64)")
    urdf_name = c.text("urdf", doc["urdf"])
    if not urdf_name or Path(urdf_name).is_absolute():
        raise c.fail("urdf", f"{urdf_name!r} must be a path relative to the description")
    urdf_path = locate(urdf_name)
    base_link = c.text("base_link", doc["base_link"])
    wheels, wheel_limits = wheels_from(c, doc["wheels"])
    return Header(name, urdf_path, base_link, wheels, wheel_limits)
