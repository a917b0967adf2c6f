"""Domain errors of the planner.

    PlannerError
    ├── InvalidInput          a parameter or state is malformed (wrong shape, not finite)
    ├── JointLimitExceeded    a joint angle or rate is outside its limit
    ├── InfeasibleGoal        no solution exists (unreachable pose, no reactionless path)
    └── DidNotConverge        an iterative solver stopped without meeting its tolerance

Messages name the bad value and the limit. The planner raises these and never returns
``None`` for failure; the server maps each to a 4xx reply.
"""

from __future__ import annotations

__all__ = [
    "DidNotConverge",
    "InfeasibleGoal",
    "InvalidInput",
    "JointLimitExceeded",
    "PlannerError",
]


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
