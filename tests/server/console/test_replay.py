"""Replay of a recorded pass over the console websocket: every frame once and in order at
any speed, pause, seek, step, independent consoles, and errors that leave the socket usable.

The pass is a short plan flown offline and stored as the link would have (``flight``,
``add_flown_pass``). Nothing here asserts on time: "pause stops delivery" is shown by
counts and a ping/pong barrier, and replays end by a ``replay_state`` that says finished.
"""

from __future__ import annotations

import asyncio
import json
import time
import uuid
from collections.abc import Callable
from types import SimpleNamespace
from typing import Any

import pytest
from fastapi.testclient import TestClient
from starlette.testclient import WebSocketTestSession

from server.services._console_replay import COLUMNS
from server.services.console import ConsoleHub, ConsoleLimits
from server.services.dbworker import Publisher
from server.services.link import LinkStatus
from server.storage import repository as repo
from telemetry.layout import DEFAULT_LAYOUT, FrameLayout
from telemetry.uplink import plan_commands
from tests.server.storage.factories import make_frames, make_plan
from tests.support.api import add_pass
from tests.support.console import (
    AS_VIEWER,
    CONSOLE,
    FakeSpacecraft,
    Flight,
    add_flown_pass,
    drain,
    frames_of,
    hub,
    open_replay,
    send,
    subscribe,
    until_finished,
    until_state,
    welcome,
)

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time

#: ETS-VII's telemetry fields: the frames these tests fly.
TELEMETRY_FIELDS = DEFAULT_LAYOUT.fields

VIEWER = {"Authorization": "Bearer v-token"}
X10 = {"mode": "real_time", "factor": 10.0}
STEP = {"mode": "step"}


def fast(batch_frames: int = 100) -> dict[str, Any]:
    return {"mode": "as_fast_as_possible", "batch_frames": batch_frames}


def reply_to(ws: WebSocketTestSession, type_: str, **fields: Any) -> dict[str, Any]:
    """Send a control message; its ``replay_state`` reply (data before it must be none)."""
    send(ws, type_, **fields)
    reason = type_.removeprefix("replay_")
    data, state = until_state(ws, lambda m: m["reason"] == reason)
    assert data == [], data
    return state


def frame_seqs(data: list[dict[str, Any]]) -> list[int]:
    return [s for m in data if m["type"] == "telemetry" for s in m["columns"]["seq"]]


def stored_seqs(client: TestClient, pass_id: str) -> list[int]:
    with client.app.state.sessions() as session:  # type: ignore[attr-defined]
        return repo.frame_seqs(session=session, pass_id=pass_id)


def times_ns(flight: Flight) -> list[int]:
    return sorted(f.generation_time_ns for f in flight[1].frames)


def test_replay_at_x10_delivers_every_frame_in_order_exactly_once(
    client: TestClient, flight: Flight
) -> None:
    plan, flown = flight
    pass_id = add_flown_pass(client, flight)
    stored = stored_seqs(client, pass_id)
    assert len(stored) == len(flown.frames) == 61
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        welcome(ws)
        opened = open_replay(ws, pass_id.upper(), speed=X10)  # any UUID spelling
        data, final = until_finished(ws)
    replay_id = opened["replay_id"]
    assert opened["pass_id"] == pass_id and opened["name"] == "flown"
    assert (opened["frames"], opened["commands"], opened["epoch_ns"]) == (61, 18, flown.epoch_ns)
    assert opened["first_generation_time_ns"] == flown.frames[0].generation_time_ns
    assert opened["last_generation_time_ns"] == flown.frames[-1].generation_time_ns
    assert opened["playing"] is True and opened["position"] == 0 and opened["seq"] == 0
    assert opened["speed"] == X10 and opened["columns"] == list(COLUMNS)

    # Every stored frame once, in order; the messages numbered 1, 2, 3, ... in one stream.
    assert frame_seqs(data) == stored
    assert [m["seq"] for m in data] == list(range(1, len(data) + 1))
    assert {(m["topic"], m["replay_id"], m["pass_id"]) for m in data} == {
        ("replay", replay_id, pass_id)
    }
    telemetry = [m for m in data if m["type"] == "telemetry"]
    assert [m["row"] for m in telemetry] == [
        sum(m["count"] for m in telemetry[:i]) for i in range(len(telemetry))
    ]
    assert final["position"] == 61 and final["playing"] is False and final["seq"] == len(data)
    assert final["next_generation_time_ns"] is None and final["reason"] == "finished"

    # The live telemetry message's columns, with the archive's values (REST).
    assert list(telemetry[0]["columns"]) == ["seq", "generation_time_ns", *TELEMETRY_FIELDS]
    got = frames_of(telemetry)
    fields = ",".join(TELEMETRY_FIELDS)
    response = client.get(f"/api/passes/{pass_id}/telemetry?fields={fields}", headers=VIEWER)
    assert response.status_code == 200, response.text
    rows = response.json()["rows"]
    assert len(rows) == 61
    for row in rows:
        assert got[row["seq"]] == {
            "seq": row["seq"],
            "generation_time_ns": row["generation_time_ns"],
            **row["values"],
        }

    # The commands at their time tags, each once, in tag order.
    commands = [c for m in data if m["type"] == "commands" for c in m["commands"]]
    expected = plan_commands(plan, epoch_ns=flown.epoch_ns, first_seq=0)
    assert [(c["seq"], c["execute_time_ns"]) for c in commands] == [
        (c.seq, c.execute_time_ns) for c in expected
    ]
    assert {c["stage"] for c in commands} == {"queued"}


def test_as_fast_as_possible_delivers_every_frame_in_batches(
    client: TestClient, flight: Flight
) -> None:
    pass_id = add_flown_pass(client, flight)
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        welcome(ws)
        # j7: the archive has the column, this 6-joint pass does not: left out
        open_replay(ws, pass_id, speed=fast(7), fields=["j1", "j7", "wz"])
        data, final = until_finished(ws)
    telemetry = [m for m in data if m["type"] == "telemetry"]
    assert frame_seqs(data) == stored_seqs(client, pass_id)
    assert [m["count"] for m in telemetry] == [7] * 8 + [5]
    assert all(
        list(m["columns"]) == ["seq", "generation_time_ns", "reception_time_ns", "j1", "wz"]
        for m in telemetry
    )
    assert final["speed"] == fast(7) and final["finished"] is True


def test_pause_stops_delivery_and_play_resumes_where_it_stopped(
    client: TestClient, flight: Flight
) -> None:
    pass_id = add_flown_pass(client, flight)
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        welcome(ws)
        replay_id = open_replay(ws, pass_id, speed={"mode": "real_time", "factor": 1.0})[
            "replay_id"
        ]
        first = ws.receive_json()  # the first frame is due at once
        assert first["type"] == "telemetry" and first["columns"]["seq"][:1] == [0]
        send(ws, "replay_pause", replay_id=replay_id)
        before, paused = until_state(ws, lambda m: m["reason"] == "pause")
        delivered = frame_seqs([first, *before])
        # The reply comes after every frame sent before the pause: its position counts them.
        assert paused["playing"] is False and paused["position"] == len(delivered) < 61
        time.sleep(0.3)  # three frames' worth at x1 (not a timing assertion: none may come)
        assert drain(ws) == []
        assert reply_to(ws, "replay_pause", replay_id=replay_id)["position"] == len(delivered)
        state = reply_to(ws, "replay_speed", replay_id=replay_id, speed=fast())
        assert state["position"] == len(delivered) and state["playing"] is False
        assert drain(ws) == []
        assert reply_to(ws, "replay_play", replay_id=replay_id)["playing"] is True
        after, _ = until_finished(ws)
    # Nothing lost, nothing twice.
    assert delivered + frame_seqs(after) == stored_seqs(client, pass_id)


def test_seek_lands_on_the_first_frame_at_or_after_the_time(
    client: TestClient, flight: Flight
) -> None:
    plan, flown = flight
    pass_id = add_flown_pass(client, flight)
    times = times_ns(flight)
    stored = stored_seqs(client, pass_id)
    k = 13
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        welcome(ws)
        replay_id = open_replay(ws, pass_id, speed=STEP, paused=True)["replay_id"]
        # Between frames k and k + 1: frame k + 1 is next.
        state = reply_to(ws, "replay_seek", replay_id=replay_id, onboard_time_ns=times[k] + 1)
        assert state["position"] == k + 1 and state["next_generation_time_ns"] == times[k + 1]
        send(ws, "replay_step", replay_id=replay_id)
        data, _ = until_state(ws, lambda m: m["reason"] == "step")
        assert frame_seqs(data) == [stored[k + 1]]
        # Exactly on frame k (on the plan's clock): frame k is next.
        plan_t_s = (times[k] - flown.epoch_ns) / 1e9
        state = reply_to(ws, "replay_seek", replay_id=replay_id, plan_t_s=plan_t_s)
        assert state["next_generation_time_ns"] == times[k]
        assert state["playhead_t_s"] == pytest.approx(plan_t_s, abs=1e-9)
        reply_to(ws, "replay_speed", replay_id=replay_id, speed=fast(10))
        reply_to(ws, "replay_play", replay_id=replay_id)
        data, _ = until_finished(ws)
    # From frame k on, every frame once; the commands tagged from there on.
    assert frame_seqs(data) == stored[k:]
    commands = [c["seq"] for m in data if m["type"] == "commands" for c in m["commands"]]
    expected = plan_commands(plan, epoch_ns=flown.epoch_ns, first_seq=0)
    assert commands == [c.seq for c in expected if c.execute_time_ns >= times[k]]


def test_step_delivers_exactly_one_frame(client: TestClient, flight: Flight) -> None:
    pass_id = add_flown_pass(client, flight)
    stored = stored_seqs(client, pass_id)
    times = times_ns(flight)
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        welcome(ws)
        replay_id = open_replay(ws, pass_id, paused=True)["replay_id"]
        for i in range(3):
            send(ws, "replay_step", replay_id=replay_id)
            data, state = until_state(ws, lambda m: m["reason"] == "step")
            [message] = [m for m in data if m["type"] == "telemetry"]
            assert message["count"] == 1 and message["columns"]["seq"] == [stored[i]]
            assert state["position"] == i + 1 and state["playing"] is False
        assert drain(ws) == []
        # The last frame ends the replay; then there is nothing to step or play.
        reply_to(ws, "replay_seek", replay_id=replay_id, onboard_time_ns=times[-1])
        send(ws, "replay_step", replay_id=replay_id)
        data, state = until_state(ws, lambda m: m["reason"] == "step")
        assert frame_seqs(data) == [stored[-1]] and state["finished"] is True
        for type_ in ("replay_step", "replay_play"):
            send(ws, type_, replay_id=replay_id)
            error = ws.receive_json()
            assert error["type"] == "error" and "at its end" in error["reason"], error
            assert error["ref_type"] == type_


def test_two_consoles_replay_independently(client: TestClient, flight: Flight) -> None:
    pass_id = add_flown_pass(client, flight)
    stored = stored_seqs(client, pass_id)
    with (
        client.websocket_connect(CONSOLE, headers=AS_VIEWER) as a,
        client.websocket_connect(CONSOLE, headers=AS_VIEWER) as b,
    ):
        welcome(a)
        welcome(b)
        a_id = open_replay(a, pass_id, speed=STEP, paused=True)["replay_id"]
        b_id = open_replay(b, pass_id, speed=fast(10))["replay_id"]
        assert a_id != b_id
        data_b, _ = until_finished(b)
        assert frame_seqs(data_b) == stored
        assert drain(a) == []  # a's replay did not move
        # b cannot touch a's replay; both sockets go on.
        for type_ in ("replay_play", "replay_step", "replay_close"):
            send(b, type_, replay_id=a_id)
            error = b.receive_json()
            assert error["type"] == "error" and "not open on this console" in error["reason"]
        assert drain(b) == []
        send(a, "replay_step", replay_id=a_id)
        data_a, state = until_state(a, lambda m: m["reason"] == "step")
        assert frame_seqs(data_a) == stored[:1] and state["replay_id"] == a_id


def test_replay_never_mixes_with_live_telemetry(client: TestClient, flight: Flight) -> None:
    flown_id = add_flown_pass(client, flight)
    live_id = add_pass(client, "live")
    spacecraft = FakeSpacecraft(client, live_id)
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        welcome(ws)
        subscribe(ws, topic="telemetry", pass_id=live_id)
        subscribe(ws, topic="telemetry", pass_id=flown_id)  # live data of the replayed pass
        replay_id = open_replay(ws, flown_id, speed=STEP, paused=True)["replay_id"]
        spacecraft.send(make_frames(range(4)))
        send(ws, "replay_step", replay_id=replay_id)
        messages = drain(ws)
    live = [m for m in messages if m.get("topic") == "telemetry"]
    replayed = [m for m in messages if m.get("topic") == "replay" and m["type"] == "telemetry"]
    assert [(m["pass_id"], m["columns"]["seq"]) for m in live] == [(live_id, [0, 1, 2, 3])]
    assert [(m["replay_id"], m["pass_id"], m["count"]) for m in replayed] == [
        (replay_id, flown_id, 1)
    ]


BadRequest = Callable[[dict[str, Any]], dict[str, Any]]
BAD_REQUESTS: list[tuple[str, BadRequest, str]] = [
    (
        "unknown-pass",
        lambda c: {"type": "replay_open", "pass_id": str(uuid.uuid4())},
        "not found",
    ),
    ("not-a-uuid", lambda c: {"type": "replay_open", "pass_id": "p-9"}, "not found"),
    ("never-flown", lambda c: {"type": "replay_open", "pass_id": c["unflown"]}, "not flown"),
    (
        "factor-zero",
        lambda c: {"type": "replay_open", "pass_id": c["pass_id"], "speed": {**X10, "factor": 0}},
        "factor",
    ),
    (
        "factor-too-high",
        lambda c: {"type": "replay_open", "pass_id": c["pass_id"], "speed": {**X10, "factor": 1e6}},
        "replay factor 1000000.0 exceeds 1000.0",
    ),
    (
        "factor-string",
        lambda c: {"type": "replay_open", "pass_id": c["pass_id"], "speed": {**X10, "factor": "9"}},
        "factor",
    ),
    (
        "unknown-mode",
        lambda c: {"type": "replay_open", "pass_id": c["pass_id"], "speed": {"mode": "warp"}},
        "speed",
    ),
    (
        "batch-too-big",
        lambda c: {"type": "replay_speed", "replay_id": c["replay_id"], "speed": fast(10_000)},
        "batch_frames 10000 exceeds 500",
    ),
    (
        "unknown-field",
        lambda c: {"type": "replay_open", "pass_id": c["pass_id"], "fields": ["j13"]},
        "'j13' is not one of",
    ),
    (
        "extra-field",
        lambda c: {"type": "replay_open", "pass_id": c["pass_id"], "loop": True},
        "loop",
    ),
    (
        "seek-after-end",
        lambda c: {"type": "replay_seek", "replay_id": c["replay_id"], "onboard_time_ns": c["end"]},
        "outside the recording",
    ),
    (
        "seek-before-start",
        lambda c: {"type": "replay_seek", "replay_id": c["replay_id"], "plan_t_s": -100.0},
        "outside the recording",
    ),
    (
        "seek-both",
        lambda c: {
            "type": "replay_seek",
            "replay_id": c["replay_id"],
            "plan_t_s": 1.0,
            "onboard_time_ns": c["end"],
        },
        "one of onboard_time_ns and plan_t_s",
    ),
    (
        "seek-neither",
        lambda c: {"type": "replay_seek", "replay_id": c["replay_id"]},
        "one of onboard_time_ns and plan_t_s",
    ),
    (
        "unknown-replay",
        lambda c: {"type": "replay_play", "replay_id": "r-nope"},
        "replay 'r-nope' is not open on this console",
    ),
    ("no-replay-id", lambda c: {"type": "replay_pause"}, "replay_id"),
]


@pytest.fixture(scope="module")
def replayable(module_client: TestClient, flight: Flight) -> tuple[TestClient, str, str, list[int]]:
    """One application per backend for the bad requests, which store nothing: its client, a
    flown pass, an unflown one and the flown one's stored frame seqs."""
    pass_id = add_flown_pass(module_client, flight)
    unflown = add_pass(module_client, "unflown")
    return module_client, pass_id, unflown, stored_seqs(module_client, pass_id)


@pytest.mark.parametrize(
    ("build", "says"),
    [(b, s) for _, b, s in BAD_REQUESTS],
    ids=[i for i, _, _ in BAD_REQUESTS],
)
def test_a_bad_replay_request_gets_an_error_and_the_socket_stays_usable(
    replayable: tuple[TestClient, str, str, list[int]],
    flight: Flight,
    build: BadRequest,
    says: str,
) -> None:
    client, pass_id, unflown, stored = replayable
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        welcome(ws)
        replay_id = open_replay(ws, pass_id, speed=STEP, paused=True)["replay_id"]
        context = {
            "pass_id": pass_id,
            "unflown": unflown,
            "replay_id": replay_id,
            "end": times_ns(flight)[-1] + 1,
        }
        request = build(context)
        ws.send_json({"v": 1, **request})
        error = ws.receive_json()
        assert error["type"] == "error" and says in error["reason"], error
        assert error["ref_type"] == request["type"]
        # Still served: the replay steps, nothing else came.
        send(ws, "replay_step", replay_id=replay_id)
        data, state = until_state(ws, lambda m: m["reason"] == "step")
        assert frame_seqs(data) == stored[:1] and state["position"] == 1
        assert drain(ws) == []


def test_replay_limits_per_console_and_in_total(client: TestClient, flight: Flight) -> None:
    pass_id = add_flown_pass(client, flight)
    limits = hub(client).limits
    limits.max_replays_per_console, limits.max_replays = 2, 3
    with (
        client.websocket_connect(CONSOLE, headers=AS_VIEWER) as a,
        client.websocket_connect(CONSOLE, headers=AS_VIEWER) as b,
    ):
        welcome(a)
        welcome(b)
        first = open_replay(a, pass_id, paused=True)["replay_id"]
        open_replay(a, pass_id, paused=True)
        send(a, "replay_open", pass_id=pass_id)
        assert "2 replays per console at most" in a.receive_json()["reason"]
        open_replay(b, pass_id, paused=True)
        send(b, "replay_open", pass_id=pass_id)
        assert "the server has 3 replays open" in b.receive_json()["reason"]
        # Closing one makes room; a closed replay is gone.
        send(a, "replay_close", replay_id=first)
        closed = a.receive_json()
        assert closed == {
            "v": 1,
            "type": "replay_closed",
            "replay_id": first,
            "seq": 0,
            "reason": "requested",
        }
        open_replay(b, pass_id, paused=True)
        send(a, "replay_play", replay_id=first)
        assert "not open on this console" in a.receive_json()["reason"]
        assert len(hub(client).replays) == 3
    # A console that goes takes its replays with it.
    for _ in range(500):
        if len(hub(client).replays) == 0:
            break
        time.sleep(0.01)
    assert len(hub(client).replays) == 0


class _Socket:
    """A console's socket that takes nothing until ``open`` is set."""

    def __init__(self, *, blocked: bool) -> None:
        self.received: list[dict[str, Any]] = []
        self.largest = 0
        self.open = asyncio.Event()
        self.finished = asyncio.Event()
        if not blocked:
            self.open.set()

    async def send_text(self, text: str) -> None:
        await self.open.wait()
        message = json.loads(text)
        self.received.append(message)
        self.largest = max(self.largest, len(text))
        if message["type"] == "replay_state" and message["finished"]:
            self.finished.set()

    async def close(self, code: int, reason: str) -> None:
        raise AssertionError(f"closed {code} {reason}")


def _no_link() -> LinkStatus:
    raise AssertionError("the link poll is not started in this test")


def test_a_slow_console_holds_only_its_own_replay(client: TestClient, flight: Flight) -> None:
    """The hub on its own (its own event loop) over the test's database: a console that
    takes nothing holds its replay at the window; the other's runs to the end."""
    pass_id = add_flown_pass(client, flight)
    stored = stored_seqs(client, pass_id)
    sessions = client.app.state.sessions  # type: ignore[attr-defined]
    limits = ConsoleLimits(replay_window_bytes=8_000, max_replay_batch_frames=5)

    async def scenario() -> tuple[_Socket, _Socket, int, int]:
        hub = ConsoleHub(
            publisher=Publisher(), link_status=_no_link, sessions=sessions, limits=limits
        )
        slow, quick = _Socket(blocked=True), _Socket(blocked=False)
        consoles = []
        for socket in (slow, quick):
            console = hub.connect(
                actor="vera", role="viewer", send_text=socket.send_text, close=socket.close
            )
            request = {"v": 1, "type": "replay_open", "pass_id": pass_id, "speed": fast(5)}
            await hub.handle(console, json.dumps(request))
            consoles.append(console)
        await asyncio.wait_for(quick.finished.wait(), 60)  # a guard, not a timing assertion
        [slow_replay] = hub.replays.of(consoles[0])
        held_bytes, held_at = slow_replay.client.replay_bytes, slow_replay.engine.position
        slow.open.set()
        await asyncio.wait_for(slow.finished.wait(), 60)
        await hub.close()
        return slow, quick, held_bytes, held_at

    slow, quick, held_bytes, held_at = asyncio.run(scenario())
    for socket in (slow, quick):
        assert frame_seqs([m for m in socket.received if m.get("topic") == "replay"]) == stored
    # Held at the window (give or take the batch that crossed it), part way through.
    assert limits.replay_window_bytes < held_bytes <= limits.replay_window_bytes + slow.largest
    assert 0 < held_at < len(stored)


def test_a_seven_joint_pass_replays_with_its_own_columns(client: TestClient) -> None:
    seven = FrameLayout(7, 3)
    plan = make_plan(17, n_joints=7)
    frames = make_frames(range(30), seed=11, layout=seven)
    flight = SimpleNamespace(frames=frames, epoch_ns=frames[0].generation_time_ns)
    pass_id = add_flown_pass(client, (plan, flight), name="seven")  # type: ignore[arg-type]
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        welcome(ws)
        opened = open_replay(ws, pass_id, speed=fast(8))
        assert opened["columns"] == list(seven.columns)
        data, final = until_finished(ws)
    assert final["finished"] is True
    telemetry = [m for m in data if m["type"] == "telemetry"]
    assert frame_seqs(data) == list(range(30))
    assert all(list(m["columns"]) == list(seven.columns) for m in telemetry)
    got = {
        s: v
        for m in telemetry
        for s, v in zip(m["columns"]["seq"], m["columns"]["j7"], strict=True)
    }
    assert got == {f.seq: f.joints_rad[6] for f in frames}
