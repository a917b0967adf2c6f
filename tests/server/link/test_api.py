"""The link websocket and the control endpoints, without a spacecraft process."""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

from server.app import create_app
from server.settings import Settings
from server.storage import repository as repo
from server.storage.db import sqlite_url
from telemetry.wire import Hello, encode
from tests.server.link.harness import OPERATOR, TOKENS, VIEWER, running_ground, store_pass

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time


@pytest.fixture()
def client(tmp_path: Path) -> Iterator[TestClient]:
    with TestClient(create_app(Settings(data_dir=tmp_path, tokens=TOKENS))) as c:
        yield c


def _pass(client: TestClient) -> str:
    sessions = client.app.state.sessions  # type: ignore[attr-defined]
    return store_pass(sessions, "pass-7", (2.0, 0.0, 0.0, 0.0, 0.0, 0.0), 1.0)


@pytest.mark.parametrize(
    ("body", "status", "code"),
    [
        ({}, 422, "invalid_request"),
        ({"confirm": True}, 422, "invalid_request"),
        ({"confirm": "START pass-8"}, 422, "confirmation_mismatch"),
        ({"confirm": "start pass-7"}, 422, "confirmation_mismatch"),
        ({"confirm": "START pass-7"}, 409, "link_down"),  # right, but no spacecraft
    ],
)
def test_start_needs_the_exact_confirmation_and_the_link(
    client: TestClient, body: dict[str, object], status: int, code: str
) -> None:
    pass_id = _pass(client)
    response = client.post(f"/api/passes/{pass_id}/start", json=body, headers=OPERATOR)
    assert response.status_code == status, response.text
    assert response.json()["error"]["code"] == code
    with client.app.state.sessions() as session:  # type: ignore[attr-defined]
        assert repo.get_pass(session=session, pass_id=pass_id).state == "scheduled"
        refused = repo.list_events(session=session, kinds=["pass_control_refused"]).items
    if code == "confirmation_mismatch":
        assert [(e.actor, e.detail["confirm"]) for e in refused] == [("otto", body["confirm"])]


def test_viewers_may_read_the_link_status_but_not_start_or_abort(client: TestClient) -> None:
    pass_id = _pass(client)
    for action in ("start", "abort"):
        body = {"confirm": f"{action.upper()} pass-7"}
        response = client.post(f"/api/passes/{pass_id}/{action}", json=body, headers=VIEWER)
        assert response.status_code == 403
    status = client.get("/api/link/status", headers=VIEWER).json()
    assert status["connected"] is False and status["active_pass_id"] is None


def test_an_operator_may_abort_a_scheduled_pass(client: TestClient) -> None:
    pass_id = _pass(client)
    body = {"confirm": "ABORT pass-7", "reason": "weather at the relay"}
    response = client.post(f"/api/passes/{pass_id}/abort", json=body, headers=OPERATOR)
    assert response.status_code == 200, response.text
    assert response.json()["state"] == "aborted"
    again = client.post(f"/api/passes/{pass_id}/abort", json=body, headers=OPERATOR)
    assert again.status_code == 409


def test_the_link_replies_error_to_a_malformed_frame_and_refuses_other_roles(
    tmp_path: Path,
) -> None:
    async def session(url: str) -> tuple[list[dict[str, object]], int | None, str]:
        hello = Hello(
            vehicle="ETS-VII", onboard_time_ns=10**18, time_scale=20.0, next_telemetry_seq=0
        )
        replies: list[dict[str, object]] = []
        async with connect(url, additional_headers={"Authorization": "Bearer s-token"}) as ws:
            await ws.send(encode(hello))
            for text in (
                "{not json",
                '{"v":2,"type":"telemetry","frames":[]}',
                '{"v":1,"type":"telemetry","frames":[]}',  # version 1 is not served
            ):
                await ws.send(text)
            deadline = time.monotonic() + 5.0
            while sum(r["type"] == "error" for r in replies) < 3 and time.monotonic() < deadline:
                replies.append(json.loads(await asyncio.wait_for(ws.recv(), 5.0)))
            await ws.send(encode(hello))  # the connection is still up
        closed: ConnectionClosed | None = None
        async with connect(url, additional_headers={"Authorization": "Bearer v-token"}) as ws:
            try:
                await asyncio.wait_for(ws.recv(), 5.0)
            except ConnectionClosed as exc:
                closed = exc
        assert closed is not None and closed.rcvd is not None
        return replies, closed.rcvd.code, closed.rcvd.reason

    with running_ground(sqlite_url(tmp_path)) as ground:
        replies, code, reason = asyncio.run(session(ground.ws_url))
        status = ground.app.state.link.status()
    errors = [r for r in replies if r["type"] == "error"]
    assert "not JSON" in str(errors[0]["reason"])
    assert errors[1]["ref_type"] == "telemetry" and "frames" in str(errors[1]["reason"])
    assert "version 1 is not served" in str(errors[2]["reason"])
    assert status.errors_replied == 3
    assert code == 1008 and "viewer" in reason
