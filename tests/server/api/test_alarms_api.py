"""Alarms through the service as a console and a client see them: raised by frames the link
stores, pushed on the ``alarms`` topic, listed by ``GET /api/alarms``, acknowledged by an
operator only (``POST /api/alarms/{id}/acknowledge``); SQLite and PostgreSQL."""

from __future__ import annotations

import uuid
from typing import Any

from fastapi.testclient import TestClient

from planner.limits import Severity
from server.services.alarms import AlarmService
from tests.server.alarms.rig import TRACKING, frame, value_in
from tests.support.api import add_pass
from tests.support.console import AS_VIEWER, CONSOLE, FakeSpacecraft, drain, subscribe, welcome

VIEWER = {"Authorization": "Bearer v-token"}
OPERATOR = {"Authorization": "Bearer o-token"}


def _settled(client: TestClient) -> None:
    alarms: AlarmService = client.app.state.alarms  # type: ignore[attr-defined]
    assert client.portal is not None
    client.portal.call(alarms.settled)


def _raise(client: TestClient, pass_id: str, spacecraft: FakeSpacecraft) -> None:
    """Joint 2 enters its warning band at frame 1 and leaves it at frame 2."""
    warning = value_in(TRACKING, Severity.WARNING)
    spacecraft.send([frame(0), frame(1, {1: warning})])
    _settled(client)
    spacecraft.send([frame(2)])
    _settled(client)


def test_the_alarms_topic_pushes_raise_clear_and_acknowledgement(client: TestClient) -> None:
    pass_id = add_pass(client)
    spacecraft = FakeSpacecraft(client, pass_id)
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        welcome(ws)
        assert subscribe(ws, topic="alarms")["seq"] == 0
        _raise(client, pass_id, spacecraft)
        pushed = [m for m in drain(ws) if m["type"] == "alarm"]
        assert [(m["topic"], m["seq"]) for m in pushed] == [("alarms", 1), ("alarms", 2)]
        raised, cleared = (m["alarm"] for m in pushed)
        assert (raised["channel"], raised["current_severity"], raised["raised_frame_seq"]) == (
            "joint2",
            "warning",
            1,
        )
        assert (cleared["id"], cleared["state"]) == (raised["id"], "cleared")
        reply = client.post(
            f"/api/alarms/{raised['id']}/acknowledge", json={"comment": "ok"}, headers=OPERATOR
        )
        assert reply.status_code == 200, reply.text
        [acked] = [m["alarm"] for m in drain(ws) if m["type"] == "alarm"]
        assert (acked["acknowledged"], acked["acknowledged_by"], acked["comment"]) == (
            True,
            "otto",
            "ok",
        )


def test_list_and_acknowledge_with_their_refusals(client: TestClient) -> None:
    pass_id = add_pass(client)
    other = add_pass(client, "pass-2")
    _raise(client, pass_id, FakeSpacecraft(client, pass_id))

    def listed(**query: Any) -> list[dict[str, Any]]:
        reply = client.get("/api/alarms", params=query, headers=VIEWER)
        assert reply.status_code == 200, reply.text
        body = reply.json()
        assert body["count"] == len(body["alarms"])
        alarms: list[dict[str, Any]] = body["alarms"]
        return alarms

    [alarm] = listed(**{"pass": pass_id})
    assert alarm["severity"] == "warning" and alarm["state"] == "cleared"
    assert [e["severity"] for e in alarm["timeline"]] == ["warning", None]
    assert listed(**{"pass": other}) == []
    assert [a["id"] for a in listed(active="true")] == [alarm["id"]]
    assert listed(active="false") == []

    url = f"/api/alarms/{alarm['id']}/acknowledge"
    refused = client.post(url, json={"comment": None}, headers=VIEWER)
    assert refused.status_code == 403 and refused.json()["error"]["code"] == "forbidden"
    assert listed(active="true") != []  # a viewer's attempt changed nothing

    done = client.post(url, json={}, headers=OPERATOR)
    assert done.status_code == 200, done.text
    assert (done.json()["acknowledged"], done.json()["comment"]) == (True, None)
    assert listed(active="true") == [] and [a["id"] for a in listed(active="false")] == [
        alarm["id"]
    ]

    again = client.post(url, json={"comment": "twice"}, headers=OPERATOR)
    assert again.status_code == 409
    assert again.json()["error"]["code"] == "already_acknowledged"
    assert "otto" in again.json()["error"]["message"]

    unknown = client.post(f"/api/alarms/{uuid.uuid4()}/acknowledge", json={}, headers=OPERATOR)
    assert (unknown.status_code, unknown.json()["error"]["code"]) == (404, "alarm_not_found")
    not_an_id = client.post("/api/alarms/nope/acknowledge", json={}, headers=OPERATOR)
    assert not_an_id.status_code == 404

    # bad input: a 4xx with the reason, never a 500
    too_long = client.post(url, json={"comment": "x" * 501}, headers=OPERATOR)
    assert too_long.status_code == 422 and "comment" in too_long.text
    extra = client.post(url, json={"comment": "a", "severity": "watch"}, headers=OPERATOR)
    assert extra.status_code == 422
    no_pass = client.get("/api/alarms", params={"pass": str(uuid.uuid4())}, headers=VIEWER)
    assert no_pass.status_code == 404
    assert client.get("/api/alarms", params={"pass": "nope"}, headers=VIEWER).status_code == 404
    bad_flag = client.get("/api/alarms", params={"active": "maybe"}, headers=VIEWER)
    assert bad_flag.status_code == 422
    assert client.get("/api/alarms").status_code == 401
