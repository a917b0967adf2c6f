"""A description scaffold for a vendor's arm: ``hikoboshi robot init`` (docs/robots.md,
"Starting from a vendor's URDF").

From a URDF (read unchanged), the hand frame's link and a cube the arm is mounted on, this
module chooses what a description needs and a URDF cannot say, and writes it as TOML text:

- **the base**: a uniform cube of ``base_mass_kg`` and ``base_size_m``, the URDF's root on
  the centre of its +z face;
- **mission limits** inside the vendor's, a space arm's joint rates, **servos** that the
  integrator holds and **wheels** sized from the arm's reaction momentum
  (:mod:`planner.description.scaffold_sizing`);
- **named poses** A (the reference pose), B and C, away from singularities and clear of the
  arm's own bodies, found by sampling (:mod:`planner.description.scaffold_poses`);
- the memoryless PD **attitude law** of the shipped small robot (Orihime's);
- the **experiments' defaults**: PTP A -> B, reactionless from B along the chosen direction,
  GJM from A with the chosen hand pitch, coordination's line length, the non-holonomic
  motion from an offset of A back to A, the first offset whose plan passes the flight rules
  (:mod:`planner.description.scaffold_experiments`);
- **every experiment as written** is then planned and checked against the flight rules; the
  verdicts are in the report (``experiments``) and, for an experiment that fails, on the
  command line's stderr.

Everything is computed on the model the description will load to; the text
(:mod:`planner.description.scaffold_text`) is then built by
:func:`planner.description.build.build_robot` from its own parse, so a scaffold that does
not load is never returned. Our choices, not a vendor's; each is written as a comment beside
its key.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from planner.description.build import build_robot, model_from_urdf
from planner.description.checks import NAME, Checker
from planner.description.files import read_limited
from planner.description.reduce import Mount
from planner.description.scaffold_experiments import (
    check_experiments,
    choose_nonholonomic,
    nonholonomic_candidates,
)
from planner.description.scaffold_poses import (
    POSE_SAMPLES,
    choose_a,
    choose_b,
    sample_poses,
    scaled_sigma,
)
from planner.description.scaffold_sizing import mission_limits, servo_design, wheel_sizing
from planner.description.scaffold_text import render
from planner.description.tables import head_from
from planner.description.urdf_xml import Urdf
from planner.dynamics import DynamicsWorkspace
from planner.model import WheelSpec
from planner.robot import RobotDescription
from planner.scaffold_defaults import DEFAULT_BASE_MASS_KG, DEFAULT_BASE_SIZE_M
from planner.state import State

__all__ = [
    "DEFAULT_BASE_MASS_KG",
    "DEFAULT_BASE_SIZE_M",
    "Scaffold",
    "scaffold_description",
]


@dataclass(frozen=True)
class Scaffold:
    """The description's text and what was chosen (``report``: JSON-able)."""

    toml: str
    report: dict[str, Any]
    description: RobotDescription


def _root_link(urdf: Urdf) -> str:
    roots = [name for name in urdf.links if name not in urdf.parent_joint]
    if len(roots) != 1:
        raise urdf.c.fail("document", f"a URDF is one tree with one root link, found {roots}")
    return roots[0]


def scaffold_description(
    urdf_path: Path,
    hand: str,
    *,
    out_path: Path,
    urdf_name: str,
    name: str | None = None,
    base_mass_kg: float = DEFAULT_BASE_MASS_KG,
    base_size_m: float = DEFAULT_BASE_SIZE_M,
) -> Scaffold:
    """The description of the arm in ``urdf_path`` on a cube (see the module doc), as the
    text of ``out_path`` naming the URDF ``urdf_name`` beside it. Raises
    :class:`InvalidRobotDescription` naming the file and the element when the URDF cannot
    be loaded or no pose fits."""
    c = Checker(out_path)
    if not (math.isfinite(base_mass_kg) and base_mass_kg > 0):
        raise c.fail("--base-mass", f"must be a positive mass in kg, got {base_mass_kg}")
    if not (math.isfinite(base_size_m) and base_size_m > 0):
        raise c.fail("--base-size", f"must be a positive length in m, got {base_size_m}")
    robot_name = name if name is not None else out_path.stem
    if not NAME.match(robot_name):
        raise c.fail("name", f"{robot_name!r}: letters, digits, '_', '-' or '.' (up to 64)")
    urdf = Urdf(urdf_path, read_limited(urdf_path, "URDF"))
    root = _root_link(urdf)
    urdf.check_tree(root)
    if hand not in urdf.links:
        raise urdf.c.fail(f"link {hand!r}", f"--hand names no link of the URDF ({root!r} ...)")
    mount = Mount(
        mass_kg=base_mass_kg,
        size_m=(base_size_m,) * 3,
        rot_base_from_root=None,
        pos_base_from_root_m=np.array([0.0, 0.0, 0.5 * base_size_m]),
    )
    placeholder = tuple(
        WheelSpec(name=f"wheel_{a}", axis_base=np.eye(3)[k], spin_inertia_kgm2=0.01, mass_kg=1e-3)
        for k, a in enumerate("xyz")
    )
    model, red = model_from_urdf(urdf, root, placeholder, hand=hand, mount=mount)
    limits, rates = mission_limits(red.vendor_limit_rad, red.vendor_rate_radps)
    n = model.n_joints
    model = replace(model, joint_limit_rad=limits, joint_rate_limit_radps=rates)
    ws = DynamicsWorkspace(model)

    sampled = sample_poses(
        c, model, ws, limits, rates, root=root, base_size_m=base_size_m, pos_j1_m=red.pos_j1_m
    )
    lo, hi, reach_m, clearance = sampled.lo, sampled.hi, sampled.reach_m, sampled.clearance
    qa, pitch = choose_a(c, ws, sampled)
    qb, direction_label, distance, rpath, speed = choose_b(c, ws, sampled, qa, rates)
    joined = clearance.joined_at(qa)
    qc = rpath.joints_rad[-1]
    model = replace(model, reference_joints_rad=qa)
    ws = DynamicsWorkspace(model)
    poses = {"A": qa, "B": qb, "C": qc}
    bandwidth, lag, unit_modes, modes = servo_design(model, ws, poses)
    wheels = wheel_sizing(model, ws, qa, qb, sampled.reaction_bound_nms)
    capacity, torque = wheels.momentum_limit_nms, wheels.torque_limit_nm
    spin, rotor = wheels.spin_inertia_kgm2, wheels.rotor_mass_kg

    # --- experiments ---------------------------------------------------------------------------
    phi_init = np.clip(qa + np.radians(nonholonomic_candidates(n)[0][1]), lo, hi)
    choice = {
        "reach_m": reach_m,
        "pose_samples": POSE_SAMPLES,
        "sigma_min_Jg": {
            k: scaled_sigma(ws.evaluate(State(joints_rad=q)).J_g, reach_m) for k, q in poses.items()
        },
        "clearance_m": {k: clearance.clear(q, joined) for k, q in poses.items()},
        "gjm_hand_pitch_deg": pitch,
        "reactionless_direction": direction_label,
        "reactionless_distance_m": distance,
        "reactionless_speed_mps": speed,
        "reaction_momentum_bound_nms": sampled.reaction_bound_nms,
        "ptp_reaction_momentum_peak_nms": wheels.ptp_peak_nms,
        "ptp_reaction_torque_peak_nm": wheels.ptp_torque_nm,
        "servo_unit_fastest_per_s": unit_modes.fastest_per_s,
        "servo_fastest_per_s": modes.fastest_per_s,
        "servo_limit_per_s": modes.limit_per_s,
    }
    written = dict(
        name=robot_name,
        urdf_name=urdf_name,
        root=root,
        hand=hand,
        base_mass_kg=base_mass_kg,
        base_size_m=base_size_m,
        joint_names=red.joint_names,
        vendor=red.vendor_limit_rad,
        vendor_rate=red.vendor_rate_radps,
        limits=limits,
        rates=rates,
        poses=poses,
        bandwidth=bandwidth,
        lag=lag,
        capacity=capacity,
        torque=torque,
        spin=spin,
        rotor=rotor,
        choice=choice,
    )
    # a first description (ETS-VII's offsets) to plan the non-holonomic candidates on; the
    # model and the flight rules are the final description's
    doc = tomllib.loads(render(**written, phi_init=phi_init))
    head = head_from(c, doc, lambda _name: urdf_path)
    description = build_robot(c, doc, head, urdf, {})
    nonholonomic = choose_nonholonomic(description, qa, lo, hi)
    phi_init = np.radians(nonholonomic["phi_init_deg"])
    doc = tomllib.loads(render(**written, phi_init=phi_init, nonholonomic=nonholonomic))
    head = head_from(c, doc, lambda _name: urdf_path)
    description = build_robot(c, doc, head, urdf, {})
    checked = check_experiments(description)
    # the verdicts go into comments only: the values, and so the description, are unchanged
    text = render(**written, phi_init=phi_init, nonholonomic=nonholonomic, checked=checked)
    if tomllib.loads(text) != doc:
        raise c.fail("document", "the scaffold's text changed between its check and its writing")
    report = {
        "robot": robot_name,
        "file": str(out_path),
        "urdf": urdf_name,
        "base_link": root,
        "hand": hand,
        "n_joints": n,
        "poses_deg": {k: np.degrees(q).tolist() for k, q in poses.items()},
        "servo": {"bandwidth_radps": bandwidth, "lag_s": lag},
        "wheels": {
            "momentum_limit_nms": capacity,
            "torque_limit_nm": torque,
            "spin_inertia_kgm2": spin,
            "rotor_mass_kg": rotor,
        },
        **choice,
        "nonholonomic": {k: v for k, v in nonholonomic.items() if k != "tried"},
        "nonholonomic_tried": nonholonomic["tried"],
        "experiments": checked,
        "failing_experiments": [e for e, row in checked.items() if not row["passed"]],
    }
    return Scaffold(toml=text, report=report, description=description)
