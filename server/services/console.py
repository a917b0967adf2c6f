"""The console push (docs/console.md, v1): topics, per-stream sequence numbers, resume.

The API layer owns the websocket: it authenticates, then hands this service each text frame
(:meth:`ConsoleHub.handle`) and a way to send (``send_text``). The hub:

- **Streams**: one per topic (``commands``, ``passes``, ``events``, ``link``, ``alarms``)
  and one per pass for ``telemetry``. Every message of a stream gets the next ``seq`` (from 1, per
  server process; the process's random ``epoch`` names the numbering). A stream keeps its
  last :attr:`ConsoleLimits.ring_size` messages in memory (the ring) and, far longer, a
  compact key per message (the index) by which the message is found again in the database.
  A pass's telemetry stream is let go once the pass has ended and nobody subscribes to it
  (at that pass's end or a later one's), keeping only its last seq: a stream made again
  for it goes on counting from there, and what came before is ``resync``.
- **Sources**: the link's :class:`~server.services.link.Publisher` (committed events,
  archived frames, alarms as written; called on the event loop, so nothing here blocks or
  awaits there) and a poll of :meth:`GroundLink.status` for ``link``.
- **Resume**: ``subscribe`` with ``since_seq`` (and the ``epoch`` it belongs to) replays
  ``(since_seq, seq]`` from the ring, or from the database by the index (events by
  ``(time_ns, kind, pass_id)``, frames by ``reception_time_ns``), with their original seqs;
  when neither covers it (another epoch, the index rolled over, a replay too long, rows not
  found) the client is told ``resync``. ``link`` and ``alarms`` are states, replayed from
  the ring only (``resync``: reload ``GET /api/link/status``, ``GET /api/alarms``). Live
  messages that arrive during a database replay are held and follow it, so each
  subscription delivers strictly increasing seqs.
- **Backpressure**: each client has one send task and two queues, control before bulk
  (``_console_streams.CONTROL_TOPICS``: pass states, alarms and the link jump telemetry,
  command stages and the audit log; a topic is one class whole, so each subscription stays
  in seq order). Publishing only puts already-encoded text on the queues; a subscription
  whose client has :attr:`ConsoleLimits.queue_bytes` of live messages unsent is dropped
  (``unsubscribed`` with reason ``overflow`` and the last seq queued), so a slow console
  never slows the ingest or the uplink, and it resumes losslessly by subscribing again with
  ``since_seq``.
- **A console behind** (:meth:`ConsoleHub.check_lag`, every ``lag_check_s`` on the hub's
  clock): its lag is the age of its oldest unread message: unsent, or (for a console that
  sends ``ack``, the count of messages it has read) sent and not acknowledged; such a
  console is handed bulk data only within its window (what it read in the last
  ``ack_window_s``), so that its backlog stays here, not in the socket's buffers. It is
  told (``lag``) from ``behind_report_s``; bulk data older than ``behind_resync_s`` is
  dropped and each of its streams told ``resync`` (reload the snapshot, then live); past
  ``behind_drop_s`` it is told why (``error``, the close's reason) and closed.

Client messages are parsed in ``_console_protocol``; the messages sent are the models of
``console_messages``; streams, subscriptions and clients are ``_console_streams``; the
database replay is ``_console_replay``. The replay of a recorded pass (``replay_*``
messages: a stored pass streamed to one console at a chosen speed) is
``_console_replay_sessions``: each replay is its own task, flow-controlled by the bytes of
replay data its console has unsent.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import secrets
import time
import uuid
from collections.abc import Awaitable, Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from typing import Any, TypeVar, cast

from sqlalchemy.orm import Session, sessionmaker

from server.services._console_protocol import (
    PROTOCOL_VERSION,
    AckMsg,
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
)
from server.services._console_replay import replay_events, replay_frames, telemetry_rows
from server.services._console_replay_sessions import Replays
from server.services._console_streams import (
    ConsoleClient,
    LinkReport,
    Message,
    Payload,
    Stream,
    Subscription,
    TelemetryFilter,
    render,
)
from server.services.clock import Clock, SystemClock
from server.services.console_messages import (
    ConsoleAlarm,
    ConsoleEvent,
    ConsoleRole,
    ErrorMsg,
    LagMsg,
    PongMsg,
    ResyncMsg,
    SubscribedMsg,
    UnsubscribedMsg,
    WelcomeLimits,
    WelcomeMsg,
)
from server.services.dbworker import Publisher
from server.services.link import LinkStatus
from server.storage import repository as repo
from server.storage.errors import NotFound
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
T = TypeVar("T")

#: Event topics and the event kinds each carries (``None``: every kind).
EVENT_TOPICS: dict[str, tuple[str, ...] | None] = {
    # An abort cancels a pass's commands in one ``commands_cancelled`` event (count and seq
    # range), not one ``command_stage`` each: a console following stages needs it too.
    "commands": ("command_stage", "commands_cancelled"),
    "passes": ("pass_state",),
    "events": None,
}
TOPICS = ("telemetry", *EVENT_TOPICS, "link", "alarms")
#: Topics whose messages are states, not found again in the database (ring only).
_STATE_TOPICS = ("link", "alarms")
#: A pass's states after which its telemetry stream may be retired.
_ENDED_STATES = ("complete", "aborted", "safed")
#: How many retired telemetry streams' last seqs are remembered (a few ints each).
RETIRED_KEPT = 10_000


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
    # A console behind (docs/console.md, "Backpressure"); times on the hub's clock:
    lag_check_s: float = 0.25  # how often each console's lag is measured
    #: A console whose oldest unsent message is older than this is sent ``lag`` (at most
    #: this often, and once more, ``behind_s: 0``, when it has caught up).
    behind_report_s: float = 0.5
    #: Bulk data (telemetry, command stages, the audit log) unsent for longer than this is
    #: dropped and each of its subscriptions told ``resync``: the console reloads the
    #: snapshot over REST and goes on live, instead of reading a backlog older than that.
    behind_resync_s: float = 2.0
    #: Anything unsent for longer than this (control messages, which jump the queue,
    #: included): the console is told why (``error``, and the close's reason) and closed.
    behind_drop_s: float = 30.0
    #: A console that acknowledges what it reads (``ack``) is handed bulk data only while
    #: what it has not acknowledged is less than what it read in the last this long (at
    #: least ``ack_window_min_bytes``): the rest waits in the server's queues, not in the
    #: socket's buffers, where a control message could not pass it nor a resync drop it.
    ack_window_s: float = 0.5
    ack_window_min_bytes: int = 4096

    @property
    def hard_cap(self) -> int:
        """Messages queued to one client, other than its subscriptions' data (which
        ``queue_bytes`` and the lag bounds hold), beyond which it is disconnected."""
        return self.max_replay + 1024


def _canonical_pass(pass_id: str | None) -> str | None:
    if pass_id is None:
        return None
    try:
        return str(uuid.UUID(pass_id))
    except ValueError:
        return pass_id


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
        replay_sessions: sessionmaker[Session] | None = None,
        db_threads: int = 2,
        clock: Clock | None = None,
    ):
        """``sessions``: the hub's own reads (a subscription's pass, missed messages), in
        ``db_threads`` threads of its own; ``replay_sessions`` (default ``sessions``): the
        replays' loads of whole recordings; ``clock``: what the consoles' lag is measured
        on (default the system's)."""
        self.limits = limits or ConsoleLimits()
        self.clock: Clock = clock or SystemClock()
        #: Names this process's numbering: seqs of another epoch mean nothing here.
        self.epoch = f"{time.time_ns() // 10**9:x}-{secrets.token_hex(4)}"
        self._publisher = publisher
        self._link_status = link_status
        self._sessions = sessions
        self._streams: dict[tuple[str, str | None], Stream] = {}
        #: passes seen ending whose telemetry stream is still held
        self._ended: set[str] = set()
        #: the last seq of each retired telemetry stream, by pass (see :meth:`_retire`)
        self._retired: dict[str, int] = {}
        self._clients: set[ConsoleClient] = set()
        self._tasks: set[asyncio.Task[Any]] = set()
        self._unhook: list[Callable[[], None]] = []
        self._poller: asyncio.Task[None] | None = None
        self._lag_watch: asyncio.Task[None] | None = None
        self._db_threads = ThreadPoolExecutor(db_threads, thread_name_prefix="console-db")
        self.replays = Replays(sessions=replay_sessions or sessions, limits=self.limits)

    # -- lifecycle -----------------------------------------------------------------------

    def start(self) -> None:
        self._unhook = [
            self._publisher.subscribe(self._on_event),
            self._publisher.subscribe_frames(self._on_frames),
            self._publisher.subscribe_alarms(self._on_alarm),
        ]
        self._poller = asyncio.create_task(self._poll_link(), name="console-link-poll")
        self._lag_watch = asyncio.create_task(self._watch_lag(), name="console-lag")

    async def close(self) -> None:
        for unhook in self._unhook:
            unhook()
        self._unhook = []
        for task in (self._poller, self._lag_watch):
            if task is not None:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task
        await self.replays.close()
        for client in list(self._clients):
            self.remove(client)
            await client.stop()
        for task in list(self._tasks):
            task.cancel()
        self._db_threads.shutdown(wait=False, cancel_futures=True)

    async def _in_db_thread(self, fn: Callable[..., T], *args: Any) -> T:
        """``fn(*args)`` in one of the hub's own threads: never behind viewer requests'."""
        loop = asyncio.get_running_loop()
        return await loop.run_in_executor(self._db_threads, fn, *args)

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
            WelcomeMsg(
                epoch=self.epoch,
                actor=actor,
                role=cast(ConsoleRole, role),  # validated: a viewer or an operator
                topics=list(TOPICS),
                limits=WelcomeLimits(
                    queue_bytes=limits.queue_bytes,
                    ring_size=limits.ring_size,
                    max_replay=limits.max_replay,
                    max_subscriptions=limits.max_subscriptions,
                    max_message_bytes=limits.max_message_bytes,
                    link_heartbeat_s=limits.link_heartbeat_s,
                    behind_report_s=limits.behind_report_s,
                    behind_resync_s=limits.behind_resync_s,
                    behind_drop_s=limits.behind_drop_s,
                    ack_window_s=limits.ack_window_s,
                    max_replays_per_console=limits.max_replays_per_console,
                    max_replay_factor=limits.max_replay_factor,
                    max_replay_batch_frames=limits.max_replay_batch_frames,
                ),
            )
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

    @property
    def telemetry_streams(self) -> list[str]:
        """The passes whose telemetry stream is held (in memory)."""
        return [p for (topic, p) in self._streams if topic == "telemetry" and p is not None]

    # -- sources (event loop; never block) -------------------------------------------------

    def _stream(self, topic: str, pass_id: str | None = None) -> Stream:
        stream = self._streams.get((topic, pass_id))
        if stream is None:
            stream = self._streams[(topic, pass_id)] = Stream(topic, pass_id, self.limits)
            if pass_id is not None and pass_id in self._retired:
                # a late frame or a new subscription of an ended pass: the numbering goes on
                # (an earlier seq is no longer held: resync), and it is retired again
                stream.last_seq = self._retired.pop(pass_id)
                self._ended.add(pass_id)
        return stream

    def _retire(self) -> None:
        """Let go of the telemetry streams of ended passes nobody subscribes to: each held a
        ring of its pass's last messages for good, some megabytes a pass, so a ground flying
        pass after pass grew without bound. Only the stream's last seq is kept."""
        for pass_id in list(self._ended):
            stream = self._streams.get(("telemetry", pass_id))
            if stream is None:
                self._ended.discard(pass_id)
            elif not stream.subscriptions:
                del self._streams[("telemetry", pass_id)]
                self._ended.discard(pass_id)
                self._retired[pass_id] = stream.last_seq
        while len(self._retired) > RETIRED_KEPT:
            del self._retired[next(iter(self._retired))]

    def _push(self, stream: Stream, key: Any, payload: Payload) -> None:
        message = stream.append(key, payload)
        for sub in list(stream.subscriptions):
            sub.offer(message, live=True)

    def _on_event(self, event: dict[str, Any]) -> None:
        kind = event["kind"]
        pass_id = _canonical_pass(event.get("pass_id"))
        key = (event["time_ns"], kind, pass_id)
        payload = ConsoleEvent.model_validate({**event, "pass_id": pass_id})
        for topic, kinds in EVENT_TOPICS.items():
            if kinds is None or kind in kinds:
                self._push(self._stream(topic), key, payload)
        ended = (event.get("detail") or {}).get("to") in _ENDED_STATES
        if kind == "pass_state" and pass_id is not None and ended:
            self._ended.add(pass_id)
            self._retire()

    def _on_frames(
        self, pass_id: str, frames: list[TelemetryFrame], reception_time_ns: int
    ) -> None:
        if not frames:
            return
        batch = telemetry_rows(frames, reception_time_ns)
        rows = batch.rows
        key = (reception_time_ns, rows[0][1], max(r[1] for r in rows), len(rows))
        self._push(self._stream("telemetry", _canonical_pass(pass_id)), key, batch)

    def _on_alarm(self, alarm: dict[str, Any]) -> None:
        self._push(self._stream("alarms"), None, ConsoleAlarm.model_validate(alarm))

    def push_link_status(self, status: LinkStatus) -> None:
        self._push(self._stream("link"), None, LinkReport(time.time_ns(), status))

    # -- consoles behind ------------------------------------------------------------------

    async def _watch_lag(self) -> None:
        while True:
            try:
                self.check_lag()
            except Exception:
                log.exception("console lag check failed")
            await self.clock.sleep_until(self.clock.monotonic() + self.limits.lag_check_s)

    def check_lag(self) -> None:
        """Measure every console's lag (the age of its oldest unsent message) and act on it:
        tell it (``lag``), drop its bulk backlog for a ``resync``, or close it."""
        now = self.clock.monotonic()
        limits = self.limits
        for client in list(self._clients):
            if client.closing:
                continue
            lag = client.lag(now)
            if lag.any_s > limits.behind_drop_s:
                reason = (
                    f"behind by {lag.any_s:.0f} s, more than {limits.behind_drop_s:g} s:"
                    " the console does not keep up"
                )
                log.warning("console %s: %s; closed", client.actor, reason)
                client.control(ErrorMsg(reason=reason, ref_type=None))
                client.kill(1008, reason)
                continue
            dropped = client.drop_bulk() if lag.bulk_s > limits.behind_resync_s else {}
            behind = lag.any_s >= limits.behind_report_s
            due = now - client.last_lag_report >= limits.behind_report_s
            if (behind and due) or dropped or (client.reported_behind and not behind):
                client.control(
                    LagMsg(
                        behind_s=round(lag.any_s, 3) if behind else 0.0,
                        queued=client.queued,
                        resync_s=limits.behind_resync_s,
                        time_ns=self.clock.time_ns(),
                    )
                )
                client.last_lag_report = now
                client.reported_behind = behind
            if dropped:
                client.resyncs += 1
                log.info(
                    "console %s: behind by %.1f s, %d messages dropped: resync",
                    client.actor,
                    lag.bulk_s,
                    sum(dropped.values()),
                )
            for sub, count in dropped.items():
                if sub.closed:
                    continue
                stream = sub.stream
                client.control(
                    ResyncMsg(
                        topic=stream.topic,
                        pass_id=stream.pass_id,
                        epoch=self.epoch,
                        seq=sub.last_seq,
                        reason=(
                            f"behind by {lag.bulk_s:.1f} s, more than"
                            f" {limits.behind_resync_s:g} s: {count} messages not sent;"
                            " reload the snapshot"
                        ),
                    )
                )

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
            elif isinstance(message, AckMsg):
                client.acknowledge(message.received)
            elif isinstance(message, PingMsg):
                # in order: the pong says that what was queued before the ping has gone out
                pong = PongMsg(id=message.id, time_ns=time.time_ns())
                client.control(pong, in_order=True)
            elif isinstance(message, _REPLAY_MSGS):
                await self.replays.handle(client, message)
            else:
                raise ProtocolError("already authenticated")
        except ProtocolError as exc:
            ref_type = ref_type or exc.ref_type
            # a replay's refusal keeps its place among the replay's replies and data
            in_order = ref_type is not None and ref_type.startswith("replay_")
            client.control(ErrorMsg(reason=str(exc)[:500], ref_type=ref_type), in_order=in_order)

    async def _stream_of(self, topic: str, pass_id: str | None) -> Stream:
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
                key = await self._in_db_thread(self._pass_exists, pass_id)
            except NotFound as exc:
                raise ProtocolError(str(exc)) from None
        return self._stream("telemetry", key)

    def _pass_exists(self, pass_id: str) -> str:
        with self._sessions() as session:
            return repo.get_pass(session=session, pass_id=pass_id).id

    async def _subscribe(self, client: ConsoleClient, message: SubscribeMsg) -> None:
        if message.since_seq is not None and message.epoch is None:
            raise ProtocolError("since_seq needs the epoch it was counted in")
        flt = TelemetryFilter.of(message, self.limits.max_rate_hz)
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
        sub = Subscription(client, stream, flt)
        client.subscriptions[key] = sub
        stream.subscriptions.append(sub)
        last = stream.last_seq
        topic, pass_id = stream.topic, stream.pass_id
        client.control(SubscribedMsg(topic=topic, pass_id=pass_id, epoch=self.epoch, seq=last))
        if message.since_seq is None:
            # Live from now; the link topic is a state, so its latest message comes too.
            since: int | None = max(0, last - 1) if stream.topic == "link" else last
            reason = ""
        elif not same_epoch:
            since, reason = None, f"epoch {message.epoch!r} is not this server's ({self.epoch})"
        else:
            since, reason = message.since_seq, ""
        replay: list[Message] | None = None
        if since is not None:
            replay, reason = await self._replay(client, stream, since)
        if sub.closed:
            return
        if replay is None:
            client.control(
                ResyncMsg(topic=topic, pass_id=pass_id, epoch=self.epoch, seq=last, reason=reason)
            )
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
        self, client: ConsoleClient, stream: Stream, since: int
    ) -> tuple[list[Message] | None, str]:
        """The messages ``(since, last]``, or None and why not."""
        wanted = stream.last_seq - since
        if wanted > self.limits.max_replay or client.queued + wanted > self.limits.hard_cap:
            return None, f"{wanted} messages to replay: more than {self.limits.max_replay}"
        ring = stream.from_ring(since)
        if ring is not None:
            return ring, ""
        entries = stream.indexed(since)
        if entries is None or stream.topic in _STATE_TOPICS:
            return None, f"seq {since + 1} is no longer held"
        try:
            if stream.topic == "telemetry":
                assert stream.pass_id is not None
                found = await self._in_db_thread(
                    replay_frames, self._sessions, stream.pass_id, entries
                )
            else:
                kinds = EVENT_TOPICS[stream.topic]
                found = await self._in_db_thread(replay_events, self._sessions, kinds, entries)
        except Exception as exc:
            log.exception("console replay of %s failed", stream.topic)
            return None, f"the database replay failed: {exc!r}"[:300]
        if found is None:
            return None, f"seqs {since + 1}..{entries[-1][0]} are not all in the database"
        return [self._replayed(stream, seq, key, payload) for seq, key, payload in found], ""

    @staticmethod
    def _replayed(stream: Stream, seq: int, key: Any, payload: Payload) -> Message:
        message = Message(seq, key, payload)
        message.text = render(stream, message, None)
        return message

    def _unsubscribe(self, client: ConsoleClient, message: UnsubscribeMsg) -> None:
        key = (message.topic, _canonical_pass(message.pass_id))
        sub = client.subscriptions.pop(key, None)
        if sub is None:
            raise ProtocolError(f"not subscribed to {message.topic!r} (pass {message.pass_id})")
        self._detach(sub)
        self._unsubscribed(sub, "requested")

    def _detach(self, sub: Subscription) -> None:
        sub.closed = True
        with contextlib.suppress(ValueError):
            sub.stream.subscriptions.remove(sub)

    def drop(self, sub: Subscription, reason: str) -> None:
        """End a subscription whose client is too far behind (it may subscribe again)."""
        client = sub.client
        key = (sub.stream.topic, sub.stream.pass_id)
        if client.subscriptions.get(key) is sub:
            del client.subscriptions[key]
        self._detach(sub)
        self._unsubscribed(sub, reason)

    @staticmethod
    def _unsubscribed(sub: Subscription, reason: str) -> None:
        stream = sub.stream
        sub.client.control(
            UnsubscribedMsg(
                topic=stream.topic, pass_id=stream.pass_id, seq=sub.last_seq, reason=reason
            )
        )
