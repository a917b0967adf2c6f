"""Domain errors of the planner.

    PlannerError
    ├── InvalidInput          a parameter or state is malformed (wrong shape, not finite)
    ├── JointLimitExceeded    a joint angle or rate is outside its limit
    ├── InfeasibleGoal        no solution exists (unreachable pose, no reactionless path)
    └── DidNotConverge        an iterative solver stopped without meeting its tolerance

Messages name the bad value and the limit. The planner raises these and never returns
``None`` for failure; the server maps each to a 4xx reply. A failure while planning an
experiment also names the experiment, and a parameter to change (:func:`name_failure`).
"""

from __future__ import annotations

__all__ = [
    "DidNotConverge",
    "InfeasibleGoal",
    "InvalidInput",
    "JointLimitExceeded",
    "PlannerError",
    "name_failure",
]

#: What to change when an experiment's failure names none of its parameters.
_HINTS = {
    "ptp": "lower rate_fraction or change start_joints_deg and goal_joints_deg",
    "reactionless": "lower out_speed_mps and back_speed_mps, shorten distance_m or change "
    "direction_robot",
    "gjm": "shorten approach_distance_m, lengthen approach_s and retreat_s or change "
    "hand_pitch_deg",
    "coordination": "lower speed_mps, shorten distance_m or change direction_robot",
    "nonholonomic": "lower rate_fraction, raise max_corrections or move phi_init_deg nearer "
    "phi_end_deg",
    "pass": "drop an experiment from experiments or shorten the settling waits",
}


class PlannerError(Exception):
    """Root of every error the planner raises."""


class InvalidInput(PlannerError, ValueError):
    """A parameter or state is malformed."""


class JointLimitExceeded(PlannerError):
    """A joint angle or rate is outside its limit."""

    def __init__(self, joint: int, value: float, limit: float, unit: str, what: str = "at") -> None:
        self.joint = joint
        self.value = value
        self.limit = limit
        self.unit = unit
        super().__init__(
            f"joint {joint} {what} {value:.3f} {unit} exceeds limit {limit:.3f} {unit}"
        )


class InfeasibleGoal(PlannerError):
    """The goal cannot be reached under the constraints."""


class DidNotConverge(PlannerError):
    """An iterative solver stopped without meeting its tolerance."""


def name_failure(
    exc: PlannerError, experiment: str, parameter_names: list[str] | tuple[str, ...]
) -> PlannerError:
    """``exc`` (the same object, its class and fields kept) with a message that starts with
    the experiment's name and, when it names none of ``parameter_names``, ends with the
    experiment's usual remedy."""
    message = str(exc.args[0]) if exc.args else str(exc)
    if not message.startswith(f"{experiment}:"):
        message = f"{experiment}: {message}"
    if experiment in _HINTS and not any(name in message for name in parameter_names):
        message = f"{message}: {_HINTS[experiment]}"
    exc.args = (message, *exc.args[1:])
    return exc
