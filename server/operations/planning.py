"""Checked planning, once: plan an experiment for a robot and check it against the robot's
flight rules, or check a plan someone else made, in one call for every caller.

    plan_checked(experiment, params, robot=, window_s=)  -> CheckedPlan   plan, then check
    check(plan, description, window_s=)                  -> CheckedPlan   check (never trust)
    experiment_parameters(experiment, robot, values=|assignments=)        the typed parameters
    parameters_help()                                    every experiment's parameters

``hikoboshi plan`` and ``plan check``, ``POST /api/plans`` (and ``/validate``, ``/{id}/check``,
``/documents``), the demo (through the API) and the campaign (:mod:`server.operations.campaign`)
all plan and check here. A checked plan carries the report in its document
(``"flight_rules"``), passing or not: a plan that fails a rule is still a plan, which a
person may look at; a pass of it will not start (:mod:`server.operations.start_gate`).

The check is the ground's own: whatever report a plan arrives with is replaced by the one
computed here. A robot without collision shapes cannot be shown clear of the spacecraft: the
invalid request ``no_collision_geometry``.

The window: given a ``window`` (:class:`server.operations.windows.PassWindow`) and the start
lead, the plan is held to the window-fit rule (:func:`server.operations.windows.check_fit`,
``plan_exceeds_window``: :attr:`CheckedPlan.misfit`) and the flight rules' ``fits_pass``
row to the window's usable time less the lead; or ``window_s`` gives that time alone (None:
the robot's ``[flight_rules] pass_window_s``).

Planning takes seconds of CPU and reads no database: a server runs it in a worker process.
Nothing here is imported before it is called (the command line starts without the planner).
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from server.operations.windows import PassWindow, Refusal, check_fit
from server.services.errors import DomainError, InvalidRequestError

if TYPE_CHECKING:
    from planner.flight_rules import FlightRulesReport
    from planner.plan import Plan
    from planner.robot import RobotDescription

__all__ = [
    "NO_COLLISION_GEOMETRY",
    "PLANNING_FAILED",
    "CheckedPlan",
    "check",
    "experiment_parameters",
    "parameters_help",
    "plan_checked",
]

#: The error code of a robot whose description gives no collision shapes to check with.
NO_COLLISION_GEOMETRY = "no_collision_geometry"
#: The error code of a numerical failure the parameters caused (a singular matrix, an
#: overflow): still the request's fault, not an unexpected error.
PLANNING_FAILED = "planning_failed"


@dataclass(frozen=True, eq=False)
class CheckedPlan:
    """A plan carrying the ground's flight-rules report, the report, and the robot's
    description it was checked against."""

    plan: Plan
    report: FlightRulesReport
    description: RobotDescription
    #: the window-fit rule's refusal (``plan_exceeds_window``) when planned for a window
    misfit: Refusal | None = None

    @property
    def passed(self) -> bool:
        return self.report.passed


def parameters_help() -> str:
    """One paragraph per experiment: its parameters, types and defaults (``hikoboshi plan
    --help``)."""
    from planner.catalogue import experiments, type_name

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


def experiment_parameters(
    experiment: str,
    robot: RobotDescription | None,
    *,
    values: Mapping[str, Any] | None = None,
    assignments: Sequence[str] | None = None,
) -> Any:
    """``experiment``'s parameters (its dataclass): ``robot``'s ``[experiments.NAME]`` table
    (None: ETS-VII's numbers) under JSON ``values`` (the API) or ``NAME=VALUE``
    ``assignments`` (the command line); the planner's InvalidInput names a bad one."""
    from planner.catalogue import parameters_from_values, parse_assignments, resolve

    params_type, _ = resolve(experiment)
    defaults = None if robot is None else robot.experiment_defaults(experiment)
    if assignments is not None:
        return parse_assignments(params_type, list(assignments), defaults=defaults)
    return parameters_from_values(params_type, dict(values or {}), defaults=defaults)


def plan_checked(
    experiment: str,
    params: Any,
    *,
    robot: RobotDescription | None = None,
    window_s: float | None = None,
    window: PassWindow | None = None,
    lead_s: float = 0.0,
    optimise_offset: bool = False,
) -> CheckedPlan:
    """Plan ``experiment`` with ``params`` for ``robot`` (None: ETS-VII, its shipped
    description checks it) and :func:`check` the plan; with a ``window``, fit it there after
    ``lead_s`` (module docstring). The planner's own errors propagate; any other numerical
    failure is the invalid request ``planning_failed``."""
    from planner.catalogue import plan_experiment
    from planner.description import default_robot
    from planner.errors import PlannerError

    try:
        plan = plan_experiment(
            experiment, params, optimise_offset_flag=optimise_offset, robot=robot
        )
        if window is not None and window_s is None:
            window_s = window.usable_s - lead_s
        checked = check(plan, robot or default_robot(), window_s=window_s)
        checked.plan.to_json()  # refuses NaN and infinity: what the ground stores and flies
        if window is None:
            return checked
        misfit = check_fit(
            window,
            plan_id=f"of {experiment}",
            plan_s=plan.duration_s,
            lead_s=lead_s,
        )
        return dataclasses.replace(checked, misfit=misfit)
    except (PlannerError, DomainError):
        raise
    except (ValueError, ArithmeticError) as exc:
        raise InvalidRequestError(
            PLANNING_FAILED, f"{experiment} could not be planned: {exc}"
        ) from exc


def check(
    plan: Plan, description: RobotDescription, *, window_s: float | None = None
) -> CheckedPlan:
    """``plan`` checked against ``description``'s flight rules: a copy carrying the ground's
    report in place of whatever it came with. The planner refuses a plan for another robot
    (InvalidInput); a robot without collision shapes is ``no_collision_geometry``."""
    from planner.collision import check_collision_model
    from planner.errors import InvalidInput

    try:
        check_collision_model(description.collision, description.name)
    except InvalidInput as exc:
        raise InvalidRequestError(NO_COLLISION_GEOMETRY, str(exc)) from None
    checked, report = description.checked(plan, window_s=window_s)
    return CheckedPlan(checked, report, description)
