"""The grounds' shared live bus: one NATS JetStream stream (docs/console.md "Across grounds").

With ``nats_url`` set, every ground publishes what it commits (events, archived telemetry,
alarms; the holder its link status) here, and every ground's consoles are fed from here, so
a console sees the same live view on any ground and resumes on another. This module knows
subjects, the stream and bytes; what the bytes are is the consoles' side
(:mod:`server.services._console_jetstream`).

- **Subjects**: ``hikoboshi.<lease>.<pass>.<kind>``: ``<lease>`` the command lease's name
  (one vehicle; :func:`token` escapes what a subject cannot hold), ``<pass>`` the pass's id
  or ``_`` (none), ``<kind>`` one of :data:`KINDS` (``event.commands``, ``event.passes``,
  ``event.other``, ``telemetry``, ``alarm``, ``link``): a console's topic is one filter
  (``hikoboshi.vehicle.*.event.>`` is every event).
- **One stream** (``nats_stream``, file storage) over ``hikoboshi.>``, with limits: messages
  older than ``nats_max_age_s`` or beyond ``nats_max_bytes`` go, oldest first; a two-minute
  duplicate window drops a publish sent twice (each carries a ``Nats-Msg-Id``). The first
  ground creates it; the others use it as it is. Its creation time names the numbering
  (:attr:`LiveBus.epoch`): the stream's sequence is the consoles' ``seq`` on every ground.
- **Publishing** never waits on the event loop's caller: :meth:`LiveBus.publish` queues
  (bounded: past :data:`QUEUE_MAX` messages waiting, a message is dropped and counted,
  ``dropped``), one task sends in order and checks the acknowledgements of a window of
  messages in flight (``failed``: not acknowledged within :data:`ACK_TIMEOUT_S`).
- **Following**: one ordered consumer from the stream's end at the start (the client
  recreates it from the last sequence seen after a gap or a reconnection); **reading
  back**: an ordered consumer from a sequence, filtered, bounded.
"""

from __future__ import annotations

import asyncio
import collections
import logging
import re
import secrets
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

__all__ = [
    "ACK_TIMEOUT_S",
    "KINDS",
    "QUEUE_MAX",
    "BusConfig",
    "LiveBus",
    "token",
]

log = logging.getLogger("hikoboshi.ground.jetstream")

#: What a subject's last tokens say a message is.
KINDS = ("event.commands", "event.passes", "event.other", "telemetry", "alarm", "link")
#: Messages waiting to be published beyond which one is dropped (and counted).
QUEUE_MAX = 50_000
#: Messages sent and not yet acknowledged by JetStream at most (the publisher's window).
WINDOW = 512
#: A message not acknowledged this long (s) after it was sent is counted ``failed``.
ACK_TIMEOUT_S = 5.0
#: s: a publish repeated within this window (the same ``Nats-Msg-Id``) is stored once.
DUPLICATE_WINDOW_S = 120.0
#: s: a read back that receives nothing this long is cut short (a guard).
READ_TIMEOUT_S = 5.0

_UNSAFE = re.compile(r"[^A-Za-z0-9_-]")


def token(name: str) -> str:
    """``name`` as one subject token: letters, digits, ``_`` and ``-`` kept, anything
    else (``.``, ``*``, ``>``, spaces) written ``%XX``."""
    return _UNSAFE.sub(lambda m: "".join(f"%{b:02X}" for b in m.group().encode()), name) or "%"


@dataclass(frozen=True)
class BusConfig:
    url: str
    stream: str
    max_age_s: float
    max_bytes: int
    lease: str  # the command lease's name: one vehicle's subjects


class LiveBus:
    """The connection to NATS, the stream, the publishing task and the readers."""

    def __init__(self, config: BusConfig, *, name: str = "hikoboshi") -> None:
        self.config = config
        self.prefix = f"hikoboshi.{token(config.lease)}"
        self._name = name
        self._nc: Any = None
        self._js: Any = None
        self._queue: asyncio.Queue[tuple[str, bytes]] = asyncio.Queue()
        self._task: asyncio.Task[None] | None = None
        self._follower: Any = None
        self._ids = f"{name}-{secrets.token_hex(6)}"  # Nats-Msg-Id prefix: this process
        self._counter = 0
        #: names the stream's numbering (set by :meth:`open`)
        self.epoch = ""
        self.published = 0
        self.dropped = 0
        self.failed = 0

    def subject(self, kind: str, pass_id: str | None) -> str:
        return f"{self.prefix}.{'_' if pass_id is None else token(pass_id)}.{kind}"

    def filter(self, kind: str, pass_id: str | None = None) -> str:
        """The subjects of ``kind`` (``event.>``: every event), of one pass or of all."""
        return f"{self.prefix}.{'*' if pass_id is None else token(pass_id)}.{kind}"

    def kind_of(self, subject: str) -> tuple[str, str]:
        """``(pass token, kind)`` of one of this bus's subjects."""
        rest = subject[len(self.prefix) + 1 :]
        pass_token, _, kind = rest.partition(".")
        return pass_token, kind

    # -- lifecycle -------------------------------------------------------------------------

    async def open(self) -> None:
        """Connect (the client reconnects by itself afterwards), make sure the stream exists
        with its limits, and start publishing."""
        import nats  # the nats extra: imported only when configured
        from nats.js.api import DiscardPolicy, StorageType, StreamConfig
        from nats.js.errors import NotFoundError

        self._nc = await nats.connect(
            self.config.url,
            name=self._name,
            connect_timeout=5,
            max_reconnect_attempts=-1,
            reconnect_time_wait=0.5,
            error_cb=self._error,
        )
        self._js = self._nc.jetstream(timeout=ACK_TIMEOUT_S)
        try:
            info = await self._js.stream_info(self.config.stream)
        except NotFoundError:
            info = await self._js.add_stream(
                StreamConfig(
                    name=self.config.stream,
                    subjects=["hikoboshi.>"],
                    storage=StorageType.FILE,
                    max_age=self.config.max_age_s,
                    max_bytes=self.config.max_bytes,
                    discard=DiscardPolicy.OLD,
                    duplicate_window=DUPLICATE_WINDOW_S,
                )
            )
            info = await self._js.stream_info(self.config.stream)
        created = info.created
        stamp = int(created.timestamp() * 1e6) if created is not None else 0
        self.epoch = f"js-{token(self.config.stream)[:40]}-{stamp:x}"
        self._task = asyncio.create_task(self._publishing(), name="jetstream-publish")

    async def _error(self, exc: Exception) -> None:
        log.warning("NATS: %r", exc)

    async def close(self) -> None:
        """Publish what is queued (a few seconds at most), then disconnect."""
        if self._task is not None:
            if not await self.flush(5.0):  # a guard
                log.warning("NATS: %d messages not published at close", self._queue.qsize())
            self._task.cancel()
        if self._follower is not None:
            try:
                await self._follower.unsubscribe()
            except Exception as exc:
                log.info("NATS: unsubscribe at close: %r", exc)
        if self._nc is not None:
            try:
                await self._nc.drain()
            except Exception as exc:
                log.info("NATS: drain at close: %r", exc)

    # -- publishing ------------------------------------------------------------------------

    def publish(self, subject: str, data: bytes) -> None:
        """Queue ``data`` for ``subject`` (never blocks; past :data:`QUEUE_MAX`, dropped)."""
        if self._queue.qsize() >= QUEUE_MAX:
            self.dropped += 1
            if self.dropped in (1, 10, 100) or self.dropped % 1000 == 0:
                log.error("NATS: %d live messages dropped (the queue is full)", self.dropped)
            return
        self._queue.put_nowait((subject, data))

    async def _publishing(self) -> None:
        in_flight: collections.deque[asyncio.Future[Any]] = collections.deque()
        while True:
            if in_flight and (self._queue.empty() or len(in_flight) >= WINDOW):
                await self._settle(in_flight.popleft())
                continue
            subject, data = await self._queue.get()
            self._counter += 1
            headers = {"Nats-Msg-Id": f"{self._ids}-{self._counter}"}
            try:
                in_flight.append(
                    await self._js.publish_async(subject, data, headers=headers, wait_stall=5)
                )
            except Exception as exc:
                self.failed += 1
                log.warning("NATS: publish to %s failed: %r", subject, exc)
                self._queue.task_done()

    async def _settle(self, ack: asyncio.Future[Any]) -> None:
        try:
            await asyncio.wait_for(ack, ACK_TIMEOUT_S)
            self.published += 1
        except Exception as exc:
            self.failed += 1
            log.warning("NATS: a live message was not acknowledged: %r", exc)
        finally:
            self._queue.task_done()

    async def flush(self, timeout_s: float) -> bool:
        """Wait until what is queued is published (at most ``timeout_s``); whether it was."""
        try:
            await asyncio.wait_for(self._queue.join(), timeout_s)
        except TimeoutError:
            return False
        return True

    # -- reading ---------------------------------------------------------------------------

    async def last_on(self, subject: str) -> bytes | None:
        """The data of the stream's last message on ``subject`` (one subject), or None."""
        from nats.js.errors import NotFoundError

        try:
            msg = await self._js.get_last_msg(self.config.stream, subject)
        except NotFoundError:
            return None
        return bytes(msg.data or b"")

    async def bounds(self) -> tuple[int, int]:
        """The stream's first and last sequence now."""
        state = (await self._js.stream_info(self.config.stream)).state
        return state.first_seq, state.last_seq

    async def follow(self, deliver: Callable[[int, str, bytes], None]) -> int:
        """Hand ``deliver(seq, subject, data)`` every message of this bus published from now
        on, in order; the last sequence before them."""
        from nats.js.api import ConsumerConfig, DeliverPolicy

        _, last = await self.bounds()

        async def received(msg: Any) -> None:
            deliver(msg.metadata.sequence.stream, msg.subject, msg.data)

        self._follower = await self._js.subscribe(
            f"{self.prefix}.>",
            stream=self.config.stream,
            cb=received,
            ordered_consumer=True,
            config=ConsumerConfig(
                deliver_policy=DeliverPolicy.BY_START_SEQUENCE, opt_start_seq=last + 1
            ),
        )
        return last

    async def read(
        self, subject: str, after: int, upto: int, limit: int
    ) -> list[tuple[int, str, bytes]] | None:
        """The messages on ``subject`` (a filter) with ``after < seq <= upto``, in order;
        None when there are more than ``limit``."""
        from nats.js.api import ConsumerConfig, DeliverPolicy

        if upto <= after:
            return []
        sub = await self._js.subscribe(
            subject,
            stream=self.config.stream,
            ordered_consumer=True,
            config=ConsumerConfig(
                deliver_policy=DeliverPolicy.BY_START_SEQUENCE, opt_start_seq=after + 1
            ),
        )
        found: list[tuple[int, str, bytes]] = []
        try:
            info = await sub.consumer_info()
            # nothing pending and nothing delivered yet: none in range (a push consumer may
            # have delivered them all before its info was read, pending 0 then too)
            if info.num_pending == 0 and not (info.delivered and info.delivered.consumer_seq):
                return []
            while True:
                msg = await sub.next_msg(timeout=READ_TIMEOUT_S)
                seq = msg.metadata.sequence.stream
                if seq > upto:
                    return found
                found.append((seq, msg.subject, msg.data))
                if len(found) > limit:
                    return None
                if seq == upto or msg.metadata.num_pending == 0:
                    return found
        finally:
            await sub.unsubscribe()
