"""A description's keys for a vendor's URDF loaded unchanged: ``hand`` (the hand frame),
``reference_pose``, ``[base]`` (the mount the arm sits on), ``[locked_joints]`` (tool joints'
positions) and ``[mission_limits]`` (the planners' joint limits inside the vendor's);
checked on the parsed TOML. docs/robots.md, "A vendor's URDF"."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from planner.description.checks import Checker, frozen
from planner.description.reduce import Mount
from planner.description.urdf_xml import Urdf, rpy_matrix

__all__ = ["locked_from", "mission_limits_from", "mount_from"]

Array = NDArray[np.float64]

_MOUNT_KEYS = frozenset({"mass_kg", "size_m", "mount_xyz_m", "mount_rpy_deg"})
_LOCK_KEYS = frozenset({"position_m", "position_deg"})
_MISSION_KEYS = frozenset({"angle_deg", "rate_degps"})


def mount_from(c: Checker, value: object) -> Mount | None:
    """``[base]``: a uniform box of ``mass_kg`` and ``size_m`` (its centre the base
    reference), the URDF's root at ``mount_xyz_m`` / ``mount_rpy_deg`` on it."""
    if value is None:
        return None
    table = c.table("[base]", value)
    c.keys("[base]", table, _MOUNT_KEYS)
    for key in ("mass_kg", "size_m", "mount_xyz_m"):
        if key not in table:
            raise c.fail("[base]", f"missing {key}")
    mass = c.number("[base] mass_kg", table["mass_kg"], positive=True)
    size = c.numbers("[base] size_m", table["size_m"], 3)
    if np.any(size <= 0.0):
        raise c.fail("[base] size_m", f"must be 3 positive lengths, got {table['size_m']!r}")
    pos = c.numbers("[base] mount_xyz_m", table["mount_xyz_m"], 3)
    rpy = c.numbers("[base] mount_rpy_deg", table.get("mount_rpy_deg", [0.0, 0.0, 0.0]), 3)
    rot = None if not np.any(rpy) else rpy_matrix(np.radians(rpy))
    return Mount(
        mass_kg=mass,
        size_m=(float(size[0]), float(size[1]), float(size[2])),
        rot_base_from_root=None if rot is None else frozen(rot),
        pos_base_from_root_m=frozen(pos),
    )


def locked_from(c: Checker, value: object, urdf: Urdf) -> dict[str, float]:
    """``[locked_joints.NAME]``: ``position_m`` for a prismatic joint, ``position_deg`` for a
    revolute or continuous one; returned in metres or radians by joint name."""
    out: dict[str, float] = {}
    for name, item in c.table("[locked_joints]", value).items():
        where = f"[locked_joints.{name}]"
        table = c.table(where, item)
        c.keys(where, table, _LOCK_KEYS)
        joint = urdf.joints.get(name)
        if joint is None:
            raise c.fail(where, f"names no joint of the URDF (joints: {sorted(urdf.joints)})")
        key = "position_m" if joint.get("type") == "prismatic" else "position_deg"
        if set(table) != {key}:
            raise c.fail(where, f"a {joint.get('type')} joint is locked by {key} alone")
        number = c.number(f"{where} {key}", table[key])
        out[name] = number if key == "position_m" else math.radians(number)
    return out


def mission_limits_from(
    c: Checker,
    value: object,
    joint_names: Sequence[str],
    vendor_limit_rad: Array,
    vendor_rate_radps: Array,
) -> tuple[Array, Array]:
    """``[mission_limits]``: the planners' joint limits, each inside the vendor's.

    ``angle_deg``: a table of arm joint name -> ``[lower, upper]``; ``rate_degps``: one
    number for every joint or n. Joints it leaves out keep the vendor's limits."""
    limits = np.array(vendor_limit_rad, dtype=np.float64)
    rates = np.array(vendor_rate_radps, dtype=np.float64)
    table = c.table("[mission_limits]", value)
    c.keys("[mission_limits]", table, _MISSION_KEYS)
    angles: Mapping[str, object] = c.table("[mission_limits] angle_deg", table.get("angle_deg", {}))
    for name, pair in angles.items():
        where = f"[mission_limits] angle_deg.{name}"
        if name not in joint_names:
            raise c.fail(where, f"not an arm joint (the arm joints: {list(joint_names)})")
        lo_deg, hi_deg = (float(v) for v in c.numbers(where, pair, 2))
        if not lo_deg < hi_deg:
            raise c.fail(where, f"lower {lo_deg:.6g} must be below upper {hi_deg:.6g} deg")
        i = list(joint_names).index(name)
        vlo, vhi = (math.degrees(v) for v in vendor_limit_rad[i])
        if lo_deg < vlo - 1e-9 or hi_deg > vhi + 1e-9:
            raise c.fail(
                where,
                f"[{lo_deg:.6g}, {hi_deg:.6g}] deg leaves joint {name!r}'s vendor limits "
                f"[{vlo:.6g}, {vhi:.6g}] deg: the mission's limits must lie inside them",
            )
        limits[i] = (math.radians(lo_deg), math.radians(hi_deg))
    if "rate_degps" in table:
        raw = table["rate_degps"]
        n = len(joint_names)
        values = (
            c.numbers("[mission_limits] rate_degps", raw, n)
            if isinstance(raw, list)
            else np.full(n, c.number("[mission_limits] rate_degps", raw))
        )
        for i, (rate, name) in enumerate(zip(values, joint_names, strict=True)):
            where = (
                f"[mission_limits] rate_degps[{i}]"
                if isinstance(raw, list)
                else ("[mission_limits] rate_degps")
            )
            vendor = math.degrees(vendor_rate_radps[i])
            if not rate > 0.0:
                raise c.fail(where, f"must be > 0 deg/s, got {rate:.6g}")
            if rate > vendor + 1e-9:
                raise c.fail(
                    where,
                    f"{rate:.6g} deg/s exceeds joint {name!r}'s vendor rate limit "
                    f"{vendor:.6g} deg/s: the mission's limits must lie inside the vendor's",
                )
            rates[i] = math.radians(rate)
    return limits, rates
