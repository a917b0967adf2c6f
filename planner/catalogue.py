"""The experiments the planner offers, their parameters, and planning one by name.

One table serves the command line (``NAME=VALUE`` text) and the ground service (JSON
values), so both accept the same parameters and refuse the same mistakes with the same
:class:`~planner.errors.InvalidInput` messages.

    experiments()            name -> (parameters dataclass, planner function)
    resolve(name)            one entry, or InvalidInput naming the known experiments
    parse_assignments(...)   ["NAME=VALUE", ...] -> parameters (text, as on a command line)
    parameters_from_values   {NAME: JSON value} -> parameters (a string is read as text)
    plan_experiment(...)     the plan (seconds of CPU: callers off the event loop run it)

A robot (``planner.robot.RobotDescription``; ``None``: ETS-VII) supplies each
experiment's default parameters (its ``[experiments.NAME]`` table, under what a caller sets:
``defaults=robot.experiment_defaults(name)``) and its poses; ``plan_experiment(...,
robot=robot)`` plans on its model and stamps the plan with its name and hash.

The parameters' conversion and bounds are :mod:`planner.parameters`'s (its two conversions
and ``type_name`` are offered here too).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from planner.coordination import CoordinationParams, optimise_offset
from planner.dynamics import DynamicsWorkspace
from planner.errors import InvalidInput, PlannerError, name_failure
from planner.experiments import PtpParams, ReactionlessParams, plan_ptp, plan_reactionless
from planner.gjm import GjmParams, plan_gjm
from planner.model import default_model
from planner.nonholonomic import NonholonomicParams, plan_nonholonomic
from planner.parameters import parameters_from_values, parse_assignments, show, type_name
from planner.plan import Plan, plan_for_robot
from planner.schedule import PassParams, plan_coordination_for, plan_pass

if TYPE_CHECKING:
    from planner.robot import RobotDescription

__all__ = [
    "Entry",
    "experiments",
    "parameters_from_values",
    "parse_assignments",
    "plan_experiment",
    "resolve",
    "type_name",
]

Entry = tuple[type[Any], Callable[..., Plan]]


def experiments() -> dict[str, Entry]:
    """Experiment name -> (parameters dataclass, planner ``f(workspace, params) -> Plan``)."""
    return {
        "ptp": (PtpParams, plan_ptp),
        "reactionless": (ReactionlessParams, plan_reactionless),
        "gjm": (GjmParams, plan_gjm),
        "coordination": (CoordinationParams, plan_coordination_for),
        "nonholonomic": (NonholonomicParams, plan_nonholonomic),
        "pass": (PassParams, plan_pass),
    }


def resolve(experiment: str) -> Entry:
    table = experiments()
    if experiment not in table:
        raise InvalidInput(f"unknown experiment {show(experiment)}; choose from {sorted(table)}")
    return table[experiment]


def plan_experiment(
    experiment: str,
    params: Any,
    *,
    optimise_offset_flag: bool = False,
    robot: RobotDescription | None = None,
) -> Plan:
    """Plan ``experiment`` with ``params`` (of its dataclass) for ``robot`` (``None``: the
    built-in ETS-VII model, as before descriptions existed).

    ``optimise_offset_flag`` (coordination only) first optimises the offset size and switch
    times in the closed loop and records the optimum in the metrics.
    """
    params_type, planner_fn = resolve(experiment)
    try:
        return _plan(experiment, params, planner_fn, optimise_offset_flag, robot)
    except PlannerError as exc:
        names = [f.name for f in dataclasses.fields(params_type)]
        raise name_failure(exc, experiment, names) from None


def _plan(
    experiment: str,
    params: Any,
    planner_fn: Callable[..., Plan],
    optimise_offset_flag: bool,
    robot: RobotDescription | None,
) -> Plan:
    if optimise_offset_flag and experiment != "coordination":
        raise InvalidInput("--optimise-offset applies to the coordination experiment only")
    ws = DynamicsWorkspace(default_model() if robot is None else robot.model)
    if optimise_offset_flag:
        if robot is None:
            optimum = optimise_offset(ws, params)
        else:
            optimum = optimise_offset(
                ws, params, gains=robot.acs_gains(ws), servo=robot.servo_gains()
            )
        params = dataclasses.replace(
            params,
            offset_scale=optimum.offset_scale,
            offset_on_delay_s=optimum.on_delay_s,
            offset_off_delay_s=optimum.off_delay_s,
        )
        optimised: Plan = planner_fn(ws, params, robot=robot)
        extra = {f"optimum.{k}": float(v) for k, v in dataclasses.asdict(optimum).items()}
        return dataclasses.replace(optimised, metrics={**optimised.metrics, **extra})
    plan: Plan = planner_fn(ws, params, robot=robot)
    return plan_for_robot(plan, robot)
