"""The flight-rules check of the whole ETS-VII demo pass against the planning of that pass.

Baseline measured in the same run: planning the pass (every experiment and one prediction of
the whole pass, ``plan_experiment("pass")``). Figure: checking that plan against every rule
(the servos' response on the fine grid, the clearance of every pair exact at every sample,
the attitude, wheel, joint-limit, hand-speed and window rules), its ratio to the planning,
and coal's distance queries per second within the check. Target (flight-rules issue): the
check under 20 % of the planning time.
"""

from __future__ import annotations

from _common import best_of, emit

from planner.catalogue import parameters_from_values, plan_experiment, resolve
from planner.description import default_robot


def main() -> None:
    robot = default_robot()
    params_type, _ = resolve("pass")
    params = parameters_from_values(params_type, {})
    plans = []
    planning_s = best_of(lambda: plans.append(plan_experiment("pass", params)), repeat=2)
    plan = plans[-1]
    reports = []
    check_s = best_of(lambda: reports.append(robot.check_plan(plan)), repeat=3)
    report = reports[-1]
    figures = {
        "baseline_plan_pass_s": planning_s,
        "check_pass_s": check_s,
        "check_over_planning": check_s / planning_s,
        "plan_duration_s": plan.duration_s,
        "step_s": report.step_s,
        "samples": report.n_samples,
        "pairs": report.n_pairs,
        "distance_queries": report.n_queries,
        "distance_queries_per_s": report.n_queries / check_s,
        "queries_brute_force_would_ask": report.n_samples * report.n_pairs,
        "min_clearance_m": report.row("clearance").value,
        "min_self_clearance_m": report.row("self_clearance").value,
    }
    emit(
        "flight_rules",
        figures,
        {"check_under_20_percent_of_planning": check_s < 0.2 * planning_s},
    )


if __name__ == "__main__":
    main()
