"""``hikoboshi robot check FILE``: load a robot description and say what loading did to its
URDF (links lumped, tool joints locked, arm links renamed), its joints' vendor and mission
limits, the reference pose and hand frame, and the servos' fastest mode against what the
simulator holds (docs/robots.md, "A vendor's URDF" and "Servo stability"); ``hikoboshi robot
init`` writes a description for a vendor's URDF (``planner.description.scaffold``)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated, Any, NoReturn

import typer

from hikoboshi.output import HELP_MARKUP, make_console
from planner.scaffold_defaults import DEFAULT_BASE_MASS_KG, DEFAULT_BASE_SIZE_M

__all__ = ["register"]

robot_app = typer.Typer(
    rich_markup_mode=HELP_MARKUP,
    no_args_is_help=True,
    help="Robot descriptions: check what a description loads to, or write one for a vendor's URDF.",
)
console = make_console(soft_wrap=True)
err_console = make_console(stderr=True)


def _fail(reason: str) -> NoReturn:
    err_console.print(f"error: {reason}", markup=False, highlight=False, soft_wrap=True)
    raise typer.Exit(code=2)


def check_report(description: Any) -> dict[str, Any]:
    """What ``robot check`` prints, as one JSON-able dict."""
    import numpy as np

    from planner.dynamics import DynamicsWorkspace
    from planner.errors import PlannerError
    from planner.frames import rpy_from_matrix
    from planner.servo_check import servo_modes

    model = description.model
    ws = DynamicsWorkspace(model)
    gains = description.servo_gains()
    flown = {}
    for name in description.poses:  # hand poses solved by IK, as the planners take them
        try:
            flown[name] = description.pose_joints_rad(name, ws)
        except PlannerError:
            continue
    at_poses = servo_modes(ws, gains, poses=flown, samples=0)
    over_range = servo_modes(ws, gains, poses=flown)
    vendor = description.vendor_joint_limit_rad
    vendor_rate = description.vendor_joint_rate_limit_radps
    joints = []
    for i, link in enumerate(model.links):
        joints.append(
            {
                "joint": description.joint_names[i] if description.joint_names else f"joint{i + 1}",
                "link": link.name,
                "mission_limits_deg": np.degrees(model.joint_limit_rad[i]).tolist(),
                "mission_rate_degps": math.degrees(model.joint_rate_limit_radps[i]),
                "vendor_limits_deg": (None if vendor is None else np.degrees(vendor[i]).tolist()),
                "vendor_rate_degps": (
                    None if vendor_rate is None else math.degrees(vendor_rate[i])
                ),
            }
        )
    rot = model.rot_robot_from_hand
    return {
        "robot": description.name,
        "file": str(description.path),
        "urdf": str(description.urdf_path),
        "n_joints": model.n_joints,
        "total_mass_kg": model.total_mass_kg,
        "base_mass_kg": model.base_mass_kg,
        "joints": joints,
        "lumped": [{"link": link, "into": body} for link, body in description.lumped],
        "locked": [
            {
                "joint": name,
                "type": kind,
                "position": position if kind == "prismatic" else math.degrees(position),
                "unit": "m" if kind == "prismatic" else "deg",
            }
            for name, kind, position in description.locked
        ],
        "renamed": [{"link": old, "name": new} for old, new in description.renamed],
        "hand": {
            "link": description.hand_link,
            "rpy_deg_at_zero": np.degrees(rpy_from_matrix(rot)).tolist()
            if rot is not None
            else [0.0, 0.0, 0.0],
        },
        "reference_pose": {
            "name": description.reference_pose or "all zeros",
            "joints_deg": np.degrees(model.reference_joints).tolist(),
        },
        "collision_bodies": (
            0 if description.collision is None else len(description.collision.bodies)
        ),
        "servo": {
            "fastest_at_poses_per_s": at_poses.fastest_per_s,
            "at": at_poses.at,
            "fastest_over_range_per_s": over_range.fastest_per_s,
            "over_range_at": over_range.at,
            "over_range_joints_deg": np.degrees(over_range.at_joints_rad).tolist(),
            "samples": over_range.samples,
            "limit_per_s": at_poses.limit_per_s,
            "timestep_s": at_poses.timestep_s,
            "holds_at_poses": at_poses.stable,
            "holds_over_range": over_range.stable,
        },
    }


@robot_app.command("check")
def robot_check(
    file: Annotated[
        Path,
        typer.Argument(
            help="Robot description (TOML, docs/robots.md), or a shipped robot's name (ets7, "
            "orihime)."
        ),
    ],
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Load FILE and print what was lumped, locked and renamed, the limits, the reference
    pose, the hand frame and the servos' fastest mode. Exit 2 with the reason when it does
    not load (a servo the integrator cannot hold at the reference or a named pose is one)."""
    from planner.description import load_robot
    from planner.errors import PlannerError

    try:
        description = load_robot(file)
    except PlannerError as exc:
        _fail(str(exc))
    report = check_report(description)
    if as_json:
        print(json.dumps(report))
        return
    out = console.print
    out(
        f"{report['robot']}: {report['n_joints']} arm joints, {report['total_mass_kg']:.6g} kg "
        f"(base {report['base_mass_kg']:.6g} kg), from {report['urdf']}",
        markup=False,
        highlight=False,
    )
    for row in report["joints"]:
        vendor = row["vendor_limits_deg"]
        text = (
            f"  {row['joint']} -> {row['link']}: mission [{row['mission_limits_deg'][0]:.6g}, "
            f"{row['mission_limits_deg'][1]:.6g}] deg, {row['mission_rate_degps']:.6g} deg/s"
        )
        if vendor is not None:
            text += (
                f" (vendor [{vendor[0]:.6g}, {vendor[1]:.6g}] deg, "
                f"{row['vendor_rate_degps']:.6g} deg/s)"
            )
        out(text, markup=False, highlight=False)
    for key, title in (("lumped", "lumped"), ("locked", "locked"), ("renamed", "renamed")):
        rows = report[key]
        if not rows:
            out(f"{title}: none", markup=False, highlight=False)
            continue
        out(f"{title}:", markup=False, highlight=False)
        for row in rows:
            if key == "lumped":
                text = f"  link {row['link']} into {row['into']}"
            elif key == "locked":
                text = (
                    f"  joint {row['joint']} ({row['type']}) at {row['position']:.6g} {row['unit']}"
                )
            else:
                text = f"  link {row['link']} is {row['name']}"
            out(text, markup=False, highlight=False)
    ref = report["reference_pose"]
    out(
        f"reference pose: {ref['name']} ({', '.join(f'{v:.6g}' for v in ref['joints_deg'])} deg)",
        markup=False,
        highlight=False,
    )
    hand = report["hand"]
    out(
        f"hand: link {hand['link']}, rpy at the all-zero pose "
        f"({', '.join(f'{v:.6g}' for v in hand['rpy_deg_at_zero'])}) deg",
        markup=False,
        highlight=False,
    )
    out(f"collision bodies: {report['collision_bodies']}", markup=False, highlight=False)
    servo = report["servo"]
    out(
        f"servos: fastest mode {servo['fastest_at_poses_per_s']:.4g} 1/s at the reference and "
        f"named poses ({servo['at']}), {servo['fastest_over_range_per_s']:.4g} 1/s over "
        f"{servo['samples']} poses inside the limits ({servo['over_range_at']}); the "
        f"integrator holds {servo['limit_per_s']:.4g} 1/s at a "
        f"{servo['timestep_s'] * 1e3:.4g} ms step",
        markup=False,
        highlight=False,
    )
    if not servo["holds_over_range"]:
        out(
            "warning: somewhere inside the limits the servos are faster than the integrator "
            "holds (at "
            f"{', '.join(f'{v:.4g}' for v in servo['over_range_joints_deg'])} deg); plans "
            "must keep away, or lower [servo] lag_s / bandwidth_radps",
            markup=False,
            highlight=False,
        )


def _urdf_beside(urdf: Path, out: Path) -> tuple[str, Path | None]:
    """The URDF's name as the description names it (relative to its folder), and where it
    must be copied (None: it is already inside the description's folder)."""
    folder = out.parent.resolve()
    resolved = urdf.resolve()
    if resolved.is_relative_to(folder):
        return resolved.relative_to(folder).as_posix(), None
    target = out.parent / urdf.name
    if target.exists() and target.read_bytes() != urdf.read_bytes():
        _fail(
            f"{target}: another file of the URDF's name is in the way; choose another --out "
            "folder (the URDF is copied beside the description, unchanged)"
        )
    return urdf.name, target


@robot_app.command("init")
def robot_init(
    urdf: Annotated[Path, typer.Option("--urdf", help="The vendor's URDF, read unchanged.")],
    hand: Annotated[str, typer.Option("--hand", help="The URDF link that is the hand frame.")],
    out: Annotated[Path, typer.Option("--out", help="The description to write (TOML).")],
    base_mass: Annotated[
        float, typer.Option("--base-mass", help="The cube's mass (kg).")
    ] = DEFAULT_BASE_MASS_KG,
    base_size: Annotated[
        float, typer.Option("--base-size", help="The cube's edge (m).")
    ] = DEFAULT_BASE_SIZE_M,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Write a robot description for a vendor's arm on a cube: mission limits inside the
    vendor's, named poses A, B, C away from singularities, servos the simulator holds,
    wheels sized from the arm's reaction momentum, an attitude law and the experiments'
    defaults (docs/robots.md, "Starting from a vendor's URDF"), each experiment planned as
    written and checked against the flight rules. The URDF is copied beside FILE unchanged
    when it is not in FILE's folder. Takes a minute or more. Exit 2 with the reason when the
    URDF does not load or FILE exists; exit 1, FILE written, when an experiment as written
    fails the flight rules (one warning line each on stderr)."""
    from planner.description import load_robot
    from planner.description.scaffold import scaffold_description
    from planner.errors import PlannerError

    if out.exists():
        _fail(f"{out}: exists; remove it or choose another --out")
    if not urdf.is_file():
        _fail(f"{urdf}: --urdf names no file")
    out.parent.mkdir(parents=True, exist_ok=True)
    urdf_name, copy_to = _urdf_beside(urdf, out)
    try:
        scaffold = scaffold_description(
            urdf,
            hand,
            out_path=out,
            urdf_name=urdf_name,
            base_mass_kg=base_mass,
            base_size_m=base_size,
        )
    except PlannerError as exc:
        _fail(str(exc))
    if copy_to is not None and not copy_to.exists():
        copy_to.write_bytes(urdf.read_bytes())
    out.write_text(scaffold.toml, encoding="utf-8")
    try:
        load_robot(out)  # the file as written, read back
    except PlannerError as exc:  # not expected: the scaffold was built from this text
        out.unlink()
        _fail(str(exc))
    report = {**scaffold.report, "copied_urdf": None if copy_to is None else str(copy_to)}
    if as_json:
        print(json.dumps(report))
    else:
        _print_init(out, copy_to, report)
    failing = report["failing_experiments"]
    for experiment in failing:
        row = report["experiments"][experiment]
        why = "; ".join(row["failing"]) or row.get("error", "")
        if experiment == "nonholonomic":  # the start offset written is the nearest tried
            nh = report["nonholonomic"]
            why += f" (the nearest of {nh['candidates_tried']} starts tried: {nh['candidate']})"
        err_console.print(
            f"warning: {out}: [experiments.{experiment}] as written fails the flight rules: "
            f"{why}; edit it before planning",
            markup=False,
            highlight=False,
            soft_wrap=True,
        )
    if failing:
        raise typer.Exit(code=1)


def _print_init(out: Path, copy_to: Path | None, report: dict[str, Any]) -> None:
    out_ = console.print
    lines = [
        f"wrote {out} ({report['n_joints']} joints, base link {report['base_link']}, hand "
        f"{report['hand']})"
        + ("" if copy_to is None else f"; copied the URDF unchanged to {copy_to}"),
    ]
    for name, joints in report["poses_deg"].items():
        lines.append(
            f"  pose {name}: ({', '.join(f'{v:.4g}' for v in joints)}) deg, smallest singular "
            f"value of J_g {report['sigma_min_Jg'][name]:.3g}, clearance "
            f"{report['clearance_m'][name]:.3g} m"
        )
    wheels, servo = report["wheels"], report["servo"]
    lines += [
        f"  wheels: {wheels['momentum_limit_nms']:.6g} N m s, {wheels['torque_limit_nm']:.6g} N m "
        f"(arm reaction momentum at most {report['reaction_momentum_bound_nms']:.3g} N m s)",
        f"  servos: {servo['bandwidth_radps']:.6g} rad/s, lag {servo['lag_s']:.6g} s (fastest "
        f"mode {report['servo_fastest_per_s']:.4g} 1/s; the integrator holds "
        f"{report['servo_limit_per_s']:.4g})",
        f"  experiments: gjm hand pitch {report['gjm_hand_pitch_deg']:.6g} deg, reactionless "
        f"{report['reactionless_distance_m']:.6g} m toward robot "
        f"{report['reactionless_direction']}, nonholonomic from A offset by "
        f"{report['nonholonomic']['candidate']}",
        "  as written, against the flight rules: "
        + ", ".join(
            f"{e} {'pass' if row['passed'] else 'FAIL'}"
            + ("" if row["clearance_m"] is None else f" (clearance {row['clearance_m']:.3g} m)")
            for e, row in report["experiments"].items()
        ),
        f"next: hikoboshi robot check {out}; hikoboshi plan --robot {out} pass",
    ]
    for line in lines:
        out_(line, markup=False, highlight=False)


def register(app: typer.Typer) -> None:
    """Add ``robot`` (``check``, ``init``) to ``hikoboshi``."""
    app.add_typer(robot_app, name="robot")
