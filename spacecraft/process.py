"""The spacecraft process: the vehicle behind an emulated relay link, talking websocket.

One asyncio loop owns everything. The onboard clock runs at ``time_scale`` times wall time
(``onboard_s = (wall - wall0) * time_scale``), and every onboard duration (link delay,
telemetry period, resend timeout) is onboard time, so a 20-minute pass at 20x takes a minute.

- **Uplink**: a message from the ground reaches the vehicle only after the uplink emulator's
  delay (it may be lost, or fall in an outage); the vehicle is advanced to the delivery
  instant before it sees the message, so "late" means late in onboard time. Every delivered
  message, understood or not, tells the vehicle it has heard from the ground (its LOS
  policy's clock). Commands go to :meth:`~spacecraft.vehicle.Vehicle.receive`,
  ``schedule_delete`` to :meth:`~spacecraft.vehicle.Vehicle.delete_schedule`.
- **Downlink**: acknowledgements, verifications, errors, pongs, ``safing`` reports and
  telemetry leave through the downlink emulator and are written to the socket at their
  delivery instant; telemetry stays in the onboard store (:mod:`spacecraft.downlink`) until
  the ground acknowledges it.
- **On-board safing**: ``safe_exit`` goes to :meth:`~spacecraft.vehicle.Vehicle.safe_exit`,
  whose ``safing`` report answers it. The vehicle's own reports (on entering SAFE, then every
  onboard second while safe) go down while connected; they are not kept for a later
  connection, which instead gets the report of the SAFE state right after ``hello``.
- **Truth log** (``truth_log``, :mod:`spacecraft.truth`): the start, each fault's onset and
  each entry into and exit from SAFE, written as they happen; never sent to the ground.
- **Connection**: reconnects after any drop with exponential backoff, trying its grounds in
  order (``ground_url``, then each of ``standby_urls``; the ground it was connected to is
  tried again last): a standby refuses the handshake (503: another ground holds the command
  lease, docs/operations.md "One ground in command"; a holder that loses it closes with
  1013) and the next one is tried at once; the backoff grows only once every ground has
  been tried. A drop changes nothing
  on board: the loaded schedule keeps executing, and only the vehicle's LOS policy (silence
  for ``los_hold_after_s`` with ``hold``) refuses queued joint commands. ``hello`` is the
  session handshake, announces the schedule's capacity, the LOS policy and (when the vehicle
  flies a robot description, ``hikoboshi spacecraft --robot``) the robot's name, the hash of
  its description and its joint count, and goes straight to the ground.
- **Noise** (``garbage``, ``hikoboshi spacecraft --garbage``): while connected and the
  onboard clock is inside a window, malformed messages (:mod:`spacecraft.garbage`) go
  straight onto the socket at the window's rate per wall second, beside the real traffic
  (a rehearsal of a noisy link; docs/protocol.md "Malformed messages"). The ground closes a
  connection that sends too many; the process reconnects as after any drop.
- **Contact plan** (``contact``, :mod:`spacecraft.contact`: the windows of a mission): the
  relay is there only inside a window. The process connects at acquisition of signal and
  closes its socket at loss, and both links drop whatever is not across before the window's
  loss. Two counts: ``commands_outside_window``, the commands the ground put on the relay
  outside a window (it cannot once the socket is closed; between LOS and the close, a
  loaded loop's lag, it can, and the link loses them), and
  ``commands_delivered_outside_window``, those the vehicle received outside one (the link
  makes it 0). Between
  windows the vehicle keeps flying (gravity gradient on the base, attitude control with the
  wheels) in FAST mode: the onboard clock runs as fast as the simulation computes (at most
  ``fast_scale`` times wall time when given) until the next acquisition, where it returns
  to ``time_scale``; the ground re-reads the clock from the ``hello`` of each window.
- **Stop** (SIGTERM): the vehicle stops, the link keeps running until every telemetry frame has
  been acknowledged or ``drain_timeout_s`` (wall) has passed, then the process exits.
"""

from __future__ import annotations

import asyncio
import contextlib
import heapq
import itertools
import json
import logging
import random
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidURI

from spacecraft.contact import ContactPlan
from spacecraft.downlink import Downlink, DownlinkConfig
from spacecraft.garbage import GarbageMaker
from spacecraft.link import Garbage, LinkConfig, LinkEmulator, Outage
from spacecraft.truth import TruthLog
from spacecraft.vehicle import Vehicle, VehicleConfig
from telemetry.wire import (
    PROTOCOL_VERSION,
    AcsCommandMsg,
    CommandAck,
    CommandQuery,
    CommandStage,
    CommandUnknown,
    ErrorMsg,
    Hello,
    JointCommandMsg,
    Ping,
    Pong,
    RejectReason,
    Retransmit,
    SafeExit,
    ScheduleDelete,
    TelemetryAck,
    TelemetryMsg,
    WireError,
    decode_ground,
    encode,
)

#: Wall seconds the resend timeout allows the ground for its own processing.
RESEND_WALL_S = 3.0

__all__ = ["ProcessConfig", "SpacecraftProcess"]

log = logging.getLogger("hikoboshi.spacecraft")

#: FAST mode flies a gap in steps this long (onboard s; about 50 ms of computing each).
FAST_CHUNK_S = 5.0

#: Frames larger than this close the socket (the library's guard); smaller ones that are
#: still over the protocol's limit get an ``error`` reply.
SOCKET_MAX_BYTES = 4 * 1024 * 1024


@dataclass(frozen=True)
class ProcessConfig:
    ground_url: str
    token: str
    #: more grounds' link endpoints (hot standbys), tried in order after ``ground_url``
    standby_urls: tuple[str, ...] = ()
    time_scale: float = 1.0
    vehicle: VehicleConfig = field(default_factory=VehicleConfig)
    uplink: LinkConfig = field(default_factory=LinkConfig)
    downlink: LinkConfig = field(default_factory=lambda: LinkConfig(seed=1))
    telemetry_store: DownlinkConfig = field(default_factory=DownlinkConfig)
    epoch_ns: int | None = None  # onboard clock at start; default: wall clock, whole second
    seed: int = 0
    backoff_initial_s: float = 0.2  # wall seconds
    backoff_max_s: float = 5.0
    drain_timeout_s: float = 30.0  # wall seconds
    #: where the truth log is written (None: nowhere)
    truth_log: Path | None = None
    #: windows of malformed messages toward the ground (a rehearsal of a noisy link)
    garbage: tuple[Garbage, ...] = ()
    #: the relay's windows and delays from a mission (None: always up, the links' delay)
    contact: ContactPlan | None = None
    #: between windows the onboard clock runs at most this many times wall time (None: as
    #: fast as the simulation computes); only with ``contact``
    fast_scale: float | None = None

    def __post_init__(self) -> None:
        if not 0 < self.time_scale <= 1000:
            raise ValueError(f"time_scale = {self.time_scale} must lie in (0, 1000]")
        if self.fast_scale is not None and not self.fast_scale >= self.time_scale:
            raise ValueError(
                f"fast_scale = {self.fast_scale} must be at least time_scale = {self.time_scale}"
            )
        for url in self.ground_urls:
            if not url.startswith(("ws://", "wss://")):
                raise ValueError(f"ground URL {url!r} must start with ws:// or wss://")

    @property
    def ground_urls(self) -> tuple[str, ...]:
        """Every ground this vehicle may talk to, in the order it tries them."""
        return (self.ground_url, *self.standby_urls)


class SpacecraftProcess:
    def __init__(self, config: ProcessConfig) -> None:
        self.config = config
        epoch = config.epoch_ns if config.epoch_ns is not None else int(time.time()) * 10**9
        self.epoch_ns = epoch
        self.vehicle = Vehicle(config.vehicle, epoch_ns=epoch, seed=config.seed)
        contact = config.contact
        up, down = config.uplink, config.downlink
        if contact is not None:
            up, down = replace(up, contact=contact), replace(down, contact=contact)
        self.uplink = LinkEmulator(up)
        self.downlink_link = LinkEmulator(down)
        self.commands_outside_window = 0
        self.commands_delivered_outside_window = 0
        self.fast_forwards = 0  # how many gaps were flown in FAST mode
        # Resend after the onboard timeout plus three seconds of wall time per unit of time
        # scale: at 20x the 10 s timeout is half a wall second, less than a loaded ground
        # may take to acknowledge, and early resends only feed its backlog. One second was
        # too little: the demo's loss-and-outage pass drew 489-1597 copies (bound 460) on
        # this 2-core machine; gaps are still asked for by the ground within a second.
        store = config.telemetry_store
        self.store = Downlink(
            replace(store, resend_after_s=store.resend_after_s + RESEND_WALL_S * config.time_scale)
        )
        # onboard_s = onboard0 + (monotonic - wall0) * scale, re-anchored by FAST mode
        self._wall0 = time.monotonic()
        self._onboard0 = 0.0
        self._scale = config.time_scale
        self._ws: ClientConnection | None = None
        self._connected = asyncio.Event()
        self._incoming: list[tuple[float, int, str | bytes]] = []  # (deliver_s, n, raw)
        self._outgoing: list[tuple[float, int, str]] = []  # (deliver_s, n, text)
        self._counter = itertools.count()
        self._outbox: list[str] = []  # made while disconnected: sent after reconnecting
        self._stopping = False
        self.connections = 0
        self.errors_replied = 0
        self._truth: TruthLog | None = None
        self.garbage = GarbageMaker(config.seed, epoch_ns=epoch)
        self.garbage_sent = 0

    # -- clock ---------------------------------------------------------------------------

    def onboard_s(self) -> float:
        return self._onboard0 + (time.monotonic() - self._wall0) * self._scale

    def _anchor(self, onboard_s: float, scale: float) -> None:
        """The onboard clock reads ``onboard_s`` now (never backwards) and runs on at
        ``scale`` times wall time (0: it stands, FAST mode moves it)."""
        self._onboard0 = max(onboard_s, self.onboard_s())
        self._wall0 = time.monotonic()
        self._scale = scale

    def _wall_delay(self, onboard_s: float) -> float:
        if self._scale == 0:
            return 0.01  # FAST mode: the clock moves in steps
        return max(0.0, (onboard_s - self.onboard_s()) / self._scale)

    def onboard_ns(self, onboard_s: float) -> int:
        return self.epoch_ns + round(onboard_s * 1e9)

    def add_outage(self, outage: Outage) -> None:
        """Take the relay down in both directions on ``outage`` (onboard s of this process),
        which must start no earlier than now (:meth:`LinkEmulator.add_outage`)."""
        now_s = self.onboard_s()
        if outage.start_s < now_s:
            raise ValueError(
                f"outage start_s = {outage.start_s!r} s is in the past (onboard now {now_s:.3f} s)"
            )
        self.uplink.add_outage(outage)
        self.downlink_link.add_outage(outage)

    # -- downlink ------------------------------------------------------------------------

    def _send(self, text: str) -> None:
        """Hand one message to the downlink emulator."""
        if not self._connected.is_set():
            self._outbox.append(text)
            return
        deliver = self.downlink_link.send(self.onboard_s(), len(text.encode()))
        if deliver is not None:
            heapq.heappush(self._outgoing, (deliver, next(self._counter), text))

    async def _sender(self) -> None:
        while True:
            if not self._outgoing:
                await asyncio.sleep(0.002)
                continue
            deliver, _, text = self._outgoing[0]
            delay = self._wall_delay(deliver)
            if delay > 0:
                await asyncio.sleep(min(delay, 0.01))
                continue
            heapq.heappop(self._outgoing)
            ws = self._ws
            if ws is None:
                continue  # the socket went down while the message was in the relay
            with contextlib.suppress(ConnectionClosed):
                await ws.send(text)

    async def _noise(self) -> None:
        """Malformed messages onto the socket at each garbage window's rate (wall), while
        connected and inside the window (onboard); a burst catches up after a stall, at
        most a tenth of a second's worth."""
        windows = self.config.garbage
        if not windows:
            return
        due = time.monotonic()
        while True:
            now_s = self.onboard_s()
            window = next((w for w in windows if w.contains(now_s)), None)
            ws = self._ws
            if window is None or ws is None or not self._connected.is_set():
                await asyncio.sleep(0.01)
                due = time.monotonic()
                continue
            period = 1.0 / window.rate
            due = max(due, time.monotonic() - 0.1)
            while due <= time.monotonic():
                with contextlib.suppress(ConnectionClosed):
                    await ws.send(self.garbage.next())
                    self.garbage_sent += 1
                due += period
            await asyncio.sleep(max(0.0, due - time.monotonic()))

    # -- uplink --------------------------------------------------------------------------

    def _handle(self, raw: str | bytes) -> None:
        try:
            message = decode_ground(raw)
        except WireError as exc:
            reply = self._error_reply(raw, exc)
            if reply is not None:
                self.errors_replied += 1
                self._send(reply)
            return
        if isinstance(message, JointCommandMsg | AcsCommandMsg):
            self._send(encode(self.vehicle.receive(message)))
        elif isinstance(message, ScheduleDelete):
            self._send(encode(self.vehicle.delete_schedule(message)))
        elif isinstance(message, SafeExit):
            self._send(encode(self.vehicle.safe_exit(message)))
            self._log_truth()
        elif isinstance(message, TelemetryAck):
            self.store.on_ack(message.through_seq, message.ranges)
        elif isinstance(message, Retransmit):
            self.store.on_retransmit(message.ranges)
        elif isinstance(message, CommandQuery):
            unknown = []
            for seq in message.seqs:
                ack = self.vehicle.outcome(seq)
                if ack is None:
                    unknown.append(seq)
                else:
                    self._send(encode(ack))
            if unknown:
                unknown_msg = CommandUnknown(
                    seqs=unknown, onboard_time_ns=self.vehicle.onboard_time_ns
                )
                self._send(encode(unknown_msg))
        elif isinstance(message, Ping):
            pong = Pong(
                ping_id=message.ping_id,
                ground_time_ns=message.ground_time_ns,
                onboard_time_ns=self.vehicle.onboard_time_ns,
            )
            self._send(encode(pong))

    def _error_reply(self, raw: str | bytes, exc: WireError) -> str | None:
        """A command of this protocol version with a readable seq is refused as such;
        anything else (another version's messages included) gets ``error``, but for the
        ground's own ``error`` replies: an error is never answered with one (no ping-pong).
        The decoder's reasons and ``ref_type`` hold no control character."""
        reason = str(exc)
        if exc.ref_type == "error":
            log.warning("the ground could not read a message of ours: %s", reason[:300])
            return None
        if exc.ref_type == "command":
            doc: object = None
            with contextlib.suppress(ValueError, RecursionError):
                doc = json.loads(raw)  # it parsed once already: within size and depth
            seq = doc.get("seq") if isinstance(doc, dict) else None
            if (
                isinstance(doc, dict)
                and doc.get("v") == PROTOCOL_VERSION
                and isinstance(seq, int)
                and not isinstance(seq, bool)
                and 0 <= seq < 2**53
            ):
                return encode(
                    CommandAck(
                        seq=seq,
                        stage=CommandStage.REJECTED,
                        reason=RejectReason.MALFORMED,
                        detail=reason[:300],
                        onboard_time_ns=self.vehicle.onboard_time_ns,
                    )
                )
        return encode(ErrorMsg(reason=reason[:500], ref_type=exc.ref_type))

    async def _receiver(self, ws: ClientConnection) -> None:
        contact = self.config.contact
        async for raw in ws:
            now = self.onboard_s()
            if contact is not None and not contact.is_up(now) and self._is_command(raw):
                self.commands_outside_window += 1
                if self._truth is not None:
                    self._truth.write([{"event": "command_outside_window", "onboard_s": now}])
            deliver = self.uplink.send(now, len(raw))
            if deliver is not None:
                heapq.heappush(self._incoming, (deliver, next(self._counter), raw))

    @staticmethod
    def _is_command(raw: str | bytes) -> bool:
        try:
            return isinstance(decode_ground(raw), JointCommandMsg | AcsCommandMsg)
        except WireError:
            return False

    # -- the onboard loop ----------------------------------------------------------------

    def _advance(self, onboard_s: float) -> None:
        acks, frames = self.vehicle.advance_to(self.onboard_ns(onboard_s))
        for report in self.vehicle.take_safing_reports():
            if self._connected.is_set():  # else: a new connection gets the state after hello
                self._send(encode(report))
        for ack in acks:
            self._send(encode(ack))
        self.store.add(frames)
        self._log_truth()

    def _log_truth(self) -> None:
        events = self.vehicle.take_truth_events()
        if self._truth is not None and events:
            self._truth.write(events)

    def _flush_telemetry(self, now_s: float) -> None:
        if not self._connected.is_set():
            return
        for frames, retransmission in self.store.due(now_s):
            self._send(encode(TelemetryMsg(frames=frames, retransmission=retransmission)))

    def _deliver_due(self, now: float) -> None:
        """Hand the vehicle every uplinked message delivered by ``now`` (onboard s), each at
        its delivery instant."""
        while self._incoming and self._incoming[0][0] <= now:
            deliver, _, raw = heapq.heappop(self._incoming)
            contact = self.config.contact
            if contact is not None and not contact.is_up(deliver) and self._is_command(raw):
                self.commands_delivered_outside_window += 1
            if not self._stopping:
                self._advance(deliver)
            self.vehicle.heard_from_ground()
            try:
                self._handle(raw)
            except Exception:  # one message went wrong: the vehicle and link carry on
                log.exception("handling a message from the ground failed")

    async def _fast_forward(self, stop: asyncio.Event, now: float) -> None:
        """Fly from ``now`` (no window open) to the next acquisition of signal as fast as the
        simulation computes (at most ``fast_scale``), in chunks, then run on at
        ``time_scale``. Nothing crosses the link meanwhile; telemetry made is stored."""
        contact = self.config.contact
        assert contact is not None
        aos = contact.next_start_s(now)
        if aos is None:
            return  # no window ahead: the clock runs on at its pass speed
        self.fast_forwards += 1
        await self._lose_signal()  # if the closer has not run yet (a loaded loop)
        log.info("no window until onboard %.1f s: flying the gap fast", aos)
        wall0, h0 = time.monotonic(), self.vehicle.wheel_momentum_nms().tolist()
        fast = self.config.fast_scale
        t = now
        self._anchor(t, 0.0)  # the clock follows the vehicle, step by step
        try:
            while t < aos and not stop.is_set():
                began = time.monotonic()
                t = min(aos, t + FAST_CHUNK_S)
                self._deliver_due(t)
                self._advance(t)
                self._anchor(t, 0.0)
                spent = time.monotonic() - began
                pause = 0.0 if fast is None else max(0.0, FAST_CHUNK_S / fast - spent)
                await asyncio.sleep(pause)  # the loop's other tasks run between chunks
        finally:
            self._anchor(t, self.config.time_scale)
        log.info("acquisition of signal at onboard %.1f s", self.onboard_s())
        if self._truth is not None:
            self._truth.write(
                [
                    {
                        "event": "gap",
                        "from_s": round(now, 6),
                        "to_s": round(t, 6),
                        "wall_s": round(time.monotonic() - wall0, 3),
                        "wheel_momentum_from_nms": h0,
                        "wheel_momentum_to_nms": self.vehicle.wheel_momentum_nms().tolist(),
                    }
                ]
            )

    async def _onboard(self, stop: asyncio.Event) -> None:
        tick_s = self.config.vehicle.telemetry_period_s / 2
        contact = self.config.contact
        while True:
            now = self.onboard_s()
            if (
                contact is not None
                and not self._stopping
                and not stop.is_set()
                and not contact.is_up(now)
                and contact.next_start_s(now) is not None
            ):
                await self._fast_forward(stop, now)
                continue
            self._deliver_due(now)
            if stop.is_set() and not self._stopping:
                self._stopping = True
                log.info("stopping: draining %d unacknowledged frames", self.store.unacked)
            if not self._stopping:
                self._advance(now)
            self._flush_telemetry(now)
            if self._stopping and self.store.unacked == 0:
                return
            await asyncio.sleep(tick_s / self.config.time_scale)

    # -- connection ----------------------------------------------------------------------

    async def _connection(self, stop: asyncio.Event) -> None:
        delay = self.config.backoff_initial_s
        rng = random.Random(self.config.seed)
        urls = list(self.config.ground_urls)
        tried = 0  # grounds tried since the last backoff
        while not stop.is_set() or self._stopping:
            if not await self._window_open(stop):
                return
            url = urls[0]
            try:
                async with connect(
                    url,
                    additional_headers={"Authorization": f"Bearer {self.config.token}"},
                    max_size=SOCKET_MAX_BYTES,
                    proxy=None,
                    open_timeout=5,
                ) as ws:
                    self._ws = ws
                    self.connections += 1
                    delay = self.config.backoff_initial_s
                    now = self.onboard_s()
                    if not self._stopping:
                        # up to now before hello: a periodic report due while the link was
                        # down is not sent; the report of the state now follows hello
                        self._deliver_due(now)
                        self._advance(now)
                    hello = Hello(
                        vehicle=self.config.vehicle.vehicle_name,
                        onboard_time_ns=self.onboard_ns(now),
                        time_scale=self.config.time_scale,
                        next_telemetry_seq=self.vehicle.next_telemetry_seq,
                        last_command_seq=self.vehicle.last_command_seq,
                        schedule_capacity=self.config.vehicle.schedule_capacity,
                        los_policy=self.config.vehicle.los_policy,
                        los_hold_after_s=self.config.vehicle.los_hold_after_s,
                        robot=self.config.vehicle.robot,
                        robot_hash=self.config.vehicle.robot_hash,
                        n_joints=self._announced_joints(),
                    )
                    await ws.send(encode(hello))
                    self._connected.set()
                    backlog, self._outbox = self._outbox, []
                    for text in backlog:
                        self._send(text)
                    report = self.vehicle.safing_report()
                    if report is not None:  # a safe vehicle says so at once
                        self._send(encode(report))
                    log.info("connected to %s", url)
                    los = asyncio.create_task(self._close_at_los(ws), name="los")
                    try:
                        await self._receiver(ws)
                    finally:
                        los.cancel()
            except (OSError, ConnectionClosed, InvalidHandshake, InvalidURI, TimeoutError) as exc:
                log.warning("link to ground %s down: %s", url, exc)
            finally:
                was_connected = self._connected.is_set()
                self._connected.clear()
                self._ws = None
                if was_connected:
                    # In the relay when the link went: lost. The vehicle carries on with its
                    # schedule; its LOS policy alone decides whether the arm holds.
                    self._outgoing.clear()
            if stop.is_set() and not self._stopping:
                return
            urls.append(urls.pop(0))  # the next ground; this one again last
            tried += 1
            if tried < len(urls):
                continue
            tried = 0
            await asyncio.sleep(delay * (0.5 + rng.random()))
            delay = min(delay * 2.0, self.config.backoff_max_s)

    async def _window_open(self, stop: asyncio.Event) -> bool:
        """Wait, with a contact plan, until a window is open (True), or the process stops
        before one opens (False: stop set and not draining, or no window ahead)."""
        contact = self.config.contact
        if contact is None:
            return True
        while not contact.is_up(self.onboard_s()):
            if (stop.is_set() and not self._stopping) or (
                contact.next_start_s(self.onboard_s()) is None
            ):
                return False
            await asyncio.sleep(0.01)
        return True

    async def _close_at_los(self, ws: ClientConnection) -> None:
        """Close the socket at the loss of signal of the window it was opened in."""
        contact = self.config.contact
        if contact is None:
            return
        end = contact.end_of_contact_s(self.onboard_s())
        if end is None:
            end = self.onboard_s()
        while self.onboard_s() < end:
            await asyncio.sleep(min(0.05, self._wall_delay(end)))
        await self._lose_signal()

    async def _lose_signal(self) -> None:
        """Close the socket (if open): the window is over."""
        ws = self._ws
        if ws is None:
            return
        log.info("loss of signal at onboard %.1f s", self.onboard_s())
        with contextlib.suppress(ConnectionClosed):
            await ws.close(1001, "loss of signal")

    def _announced_joints(self) -> int | None:
        """``hello``'s joint count: with the robot of a description only (a ``hello`` without
        robot fields means ETS-VII, 6 joints, to the ground)."""
        vehicle = self.config.vehicle
        return None if vehicle.robot is None else vehicle.model.n_joints

    def _open_truth_log(self) -> None:
        path = self.config.truth_log
        if path is None:
            return
        self._truth = TruthLog(path)
        vehicle = self.config.vehicle
        self._truth.write(
            [
                {
                    "event": "start",
                    "onboard_time_ns": self.epoch_ns,
                    "vehicle": vehicle.vehicle_name,
                    "robot": vehicle.robot,
                    "faults": [fault.spec for fault in vehicle.faults],
                    "safing": vehicle.safing,
                }
            ]
        )

    def _link_record(self) -> dict[str, object]:
        """The truth log's last record: what crossed the link, and what reached the
        spacecraft's socket outside a window (with a contact plan; 0 without)."""
        up, down = self.uplink.stats, self.downlink_link.stats
        return {
            "event": "link",
            "onboard_s": round(self.onboard_s(), 6),
            "uplink": {
                "sent": up.sent,
                "delivered": up.delivered,
                "dropped_loss": up.dropped_loss,
                "dropped_outage": up.dropped_outage,
            },
            "downlink": {
                "sent": down.sent,
                "delivered": down.delivered,
                "dropped_loss": down.dropped_loss,
                "dropped_outage": down.dropped_outage,
            },
            "commands_outside_window": self.commands_outside_window,
            "commands_delivered_outside_window": self.commands_delivered_outside_window,
            "gaps_flown_fast": self.fast_forwards,
            "connections": self.connections,
        }

    async def run(self, stop: asyncio.Event) -> None:
        """Run until ``stop`` is set and the telemetry is drained (or the drain times out)."""
        self._open_truth_log()
        tasks = [
            asyncio.create_task(self._sender(), name="sender"),
            asyncio.create_task(self._connection(stop), name="connection"),
            asyncio.create_task(self._noise(), name="noise"),
        ]
        onboard = asyncio.create_task(self._onboard(stop), name="onboard")
        try:
            await stop.wait()
            try:
                await asyncio.wait_for(asyncio.shield(onboard), self.config.drain_timeout_s)
            except TimeoutError:
                log.error("drain timed out with %d frames unacknowledged", self.store.unacked)
        finally:
            for task in [*tasks, onboard]:
                task.cancel()
            for task in [*tasks, onboard]:
                with contextlib.suppress(asyncio.CancelledError):
                    await task
            if self._ws is not None:
                await self._ws.close()
            if self._truth is not None:
                self._log_truth()
                self._truth.write([self._link_record()])
                self._truth.close()
