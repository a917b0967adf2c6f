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

Its own parts, each in its module: :mod:`server.services.link_connection` (one accepted
websocket and the sends on it), :mod:`server.services.link_noise` (the messages that do not
decode: counted, audited, answered at a bounded rate; the connection closed only when its
stream is unusable) and :mod:`server.services.command_fates` (what the vehicle says of a
command, filed in its stage).

What the vehicle says about commands reaches the runner (:mod:`server.services.runner`) as
typed :data:`LinkEvent` values through :meth:`GroundLink.add_listener`, after the stage is
filed (``command_ack``: queued; ``command_unknown``'s expiries: written).
``verification`` answers a ``schedule_delete``.

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
from collections.abc import Callable
from typing import Any

from server.services.clock import Clock, OnboardClock
from server.services.command_fates import CommandFates
from server.services.dbworker import Database
from server.services.downlink import GroundDownlink, TelemetryWindow
from server.services.events import (
    CommandAcked,
    CommandsUnknown,
    LinkConnected,
    LinkDisconnected,
    LinkDown,
    LinkEvent,
    LinkHello,
    LinkTakeover,
    LinkUp,
    RequestVerified,
    SafingReported,
    VehicleSafeExitRequested,
    event_job,
)
from server.services.link_connection import Connection
from server.services.link_noise import LinkNoise
from server.services.malformed import MalformedPolicy
from server.services.safing import (
    RESEND_MARGIN_S,
    SafeExitRefused,
    SafeExitSender,
    VehicleSafingState,
    check_exit_request,
)
from server.services.vehicle import (
    ETS7_ROBOT,
    LinkStatus,
    RobotIdentity,
    ScheduleStatus,
    robot_mismatch,
)
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
    Safing,
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
    "SafeExitRefused",
    "SafingReported",
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


# --- the link ------------------------------------------------------------------------------


class GroundLink:
    def __init__(
        self,
        *,
        db: Database,
        downlink: GroundDownlink,
        clock: Clock,
        one_way_delay_s: float = 3.0,
        malformed: MalformedPolicy | None = None,
    ) -> None:
        self._db = db
        #: telemetry goes there (it sends its acknowledgements through :meth:`send`)
        self._downlink = downlink
        self.clock = clock
        self.one_way_delay_s = one_way_delay_s
        self._conn: Connection | None = None
        self._pinger: asyncio.Task[None] | None = None
        self._onboard: OnboardClock | None = None
        #: a relayed onboard stamp has been read since the latest hello (see
        #: :attr:`clock_confirmed`)
        self._confirmed = False
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
        #: messages that did not decode: counted, audited per kind per interval, answered
        #: at a bounded rate, the connection closed only when its stream is unusable
        self._noise = LinkNoise(
            db=db,
            clock=clock,
            policy=malformed or MalformedPolicy(),
            send=self.send,
            current=lambda: self._conn,
        )
        self.malformed = self._noise.guard
        #: what the vehicle says of commands, filed in their stages
        self._fates = CommandFates(db=db, clock=clock)
        self._listeners: list[Callable[[LinkEvent], None]] = []
        self._uplink_status: Callable[[], dict[str, Any] | None] | None = None
        #: this ground's command lease and database (server.services.ground_status)
        self.ground_status: Callable[[], dict[str, Any]] | None = None
        #: the vehicle's on-board safing, from its reports (server.services.safing)
        self.safing = VehicleSafingState()
        self._safe_exits = SafeExitSender(
            clock=clock, db=db, send=self.send, answer_wait_s=self._answer_wait_s
        )

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
        self._fates.expect(pass_id, seqs)

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

    @property
    def clock_confirmed(self) -> bool:
        """Whether a relayed onboard stamp has been read since the latest hello. The hello
        alone places the onboard clock where it stood when the hello was *read*: a ground
        that read it late (a process still starting after a restart, a stalled loop)
        believes the vehicle's clock behind where it is until the first relayed stamp
        (telemetry, the pong of the ping sent at the hello) corrects it, and a command it
        sends meanwhile near its last chance may reach the vehicle after its tag. The
        runner does not count such a ``late`` refusal as the vehicle no longer following
        the plan (:class:`~server.services.pass_states.RefusalStreak`)."""
        return self._confirmed and self.connected

    def _observe(self, stamp_ns: int, read_mono: float) -> None:
        if self._onboard is not None:
            self._onboard.observe(stamp_ns, self.one_way_delay_s, read_mono)
            self._confirmed = True

    # -- connections ---------------------------------------------------------------------

    async def attach(self, conn: Connection) -> None:
        """A new spacecraft connection; it supersedes an older one (a half-open socket must
        not keep a reconnecting spacecraft out). Every takeover is audited
        (``link_takeover``, both connections' details): the superseded connection's own
        detach finds the link already taken and writes nothing, so this is its one record."""
        if conn.connected_ns is None:
            conn.connected_ns = self.clock.time_ns()
        old, self._conn = self._conn, conn
        # Not awaited: the hello behind it must be read (and timed) at once.
        if old is not None:
            takeover = LinkTakeover(
                actor=conn.actor, previous=old.described(), current=conn.described()
            )
            self._db.submit(event_job(takeover, self.clock))
            log.warning(
                "link takeover: connection %d (%s) supersedes %d (%s)",
                conn.id,
                conn.peer,
                old.id,
                old.peer,
            )
            with contextlib.suppress(Exception):
                await old.close(1000, "superseded by a new spacecraft connection")
        self._db.submit(event_job(LinkConnected(actor=conn.actor, connection=conn.id), self.clock))

    async def detach(self, conn: Connection, reason: str) -> None:
        if self._conn is not conn:
            return
        self._conn = None
        conn.log_failures()
        if self._pinger is not None:
            self._pinger.cancel()
            self._pinger = None
        self._emit(LinkDown(reason))
        event = LinkDisconnected(actor=conn.actor, connection=conn.id, reason=reason)
        # queued in order behind the link's other writes, not awaited (as attach's): a
        # handler ending at shutdown is not held past the server's graceful timeout by a
        # busy database
        self._db.submit(event_job(event, self.clock))

    async def send(self, text: str) -> bool:
        """Send one message to the spacecraft; False when there is no link or it failed."""
        conn = self._conn
        return conn is not None and await conn.send(text)

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

    def _answer_wait_s(self) -> float:
        """Wall s to wait for the vehicle's answer to a request (a round trip and margin)."""
        if self._onboard is None:
            return 2 * self.one_way_delay_s + RESEND_MARGIN_S
        round_trip_s = self.round_trip_s or 2 * self.one_way_delay_s * self._onboard.scale
        return (round_trip_s + RESEND_MARGIN_S) / self._onboard.scale

    async def request_safe_exit(self, actor: str, confirm: str) -> int:
        """Send ``safe_exit`` (and again until the vehicle reports it left SAFE): the
        request's id. Refused (:class:`SafeExitRefused`) when the vehicle is not safe or
        ``confirm`` is not ``EXIT SAFE <vehicle>``; :class:`LinkUnavailable` without a link."""
        if not self.connected:
            raise LinkUnavailable("no spacecraft is connected: safe_exit needs the link")
        check_exit_request(self.vehicle, self.safing.mode, confirm)
        request_id = self._safe_exits.new_request_id()
        event = VehicleSafeExitRequested(
            actor=actor, pass_id=self.safing.pass_id, request_id=request_id, vehicle=self.vehicle
        )
        await self._db.write(event_job(event, self.clock), control=True)
        self._safe_exits.start(request_id)
        return request_id

    async def going_away(self, code: int = 1001, reason: str = "ground service stopping") -> None:
        """The server is stopping (or standing down: 1013, another ground holds the command
        lease): close the spacecraft's websocket now, so that its handler ends and records
        the detach while the database worker still runs, instead of being cancelled past
        the server's graceful timeout. The vehicle keeps its loaded commands and reconnects
        to the next ground, as after a crash."""
        conn = self._conn
        if conn is not None:
            with contextlib.suppress(Exception):
                await conn.close(code, reason)

    async def close(self) -> None:
        await self._safe_exits.close()
        if self._pinger is not None:
            self._pinger.cancel()
        self._noise.close()
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
            await self._noise.refuse(conn, exc, received)
            return
        self.malformed.readable(conn.id)  # its stream is usable, noise or not
        if conn is not self._conn:
            return  # a superseded connection
        if isinstance(message, ErrorMsg):
            # Never answered (not even before the hello); its text arrives escaped.
            self._noise.error_received(conn, message, received)
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
            self._fates.file_ack(message, self.vehicle or "spacecraft")
            reason = None if message.reason is None else message.reason.value
            seq, stage, onboard_ns = message.seq, message.stage.value, message.onboard_time_ns
            self._emit(CommandAcked(seq, stage, reason, onboard_ns, received))
        elif isinstance(message, Verification):
            self._observe(message.onboard_time_ns, received)
            self._emit(RequestVerified(message, received))
        elif isinstance(message, CommandUnknown):
            self._observe(message.onboard_time_ns, received)
            await self._fates.expire_unknown(message, self.vehicle or "spacecraft")
            self._emit(CommandsUnknown(tuple(message.seqs), message.onboard_time_ns))
        elif isinstance(message, Safing):
            self._observe(message.onboard_time_ns, received)
            if message.state == "nominal":
                # the answer to a safe_exit ends its resends, whatever the ground thought
                self._safe_exits.answered(message.exit_request_id)
            filed = self.safing.on_report(message)
            if filed is not None:  # None: stale (an older report the relay delivered late)
                entered, exited = filed
                self._emit(SafingReported(message, entered, exited, received))
        elif isinstance(message, Pong):
            self._observe(message.onboard_time_ns, received)
            sent = self._pings.pop(message.ping_id, None)
            if sent is not None:
                self.round_trip_s = (received - sent) * self.time_scale

    @property
    def errors_replied(self) -> int:
        return self.malformed.replied

    @property
    def errors_received(self) -> int:
        """``error`` messages from the vehicle, readable or not."""
        return self._noise.errors_received

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
        self._confirmed = False
        conn.greeted = True
        self.safing.on_hello()  # a safe vehicle reports so right after its hello
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
            frames_behind=down.frames_behind(onboard_now if self.connected else None),
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
            vehicle_mode=self.safing.mode,
            safing=self.safing.status(),
            malformed_received=self.malformed.malformed,
            malformed_by_kind=dict(self.malformed.by_kind),
            errors_unanswered=self.malformed.unanswered,
            malformed_closes=self.malformed.closes,
            ground=None if self.ground_status is None else self.ground_status(),
        )
