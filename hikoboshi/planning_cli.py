"""``hikoboshi plan``: experiment parameters from the command line to a plan file."""

from __future__ import annotations

import dataclasses
import os
import tempfile
import typing
from pathlib import Path
from typing import TYPE_CHECKING, Any

from planner.catalogue import experiments, parse_assignments, plan_experiment, resolve, type_name
from planner.plan import Plan

if TYPE_CHECKING:
    from planner.robot import RobotDescription

__all__ = ["make_plan", "parameters_help", "parse_parameters", "write_atomically"]


def parameters_help() -> str:
    """One paragraph per experiment: its parameters, types and defaults."""
    lines = []
    for name, (params_type, _) in experiments().items():
        hints = typing.get_type_hints(params_type)
        fields = ", ".join(
            f"{f.name}={_show(f.default)} ({type_name(hints[f.name])})"
            for f in dataclasses.fields(params_type)
        )
        lines.append(f"{name}: {fields}")
    return "\n\n".join(lines)


def _show(value: Any) -> str:
    if isinstance(value, tuple):
        return ",".join(str(v) for v in value) if value else "''"
    return str(value)


def parse_parameters(params_type: type, assignments: list[str]) -> Any:
    return parse_assignments(params_type, assignments)


def make_plan(
    experiment: str,
    assignments: list[str],
    *,
    optimise_offset_flag: bool,
    robot: RobotDescription | None = None,
) -> Plan:
    """The plan for ``robot`` (``None``: ETS-VII as built in): its ``[experiments.NAME]``
    table under the ``--set`` assignments, its poses."""
    params_type, _ = resolve(experiment)
    defaults = None if robot is None else robot.experiment_defaults(experiment)
    params = parse_assignments(params_type, assignments, defaults=defaults)
    return plan_experiment(
        experiment, params, optimise_offset_flag=optimise_offset_flag, robot=robot
    )


def write_atomically(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` so that a reader sees the old file or the whole new one."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
