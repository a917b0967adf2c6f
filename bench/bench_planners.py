"""Time of each planner with its defaults (the seed's experiments), and of the pass schedule.

Baseline measured in the same run: one free-drift prediction of the PTP A -> B commands
(eq. 10 integration), the kernel every planner builds on. Target (planner issue): each
experiment planner under 2 s. The offset optimisation (closed loop, tens of flights) and the
whole-pass schedule (every planner plus one prediction of the whole pass) are reported too.
"""

from __future__ import annotations

import numpy as np
from _common import best_of, emit

from planner.coordination import CoordinationParams, optimise_offset, plan_coordination
from planner.dynamics import DynamicsWorkspace
from planner.experiments import plan_ptp, plan_reactionless
from planner.gjm import plan_gjm
from planner.model import default_model
from planner.nonholonomic import plan_nonholonomic
from planner.prediction import predict
from planner.ptp import ptp_commands
from planner.schedule import plan_pass


def main() -> None:
    ws = DynamicsWorkspace(default_model())
    t, q = ptp_commands(ws.model, np.zeros(6), np.radians([31.6, 21.4, -8.8, 77.4, 0.0, 68.6]))
    figures: dict[str, float] = {
        "baseline_free_drift_prediction_ptp_s": best_of(lambda: predict(ws, t, q), repeat=3)
    }
    planners = {
        "ptp": lambda: plan_ptp(ws),
        "reactionless": lambda: plan_reactionless(ws),
        "gjm": lambda: plan_gjm(ws),
        "coordination": lambda: plan_coordination(ws),
        "nonholonomic": lambda: plan_nonholonomic(ws),
    }
    for name, fn in planners.items():
        figures[f"{name}_s"] = best_of(fn, repeat=2)
    figures["pass_schedule_s"] = best_of(lambda: plan_pass(ws), repeat=1)
    figures["offset_optimisation_s"] = best_of(
        lambda: optimise_offset(ws, CoordinationParams(settle_s=100.0), max_evaluations=30),
        repeat=1,
    )
    emit(
        "planners",
        figures,
        {f"{name}_under_2s": figures[f"{name}_s"] < 2.0 for name in planners},
    )


if __name__ == "__main__":
    main()
