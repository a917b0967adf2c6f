"""The ground end of the space-ground link (docs/protocol.md, v1): one spacecraft at a time.

The API layer owns the websocket and hands this service each text frame
(:meth:`GroundLink.handle`) and a way to send (:class:`Connection`). The service:

- **Clock**: ``hello`` gives the onboard time at a ``time.monotonic`` instant and the time
  scale, so :meth:`GroundLink.onboard_now_ns` is the onboard clock now and
  :meth:`GroundLink.mono_at_onboard` the monotonic instant of an onboard time. ``hello`` is
  not delayed by the relay, so it is the exact mapping; ``pong`` only measures the round
  trip (``round_trip_s``, onboard seconds, the relay's emulated delay both ways).
- **Downlink**: every ``telemetry`` frame is stored (storage dedupes by ``(pass, seq)``)
  against the pass whose *telemetry window* contains its ``generation_time_ns``; windows
  are opened and closed by the runner (:mod:`server.services.runner`). A frame generated
  outside every window is **not archived**: it is counted (``frames_outside_pass``) and
  still acknowledged, so the spacecraft does not resend it for ever. Windows live in
  memory: after a ground restart, late frames of an earlier pass are counted, not stored.
- **Acknowledgement**: after each telemetry message, ``telemetry_ack`` with the frames held
  (cumulative from seq 0, the rest as ranges), and ``retransmit`` for the gaps between the
  frames held. A seq is asked for again at most once per resend window (10 s onboard, the
  spacecraft's own resend timeout); frames below the lowest one seen are left to that
  timeout (after a ground restart the ground cannot know which of them were acknowledged).
- **Commands**: ``command_ack`` moves the command's stage (``received``, ``executed``,
  ``rejected`` with its reason) with the onboard time; a stage never moves backwards
  (:data:`STAGE_RANK`), since acknowledgements may cross.
- **Events**: every command stage change and every link event (connect, hello, disconnect,
  error replies, retransmit requests) is written to the events table in the transaction
  that makes it, and then handed to the :class:`Publisher`'s subscribers (a console push).

Every database write goes through :class:`Database`: one worker thread, so writes keep
their order and an SQLite commit never stalls the event loop (and with it the 4 Hz uplink).
"""

from __future__ import annotations

import asyncio
import bisect
import contextlib
import itertools
import json
import logging
import math
import queue
import sys
import threading
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any, TypeVar

from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from server.storage import repository as repo
from server.storage.models import CommandRecord
from telemetry.wire import (
    CommandAck,
    CommandQuery,
    CommandUnknown,
    ErrorMsg,
    Hello,
    Ping,
    Pong,
    Retransmit,
    TelemetryAck,
    TelemetryFrame,
    TelemetryMsg,
    WireError,
    decode_spacecraft,
    encode,
)

__all__ = [
    "STAGE_RANK",
    "Connection",
    "Database",
    "GroundLink",
    "LinkStatus",
    "LinkUnavailable",
    "Publisher",
    "SeqRanges",
    "set_command_stage",
]

log = logging.getLogger("hikoboshi.ground.link")

T = TypeVar("T")

#: The spacecraft resends unacknowledged frames after this long (onboard s, protocol doc).
RESEND_WINDOW_S = 10.0
#: A gap is asked for once it has stayed open this long (onboard s): the relay's jitter
#: delivers frames out of order.
GAP_GRACE_S = 1.0
#: Wall seconds added to the onboard windows for each end's own processing time.
WALL_ALLOWANCE_S = 1.0
#: A ping this often (onboard s) while connected.
PING_PERIOD_S = 10.0
#: A stage only ever moves to a higher rank; the last three end a command.
STAGE_RANK = {
    "queued": 0,
    "released": 1,
    "sent": 2,
    "received": 3,
    "executed": 4,
    "rejected": 4,
    "expired": 4,
}
MAX_ACK_RANGES = 1000


class LinkUnavailable(Exception):
    """No spacecraft is connected, or its clock is not known yet."""


# --- plumbing ------------------------------------------------------------------------------


FrameCallback = Callable[[str, list[TelemetryFrame], int], None]


class Publisher:
    """An in-process publish hook for the consoles: subscribers get every event dict once it
    is committed, and every newly archived telemetry frame (``pass_id, frames,
    reception_time_ns``). A subscriber must not block; one that raises is logged and kept."""

    def __init__(self) -> None:
        self._subscribers: list[Callable[[dict[str, Any]], None]] = []
        self._frame_subscribers: list[FrameCallback] = []

    def subscribe(self, callback: Callable[[dict[str, Any]], None]) -> Callable[[], None]:
        self._subscribers.append(callback)
        return lambda: self._subscribers.remove(callback)

    def subscribe_frames(self, callback: FrameCallback) -> Callable[[], None]:
        self._frame_subscribers.append(callback)
        return lambda: self._frame_subscribers.remove(callback)

    def publish_frames(
        self, pass_id: str, frames: list[TelemetryFrame], reception_time_ns: int
    ) -> None:
        for callback in list(self._frame_subscribers):
            try:
                callback(pass_id, frames, reception_time_ns)
            except Exception:
                log.exception("frame subscriber failed on pass %s", pass_id)

    def publish(self, events: list[dict[str, Any]]) -> None:
        for event in events:
            for callback in list(self._subscribers):
                try:
                    callback(event)
                except Exception:
                    log.exception("event subscriber failed on %s", event.get("kind"))


class Database:
    """Transactions on one worker thread, in the order they were asked for (see the module
    docstring), with group commit: the jobs waiting when the worker comes round run in one
    transaction, so a burst of acknowledgements costs one commit, not hundreds. A job that
    fails rolls its whole group back; the group is then run again one job per transaction,
    so only the failing job fails.

    A job returns the event dicts it wrote; they are published once it has committed.
    """

    MAX_GROUP = 256

    def __init__(self, sessions: sessionmaker[Session], publisher: Publisher) -> None:
        self._sessions = sessions
        self._publisher = publisher
        self._queue: queue.SimpleQueue[_Job | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._worker, name="ground-db", daemon=True)
        self._thread.start()
        self._pending: set[asyncio.Future[Any]] = set()
        self.groups = 0
        self.jobs = 0

    def _transaction(self, job: Callable[[Session], T]) -> T:
        with self._sessions() as session:
            try:
                result = job(session)
                session.commit()
            except BaseException:
                session.rollback()
                raise
            return result

    def _worker(self) -> None:
        while True:
            first = self._queue.get()
            if first is None:
                return
            group = [first]
            stop = False
            while len(group) < self.MAX_GROUP:
                try:
                    item = self._queue.get_nowait()
                except queue.Empty:
                    break
                if item is None:
                    stop = True
                    break
                group.append(item)
            self._run_group(group)
            if stop:
                return

    def _run_group(self, group: list[_Job]) -> None:
        self.groups += 1
        self.jobs += len(group)
        outcomes: list[tuple[bool, Any]]
        try:
            with self._sessions() as session:
                try:
                    results = [job.fn(session) for job in group]
                    session.commit()
                except BaseException:
                    session.rollback()
                    raise
            outcomes = [(True, r) for r in results]
        except Exception:
            if len(group) == 1:
                outcomes = [(False, sys.exc_info()[1])]
            else:
                outcomes = []
                for job in group:  # isolate the failure: one transaction each
                    try:
                        outcomes.append((True, self._transaction(job.fn)))
                    except Exception as exc:
                        outcomes.append((False, exc))
        for job, (ok, value) in zip(group, outcomes, strict=True):
            job.loop.call_soon_threadsafe(_settle, job.future, ok, value)

    def _enqueue(self, job: Callable[[Session], T]) -> asyncio.Future[T]:
        loop = asyncio.get_running_loop()
        future: asyncio.Future[T] = loop.create_future()
        self._queue.put(_Job(job, future, loop))
        return future

    async def run(self, job: Callable[[Session], T]) -> T:
        return await self._enqueue(job)

    async def write(self, job: Callable[[Session], list[dict[str, Any]]]) -> None:
        """Run ``job`` (which returns the events it wrote) and publish its events."""
        self._publisher.publish(await self.run(job))

    def submit(self, job: Callable[[Session], list[dict[str, Any]]]) -> None:
        """Queue ``job`` without waiting (the emitter must not wait for a commit); its
        events are published when it commits, a failure is logged."""
        future = self._enqueue(job)
        self._pending.add(future)

        def done(f: asyncio.Future[list[dict[str, Any]]]) -> None:
            self._pending.discard(f)
            if f.cancelled():
                return
            if (exc := f.exception()) is not None:
                log.error("database write failed: %r", exc)
                return
            self._publisher.publish(f.result())

        future.add_done_callback(done)

    async def drain(self) -> None:
        """Wait for every submitted job."""
        while self._pending:
            await asyncio.gather(*list(self._pending), return_exceptions=True)

    def close(self) -> None:
        self._queue.put(None)
        self._thread.join()


@dataclass
class _Job:
    fn: Callable[[Session], Any]
    future: asyncio.Future[Any]
    loop: asyncio.AbstractEventLoop


def _settle(future: asyncio.Future[Any], ok: bool, value: Any) -> None:
    if future.cancelled():
        return
    if ok:
        future.set_result(value)
    else:
        future.set_exception(value)


def event_dict(
    kind: str, actor: str, detail: dict[str, Any], pass_id: str | None, time_ns: int
) -> dict[str, Any]:
    return {"kind": kind, "actor": actor, "detail": detail, "pass_id": pass_id, "time_ns": time_ns}


def write_event(
    session: Session, kind: str, actor: str, detail: dict[str, Any], pass_id: str | None = None
) -> dict[str, Any]:
    """Add an event row (ground time now) and return it as the dict to publish."""
    now = time.time_ns()
    record = repo.add_event(
        session=session, time_ns=now, kind=kind, actor=actor, detail=detail, pass_id=pass_id
    )
    return {**event_dict(kind, actor, detail, pass_id, now), "id": record.id}


def set_command_stage(
    session: Session,
    *,
    pass_id: str,
    seq: int,
    stage: str,
    time_ns: int,
    actor: str,
    reason: str | None = None,
    detail: str | None = None,
) -> list[dict[str, Any]]:
    """Move a command forward to ``stage`` at ``time_ns`` (on the clock the storage models
    name for it) and write the event; nothing if that would move it backwards."""
    record = repo.get_command(session=session, pass_id=pass_id, seq=seq)
    # The vehicle's own word beats the ground's inference: a command taken as lost
    # (``command_unknown`` -> expired) that then reaches the vehicle after all is what the
    # vehicle says it is.
    overrules = record.stage == "expired" and stage in ("executed", "rejected")
    if STAGE_RANK[stage] <= STAGE_RANK[record.stage] and not overrules:
        return []
    previous = record.stage
    repo.update_command_stage(
        session=session,
        pass_id=pass_id,
        seq=seq,
        stage=stage,
        time_ns=time_ns,
        reject_reason=reason,
    )
    info: dict[str, Any] = {"seq": seq, "from": previous, "stage": stage, "time_ns": time_ns}
    if reason is not None:
        info["reason"] = reason
    if detail is not None:
        info["detail"] = detail
    return [write_event(session, "command_stage", actor, info, pass_id)]


# --- frame bookkeeping ---------------------------------------------------------------------


class SeqRanges:
    """A set of non-negative ints kept as sorted, disjoint, non-adjacent inclusive ranges."""

    def __init__(self) -> None:
        self._ranges: list[list[int]] = []
        self.count = 0

    def __contains__(self, seq: int) -> bool:
        i = bisect.bisect_right(self._ranges, seq, key=lambda r: r[0]) - 1
        return i >= 0 and self._ranges[i][1] >= seq

    def add(self, seq: int) -> bool:
        """Add ``seq``; whether it was new."""
        rs = self._ranges
        i = bisect.bisect_right(rs, seq, key=lambda r: r[0])
        prev = i - 1
        if prev >= 0 and rs[prev][1] >= seq:
            return False
        join_prev = prev >= 0 and rs[prev][1] == seq - 1
        join_next = i < len(rs) and rs[i][0] == seq + 1
        if join_prev and join_next:
            rs[prev][1] = rs[i][1]
            del rs[i]
        elif join_prev:
            rs[prev][1] = seq
        elif join_next:
            rs[i][0] = seq
        else:
            rs.insert(i, [seq, seq])
        self.count += 1
        return True

    def ranges(self) -> list[tuple[int, int]]:
        return [(lo, hi) for lo, hi in self._ranges]

    def gaps(self) -> list[tuple[int, int]]:
        """The missing ranges between the lowest and the highest member."""
        rs = self._ranges
        return [(rs[k][1] + 1, rs[k + 1][0] - 1) for k in range(len(rs) - 1)]

    def highest(self) -> int:
        return self._ranges[-1][1] if self._ranges else -1


@dataclass
class TelemetryWindow:
    """Frames generated in ``[start_ns, end_ns)`` (onboard) belong to the pass."""

    pass_id: str
    start_ns: int
    end_ns: int | None = None

    def contains(self, generation_time_ns: int) -> bool:
        return self.start_ns <= generation_time_ns and (
            self.end_ns is None or generation_time_ns < self.end_ns
        )


@dataclass
class Connection:
    """One accepted websocket, as the API layer hands it over."""

    actor: str  # the token holder's name
    send_text: Callable[[str], Awaitable[None]]
    close: Callable[[int, str], Awaitable[None]]
    id: int = field(default_factory=itertools.count(1).__next__)
    greeted: bool = False  # its hello has arrived
    lock: asyncio.Lock = field(default_factory=asyncio.Lock)


@dataclass(frozen=True)
class LinkStatus:
    connected: bool
    actor: str | None
    vehicle: str | None
    time_scale: float | None
    onboard_time_ns: int | None
    round_trip_s: float | None  # onboard s, last pong
    frames_received: int  # distinct frames held since the ground started
    duplicates: int
    frames_outside_pass: int
    highest_seq: int
    frames_behind: int | None  # estimated generated onboard minus held
    open_gaps: list[tuple[int, int]]
    frames_missing: int
    retransmit_requests: int
    errors_replied: int
    errors_received: int


# --- the link ------------------------------------------------------------------------------


class GroundLink:
    def __init__(self, *, sessions: sessionmaker[Session], publisher: Publisher | None = None):
        self.publisher = publisher or Publisher()
        self.db = Database(sessions, self.publisher)
        self._conn: Connection | None = None
        self._pinger: asyncio.Task[None] | None = None
        # clock: (onboard ns, monotonic s, scale) from the last hello
        self._clock: tuple[int, float, float] | None = None
        self.vehicle: str | None = None
        self.last_command_seq = -1
        self.round_trip_s: float | None = None
        self._pings: dict[int, float] = {}
        self._ping_ids = itertools.count()
        # downlink
        self.held = SeqRanges()
        self._requested_at: dict[int, float] = {}
        self._gap_seen_at: dict[int, float] = {}
        self.windows: list[TelemetryWindow] = []
        self._newest: tuple[int, int] | None = None  # (seq, generation ns)
        #: The newest frame received (highest seq): what the vehicle last said it does.
        self.latest_frame: TelemetryFrame | None = None
        self._oldest: tuple[int, int] | None = None
        self.duplicates = 0
        #: pass id -> copies of its frames dropped since the service started
        self.duplicates_by_pass: dict[str, int] = {}
        self.frames_outside_pass = 0
        self.retransmit_requests = 0
        self.errors_replied = 0
        self.errors_received = 0
        #: seq -> pass, for acknowledgements (registered by the runner)
        self.command_pass: dict[int, str] = {}

    # -- clock ---------------------------------------------------------------------------

    @property
    def connected(self) -> bool:
        return self._conn is not None and self._conn.greeted and self._clock is not None

    @property
    def time_scale(self) -> float:
        if self._clock is None:
            raise LinkUnavailable("no hello from the spacecraft yet")
        return self._clock[2]

    def onboard_now_ns(self) -> int:
        if self._clock is None:
            raise LinkUnavailable("no hello from the spacecraft yet")
        onboard_ns, mono, scale = self._clock
        return onboard_ns + round((time.monotonic() - mono) * scale * 1e9)

    def mono_at_onboard(self, onboard_ns: int) -> float:
        """The ``time.monotonic`` instant at which the onboard clock reads ``onboard_ns``."""
        if self._clock is None:
            raise LinkUnavailable("no hello from the spacecraft yet")
        ref_ns, mono, scale = self._clock
        return mono + (onboard_ns - ref_ns) / 1e9 / scale

    # -- connections ---------------------------------------------------------------------

    async def attach(self, conn: Connection) -> None:
        """A new spacecraft connection; it supersedes an older one (a half-open socket must
        not keep a reconnecting spacecraft out)."""
        old, self._conn = self._conn, conn
        if old is not None:
            with contextlib.suppress(Exception):
                await old.close(1000, "superseded by a new spacecraft connection")
        # Not awaited: the hello behind it must be read (and timed) at once.
        self.db.submit(
            lambda s: [write_event(s, "link_connected", conn.actor, {"connection": conn.id})]
        )

    async def detach(self, conn: Connection, reason: str) -> None:
        if self._conn is not conn:
            return
        self._conn = None
        if self._pinger is not None:
            self._pinger.cancel()
            self._pinger = None
        detail = {"connection": conn.id, "reason": reason}
        await self.db.write(lambda s: [write_event(s, "link_disconnected", conn.actor, detail)])

    async def send(self, text: str) -> bool:
        """Send one message to the spacecraft; False when there is no link or it failed."""
        conn = self._conn
        if conn is None:
            return False
        try:
            async with conn.lock:
                await conn.send_text(text)
        except Exception as exc:  # the socket went away under us
            log.warning("send to spacecraft failed: %r", exc)
            return False
        return True

    async def close(self) -> None:
        if self._pinger is not None:
            self._pinger.cancel()
        conn, self._conn = self._conn, None
        if conn is not None:
            with contextlib.suppress(Exception):
                await conn.close(1001, "ground service stopping")
        await self.db.drain()
        await asyncio.to_thread(self.db.close)

    # -- incoming ------------------------------------------------------------------------

    async def handle(
        self, conn: Connection, raw: str | bytes, received_mono: float | None = None
    ) -> None:
        """One frame from the spacecraft, read off the socket at ``received_mono``
        (``time.monotonic``; now if not given); a malformed one gets an ``error`` reply."""
        received = time.monotonic() if received_mono is None else received_mono
        try:
            message = decode_spacecraft(raw)
        except WireError as exc:
            self.errors_replied += 1
            await self.send(encode(ErrorMsg(reason=str(exc)[:500], ref_type=_ref_type(raw))))
            detail = {"reason": str(exc)[:500]}
            await self.db.write(
                lambda s: [write_event(s, "link_error_replied", conn.actor, detail)]
            )
            return
        if conn is not self._conn:
            return  # a superseded connection
        if isinstance(message, Hello):
            await self._on_hello(conn, message, received)
        elif not conn.greeted:
            await self.send(encode(ErrorMsg(reason="hello expected first", ref_type=message.type)))
        elif isinstance(message, TelemetryMsg):
            await self._on_telemetry(message)
        elif isinstance(message, CommandAck):
            await self._on_command_ack(message)
        elif isinstance(message, CommandUnknown):
            await self._on_command_unknown(message)
        elif isinstance(message, Pong):
            sent = self._pings.pop(message.ping_id, None)
            if sent is not None:
                self.round_trip_s = (time.monotonic() - sent) * self.time_scale
        elif isinstance(message, ErrorMsg):
            self.errors_received += 1
            info: dict[str, Any] = {"reason": message.reason, "ref_type": message.ref_type}
            await self.db.write(lambda s: [write_event(s, "link_error_received", conn.actor, info)])

    async def _on_hello(self, conn: Connection, hello: Hello, received_mono: float) -> None:
        # Timed when read off the socket: at 20x, 50 ms of queueing would put the ground's
        # idea of the onboard clock a whole second behind, eating into the uplink margin.
        self._clock = (hello.onboard_time_ns, received_mono, hello.time_scale)
        conn.greeted = True
        self.vehicle = hello.vehicle
        self.last_command_seq = hello.last_command_seq
        if hello.next_telemetry_seq <= self.held.highest():
            # The vehicle counts from 0 again: a new spacecraft process.
            self.held = SeqRanges()
            self._requested_at.clear()
            self._newest = self._oldest = None
        detail = hello.model_dump(mode="json", exclude={"v", "type"})
        await self.db.write(lambda s: [write_event(s, "link_hello", conn.actor, detail)])
        if self._pinger is None or self._pinger.done():
            self._pinger = asyncio.create_task(self._ping_loop(), name="ground-pinger")

    async def _ping_loop(self) -> None:
        while self.connected:
            ping_id = next(self._ping_ids)
            self._pings = {k: v for k, v in self._pings.items() if k > ping_id - 10}
            self._pings[ping_id] = time.monotonic()
            await self.send(encode(Ping(ping_id=ping_id, ground_time_ns=time.time_ns())))
            await asyncio.sleep(PING_PERIOD_S / self.time_scale)

    def _window_of(self, frame: TelemetryFrame) -> str | None:
        for window in reversed(self.windows):  # the later pass wins an overlap
            if window.contains(frame.generation_time_ns):
                return window.pass_id
        return None

    async def _on_telemetry(self, message: TelemetryMsg) -> None:
        reception_ns = time.time_ns()
        by_pass: dict[str, list[TelemetryFrame]] = {}
        fresh: list[TelemetryFrame] = []
        for frame in message.frames:
            pass_id = self._window_of(frame)
            if frame.seq in self.held:
                self.duplicates += 1
                if pass_id is not None:
                    self.duplicates_by_pass[pass_id] = self.duplicates_by_pass.get(pass_id, 0) + 1
                continue
            fresh.append(frame)
            if pass_id is not None:
                by_pass.setdefault(pass_id, []).append(frame)

        def job(session: Session) -> dict[str, int]:
            duplicates = {}
            for pass_id, frames in by_pass.items():
                result = repo.ingest_frames(
                    session=session,
                    pass_id=pass_id,
                    frames=frames,
                    reception_time_ns=reception_ns,
                )
                duplicates[pass_id] = result.duplicates
            return duplicates

        if by_pass:
            # Copies the archive already held (after a ground restart the in-memory set
            # starts empty): dropped by the storage's dedupe.
            for pass_id, n in (await self.db.run(job)).items():
                self.duplicates += n
                self.duplicates_by_pass[pass_id] = self.duplicates_by_pass.get(pass_id, 0) + n
            for pass_id, frames in by_pass.items():
                self.publisher.publish_frames(pass_id, frames, reception_ns)
        stored = {frame.seq for frames in by_pass.values() for frame in frames}
        for frame in fresh:
            if self.held.add(frame.seq):
                self._requested_at.pop(frame.seq, None)
                if frame.seq not in stored:
                    self.frames_outside_pass += 1
                if self._newest is None or frame.seq > self._newest[0]:
                    self._newest = (frame.seq, frame.generation_time_ns)
                    self.latest_frame = frame
                if self._oldest is None or frame.seq < self._oldest[0]:
                    self._oldest = (frame.seq, frame.generation_time_ns)
        await self._acknowledge()

    async def _acknowledge(self) -> None:
        ranges = self.held.ranges()
        through = -1
        if ranges and ranges[0][0] == 0:
            through = ranges.pop(0)[1]
        await self.send(encode(TelemetryAck(through_seq=through, ranges=ranges[:MAX_ACK_RANGES])))
        now = time.monotonic()
        # Onboard time scaled to wall, plus wall time for the two ends' own processing:
        # at high time scales the onboard windows shrink below what a loaded machine takes
        # to handle a message, and asking early only brings copies.
        window_s = RESEND_WINDOW_S / self.time_scale + WALL_ALLOWANCE_S
        grace_s = GAP_GRACE_S / self.time_scale + WALL_ALLOWANCE_S / 5
        due: list[tuple[int, int]] = []
        gaps = self.held.gaps()
        missing = {seq for lo, hi in gaps for seq in range(lo, hi + 1)}
        self._gap_seen_at = {
            seq: self._gap_seen_at.get(seq, now) for seq in missing
        }  # a gap is asked for once it has stayed open a while (jitter reorders frames)
        for lo, hi in gaps:
            for seq in range(lo, hi + 1):
                if now - self._gap_seen_at[seq] < grace_s:
                    continue
                if now - self._requested_at.get(seq, -math.inf) >= window_s:
                    self._requested_at[seq] = now
                    if due and due[-1][1] == seq - 1:
                        due[-1] = (due[-1][0], seq)
                    else:
                        due.append((seq, seq))
        if due:
            self.retransmit_requests += 1
            await self.send(encode(Retransmit(ranges=due[:MAX_ACK_RANGES])))
            detail = {"ranges": due[:20], "frames": sum(hi - lo + 1 for lo, hi in due)}
            actor = "ground"
            self.db.submit(lambda s: [write_event(s, "retransmit_requested", actor, detail)])

    async def _on_command_ack(self, ack: CommandAck) -> None:
        pass_id = self.command_pass.get(ack.seq)
        actor = self.vehicle or "spacecraft"

        def job(session: Session) -> list[dict[str, Any]]:
            key = pass_id
            if key is None:
                query = (
                    select(CommandRecord.pass_id)
                    .where(CommandRecord.seq == ack.seq)
                    .order_by(CommandRecord.queued_at_ns.desc())
                    .limit(1)
                )
                key = session.scalar(query)
            if key is None:
                info = {"seq": ack.seq, "stage": ack.stage.value}
                return [write_event(session, "command_ack_unknown", actor, info)]
            return set_command_stage(
                session,
                pass_id=key,
                seq=ack.seq,
                stage=ack.stage.value,
                time_ns=ack.onboard_time_ns,
                actor=actor,
                reason=None if ack.reason is None else ack.reason.value,
                detail=ack.detail,
            )

        # Not awaited: acknowledgements queue behind each other in order and share commits.
        self.db.submit(job)

    async def _on_command_unknown(self, message: CommandUnknown) -> None:
        """The vehicle never received these: lost on the uplink; they can no longer run."""
        actor = self.vehicle or "spacecraft"

        def job(session: Session) -> list[dict[str, Any]]:
            events: list[dict[str, Any]] = []
            for seq in message.seqs:
                key = self.command_pass.get(seq) or session.scalar(
                    select(CommandRecord.pass_id)
                    .where(CommandRecord.seq == seq)
                    .order_by(CommandRecord.queued_at_ns.desc())
                    .limit(1)
                )
                if key is None:
                    continue
                record = repo.get_command(session=session, pass_id=key, seq=seq)
                if record.stage != "sent" or record.execute_time_ns > message.onboard_time_ns:
                    continue  # received after all, or still in flight and not due yet
                events += set_command_stage(
                    session,
                    pass_id=key,
                    seq=seq,
                    stage="expired",
                    time_ns=time.time_ns(),
                    actor=actor,
                    detail="never reached the vehicle (lost on the uplink)",
                )
            return events

        await self.db.write(job)

    async def query_commands(self, seqs: list[int]) -> bool:
        """Ask the vehicle what became of these commands (lost acknowledgements)."""
        if not seqs:
            return True
        ok = True
        for lo in range(0, len(seqs), 1000):
            ok = await self.send(encode(CommandQuery(seqs=seqs[lo : lo + 1000]))) and ok
        return ok

    # -- status --------------------------------------------------------------------------

    def status(self) -> LinkStatus:
        gaps = self.held.gaps()
        onboard_now = self.onboard_now_ns() if self._clock is not None else None
        behind: int | None = None
        if self._newest is not None and self._oldest is not None and onboard_now is not None:
            span_seq = self._newest[0] - self._oldest[0]
            if span_seq > 0:
                period_ns = (self._newest[1] - self._oldest[1]) / span_seq
                since = max(0, onboard_now - self._newest[1])
                generated = self._newest[0] + 1 + int(since // period_ns)
                behind = generated - (self._oldest[0] + self.held.count)
        return LinkStatus(
            connected=self.connected,
            actor=None if self._conn is None else self._conn.actor,
            vehicle=self.vehicle,
            time_scale=None if self._clock is None else self._clock[2],
            onboard_time_ns=onboard_now,
            round_trip_s=self.round_trip_s,
            frames_received=self.held.count,
            duplicates=self.duplicates,
            frames_outside_pass=self.frames_outside_pass,
            highest_seq=self.held.highest(),
            frames_behind=behind,
            open_gaps=gaps[:100],
            frames_missing=sum(hi - lo + 1 for lo, hi in gaps),
            retransmit_requests=self.retransmit_requests,
            errors_replied=self.errors_replied,
            errors_received=self.errors_received,
        )


def _ref_type(raw: str | bytes) -> str | None:
    """The ``type`` of a message that failed to decode, if it can be read cheaply."""
    if len(raw) > 64 * 1024:
        return None
    with contextlib.suppress(ValueError, UnicodeDecodeError, RecursionError):
        doc = json.loads(raw)
        if isinstance(doc, dict) and isinstance(doc.get("type"), str):
            return str(doc["type"])[:64]
    return None
