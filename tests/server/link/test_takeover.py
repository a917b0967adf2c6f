"""Link takeovers: every second spacecraft-token connection that supersedes the one holding
the link is audited (``link_takeover``, both connections' details) and shown to consoles."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path
from typing import Any

import pytest
from websockets.asyncio.client import ClientConnection, connect

from server.storage import repository as repo
from server.storage.db import sqlite_url
from tests.server.link.harness import Ground, running_ground

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time

TAKEOVERS = 15


def _events(ground: Ground, kind: str) -> list[Any]:
    with ground.readers() as session:
        return list(repo.list_events(session=session, kinds=[kind], limit=1000).items)


async def _connect_in_turn(url: str, count: int) -> None:
    """``count`` spacecraft connections, each opened while the one before still holds the
    link (so each supersedes it), with its own User-Agent."""
    held: list[ClientConnection] = []
    try:
        for k in range(count):
            ws = await connect(
                url,
                additional_headers={"Authorization": "Bearer s-token"},
                user_agent_header=f"relay-{k}",
            )
            held.append(ws)
            # The server attaches a connection once it has accepted it; a ping round trip
            # proves the handler runs, so the next connection finds this one attached.
            await asyncio.wait_for(ws.ping(), 10.0)
    finally:
        for ws in held:
            await ws.close()


@pytest.mark.slow
def test_every_takeover_is_audited_with_both_connections(tmp_path: Path) -> None:
    with running_ground(sqlite_url(tmp_path)) as ground:
        published: list[dict[str, Any]] = []
        ground.app.state.publisher.subscribe(lambda r: published.append(r.document()))
        asyncio.run(_connect_in_turn(ground.ws_url, TAKEOVERS + 1))
        deadline = time.monotonic() + 20.0  # a guard, not a timing assertion
        while len(_events(ground, "link_takeover")) < TAKEOVERS:
            assert time.monotonic() < deadline, "takeover events not written"
            time.sleep(0.05)
        takeovers = _events(ground, "link_takeover")
        connected = _events(ground, "link_connected")
    assert len(takeovers) == TAKEOVERS
    assert len(connected) == TAKEOVERS + 1
    pairs = sorted(
        (e.detail["previous"]["connection"], e.detail["current"]["connection"]) for e in takeovers
    )
    # Each takes the link from the connection just before it: a chain, no gaps.
    assert all(cur == prev + 1 for prev, cur in pairs)
    assert [p for p, _ in pairs[1:]] == [c for _, c in pairs[:-1]]
    agents = sorted(
        (e.detail["previous"]["user_agent"], e.detail["current"]["user_agent"]) for e in takeovers
    )
    assert ("relay-0", "relay-1") in agents and ("relay-14", "relay-15") in agents
    for e in takeovers:
        previous, current = e.detail["previous"], e.detail["current"]
        assert e.actor == "ets7"
        for side in (previous, current):
            assert side["actor"] == "ets7"
            host, _, port = side["peer"].rpartition(":")
            assert host == "127.0.0.1" and port.isdigit()
            assert isinstance(side["connected_ns"], int)
        assert previous["peer"] != current["peer"]  # two sockets, two client ports
        assert previous["connected_ns"] <= current["connected_ns"]
    shown = [m for m in published if m["kind"] == "link_takeover"]
    assert len(shown) == TAKEOVERS
    assert {m["id"] for m in shown} == {e.id for e in takeovers}


def test_a_first_connection_is_no_takeover(tmp_path: Path) -> None:
    with running_ground(sqlite_url(tmp_path)) as ground:
        asyncio.run(_connect_in_turn(ground.ws_url, 1))
        deadline = time.monotonic() + 20.0  # a guard, not a timing assertion
        while not _events(ground, "link_connected"):
            assert time.monotonic() < deadline, "link_connected not written"
            time.sleep(0.05)
        assert _events(ground, "link_takeover") == []
