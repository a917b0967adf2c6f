"""The console push (docs/console.md, v1): topics, per-stream sequence numbers, resume.

The API layer owns the websocket: it authenticates, then hands this service each text frame
(:meth:`ConsoleHub.handle`) and a way to send (``send_text``). The hub:

- **Streams**: one per topic (``commands``, ``passes``, ``events``, ``link``) and one per
  pass for ``telemetry``. Every message of a stream gets the next ``seq`` (from 1, per
  server process; the process's random ``epoch`` names the numbering). A stream keeps its
  last :attr:`ConsoleLimits.ring_size` messages in memory (the ring) and, far longer, a
  compact key per message (the index) by which the message is found again in the database.
- **Sources**: the link's :class:`~server.services.link.Publisher` (committed events,
  archived frames; called on the event loop, so nothing here blocks or awaits there) and a
  poll of :meth:`GroundLink.status` for ``link``.
- **Resume**: ``subscribe`` with ``since_seq`` (and the ``epoch`` it belongs to) replays
  ``(since_seq, seq]`` from the ring, or from the database by the index (events by
  ``(time_ns, kind, pass_id)``, frames by ``reception_time_ns``), with their original seqs;
  when neither covers it (another epoch, the index rolled over, a replay too long, rows not
  found) the client is told ``resync``. Live messages that arrive during a database replay
  are held and follow it, so each subscription delivers strictly increasing seqs.
- **Backpressure**: each client has one send task and a queue. Publishing only puts
  already-encoded text on the queues; a subscription whose client has
  :attr:`ConsoleLimits.queue_bytes` of live messages unsent is dropped (``unsubscribed`` with
  reason ``overflow`` and the last seq queued), so a slow console never slows the ingest
  or the uplink, and it resumes losslessly by subscribing again with ``since_seq``.

Client messages are parsed in ``_console_protocol``; the database replay is
``_console_replay``. The replay of a recorded pass (``replay_*`` messages: a stored pass
streamed to one console at a chosen speed) is ``_console_replay_sessions``: each replay is
its own task, flow-controlled by the bytes of replay data its console has unsent.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import secrets
import time
import uuid
from collections import deque
from collections.abc import Awaitable, Callable, Iterable
from dataclasses import asdict, dataclass
from typing import Any

from sqlalchemy.orm import Session, sessionmaker

from server.services._console_protocol import (
    PROTOCOL_VERSION,
    AuthMsg,
    PingMsg,
    ProtocolError,
    ReplayCloseMsg,
    ReplayOpenMsg,
    ReplayPauseMsg,
    ReplayPlayMsg,
    ReplaySeekMsg,
    ReplaySpeedMsg,
    ReplayStepMsg,
    SubscribeMsg,
    UnsubscribeMsg,
    decode_client,
    encode,
)
from server.services._console_replay import (
    Row,
    TelemetryRows,
    replay_events,
    replay_frames,
    telemetry_rows,
)
from server.services._console_replay_sessions import Replays
from server.services.dbworker import Publisher
from server.services.link import LinkStatus
from server.storage import repository as repo
from server.storage.errors import NotFound
from server.storage.models import TELEMETRY_FIELDS
from telemetry.wire import TelemetryFrame

__all__ = [
    "EVENT_TOPICS",
    "PROTOCOL_VERSION",
    "TOPICS",
    "AuthMsg",
    "ConsoleClient",
    "ConsoleHub",
    "ConsoleLimits",
    "ProtocolError",
    "decode_client",
]

log = logging.getLogger("hikoboshi.ground.console")

#: Event topics and the event kinds each carries (``None``: every kind).
EVENT_TOPICS: dict[str, tuple[str, ...] | None] = {
    # An abort cancels a pass's commands in one ``commands_cancelled`` event (count and seq
    # range), not one ``command_stage`` each: a console following stages needs it too.
    "commands": ("command_stage", "commands_cancelled"),
    "passes": ("pass_state",),
    "events": None,
}
TOPICS = ("telemetry", *EVENT_TOPICS, "link")


@dataclass
class ConsoleLimits:
    """What one console and one stream may hold; read when used, so a test may shrink it."""

    ring_size: int = 1024  # messages per stream kept in memory for a replay
    index_size: int = 1_000_000  # messages per stream that can be found in the database
    #: Live data unsent to one client (bytes of text) beyond which its subscription is
    #: dropped: a burst (an abort expires thousands of commands at once) fits; a console
    #: that stopped reading is found out in minutes, not hours.
    queue_bytes: int = 2 * 1024 * 1024
    max_replay: int = 4096  # messages one subscribe may replay (more: resync)
    max_subscriptions: int = 32
    max_message_bytes: int = 64 * 1024  # client -> server
    max_rate_hz: float = 1000.0
    link_poll_s: float = 1.0  # wall
    link_heartbeat_s: float = 5.0  # wall: the link status is pushed at least this often
    auth_timeout_s: float = 10.0
    # Replay of recorded passes:
    max_replays_per_console: int = 4
    max_replays: int = 32  # in the whole server (each holds its recording in memory)
    max_replay_frames: int = 200_000  # frames of one recording (~5.5 h at 10 Hz, ~70 MB)
    max_replay_factor: float = 1000.0
    max_replay_batch_frames: int = 500  # frames per message (and as-fast-as-possible batch)
    #: Replay data unsent to one console beyond which its replays hold (until half is sent).
    replay_window_bytes: int = 1024 * 1024
    replay_tick_s: float = 0.02  # wall: a real-time replay sends at most this often
    replay_report_s: float = 0.5  # wall: replay_state while frames flow, at most this often

    @property
    def hard_cap(self) -> int:
        """Messages of any kind queued to one client beyond which it is disconnected."""
        return self.max_replay + 1024


def _canonical_pass(pass_id: str | None) -> str | None:
    if pass_id is None:
        return None
    try:
        return str(uuid.UUID(pass_id))
    except ValueError:
        return pass_id


# --- streams -------------------------------------------------------------------------------


@dataclass(slots=True)
class _Message:
    seq: int
    key: Any  # how to find it in the database (None: it is not stored)
    payload: Any  # event dict, link status document, or telemetry rows
    text: str | None = None  # encoded once, for every subscriber without a filter


class _Stream:
    def __init__(self, topic: str, pass_id: str | None, limits: ConsoleLimits):
        self.topic = topic
        self.pass_id = pass_id
        self.limits = limits
        self.last_seq = 0
        self.ring: deque[_Message] = deque()
        # keys[i] belongs to seq last_seq - len(keys) + 1 + i
        self.keys: deque[Any] = deque()
        self.subscriptions: list[_Subscription] = []

    def append(self, key: Any, payload: Any) -> _Message:
        self.last_seq += 1
        message = _Message(self.last_seq, key, payload)
        message.text = _render(self, message, None)
        self.ring.append(message)
        self.keys.append(key)
        while len(self.ring) > self.limits.ring_size:
            self.ring.popleft()
        while len(self.keys) > self.limits.index_size:
            self.keys.popleft()
        return message

    def from_ring(self, since_seq: int) -> list[_Message] | None:
        """Messages after ``since_seq``, or None when the ring no longer holds them all."""
        if since_seq >= self.last_seq:
            return []
        if not self.ring or self.ring[0].seq > since_seq + 1:
            return None
        return [m for m in self.ring if m.seq > since_seq]

    def indexed(self, since_seq: int) -> list[tuple[int, Any]] | None:
        """``(seq, key)`` after ``since_seq``, or None when the index does not reach back."""
        first = self.last_seq - len(self.keys) + 1
        if since_seq + 1 < first:
            return None
        skip = since_seq + 1 - first
        return [(first + i, k) for i, k in enumerate(self.keys) if i >= skip]


@dataclass
class _TelemetryFilter:
    #: The columns asked for (None: every column of the pass's layout); one a pass's robot
    #: does not have (``j7`` of a 6-joint pass) is left out of its messages.
    columns: tuple[str, ...] | None
    period_ns: int | None  # decimation: one frame per this much generation time
    next_generation_ns: int = -(2**63)

    def apply(self, rows: list[Row]) -> list[Row]:
        if self.period_ns is not None:
            kept = []
            for row in rows:
                if row[1] >= self.next_generation_ns:
                    kept.append(row)
                    self.next_generation_ns = row[1] + self.period_ns
            rows = kept
        return rows


def _render(stream: _Stream, message: _Message, flt: _TelemetryFilter | None) -> str | None:
    """The message as sent; None when a filter leaves nothing of it."""
    doc: dict[str, Any] = {"v": PROTOCOL_VERSION, "topic": stream.topic}
    if stream.topic == "telemetry":
        batch: TelemetryRows = message.payload
        rows: list[Row] = batch.rows
        names: Iterable[str] = batch.columns
        if flt is not None:
            kept = flt.apply(rows)
            if not kept:
                return None
            if flt.columns is None and len(kept) == len(rows) and message.text is not None:
                return message.text  # decimation kept it whole: the shared text will do
            rows = kept
            if flt.columns is not None:
                index = {name: i for i, name in enumerate(batch.columns)}
                names = [name for name in flt.columns if name in index]
                rows = [tuple(row[index[name]] for name in names) for row in rows]
        doc |= {"type": "telemetry", "pass_id": stream.pass_id, "seq": message.seq}
        doc["count"] = len(rows)
        doc["columns"] = dict(zip(names, (list(c) for c in zip(*rows, strict=True)), strict=True))
    elif stream.topic == "link":
        doc |= {"type": "link", "seq": message.seq, **message.payload}
    else:
        doc |= {"type": "event", "seq": message.seq, "event": message.payload}
    return encode(doc)


class _Subscription:
    def __init__(self, client: ConsoleClient, stream: _Stream, flt: _TelemetryFilter | None):
        self.client = client
        self.stream = stream
        self.filter = flt
        self.replaying = True
        self.backlog: list[_Message] = []
        self.backlog_bytes = 0
        self.last_seq = 0  # the last seq queued (or passed over by the filter)
        self.closed = False

    def offer(self, message: _Message, *, live: bool) -> None:
        if self.closed:
            return
        if self.replaying and live:
            self.backlog.append(message)
            self.backlog_bytes += len(message.text or "")
            if self.backlog_bytes > self.client.limits.queue_bytes:
                self.client.hub.drop(self, "overflow: the console is not keeping up")
            return
        if message.seq <= self.last_seq:
            return  # already queued (a live message that raced a replay)
        text = message.text if self.filter is None else _render(self.stream, message, self.filter)
        if text is not None and not self.client.queue_data(text, live=live):
            self.client.hub.drop(self, "overflow: the console is not keeping up")
            return
        self.last_seq = message.seq

    def info(self) -> dict[str, Any]:
        doc: dict[str, Any] = {"topic": self.stream.topic}
        if self.stream.pass_id is not None:
            doc["pass_id"] = self.stream.pass_id
        return doc


# --- clients -------------------------------------------------------------------------------

_CONTROL, _LIVE, _REPLAY = 0, 1, 2  # what a queued text is


class ConsoleClient:
    """One console websocket: its subscriptions, its queue and its send task."""

    def __init__(
        self,
        hub: ConsoleHub,
        actor: str,
        send_text: Callable[[str], Awaitable[None]],
        close: Callable[[int, str], Awaitable[None]],
    ):
        self.hub = hub
        self.actor = actor
        self.limits = hub.limits
        self._send_text = send_text
        self._close = close
        self.subscriptions: dict[tuple[str, str | None], _Subscription] = {}
        # (text, kind): control, live data (may be dropped) or replay data (flow-controlled)
        self._queue: asyncio.Queue[tuple[str, int] | None] = asyncio.Queue()
        self.live_bytes = 0  # live data queued and not yet handed to the socket
        self.replay_bytes = 0  # replay data queued and not yet handed to the socket
        self._replay_sent = asyncio.Event()
        self.closing = False
        self.sender = asyncio.create_task(self._send_loop(), name=f"console-send-{actor}")

    @property
    def queued(self) -> int:
        return self._queue.qsize()

    def queue_data(self, text: str, *, live: bool) -> bool:
        """Queue a data message; False (nothing queued) when the client is too far behind."""
        if live:
            if self.live_bytes + len(text) > self.limits.queue_bytes:
                return False
            self.live_bytes += len(text)
        self._queue.put_nowait((text, _LIVE if live else _CONTROL))
        return True

    def queue_replay(self, text: str) -> None:
        """Queue replay data (never dropped: a replay waits, :meth:`replay_below`)."""
        self.replay_bytes += len(text)
        self._queue.put_nowait((text, _REPLAY))

    async def replay_below(self, limit_bytes: int) -> None:
        """Return once at most ``limit_bytes`` of replay data are unsent."""
        while self.replay_bytes > limit_bytes:
            self._replay_sent.clear()
            await self._replay_sent.wait()

    def control(self, doc: dict[str, Any]) -> None:
        """Queue a control message (never dropped; a client that lets them pile up goes)."""
        if self._queue.qsize() >= self.limits.hard_cap:
            self.kill(1008, "the console does not read its messages")
            return
        self._queue.put_nowait((encode({"v": PROTOCOL_VERSION, **doc}), _CONTROL))

    def kill(self, code: int, reason: str) -> None:
        if self.closing:
            return
        self.closing = True
        self.hub.remove(self)

        async def close() -> None:
            with contextlib.suppress(Exception):
                await self._close(code, reason)

        self.hub.background(asyncio.get_running_loop().create_task(close()))

    async def _send_loop(self) -> None:
        while (item := await self._queue.get()) is not None:
            text, kind = item
            if kind == _LIVE:
                self.live_bytes -= len(text)
            elif kind == _REPLAY:
                self.replay_bytes -= len(text)
                self._replay_sent.set()
            try:
                await self._send_text(text)
            except Exception as exc:  # the socket went away; the receive loop ends it
                log.info("console %s: send failed: %r", self.actor, exc)
                return

    async def stop(self) -> None:
        self._queue.put_nowait(None)
        if not self.sender.done():
            self.sender.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await self.sender


# --- the hub -------------------------------------------------------------------------------

_REPLAY_MSGS = (
    ReplayOpenMsg,
    ReplayPlayMsg,
    ReplayPauseMsg,
    ReplayStepMsg,
    ReplaySpeedMsg,
    ReplaySeekMsg,
    ReplayCloseMsg,
)


class ConsoleHub:
    """Every console of the ground service (on ``app.state.console``)."""

    def __init__(
        self,
        *,
        publisher: Publisher,
        link_status: Callable[[], LinkStatus],
        sessions: sessionmaker[Session],
        limits: ConsoleLimits | None = None,
    ):
        self.limits = limits or ConsoleLimits()
        #: Names this process's numbering: seqs of another epoch mean nothing here.
        self.epoch = f"{time.time_ns() // 10**9:x}-{secrets.token_hex(4)}"
        self._publisher = publisher
        self._link_status = link_status
        self._sessions = sessions
        self._streams: dict[tuple[str, str | None], _Stream] = {}
        self._clients: set[ConsoleClient] = set()
        self._tasks: set[asyncio.Task[Any]] = set()
        self._unhook: list[Callable[[], None]] = []
        self._poller: asyncio.Task[None] | None = None
        self.replays = Replays(sessions=sessions, limits=self.limits)

    # -- lifecycle -----------------------------------------------------------------------

    def start(self) -> None:
        self._unhook = [
            self._publisher.subscribe(self._on_event),
            self._publisher.subscribe_frames(self._on_frames),
        ]
        self._poller = asyncio.create_task(self._poll_link(), name="console-link-poll")

    async def close(self) -> None:
        for unhook in self._unhook:
            unhook()
        self._unhook = []
        if self._poller is not None:
            self._poller.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._poller
        await self.replays.close()
        for client in list(self._clients):
            self.remove(client)
            await client.stop()
        for task in list(self._tasks):
            task.cancel()

    def background(self, task: asyncio.Task[Any]) -> None:
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def connect(
        self,
        *,
        actor: str,
        role: str,
        send_text: Callable[[str], Awaitable[None]],
        close: Callable[[int, str], Awaitable[None]],
    ) -> ConsoleClient:
        client = ConsoleClient(self, actor, send_text, close)
        self._clients.add(client)
        limits = self.limits
        client.control(
            {
                "type": "welcome",
                "epoch": self.epoch,
                "actor": actor,
                "role": role,
                "topics": list(TOPICS),
                "limits": {
                    "queue_bytes": limits.queue_bytes,
                    "ring_size": limits.ring_size,
                    "max_replay": limits.max_replay,
                    "max_subscriptions": limits.max_subscriptions,
                    "max_message_bytes": limits.max_message_bytes,
                    "link_heartbeat_s": limits.link_heartbeat_s,
                    "max_replays_per_console": limits.max_replays_per_console,
                    "max_replay_factor": limits.max_replay_factor,
                    "max_replay_batch_frames": limits.max_replay_batch_frames,
                },
            }
        )
        return client

    def remove(self, client: ConsoleClient) -> None:
        self.replays.close_client(client)
        for sub in list(client.subscriptions.values()):
            self._detach(sub)
        client.subscriptions.clear()
        self._clients.discard(client)

    async def disconnect(self, client: ConsoleClient) -> None:
        self.remove(client)
        await client.stop()

    @property
    def clients(self) -> int:
        return len(self._clients)

    # -- sources (event loop; never block) -------------------------------------------------

    def _stream(self, topic: str, pass_id: str | None = None) -> _Stream:
        stream = self._streams.get((topic, pass_id))
        if stream is None:
            stream = self._streams[(topic, pass_id)] = _Stream(topic, pass_id, self.limits)
        return stream

    def _push(self, stream: _Stream, key: Any, payload: Any) -> None:
        message = stream.append(key, payload)
        for sub in list(stream.subscriptions):
            sub.offer(message, live=True)

    def _on_event(self, event: dict[str, Any]) -> None:
        kind = event["kind"]
        pass_id = _canonical_pass(event.get("pass_id"))
        key = (event["time_ns"], kind, pass_id)
        payload = {**event, "pass_id": pass_id}
        for topic, kinds in EVENT_TOPICS.items():
            if kinds is None or kind in kinds:
                self._push(self._stream(topic), key, payload)

    def _on_frames(
        self, pass_id: str, frames: list[TelemetryFrame], reception_time_ns: int
    ) -> None:
        if not frames:
            return
        batch = telemetry_rows(frames, reception_time_ns)
        rows = batch.rows
        key = (reception_time_ns, rows[0][1], max(r[1] for r in rows), len(rows))
        self._push(self._stream("telemetry", _canonical_pass(pass_id)), key, batch)

    def push_link_status(self, status: LinkStatus) -> None:
        payload = {"ground_time_ns": time.time_ns(), "status": asdict(status)}
        self._push(self._stream("link"), None, payload)

    async def _poll_link(self) -> None:
        previous: dict[str, Any] | None = None
        pushed = -float("inf")
        while True:
            try:
                status = self._link_status()
                # The onboard clock always moves: a change is anything else.
                compare = {**asdict(status), "onboard_time_ns": None}
                now = time.monotonic()
                if compare != previous or now - pushed >= self.limits.link_heartbeat_s:
                    self.push_link_status(status)
                    previous, pushed = compare, now
            except Exception:
                log.exception("link status poll failed")
            await asyncio.sleep(self.limits.link_poll_s)

    # -- client messages -------------------------------------------------------------------

    async def handle(self, client: ConsoleClient, raw: str | bytes) -> None:
        """One frame from a console; anything wrong with it is answered with ``error``."""
        ref_type: str | None = None
        try:
            message = decode_client(raw, self.limits.max_message_bytes)
            ref_type = message.type
            if isinstance(message, SubscribeMsg):
                await self._subscribe(client, message)
            elif isinstance(message, UnsubscribeMsg):
                self._unsubscribe(client, message)
            elif isinstance(message, PingMsg):
                client.control({"type": "pong", "id": message.id, "time_ns": time.time_ns()})
            elif isinstance(message, _REPLAY_MSGS):
                await self.replays.handle(client, message)
            else:
                raise ProtocolError("already authenticated")
        except ProtocolError as exc:
            ref_type = ref_type or exc.ref_type
            client.control({"type": "error", "reason": str(exc)[:500], "ref_type": ref_type})

    async def _stream_of(self, topic: str, pass_id: str | None) -> _Stream:
        if topic not in TOPICS:
            raise ProtocolError(f"unknown topic {topic!r}: one of {', '.join(TOPICS)}")
        if topic != "telemetry":
            if pass_id is not None:
                raise ProtocolError(f"pass_id applies to telemetry only, not {topic!r}")
            return self._stream(topic)
        if pass_id is None:
            raise ProtocolError("telemetry needs a pass_id")
        key = _canonical_pass(pass_id)
        if ("telemetry", key) not in self._streams:
            try:
                key = await asyncio.to_thread(self._pass_exists, pass_id)
            except NotFound as exc:
                raise ProtocolError(str(exc)) from None
        return self._stream("telemetry", key)

    def _pass_exists(self, pass_id: str) -> str:
        with self._sessions() as session:
            return repo.get_pass(session=session, pass_id=pass_id).id

    def _telemetry_filter(self, message: SubscribeMsg) -> _TelemetryFilter | None:
        if message.max_rate_hz is None and message.fields is None:
            return None
        if message.topic != "telemetry":
            raise ProtocolError("max_rate_hz and fields apply to telemetry only")
        period_ns = None
        if message.max_rate_hz is not None:
            if message.max_rate_hz > self.limits.max_rate_hz:
                limit = self.limits.max_rate_hz
                raise ProtocolError(f"max_rate_hz {message.max_rate_hz} exceeds {limit}")
            period_ns = round(1e9 / message.max_rate_hz)
        columns = None
        if message.fields is not None:
            for name in message.fields:
                if name not in TELEMETRY_FIELDS:
                    raise ProtocolError(f"field {name!r} is not one of {TELEMETRY_FIELDS}")
            if len(set(message.fields)) != len(message.fields):
                raise ProtocolError(f"fields {message.fields} repeat a name")
            wanted = ["seq", "generation_time_ns", "reception_time_ns", *message.fields]
            columns = tuple(dict.fromkeys(wanted))
        return _TelemetryFilter(columns=columns, period_ns=period_ns)

    async def _subscribe(self, client: ConsoleClient, message: SubscribeMsg) -> None:
        if message.since_seq is not None and message.epoch is None:
            raise ProtocolError("since_seq needs the epoch it was counted in")
        flt = self._telemetry_filter(message)
        stream = await self._stream_of(message.topic, message.pass_id)
        key = (stream.topic, stream.pass_id)
        if key not in client.subscriptions and (
            len(client.subscriptions) >= self.limits.max_subscriptions
        ):
            raise ProtocolError(f"{self.limits.max_subscriptions} subscriptions at most")
        same_epoch = message.epoch == self.epoch
        if message.since_seq is not None and same_epoch and message.since_seq > stream.last_seq:
            raise ProtocolError(
                f"since_seq {message.since_seq} is ahead of the stream (last seq {stream.last_seq})"
            )
        if (old := client.subscriptions.pop(key, None)) is not None:
            self._detach(old)
        sub = _Subscription(client, stream, flt)
        client.subscriptions[key] = sub
        stream.subscriptions.append(sub)
        last = stream.last_seq
        client.control({"type": "subscribed", **sub.info(), "epoch": self.epoch, "seq": last})
        if message.since_seq is None:
            # Live from now; the link topic is a state, so its latest message comes too.
            since: int | None = max(0, last - 1) if stream.topic == "link" else last
            reason = ""
        elif not same_epoch:
            since, reason = None, f"epoch {message.epoch!r} is not this server's ({self.epoch})"
        else:
            since, reason = message.since_seq, ""
        replay: list[_Message] | None = None
        if since is not None:
            replay, reason = await self._replay(client, stream, since)
        if sub.closed:
            return
        if replay is None:
            info = {**sub.info(), "epoch": self.epoch, "seq": last, "reason": reason}
            client.control({"type": "resync", **info})
            sub.last_seq = last
        else:
            sub.last_seq = since if since is not None else last
            for m in replay:
                sub.offer(m, live=False)
        sub.replaying = False
        backlog, sub.backlog, sub.backlog_bytes = sub.backlog, [], 0
        for m in backlog:
            sub.offer(m, live=True)

    async def _replay(
        self, client: ConsoleClient, stream: _Stream, since: int
    ) -> tuple[list[_Message] | None, str]:
        """The messages ``(since, last]``, or None and why not."""
        wanted = stream.last_seq - since
        if wanted > self.limits.max_replay or client.queued + wanted > self.limits.hard_cap:
            return None, f"{wanted} messages to replay: more than {self.limits.max_replay}"
        ring = stream.from_ring(since)
        if ring is not None:
            return ring, ""
        entries = stream.indexed(since)
        if entries is None or stream.topic == "link":
            return None, f"seq {since + 1} is no longer held"
        try:
            if stream.topic == "telemetry":
                assert stream.pass_id is not None
                found = await asyncio.to_thread(
                    replay_frames, self._sessions, stream.pass_id, entries
                )
            else:
                kinds = EVENT_TOPICS[stream.topic]
                found = await asyncio.to_thread(replay_events, self._sessions, kinds, entries)
        except Exception as exc:
            log.exception("console replay of %s failed", stream.topic)
            return None, f"the database replay failed: {exc!r}"[:300]
        if found is None:
            return None, f"seqs {since + 1}..{entries[-1][0]} are not all in the database"
        return [self._replayed(stream, seq, key, payload) for seq, key, payload in found], ""

    @staticmethod
    def _replayed(stream: _Stream, seq: int, key: Any, payload: Any) -> _Message:
        message = _Message(seq, key, payload)
        message.text = _render(stream, message, None)
        return message

    def _unsubscribe(self, client: ConsoleClient, message: UnsubscribeMsg) -> None:
        key = (message.topic, _canonical_pass(message.pass_id))
        sub = client.subscriptions.pop(key, None)
        if sub is None:
            raise ProtocolError(f"not subscribed to {message.topic!r} (pass {message.pass_id})")
        self._detach(sub)
        info = {**sub.info(), "seq": sub.last_seq, "reason": "requested"}
        client.control({"type": "unsubscribed", **info})

    def _detach(self, sub: _Subscription) -> None:
        sub.closed = True
        with contextlib.suppress(ValueError):
            sub.stream.subscriptions.remove(sub)

    def drop(self, sub: _Subscription, reason: str) -> None:
        """End a subscription whose client is too far behind (it may subscribe again)."""
        client = sub.client
        key = (sub.stream.topic, sub.stream.pass_id)
        if client.subscriptions.get(key) is sub:
            del client.subscriptions[key]
        self._detach(sub)
        client.control(
            {"type": "unsubscribed", **sub.info(), "seq": sub.last_seq, "reason": reason}
        )
