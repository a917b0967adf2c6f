"""The clearance flown, from the measured joints of a real short pass (the cheap PTP flown
offline through the vehicle), beside the predicted one: exact against every pair asked at
every frame, close to the plan's prediction, and in the report's JSON and HTML."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from fastapi.testclient import TestClient

from planner.clearance_watch import ClearanceWatch
from planner.collision import ShapeSet, body_poses
from planner.description import default_robot
from planner.plan import Plan
from server.services.analyses import compute_analyses
from server.services.clearance import flown_clearance
from server.services.reports import build_report, render_html
from spacecraft.offline import fly_offline
from telemetry.recording import PassRecording
from tests.support.api import OPERATOR, VIEWER
from tests.support.recordings import mcap_bytes


@pytest.fixture(scope="module")
def checked_recording(ptp_plan: Plan) -> PassRecording:
    """The cheap PTP with its flight-rules report, flown offline."""
    plan, _ = default_robot().checked(ptp_plan)
    flight = fly_offline(plan, seed=3)
    return PassRecording.from_frames("checked PTP", plan, flight.epoch_ns, flight.frames)


def _every_pair_at_every_frame(recording: PassRecording) -> tuple[float, int]:
    """The least distance over every checked pair at every frame, each one asked."""
    description = default_robot()
    collision = description.collision
    assert collision is not None
    R, t = body_poses(description.model, recording.frames.joints_rad)
    shapes = ShapeSet(collision)
    frame_of = [b.joint for b in collision.bodies]
    per_frame = np.array(
        [
            min(
                shapes.distance(
                    a, b, R[s, frame_of[a]], t[s, frame_of[a]], R[s, frame_of[b]], t[s, frame_of[b]]
                ).distance_m
                for a, b in collision.pairs
            )
            for s in range(len(recording.frames))
        ]
    )
    return float(per_frame.min()), shapes.queries


def test_the_flown_minimum_is_exact_and_close_to_the_predicted(
    checked_recording: PassRecording,
) -> None:
    flown = flown_clearance(checked_recording, default_robot())
    assert flown.n_frames == flown.n_frames_total == len(checked_recording.frames)
    exact, asked = _every_pair_at_every_frame(checked_recording)
    assert flown.value_m == pytest.approx(exact, abs=1e-9)
    assert flown.n_queries < asked / 5  # the bound skips most pairs
    assert flown.passed and flown.value_m >= flown.limit_m == 0.10
    assert flown.predicted_m is not None and flown.predicted_bodies is not None
    # the servos follow the commands closely: flown and predicted agree to a millimetre
    assert flown.value_m == pytest.approx(flown.predicted_m, abs=1e-3)
    assert set(flown.bodies) == set(flown.predicted_bodies)


def test_the_live_watch_finds_the_same_minimum_at_the_same_frame(
    checked_recording: PassRecording,
) -> None:
    """One engine: the live watch, fed the frames in the link's batches and watching a
    threshold above the pass's minimum, is exact there and finds the analysis's minimum."""
    description = default_robot()
    flown = flown_clearance(checked_recording, description)
    watch = ClearanceWatch(description, flown.value_m + 0.002)
    joints = np.asarray(checked_recording.frames.joints_rad)
    live = np.concatenate(
        [watch.clearances_m(joints[i : i + 10]) for i in range(0, len(joints), 10)]
    )
    assert float(live.min()) == pytest.approx(flown.value_m, abs=1e-9)
    assert float(checked_recording.t_s()[int(np.argmin(live))]) == flown.t_s


def test_a_plan_without_a_report_has_nothing_predicted(checked_recording: PassRecording) -> None:
    bare = replace(checked_recording, plan=replace(checked_recording.plan, flight_rules=None))
    flown = flown_clearance(bare, default_robot())
    assert flown.predicted_m is None and flown.to_dict()["predicted"] is None


def test_the_report_sets_the_flown_clearance_beside_the_predicted(
    checked_recording: PassRecording,
) -> None:
    run = compute_analyses(checked_recording)
    doc = run.documents["flown_clearance"]
    assert doc["status"] == "ok", doc
    expected = flown_clearance(checked_recording, default_robot())
    assert doc["result"] == expected.to_dict()
    report = build_report(
        pass_id=None,
        name="checked PTP",
        state=None,
        experiment="ptp",
        imported=False,
        documents={kind: (d, None) for kind, d in run.documents.items()},
        figure_names=[],
    )
    [table] = [t for t in report.tables if t.id == "clearance"]
    assert table.columns == ["", "min_clearance_m", "t_s", "bodies", "limit_m", "verdict"]
    flown_row, predicted_row = table.rows
    assert flown_row == [
        "flown (measured joints)",
        expected.value_m,
        expected.t_s,
        " / ".join(expected.bodies),
        0.10,
        "pass",
    ]
    assert predicted_row[0] == "predicted (the plan's flight rules)"
    assert predicted_row[1] == expected.predicted_m and predicted_row[5] == "pass"
    page = render_html(report, {})
    assert "Clearance: flown against predicted" in page
    assert "flown (measured joints)" in page and "predicted (the plan&#x27;s flight rules)" in page


@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_the_served_report_shows_the_flown_clearance(
    client: TestClient, checked_recording: PassRecording
) -> None:
    """Through the API, on SQLite (the import, the analyses route and the report on both
    backends are test_reports_api.py's round trip). An imported plan's report is not the
    ground's word (it is stored without it): nothing predicted is set beside the flown
    clearance."""
    bare = replace(checked_recording, plan=replace(checked_recording.plan, flight_rules=None))
    response = client.post("/api/passes/import", content=mcap_bytes(bare), headers=OPERATOR)
    assert response.status_code == 201, response.text
    pass_id = response.json()["imported"]["id"]
    ran = client.post(f"/api/passes/{pass_id}/analyses", headers=OPERATOR)
    assert ran.status_code == 201, ran.text
    stored = {a["kind"]: a for a in ran.json()["data"]}["flown_clearance"]
    assert stored["status"] == "ok", stored["error"]
    expected = flown_clearance(bare, default_robot())
    assert stored["result"]["flown"]["value_m"] == pytest.approx(expected.value_m, abs=1e-12)
    assert stored["result"]["predicted"] is None
    report = client.get(f"/api/passes/{pass_id}/report", headers=VIEWER).json()
    [table] = [t for t in report["tables"] if t["id"] == "clearance"]
    assert [row[0] for row in table["rows"]] == ["flown (measured joints)"]
    assert any("no flight-rules report" in note for note in table["notes"])
    page = client.get(f"/api/passes/{pass_id}/report.html", headers=VIEWER).text
    assert "Clearance: flown against predicted" in page
