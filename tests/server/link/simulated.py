"""The ground's link and runner in simulated time, against a scripted relay and vehicle.

:class:`SimulatedSpacecraft` is a test double of the flight segment at the protocol level
(docs/protocol.md): a relay that delays, loses and blacks out messages in both directions,
and a vehicle that keeps an onboard schedule (acknowledging ``received``, answering a copy
of a command it holds with its stored acknowledgement, executing each command at its tag,
refusing late ones, deleting from a tag on ``schedule_delete``, answering
``command_query`` and ``ping``). Everything runs on a :class:`ManualClock`: the vehicle's
events and the ground's sleepers are interleaved in time order, so a test of a 10-minute
pass under loss runs in seconds and does not depend on the machine being idle. The real
vehicle and spacecraft process are exercised by ``test_e2e.py``.
"""

from __future__ import annotations

import asyncio
import functools
import heapq
import itertools
import random
from collections.abc import Callable, Coroutine
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sqlalchemy.orm import Session, sessionmaker

from server.app import build_live_path
from server.services.alarms import AlarmService
from server.services.clock import ManualClock
from server.services.dbworker import Database
from server.services.downlink import GroundDownlink
from server.services.link import Connection, GroundLink
from server.services.runner import PassRunner
from server.settings import Settings
from server.storage import repository as repo
from server.storage.db import (
    make_engine,
    read_session_factory,
    session_factory,
    sqlite_url,
    upgrade,
)
from telemetry.wire import (
    AcsCommandMsg,
    CommandAck,
    CommandQuery,
    CommandStage,
    CommandUnknown,
    Hello,
    JointCommandMsg,
    Ping,
    Pong,
    RejectReason,
    SafeExit,
    Safing,
    SafingTrigger,
    ScheduleDelete,
    Verification,
    decode_ground,
    encode,
)
from tests.server.link.harness import add_plan_and_pass
from tests.server.storage.factories import make_plan

EPOCH_NS = 1_900_000_000 * 10**9  # the onboard clock at the simulation's start


@dataclass
class Outage:
    start_s: float  # onboard s since the simulation's start
    end_s: float


@dataclass
class Vehicle:
    capacity: int = 1024
    schedule: dict[int, JointCommandMsg | AcsCommandMsg] = field(default_factory=dict)
    contents: dict[int, dict[str, Any]] = field(default_factory=dict)
    outcomes: dict[int, CommandAck] = field(default_factory=dict)
    executed: dict[int, list[int]] = field(default_factory=dict)  # seq -> onboard times
    barrier: tuple[int, int] | None = None  # (from ns, max seq)
    verifications: dict[int, Verification] = field(default_factory=dict)
    copies_received: int = 0
    max_queued: int = 0
    schedule_full: int = 0
    #: on-board safing: the onboard time SAFE was entered (None: nominal)
    safe_since_ns: int | None = None
    trigger: SafingTrigger | None = None
    cancelled_on_safing: int = 0
    #: request_id -> the report each safe_exit got
    exits: dict[int, Safing] = field(default_factory=dict)
    safe_exits_received: int = 0


class SimulatedSpacecraft:
    def __init__(
        self,
        clock: ManualClock,
        *,
        delay_s: float = 3.0,
        loss: float = 0.0,
        outages: tuple[Outage, ...] = (),
        capacity: int = 1024,
        seed: int = 0,
    ) -> None:
        self.clock = clock
        self.delay_s = delay_s
        self.loss = loss
        self.outages = outages
        self.rng = random.Random(seed)
        self.mono0 = clock.monotonic()
        self.vehicle = Vehicle(capacity=capacity)
        self._events: list[tuple[float, int, str, Any]] = []  # (mono, order, to, payload)
        self._order = itertools.count()
        self.link: GroundLink | None = None
        self.db: Database | None = None
        self.conn: Connection | None = None
        self.lost = 0

    # -- time ------------------------------------------------------------------------------

    def onboard_ns(self, mono: float | None = None) -> int:
        at = self.clock.monotonic() if mono is None else mono
        return EPOCH_NS + round((at - self.mono0) * 1e9)

    def mono_of(self, onboard_ns: int) -> float:
        return self.mono0 + (onboard_ns - EPOCH_NS) / 1e9

    def _in_outage(self, mono: float) -> bool:
        t = mono - self.mono0
        return any(o.start_s <= t < o.end_s for o in self.outages)

    def _relay(self, to: str, payload: Any) -> None:
        now = self.clock.monotonic()
        if self.rng.random() < self.loss or self._in_outage(now):
            self.lost += 1
            return
        heapq.heappush(self._events, (now + self.delay_s, next(self._order), to, payload))

    # -- the ground's socket ---------------------------------------------------------------

    async def connect(
        self, ground: Ground, *, hello_read_late_s: float = 0.0, **robot: Any
    ) -> None:
        """Open a session with ``ground``'s link: its hello is stamped now and read
        ``hello_read_late_s`` later (a ground busy starting up); ``robot`` adds hello's
        ``robot``, ``robot_hash`` and ``n_joints`` (none: ETS-VII as the ground takes it)."""
        self.link = link = ground.link
        self.db = ground.db

        async def send_text(text: str) -> None:
            self._relay("vehicle", text)

        async def close(code: int, reason: str) -> None:
            return None

        self.conn = Connection(actor="ets7", send_text=send_text, close=close)
        await link.attach(self.conn)
        hello = Hello(
            vehicle="ETS-VII",
            onboard_time_ns=self.onboard_ns(),
            time_scale=1.0,
            next_telemetry_seq=0,
            last_command_seq=max(self.vehicle.contents, default=-1),
            schedule_capacity=self.vehicle.capacity,
            **robot,
        )
        await link.handle(
            self.conn, encode(hello), received_mono=self.clock.monotonic() + hello_read_late_s
        )

    def lose_ground(self) -> None:
        """The ground process died: its socket is gone, nobody reads or detaches it."""
        self.link = None
        self.db = None
        self.conn = None

    async def disconnect(self) -> None:
        assert self.link is not None and self.conn is not None
        await self.link.detach(self.conn, "socket dropped")
        self.conn = None

    # -- the vehicle -----------------------------------------------------------------------

    def _ack(self, ack: CommandAck | Verification | CommandUnknown | Pong | Safing) -> None:
        self._relay("ground", encode(ack))

    def safe(self, trigger: SafingTrigger | None = None) -> None:
        """On-board safing now (docs/protocol.md): every queued command dropped and
        acknowledged ``rejected`` ``safing``, then the ``safing`` report."""
        v = self.vehicle
        now_ns = self.onboard_ns()
        self._execute_until(now_ns)
        v.safe_since_ns, v.trigger = now_ns, trigger
        dropped = sorted(v.schedule)
        v.schedule.clear()
        for seq in dropped:
            ack = CommandAck(
                seq=seq,
                stage=CommandStage.REJECTED,
                reason=RejectReason.SAFING,
                detail="dropped: the vehicle entered SAFE",
                onboard_time_ns=now_ns,
            )
            v.outcomes[seq] = ack
            self._ack(ack)
        v.cancelled_on_safing = len(dropped)
        self.report_safing()

    def report_safing(self) -> None:
        """The ``safing`` report (the vehicle's 1 s repeat, when called again)."""
        v = self.vehicle
        if v.safe_since_ns is None:
            return
        self._ack(
            Safing(
                state="safe",
                since_time_ns=v.safe_since_ns,
                trigger=v.trigger,
                cancelled=v.cancelled_on_safing,
                onboard_time_ns=self.onboard_ns(),
            )
        )

    def _receive(self, text: str, now_ns: int) -> None:
        v = self.vehicle
        message = decode_ground(text)
        if isinstance(message, SafeExit):
            v.safe_exits_received += 1
            answer = v.exits.get(message.request_id)
            if answer is None:
                answer = Safing(
                    state="nominal",
                    since_time_ns=v.safe_since_ns,
                    exit_request_id=message.request_id,
                    onboard_time_ns=now_ns,
                )
                v.exits[message.request_id] = answer
                v.safe_since_ns = None
            self._ack(answer)
            return
        if isinstance(message, (JointCommandMsg, AcsCommandMsg)):
            content = message.model_dump()
            seq = message.seq
            if seq in v.contents:
                v.copies_received += 1
                if v.contents[seq] == content:
                    self._ack(v.outcomes[seq])
                else:
                    self._ack(
                        CommandAck(
                            seq=seq,
                            stage=CommandStage.REJECTED,
                            reason=RejectReason.DUPLICATE,
                            onboard_time_ns=now_ns,
                        )
                    )
                return
            if len(v.schedule) >= v.capacity:
                v.schedule_full += 1
                self._ack(
                    CommandAck(
                        seq=seq,
                        stage=CommandStage.REJECTED,
                        reason=RejectReason.SCHEDULE_FULL,
                        onboard_time_ns=now_ns,
                    )
                )
                return
            v.contents[seq] = content
            tag = message.execute_time_ns
            if v.safe_since_ns is not None:
                reason: RejectReason | None = RejectReason.SAFING
            elif v.barrier is not None and tag >= v.barrier[0] and seq <= v.barrier[1]:
                reason = RejectReason.CANCELLED
            elif tag <= now_ns:
                reason = RejectReason.LATE
            else:
                reason = None
            if reason is not None:
                ack = CommandAck(
                    seq=seq, stage=CommandStage.REJECTED, reason=reason, onboard_time_ns=now_ns
                )
            else:
                v.schedule[seq] = message
                v.max_queued = max(v.max_queued, len(v.schedule))
                ack = CommandAck(seq=seq, stage=CommandStage.RECEIVED, onboard_time_ns=now_ns)
            v.outcomes[seq] = ack
            self._ack(ack)
        elif isinstance(message, ScheduleDelete):
            if message.request_id in v.verifications:
                self._ack(v.verifications[message.request_id])
                return
            deleted = sorted(
                seq
                for seq, cmd in v.schedule.items()
                if cmd.execute_time_ns >= message.from_time_ns and seq <= message.max_seq
            )
            for seq in deleted:
                del v.schedule[seq]
                v.outcomes[seq] = CommandAck(
                    seq=seq,
                    stage=CommandStage.REJECTED,
                    reason=RejectReason.CANCELLED,
                    onboard_time_ns=now_ns,
                )
            v.barrier = (message.from_time_ns, message.max_seq)
            report = Verification(
                request_id=message.request_id,
                stage="completed",
                deleted=len(deleted),
                deleted_ranges=[(s, s) for s in deleted][:1000],
                onboard_time_ns=now_ns,
            )
            v.verifications[message.request_id] = report
            self._ack(report)
        elif isinstance(message, CommandQuery):
            unknown = [s for s in message.seqs if s not in v.outcomes]
            for seq in message.seqs:
                if seq in v.outcomes:
                    self._ack(v.outcomes[seq])
            if unknown:
                self._ack(CommandUnknown(seqs=unknown, onboard_time_ns=now_ns))
        elif isinstance(message, Ping):
            self._ack(
                Pong(
                    ping_id=message.ping_id,
                    ground_time_ns=message.ground_time_ns,
                    onboard_time_ns=now_ns,
                )
            )

    def _execute_until(self, now_ns: int) -> None:
        v = self.vehicle
        due = sorted(
            (cmd.execute_time_ns, seq)
            for seq, cmd in v.schedule.items()
            if cmd.execute_time_ns <= now_ns
        )
        for tag, seq in due:
            del v.schedule[seq]
            v.executed.setdefault(seq, []).append(tag)
            ack = CommandAck(seq=seq, stage=CommandStage.EXECUTED, onboard_time_ns=tag)
            v.outcomes[seq] = ack
            self._relay_at("ground", encode(ack), self.mono_of(tag))

    def _relay_at(self, to: str, payload: Any, mono: float) -> None:
        if self.rng.random() < self.loss or self._in_outage(mono):
            self.lost += 1
            return
        heapq.heappush(self._events, (mono + self.delay_s, next(self._order), to, payload))

    def _next_tag_mono(self) -> float:
        tags = [c.execute_time_ns for c in self.vehicle.schedule.values()]
        return self.mono_of(min(tags)) if tags else float("inf")

    async def _deliver_to_ground(self, payload: str, at: float) -> None:
        if self.link is not None and self.conn is not None:
            await self.link.handle(self.conn, payload, received_mono=at)

    async def run(self, seconds: float, *, step_s: float = 0.25, drain: bool = True) -> None:
        """Let ``seconds`` pass: the vehicle's events and the ground's sleepers in time
        order, the ground's database writes finished at every step (unless not ``drain``:
        a database held up)."""
        end = self.clock.monotonic() + seconds
        while self.clock.monotonic() < end:
            nxt = min(
                end,
                self.clock.monotonic() + step_s,
                self._events[0][0] if self._events else end,
                self._next_tag_mono(),
            )
            await self.clock.advance(max(0.0, nxt - self.clock.monotonic()))
            await self._process(ground_reads=True)
            if self.db is not None and drain:
                await self.db.drain()
            await self.clock.settle()

    async def _process(self, *, ground_reads: bool) -> None:
        now = self.clock.monotonic()
        while True:
            tag_at = self._next_tag_mono()
            event_at = self._events[0][0] if self._events else float("inf")
            if min(tag_at, event_at) > now:
                return
            if tag_at <= event_at:
                self._execute_until(self.onboard_ns(tag_at))
                continue
            if self._events[0][2] == "ground" and not ground_reads:
                # the ground does not read while stalled: later ones wait behind it
                ground = [e for e in self._events if e[2] == "ground"]
                others = [e for e in self._events if e[2] != "ground"]
                if not others or min(others)[0] > now:
                    self._execute_until(self.onboard_ns(now))
                    return
                heapq.heapify(others)
                at, _order, to, payload = heapq.heappop(others)
                self._events = others + ground
                heapq.heapify(self._events)
                self._execute_until(self.onboard_ns(at))
                self._receive(payload, self.onboard_ns(at))
                continue
            at, _, to, payload = heapq.heappop(self._events)
            if to == "vehicle":
                self._execute_until(self.onboard_ns(at))
                self._receive(payload, self.onboard_ns(at))
            else:
                await self._deliver_to_ground(payload, max(at, now) if ground_reads else now)

    async def stall_ground(self, seconds: float) -> None:
        """The ground process stalls for ``seconds`` (GIL, database, garbage collector):
        time moves, the vehicle and the relay go on, the ground's loop runs nothing and
        reads nothing until the end."""
        self.clock.jump(seconds)
        await self._process(ground_reads=False)


@dataclass
class Ground:
    link: GroundLink
    runner: PassRunner
    sessions: sessionmaker[Session]
    db: Database
    downlink: GroundDownlink
    alarms: AlarmService | None = None

    async def restarted(self) -> None:
        """What the service does once it has started (server/app.py's lifespan): take over
        the vehicle's alarms still listed, then recover the passes."""
        if self.alarms is not None:
            await self.alarms.load_vehicle_alarms()
        await self.runner.recover()


def make_sessions(tmp_path: Path) -> sessionmaker[Session]:
    engine = make_engine(sqlite_url(tmp_path))
    upgrade(engine)
    return session_factory(engine)


#: The database workers of the grounds made since the last :func:`close_grounds`.
_OPEN: list[Database] = []


def ground(sessions: sessionmaker[Session], clock: ManualClock, **settings: Any) -> Ground:
    """A ground on the simulated link; its database worker is closed by
    :func:`close_grounds` (tests/server/link/conftest.py, after every test)."""
    live = build_live_path(sessions=sessions, settings=Settings(**settings), clock=clock)
    _OPEN.append(live.db)
    return Ground(live.link, live.runner, sessions, live.db, live.downlink, live.alarms)


def close_grounds() -> None:
    """End the database worker of every ground made so far (a test's grounds outlive its
    event loop: their threads would idle on for the rest of the run)."""
    while _OPEN:
        _OPEN.pop().close()


def simulated(test: Callable[..., Coroutine[Any, Any, None]]) -> Callable[..., None]:
    """Run an async test on a fresh event loop (its time is the ManualClock's), then close
    the grounds it made."""

    @functools.wraps(test)
    def run(*args: Any, **kwargs: Any) -> None:
        try:
            asyncio.run(test(*args, **kwargs))
        finally:
            close_grounds()

    return run


def store_pass(sessions: sessionmaker[Session], n_commands: int, clock: ManualClock) -> str:
    return add_plan_and_pass(
        sessions,
        make_plan(n_commands),
        f"sim-{n_commands}",
        now_ns=clock.time_ns(),
        window_s=3600.0,
    )


def commands(sessions: sessionmaker[Session], pass_id: str) -> list[Any]:
    with sessions() as session:
        return list(repo.list_commands(session=session, pass_id=pass_id))


def pass_state(sessions: sessionmaker[Session], pass_id: str) -> str:
    """The pass's state, read as a reader does (no write lock on SQLite: a job the test
    holds in the database worker's transaction does not block it)."""
    with read_session_factory(sessions.kw["bind"])() as session:
        return repo.get_pass(session=session, pass_id=pass_id, refresh=True).state


async def kill_ground(g: Ground, sc: SimulatedSpacecraft) -> None:
    """``g``'s process dies mid-pass: no shutdown, nothing more from it."""
    task = g.runner._active.task  # type: ignore[union-attr]
    assert task is not None
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    await g.db.drain()
    g.db.close()
    sc.lose_ground()
