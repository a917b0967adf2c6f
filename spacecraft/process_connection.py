"""The spacecraft process's connection (:class:`ProcessConnection`, a part of
:class:`spacecraft.process.SpacecraftProcess`): every task that reads or writes the
websocket, and the list of grounds it tries.

- **Connection**: reconnects after any drop with exponential backoff, trying its grounds in
  order (``ground_url``, then each of ``standby_urls``; the ground it was connected to is
  tried again last): a standby refuses the handshake (503: another ground holds the command
  lease, docs/operations.md "One ground in command"; a holder that loses it closes with
  1013) and the next one is tried at once; the backoff grows only once every ground has
  been tried. A drop changes nothing on board: the loaded schedule keeps executing, and
  only the vehicle's LOS policy (silence for ``los_hold_after_s`` with ``hold``) refuses
  queued joint commands. ``hello`` is the session handshake, announces the schedule's
  capacity, the LOS policy and (when the vehicle flies a robot description, ``hikoboshi
  spacecraft --robot``) the robot's name, the hash of its description and its joint count,
  and goes straight to the ground.
- **Noise** (``garbage``, ``hikoboshi spacecraft --garbage``): while connected and the
  onboard clock is inside a window, malformed messages (:mod:`spacecraft.garbage`) go
  straight onto the socket at the window's rate per wall second, beside the real traffic
  (a rehearsal of a noisy link; docs/protocol.md "Malformed messages"). The ground closes a
  connection that sends too many; the process reconnects as after any drop.
- **Contact plan**: with one, the process connects only inside a window (acquisition of
  signal) and closes its socket at the window's loss (:mod:`spacecraft.contact`).
- **The socket's two directions**: what the ground sends is read and handed to the uplink
  emulator (the process delivers it to the vehicle at its delivery instant); what the
  downlink emulator delivers is written to the socket then, and lost with the connection.
"""

from __future__ import annotations

import asyncio
import contextlib
import heapq
import itertools
import logging
import random
import time
from typing import TYPE_CHECKING

from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidURI

from spacecraft.garbage import GarbageMaker
from spacecraft.link import LinkEmulator
from spacecraft.process_config import ProcessConfig
from spacecraft.vehicle import Vehicle
from telemetry.wire import AcsCommandMsg, Hello, JointCommandMsg, WireError, decode_ground, encode

if TYPE_CHECKING:
    from spacecraft.truth import TruthLog

__all__ = ["SOCKET_MAX_BYTES", "ProcessConnection"]

log = logging.getLogger("hikoboshi.spacecraft")

#: Frames larger than this close the socket (the library's guard); smaller ones that are
#: still over the protocol's limit get an ``error`` reply.
SOCKET_MAX_BYTES = 4 * 1024 * 1024


class ProcessConnection:
    """The socket's tasks (see the module docstring), over the process's state, which
    :class:`~spacecraft.process.SpacecraftProcess`'s constructor sets, and its clock and
    onboard steps."""

    config: ProcessConfig
    vehicle: Vehicle
    uplink: LinkEmulator
    garbage: GarbageMaker
    garbage_sent: int
    connections: int
    commands_outside_window: int
    _ws: ClientConnection | None
    _connected: asyncio.Event
    _incoming: list[tuple[float, int, str | bytes]]
    _outgoing: list[tuple[float, int, str]]
    _counter: itertools.count[int]
    _outbox: list[str]
    _stopping: bool
    _truth: TruthLog | None

    def onboard_s(self) -> float:
        raise NotImplementedError

    def onboard_ns(self, onboard_s: float) -> int:
        raise NotImplementedError

    def _wall_delay(self, onboard_s: float) -> float:
        raise NotImplementedError

    def _send(self, text: str) -> None:
        raise NotImplementedError

    def _advance(self, onboard_s: float) -> None:
        raise NotImplementedError

    def _deliver_due(self, now: float) -> None:
        raise NotImplementedError

    # -- the grounds, in turn ------------------------------------------------------------

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

    # -- the socket's two directions, and the noise ---------------------------------------

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
