"""``POST /api/plans/documents`` never trusts the document's prediction: the ground predicts
the plan again from its commands, refuses a document whose prediction differs (422 naming the
quantity, the time and both values, nothing stored) and stores its own prediction in place of
one within the tolerance (docs/planning.md, "Uploading a plan document")."""

from __future__ import annotations

import json
from typing import Any

import pytest
from fastapi.testclient import TestClient

from planner.catalogue import parameters_from_values, plan_experiment
from planner.description import default_robot
from planner.experiments import PtpParams
from planner.plan import Plan
from server.operations.planning import check
from tests.support.api import OPERATOR, VIEWER

ROUTE = "/api/plans/documents"


@pytest.fixture(scope="module")
def drifting_plan() -> Plan:
    """A real PTP in free drift whose base turns past the 2 deg attitude rule."""
    params = parameters_from_values(
        PtpParams,
        {"settle_s": 0.25, "acs_feedback": False, "goal_joints_deg": [60, 45, -45, 0, 0, 0]},
    )
    return plan_experiment("ptp", params)


def _failing(document: dict[str, Any]) -> list[str]:
    return [r["rule"] for r in document["flight_rules"]["rows"] if r["verdict"] == "fail"]


def _refusal(client: TestClient, document: dict[str, Any]) -> dict[str, Any]:
    response = client.post(ROUTE, content=json.dumps(document), headers=OPERATOR)
    assert response.status_code == 422, response.text
    error: dict[str, Any] = response.json()["error"]
    assert error["code"] == "invalid_plan_document", error
    assert client.get("/api/plans", headers=VIEWER).json()["count"] == 0
    return error


def test_a_prediction_forged_to_pass_the_attitude_rule_is_refused(
    module_client: TestClient, drifting_plan: Plan
) -> None:
    genuine = check(drifting_plan, default_robot())
    assert [r.rule for r in genuine.report.failing] == ["attitude_excursion_free_drift"]
    document = json.loads(drifting_plan.to_json())
    prediction = document["prediction"]
    rows = len(prediction["t_s"])
    prediction["quat_orbit_from_base_xyzw"] = [[0.0, 0.0, 0.0, 1.0]] * rows  # a still base
    prediction["rpy_base_rad"] = [[0.0, 0.0, 0.0]] * rows
    # as the document says, the plan would pass: the forgery works if the ground believes it
    assert check(Plan.from_dict(document), default_robot()).passed

    error = _refusal(module_client, document)
    detail = error["detail"]
    assert detail["quantity"] == "quat_orbit_from_base_xyzw"
    assert detail["document"] == (0.0 if detail["component"] < 3 else 1.0)
    quats = drifting_plan.prediction.quat_orbit_from_base_xyzw
    k = drifting_plan.prediction.t_s.tolist().index(detail["t_s"])
    assert detail["ground"] == quats[k, detail["component"]]
    assert abs(detail["ground"] - detail["document"]) > detail["tolerance"]
    # the first row the ground's base has turned by more than the tolerance
    assert k > 0 and abs(quats[:k] - [0.0, 0.0, 0.0, 1.0]).max() <= detail["tolerance"]
    assert "its prediction is not the ground's: quat_orbit_from_base_xyzw" in error["message"]
    assert f"at t = {detail['t_s']:.2f} s" in error["message"]


def test_an_edited_wheel_momentum_is_refused_naming_it(
    module_client: TestClient, ptp_plan: Plan
) -> None:
    document = json.loads(ptp_plan.to_json())
    wheels = document["prediction"]["wheel_momentum_nms"]
    k = len(wheels) // 2
    true_value = wheels[k][2]
    wheels[k][2] = true_value - 0.01

    detail = _refusal(module_client, document)["detail"]
    assert detail == {
        "quantity": "wheel_momentum_nms",
        "component": 2,
        "t_s": float(ptp_plan.prediction.t_s[k]),
        "document": true_value - 0.01,
        "ground": true_value,
        "unit": "N m s",
        "tolerance": 1e-6,
    }


def test_a_prediction_within_the_tolerance_is_stored_as_the_grounds(
    client: TestClient, drifting_plan: Plan
) -> None:
    document = json.loads(drifting_plan.to_json())
    genuine = json.loads(drifting_plan.to_json())["prediction"]
    document["prediction"]["wheel_momentum_nms"][3][0] += 1e-8
    document["prediction"]["hand_pos_orbit_m"][-1][1] -= 1e-8
    response = client.post(ROUTE, content=json.dumps(document), headers=OPERATOR)
    assert response.status_code == 201, response.text
    stored = json.loads(
        client.get(f"/api/plans/{response.json()['id']}/document", headers=VIEWER).text
    )
    assert stored["prediction"] == genuine  # the planner's numbers, not the file's
    assert stored["commands"] == document["commands"]
    # a genuine plan that fails a rule is stored failing (a pass of it will not start)
    assert _failing(stored) == ["attitude_excursion_free_drift"]
