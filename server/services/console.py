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
- **Sources** (``_console_book``): the link's :class:`~server.services.link.Publisher`
  (committed events, archived frames, alarms as written; on the event loop, so nothing
  there blocks) and a poll of :meth:`GroundLink.status` for ``link``. **Across grounds**
  (``nats_url``, ``_console_jetstream``) they go to JetStream and every stream comes back
  from it, numbered by the JetStream stream's sequence (its creation names the ``epoch``),
  the same on every ground; a resume the ring does not cover reads JetStream.
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
``console_messages``; streams, subscriptions and clients are ``_console_streams``; topics
and limits ``_console_limits``; the lag watch ``_console_lag``; the database replay is
``_console_replay``. The replay of a recorded pass (``replay_*``
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
from collections.abc import Awaitable, Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING, Any, TypeVar, cast

from sqlalchemy.orm import Session, sessionmaker

from server.services._console_book import StreamBook
from server.services._console_lag import check_lag
from server.services._console_limits import (
    EVENT_TOPICS,
    STATE_TOPICS,
    TOPICS,
    ConsoleLimits,
    canonical_pass,
)
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
from server.services._console_replay import (
    replay_events,
    replay_frames,
)
from server.services._console_replay_sessions import Replays
from server.services._console_streams import (
    ConsoleClient,
    Message,
    Payload,
    Stream,
    Subscription,
    TelemetryFilter,
    render,
)
from server.services.clock import Clock, SystemClock
from server.services.console_messages import (
    ConsoleRole,
    ErrorMsg,
    PongMsg,
    ResyncMsg,
    SubscribedMsg,
    UnsubscribedMsg,
    WelcomeLimits,
    WelcomeMsg,
)
from server.services.dbworker import Publisher
from server.services.event_log import Recorded
from server.services.link import LinkStatus
from server.storage import repository as repo
from server.storage.errors import NotFound

if TYPE_CHECKING:
    from server.services._console_jetstream import AcrossGrounds

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
        across: AcrossGrounds | None = None,
    ):
        """``sessions``: the hub's own reads (a subscription's pass, missed messages), in
        ``db_threads`` threads of its own; ``replay_sessions`` (default ``sessions``): the
        replays' loads of whole recordings; ``clock``: what the consoles' lag is measured
        on (default the system's); ``across`` (``nats_url``): the streams come from
        JetStream, numbered by it, instead of from ``publisher`` (docs/console.md "Across
        grounds")."""
        self.limits = limits or ConsoleLimits()
        self.clock: Clock = clock or SystemClock()
        self.across = across
        #: Names the numbering: this process's, or across grounds the JetStream stream's;
        #: seqs of another epoch mean nothing here.
        self.epoch = (
            across.epoch
            if across is not None
            else f"{time.time_ns() // 10**9:x}-{secrets.token_hex(4)}"
        )
        self._publisher = publisher
        self._sessions = sessions
        self.book = StreamBook(self.limits, link_status, across)
        self._streams = self.book.streams
        self._clients: set[ConsoleClient] = set()
        self._tasks: set[asyncio.Task[Any]] = set()
        self._unhook: list[Callable[[], None]] = []
        self._poller: asyncio.Task[None] | None = None
        self._lag_watch: asyncio.Task[None] | None = None
        self._db_threads = ThreadPoolExecutor(db_threads, thread_name_prefix="console-db")
        self.replays = Replays(sessions=replay_sessions or sessions, limits=self.limits)

    # -- lifecycle -----------------------------------------------------------------------

    def start(self) -> None:
        book = self.book
        if self.across is not None:  # the publisher's messages come back from JetStream
            self.across.attach(book)
        else:
            self._unhook = [
                self._publisher.subscribe(book.on_event),
                self._publisher.subscribe_frames(book.on_frames),
                self._publisher.subscribe_alarms(book.on_alarm),
            ]
        self._poller = asyncio.create_task(book.poll_link(), name="console-link-poll")
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

    def consoles(self) -> list[ConsoleClient]:
        return list(self._clients)

    @property
    def telemetry_streams(self) -> list[str]:
        """The passes whose telemetry stream is held (in memory)."""
        return [p for (topic, p) in self._streams if topic == "telemetry" and p is not None]

    # -- sources (the book's; event loop, never block) ------------------------------------

    def _stream(self, topic: str, pass_id: str | None = None) -> Stream:
        return self.book.stream(topic, pass_id)

    def _on_event(self, recorded: Recorded) -> None:
        self.book.on_event(recorded)

    def push_link_status(self, status: LinkStatus) -> None:
        self.book.push_link_status(status)

    # -- consoles behind ------------------------------------------------------------------

    async def _watch_lag(self) -> None:
        while True:
            try:
                self.check_lag()
            except Exception:
                log.exception("console lag check failed")
            await self.clock.sleep_until(self.clock.monotonic() + self.limits.lag_check_s)

    def check_lag(self) -> None:
        """Measure every console's lag and act on it (:func:`_console_lag.check_lag`)."""
        check_lag(self)

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
        key = canonical_pass(pass_id)
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
            # across grounds, another ground's hub may be ahead of this one's: JetStream says
            last = stream.last_seq if self.across is None else await self.across.last_seq()
            if message.since_seq > last:
                raise ProtocolError(
                    f"since_seq {message.since_seq} is ahead of the stream (last seq {last})"
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
        limit = min(self.limits.max_replay, self.limits.hard_cap - client.queued)
        if self.across is not None:
            ring = stream.from_ring(since)
            if ring is not None and len(ring) <= limit:
                return ring, ""
            if ring is not None:
                return None, f"{len(ring)} messages to replay: more than {limit}"
            return await self.across.replay(stream, since, limit)
        wanted = stream.last_seq - since
        if wanted > limit:
            return None, f"{wanted} messages to replay: more than {self.limits.max_replay}"
        ring = stream.from_ring(since)
        if ring is not None:
            return ring, ""
        entries = stream.indexed(since)
        if entries is None or stream.topic in STATE_TOPICS:
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
        return [self.replayed(stream, seq, key, payload) for seq, key, payload in found], ""

    @staticmethod
    def replayed(stream: Stream, seq: int, key: Any, payload: Payload) -> Message:
        message = Message(seq, key, payload)
        message.text = render(stream, message, None)
        return message

    def _unsubscribe(self, client: ConsoleClient, message: UnsubscribeMsg) -> None:
        key = (message.topic, canonical_pass(message.pass_id))
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
