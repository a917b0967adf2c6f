"""Assembling command blocks, holds and segments on the 4 Hz grid (private helper)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.errors import InvalidInput
from planner.model import RobotModel
from planner.plan import AcsCommand, Plan, Prediction, Segment, check_plan_limits
from planner.ptp import COMMAND_PERIOD_S

Array = NDArray[np.float64]


class CommandBuilder:
    """Joint commands exactly one period apart from t = 0, with named segments."""

    def __init__(self, start_joints_rad: Array) -> None:
        self._rows: list[Array] = [np.asarray(start_joints_rad, dtype=np.float64).copy()]
        self.segments: list[Segment] = []

    @property
    def t_s(self) -> float:
        """Time of the last command."""
        return (len(self._rows) - 1) * COMMAND_PERIOD_S

    @property
    def joints_rad(self) -> Array:
        return self._rows[-1].copy()

    def block(self, rows: Array, name: str, kind: str) -> tuple[float, float]:
        """Append commands whose first row is the current last command (it is not repeated).

        Returns the segment's start and end times.
        """
        rows = np.asarray(rows, dtype=np.float64)
        if not np.allclose(rows[0], self._rows[-1], atol=1e-9):
            raise InvalidInput(f"segment {name!r} does not start where the plan stands")
        start = self.t_s
        self._rows.extend(rows[1:])
        self.segments.append(Segment(name, kind, start, self.t_s))
        return start, self.t_s

    def hold(self, duration_s: float, name: str, kind: str = "hold") -> tuple[float, float]:
        n = round(duration_s / COMMAND_PERIOD_S)
        if n < 0 or abs(n * COMMAND_PERIOD_S - duration_s) > 1e-9:
            raise InvalidInput(f"hold {name!r} of {duration_s} s is not whole 0.25 s periods")
        return self.block(np.tile(self._rows[-1], (n + 1, 1)), name, kind)

    def plan(
        self,
        model: RobotModel,
        *,
        experiment: str,
        parameters: Mapping[str, Any],
        prediction: Prediction,
        metrics: Mapping[str, float],
        acs_commands: Sequence[AcsCommand],
        joints_rad: Array | None = None,
    ) -> Plan:
        """The plan of these commands (or of ``joints_rad`` on the same grid, e.g. pre-shaped
        ones), checked against the joint and rate limits."""
        times, rows = self.arrays()
        plan = Plan(
            experiment=experiment,
            parameters=dict(parameters),
            initial_joints_rad=rows[0],
            command_times_s=times,
            command_joints_rad=rows if joints_rad is None else joints_rad,
            segments=tuple(self.segments),
            prediction=prediction,
            metrics=dict(metrics),
            acs_commands=tuple(acs_commands),
        )
        check_plan_limits(model, plan)
        return plan

    def arrays(self) -> tuple[Array, Array]:
        rows = np.array(self._rows)
        return np.arange(rows.shape[0], dtype=np.float64) * COMMAND_PERIOD_S, rows
