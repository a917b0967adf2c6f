"""``/api/plans``: real planner output stored and read back; refusals in the one error
shape with nothing stored."""

from __future__ import annotations

from datetime import UTC, datetime

import pytest
from fastapi.testclient import TestClient

from planner.plan import Plan
from server.storage import repository as repo
from tests.support.api import CHEAP_PTP, OPERATOR, VIEWER, sessions

NO_PLAN = "00000000-0000-0000-0000-000000000000"


def _nothing_stored(client: TestClient) -> None:
    assert client.get("/api/plans", headers=VIEWER).json()["count"] == 0
    assert client.get("/api/events", headers=VIEWER).json()["count"] == 0


@pytest.fixture(scope="module")
def shared_client(module_client: TestClient) -> TestClient:
    """One application per module and backend, for the tests that store nothing (and say
    so with ``_nothing_stored``)."""
    return module_client


def test_an_operator_plans_and_stores_a_real_experiment(client: TestClient) -> None:
    before = datetime.now(UTC)
    response = client.post("/api/plans", json=CHEAP_PTP, headers=OPERATOR)
    assert response.status_code == 201, response.text
    body = response.json()
    created_at = datetime.fromisoformat(body["created_at"])
    assert created_at.utcoffset() is not None and created_at.utcoffset().total_seconds() == 0
    assert before.replace(microsecond=0) <= created_at <= datetime.now(UTC)
    assert body["experiment"] == "ptp"
    assert body["parameters"]["settle_s"] == 0.25
    assert len(body["parameters"]["goal_joints_deg"]) == 6  # the planner's resolved pose B

    document = client.get(f"/api/plans/{body['id']}/document", headers=VIEWER)
    assert document.status_code == 200
    assert document.headers["content-type"] == "application/json"
    plan = Plan.from_json(document.text)
    assert body["duration_s"] == plan.duration_s
    assert body["n_commands"] == len(plan.command_times_s) + len(plan.acs_commands)
    assert body["metrics"] == dict(plan.metrics)
    assert [s["name"] for s in body["segments"]] == [s.name for s in plan.segments]
    assert plan.segment("settle").t_end_s - plan.segment("settle").t_start_s == 0.25

    assert client.get(f"/api/plans/{body['id']}", headers=VIEWER).json() == body
    listing = client.get("/api/plans", headers=VIEWER).json()
    assert listing["count"] == 1
    assert listing["data"][0]["id"] == body["id"]
    assert "segments" not in listing["data"][0]
    events = client.get("/api/events", headers=VIEWER).json()["data"]
    assert [(e["kind"], e["actor"], e["detail"]["plan_id"]) for e in events] == [
        ("plan_created", "otto", body["id"])
    ]


@pytest.mark.parametrize(
    ("request_body", "needle"),
    [
        ({"experiment": "warp"}, "unknown experiment 'warp'"),
        ({"experiment": "ptp", "parameters": {"speed": 1}}, "unknown parameter 'speed'"),
        ({"experiment": "ptp", "parameters": {"settle_s": "soon"}}, "settle_s"),
        ({"experiment": "ptp", "parameters": {"settle_s": True}}, "expected float"),
        ({"experiment": "ptp", "parameters": {"settle_s": 0.3}}, "multiple of 0.25 s"),
        ({"experiment": "ptp", "parameters": {"settle_s": 1e9}}, "exceeds the limit"),
        (
            {"experiment": "ptp", "parameters": {"goal_joints_deg": [400, 0, 0, 0, 0, 0]}},
            "exceeds limit",
        ),
    ],
)
def test_a_refused_plan_is_422_with_the_planners_message_and_stores_nothing(
    shared_client: TestClient, request_body: dict[str, object], needle: str
) -> None:
    response = shared_client.post("/api/plans", json=request_body, headers=OPERATOR)
    assert response.status_code == 422, response.text
    error = response.json()["error"]
    assert needle in error["message"]
    assert error["code"] in ("InvalidInput", "JointLimitExceeded")
    _nothing_stored(shared_client)


def test_a_malformed_body_is_422_in_the_error_shape(shared_client: TestClient) -> None:
    response = shared_client.post("/api/plans", json={"parameters": {}}, headers=OPERATOR)
    assert response.status_code == 422
    assert response.json()["error"]["code"] == "invalid_request"
    assert "experiment" in response.json()["error"]["message"]
    _nothing_stored(shared_client)


def test_a_label_that_could_read_as_another_is_422_naming_the_character(
    shared_client: TestClient,
) -> None:
    """A plan's ``label`` is shown and quoted to operators: it keeps a name's rule."""
    body = {"experiment": "ptp", "parameters": {"label": "A->B \u202eC"}}
    response = shared_client.post("/api/plans", json=body, headers=OPERATOR)
    assert response.status_code == 422, response.text
    error = response.json()["error"]
    assert error["code"] == "invalid_request"
    assert "U+202E RIGHT-TO-LEFT OVERRIDE" in error["message"]
    _nothing_stored(shared_client)


def test_tokens_and_roles(shared_client: TestClient) -> None:
    assert shared_client.get("/api/plans").status_code == 401
    assert (
        shared_client.post("/api/plans", json=CHEAP_PTP).json()["error"]["code"] == "unauthorized"
    )
    refused = shared_client.post("/api/plans", json=CHEAP_PTP, headers=VIEWER)
    assert refused.status_code == 403
    assert refused.json()["error"]["code"] == "forbidden"
    assert (
        shared_client.post("/api/plans/validate", json=CHEAP_PTP, headers=VIEWER).status_code == 403
    )
    _nothing_stored(shared_client)


def test_validate_plans_without_storing(shared_client: TestClient) -> None:
    ok = shared_client.post("/api/plans/validate", json=CHEAP_PTP, headers=OPERATOR).json()
    assert ok["valid"] is True and ok["errors"] == []
    assert ok["summary"]["experiment"] == "ptp"
    assert ok["summary"]["segments"][-1]["name"] == "settle"
    bad = shared_client.post(
        "/api/plans/validate",
        json={"experiment": "ptp", "parameters": {"settle_s": 0.3}},
        headers=OPERATOR,
    ).json()
    assert bad["valid"] is False and bad["summary"] is None
    assert bad["errors"][0]["code"] == "InvalidInput"
    assert "0.25 s" in bad["errors"][0]["message"]
    _nothing_stored(shared_client)


@pytest.mark.parametrize("plan_id", [NO_PLAN, "not-a-uuid"])
def test_an_unknown_plan_is_404(shared_client: TestClient, plan_id: str) -> None:
    for path in (f"/api/plans/{plan_id}", f"/api/plans/{plan_id}/document"):
        response = shared_client.get(path, headers=VIEWER)
        assert response.status_code == 404
        assert response.json()["error"]["code"] == "not_found"


def test_plans_page_newest_first(client: TestClient, ptp_plan: Plan) -> None:
    with sessions(client)() as session:
        ids = [
            repo.add_plan(session=session, plan=ptp_plan, created_at_ns=t * 10**9).id
            for t in range(5)
        ]
        session.commit()
    newest_first = ids[::-1]
    pages = [client.get(f"/api/plans?limit=2&offset={o}", headers=VIEWER).json() for o in (0, 2, 4)]
    assert [p["count"] for p in pages] == [5, 5, 5]
    assert [d["id"] for p in pages for d in p["data"]] == newest_first
    assert pages[0]["data"][0]["created_at"] == "1970-01-01T00:00:04Z"
    assert client.get("/api/plans?limit=0", headers=VIEWER).status_code == 422
    assert client.get("/api/plans?offset=-1", headers=VIEWER).status_code == 422
