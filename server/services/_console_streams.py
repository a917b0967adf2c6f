"""The console hub's streams, subscriptions and clients (:mod:`server.services.console`).

A :class:`Stream` is one topic's (or one pass's telemetry) numbered messages: a ring of the
last ones and an index of keys to find older ones in the database. A :class:`Subscription`
is one client's view of a stream (a telemetry filter, the replay backlog, the last seq
queued). A :class:`ConsoleClient` is one websocket: its subscriptions, its queue and its
send task. Every message is a :mod:`server.services.console_messages` model, encoded once.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections import deque
from collections.abc import Awaitable, Callable, Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple, cast

from server.services._console_protocol import ProtocolError, SubscribeMsg
from server.services._console_replay import Row, TelemetryRows
from server.services.console_messages import (
    AlarmMsg,
    ConsoleEvent,
    EventMsg,
    EventTopic,
    FrameColumns,
    LinkMsg,
    ServerMsg,
    TelemetryMsg,
)
from server.services.link import LinkStatus
from server.storage.models import TELEMETRY_FIELDS
from telemetry.alarm import AlarmPublic

if TYPE_CHECKING:
    from server.services._console_limits import ConsoleLimits
    from server.services.console import ConsoleHub

__all__ = [
    "CONTROL_TOPICS",
    "ConsoleClient",
    "Lag",
    "LinkReport",
    "Message",
    "Payload",
    "Stream",
    "Subscription",
    "TelemetryFilter",
    "render",
    "requested_columns",
]

log = logging.getLogger("hikoboshi.ground.console")


class LinkReport(NamedTuple):
    """A ``link`` message's payload: the status and when the ground took it."""

    ground_time_ns: int
    status: LinkStatus


#: What a stream's message carries: an event, a link report, telemetry rows or an alarm.
Payload = ConsoleEvent | LinkReport | TelemetryRows | AlarmPublic


def requested_columns(fields: list[str] | None) -> tuple[str, ...] | None:
    """The columns a console asked for (checked against every stored field), None for all."""
    if fields is None:
        return None
    for name in fields:
        if name not in TELEMETRY_FIELDS:
            raise ProtocolError(f"field {name!r} is not one of {TELEMETRY_FIELDS}")
    if len(set(fields)) != len(fields):
        raise ProtocolError(f"fields {fields} repeat a name")
    return tuple(dict.fromkeys(["seq", "generation_time_ns", "reception_time_ns", *fields]))


# --- streams -------------------------------------------------------------------------------


@dataclass(slots=True)
class Message:
    """One message of a stream, as held in its ring."""

    seq: int
    key: Any  # how to find it in the database (None: it is not stored)
    payload: Payload
    text: str | None = None  # encoded once, for every subscriber without a filter


class Stream:
    """One topic's (or one pass's telemetry) numbered messages: a ring and an index."""

    def __init__(self, topic: str, pass_id: str | None, limits: ConsoleLimits, floor: int = 0):
        """``floor``: the seq after which every message of the stream comes to it (0 in
        one process; across grounds, where the hub started following JetStream)."""
        self.topic = topic
        self.pass_id = pass_id
        self.limits = limits
        self.last_seq = floor
        #: the ring holds every message after this seq (the last one it let go)
        self.floor = floor
        self.ring: deque[Message] = deque()
        # keys[i] belongs to seq last_seq - len(keys) + 1 + i (numbered here only)
        self.keys: deque[Any] = deque()
        self.subscriptions: list[Subscription] = []

    def append(self, key: Any, payload: Payload, seq: int | None = None) -> Message:
        """The next message: numbered here, or by JetStream (``seq``, increasing, not
        contiguous: it numbers every subject of the stream; no index is kept then)."""
        if seq is None:
            self.last_seq += 1
            self.keys.append(key)
            while len(self.keys) > self.limits.index_size:
                self.keys.popleft()
        else:
            self.last_seq = seq
        message = Message(self.last_seq, key, payload)
        message.text = render(self, message, None)
        self.ring.append(message)
        while len(self.ring) > self.limits.ring_size:
            self.floor = self.ring.popleft().seq
        return message

    def from_ring(self, since_seq: int) -> list[Message] | None:
        """Messages after ``since_seq``, or None when the ring no longer holds them all."""
        if since_seq >= self.last_seq:
            return []
        if since_seq < self.floor:
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
class TelemetryFilter:
    """What a telemetry subscription asked for: columns and decimation."""

    #: The columns asked for (None: every column of the pass's layout); one a pass's robot
    #: does not have (``j7`` of a 6-joint pass) is left out of its messages.
    columns: tuple[str, ...] | None
    period_ns: int | None  # decimation: one frame per this much generation time
    next_generation_ns: int = -(2**63)

    @classmethod
    def of(cls, message: SubscribeMsg, max_rate_hz: float) -> TelemetryFilter | None:
        """The filter a ``subscribe`` asks for (None: none), or :class:`ProtocolError`."""
        if message.max_rate_hz is None and message.fields is None:
            return None
        if message.topic != "telemetry":
            raise ProtocolError("max_rate_hz and fields apply to telemetry only")
        period_ns = None
        if message.max_rate_hz is not None:
            if message.max_rate_hz > max_rate_hz:
                raise ProtocolError(f"max_rate_hz {message.max_rate_hz} exceeds {max_rate_hz}")
            period_ns = round(1e9 / message.max_rate_hz)
        return cls(columns=requested_columns(message.fields), period_ns=period_ns)

    def apply(self, rows: list[Row]) -> list[Row]:
        if self.period_ns is not None:
            kept = []
            for row in rows:
                if row[1] >= self.next_generation_ns:
                    kept.append(row)
                    self.next_generation_ns = row[1] + self.period_ns
            rows = kept
        return rows


def render(stream: Stream, message: Message, flt: TelemetryFilter | None) -> str | None:
    """The message as sent; None when a filter leaves nothing of it."""
    payload = message.payload
    doc: ServerMsg
    if isinstance(payload, TelemetryRows):
        batch = payload
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
        assert stream.pass_id is not None  # a telemetry stream is a pass's
        doc = TelemetryMsg(
            pass_id=stream.pass_id,
            seq=message.seq,
            count=len(rows),
            columns=FrameColumns(
                dict(zip(names, (list(c) for c in zip(*rows, strict=True)), strict=True))
            ),
        )
    elif isinstance(payload, LinkReport):
        doc = LinkMsg(seq=message.seq, ground_time_ns=payload.ground_time_ns, status=payload.status)
    elif isinstance(payload, AlarmPublic):
        doc = AlarmMsg(seq=message.seq, alarm=payload)
    else:
        doc = EventMsg(topic=cast(EventTopic, stream.topic), seq=message.seq, event=payload)
    return doc.encode()


class Subscription:
    """One client's subscription to one stream."""

    def __init__(self, client: ConsoleClient, stream: Stream, flt: TelemetryFilter | None):
        self.client = client
        self.stream = stream
        self.filter = flt
        self.replaying = True
        self.backlog: list[Message] = []
        self.backlog_bytes = 0
        self.last_seq = 0  # the last seq queued (or passed over by the filter)
        self.closed = False

    def offer(self, message: Message, *, live: bool) -> None:
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
        text = message.text if self.filter is None else render(self.stream, message, self.filter)
        if text is not None and not self.client.queue_data(self, text, live=live):
            self.client.hub.drop(self, "overflow: the console is not keeping up")
            return
        self.last_seq = message.seq


# --- clients -------------------------------------------------------------------------------

#: Streams whose messages jump the queue (states an operator must see at once); every other
#: stream's (telemetry, command stages, the audit log) is bulk. A stream is one class or
#: the other whole, so each subscription's messages stay in seq order.
CONTROL_TOPICS = frozenset({"passes", "alarms", "link"})

#: What a queued text is: a subscription's message (live, or a resume's replay: dropped
#: when the client falls behind, and announced), a recorded pass's replay data
#: (flow-controlled, never dropped), or anything else (never dropped).
_DATA, _REPLAY, _OTHER = 0, 1, 2


@dataclass(slots=True)
class _Item:
    text: str
    kind: int
    queued_mono: float  # the hub's clock, when queued
    sub: Subscription | None = None  # _DATA: whose message
    live: bool = False  # _DATA: counted in live_bytes


@dataclass(frozen=True, slots=True)
class Lag:
    """How far behind a client is: the age of its oldest unsent message, per class."""

    bulk_s: float  # data of bulk streams (0: none unsent)
    any_s: float  # anything, the message being sent included
    queued: int  # messages unsent


class ConsoleClient:
    """One console websocket: its subscriptions, its two queues and its send task.

    The control queue (control messages, and the data of :data:`CONTROL_TOPICS`) is sent
    before the bulk queue (the other streams' data, a recorded pass's replay, and the
    replies that keep their place among them: ``pong``, ``replay_*``). Each is in order.
    """

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
        self._monotonic = hub.clock.monotonic
        self._send_text = send_text
        self._close = close
        self.subscriptions: dict[tuple[str, str | None], Subscription] = {}
        self._control: deque[_Item] = deque()
        self._bulk: deque[_Item] = deque()
        self._wake = asyncio.Event()
        self._stopped = False
        #: when the text being sent was taken off a queue (None: not sending)
        self._sending_since: float | None = None
        self._undroppable = 0  # queued texts that are not a subscription's data
        #: Acknowledgements (``ack``), from the console's first: messages handed to the
        #: socket, and those it has said it read; (queued, sent) times of the rest.
        self.acks = False
        self._sent = 0
        self._acked = 0
        self._unacked: deque[tuple[float, int]] = deque()  # (queued, bytes) of each
        self.unacked_bytes = 0
        self._read: deque[tuple[float, int]] = deque()  # (when acknowledged, bytes)
        self._read_bytes = 0  # of those within the last ack_window_s
        self._last_read_bytes = 0  # what the latest ack said was read
        self.live_bytes = 0  # live data queued and not yet handed to the socket
        self.replay_bytes = 0  # replay data queued and not yet handed to the socket
        self._replay_sent = asyncio.Event()
        self.closing = False
        #: the last ``lag`` sent said the client was behind (a ``behind_s: 0`` follows)
        self.reported_behind = False
        self.last_lag_report: float = -float("inf")
        self.resyncs = 0  # times its bulk backlog was dropped for being behind
        self.sender = asyncio.create_task(self._send_loop(), name=f"console-send-{actor}")

    @property
    def queued(self) -> int:
        return len(self._control) + len(self._bulk)

    def _put(self, item: _Item, *, control: bool) -> None:
        (self._control if control else self._bulk).append(item)
        if item.kind != _DATA:
            self._undroppable += 1
        self._wake.set()

    def queue_data(self, sub: Subscription, text: str, *, live: bool) -> bool:
        """Queue a subscription's message; False (nothing queued) when the client is too far
        behind."""
        if live:
            if self.live_bytes + len(text) > self.limits.queue_bytes:
                return False
            self.live_bytes += len(text)
        item = _Item(text, _DATA, self._monotonic(), sub, live)
        self._put(item, control=sub.stream.topic in CONTROL_TOPICS)
        return True

    def queue_replay(self, text: str) -> None:
        """Queue replay data (never dropped: a replay waits, :meth:`replay_below`)."""
        self.replay_bytes += len(text)
        self._put(_Item(text, _REPLAY, self._monotonic()), control=False)

    async def replay_below(self, limit_bytes: int) -> None:
        """Return once at most ``limit_bytes`` of replay data are unsent."""
        while self.replay_bytes > limit_bytes:
            self._replay_sent.clear()
            await self._replay_sent.wait()

    def control(self, message: ServerMsg, *, in_order: bool = False) -> None:
        """Queue a control message (never dropped; a client that lets them pile up goes):
        ahead of bulk data, or ``in_order`` after what is queued (a ``pong``, which says
        that what was queued before the ``ping`` has been sent, and a replay's replies,
        which keep their place among its data)."""
        if self._undroppable >= self.limits.hard_cap:
            self.kill(1008, "the console does not read its messages")
            return
        self._put(_Item(message.encode(), _OTHER, self._monotonic()), control=not in_order)

    def acknowledge(self, received: int) -> None:
        """The console has read ``received`` messages of this socket."""
        if received > self._sent:
            raise ProtocolError(f"ack of {received} messages: {self._sent} sent")
        if received < self._acked:
            raise ProtocolError(f"ack of {received} messages after one of {self._acked}")
        read, self._acked = received - self._acked, received
        if not self.acks:
            self.acks = True  # counted from here on: what was sent before is not held
            self._unacked.clear()
            self.unacked_bytes = 0
        now = self._monotonic()
        self._last_read_bytes = 0
        for _ in range(min(read, len(self._unacked))):
            _, size = self._unacked.popleft()
            self.unacked_bytes -= size
            self._read.append((now, size))
            self._read_bytes += size
            self._last_read_bytes += size
        self._wake.set()

    def window_bytes(self) -> int:
        """What may be sent and not yet acknowledged: what the console read in the last
        ``ack_window_s`` (at least ``ack_window_min_bytes``), so that the socket holds about
        that long of its reading, whatever its pace; or what its latest ack said it read,
        if more (a console whose acks come further apart than that, a browser's background
        tab, is not starved for it)."""
        since = self._monotonic() - self.limits.ack_window_s
        while self._read and self._read[0][0] < since:
            self._read_bytes -= self._read.popleft()[1]
        return max(self.limits.ack_window_min_bytes, self._read_bytes, self._last_read_bytes)

    def _window_full(self) -> bool:
        return self.acks and self.unacked_bytes > 0 and self.unacked_bytes >= self.window_bytes()

    def lag(self, now: float) -> Lag:
        """How far behind the client is at ``now`` (the hub's monotonic clock)."""
        bulk = next((i for i in self._bulk if i.kind == _DATA), None)
        bulk_s = now - bulk.queued_mono if bulk is not None else 0.0
        oldest = [q[0].queued_mono for q in (self._control, self._bulk) if q]
        if self._sending_since is not None:
            oldest.append(self._sending_since)
        if self._unacked:  # sent, not yet read
            oldest.append(self._unacked[0][0])
        any_s = now - min(oldest) if oldest else 0.0
        return Lag(bulk_s=max(0.0, bulk_s), any_s=max(0.0, any_s), queued=self.queued)

    def drop_bulk(self) -> dict[Subscription, int]:
        """Take every subscription's message off the bulk queue (live or a resume's replay);
        how many of each subscription's were dropped. A recorded pass's replay and the
        other replies stay."""
        dropped: dict[Subscription, int] = {}
        kept: deque[_Item] = deque()
        for item in self._bulk:
            if item.kind == _DATA and item.sub is not None:
                dropped[item.sub] = dropped.get(item.sub, 0) + 1
                if item.live:
                    self.live_bytes -= len(item.text)
            else:
                kept.append(item)
        self._bulk = kept
        return dropped

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
        while not self._stopped:
            if self._control:
                item = self._control.popleft()
            elif self._bulk and not self._window_full():
                item = self._bulk.popleft()
            else:  # nothing to send, or bulk that waits for an ack (which wakes it)
                self._wake.clear()
                await self._wake.wait()
                continue
            text = item.text
            if item.kind != _DATA:
                self._undroppable -= 1
            if item.live:
                self.live_bytes -= len(text)
            elif item.kind == _REPLAY:
                self.replay_bytes -= len(text)
                self._replay_sent.set()
            self._sending_since = item.queued_mono
            # counted before the send: the console may read it (and say so) before it returns
            self._sent += 1
            if self.acks:
                self._unacked.append((item.queued_mono, len(text)))
                self.unacked_bytes += len(text)
            try:
                await self._send_text(text)
            except Exception as exc:  # the socket went away; the receive loop ends it
                log.info("console %s: send failed: %r", self.actor, exc)
                return
            finally:
                self._sending_since = None

    async def stop(self) -> None:
        self._stopped = True
        self._wake.set()
        if not self.sender.done():
            self.sender.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await self.sender
