"""Flight rules through REST: every plan is stored with its rules table, a plan
that fails one is not valid and its pass does not start (409 ``flight_rule_violation``,
audited, the pass still ``scheduled``, no command stored for the link), a plan stored without
a table is refused at start until ``POST /api/plans/{id}/check`` has checked it. SQLite and
PostgreSQL (the ``client`` fixture)."""

from __future__ import annotations

import json
import shutil
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from planner.description import EXAMPLES_DIR
from planner.plan import Plan
from server.app import create_app
from server.settings import Settings
from server.storage import repository as repo
from tests.support.api import CHEAP_PTP, OPERATOR, TOKENS, VIEWER, sessions

#: The issue's plan: its hand ends inside ETS-VII's base box.
INTO_THE_BASE: dict[str, Any] = {
    "experiment": "ptp",
    "parameters": {"goal_joints_deg": [90, 120, 60, 0, 0, 0], "settle_s": 0.25},
}


def _schedule(client: TestClient, plan_id: str, name: str, window_s: float = 1200.0) -> str:
    aos = datetime.now(UTC)  # open: a start is held to its window
    body = {
        "name": name,
        "plan_id": plan_id,
        "aos_time": aos.isoformat(),
        "los_time": (aos + timedelta(seconds=window_s)).isoformat(),
        "relay": "TDRS-W",
    }
    response = client.post("/api/passes", json=body, headers=OPERATOR)
    assert response.status_code == 201, response.text
    return str(response.json()["id"])


def _start(client: TestClient, pass_id: str, name: str) -> Any:
    body = {"confirm": f"START {name}"}
    return client.post(f"/api/passes/{pass_id}/start", json=body, headers=OPERATOR)


def _events(client: TestClient, kind: str) -> list[dict[str, Any]]:
    data = client.get("/api/events", headers=VIEWER, params={"limit": 1000}).json()["data"]
    return [e for e in data if e["kind"] == kind]


def _commands(client: TestClient, pass_id: str) -> int:
    with sessions(client)() as session:
        return len(repo.list_commands(session=session, pass_id=pass_id))


def test_a_plan_into_the_base_is_stored_invalid_and_its_pass_never_starts(
    client: TestClient,
) -> None:
    validation = client.post("/api/plans/validate", json=INTO_THE_BASE, headers=OPERATOR)
    assert validation.status_code == 200, validation.text
    checked = validation.json()
    assert checked["valid"] is False
    assert [e["code"] for e in checked["errors"]] == ["flight_rule_violation"]
    assert "clearance" in checked["errors"][0]["message"]
    assert "base_link" in checked["errors"][0]["message"]
    table = checked["flight_rules"]
    assert table["passed"] is False and table["robot"] == "ets7"
    rows = {r["rule"]: r for r in table["rows"]}
    clearance = rows["clearance"]
    assert clearance["verdict"] == "fail" and clearance["unit"] == "m"
    assert clearance["value"] < 0.0 <= clearance["limit"]  # into the box, not near it
    assert set(clearance["bodies"]) == {"hand", "base_link"}
    assert len(clearance["points_robot_m"]) == 2
    assert 0.0 < clearance["t_s"] < checked["summary"]["duration_s"]
    assert len(table["clearance"]["t_s"]) == len(table["clearance"]["min_m"]) > 100
    assert min(table["clearance"]["min_m"]) == pytest.approx(clearance["value"])
    assert checked["summary"]["experiment"] == "ptp"
    assert _events(client, "plan_created") == []  # validation stores nothing

    created = client.post("/api/plans", json=INTO_THE_BASE, headers=OPERATOR)
    assert created.status_code == 201, created.text  # stored: the user may look at it
    plan = created.json()
    assert plan["flight_rules"] == table
    assert client.get(f"/api/plans/{plan['id']}", headers=VIEWER).json() == plan
    document = client.get(f"/api/plans/{plan['id']}/document", headers=VIEWER).text
    assert json.loads(document)["flight_rules"] == table

    pass_id = _schedule(client, plan["id"], "into-the-base")
    refused = _start(client, pass_id, "into-the-base")
    assert refused.status_code == 409, refused.text
    error = refused.json()["error"]
    assert error["code"] == "flight_rule_violation"
    assert "hand" in error["message"] and "base_link" in error["message"]
    failing = error["detail"]["rows"]
    assert [r["rule"] for r in failing] == ["clearance"]
    assert failing[0] == clearance
    audit = _events(client, "pass_start_refused")
    assert len(audit) == 1 and audit[0]["pass_id"] == pass_id and audit[0]["actor"] == "otto"
    assert audit[0]["detail"]["reason"] == "flight_rule_violation"
    assert audit[0]["detail"]["rows"] == failing
    state = client.get(f"/api/passes/{pass_id}", headers=VIEWER).json()
    assert state["state"] == "scheduled" and state["epoch_ns"] is None
    assert _commands(client, pass_id) == 0
    assert _events(client, "pass_state") == []
    # the same again: no override, no state change
    assert _start(client, pass_id, "into-the-base").json()["error"]["code"] == (
        "flight_rule_violation"
    )
    assert len(_events(client, "pass_start_refused")) == 2


def test_a_plan_that_keeps_the_rules_passes_the_gate_and_fits_its_pass_s_window(
    client: TestClient,
) -> None:
    validation = client.post("/api/plans/validate", json=CHEAP_PTP, headers=OPERATOR).json()
    assert validation["valid"] is True and validation["errors"] == []
    assert validation["flight_rules"]["passed"] is True
    assert {r["verdict"] for r in validation["flight_rules"]["rows"]} == {"pass"}
    plan = client.post("/api/plans", json=CHEAP_PTP, headers=OPERATOR).json()
    assert plan["flight_rules"]["passed"] is True
    clearance = next(r for r in plan["flight_rules"]["rows"] if r["rule"] == "clearance")
    assert clearance["value"] >= clearance["limit"] == 0.10
    pass_id = _schedule(client, plan["id"], "good")
    response = _start(client, pass_id, "good")
    # past the flight rules: refused only for want of a spacecraft, as before the rules
    assert response.status_code == 409 and response.json()["error"]["code"] == "link_down"
    assert _events(client, "pass_start_refused") == []

    # The fits_pass row is taken with the pass's own window.
    rows = {r["rule"]: r for r in plan["flight_rules"]["rows"]}
    assert rows["fits_pass"]["verdict"] == "pass"  # the description's pass_window_s
    # A window that holds the plan and the scheduler's start lead, with little to spare:
    # the plan's duration against (los - aos) less that lead.
    settings = client.app.state.settings  # type: ignore[attr-defined]
    from server.operations.windows import start_lead_s

    lead_s = start_lead_s(settings)
    window = plan["duration_s"] + lead_s + 1.0
    pass_id = _schedule(client, plan["id"], "tight", window_s=window)
    assert _start(client, pass_id, "tight").json()["error"]["code"] == "link_down"
    assert _events(client, "pass_start_refused") == []


def test_a_plan_stored_without_a_table_is_refused_until_checked_then_starts(
    client: TestClient, ptp_plan: Plan
) -> None:
    """The start never computes: a plan the ground has not checked (stored before the
    rules, or imported) is refused, saying how to check it; checked, it goes on to start."""
    with sessions(client)() as session:
        record = repo.add_plan(session=session, plan=ptp_plan, created_at_ns=0)
        session.commit()
        plan_id = str(record.id)
    assert ptp_plan.flight_rules is None
    assert client.get(f"/api/plans/{plan_id}", headers=VIEWER).json()["flight_rules"] is None
    pass_id = _schedule(client, plan_id, "older")
    refused = _start(client, pass_id, "older")
    assert refused.status_code == 409
    error = refused.json()["error"]
    assert error["code"] == "flight_rules_unchecked"
    assert f"POST /api/plans/{plan_id}/check" in error["message"]
    [event] = _events(client, "pass_start_refused")
    assert event["pass_id"] == pass_id and event["detail"]["reason"] == "flight_rules_unchecked"
    assert client.get(f"/api/passes/{pass_id}", headers=VIEWER).json()["state"] == "scheduled"

    assert client.post(f"/api/plans/{plan_id}/check", headers=VIEWER).status_code == 403
    checked = client.post(f"/api/plans/{plan_id}/check", headers=OPERATOR)
    assert checked.status_code == 200, checked.text
    table = checked.json()["flight_rules"]
    assert table["passed"] is True
    assert client.get(f"/api/plans/{plan_id}", headers=VIEWER).json()["flight_rules"] == table
    [event] = _events(client, "plan_checked")
    assert event["detail"] == {"plan_id": plan_id, "robot": "ets7", "passed": True, "failing": []}
    # checked and passed: the start now goes as far as the link
    assert _start(client, pass_id, "older").json()["error"]["code"] == "link_down"
    assert client.post("/api/plans/no-such-plan/check", headers=OPERATOR).status_code == 404


@pytest.fixture(scope="module")
def into_the_base_plan() -> Plan:
    """The plan into the base, planned once, without its rules table (as an older server
    or an import would store it)."""
    from planner.catalogue import parameters_from_values, plan_experiment
    from planner.experiments import PtpParams

    params = parameters_from_values(PtpParams, INTO_THE_BASE["parameters"])
    return plan_experiment("ptp", params)


def test_a_plan_without_a_table_that_fails_its_check_is_refused_at_start(
    client: TestClient, into_the_base_plan: Plan
) -> None:
    bad = into_the_base_plan
    assert bad.flight_rules is None
    with sessions(client)() as session:
        plan_id = str(repo.add_plan(session=session, plan=bad, created_at_ns=0).id)
        session.commit()
    pass_id = _schedule(client, plan_id, "older-bad")
    checked = client.post(f"/api/plans/{plan_id}/check", headers=OPERATOR)
    assert checked.status_code == 200 and checked.json()["flight_rules"]["passed"] is False
    [event] = _events(client, "plan_checked")
    assert event["detail"]["passed"] is False and event["detail"]["failing"] == ["clearance"]
    refused = _start(client, pass_id, "older-bad")
    assert refused.status_code == 409
    assert refused.json()["error"]["code"] == "flight_rule_violation"
    assert client.get(f"/api/passes/{pass_id}", headers=VIEWER).json()["state"] == "scheduled"
    assert _commands(client, pass_id) == 0


def _no_collision_robot(folder: Path) -> Path:
    """Orihime's description under another name, its URDF stripped of every <collision>."""
    source = EXAMPLES_DIR / "orihime"
    shutil.copytree(source, folder / "bare")
    urdf = folder / "bare" / "orihime.urdf"
    text = urdf.read_text()
    out, pos = [], 0
    while (start := text.find("<collision", pos)) >= 0:
        out.append(text[pos:start])
        pos = text.index("</collision>", start) + len("</collision>")
    out.append(text[pos:])
    urdf.write_text("".join(out))
    toml = folder / "bare" / "orihime.toml"
    described = toml.read_text().replace('name = "orihime"', 'name = "bare"', 1)
    # its allowed contacts name bodies that no longer have shapes
    cut = described.find("[[flight_rules.allowed_contact]]")
    toml.write_text(described if cut < 0 else described[:cut])
    return toml


def test_a_robot_without_collision_shapes_cannot_be_shown_clear(
    database_url: str, tmp_path: Path
) -> None:
    bare = _no_collision_robot(tmp_path)
    settings = Settings(
        data_dir=tmp_path, database_url=database_url, tokens=TOKENS, robot_files=(bare,)
    )
    request = {"experiment": "ptp", "parameters": {"settle_s": 0.25}, "robot": "bare"}
    with TestClient(create_app(settings)) as client:
        validation = client.post("/api/plans/validate", json=request, headers=OPERATOR)
        assert validation.status_code == 200, validation.text
        body = validation.json()
        assert body["valid"] is False and body["flight_rules"] is None
        [error] = body["errors"]
        assert error["code"] == "no_collision_geometry"
        assert "'bare'" in error["message"] and "<collision>" in error["message"]
        created = client.post("/api/plans", json=request, headers=OPERATOR)
        assert created.status_code == 422, created.text
        assert created.json()["error"]["code"] == "no_collision_geometry"
        assert client.get("/api/plans", headers=VIEWER).json()["count"] == 0


def test_the_openapi_document_types_the_rules_table(client: TestClient) -> None:
    schemas = client.get("/openapi.json").json()["components"]["schemas"]
    row = schemas["FlightRuleRowPublic"]["properties"]
    assert set(row) >= {"rule", "value", "limit", "unit", "bound", "verdict", "t_s", "bodies"}
    assert "clearance" in row["rule"]["enum"]
    for model in ("PlanPublic", "PlanValidation"):
        assert "flight_rules" in schemas[model]["properties"]


def test_the_apis_rule_names_are_the_planners() -> None:
    """The schema's literal list (mypy needs it written out) is held to the planner's."""
    from typing import get_args

    from planner.flight_rules import RULE_NAMES
    from server.schemas.plans import FlightRuleName

    assert get_args(FlightRuleName) == RULE_NAMES
