"""``POST /api/vehicle/safe-exit`` at the API: the operator's role, the typed confirmation,
and the refusals with their reasons; a start refused while the vehicle is safe. The vehicle
here is a connection of the real link that records what the ground sends and says what the
test makes it say (the exit with a simulated vehicle, resends under loss included, is in
tests/server/link/test_safing_sim.py)."""

from __future__ import annotations

import time
from typing import Any

from fastapi.testclient import TestClient
from sqlalchemy import select

from server.services.dbworker import Database
from server.services.link import Connection, GroundLink
from server.storage.models import EventRecord
from telemetry.wire import Hello, SafeExit, Safing, SafingTrigger, decode_ground, encode
from tests.server.link.harness import add_plan_and_pass
from tests.server.storage.factories import T0_NS, make_plan
from tests.support.api import OPERATOR, VIEWER, sessions

TRIGGER = SafingTrigger(quantity="joint_tracking_error_deg", channel="joint3", value=6.2, limit=3.0)


class Vehicle:
    """A spacecraft connection on the app's link: what the ground sends is kept."""

    def __init__(self, client: TestClient) -> None:
        self.link: GroundLink = client.app.state.link  # type: ignore[attr-defined]
        self.sent: list[str] = []
        portal = client.portal
        assert portal is not None
        self.portal = portal

        async def keep(text: str) -> None:
            self.sent.append(text)

        async def close(_: int, __: str) -> None:
            return None

        self.conn = Connection(actor="ets7", send_text=keep, close=close)
        hello = Hello(
            vehicle="ETS-VII", onboard_time_ns=T0_NS, time_scale=1.0, next_telemetry_seq=0
        )
        portal.call(self.link.attach, self.conn)
        self.say(hello)

    def say(self, message: Any) -> None:
        self.portal.call(self.link.handle, self.conn, encode(message))

    def safe_exits(self) -> list[int]:
        out = []
        for text in self.sent:
            message = decode_ground(text)
            if isinstance(message, SafeExit):
                out.append(message.request_id)
        return out


def _safe(at_s: float = 1.0) -> Safing:
    since = T0_NS + round(at_s * 1e9)
    return Safing(
        state="safe", since_time_ns=since, trigger=TRIGGER, cancelled=4, onboard_time_ns=since
    )


def _kinds(client: TestClient) -> list[tuple[str, str, dict[str, Any]]]:
    with sessions(client)() as session:
        rows = session.scalars(select(EventRecord).order_by(EventRecord.id))
        return [(e.kind, e.actor, e.detail) for e in rows]


def _exit(client: TestClient, confirm: str, headers: dict[str, str] = OPERATOR) -> Any:
    return client.post("/api/vehicle/safe-exit", json={"confirm": confirm}, headers=headers)


def test_a_viewer_cannot_take_the_vehicle_out_of_safe(client: TestClient) -> None:
    vehicle = Vehicle(client)
    vehicle.say(_safe())
    response = _exit(client, "EXIT SAFE ETS-VII", VIEWER)
    assert response.status_code == 403
    assert vehicle.safe_exits() == []


def test_safe_exit_without_a_link_is_refused_with_the_reason(client: TestClient) -> None:
    response = _exit(client, "EXIT SAFE ETS-VII")
    assert response.status_code == 503
    assert response.json()["error"]["code"] == "link_down"
    assert "no spacecraft is connected" in response.json()["error"]["message"]
    assert response.headers["Retry-After"]


def test_safe_exit_needs_a_confirmation(client: TestClient) -> None:
    missing = client.post("/api/vehicle/safe-exit", json={}, headers=OPERATOR)
    assert missing.status_code == 422
    extra = client.post(
        "/api/vehicle/safe-exit", json={"confirm": "x", "force": True}, headers=OPERATOR
    )
    assert extra.status_code == 422
    assert "vehicle_safe_exit_requested" not in [k for k, _, _ in _kinds(client)]


def test_a_nominal_vehicle_is_not_taken_out_of_safe(client: TestClient) -> None:
    vehicle = Vehicle(client)
    response = _exit(client, "EXIT SAFE ETS-VII")
    assert response.status_code == 409
    assert response.json()["error"]["code"] == "vehicle_not_safe"
    assert vehicle.safe_exits() == []


def test_the_exit_of_a_safe_vehicle_with_its_refusals(client: TestClient) -> None:
    vehicle = Vehicle(client)
    pass_id = add_plan_and_pass(
        sessions(client), make_plan(40), "after-safing", now_ns=time.time_ns(), window_s=3600.0
    )
    vehicle.say(_safe())
    status = client.get("/api/link/status", headers=VIEWER).json()
    assert status["vehicle_mode"] == "safe"
    assert status["safing"]["trigger"]["channel"] == "joint3"
    assert status["safing"]["since_time_ns"] == T0_NS + 10**9
    # no pass starts while the vehicle is safe
    start = client.post(
        f"/api/passes/{pass_id}/start", json={"confirm": "START after-safing"}, headers=OPERATOR
    )
    assert start.status_code == 409, start.text
    assert start.json()["error"]["code"] == "vehicle_safe"
    # a wrong confirmation: 422 naming the text expected, audited, nothing sent
    wrong = _exit(client, "EXIT SAFE ETS-8")
    assert wrong.status_code == 422
    assert wrong.json()["error"]["code"] == "confirmation_mismatch"
    assert "'EXIT SAFE ETS-VII'" in wrong.json()["error"]["message"]
    assert vehicle.safe_exits() == []
    refused = [(a, d) for k, a, d in _kinds(client) if k == "pass_control_refused"]
    assert refused == [("otto", {"action": "EXIT SAFE", "confirm": "EXIT SAFE ETS-8"})]
    # the right one: 202 with the request's id, audited, the telecommand sent
    accepted = _exit(client, "EXIT SAFE ETS-VII")
    assert accepted.status_code == 202, accepted.text
    request_id = accepted.json()["request_id"]
    assert vehicle.safe_exits() == [request_id]
    requested = [(a, d) for k, a, d in _kinds(client) if k == "vehicle_safe_exit_requested"]
    assert requested == [("otto", {"request_id": request_id, "vehicle": "ETS-VII"})]
    # the vehicle's answer ends the episode; the link status and the events show it
    vehicle.say(
        Safing(
            state="nominal",
            since_time_ns=T0_NS + 10**9,
            exit_request_id=request_id,
            onboard_time_ns=T0_NS + 9 * 10**9,
        )
    )
    status = client.get("/api/link/status", headers=VIEWER).json()
    assert status["vehicle_mode"] == "nominal"
    assert status["safing"]["exit_request_id"] == request_id
    db: Database = client.app.state.db  # type: ignore[attr-defined]
    vehicle.portal.call(db.drain)
    exited = [d for k, _, d in _kinds(client) if k == "vehicle_safe_exited"]
    assert [d["request_id"] for d in exited] == [request_id]
    again = _exit(client, "EXIT SAFE ETS-VII")
    assert again.status_code == 409
    assert again.json()["error"]["code"] == "vehicle_not_safe"
    assert vehicle.safe_exits() == [request_id]
