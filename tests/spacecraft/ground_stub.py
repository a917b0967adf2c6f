"""A minimal ground station for the spacecraft's tests: a real websocket server on loopback.

It checks the token, learns the onboard clock from ``hello``, sends commands (and any other
message) when told to, stores telemetry deduplicated by sequence number (counting
duplicates), acknowledges cumulatively with the ranges it holds beyond, and asks for the gaps
it sees. It speaks the protocol version of :mod:`telemetry.wire` (2); it does not retransmit
commands by itself (a test sends copies when it wants them).
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from websockets.asyncio.server import ServerConnection, serve
from websockets.http11 import Request, Response

from spacecraft.link import LinkConfig
from spacecraft.process import ProcessConfig, SpacecraftProcess
from spacecraft.vehicle_config import VehicleConfig
from telemetry.wire import (
    CommandAck,
    ErrorMsg,
    Hello,
    Retransmit,
    TelemetryAck,
    TelemetryFrame,
    TelemetryMsg,
    Verification,
    decode_spacecraft,
    encode,
)

TOKEN = "test-spacecraft-token"


def ranges_of(seqs: set[int]) -> list[tuple[int, int]]:
    out: list[tuple[int, int]] = []
    for s in sorted(seqs):
        if out and s == out[-1][1] + 1:
            out[-1] = (out[-1][0], s)
        else:
            out.append((s, s))
    return out


@dataclass
class GroundStub:
    frames: dict[int, TelemetryFrame] = field(default_factory=dict)
    duplicates: int = 0
    acks: list[CommandAck] = field(default_factory=list)
    errors: list[ErrorMsg] = field(default_factory=list)
    verifications: list[Verification] = field(default_factory=list)
    hellos: list[Hello] = field(default_factory=list)
    other: list[Any] = field(default_factory=list)
    connection: ServerConnection | None = None
    onboard_ref: tuple[int, float, float] | None = None  # (onboard ns, wall, scale)
    refused: int = 0
    port: int = 0
    _server: Any = None

    async def start(self) -> None:
        def check_token(connection: ServerConnection, request: Request) -> Response | None:
            if request.headers.get("Authorization") != f"Bearer {TOKEN}":
                self.refused += 1
                return connection.respond(401, "bad token\n")
            return None

        self._server = await serve(self._handler, "127.0.0.1", 0, process_request=check_token)
        self.port = self._server.sockets[0].getsockname()[1]

    @property
    def url(self) -> str:
        return f"ws://127.0.0.1:{self.port}/link"

    async def stop(self) -> None:
        self._server.close()
        await self._server.wait_closed()

    def onboard_now_ns(self) -> int:
        assert self.onboard_ref is not None, "no hello yet"
        ns, wall, scale = self.onboard_ref
        return ns + round((time.monotonic() - wall) * scale * 1e9)

    async def send(self, message: Any) -> None:
        assert self.connection is not None
        await self.connection.send(message if isinstance(message, str | bytes) else encode(message))

    async def _handler(self, ws: ServerConnection) -> None:
        self.connection = ws
        with contextlib.suppress(Exception):
            async for raw in ws:
                msg = decode_spacecraft(raw)
                if isinstance(msg, Hello):
                    self.hellos.append(msg)
                    self.onboard_ref = (msg.onboard_time_ns, time.monotonic(), msg.time_scale)
                elif isinstance(msg, TelemetryMsg):
                    for frame in msg.frames:
                        if frame.seq in self.frames:
                            self.duplicates += 1
                        else:
                            self.frames[frame.seq] = frame
                    await self._acknowledge(ws)
                elif isinstance(msg, CommandAck):
                    self.acks.append(msg)
                elif isinstance(msg, ErrorMsg):
                    self.errors.append(msg)
                elif isinstance(msg, Verification):
                    self.verifications.append(msg)
                else:
                    self.other.append(msg)

    async def _acknowledge(self, ws: ServerConnection) -> None:
        seqs = set(self.frames)
        through = -1
        while through + 1 in seqs:
            through += 1
        beyond = {s for s in seqs if s > through}
        await ws.send(encode(TelemetryAck(through_seq=through, ranges=ranges_of(beyond)[:1000])))
        if beyond:
            missing = set(range(through + 1, max(beyond))) - seqs
            if missing:
                await ws.send(encode(Retransmit(ranges=ranges_of(missing)[:1000])))

    async def wait_for(self, predicate: Any, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while not predicate():
            if time.monotonic() > deadline:
                raise TimeoutError("condition not met in time")
            await asyncio.sleep(0.01)


#: The spacecraft processes' time scale in these tests.
SCALE = 20.0


def process_config(
    stub: GroundStub,
    vehicle: VehicleConfig | None = None,
    truth_log: Path | None = None,
    **link: object,
) -> ProcessConfig:
    """A spacecraft process for ``stub`` at SCALE (its link's options ``link``)."""
    return ProcessConfig(
        ground_url=stub.url,
        token=TOKEN,
        time_scale=SCALE,
        vehicle=vehicle or VehicleConfig(),
        uplink=LinkConfig(seed=11, **link),  # type: ignore[arg-type]
        downlink=LinkConfig(seed=12, **link),  # type: ignore[arg-type]
        seed=3,
        backoff_initial_s=0.05,
        backoff_max_s=0.5,
        drain_timeout_s=20.0,
        truth_log=truth_log,
    )


def run_session(
    scenario: Callable[[GroundStub, SpacecraftProcess], Awaitable[None]],
    vehicle: VehicleConfig | None = None,
    truth_log: Path | None = None,
    **link: object,
) -> tuple[GroundStub, SpacecraftProcess]:
    """``scenario(stub, process)`` with a spacecraft process connected to a fresh stub."""

    async def main() -> tuple[GroundStub, SpacecraftProcess]:
        stub = GroundStub()
        await stub.start()
        process = SpacecraftProcess(process_config(stub, vehicle, truth_log, **link))
        stop = asyncio.Event()
        runner = asyncio.create_task(process.run(stop))
        try:
            await stub.wait_for(lambda: stub.hellos, timeout_s=10.0)
            await scenario(stub, process)
        finally:
            stop.set()
            await asyncio.wait_for(runner, timeout=30.0)
            await stub.stop()
        return stub, process

    return asyncio.run(main())
