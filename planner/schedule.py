"""A pass schedule: the four experiments in order within one contact window (SPEC 3, 5).

The arm moves between experiments by PTP transfers with wheel feedback on, and waits for the
attitude to settle after each. Every piece is planned on its own (each planner's checks
apply), then the pieces are joined on one 4 Hz grid: attitude-control commands and segments
are shifted to pass time and the whole pass is predicted again, so that the attitude and
the wheel momentum carry over from one experiment to the next.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import NDArray

from planner._builder import CommandBuilder
from planner.attitude_control import AcsGains, AcsMode, default_acs_gains
from planner.coordination import CoordinationParams, plan_coordination
from planner.dynamics import DynamicsWorkspace
from planner.errors import InfeasibleGoal, InvalidInput
from planner.experiments import PtpParams, ReactionlessParams, plan_ptp, plan_reactionless
from planner.gjm import GjmParams, plan_gjm
from planner.plan import AcsCommand, Plan, Segment, check_plan_limits
from planner.prediction import predict
from planner.ptp import ptp_commands

__all__ = ["EXPERIMENTS", "PassParams", "plan_pass"]

Array = NDArray[np.float64]

EXPERIMENTS = ("ptp", "reactionless", "gjm", "coordination", "nonholonomic")


@dataclass(frozen=True)
class PassParams:
    window_s: float = 1260.0  # SPEC 3/5: about 20 minutes of robot time
    experiments: tuple[str, ...] = EXPERIMENTS
    transfer_settle_s: float = 45.0  # after each PTP transfer between experiments
    ptp_settle_s: float = 100.0  # experiment 1's settling wait (flight: about 100 s)
    coordination_settle_s: float = 80.0
    coordination_pause_s: float = 10.0

    def check(self) -> None:
        unknown = [e for e in self.experiments if e not in EXPERIMENTS]
        if unknown or not self.experiments:
            raise InvalidInput(f"experiments {list(self.experiments)} must come from {EXPERIMENTS}")
        if not 0 < self.window_s <= 3600:
            raise InvalidInput(f"window_s = {self.window_s} must lie in (0, 3600] s")


def _experiment_plans(ws: DynamicsWorkspace, params: PassParams, gains: AcsGains) -> list[Plan]:
    plans = []
    for name in params.experiments:
        if name == "ptp":
            plans.append(plan_ptp(ws, PtpParams(settle_s=params.ptp_settle_s), gains))
        elif name == "reactionless":
            plans.append(plan_reactionless(ws, ReactionlessParams(), gains))
        elif name == "gjm":
            plans.append(plan_gjm(ws, GjmParams()))
        elif name == "coordination":
            plans.append(
                plan_coordination(
                    ws,
                    CoordinationParams(
                        settle_s=params.coordination_settle_s, pause_s=params.coordination_pause_s
                    ),
                    gains,
                )
            )
        else:
            from planner.nonholonomic import NonholonomicParams, plan_nonholonomic

            plans.append(plan_nonholonomic(ws, NonholonomicParams()))
    return plans


def plan_pass(
    ws: DynamicsWorkspace, params: PassParams = PassParams(), gains: AcsGains | None = None
) -> Plan:
    """The experiments of ``params`` in order, from pose A, as one plan."""
    params.check()
    model = ws.model
    gains = gains or default_acs_gains(ws)
    pieces = _experiment_plans(ws, params, gains)
    builder = CommandBuilder(np.zeros(model.n_joints))
    acs: list[AcsCommand] = [AcsCommand(0.0, AcsMode.FEEDBACK)]
    segments: list[Segment] = []
    metrics: dict[str, float] = {}

    def nominal_feedback() -> None:
        # Between experiments the wheels hold the nominal attitude (transfers included).
        last = acs[-1]
        if (
            last.mode is not AcsMode.FEEDBACK
            or last.feedforward
            or not np.allclose(last.target_quat_orbit_from_base_xyzw, [0.0, 0.0, 0.0, 1.0])
        ):
            acs.append(AcsCommand(builder.t_s, AcsMode.FEEDBACK))

    for piece in pieces:
        nominal_feedback()
        if not np.allclose(builder.joints_rad, piece.initial_joints_rad, atol=1e-9):
            _, move = ptp_commands(model, builder.joints_rad, piece.initial_joints_rad)
            builder.block(move, f"transfer to {piece.experiment}", "ptp")
            builder.hold(params.transfer_settle_s, f"settle before {piece.experiment}", "settle")
        offset = builder.t_s
        builder.block(piece.command_joints_rad, piece.experiment, piece.segments[0].kind)
        builder.segments.pop()  # replaced by the piece's own segments below
        segments.extend(builder.segments)
        builder.segments.clear()
        segments.extend(
            Segment(
                f"{piece.experiment}: {s.name}", s.kind, s.t_start_s + offset, s.t_end_s + offset
            )
            for s in piece.segments
        )
        acs.extend(
            AcsCommand(c.t_s + offset, c.mode, c.target_quat_orbit_from_base_xyzw, c.feedforward)
            for c in piece.acs_commands
        )
        for key, value in piece.metrics.items():
            metrics[f"{piece.experiment}.{key}"] = value
        metrics[f"{piece.experiment}.start_s"] = offset
    nominal_feedback()
    segments.extend(builder.segments)
    times, joints = builder.arrays()
    if times[-1] > params.window_s:
        raise InfeasibleGoal(
            f"the pass needs {times[-1]:.1f} s, more than the {params.window_s:.1f} s window: "
            "drop an experiment or shorten the settling waits"
        )
    prediction = predict(ws, times, joints, acs_commands=acs, acs_gains=gains)
    metrics["duration_s"] = float(times[-1])
    metrics["window_margin_s"] = float(params.window_s - times[-1])
    plan = Plan(
        experiment="pass",
        parameters={**asdict(params), "experiments": list(params.experiments)},
        initial_joints_rad=np.zeros(model.n_joints),
        command_times_s=times,
        command_joints_rad=joints,
        segments=tuple(segments),
        prediction=prediction,
        metrics=metrics,
        acs_commands=tuple(sorted(acs, key=lambda c: c.t_s)),
    )
    check_plan_limits(model, plan)
    return plan
