"""The ground end of the space-ground link (docs/protocol.md, v2): one spacecraft at a time.

The API layer owns the websocket and hands this service each text frame
(:meth:`GroundLink.handle`, timed once when read off the socket, on the injected clock)
and a way to send (:class:`Connection`). This module is the protocol: the session
(``hello``, ping), the onboard clock, and the routing of what the vehicle says. Its
collaborators are built beside it by the composition root (:mod:`server.app`) and handed to
it, each the one owner of its state:

- :mod:`server.services.clock`: the injected ground clock and the ground's estimate of the
  onboard clock (from ``hello``, refined by every later onboard time stamp);
- :mod:`server.services.downlink`: telemetry in, stored once, acknowledged, gaps asked for,
  against the telemetry windows the runner opens on it;
- :mod:`server.storage.stages` and :mod:`server.services.command_stages`: the stage rules of
  a command and the writes that move it; :mod:`server.services.events`: every event;
- :mod:`server.services.dbworker`: the database worker thread and the consoles' publisher.

What the vehicle says about commands reaches the runner (:mod:`server.services.runner`) as
typed :data:`LinkEvent` values through :meth:`GroundLink.add_listener`, after this module
has filed the stage: ``command_ack`` moves the command's stage (``received``,
``executed``, ``rejected`` with its reason, ``cancelled`` when a ``schedule_delete``
removed it) with the onboard time, never backwards; a ``schedule_full`` refusal is
transient (the vehicle did not keep the command; the runner sends it again) and leaves the
stage alone. ``command_unknown`` expires the commands the vehicle never received whose tag
has passed. ``verification`` answers a ``schedule_delete``.

``hello`` names the robot the vehicle flies (its description's name, ``content_sha256`` and
joint count; a ``hello`` without them is ETS-VII's, 6 joints): :attr:`GroundLink.robot`,
which the runner compares with a plan's robot (:func:`robot_mismatch`) before it starts a
pass and whenever the vehicle greets again.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from server.services.clock import Clock, OnboardClock
from server.services.command_stages import set_command_stage
from server.services.dbworker import Database
from server.services.downlink import GroundDownlink, TelemetryWindow
from server.services.events import (
    CommandAcked,
    CommandAckUnknown,
    CommandDeferred,
    CommandsUnknown,
    LinkConnected,
    LinkDisconnected,
    LinkDown,
    LinkErrorReceived,
    LinkErrorReplied,
    LinkEvent,
    LinkHello,
    LinkUp,
    RequestVerified,
    event_job,
    record,
)
from server.services.vehicle import (
    ETS7_ROBOT,
    LinkStatus,
    RobotIdentity,
    ScheduleStatus,
    robot_mismatch,
)
from server.storage import repository as repo
from server.storage.models import CommandRecord
from server.storage.stages import acked_stage, expires_unknown
from telemetry.wire import (
    DEFAULT_SCHEDULE_CAPACITY,
    AcsCommandMsg,
    CommandAck,
    CommandQuery,
    CommandUnknown,
    ErrorMsg,
    Hello,
    JointCommandMsg,
    Ping,
    Pong,
    ScheduleDelete,
    TelemetryMsg,
    Verification,
    WireError,
    decode_spacecraft,
    encode,
)

__all__ = [
    "ETS7_ROBOT",
    "CommandAcked",
    "CommandsUnknown",
    "Connection",
    "GroundLink",
    "LinkDown",
    "LinkEvent",
    "LinkStatus",
    "LinkUnavailable",
    "LinkUp",
    "RequestVerified",
    "RobotIdentity",
    "ScheduleStatus",
    "TelemetryWindow",
    "robot_mismatch",
]

log = logging.getLogger("hikoboshi.ground.link")

#: A ping this often (onboard s) while connected.
PING_PERIOD_S = 10.0
#: Onboard seconds of relay jitter the clock refinement allows (SPEC 6: 0.05 s sigma).
JITTER_ALLOWANCE_S = 0.5


class LinkUnavailable(Exception):
    """No spacecraft is connected, or its clock is not known yet."""


# --- connection and status -----------------------------------------------------------------


@dataclass
class Connection:
    """One accepted websocket, as the API layer hands it over."""

    actor: str  # the token holder's name
    send_text: Callable[[str], Awaitable[None]]
    close: Callable[[int, str], Awaitable[None]]
    id: int = field(default_factory=itertools.count(1).__next__)
    greeted: bool = False  # its hello has arrived
    lock: asyncio.Lock = field(default_factory=asyncio.Lock)


# --- the link ------------------------------------------------------------------------------


class GroundLink:
    def __init__(
        self,
        *,
        db: Database,
        downlink: GroundDownlink,
        clock: Clock,
        one_way_delay_s: float = 3.0,
    ) -> None:
        self._db = db
        #: telemetry goes there (it sends its acknowledgements through :meth:`send`)
        self._downlink = downlink
        self.clock = clock
        self.one_way_delay_s = one_way_delay_s
        self._conn: Connection | None = None
        self._pinger: asyncio.Task[None] | None = None
        self._onboard: OnboardClock | None = None
        self.vehicle: str | None = None
        #: the robot of the latest hello (None before the first)
        self.robot: RobotIdentity | None = None
        self.last_command_seq = -1
        self.schedule_capacity = DEFAULT_SCHEDULE_CAPACITY
        self.los_policy = "continue"
        self.los_hold_after_s: float | None = None
        self.round_trip_s: float | None = None
        self._pings: dict[int, float] = {}
        self._ping_ids = itertools.count()
        self.errors_replied = 0
        self.errors_received = 0
        #: seq -> pass, for acknowledgements (registered by the runner)
        self._command_pass: dict[int, str] = {}
        self._listeners: list[Callable[[LinkEvent], None]] = []
        self._uplink_status: Callable[[], dict[str, Any] | None] | None = None

    # -- what the runner asks for --------------------------------------------------------

    def add_listener(self, callback: Callable[[LinkEvent], None]) -> Callable[[], None]:
        """``callback`` gets every :data:`LinkEvent` (after its stage is filed, for acks)."""
        self._listeners.append(callback)
        return lambda: self._listeners.remove(callback)

    def _emit(self, event: LinkEvent) -> None:
        for callback in list(self._listeners):
            try:
                callback(event)
            except Exception:
                log.exception("link listener failed on %s", type(event).__name__)

    def expect_commands(self, pass_id: str, seqs: list[int]) -> None:
        """Acknowledgements of these seqs belong to ``pass_id``."""
        for seq in seqs:
            self._command_pass[seq] = pass_id

    def set_uplink_status(self, provider: Callable[[], dict[str, Any] | None] | None) -> None:
        self._uplink_status = provider

    # -- clock ---------------------------------------------------------------------------

    @property
    def connected(self) -> bool:
        return self._conn is not None and self._conn.greeted and self._onboard is not None

    @property
    def time_scale(self) -> float:
        if self._onboard is None:
            raise LinkUnavailable("no hello from the spacecraft yet")
        return self._onboard.scale

    @property
    def onboard_clock(self) -> OnboardClock:
        if self._onboard is None:
            raise LinkUnavailable("no hello from the spacecraft yet")
        return self._onboard

    def onboard_now_ns(self) -> int:
        return self.onboard_clock.now_ns()

    def mono_at_onboard(self, onboard_ns: int) -> float:
        """The ground monotonic instant at which the onboard clock reads ``onboard_ns``."""
        return self.onboard_clock.mono_at(onboard_ns)

    def _observe(self, stamp_ns: int, read_mono: float) -> None:
        if self._onboard is not None:
            self._onboard.observe(stamp_ns, self.one_way_delay_s, read_mono)

    # -- connections ---------------------------------------------------------------------

    async def attach(self, conn: Connection) -> None:
        """A new spacecraft connection; it supersedes an older one (a half-open socket must
        not keep a reconnecting spacecraft out)."""
        old, self._conn = self._conn, conn
        if old is not None:
            with contextlib.suppress(Exception):
                await old.close(1000, "superseded by a new spacecraft connection")
        # Not awaited: the hello behind it must be read (and timed) at once.
        self._db.submit(event_job(LinkConnected(actor=conn.actor, connection=conn.id), self.clock))

    async def detach(self, conn: Connection, reason: str) -> None:
        if self._conn is not conn:
            return
        self._conn = None
        if self._pinger is not None:
            self._pinger.cancel()
            self._pinger = None
        self._emit(LinkDown(reason))
        event = LinkDisconnected(actor=conn.actor, connection=conn.id, reason=reason)
        await self._db.write(event_job(event, self.clock))

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

    async def send_command(self, command: JointCommandMsg | AcsCommandMsg) -> bool:
        return self.connected and await self.send(encode(command))

    async def send_schedule_delete(self, request: ScheduleDelete) -> bool:
        return self.connected and await self.send(encode(request))

    async def query_commands(self, seqs: list[int]) -> bool:
        """Ask the vehicle what became of these commands (lost acknowledgements)."""
        if not seqs:
            return True
        ok = True
        for lo in range(0, len(seqs), 1000):
            ok = await self.send(encode(CommandQuery(seqs=seqs[lo : lo + 1000]))) and ok
        return ok

    async def close(self) -> None:
        if self._pinger is not None:
            self._pinger.cancel()
        conn, self._conn = self._conn, None
        if conn is not None:
            with contextlib.suppress(Exception):
                await conn.close(1001, "ground service stopping")

    # -- incoming ------------------------------------------------------------------------

    async def handle(
        self, conn: Connection, raw: str | bytes, received_mono: float | None = None
    ) -> None:
        """One frame from the spacecraft, read off the socket at ``received_mono`` (the
        ground clock's monotonic time; now if not given); a malformed one gets an ``error``
        reply."""
        received = self.clock.monotonic() if received_mono is None else received_mono
        try:
            message = decode_spacecraft(raw)
        except WireError as exc:
            await self._refuse(conn, exc)
            return
        if conn is not self._conn:
            return  # a superseded connection
        if isinstance(message, ErrorMsg):
            # Never answered (not even before the hello); its text arrives escaped.
            self.errors_received += 1
            info = LinkErrorReceived(
                actor=conn.actor, reason=message.reason, ref_type=message.ref_type
            )
            await self._db.write(event_job(info, self.clock))
        elif isinstance(message, Hello):
            await self._on_hello(conn, message, received)
        elif not conn.greeted:
            await self.send(encode(ErrorMsg(reason="hello expected first", ref_type=message.type)))
        elif isinstance(message, TelemetryMsg):
            if message.frames:
                self._observe(max(f.generation_time_ns for f in message.frames), received)
            await self._downlink.on_telemetry(message, received)
        elif isinstance(message, CommandAck):
            self._observe(message.onboard_time_ns, received)
            self._on_command_ack(message, received)
        elif isinstance(message, Verification):
            self._observe(message.onboard_time_ns, received)
            self._emit(RequestVerified(message, received))
        elif isinstance(message, CommandUnknown):
            self._observe(message.onboard_time_ns, received)
            await self._on_command_unknown(message)
        elif isinstance(message, Pong):
            self._observe(message.onboard_time_ns, received)
            sent = self._pings.pop(message.ping_id, None)
            if sent is not None:
                self.round_trip_s = (received - sent) * self.time_scale

    async def _refuse(self, conn: Connection, exc: WireError) -> None:
        """A message that did not decode: an ``error`` reply naming the reason (the wire's
        reasons hold no control character), and a ``link_error_replied`` event; the session
        carries on. A broken ``error`` from the vehicle is counted, never answered."""
        reason = str(exc)[:500]
        if exc.ref_type == "error":
            self.errors_received += 1
            text = f"unreadable error message: {reason}"[:500]
            info = LinkErrorReceived(actor=conn.actor, reason=text, ref_type=None)
            await self._db.write(event_job(info, self.clock))
            return
        self.errors_replied += 1
        await self.send(encode(ErrorMsg(reason=reason, ref_type=exc.ref_type)))
        replied = LinkErrorReplied(actor=conn.actor, reason=reason, ref_type=exc.ref_type)
        await self._db.write(event_job(replied, self.clock))

    async def _on_hello(self, conn: Connection, hello: Hello, received_mono: float) -> None:
        # Timed when read off the socket: at 20x, 50 ms of queueing would put the ground's
        # idea of the onboard clock a whole second behind (later stamps correct it).
        self._onboard = OnboardClock(
            self.clock,
            hello.onboard_time_ns,
            received_mono,
            hello.time_scale,
            jitter_allowance_s=JITTER_ALLOWANCE_S,
        )
        conn.greeted = True
        self.vehicle = hello.vehicle
        self.robot = RobotIdentity.of_hello(hello)
        self.last_command_seq = hello.last_command_seq
        self.schedule_capacity = hello.schedule_capacity
        self.los_policy = hello.los_policy
        self.los_hold_after_s = hello.los_hold_after_s
        if hello.next_telemetry_seq <= self._downlink.held.highest():
            self._downlink.restart_numbering()  # a new spacecraft process counts from 0
        detail = hello.model_dump(mode="json", exclude={"v", "type"})
        await self._db.write(event_job(LinkHello(actor=conn.actor, hello=detail), self.clock))
        if self._pinger is None or self._pinger.done():
            self._pinger = asyncio.create_task(self._ping_loop(), name="ground-pinger")
        self._emit(LinkUp(hello))

    async def _ping_loop(self) -> None:
        while self.connected:
            ping_id = next(self._ping_ids)
            self._pings = {k: v for k, v in self._pings.items() if k > ping_id - 10}
            self._pings[ping_id] = self.clock.monotonic()
            await self.send(encode(Ping(ping_id=ping_id, ground_time_ns=self.clock.time_ns())))
            await self.clock.sleep_until(self.clock.monotonic() + PING_PERIOD_S / self.time_scale)

    def _pass_of(self, session: Session, seq: int) -> str | None:
        key = self._command_pass.get(seq)
        if key is not None:
            return key
        return session.scalar(
            select(CommandRecord.pass_id)
            .where(CommandRecord.seq == seq)
            .order_by(CommandRecord.queued_at_ns.desc())
            .limit(1)
        )

    def _on_command_ack(self, ack: CommandAck, read_mono: float) -> None:
        actor = self.vehicle or "spacecraft"
        reason = None if ack.reason is None else ack.reason.value
        stage = ack.stage.value
        filed = acked_stage(stage, reason)
        if filed is None:
            # Transient: the vehicle did not keep it, the runner sends it again.
            deferred = CommandDeferred(
                actor=actor, seq=ack.seq, reason=reason, detail_text=ack.detail
            )
            self._db.submit(event_job(deferred, self.clock))
        else:
            # cancelled: the ground's clock (the stage times of storage/models.py)
            at_ns = self.clock.time_ns() if filed == "cancelled" else ack.onboard_time_ns

            def job(session: Session) -> list[dict[str, Any]]:
                key = self._pass_of(session, ack.seq)
                if key is None:
                    unknown = CommandAckUnknown(actor=actor, seq=ack.seq, stage=stage)
                    return [record(session, unknown, self.clock.time_ns())]
                return set_command_stage(
                    session,
                    clock=self.clock,
                    pass_id=key,
                    seq=ack.seq,
                    stage=filed,
                    time_ns=at_ns,
                    actor=actor,
                    reason=reason,
                    detail=ack.detail,
                )

            # Not awaited: acknowledgements queue behind each other in order, share commits.
            self._db.submit(job)
        self._emit(CommandAcked(ack.seq, stage, reason, ack.onboard_time_ns, read_mono))

    async def _on_command_unknown(self, message: CommandUnknown) -> None:
        """The vehicle never received these: lost on the uplink; those whose tag has passed
        can no longer run."""
        actor = self.vehicle or "spacecraft"
        now_ns = self.clock.time_ns()

        def job(session: Session) -> list[dict[str, Any]]:
            events: list[dict[str, Any]] = []
            for seq in message.seqs:
                key = self._pass_of(session, seq)
                if key is None:
                    continue
                record = repo.get_command(session=session, pass_id=key, seq=seq)
                if not expires_unknown(
                    record.stage, record.execute_time_ns, message.onboard_time_ns
                ):
                    continue  # received after all, already final, or not due yet
                events += set_command_stage(
                    session,
                    clock=self.clock,
                    pass_id=key,
                    seq=seq,
                    stage="expired",
                    time_ns=now_ns,
                    actor=actor,
                    detail="never reached the vehicle before its tag",
                )
            return events

        await self._db.write(job)
        self._emit(CommandsUnknown(tuple(message.seqs), message.onboard_time_ns))

    # -- status --------------------------------------------------------------------------

    def status(self) -> LinkStatus:
        down = self._downlink
        gaps = down.held.gaps()
        onboard_now = self.onboard_now_ns() if self._onboard is not None else None
        uplink = None
        if self._uplink_status is not None:
            try:
                uplink = self._uplink_status()
            except Exception:
                log.exception("uplink status failed")
        return LinkStatus(
            connected=self.connected,
            actor=None if self._conn is None else self._conn.actor,
            vehicle=self.vehicle,
            time_scale=None if self._onboard is None else self._onboard.scale,
            onboard_time_ns=onboard_now,
            round_trip_s=self.round_trip_s,
            frames_received=down.held.count,
            duplicates=down.duplicates,
            frames_outside_pass=down.frames_outside_pass,
            highest_seq=down.held.highest(),
            frames_behind=down.frames_behind(onboard_now),
            open_gaps=gaps[:100],
            frames_missing=sum(hi - lo + 1 for lo, hi in gaps),
            retransmit_requests=down.retransmit_requests,
            errors_replied=self.errors_replied,
            errors_received=self.errors_received,
            schedule=ScheduleStatus.of(self._downlink.latest_frame, self.schedule_capacity),
            uplink=uplink,
            clock_corrected_s=0.0 if self._onboard is None else self._onboard.corrected_ns / 1e9,
            robot=None if self.robot is None else self.robot.name,
            robot_hash=None if self.robot is None else self.robot.hash,
            n_joints=None if self.robot is None else self.robot.n_joints,
        )
