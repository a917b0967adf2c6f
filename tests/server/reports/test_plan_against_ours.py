"""The report of a pass of a robot other than ETS-VII (issue 28, part 5): Orihime's PTP,
planned with its defaults and flown offline through the simulated vehicle, analysed as the
ground does. Its first table holds the pass against its own plan's predictions, not the
flight's, says so, and each verdict follows from the numbers; ETS-VII's report keeps the
flight's table."""

from __future__ import annotations

import pytest

from planner.catalogue import parameters_from_values, plan_experiment, resolve
from planner.description import EXAMPLES_DIR, load_robot
from planner.plan import Plan
from server.schemas.analyses import ReportPublic
from server.services.analyses import compute_analyses
from server.services.report_tables import predicted_of
from server.services.reports import build_report, render_html
from spacecraft.offline import fly_offline
from telemetry.recording import PassRecording


@pytest.fixture(scope="module")
def orihime_ptp() -> tuple[Plan, ReportPublic, dict[str, object]]:
    robot = load_robot(EXAMPLES_DIR / "orihime" / "orihime.toml")
    params = parameters_from_values(
        resolve("ptp")[0], {}, defaults=robot.experiment_defaults("ptp")
    )
    plan = plan_experiment("ptp", params, robot=robot)
    flight = fly_offline(plan, robot=robot, seed=2)
    recording = PassRecording.from_frames("orihime PTP", plan, flight.epoch_ns, flight.frames)
    run = compute_analyses(recording, robot.model)
    report = build_report(
        pass_id=None,
        name=recording.name,
        state="completed",
        experiment=plan.experiment,
        imported=False,
        documents={kind: (doc, 0) for kind, doc in run.documents.items()},
        figure_names=list(run.figures),
        plan=predicted_of(plan.to_dict()),
    )
    return plan, report, dict(run.documents)


@pytest.mark.slow
def test_orihime_s_pass_is_held_against_its_own_plan(
    orihime_ptp: tuple[Plan, ReportPublic, dict[str, object]],
) -> None:
    plan, report, documents = orihime_ptp
    table = report.tables[0]
    assert table.id == "plan_against_ours"
    assert "robot orihime is not ETS-VII" in table.title
    assert any("The flight's numbers are ETS-VII's" in note for note in table.notes)
    assert not any(t.id == "flight_against_ours" for t in report.tables)
    rows = {str(row[0]): row for row in table.rows}
    ptp = next(row for text, row in rows.items() if text.startswith("Exp. 1: PTP"))
    predicted = float(plan.metrics["settling_time_after_motion_s"])
    assert ptp[2] == f"plan: {predicted:.1f} s to settle"
    # the verdict from the flown number, recomputed here
    doc = documents["pass_analysis"]
    assert isinstance(doc, dict) and doc["status"] == "ok"
    (motion,) = [m for m in doc["result"]["reaction"]["motions"] if m["kind"] == "ptp"]
    flown = motion["settling_time_s"]
    assert flown is not None
    tolerance = max(0.3 * predicted, 5.0)
    holds = abs(flown - predicted) <= tolerance
    assert ptp[-1] == ("reproduced" if holds else "not reproduced"), (flown, predicted)
    assert f"{flown:.1f} s" in str(ptp[3])
    # a PTP plan predicts nothing of the other experiments: not measured, never a pass
    gjm = next(row for text, row in rows.items() if text.startswith("Exp. 2: GJM"))
    assert gjm[-1] == "not measured"
    page = render_html(report, {})
    assert '<h2 id="plan_against_ours">' in page


def test_ets7_s_plan_keeps_the_flight_s_table(ptp_plan: Plan) -> None:
    assert predicted_of(ptp_plan.to_dict()) is None
    assert predicted_of({"experiment": "ptp", "metrics": {}}) is None  # names no robot
    other = predicted_of({"robot": "x", "robot_hash": "ab" * 32, "experiment": "ptp"})
    assert other is not None and other.robot == "x" and dict(other.metrics) == {}
