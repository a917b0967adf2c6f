"""A console's side of the websocket protocol, as the console tests speak it: control
messages, replays opened and run to a state, telemetry messages read back as rows."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from starlette.testclient import WebSocketTestSession

from planner.plan import Plan
from spacecraft.offline import OfflineFlight


def frames_of(messages: list[dict[str, Any]]) -> dict[int, dict[str, Any]]:
    """Frame seq -> its values, from telemetry messages (columns to rows)."""
    out: dict[int, dict[str, Any]] = {}
    for message in messages:
        columns = message["columns"]
        assert all(len(c) == message["count"] for c in columns.values())
        for i, seq in enumerate(columns["seq"]):
            out[seq] = {name: values[i] for name, values in columns.items()}
    return out


Flight = tuple[Plan, OfflineFlight]


def send(ws: WebSocketTestSession, type_: str, **fields: Any) -> None:
    ws.send_json({"v": 1, "type": type_, **fields})


def open_replay(ws: WebSocketTestSession, pass_id: str, **fields: Any) -> dict[str, Any]:
    send(ws, "replay_open", pass_id=pass_id, **fields)
    reply: dict[str, Any] = ws.receive_json()
    assert reply["type"] == "replay_opened", reply
    return reply


def until_state(
    ws: WebSocketTestSession, done: Callable[[dict[str, Any]], bool]
) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Replay data up to the first ``replay_state`` for which ``done`` holds (other states,
    e.g. progress reports, are passed over)."""
    data = []
    while True:
        message: dict[str, Any] = ws.receive_json()
        if message.get("topic") == "replay":
            data.append(message)
        elif message["type"] == "replay_state" and done(message):
            return data, message
        else:
            assert message["type"] == "replay_state", message


def until_finished(ws: WebSocketTestSession) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    return until_state(ws, lambda m: bool(m["finished"]))
