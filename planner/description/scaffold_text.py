"""A scaffold's TOML text (``hikoboshi robot init``, :mod:`planner.description.scaffold`):
every value the scaffold chose, each with the reason beside it as a comment, and the
experiments' verdicts against the flight rules above them.

:func:`render` takes the choices as keywords (the ``written`` values of
:func:`planner.description.scaffold.scaffold_description`, the non-holonomic start and,
once checked, the verdicts); the numbers are written to a few significant digits so that
the text reads well and parses back to the values the scaffold checked.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from planner.description.scaffold_experiments import NONHOLONOMIC_SCALES
from planner.description.scaffold_poses import (
    CAPSULE_RADIUS_M,
    COORDINATION_DISTANCE_M,
    DIRECTIONS,
    GJM_DISTANCE_M,
    HAND_RADIUS_M,
    MIN_CLEARANCE_M,
)
from planner.description.scaffold_sizing import (
    LIMIT_MARGIN_DEG,
    MAX_MISSION_DEG,
    MAX_SERVO_LAG_S,
    MISSION_RATE_DEGPS,
    SERVO_DAMPING,
    SERVO_MARGIN,
    WHEEL_FILL_S,
    WHEEL_MARGIN,
    WHEEL_RADIUS_M,
    WHEEL_SPEED_RADPS,
)

__all__ = ["render"]


def _num(x: float) -> str:
    return repr(float(f"{x:.6g}"))


def _nums(values: Any, digits: int = 3) -> str:
    return "[" + ", ".join(repr(round(float(v), digits)) for v in values) + "]"


def render(**k: Any) -> str:
    """The TOML text, each choice commented."""
    ch = k["choice"]
    lines = [
        f"# {k['name']}: a description written by `hikoboshi robot init` (docs/robots.md,",
        "# \"Starting from a vendor's URDF\"): the vendor's URDF unchanged on a cube. Every value",
        "# below is the scaffold's choice, with the reason beside it; edit freely.",
        f'name = "{k["name"]}"',
        f'description = "{k["name"]} (vendor URDF) on a {_num(k["base_mass_kg"])} kg cube, '
        'scaffolded by hikoboshi robot init"',
        f'urdf = "{k["urdf_name"]}"',
        f'base_link = "{k["root"]}"',
        f'hand = "{k["hand"]}"',
        'reference_pose = "A"',
        "urdf_collision = false  # the vendor's collision meshes are package:// files",
        "",
        f"# Capsules of {CAPSULE_RADIUS_M} m along the links, a {HAND_RADIUS_M} m hand sphere "
        "and the cube.",
        "[generated_collision]",
        f"radius_m = {CAPSULE_RADIUS_M}",
        f"hand_radius_m = {HAND_RADIUS_M}",
        "",
        "# The cube (uniform), the URDF's root on the centre of its +z face.",
        "[base]",
        f"mass_kg = {_num(k['base_mass_kg'])}",
        f"size_m = {_nums([k['base_size_m']] * 3, 6)}",
        f"mount_xyz_m = {_nums([0.0, 0.0, 0.5 * k['base_size_m']], 6)}",
        "",
        f"# Mission limits: the vendor's range less {LIMIT_MARGIN_DEG:g} deg a side, within "
        f"+-{MAX_MISSION_DEG:g} deg;",
        f"# {MISSION_RATE_DEGPS:g} deg/s (a space arm's rate, ETS-VII's) or the vendor's if "
        "slower.",
        "[mission_limits]",
        f"rate_degps = {_nums(np.degrees(k['rates']), 4)}",
        "angle_deg = { "
        + ", ".join(
            f"{name} = {_nums(np.degrees(k['limits'][i]), 3)}"
            for i, name in enumerate(k["joint_names"])
        )
        + " }",
        "",
    ]
    lines += [
        f"# Wheels sized from the arm's reaction momentum: |H~bm phi'| is at most "
        f"{ch['reaction_momentum_bound_nms']:.3g} N m s",
        f"# ({k['choice']['pose_samples']} sampled poses, every joint at its mission rate); "
        f"capacity {WHEEL_MARGIN:g} x that. PTP A->B peaks",
        f"# at {ch['ptp_reaction_momentum_peak_nms']:.3g} N m s and "
        f"{ch['ptp_reaction_torque_peak_nm']:.3g} N m; torque {WHEEL_MARGIN:g} x that, at "
        f"least capacity / {WHEEL_FILL_S:g} s.",
        f"# Rotors: {WHEEL_SPEED_RADPS:g} rad/s at capacity, thin discs of "
        f"{WHEEL_RADIUS_M:g} m radius.",
    ]
    for axis in ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)):
        lines += [
            "[[wheels]]",
            f"axis = {_nums(axis, 1)}",
            f"spin_inertia_kgm2 = {_num(k['spin'])}",
            f"rotor_mass_kg = {_num(k['rotor'])}",
            f"torque_limit_nm = {_num(k['torque'])}",
            f"momentum_limit_nms = {_num(k['capacity'])}",
            "",
        ]
    lines += [
        "# The memoryless PD law of the shipped small robot (Orihime).",
        "[acs]",
        "bandwidth_radps = 0.1",
        "damping_ratio = 0.7",
        "rate_filter_tau_s = 0.0",
        "dead_band_deg = 0.0",
        "",
        f"# Fastest servo mode {ch['servo_fastest_per_s']:.4g} 1/s over the poses and the "
        f"sampled range (the integrator holds {ch['servo_limit_per_s']:.4g});",
        f"# chosen for at most {SERVO_MARGIN:g} of that, damping ratio {SERVO_DAMPING:g} at "
        f"A where the lag stays under {MAX_SERVO_LAG_S:g} s.",
        "[servo]",
        f"bandwidth_radps = {_num(k['bandwidth'])}",
        f"lag_s = {_num(k['lag'])}",
        "",
        f"# Poses away from singularities: smallest singular value of J_g (angular rows x "
        f"{ch['reach_m']:.3g} m,",
        "# the reach) "
        + ", ".join(f"{p} {v:.3g}" for p, v in ch["sigma_min_Jg"].items())
        + "; clearance of the generated bodies "
        + ", ".join(f"{p} {v:.3g} m" for p, v in ch["clearance_m"].items())
        + ".",
    ]
    notes = {
        "A": "the reference pose: servo design, IK seed, the vehicle's start, coordination's "
        "and GJM's start",
        "B": "PTP's goal, the reactionless start",
        "C": f"B + {ch['reactionless_distance_m']:g} m toward robot "
        f"{ch['reactionless_direction']} by the reactionless path",
    }
    for name, q in k["poses"].items():
        lines += [
            f"[poses.{name}]",
            f'description = "{notes[name]}"',
            f"joints_deg = {_nums(np.degrees(q), 3)}",
            "",
        ]
    direction = DIRECTIONS[ch["reactionless_direction"]]
    checked = k.get("checked")
    if checked is not None:
        verdicts = [
            f"{e} {'passes' if row['passed'] else 'FAILS'}"
            + ("" if row["clearance_m"] is None else f" ({row['clearance_m']:.3g} m)")
            for e, row in checked.items()
        ]
        lines += _wrapped(
            "Each experiment below, planned as written, against the flight rules (clearance "
            "of the arm from the base): " + ", ".join(verdicts) + "."
        )
    lines += [
        "[experiments.ptp]",
        f"start_joints_deg = {_nums(np.degrees(k['poses']['A']), 3)}",
        "",
        "# The direction and length with the least lateral wander of the six axes tried; the",
        "# speed keeps the joints within 0.9 of their rate.",
        "[experiments.reactionless]",
        f"direction_robot = {_nums(direction, 1)}",
        f"distance_m = {_num(ch['reactionless_distance_m'])}",
        f"out_speed_mps = {_num(ch['reactionless_speed_mps'])}",
        f"back_speed_mps = {_num(0.5 * ch['reactionless_speed_mps'])}",
        "",
        "# A holds this hand pitch (about robot y); the approach runs along the hand's x.",
        "[experiments.gjm]",
        f"hand_pitch_deg = {_num(ch['gjm_hand_pitch_deg'])}",
        f"approach_distance_m = {GJM_DISTANCE_M}",
        "",
        "# Along robot +x from A and back, checked well conditioned.",
        "[experiments.coordination]",
        f"distance_m = {COORDINATION_DISTANCE_M}",
        "",
        *_nonholonomic_comment(k.get("nonholonomic")),
        "[experiments.nonholonomic]",
        f"phi_init_deg = {_nums(np.degrees(k['phi_init']), 3)}",
        f"phi_end_deg = {_nums(np.degrees(k['poses']['A']), 3)}",
        "",
        f"# Generated bodies: {MIN_CLEARANCE_M} m apart (the pairs nearer at A are joined).",
        "[flight_rules]",
        f"min_clearance_m = {MIN_CLEARANCE_M}",
        "",
    ]
    return "\n".join(lines)


def _wrapped(text: str, width: int = 92) -> list[str]:
    """``text`` as comment lines of at most ``width`` characters."""
    lines: list[str] = []
    line = "#"
    for word in text.split():
        if len(line) + 1 + len(word) > width and line != "#":
            lines.append(line)
            line = "#"
        line += " " + word
    return [*lines, line]


def _metres(value: float | None) -> str:
    return "none to check" if value is None else f"{value:.4g} m"


def _nonholonomic_comment(nh: dict[str, Any] | None) -> list[str]:
    """What was tried for the non-holonomic start and why this one (None: the first
    description's, ETS-VII's offsets)."""
    if nh is None:
        return ["# From A offset by ETS-VII's offsets (clipped to the limits) back to A."]
    offsets = ", ".join(f"{v:g}" for v in nh["offset_deg"])
    scales = ", ".join(f"x{v:g}" for v in NONHOLONOMIC_SCALES)
    tried = (
        f"{nh['candidates_tried']} tried (ETS-VII's offsets as they are, reversed, the other "
        f"sign patterns; at {scales}): the meeting's paths found coarsely and sampled for "
        f"clearance, {nh['fully_checked']} of them planned and checked in full"
    )
    best = nh["best_screened_clearance_m"]
    if nh["passed"]:
        text = (
            f"From A offset by {nh['candidate']} ({offsets} deg, clipped to the limits) back "
            f"to A: the first candidate whose plan passes the flight rules, clearance "
            f"{_metres(nh['clearance_m'])} from the base and {_metres(nh['self_clearance_m'])} "
            f"between the links (at least {MIN_CLEARANCE_M} m), end attitude error "
            f"{nh['end_attitude_error_deg']:.2g} deg. {tried}."
        )
    elif nh.get("clearance_m") is not None:
        text = (
            f"NO candidate passes the flight rules: written is the nearest, A offset by "
            f"{nh['candidate']} ({offsets} deg): {'; '.join(nh['failing'])}. {tried}. "
            "Choose phi_init_deg (and phi_end_deg) yourself."
        )
    else:
        text = (
            f"NO candidate passes the flight rules: written is the nearest, A offset by "
            f"{nh['candidate']} ({offsets} deg), whose coarse paths come nearest: "
            f"{'no meeting inside the limits' if best is None else _metres(best)} (at least "
            f"{MIN_CLEARANCE_M} m). {tried}. Choose phi_init_deg (and phi_end_deg) yourself."
        )
    return _wrapped(text)
