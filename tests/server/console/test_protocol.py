"""The console websocket: who may connect, requests and their replies, topics and seqs."""

from __future__ import annotations

from typing import Any

import pytest
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from server.services.link import LinkStatus
from tests.support.api import add_pass
from tests.support.console import (
    AS_VIEWER,
    CONSOLE,
    drain,
    emit_events,
    hub,
    link,
    subscribe,
    welcome,
)

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time

SUBSCRIBE: dict[str, Any] = {"v": 1, "type": "subscribe"}


@pytest.mark.parametrize(
    ("path", "headers", "first", "actor"),
    [
        ("/api/console", {"Authorization": "Bearer v-token"}, None, "vera"),
        ("/api/console", {}, {"v": 1, "type": "auth", "token": "v-token"}, "vera"),
        ("/api/console", {"Authorization": "Bearer o-token"}, None, "otto"),
    ],
    ids=["header", "auth-message", "operator"],
)
def test_viewers_and_operators_connect(
    client: TestClient,
    path: str,
    headers: dict[str, str],
    first: dict[str, Any] | None,
    actor: str,
) -> None:
    with client.websocket_connect(path, headers=headers) as ws:
        if first is not None:
            ws.send_json(first)
        hello = welcome(ws)
        assert hello["actor"] == actor and hello["epoch"] == hub(client).epoch
        assert set(hello["topics"]) == {
            "telemetry",
            "commands",
            "passes",
            "events",
            "link",
            "alarms",
        }
        assert subscribe(ws, topic="commands")["seq"] == 0


@pytest.mark.parametrize(
    ("path", "headers", "first", "says"),
    [
        ("/api/console", {}, {**SUBSCRIBE, "topic": "commands"}, "auth expected first"),
        ("/api/console", {}, {"v": 1, "type": "auth", "token": "nope"}, "unknown API token"),
        ("/api/console", {}, {"v": 1, "type": "auth", "token": "s-token"}, "spacecraft"),
        ("/api/console", {}, "not json", "auth expected first"),
        ("/api/console", {"Authorization": "Bearer nope"}, None, "unknown API token"),
        ("/api/console", {"Authorization": "Bearer s-token"}, None, "spacecraft"),
        # A token in the URL is not looked at (it would end up in access logs).
        ("/api/console?token=v-token", {}, {**SUBSCRIBE, "topic": "commands"}, "auth expected"),
    ],
    ids=[
        "no-token",
        "bad-token",
        "spacecraft",
        "garbage",
        "bad-header-token",
        "spacecraft-header",
        "query-token-ignored",
    ],
)
def test_refused_without_a_viewer_token(
    client: TestClient,
    path: str,
    headers: dict[str, str],
    first: dict[str, Any] | str | None,
    says: str,
) -> None:
    with client.websocket_connect(path, headers=headers) as ws:
        if isinstance(first, str):
            ws.send_text(first)
        elif first is not None:
            ws.send_json(first)
        with pytest.raises(WebSocketDisconnect) as refused:
            ws.receive_json()
    assert refused.value.code == 1008
    assert says in refused.value.reason
    assert hub(client).clients == 0


BAD_REQUESTS: list[tuple[str, Any, str]] = [
    ("not-json", "{not json", "not JSON"),
    ("array", "[1, 2]", "one JSON object"),
    ("no-version", {"type": "ping"}, "version None"),
    ("version-2", {"v": 2, "type": "ping"}, "version 2"),
    ("unknown-type", {"v": 1, "type": "launch"}, "unknown message type 'launch'"),
    ("unknown-topic", {**SUBSCRIBE, "topic": "weather"}, "unknown topic 'weather'"),
    ("no-topic", {**SUBSCRIBE}, "topic"),
    ("extra-field", {**SUBSCRIBE, "topic": "commands", "colour": 1}, "colour"),
    ("telemetry-no-pass", {**SUBSCRIBE, "topic": "telemetry"}, "needs a pass_id"),
    ("unknown-pass", {**SUBSCRIBE, "topic": "telemetry", "pass_id": "p-9"}, "not found"),
    ("pass-on-commands", {**SUBSCRIBE, "topic": "commands", "pass_id": "x"}, "telemetry only"),
    ("negative-since", {**SUBSCRIBE, "topic": "events", "since_seq": -1, "epoch": "e"}, "since"),
    ("string-since", {**SUBSCRIBE, "topic": "events", "since_seq": "3", "epoch": "e"}, "since"),
    ("since-no-epoch", {**SUBSCRIBE, "topic": "events", "since_seq": 0}, "needs the epoch"),
    ("rate-on-events", {**SUBSCRIBE, "topic": "events", "max_rate_hz": 10}, "telemetry only"),
    ("zero-rate", {**SUBSCRIBE, "topic": "commands", "max_rate_hz": 0}, "max_rate_hz"),
    ("not-subscribed", {"v": 1, "type": "unsubscribe", "topic": "passes"}, "not subscribed"),
    ("auth-again", {"v": 1, "type": "auth", "token": "o-token"}, "already authenticated"),
    ("too-big", {"v": 1, "type": "ping", "id": "x" * 70_000}, "exceeds 65536"),
]


@pytest.mark.parametrize(
    ("request_", "says"),
    [(r, s) for _, r, s in BAD_REQUESTS],
    ids=[i for i, _, _ in BAD_REQUESTS],
)
def test_a_bad_request_gets_an_error_and_the_socket_stays_usable(
    module_client: TestClient, request_: Any, says: str
) -> None:
    """On one application per backend (a bad request changes nothing; each case's socket is
    its own): the topic's seq is where the cases before left it, a fresh one's is 0
    (``test_viewers_and_operators_connect``)."""
    client = module_client
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        welcome(ws)
        if isinstance(request_, str):
            ws.send_text(request_)
        else:
            ws.send_json(request_)
        error = ws.receive_json()
        assert error["type"] == "error" and says in error["reason"], error
        # Still served: a subscription works and delivers the next event, seq after seq.
        seq = subscribe(ws, topic="commands")["seq"]
        [n] = [d["n"] for d in emit_events(client, ["command_stage"])]
        [message] = drain(ws)
        assert message["event"]["detail"]["n"] == n and message["seq"] == seq + 1


def test_a_binary_frame_and_a_stream_ahead_of_the_server_get_errors(client: TestClient) -> None:
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        epoch = welcome(ws)["epoch"]
        ws.send_bytes(b'{"v": 1, "type": "ping"}')
        assert "binary" in ws.receive_json()["reason"]
        emit_events(client, ["command_stage"] * 2)
        ws.send_json({**SUBSCRIBE, "topic": "commands", "since_seq": 3, "epoch": epoch})
        error = ws.receive_json()
        assert error["type"] == "error" and "ahead of the stream (last seq 2)" in error["reason"]
        assert drain(ws) == []


def test_subscribe_delivers_and_unsubscribe_stops(client: TestClient) -> None:
    pass_id = add_pass(client)
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        epoch = welcome(ws)["epoch"]
        emit_events(client, ["command_stage"])  # before: not delivered (live from now)
        reply = subscribe(ws, topic="commands")
        assert reply == {
            "v": 1,
            "type": "subscribed",
            "topic": "commands",
            "epoch": epoch,
            "seq": 1,
        }
        [detail] = emit_events(client, ["command_stage"], pass_id)
        [message] = drain(ws)
        assert message["type"] == "event" and message["topic"] == "commands"
        assert message["seq"] == 2
        event = message["event"]
        assert (event["kind"], event["actor"], event["pass_id"]) == (
            "command_stage",
            "tester",
            pass_id,
        )
        assert event["detail"] == detail
        ws.send_json({"v": 1, "type": "unsubscribe", "topic": "commands"})
        assert ws.receive_json() == {
            "v": 1,
            "type": "unsubscribed",
            "topic": "commands",
            "seq": 2,
            "reason": "requested",
        }
        emit_events(client, ["command_stage"])
        assert drain(ws) == []


def test_topics_route_events_and_number_each_stream_from_one(client: TestClient) -> None:
    kinds = ["command_stage", "pass_state", "link_hello", "commands_cancelled", "pass_state"] * 3
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        welcome(ws)
        for topic in ("commands", "passes", "events"):
            subscribe(ws, topic=topic)
        details = emit_events(client, kinds)
        messages = drain(ws)
    by_topic: dict[str, list[dict[str, Any]]] = {}
    for message in messages:
        by_topic.setdefault(message["topic"], []).append(message)
    expected = {
        "commands": [
            d["n"]
            for k, d in zip(kinds, details, strict=True)
            if k in ("command_stage", "commands_cancelled")  # an abort's one event too
        ],
        "passes": [d["n"] for k, d in zip(kinds, details, strict=True) if k == "pass_state"],
        "events": [d["n"] for d in details],
    }
    for topic, ns in expected.items():
        got = by_topic[topic]
        assert [m["event"]["detail"]["n"] for m in got] == ns
        # Each stream counts its own messages from 1, without gaps.
        assert [m["seq"] for m in got] == list(range(1, len(ns) + 1))


def test_link_status_comes_at_once_and_on_change(client: TestClient) -> None:
    console = hub(client)
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        welcome(ws)
        client.portal.call(console.push_link_status, link(client).status())  # type: ignore[union-attr]
        reply = subscribe(ws, topic="link")
        first = drain(ws)
        # The latest status is replayed straight after subscribing (a state, not a log).
        assert [m["seq"] for m in first] == [reply["seq"]]
        status = first[0]["status"]
        assert status["connected"] is False and status["frames_received"] == 0
        changed = LinkStatus(**{**status, "frames_received": 5})
        client.portal.call(console.push_link_status, changed)  # type: ignore[union-attr]
        [second] = drain(ws)
        assert second["seq"] == reply["seq"] + 1
        assert second["status"]["frames_received"] == 5
        assert second["ground_time_ns"] >= first[0]["ground_time_ns"]
