"""Console push: delivery latency of live telemetry to 100 consoles on real sockets.

The ground service runs under uvicorn on loopback (a thread of this process, on SQLite in a
scratch directory). A stand-in spacecraft connects to ``/api/link`` like the real one and
sends one frame every 0.1 s (10 Hz); the frames go through the real link: stored, then
published. The consoles run in a **separate process** (so their JSON parsing does not share
the server's interpreter lock), each a websocket on ``/api/console`` subscribed to the
pass's telemetry at ``max_rate_hz: 10``.

Latency of a frame to a console: from the moment the publisher hands it out (a hook placed
before the console hub's, ``time.time_ns``) to the moment the console has read it off its
socket (``time.time_ns`` in the other process; one machine, one clock). Also: the
spacecraft's send -> ``telemetry_ack`` round trip, which must not grow with consoles
(ingest is not held up by them).

Runs: a baseline with one console, then 100 consoles, in the same run. Target (console
issue): p99 < 50 ms with 100 consoles.
"""

from __future__ import annotations

import asyncio
import json
import multiprocessing as mp
import socket
import tempfile
import threading
import time
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np
import uvicorn
from _common import emit
from bench_ingest import new_pass
from websockets.asyncio.client import connect

from server.app import create_app
from server.services.link import GroundLink, TelemetryWindow
from server.settings import ApiToken, Role, Settings
from telemetry.layout import DEFAULT_LAYOUT
from telemetry.wire import Hello, TelemetryFrame, TelemetryMsg, encode

TOKENS = {
    "v-token": ApiToken(name="bench-console", role=Role.VIEWER),
    "s-token": ApiToken(name="bench-sc", role=Role.SPACECRAFT),
}
RATE_HZ = 10.0
DURATION_S = 20.0
WARMUP_FRAMES = 10
CONSOLES = 100
T0_NS = 1_000_000_000_000


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def _frame(seq: int, rng: np.random.Generator) -> TelemetryFrame:
    """An ETS-VII frame of random values (a row of its layout read as a wire frame)."""
    v = rng.normal(size=len(DEFAULT_LAYOUT.float_fields)).tolist()
    gen_ns = T0_NS + seq * round(1e9 / RATE_HZ)
    return DEFAULT_LAYOUT.frame((seq, gen_ns, *v, "feedback", False, 0, None, -1, 0))


# --- the consoles (child process) ------------------------------------------------------------


async def _consoles(url: str, pass_id: str, n: int, last_seq: int, ready: Any) -> list[Any]:
    subscribed = 0
    all_ready = asyncio.Event()

    async def one() -> list[tuple[int, int]]:
        nonlocal subscribed
        received: list[tuple[int, int]] = []
        headers = {"Authorization": "Bearer v-token"}  # never ?token=: URLs end up in logs
        async with connect(url, max_size=2**24, open_timeout=30, additional_headers=headers) as ws:
            await ws.recv()  # welcome
            subscribe = {"v": 1, "type": "subscribe", "topic": "telemetry", "pass_id": pass_id}
            await ws.send(json.dumps(subscribe | {"max_rate_hz": RATE_HZ}))
            assert json.loads(await ws.recv())["type"] == "subscribed"
            subscribed += 1
            if subscribed == n:
                all_ready.set()
            while True:
                text = await ws.recv()
                now = time.time_ns()
                message = json.loads(text)
                if message["type"] != "telemetry":
                    continue
                seqs = message["columns"]["seq"]
                received += [(s, now) for s in seqs]
                if seqs[-1] >= last_seq:
                    return received

    tasks = [asyncio.create_task(one()) for _ in range(n)]
    await all_ready.wait()
    ready.set()
    return list(await asyncio.wait_for(asyncio.gather(*tasks), DURATION_S + 60.0))


def _console_process(
    url: str, pass_id: str, n: int, last_seq: int, ready: Any, out: Connection
) -> None:
    out.send(asyncio.run(_consoles(url, pass_id, n, last_seq, ready)))


# --- the ground and the spacecraft (this process) --------------------------------------------


async def _spacecraft(
    ws_url: str, first_seq: int, n_frames: int, acked: dict[int, int], sent: dict[int, int]
) -> None:
    rng = np.random.default_rng(first_seq)
    async with connect(
        f"{ws_url}/api/link", max_size=2**24, additional_headers={"Authorization": "Bearer s-token"}
    ) as ws:
        hello = Hello(
            vehicle="bench",
            onboard_time_ns=T0_NS + first_seq * round(1e9 / RATE_HZ),
            time_scale=1.0,
            next_telemetry_seq=first_seq,
        )
        await ws.send(encode(hello))

        async def read_acks() -> None:
            async for text in ws:
                message = json.loads(text)
                if message["type"] == "telemetry_ack":
                    now = time.time_ns()
                    through = max([message["through_seq"], *(hi for _, hi in message["ranges"])])
                    for seq in list(sent):
                        if seq <= through and seq not in acked:
                            acked[seq] = now

        reader = asyncio.create_task(read_acks())
        start = time.monotonic()
        for k in range(n_frames):
            # Absolute deadlines: the cadence does not drift.
            await asyncio.sleep(max(0.0, start + k / RATE_HZ - time.monotonic()))
            seq = first_seq + k
            sent[seq] = time.time_ns()
            await ws.send(encode(TelemetryMsg(frames=[_frame(seq, rng)])))
        await asyncio.sleep(0.5)
        reader.cancel()


def _percentiles(values_ms: list[float]) -> dict[str, float]:
    a = np.asarray(values_ms)
    return {
        "n": len(values_ms),
        "p50_ms": round(float(np.percentile(a, 50)), 3),
        "p99_ms": round(float(np.percentile(a, 99)), 3),
        "max_ms": round(float(a.max()), 3),
    }


def run(app: Any, base_url: str, n_consoles: int, first_seq: int) -> dict[str, Any]:
    link: GroundLink = app.state.link
    pass_id = new_pass(app.state.sessions, duration_s=DURATION_S, name=f"bench-{time.time_ns()}")
    link.windows.append(TelemetryWindow(pass_id=pass_id, start_ns=0))
    n_frames = round(DURATION_S * RATE_HZ)
    last_seq = first_seq + n_frames - 1
    published: dict[int, int] = {}

    def stamp(pid: str, frames: list[TelemetryFrame], _: int) -> None:
        now = time.time_ns()
        for frame in frames:
            published[frame.seq] = now

    # First in line: stamped before the hub queues the frame for any console.
    link.publisher._frame_subscribers.insert(0, stamp)
    ctx = mp.get_context("spawn")
    ready = ctx.Event()
    receive, send = ctx.Pipe(duplex=False)
    ws_base = base_url.replace("http://", "ws://")
    consoles = ctx.Process(
        target=_console_process,
        args=(f"{ws_base}/api/console", pass_id, n_consoles, last_seq, ready, send),
    )
    consoles.start()
    try:
        assert ready.wait(60.0), "the consoles did not subscribe"
        acked: dict[int, int] = {}
        sent: dict[int, int] = {}
        asyncio.run(_spacecraft(ws_base, first_seq, n_frames, acked, sent))
        received: list[list[tuple[int, int]]] = receive.recv()
    finally:
        consoles.join(timeout=60.0)
        link.publisher._frame_subscribers.remove(stamp)
    latencies_ms = [
        (t_ns - published[seq]) / 1e6
        for per_console in received
        for seq, t_ns in per_console
        if seq >= first_seq + WARMUP_FRAMES
    ]
    delivered = {len({s for s, _ in per_console}) for per_console in received}
    ack_ms = [
        (acked[s] - sent[s]) / 1e6 for s in sent if s in acked and s >= first_seq + WARMUP_FRAMES
    ]
    return {
        "consoles": n_consoles,
        "frames": n_frames,
        "frames_per_console": sorted(delivered),
        "publish_to_console": _percentiles(latencies_ms),
        "spacecraft_send_to_ack": _percentiles(ack_ms),
    }


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        # Every console here is one token's, from one address: the caps admit them all.
        caps = {"consoles_per_token": CONSOLES + 1, "consoles_per_address": CONSOLES + 1}
        app = create_app(Settings(data_dir=Path(tmp), tokens=TOKENS, **caps))
        port = _free_port()
        config = uvicorn.Config(
            app, host="127.0.0.1", port=port, log_level="warning", ws_max_size=2**24
        )
        server = uvicorn.Server(config)
        thread = threading.Thread(target=server.run, name="uvicorn", daemon=True)
        thread.start()
        while not server.started:
            time.sleep(0.01)
        base = f"http://127.0.0.1:{port}"
        try:
            n = round(DURATION_S * RATE_HZ)
            baseline = run(app, base, 1, first_seq=0)
            loaded = run(app, base, CONSOLES, first_seq=n)
        finally:
            server.should_exit = True
            thread.join(timeout=30.0)
    p99 = loaded["publish_to_console"]["p99_ms"]
    emit(
        "console",
        {
            "rate_hz": RATE_HZ,
            "duration_s": DURATION_S,
            "baseline_1_console": baseline,
            f"loaded_{CONSOLES}_consoles": loaded,
            "p99_ratio_loaded_to_baseline": round(
                p99 / baseline["publish_to_console"]["p99_ms"], 2
            ),
        },
        {
            "p99_under_50_ms_with_100_consoles": p99 < 50.0,
            "every_console_got_every_frame": loaded["frames_per_console"] == [loaded["frames"]],
        },
    )


if __name__ == "__main__":
    main()
