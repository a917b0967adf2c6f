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
    LinkClosedMalformed,
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
    record,
)
from server.services.malformed import MalformedGuard, MalformedPolicy, tally_events
from server.services.safing import (
    RESEND_MARGIN_S,
    SafeExitSender,
    VehicleSafingState,
    exit_confirmation,
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


class SafeExitRefused(Exception):
    """A ``safe_exit`` the ground will not send: ``code`` says why (``vehicle_not_safe``,
    ``confirmation_mismatch``)."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code


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
    #: who is at the other end, for the takeover audit: the peer's ``host:port`` and
    #: ``User-Agent`` header (None: unknown), and when it connected (ground ns, the
    #: link's clock; stamped by :meth:`GroundLink.attach` when not given)
    peer: str | None = None
    user_agent: str | None = None
    connected_ns: int | None = None
    #: sends that failed on it (the socket went away under the uplink): the first is
    #: logged, the rest counted, as a closed link fails every queued command's send
    send_failures: int = 0

    def described(self) -> dict[str, Any]:
        """This connection as the takeover event names it."""
        return {
            "connection": self.id,
            "actor": self.actor,
            "peer": self.peer,
            "user_agent": self.user_agent,
            "connected_ns": self.connected_ns,
        }


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
        self.errors_received = 0
        #: messages that did not decode: counted, audited per kind per interval, answered
        #: at a bounded rate, the connection closed past a threshold (malformed.py)
        self.malformed = MalformedGuard(malformed or MalformedPolicy())
        self._auditor: asyncio.Task[None] | None = None
        self._noise_actor = "spacecraft"
        #: seq -> pass, for acknowledgements (registered by the runner)
        self._command_pass: dict[int, str] = {}
        self._listeners: list[Callable[[LinkEvent], None]] = []
        self._uplink_status: Callable[[], dict[str, Any] | None] | None = None
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
        if conn.send_failures > 1:
            log.warning(
                "connection %d: %d sends failed after its socket went away",
                conn.id,
                conn.send_failures,
            )
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
        if conn is None:
            return False
        try:
            async with conn.lock:
                await conn.send_text(text)
        except Exception as exc:  # the socket went away under us
            conn.send_failures += 1
            if conn.send_failures == 1:
                log.warning(
                    "send to spacecraft failed on connection %d: %r (further failures on it"
                    " are counted, not logged)",
                    conn.id,
                    exc,
                )
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
        expected = exit_confirmation(self.vehicle)
        if confirm != expected:
            raise SafeExitRefused(
                "confirmation_mismatch", f"confirm must be exactly {expected!r}, got {confirm!r}"
            )
        if self.safing.mode != "safe":
            raise SafeExitRefused(
                "vehicle_not_safe", f"the vehicle {self.vehicle!r} is not in SAFE"
            )
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
        if self._auditor is not None:
            self._auditor.cancel()
        self._audit_interval()  # what the open interval counted so far
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
            await self._refuse(conn, exc, received)
            return
        if conn is not self._conn:
            return  # a superseded connection
        if isinstance(message, ErrorMsg):
            # Never answered (not even before the hello); its text arrives escaped.
            self.errors_received += 1
            self._noisy(conn, received)
            self.malformed.error_received(message.reason, message.ref_type, received)
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

    async def _refuse(self, conn: Connection, exc: WireError, received: float) -> None:
        """A message that did not decode: counted, audited with its kind once per
        interval, answered with ``error`` (naming the reason; the wire's reasons hold no
        control character) at a bounded rate, the connection closed past the threshold
        (:mod:`server.services.malformed`). Nothing here waits for the database, and the
        loop is let go after each: the uplink and the acknowledgements go first. A broken
        ``error`` from the vehicle is counted, never answered."""
        reason = str(exc)[:500]
        if exc.ref_type == "error":
            self.errors_received += 1
            reason = f"unreadable error message: {reason}"[:500]
        self._noisy(conn, received)
        verdict = self.malformed.refused(conn.id, exc, reason, received)
        if verdict.reply is not None and conn is self._conn:
            await self.send(encode(ErrorMsg(reason=verdict.reply, ref_type=exc.ref_type)))
        if verdict.close is not None:
            count = self.malformed.policy.close_after + 1
            log.warning("closing the spacecraft's link: %s", verdict.close)
            closed = LinkClosedMalformed(
                actor=conn.actor,
                connection=conn.id,
                reason=verdict.close,
                count=count,
                interval_s=self.malformed.policy.interval_s,
            )
            self._db.submit(event_job(closed, self.clock))
            with contextlib.suppress(Exception):
                await conn.close(1008, verdict.close)
        await asyncio.sleep(0)

    def _noisy(self, conn: Connection, now: float) -> None:
        """Before tallying a message of ``conn`` at ``now``: the interval it ends is
        audited, and an auditor waits for the end of the one it opens."""
        self._noise_actor = conn.actor
        end = self.malformed.interval_end()
        if end is not None and now >= end:
            self._audit_interval()
        if self._auditor is None or self._auditor.done():
            self._auditor = asyncio.create_task(self._audit_intervals(), name="link-noise")

    async def _audit_intervals(self) -> None:
        await asyncio.sleep(0)  # the message that started it is tallied first
        while (end := self.malformed.interval_end()) is not None:
            await self.clock.sleep_until(end)
            if self.malformed.interval_end() == end:
                self._audit_interval()

    def _audit_interval(self) -> None:
        """One audit row per kind of the open interval (queued, not waited for)."""
        events = tally_events(self.malformed.take_interval(), self._noise_actor, self.clock)
        if events:
            self._db.submit(lambda s: [record(s, e, self.clock.time_ns()) for e in events])

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
            vehicle_mode=self.safing.mode,
            safing=self.safing.status(),
            malformed_received=self.malformed.malformed,
            malformed_by_kind=dict(self.malformed.by_kind),
            errors_unanswered=self.malformed.unanswered,
            malformed_closes=self.malformed.closes,
        )
