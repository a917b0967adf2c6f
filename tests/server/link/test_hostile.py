"""Hostile frames on the real link websocket, on SQLite and PostgreSQL: nesting beyond the
parser, NUL and other control characters in what the vehicle says. Each gets an ``error``
reply (or, for an ``error`` message, is stored escaped and never answered), nothing the
databases refuse reaches them, and the session stays up for the next good message."""

from __future__ import annotations

import asyncio
import json
import time
from typing import Any

import httpx
import pytest
from websockets.asyncio.client import ClientConnection, connect

from server.storage import repository as repo
from telemetry.wire import MAX_DEPTH, Hello, Pong, encode
from tests.server.link.harness import VIEWER, Ground, running_ground

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time

#: ground s: the malformed messages' audit interval (5 s by default), short for the test
INTERVAL_S = 0.5
HELLO = Hello(vehicle="ETS-VII", onboard_time_ns=10**18, time_scale=20.0, next_telemetry_seq=0)


async def _next_error(ws: ClientConnection) -> dict[str, Any]:
    """The next ``error`` reply (the ground's pings, once greeted, are passed over)."""
    deadline = time.monotonic() + 10.0
    while True:
        reply = json.loads(await asyncio.wait_for(ws.recv(), deadline - time.monotonic()))
        if reply["type"] == "error":
            return dict(reply)


async def _session(ground: Ground) -> dict[str, Any]:
    hello = json.loads(encode(HELLO))
    headers = {"Authorization": "Bearer s-token"}
    errors: dict[str, Any] = {}
    async with connect(ground.ws_url, additional_headers=headers) as ws:
        await ws.send("[" * 10_000)  # 10 KB of brackets: RecursionError in json.loads
        errors["brackets"] = await _next_error(ws)
        await ws.send('{"v":2,"type":"hello","x":' + "[" * 20 + "]" * 20 + "}")
        errors["deep"] = await _next_error(ws)
        await ws.send(json.dumps({**hello, "vehicle": "ETS\x00VII"}))
        errors["hello_nul"] = await _next_error(ws)
        await ws.send(json.dumps({**hello, "vehicle": "ETS\x1bVII"}))
        errors["hello_esc"] = await _next_error(ws)
        # Errors from the vehicle are never answered: stored escaped, or (unreadable) counted.
        await ws.send(json.dumps({"v": 2, "type": "error", "reason": "bad\x00byte\ud800"}))
        await ws.send(json.dumps({"v": 2, "type": "error", "reason": "r", "x": _deep(30)}))
        await ws.send(b"\xff\xfe")  # the next reply is this one's: the errors got none
        errors["binary"] = await _next_error(ws)
        await ws.send(encode(HELLO))  # the session is still up: greeted now
        async with httpx.AsyncClient(base_url=ground.url) as client:
            deadline = time.monotonic() + 10.0
            while not (await client.get("/api/link/status", headers=VIEWER)).json()["connected"]:
                assert time.monotonic() < deadline, "the good hello after the bad was not taken"
                await asyncio.sleep(0.05)
            # Greeted, and still answering: a hostile message, then a good one.
            await ws.send(json.dumps({"v": 2, "type": "pong", "ping_id\x00": 1}))
            errors["pong_key"] = await _next_error(ws)
            pong = Pong(ping_id=99, ground_time_ns=1, onboard_time_ns=10**18 + 1)
            await ws.send(encode(pong))
            status = (await client.get("/api/link/status", headers=VIEWER)).json()
        errors["status"] = status
    return errors


def _deep(depth: int) -> list[Any]:
    value: list[Any] = []
    for _ in range(depth - 1):
        value = [value]
    return value


def _audited(ground: Ground) -> list[Any]:
    """The link's error events once the interval's rows are written (at its end: one row
    per kind with its count, server/services/malformed.py)."""
    deadline = time.monotonic() + 20.0  # a guard: the interval is INTERVAL_S
    while True:
        with ground.readers() as session:
            events = repo.list_events(
                session=session,
                kinds=["link_error_replied", "link_error_received", "link_hello"],
                limit=1000,
            ).items
        counted = sum(e.detail.get("count", 0) for e in events)
        if counted == 8 or time.monotonic() > deadline:
            return list(events)
        time.sleep(0.1)


def test_hostile_frames_get_error_replies_and_the_link_stays_up(database_url: str) -> None:
    with running_ground(database_url, malformed_interval_s=INTERVAL_S) as ground:
        got = asyncio.run(_session(ground))
        events = _audited(ground)
        link = ground.app.state.link
        assert link.vehicle == "ETS-VII"
    nested = f"nested deeper than {MAX_DEPTH} levels"
    assert nested in got["brackets"]["reason"] and got["brackets"]["ref_type"] is None
    assert nested in got["deep"]["reason"] and got["deep"]["ref_type"] == "hello"
    assert "control character U+0000" in got["hello_nul"]["reason"]
    assert got["hello_nul"]["ref_type"] == "hello"
    assert "control character U+001B" in got["hello_esc"]["reason"]
    assert "not JSON" in got["binary"]["reason"]
    assert "control character U+0000" in got["pong_key"]["reason"]
    assert got["pong_key"]["ref_type"] == "pong"
    status = got["status"]
    assert status["connected"] and status["vehicle"] == "ETS-VII"
    assert status["errors_replied"] == 6 and status["errors_received"] == 2
    by_kind: dict[str, list[dict[str, Any]]] = {}
    for event in events:
        by_kind.setdefault(event.kind, []).append(dict(event.detail))
    # one row per kind (the type claimed, the class of the refusal) and interval, with its
    # count and how many were answered (all: far under the bound on replies)
    replied: dict[tuple[str | None, str], list[int]] = {}
    for e in by_kind["link_error_replied"]:
        counts = replied.setdefault((e["ref_type"], e["code"]), [0, 0])
        counts[0] += e["count"]
        counts[1] += e["replied"]
    assert replied == {
        (None, "too_deep"): [1, 1],
        ("hello", "too_deep"): [1, 1],
        ("hello", "control_character"): [2, 2],
        (None, "not_json"): [1, 1],
        ("pong", "control_character"): [1, 1],
    }
    assert [e["vehicle"] for e in by_kind["link_hello"]] == ["ETS-VII"]
    received = {e["code"]: e for e in by_kind["link_error_received"]}
    # stored, escaped, the same on both databases
    assert received["received"]["reason"] == "bad\\x00byte\\ud800"
    unreadable = received["unreadable"]["reason"]
    assert "unreadable error message" in unreadable and nested in unreadable
    assert status["malformed_received"] == 7 and status["errors_unanswered"] == 0
    for detail in (e for details in by_kind.values() for e in details):
        text = json.dumps(detail, ensure_ascii=False)
        assert not any(ord(c) < 0x20 for c in text), text
