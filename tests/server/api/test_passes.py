"""``/api/passes`` and a pass's commands: scheduling against a real plan, the window rules,
the audit event, listings and pages."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from typing import Any

import pytest
from fastapi.testclient import TestClient

from planner.plan import Plan
from server.operations.windows import start_lead_s
from server.settings import Settings
from server.storage import repository as repo
from tests.server.storage.factories import T0_NS, make_commands
from tests.support.api import OPERATOR, VIEWER, sessions

AOS = datetime(2031, 3, 4, 5, 6, 7, 250000, tzinfo=UTC)
#: The start lead of the default settings at time scale 1 (31.25 s: ``uplink_start_lead_s``,
#: 1 s for the start and the grid step): the plan starts at most this long after the start,
#: so that its first command can be sent again if the relay loses it.
LEAD_S = start_lead_s(Settings())


def _stored_plan(client: TestClient, plan: Plan) -> str:
    with sessions(client)() as session:
        plan_id = repo.add_plan(session=session, plan=plan, created_at_ns=0).id
        session.commit()
    return plan_id


def _request(plan_id: str, window_s: float, **extra: Any) -> dict[str, Any]:
    return {
        "plan_id": plan_id,
        "name": "ETS-VII pass 12",
        "aos_time": AOS.isoformat(),
        "los_time": (AOS + timedelta(seconds=window_s)).isoformat(),
        **extra,
    }


def _nothing_scheduled(client: TestClient) -> None:
    assert client.get("/api/passes", headers=VIEWER).json()["count"] == 0
    assert client.get("/api/events", headers=VIEWER).json()["count"] == 0


def test_an_operator_schedules_a_pass_of_a_real_plan(client: TestClient, ptp_plan: Plan) -> None:
    plan_id = _stored_plan(client, ptp_plan)
    window_s = ptp_plan.duration_s + LEAD_S  # exactly enough
    response = client.post("/api/passes", json=_request(plan_id, window_s), headers=OPERATOR)
    assert response.status_code == 201, response.text
    body = response.json()
    assert body["state"] == "scheduled" and body["state_reason"] is None
    assert body["relay"] == "TDRS" and body["plan_id"] == plan_id and body["version"] == 1
    assert datetime.fromisoformat(body["aos_time"]) == AOS
    assert body["aos_time"] == "2031-03-04T05:06:07.250000Z"
    assert datetime.fromisoformat(body["los_time"]) == AOS + timedelta(seconds=window_s)

    assert client.get(f"/api/passes/{body['id']}", headers=VIEWER).json() == body
    events = client.get(f"/api/events?pass_id={body['id']}", headers=VIEWER).json()
    assert events["count"] == 1
    event = events["data"][0]
    assert (event["kind"], event["actor"], event["pass_id"]) == (
        "pass_scheduled",
        "otto",
        body["id"],
    )
    aos_ns = (AOS - datetime(1970, 1, 1, tzinfo=UTC)) // timedelta(microseconds=1) * 1000
    assert event["detail"]["aos_time_ns"] == aos_ns


@pytest.fixture(scope="module")
def plan_to_refuse(module_client: TestClient, ptp_plan: Plan) -> tuple[TestClient, str]:
    """One application per backend for the refusals, with a stored plan: a refusal stores
    nothing, so after each of them there is still no pass and no event."""
    return module_client, _stored_plan(module_client, ptp_plan)


@pytest.mark.parametrize(
    ("change", "status", "code"),
    [
        ({"window_s": -1.0}, 422, "window_reversed"),
        ({"window_s": 0.0}, 422, "window_reversed"),
        ({"short_by_s": 0.25}, 409, "plan_exceeds_window"),
        ({"name": ""}, 422, "invalid_request"),
        ({"name": "x" * 129}, 422, "invalid_request"),
        ({"relay": ""}, 422, "invalid_request"),
        ({"aos_time": "2031-03-04T05:06:07"}, 422, "invalid_request"),  # no zone
        ({"aos_time": "1969-12-31T23:59:59Z"}, 422, "time_out_of_range"),
        ({"plan_id": "00000000-0000-0000-0000-000000000000"}, 404, "not_found"),
        ({"plan_id": "nonsense"}, 404, "not_found"),
    ],
)
def test_a_refused_pass_names_its_reason_and_stores_nothing(
    plan_to_refuse: tuple[TestClient, str],
    ptp_plan: Plan,
    change: dict[str, Any],
    status: int,
    code: str,
) -> None:
    client, plan_id = plan_to_refuse
    change = dict(change)  # shared by the backends' runs
    window_s = change.pop("window_s", ptp_plan.duration_s + LEAD_S - change.pop("short_by_s", 0))
    body = {**_request(plan_id, window_s), **change}
    response = client.post("/api/passes", json=body, headers=OPERATOR)
    assert response.status_code == status, response.text
    error = response.json()["error"]
    assert error["code"] == code and error["message"]
    _nothing_scheduled(client)


def test_a_name_that_could_read_as_another_is_refused_naming_the_character(
    client: TestClient, ptp_plan: Plan
) -> None:
    """Operators read a pass's name and type it back to start or abort it: a bidi control
    (``START pass \u202e1`` reads as another pass), a zero-width or other invisible
    character, a C1 control, a separator or a noncharacter is refused, 422 with the
    character named; letters of any script and combining accents are names."""
    plan_id = _stored_plan(client, ptp_plan)
    window_s = ptp_plan.duration_s + LEAD_S
    refused = {
        "pass \u202e1 tnega": "U+202E RIGHT-TO-LEFT OVERRIDE",
        "pass\u200d1": "U+200D ZERO WIDTH JOINER",
        "pass\u2066x\u2069": "U+2066 LEFT-TO-RIGHT ISOLATE",
        "pass\x851": "U+0085, a control character",
        "two\u2028lines": "U+2028 LINE SEPARATOR",
        "pass\uffff": "U+FFFF, a noncharacter",
    }
    for name, said in refused.items():
        body = {**_request(plan_id, window_s), "name": name}
        response = client.post("/api/passes", json=body, headers=OPERATOR)
        assert response.status_code == 422, (name, response.text)
        error = response.json()["error"]
        assert error["code"] == "invalid_request" and said in error["message"], error
    _nothing_scheduled(client)
    for name in ("軌道 pass", "café́ 1", "🛰 pass"):
        body = {**_request(plan_id, window_s), "name": name}
        response = client.post("/api/passes", json=body, headers=OPERATOR)
        assert response.status_code == 201, response.text
        assert response.json()["name"] == name


def test_tokens_and_roles(client: TestClient, ptp_plan: Plan) -> None:
    body = _request(_stored_plan(client, ptp_plan), 3600)
    assert client.post("/api/passes", json=body).status_code == 401
    assert client.post("/api/passes", json=body, headers=VIEWER).status_code == 403
    assert client.get("/api/passes").status_code == 401
    assert client.get("/api/events").status_code == 401
    _nothing_scheduled(client)


def test_passes_list_in_aos_order_filtered_by_state(client: TestClient, ptp_plan: Plan) -> None:
    plan_id = _stored_plan(client, ptp_plan)
    ids = []
    for hours in (3, 1, 2):
        request = _request(plan_id, 3600)
        aos = AOS + timedelta(hours=hours)
        request.update(aos_time=aos.isoformat(), los_time=(aos + timedelta(hours=1)).isoformat())
        ids.append(client.post("/api/passes", json=request, headers=OPERATOR).json()["id"])
    with sessions(client)() as session:
        repo.update_pass_state(
            session=session,
            pass_id=ids[0],
            expected_version=1,
            state="aborted",
            updated_at_ns=1,
            reason="operator abort",
        )
        session.commit()
    everything = client.get("/api/passes", headers=VIEWER).json()
    assert everything["count"] == 3
    assert [p["id"] for p in everything["data"]] == [ids[1], ids[2], ids[0]]
    aborted = client.get("/api/passes?state=aborted", headers=VIEWER).json()
    assert [(p["id"], p["state_reason"]) for p in aborted["data"]] == [(ids[0], "operator abort")]
    both = client.get("/api/passes?state=aborted&state=scheduled&limit=1&offset=1", headers=VIEWER)
    assert both.json()["count"] == 3 and both.json()["data"][0]["id"] == ids[2]
    bad = client.get("/api/passes?state=lost", headers=VIEWER)
    assert bad.status_code == 422 and bad.json()["error"]["code"] == "invalid_request"
    assert client.get(f"/api/passes/{plan_id}", headers=VIEWER).status_code == 404


def test_commands_page_with_each_stages_time(client: TestClient, ptp_plan: Plan) -> None:
    plan_id = _stored_plan(client, ptp_plan)
    pass_id = client.post("/api/passes", json=_request(plan_id, 3600), headers=OPERATOR).json()[
        "id"
    ]
    queued_ns = 1_900_000_000_123_456_000
    with sessions(client)() as session:
        repo.add_commands(
            session=session, pass_id=pass_id, commands=make_commands(6), queued_at_ns=queued_ns
        )
        repo.update_command_stage(
            session=session, pass_id=pass_id, seq=0, stage="sent", time_ns=queued_ns + 10**9
        )
        repo.update_command_stage(
            session=session, pass_id=pass_id, seq=1, stage="executed", time_ns=T0_NS + 7
        )
        session.commit()
    url = f"/api/passes/{pass_id}/commands"
    every = client.get(url, headers=VIEWER).json()
    assert every["count"] == 6
    assert [c["seq"] for c in every["data"]] == list(range(6))
    first, second = every["data"][:2]
    assert first["kind"] == "acs" and first["payload"]["mode"] == "free_drift"
    assert first["queued_at"] == "2030-03-17T17:46:40.123456Z"
    assert datetime.fromisoformat(first["sent_at"]) - datetime.fromisoformat(
        first["queued_at"]
    ) == timedelta(seconds=1)
    assert second["stage"] == "executed" and second["executed_at_ns"] == T0_NS + 7
    assert second["sent_at"] is None and second["execute_time_ns"] == T0_NS + 250_000_000

    queued = client.get(f"{url}?stage=queued&limit=2&offset=1", headers=VIEWER).json()
    assert queued["count"] == 4
    assert [c["seq"] for c in queued["data"]] == [3, 4]
    assert client.get(f"{url}?stage=lost", headers=VIEWER).status_code == 422
    missing = client.get(
        "/api/passes/00000000-0000-0000-0000-000000000000/commands", headers=VIEWER
    )
    assert missing.status_code == 404


def test_rest_side_events_reach_the_consoles_once_committed(
    client: TestClient, ptp_plan: Plan
) -> None:
    """Every REST-side event write is published too (issue 23): scheduling a pass, and a
    refused pass control, reach the publisher the consoles subscribe to, as stored."""
    published: list[dict[str, Any]] = []
    unsubscribe = client.app.state.publisher.subscribe(  # type: ignore[attr-defined]
        lambda recorded: published.append(recorded.document())
    )
    try:
        plan_id = _stored_plan(client, ptp_plan)
        body = _request(plan_id, ptp_plan.duration_s + LEAD_S)
        pass_id = client.post("/api/passes", json=body, headers=OPERATOR).json()["id"]
        refused = client.post(
            f"/api/passes/{pass_id}/abort", json={"confirm": "ABORT nothing"}, headers=OPERATOR
        )
        assert refused.status_code == 422
    finally:
        unsubscribe()
    stored = client.get(f"/api/events?pass_id={pass_id}", headers=VIEWER).json()["data"]
    assert [e["kind"] for e in published] == ["pass_scheduled", "pass_control_refused"]
    by_id = {e["id"]: e for e in stored}
    for event in published:
        row = by_id[event["id"]]
        assert event["detail"] == row["detail"] and event["pass_id"] == pass_id
    assert published[1]["detail"] == {"action": "abort", "confirm": "ABORT nothing"}
