"""A slow console: its subscription is dropped, publishing never waits, it resumes losslessly.

The hub on its own (no app): one console whose socket does not take anything until released,
one that takes everything.
"""

from __future__ import annotations

import asyncio
import json
from typing import Any

import pytest

from server.services.clock import Clock, ManualClock, SystemClock
from server.services.console import ConsoleHub, ConsoleLimits
from server.services.dbworker import Publisher
from server.services.events import PassState, Recorded
from server.services.link import LinkStatus
from tests.support.console import stage_event

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time

N_EVENTS = 50


def _status() -> LinkStatus:
    raise AssertionError("the link poll is not started in these tests")


class Socket:
    def __init__(self, *, blocked: bool) -> None:
        self.received: list[dict[str, Any]] = []
        self.open = asyncio.Event()
        if not blocked:
            self.open.set()

    async def send_text(self, text: str) -> None:
        await self.open.wait()
        self.received.append(json.loads(text))

    async def close(self, code: int, reason: str) -> None:
        raise AssertionError(f"closed {code} {reason}")


async def _settle() -> None:
    # Let the send tasks run until nothing is left to take (bounded: no timing assumed).
    for _ in range(10 * N_EVENTS):
        await asyncio.sleep(0)


def test_a_slow_console_is_dropped_without_holding_up_the_publisher() -> None:
    async def scenario() -> tuple[list[dict[str, Any]], list[dict[str, Any]], list[bool]]:
        publisher = Publisher()
        # About ten event messages of ~170 bytes.
        limits = ConsoleLimits(queue_bytes=1700, ring_size=N_EVENTS)
        hub = ConsoleHub(
            publisher=publisher,
            link_status=_status,
            sessions=None,  # type: ignore[arg-type]
            limits=limits,
        )
        hub._unhook = [publisher.subscribe(hub._on_event)]  # no link poll
        slow, fast = Socket(blocked=True), Socket(blocked=False)
        clients = {}
        for name, socket in (("slow", slow), ("fast", fast)):
            clients[name] = hub.connect(
                actor=name, role="viewer", send_text=socket.send_text, close=socket.close
            )
            subscribe = {"v": 1, "type": "subscribe", "topic": "commands"}
            await hub.handle(clients[name], json.dumps(subscribe))
        returned = []
        for n in range(1, N_EVENTS + 1):
            publisher.publish([stage_event(n)])  # synchronous: it cannot wait for a socket
            returned.append(True)
            await asyncio.sleep(0)  # the link awaits its database between batches
        # The slow console catches up (its socket drains) and resumes where it was dropped.
        slow.open.set()
        await _settle()
        dropped = next(m for m in slow.received if m["type"] == "unsubscribed")
        resume = {"v": 1, "type": "subscribe", "topic": "commands"}
        resume |= {"since_seq": dropped["seq"], "epoch": hub.epoch}
        await hub.handle(clients["slow"], json.dumps(resume))
        await _settle()
        await hub.close()
        return slow.received, fast.received, returned

    slow, fast, returned = asyncio.run(scenario())
    assert len(returned) == N_EVENTS
    assert [m["seq"] for m in fast if m["type"] == "event"] == list(range(1, N_EVENTS + 1))
    [dropped] = [m for m in slow if m["type"] == "unsubscribed"]
    assert dropped["reason"].startswith("overflow") and dropped["topic"] == "commands"
    # The notice jumps the queue (a control message); what was queued before the drop still
    # goes out after it, then the resumed rest: every event once, in order.
    events = [m["seq"] for m in slow if m["type"] == "event"]
    assert events == list(range(1, N_EVENTS + 1))
    first_event = next(i for i, m in enumerate(slow) if m["type"] == "event")
    assert slow.index(dropped) < first_event
    assert 5 <= dropped["seq"] < N_EVENTS // 2


# --- two queues, and a console that knows it is behind -------------------------------------


class Recorder:
    """A console socket that takes nothing until released (or one message per ``period_s``
    of wall time), recording each message with the hub clock's time it was taken."""

    def __init__(self, clock: Clock, *, blocked: bool = True, period_s: float = 0.0) -> None:
        self.clock = clock
        self.period_s = period_s
        self.received: list[dict[str, Any]] = []
        self.at: list[float] = []
        self.closed: list[tuple[int, str]] = []
        self.open = asyncio.Event()
        if not blocked:
            self.open.set()

    async def send_text(self, text: str) -> None:
        await self.open.wait()
        if self.period_s:
            await asyncio.sleep(self.period_s)
        self.received.append(json.loads(text))
        self.at.append(self.clock.monotonic())

    async def close(self, code: int, reason: str) -> None:
        self.closed.append((code, reason))

    def of_type(self, kind: str) -> list[dict[str, Any]]:
        return [m for m in self.received if m["type"] == kind]


def _abort(pass_id: str, time_ns: int) -> Recorded:
    state = PassState(
        actor="otto",
        pass_id=pass_id,
        from_state="running",
        to="aborted",
        reason="operator abort",
        version=4,
    )
    return Recorded(state, time_ns, 10**6 + time_ns)


PASS = "7d3c0000-0000-4000-8000-000000000001"


def _hub(limits: ConsoleLimits, clock: Clock) -> tuple[ConsoleHub, Publisher]:
    publisher = Publisher()
    hub = ConsoleHub(
        publisher=publisher,
        link_status=_status,
        sessions=None,  # type: ignore[arg-type]
        limits=limits,
        clock=clock,
    )
    hub._unhook = [publisher.subscribe(hub._on_event)]  # no link poll
    return hub, publisher


async def _connect(hub: ConsoleHub, socket: Recorder, name: str, topics: list[str]) -> Any:
    client = hub.connect(actor=name, role="viewer", send_text=socket.send_text, close=socket.close)
    for topic in topics:
        await hub.handle(client, json.dumps({"v": 1, "type": "subscribe", "topic": topic}))
    return client


def _seqs(received: list[dict[str, Any]], topic: str) -> list[int]:
    return [m["seq"] for m in received if m["type"] == "event" and m["topic"] == topic]


def test_pass_states_jump_the_queue_and_each_stream_stays_in_order() -> None:
    async def scenario() -> Recorder:
        clock = ManualClock()
        hub, publisher = _hub(ConsoleLimits(ring_size=N_EVENTS), clock)
        slow = Recorder(clock)
        await _connect(hub, slow, "slow", ["commands", "passes", "events"])
        for n in range(1, N_EVENTS + 1):
            publisher.publish([stage_event(n)])
            if n == 10:
                publisher.publish([_abort(PASS, n)])
        await _settle()
        slow.open.set()
        await _settle()
        await _settle()
        await hub.close()
        return slow

    slow = asyncio.run(scenario())
    # The first message (welcome) was being sent when the socket blocked; then the control
    # replies (subscribed x3), then the abort on ``passes``, ahead of 40 command stages
    # queued before it; the abort on ``events`` (every kind, bulk) keeps its place there.
    types = [(m["type"], m.get("topic")) for m in slow.received[:5]]
    assert types == [("welcome", None)] + [
        ("subscribed", t) for t in ("commands", "passes", "events")
    ] + [("event", "passes")]
    assert slow.received[4]["event"]["detail"]["to"] == "aborted"
    assert _seqs(slow.received, "commands") == list(range(1, N_EVENTS + 1))
    events = [m for m in slow.received if m["type"] == "event" and m["topic"] == "events"]
    assert [m["seq"] for m in events] == list(range(1, N_EVENTS + 2))
    assert events[10]["event"]["kind"] == "pass_state"  # after the 10th command stage
    assert not slow.of_type("lag") and not slow.of_type("resync")  # time did not move


def test_a_console_behind_is_told_by_how_much_then_resynced() -> None:
    limits = ConsoleLimits(ring_size=N_EVENTS)

    async def scenario() -> tuple[Recorder, Recorder, int]:
        clock = ManualClock()
        hub, publisher = _hub(limits, clock)
        hub._lag_watch = asyncio.create_task(hub._watch_lag())
        slow, fast = Recorder(clock), Recorder(clock, blocked=False)
        client = await _connect(hub, slow, "slow", ["commands", "passes"])
        await _connect(hub, fast, "fast", ["commands", "passes"])
        for n in range(1, 21):
            publisher.publish([stage_event(n)])
        await clock.advance(1.0)  # behind by 1 s: told (lag), nothing dropped
        await clock.advance(limits.behind_resync_s)  # past the bound: the backlog goes
        resyncs = client.resyncs
        slow.open.set()
        await _settle()
        for n in range(21, 26):  # live again, after the resync's seq
            publisher.publish([stage_event(n)])
        await clock.advance(1.0)  # caught up: told so, once
        await clock.advance(1.0)
        await hub.close()
        return slow, fast, resyncs

    slow, fast, resyncs = asyncio.run(scenario())
    assert _seqs(fast.received, "commands") == list(range(1, 26))
    assert not fast.of_type("lag") and not fast.of_type("resync")
    lags = slow.of_type("lag")
    assert lags[0]["behind_s"] >= limits.behind_report_s and lags[0]["queued"] >= 20
    assert lags[0]["resync_s"] == limits.behind_resync_s
    assert max(m["behind_s"] for m in lags) > limits.behind_resync_s
    assert lags[-1]["behind_s"] == 0 and sum(m["behind_s"] == 0 for m in lags) == 1
    [resync] = slow.of_type("resync")
    assert resyncs == 1 and resync["topic"] == "commands" and resync["seq"] == 20
    assert resync["reason"].startswith("behind by ") and "reload the snapshot" in resync["reason"]
    assert "20 messages not sent" in resync["reason"]
    # None of the backlog was sent: after the resync, live messages from seq 21.
    assert _seqs(slow.received, "commands") == list(range(21, 26))
    assert slow.received.index(resync) < next(
        i for i, m in enumerate(slow.received) if m["type"] == "event"
    )
    assert not slow.of_type("unsubscribed") and not slow.closed


def test_a_console_behind_past_the_drop_bound_is_told_why_and_closed() -> None:
    limits = ConsoleLimits()

    async def scenario() -> tuple[Recorder, int, int]:
        clock = ManualClock()
        hub, publisher = _hub(limits, clock)
        hub._lag_watch = asyncio.create_task(hub._watch_lag())
        stuck = Recorder(clock)  # takes nothing at all, control messages included
        await _connect(hub, stuck, "stuck", ["passes"])
        publisher.publish([_abort(PASS, 1)])
        await clock.advance(limits.behind_drop_s - 1.0)
        before = hub.clients
        await clock.advance(2.0)
        await _settle()
        after = hub.clients
        await hub.close()
        return stuck, before, after

    stuck, before, after = asyncio.run(scenario())
    assert (before, after) == (1, 0)
    [(code, reason)] = stuck.closed
    assert code == 1008
    assert reason.startswith("behind by 3") and f"more than {limits.behind_drop_s:g} s" in reason


#: The slow-console case: command events published at this rate for this long, the abort
#: halfway, to three fast consoles and one that reads 20 messages a second.
BURST_HZ, BURST_S, SLOW_HZ = 1000, 4.0, 20


@pytest.mark.slow
def test_a_slow_console_beside_fast_ones_sees_the_abort_and_how_far_behind_it_is() -> None:
    limits = ConsoleLimits()  # the service's own bounds
    topics = ["commands", "passes", "events"]

    async def scenario() -> tuple[Recorder, list[Recorder], float, float, int, int]:
        clock = SystemClock()
        hub, publisher = _hub(limits, clock)
        hub._lag_watch = asyncio.create_task(hub._watch_lag())
        slow = Recorder(clock, blocked=False, period_s=1 / SLOW_HZ)
        fast = [Recorder(clock, blocked=False) for _ in range(3)]
        await _connect(hub, slow, "slow", topics)
        for i, socket in enumerate(fast):
            await _connect(hub, socket, f"fast-{i}", topics)
        start = clock.monotonic()
        abort_at = -1.0
        n = 0
        batch = BURST_HZ // 100  # a batch every 10 ms, as the link commits them
        while (elapsed := clock.monotonic() - start) < BURST_S:
            due = int(elapsed * BURST_HZ)
            while n < due:
                n += 1
                publisher.publish([stage_event(n)])
                if n % batch == 0:
                    await asyncio.sleep(0)
            if abort_at < 0 and elapsed >= BURST_S / 2:
                publisher.publish([_abort(PASS, n)])
                abort_at = clock.monotonic()
            await asyncio.sleep(0.01)
        # Until the slow console has been told it caught up after the burst (a guard, not a
        # timing assertion).
        deadline = clock.monotonic() + 30.0
        end = clock.monotonic()
        while not any(
            m["type"] == "lag" and m["behind_s"] == 0 and t > end
            for m, t in zip(slow.received, slow.at, strict=True)
        ):
            assert clock.monotonic() < deadline, "the slow console was never told it caught up"
            await asyncio.sleep(0.1)
        clients = hub.clients
        await hub.close()
        return slow, fast, start, abort_at, clients, n

    slow, fast, start, abort_at, clients, published = asyncio.run(scenario())
    assert published > 1000 and clients == 4  # thousands of command events; nobody dropped
    for socket in fast:
        assert _seqs(socket.received, "commands") == list(range(1, published + 1))
        assert not socket.of_type("lag") and not socket.of_type("resync")
    assert not slow.of_type("unsubscribed") and not slow.closed and not slow.of_type("error")

    def first(predicate: Any) -> float:
        return next(t for m, t in zip(slow.received, slow.at, strict=True) if predicate(m))

    lag_seen = first(lambda m: m["type"] == "lag" and m["behind_s"] > 0) - start
    abort_seen = (
        first(lambda m: m["type"] == "event" and m["event"]["kind"] == "pass_state") - abort_at
    )
    print(
        f"\nslow console: told it is behind {lag_seen:.2f} s after the burst began, saw the"
        f" abort {abort_seen:.2f} s after it; {len(slow.of_type('resync'))} resyncs,"
        f" {len(slow.received)} messages read; {published} command events published"
    )
    # Generous guards, not timing assertions (the bounds are 2 s and 5 s).
    assert lag_seen < 10.0 and abort_seen < 10.0
    resyncs = slow.of_type("resync")
    assert {m["topic"] for m in resyncs} <= {"commands", "events"} and resyncs
    assert all(m["reason"].startswith("behind by ") for m in resyncs)
    for topic in topics:  # each stream in order, the resyncs' gaps announced
        seqs = _seqs(slow.received, topic)
        assert seqs == sorted(set(seqs)), topic


def test_a_console_that_acknowledges_holds_no_more_than_its_window_in_the_socket() -> None:
    limits = ConsoleLimits(ring_size=N_EVENTS, ack_window_min_bytes=1000)

    async def scenario() -> dict[str, Any]:
        clock = ManualClock()
        hub, publisher = _hub(limits, clock)
        socket = Recorder(clock, blocked=False)  # takes all it is sent, reads when it acks
        client = await _connect(hub, socket, "acking", [])

        async def ack(received: int) -> None:
            await hub.handle(client, json.dumps({"v": 1, "type": "ack", "received": received}))

        await _settle()
        await ack(1)  # the welcome: from here on, held to its window
        for topic in ("commands", "passes"):
            await hub.handle(client, json.dumps({"v": 1, "type": "subscribe", "topic": topic}))
        for n in range(1, 41):
            publisher.publish([stage_event(n)])
        await _settle()
        out: dict[str, Any] = {"held": list(socket.received), "queued": client.queued}
        publisher.publish([_abort(PASS, 41)])  # a control message: not held
        await _settle()
        out["abort"] = list(socket.received)
        await ack(len(socket.received))  # read it all: the window lets more go
        await _settle()
        out["after_ack"] = list(socket.received)
        await ack(10**6)  # more than it was sent: an error, the socket goes on
        await _settle()
        out["error"] = socket.of_type("error")
        await hub.close()
        return out

    out = asyncio.run(scenario())
    held = _seqs(out["held"], "commands")
    # 1000 bytes of ~190-byte events may be unacknowledged: five or six, then it waits.
    assert 3 <= len(held) <= 7 and held == list(range(1, len(held) + 1)), held
    assert out["queued"] == 40 - len(held)
    assert out["abort"][-1]["topic"] == "passes" and len(out["abort"]) == len(out["held"]) + 1
    # Having read everything it had (some 1200 bytes), more goes out: its window grew.
    after = _seqs(out["after_ack"], "commands")
    assert len(held) < len(after) < 40 and after == list(range(1, len(after) + 1))
    [error] = out["error"]
    assert error["reason"].startswith("ack of 1000000 messages:") and error["ref_type"] == "ack"
