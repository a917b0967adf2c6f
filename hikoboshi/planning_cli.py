"""``hikoboshi plan``: experiment parameters from the command line to a plan file."""

from __future__ import annotations

import contextlib
import dataclasses
import os
import tempfile
import typing
from collections.abc import Callable
from pathlib import Path
from typing import Any

from planner.coordination import CoordinationParams, optimise_offset, plan_coordination
from planner.dynamics import DynamicsWorkspace
from planner.errors import InvalidInput
from planner.experiments import PtpParams, ReactionlessParams, plan_ptp, plan_reactionless
from planner.gjm import GjmParams, plan_gjm
from planner.model import default_model
from planner.plan import Plan
from planner.schedule import PassParams, plan_pass


def _nonholonomic() -> tuple[type, Callable[..., Plan]]:
    from planner.nonholonomic import NonholonomicParams, plan_nonholonomic

    return NonholonomicParams, plan_nonholonomic


def experiments() -> dict[str, tuple[type, Callable[..., Plan]]]:
    table: dict[str, tuple[type, Callable[..., Plan]]] = {
        "ptp": (PtpParams, plan_ptp),
        "reactionless": (ReactionlessParams, plan_reactionless),
        "gjm": (GjmParams, plan_gjm),
        "coordination": (CoordinationParams, plan_coordination),
    }
    with contextlib.suppress(ImportError):  # until the planner lands
        table["nonholonomic"] = _nonholonomic()
    table["pass"] = (PassParams, plan_pass)
    return table


def parameters_help() -> str:
    """One paragraph per experiment: its parameters, types and defaults."""
    lines = []
    for name, (params_type, _) in experiments().items():
        hints = typing.get_type_hints(params_type)
        fields = ", ".join(
            f"{f.name}={_show(f.default)} ({_type_name(hints[f.name])})"
            for f in dataclasses.fields(params_type)
        )
        lines.append(f"{name}: {fields}")
    return "\n\n".join(lines)


def _show(value: Any) -> str:
    if isinstance(value, tuple):
        return ",".join(str(v) for v in value) if value else "''"
    return str(value)


def _type_name(hint: Any) -> str:
    return str(hint).replace("typing.", "").replace("<class '", "").replace("'>", "")


def _convert(name: str, text: str, hint: Any) -> Any:
    args = typing.get_args(hint)
    if type(None) in args:  # Optional[...]: "none" means the default derivation
        if text.strip().lower() in ("", "none"):
            return None
        hint = next(a for a in args if a is not type(None))
        args = typing.get_args(hint)
    origin = typing.get_origin(hint)
    try:
        if hint is bool:
            lowered = text.strip().lower()
            if lowered not in ("true", "false", "1", "0", "yes", "no"):
                raise ValueError(f"not a boolean: {text!r}")
            return lowered in ("true", "1", "yes")
        if hint is float:
            value = float(text)
            if value != value or value in (float("inf"), float("-inf")):
                raise ValueError(f"not finite: {text!r}")
            return value
        if hint is int:
            return int(text)
        if hint is str:
            return text
        if origin is tuple:
            item = args[0]
            parts = [p.strip() for p in text.split(",") if p.strip()]
            return tuple(_convert(name, p, item) for p in parts)
    except ValueError as exc:
        raise InvalidInput(f"parameter {name}: {exc}") from None
    raise InvalidInput(f"parameter {name} has a type the command line cannot set: {hint}")


def parse_parameters(params_type: type, assignments: list[str]) -> Any:
    hints = typing.get_type_hints(params_type)
    names = {f.name for f in dataclasses.fields(params_type)}
    values: dict[str, Any] = {}
    for assignment in assignments:
        if "=" not in assignment:
            raise InvalidInput(f"--set needs NAME=VALUE, got {assignment!r}")
        key, text = assignment.split("=", 1)
        key = key.strip()
        if key not in names:
            raise InvalidInput(
                f"unknown parameter {key!r} for {params_type.__name__}; known: {sorted(names)}"
            )
        values[key] = _convert(key, text, hints[key])
    try:
        params = params_type(**values)
    except TypeError as exc:
        raise InvalidInput(str(exc)) from None
    check = getattr(params, "check", None)
    if callable(check):
        check()
    return params


def make_plan(experiment: str, assignments: list[str], *, optimise_offset_flag: bool) -> Plan:
    table = experiments()
    if experiment not in table:
        raise InvalidInput(f"unknown experiment {experiment!r}; choose from {sorted(table)}")
    params_type, planner_fn = table[experiment]
    params = parse_parameters(params_type, assignments)
    ws = DynamicsWorkspace(default_model())
    if experiment == "coordination" and optimise_offset_flag:
        optimum = optimise_offset(ws, params)
        params = dataclasses.replace(
            params,
            offset_scale=optimum.offset_scale,
            offset_on_delay_s=optimum.on_delay_s,
            offset_off_delay_s=optimum.off_delay_s,
        )
        optimised: Plan = planner_fn(ws, params)
        extra = {f"optimum.{k}": float(v) for k, v in dataclasses.asdict(optimum).items()}
        return dataclasses.replace(optimised, metrics={**optimised.metrics, **extra})
    if optimise_offset_flag:
        raise InvalidInput("--optimise-offset applies to the coordination experiment only")
    plan: Plan = planner_fn(ws, params)
    return plan


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
