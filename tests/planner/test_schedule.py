"""The pass schedule: experiments joined on one grid within the contact window."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from planner.attitude_control import AcsMode
from planner.dynamics import DynamicsWorkspace
from planner.errors import InfeasibleGoal, InvalidInput
from planner.plan import Plan, check_plan_limits
from planner.schedule import EXPERIMENTS, PassParams, plan_pass
from telemetry.recording import PassRecording


@pytest.fixture(scope="module")
def full_pass(demo_recording: PassRecording) -> Plan:
    """ETS-VII's demo pass with the defaults (``plan_pass``): the plan the session's flown
    demo pass (tests/conftest.py) planned, not planned a second time (read only)."""
    plan = demo_recording.plan
    assert isinstance(plan, Plan) and plan.experiment == "pass"
    return plan


@pytest.mark.slow
def test_the_pass_holds_every_experiment_in_order_within_the_window(full_pass: Plan) -> None:
    plan = full_pass
    from planner.model import default_model

    check_plan_limits(default_model(), plan)
    np.testing.assert_array_equal(np.diff(plan.command_times_s), 0.25)
    assert plan.duration_s <= PassParams().window_s
    assert plan.duration_s > 900.0  # about 20 minutes of robot time, not a toy
    starts = [plan.metrics[f"{e}.start_s"] for e in EXPERIMENTS]
    assert starts == sorted(starts)
    kinds = {s.kind for s in plan.segments}
    assert {"ptp", "reactionless", "gjm", "coordination", "nonholonomic", "settle"} <= kinds
    # segments tile the pass without overlapping
    spans = sorted((s.t_start_s, s.t_end_s) for s in plan.segments)
    for (_, end), (start, _) in itertools.pairwise(spans):
        assert start >= end - 1e-9


@pytest.mark.slow
def test_free_drift_only_where_the_experiments_ask_for_it(full_pass: Plan) -> None:
    plan = full_pass
    free = [c for c in plan.acs_commands if c.mode is AcsMode.FREE_DRIFT]
    assert len(free) == 2  # experiment 2 (GJM) and experiment 4 (non-holonomic)
    for command in free:
        after = [c for c in plan.acs_commands if c.t_s > command.t_s]
        segment = next(s for s in plan.segments if abs(s.t_start_s - command.t_s) < 1e-9)
        assert segment.name.startswith(("gjm", "nonholonomic"))
        if after:
            # the wheels come back on before the arm moves to the next experiment
            assert after[0].mode is AcsMode.FEEDBACK


def test_a_pass_that_does_not_fit_is_refused() -> None:
    from planner.model import default_model

    ws = DynamicsWorkspace(default_model())
    with pytest.raises(InfeasibleGoal, match=r"more than the 100\.0 s window"):
        plan_pass(ws, PassParams(window_s=100.0, experiments=("ptp",)))
    with pytest.raises(InvalidInput, match="experiments"):
        plan_pass(ws, PassParams(experiments=("ptp", "juggling")))


@pytest.mark.slow
def test_the_pass_keeps_every_flight_rule_and_carries_its_report(full_pass: Plan) -> None:
    """ETS-VII's whole demo pass meets every rule (tests/planner/test_flight_rules.py tests
    the rules themselves), and the report travels in the plan's document."""
    from planner.description import default_robot
    from planner.flight_rules import FlightRulesReport

    checked, report = default_robot().checked(full_pass)
    assert report.passed, [r.describe() for r in report.failing]
    assert {r.rule for r in report.rows} >= {"clearance", "self_clearance", "fits_pass"}
    again = Plan.from_json(checked.to_json())
    assert again.flight_rules is not None
    assert FlightRulesReport.from_dict(again.flight_rules) == report
