"""A slow console beside fast ones, on real sockets: how soon it knows it is behind and sees
the abort (docs/console.md, "A console behind").

The ground service runs under uvicorn on loopback (a thread of this process, SQLite in a
scratch directory). Four consoles connect to ``/api/console`` (websockets, this process's
main loop) and subscribe to ``commands``, ``passes`` and ``events``: three read everything,
one reads 20 messages a second. In the server's loop, the publisher hands out command-stage
events at 1000/s for 8 s (as the link does after its commits), and a pass's abort
(``pass_state`` to ``aborted``) halfway.

Figures: for the slow console, the time from the burst's start to its first ``lag`` with
``behind_s > 0``, from the abort's publication to its arrival, its resyncs and whether it
was dropped; the same abort delay for a fast console of the same run (the baseline), and
their ratio. What the socket itself buffers (the server's transport, the kernel's buffers,
the client library's queue) is not in the server's queues: it is what the abort's delay
measures beyond the hub's.
"""

from __future__ import annotations

import asyncio
import json
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import uvicorn
from _common import emit, free_port
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

from server.app import create_app
from server.services.console import ConsoleHub
from server.services.dbworker import Publisher
from server.settings import ApiToken, Role, Settings
from tests.support.console import stage_event

TOKENS = {"v-token": ApiToken(name="bench-console", role=Role.VIEWER)}
BURST_HZ, BURST_S, SLOW_HZ = 1000, 8.0, 20.0
TOPICS = ("commands", "passes", "events")
PASS = "7d3c0000-0000-4000-8000-000000000001"
#: Whether the consoles acknowledge what they read (``--no-ack``: as a console without it).
ACK = "--no-ack" not in sys.argv
ACK_EVERY_S = 0.25


async def _burst(publisher: Publisher, marks: dict[str, float]) -> int:
    """In the server's loop: the events at BURST_HZ, the abort halfway; how many."""
    start = marks["start"] = time.monotonic()
    n = 0
    while (elapsed := time.monotonic() - start) < BURST_S:
        while n < int(elapsed * BURST_HZ):
            n += 1
            publisher.publish([stage_event(n, PASS)])
        if "abort" not in marks and elapsed >= BURST_S / 2:
            detail = {"from": "running", "to": "aborted", "reason": "operator abort"}
            publisher.publish(
                [
                    {
                        "kind": "pass_state",
                        "actor": "otto",
                        "detail": detail,
                        "pass_id": PASS,
                        "time_ns": n,
                    }
                ]
            )
            marks["abort"] = time.monotonic()
        await asyncio.sleep(0.01)
    return n


async def _console_or_closed(
    url: str, period_s: float, ready: asyncio.Event, out: dict[str, Any], stop: asyncio.Event
) -> None:
    try:
        await _console(url, period_s, ready, out, stop)
    except ConnectionClosed as exc:
        out["closed"] = f"{exc!r} after {out.get('messages')} messages"


async def _console(
    url: str, period_s: float, ready: asyncio.Event, out: dict[str, Any], stop: asyncio.Event
) -> None:
    headers = {"Authorization": "Bearer v-token"}
    # no keepalive pings (a browser sends none): a pong queued behind unread data is late
    async with connect(url, additional_headers=headers, max_size=2**24, ping_interval=None) as ws:
        if ACK:  # from the start: nothing is sent it has not room for
            await ws.send(json.dumps({"v": 1, "type": "ack", "received": 0}))
        for topic in TOPICS:
            await ws.send(json.dumps({"v": 1, "type": "subscribe", "topic": topic}))
        subscribed = 0
        acked_at, acked = time.monotonic(), 0
        out.update(lag_at=None, abort_at=None, resyncs=0, dropped=[], messages=0, caught_up_at=None)
        while not stop.is_set():
            now = time.monotonic()
            if ACK and now - acked_at >= ACK_EVERY_S and out["messages"] > acked:
                # what it has read, on a timer of its own (as the web console)
                acked, acked_at = out["messages"], now
                await ws.send(json.dumps({"v": 1, "type": "ack", "received": acked}))
            try:
                raw = await asyncio.wait_for(ws.recv(), ACK_EVERY_S)
            except TimeoutError:
                continue
            now = time.monotonic()
            m = json.loads(raw)
            out["messages"] += 1
            kind = m["type"]
            if kind == "subscribed":
                subscribed += 1
                if subscribed == len(TOPICS):
                    ready.set()
            if kind == "lag":
                out.setdefault("lags", []).append((round(now, 2), m["behind_s"], m["queued"]))
            if kind == "lag" and m["behind_s"] > 0 and out["lag_at"] is None:
                out["lag_at"] = now
            elif kind == "lag" and m["behind_s"] == 0 and out["abort_at"] is not None:
                out["caught_up_at"] = now
            elif kind == "resync":
                out["resyncs"] += 1
            elif kind in ("unsubscribed", "error"):
                out["dropped"].append(m)
            elif kind == "event" and m["event"]["kind"] == "pass_state":
                out["abort_at"] = out["abort_at"] or now
            if period_s:
                await asyncio.sleep(period_s)


async def _run(app: Any, url: str) -> dict[str, Any]:
    hub: ConsoleHub = app.state.console
    assert hub._lag_watch is not None
    server_loop = hub._lag_watch.get_loop()
    stop = asyncio.Event()
    outs: list[dict[str, Any]] = [{} for _ in range(4)]
    readies = [asyncio.Event() for _ in outs]
    periods = [1 / SLOW_HZ, 0.0, 0.0, 0.0]
    tasks = [
        asyncio.create_task(_console_or_closed(url, p, r, o, stop))
        for p, r, o in zip(periods, readies, outs, strict=True)
    ]
    for ready in readies:
        await asyncio.wait_for(ready.wait(), 30.0)
    marks: dict[str, float] = {}
    burst = asyncio.run_coroutine_threadsafe(_burst(app.state.publisher, marks), server_loop)
    published = await asyncio.wrap_future(burst)
    deadline = time.monotonic() + 60.0
    while (
        outs[0]["caught_up_at"] is None and "closed" not in outs[0] and time.monotonic() < deadline
    ):
        await asyncio.sleep(0.1)
    clients = hub.clients
    stop.set()
    await asyncio.gather(*tasks)
    slow, fast = outs[0], outs[1]

    def since(at: float | None, mark: str) -> float | None:
        return None if at is None else round(at - marks[mark], 3)

    return {
        "published": published,
        "clients_at_end": clients,
        "slow_lag_shown_s": since(slow["lag_at"], "start"),
        "slow_abort_seen_s": since(slow["abort_at"], "abort"),
        "fast_abort_seen_s": since(fast["abort_at"], "abort"),
        "slow_caught_up_s": since(slow["caught_up_at"], "abort"),
        "slow_resyncs": slow["resyncs"],
        "slow_dropped": slow["dropped"][:3] + ([slow["closed"]] if "closed" in slow else []),
        "fast_closed": [o["closed"] for o in outs[1:] if "closed" in o],
        "slow_messages": slow["messages"],
        "slow_lags": [(round(t - marks["start"], 2), b, q) for t, b, q in slow.get("lags", [])][
            :12
        ],
        "fast_messages": fast["messages"],
        "fast_resyncs": fast["resyncs"],
    }


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        app = create_app(Settings(data_dir=Path(tmp), tokens=TOKENS))
        port = free_port()
        config = uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning")
        server = uvicorn.Server(config)
        thread = threading.Thread(target=server.run, name="uvicorn", daemon=True)
        thread.start()
        while not server.started:
            time.sleep(0.01)
        try:
            figures = asyncio.run(_run(app, f"ws://127.0.0.1:{port}/api/console"))
        finally:
            server.should_exit = True
            thread.join(timeout=30.0)
    slow_abort, fast_abort = figures["slow_abort_seen_s"], figures["fast_abort_seen_s"]
    figures["abort_ratio_slow_to_fast"] = (
        round(slow_abort / fast_abort, 1) if slow_abort and fast_abort else None
    )
    figures["consoles_acknowledge"] = ACK
    lag = figures["slow_lag_shown_s"]
    emit(
        "console_lag",
        figures,
        {
            "lag_shown_within_2_s": lag is not None and lag < 2.0,
            "abort_seen_within_5_s": slow_abort is not None and slow_abort < 5.0,
            "slow_console_not_dropped": not figures["slow_dropped"]
            and figures["clients_at_end"] == 4,
        },
    )


if __name__ == "__main__":
    main()
