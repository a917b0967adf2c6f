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
- **Connection** (:class:`spacecraft.process_connection.ProcessConnection`, every task
  that reads or writes the socket): reconnects after any drop, trying its grounds in order,
  and sends ``hello``; malformed messages beside the real traffic (``garbage``).
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
import time
from dataclasses import replace

from websockets.asyncio.client import ClientConnection

from spacecraft.downlink import Downlink
from spacecraft.garbage import GarbageMaker
from spacecraft.link import LinkEmulator, Outage
from spacecraft.process_config import ProcessConfig
from spacecraft.process_connection import SOCKET_MAX_BYTES, ProcessConnection
from spacecraft.truth import TruthLog
from spacecraft.vehicle import Vehicle
from telemetry.wire import (
    PROTOCOL_VERSION,
    AcsCommandMsg,
    CommandAck,
    CommandQuery,
    CommandStage,
    CommandUnknown,
    ErrorMsg,
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

__all__ = ["SOCKET_MAX_BYTES", "ProcessConfig", "SpacecraftProcess"]

log = logging.getLogger("hikoboshi.spacecraft")

#: FAST mode flies a gap in steps this long (onboard s; about 50 ms of computing each).
FAST_CHUNK_S = 5.0


class SpacecraftProcess(ProcessConnection):
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

    # -- truth log and run ---------------------------------------------------------------

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
