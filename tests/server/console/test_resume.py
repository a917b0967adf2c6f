"""Resume after a reconnect: replay from memory or from the database, never a silent gap.

The client's rule (docs/console.md): per stream ``(topic, pass_id)`` of one epoch, keep the
highest seq seen and drop any message at or below it.
"""

from __future__ import annotations

import threading
from typing import Any

import pytest
from fastapi.testclient import TestClient

import server.services.console as console_service
from tests.server.storage.factories import make_frames
from tests.support.api import add_pass
from tests.support.console import (
    AS_VIEWER,
    CONSOLE,
    FakeSpacecraft,
    drain,
    emit_events,
    hub,
    subscribe,
    welcome,
)

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time


class Console:
    """What a console keeps: the last seq per stream, and the payloads it accepted."""

    def __init__(self) -> None:
        self.last: dict[tuple[str, str | None], int] = {}
        self.accepted: list[dict[str, Any]] = []
        self.duplicates = 0

    def take(self, messages: list[dict[str, Any]]) -> None:
        for message in messages:
            if message["type"] not in ("event", "telemetry"):
                continue
            stream = (message["topic"], message.get("pass_id"))
            if message["seq"] <= self.last.get(stream, 0):
                self.duplicates += 1
                continue
            self.last[stream] = message["seq"]
            self.accepted.append(message)

    def ns(self) -> list[int]:
        return [m["event"]["detail"]["n"] for m in self.accepted]


def seqs(messages: list[dict[str, Any]], kind: str = "event") -> list[int]:
    return [m["seq"] for m in messages if m["type"] == kind]


def test_resume_from_memory_delivers_everything_exactly_once(client: TestClient) -> None:
    view = Console()
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        epoch = welcome(ws)["epoch"]
        subscribe(ws, topic="commands")
        sent = emit_events(client, ["command_stage"] * 10)
        received = drain(ws)
        view.take(received[:6])  # the console saw six before the network dropped
    sent += emit_events(client, ["command_stage"] * 5)  # while it is away
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        welcome(ws)
        # Resume from an older seq than the last seen: an overlap of two.
        reply = subscribe(
            ws, topic="commands", since_seq=view.last[("commands", None)] - 2, epoch=epoch
        )
        assert reply["seq"] == 15
        sent += emit_events(client, ["command_stage"] * 3)  # live again
        again = drain(ws)
    assert seqs(again) == list(range(5, 19))  # strictly increasing, from since_seq + 1
    view.take(again)
    assert view.duplicates == 2
    assert view.ns() == [d["n"] for d in sent]


def test_telemetry_resume_from_memory(client: TestClient) -> None:
    pass_id = add_pass(client)
    spacecraft = FakeSpacecraft(client, pass_id)
    frames = make_frames(range(40))
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        epoch = welcome(ws)["epoch"]
        subscribe(ws, topic="telemetry", pass_id=pass_id)
        for lo in range(0, 20, 5):
            spacecraft.send(frames[lo : lo + 5])
        first = drain(ws)
    for lo in range(20, 40, 5):
        spacecraft.send(frames[lo : lo + 5])
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        welcome(ws)
        subscribe(ws, topic="telemetry", pass_id=pass_id, since_seq=first[-1]["seq"], epoch=epoch)
        second = drain(ws)
    assert seqs(first, "telemetry") == [1, 2, 3, 4] and seqs(second, "telemetry") == [5, 6, 7, 8]
    got = [s for m in first + second for s in m["columns"]["seq"]]
    assert got == list(range(40))


def test_resume_from_the_database_when_the_ring_has_rolled_over(
    client: TestClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    hub(client).limits.ring_size = 4
    calls: list[str] = []
    for name in ("replay_events", "replay_frames"):
        original = getattr(console_service, name)

        def counted(*args: Any, _name: str = name, _original: Any = original) -> Any:
            calls.append(_name)
            return _original(*args)

        monkeypatch.setattr(console_service, name, counted)
    pass_id = add_pass(client)
    spacecraft = FakeSpacecraft(client, pass_id)
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        epoch = welcome(ws)["epoch"]
        subscribe(ws, topic="commands")
        subscribe(ws, topic="events")
        subscribe(ws, topic="telemetry", pass_id=pass_id)
        sent = emit_events(client, ["command_stage", "pass_state"] * 8, pass_id)
        for lo in range(0, 60, 6):
            spacecraft.send(make_frames(range(lo, lo + 6)))
        live = drain(ws)
    assert sum(1 for m in live if m["topic"] == "commands") == 8
    first_event = min(m["seq"] for m in live if m["topic"] == "events")
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        welcome(ws)
        for topic, since_seq, extra in [
            ("commands", 1, {}),  # the ring holds 5..8
            ("events", first_event - 1, {}),
            ("telemetry", 2, {"pass_id": pass_id}),
        ]:
            ws.send_json(
                {"v": 1, "type": "subscribe", "topic": topic, "since_seq": since_seq}
                | {"epoch": epoch, **extra}
            )
        replayed = drain(ws)
    assert [m["type"] for m in replayed if m["type"] not in ("event", "telemetry")] == [
        "subscribed"
    ] * 3
    by_topic = {
        topic: [m for m in replayed if m["type"] in ("event", "telemetry") and m["topic"] == topic]
        for topic in ("commands", "events", "telemetry")
    }
    assert [m["seq"] for m in by_topic["commands"]] == list(range(2, 9))
    assert [m["seq"] for m in by_topic["telemetry"]] == list(range(3, 11))
    # The same messages, seqs and contents, as were sent live.
    for topic, messages in by_topic.items():
        originals = {m["seq"]: m for m in live if m["topic"] == topic}
        assert [m["seq"] for m in messages] == sorted(originals)[-len(messages) :]
        for message in messages:
            assert message == originals[message["seq"]]
    assert sorted(calls) == ["replay_events", "replay_events", "replay_frames"]
    replayed_ns = [m["event"]["detail"].get("n") for m in by_topic["events"]]
    assert [n for n in replayed_ns if n is not None] == [d["n"] for d in sent]


def test_another_epoch_or_a_forgotten_seq_is_told_to_resync(client: TestClient) -> None:
    console = hub(client)
    console.limits.ring_size = 2
    console.limits.index_size = 3
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        epoch = welcome(ws)["epoch"]
        emit_events(client, ["pass_state"] * 6)
        # A restarted server: the seqs of the old epoch mean nothing here.
        subscribe(ws, topic="passes", since_seq=6, epoch="an-old-epoch")
        [resync] = drain(ws)
        assert resync["type"] == "resync" and resync["seq"] == 6 and resync["epoch"] == epoch
        assert "an-old-epoch" in resync["reason"]
        # seq 2 is in neither the ring (5, 6) nor the index (4..6).
        subscribe(ws, topic="passes", since_seq=1, epoch=epoch)
        [resync] = drain(ws)
        assert resync["type"] == "resync" and resync["seq"] == 6
        # Live messages follow the resync.
        [detail] = emit_events(client, ["pass_state"])
        [message] = drain(ws)
        assert message["seq"] == 7 and message["event"]["detail"] == detail


def test_live_messages_wait_for_a_database_replay_and_follow_it(
    client: TestClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    hub(client).limits.ring_size = 1
    replaying = threading.Event()
    published: list[dict[str, Any]] = []
    replay_events = console_service.replay_events  # type: ignore[attr-defined]

    def replay_while_publishing(*args: Any) -> Any:
        replaying.set()
        # Published from the event loop while the replay runs in its thread.
        published.extend(emit_events(client, ["command_stage"] * 3))
        return replay_events(*args)

    monkeypatch.setattr(console_service, "replay_events", replay_while_publishing)
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        epoch = welcome(ws)["epoch"]
        sent = emit_events(client, ["command_stage"] * 5)
        reply = subscribe(ws, topic="commands", since_seq=0, epoch=epoch)
        messages = drain(ws)
    assert replaying.is_set() and reply["seq"] == 5
    assert seqs(messages) == list(range(1, 9))
    assert [m["event"]["detail"]["n"] for m in messages] == [d["n"] for d in sent + published]


def test_an_ended_passs_telemetry_stream_is_let_go_and_counts_on(client: TestClient) -> None:
    """A ground flying pass after pass held every pass's telemetry ring for good (about
    2 MB a pass in bench/bench_soak.py); an ended pass's stream nobody subscribes to is let
    go, keeping only its last seq."""
    console = hub(client)
    flown, other = add_pass(client, "flown"), add_pass(client, "other")
    spacecraft = FakeSpacecraft(client, flown)
    ended = {"to": "complete"}
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        epoch = welcome(ws)["epoch"]
        subscribe(ws, topic="telemetry", pass_id=flown)
        for lo in range(0, 15, 5):
            spacecraft.send(make_frames(range(lo, lo + 5)))
        assert seqs(drain(ws), "telemetry") == [1, 2, 3]
        emit_events(client, ["pass_state"], flown, ended)
        assert console.telemetry_streams == [flown]  # subscribed: held
    emit_events(client, ["pass_state"], other, {"to": "running"})
    assert console.telemetry_streams == [flown]  # a pass that has not ended lets none go
    emit_events(client, ["pass_state"], other, ended)
    assert console.telemetry_streams == []
    # a late frame of the ended pass: its stream again, counting on from its last seq
    spacecraft.send(make_frames(range(15, 16)))
    assert console.telemetry_streams == [flown]
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        welcome(ws)
        assert subscribe(ws, topic="telemetry", pass_id=flown)["seq"] == 4
        # seqs 2..3 went with the stream: told to resync, not given a gap
        ws.send_json(
            {"v": 1, "type": "subscribe", "topic": "telemetry", "pass_id": flown}
            | {"since_seq": 1, "epoch": epoch}
        )
        [resync] = [m for m in drain(ws) if m["type"] == "resync"]
        assert resync["seq"] == 4
    emit_events(client, ["pass_state"], other, {"to": "aborted"})
    assert console.telemetry_streams == []
