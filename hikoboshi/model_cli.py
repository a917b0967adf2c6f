"""``hikoboshi model``: the robot model (ETS-VII, or ``--robot FILE``) as URDF or MJCF, its
planning quantities at one pose (``model quantities``) and its limits (``model limits``,
:mod:`hikoboshi.limits_cli`)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.table import Table

from hikoboshi import limits_cli
from hikoboshi.cli_common import RobotOption, _fail, _load, console
from hikoboshi.output import HELP_MARKUP

if TYPE_CHECKING:
    import numpy as np

__all__ = ["model_app", "quantities_document", "register"]

model_app = typer.Typer(
    rich_markup_mode=HELP_MARKUP,
    no_args_is_help=True,
    help="The robot model (ETS-VII or --robot FILE): export and quantities.",
)
limits_cli.register(model_app)  # model limits


def _robot(robot: Path | None) -> tuple[str, Any]:
    """The robot's name and RobotModel: from ``robot``, or ETS-VII's built-in model."""
    from planner.model import default_model

    if robot is None:
        return "ets7", default_model()
    description = _load(robot)
    return description.name, description.model


@model_app.command("urdf")
def model_urdf(robot: RobotOption = None) -> None:
    """Print the model as URDF (base, arm and a hand link); its root link is the base."""
    from planner.model import default_model
    from planner.urdf import urdf_xml

    if robot is None:
        sys.stdout.write(urdf_xml(default_model()))
        return
    description = _load(robot)
    box = description.base_box_size_m
    extra = {} if box is None else {"base_box_size_m": box}
    sys.stdout.write(urdf_xml(description.model, name=description.name, **extra))


@model_app.command("mjcf")
def model_mjcf(robot: RobotOption = None) -> None:
    """Print the MuJoCo model (MJCF) the simulator steps."""
    from planner.mjcf import mjcf_xml

    name, model = _robot(robot)
    sys.stdout.write(mjcf_xml(model, name=name))


def _parse_joints_deg(text: str, n: int) -> np.ndarray:
    import numpy as np

    parts = [p.strip() for p in text.split(",")]
    if len(parts) != n:
        _fail(f"--joints-deg needs {n} comma-separated angles, got {len(parts)}: {text!r}")
    values = []
    for i, part in enumerate(parts):
        try:
            value = float(part)
        except ValueError:
            _fail(f"--joints-deg value {i + 1} is not a number: {part!r}")
        if not np.isfinite(value):
            _fail(f"--joints-deg value {i + 1} is not finite: {part!r}")
        values.append(value)
    return np.array(values)


def quantities_document(joints_deg: np.ndarray, model: Any = None) -> dict[str, Any]:
    """The JSON object of ``hikoboshi model quantities`` (base at nominal, zero momentum);
    ``model`` is a RobotModel (default: ETS-VII)."""
    import numpy as np

    from planner.dynamics import DynamicsWorkspace
    from planner.frames import rpy_from_matrix
    from planner.model import default_model
    from planner.state import State

    model = default_model() if model is None else model
    joints_rad = model.check_joints(np.radians(joints_deg))
    zero_rates = np.zeros(model.n_joints)
    q = DynamicsWorkspace(model).evaluate(
        State(joints_rad=joints_rad, joint_rates_radps=zero_rates)
    )
    return {
        "joints_deg": joints_deg.tolist(),
        "total_mass_kg": q.total_mass_kg,
        "hand_position_robot_m": q.hand.pos_robot_m.tolist(),
        "hand_rpy_deg": np.degrees(rpy_from_matrix(q.hand.rot_robot_from_hand)).tolist(),
        "generalized_jacobian": q.J_g.tolist(),
        "base_reaction_map": q.reaction_map.tolist(),
        "system_inertia_com_kgm2": q.inertia_com_orbit_kgm2.tolist(),
        "gravity_gradient_torque_nm": q.gravity_gradient_torque_base_nm.tolist(),
    }


@model_app.command("quantities")
def model_quantities(
    joints_deg: Annotated[
        str,
        typer.Option(
            "--joints-deg",
            help="One angle per joint in degrees, comma-separated: J1,J2,...,Jn (six for ETS-VII)",
        ),
    ],
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    robot: RobotOption = None,
) -> None:
    """Planning quantities at one arm pose, base at the orbit frame's nominal attitude."""
    import numpy as np

    from planner.errors import PlannerError

    name, model = _robot(robot)
    values = _parse_joints_deg(joints_deg, model.n_joints)
    try:
        doc = quantities_document(values, model)
    except PlannerError as exc:
        _fail(str(exc))
    if as_json:
        sys.stdout.write(json.dumps(doc) + "\n")
        return
    title = "ETS-VII" if robot is None else name
    table = Table(title=f"{title} at joints {joints_deg} deg")
    table.add_column("quantity")
    table.add_column("value")
    for key, value in doc.items():
        table.add_row(key, json.dumps(np.round(np.asarray(value), 6).tolist()))
    console.print(table)


def register(app: typer.Typer) -> None:
    """Add ``model`` (``limits``, ``urdf``, ``mjcf``, ``quantities``) to ``hikoboshi``."""
    app.add_typer(model_app, name="model")
