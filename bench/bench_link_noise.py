"""A noisy link: what a flood of malformed messages costs the link's real traffic.

The ground's live path (``build_live_path``: the link, its database worker on SQLite in a
temporary directory, the system clock) reads one socket's worth of messages in order, as
``server/api/link.py`` does: 400 malformed messages a second (``spacecraft/garbage.py``'s
mix) with a ``command_ack`` every 50 ms between them, for ``SECONDS`` s, while a 4 Hz task
stands in for the uplink's sends (it sleeps to each 250 ms deadline on the same loop).

Figures, each against a baseline in the same process:

- ``ack_delay_ms``: from an ack's arrival (its place in the stream) until the link has
  handled it, p50 / p99 / max; baseline: the same stream without the garbage.
- ``tick_late_ms``: how late the 4 Hz task wakes, p99 / max; baseline: without garbage.
- ``malformed_us`` / ``ack_us``: the link's own time per malformed message and per ack.
- ``per_message_audit``: the same flood handled as main did before (an ``error`` reply
  and an audit row written and waited for, per message): its ack delays, for the ratio.

Run: ``PYTHONPATH=. .venv/bin/python bench/bench_link_noise.py``. Target: the acks'
p99 delay under the flood within 10 ms of the baseline's, the ticker's p99 lateness under
20 ms.
"""

from __future__ import annotations

import asyncio
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from _common import emit

from server.app import build_live_path
from server.services.clock import SystemClock
from server.services.events import LinkErrorReplied, event_job
from server.services.link import Connection, GroundLink
from server.settings import Settings
from server.storage.db import make_engine, session_factory, sqlite_url, upgrade
from spacecraft.garbage import GarbageMaker
from telemetry.wire import CommandAck, CommandStage, ErrorMsg, Hello, WireError, encode

SECONDS = 5.0
RATE = 400.0
ACK_PERIOD_S = 0.05
HELLO = Hello(vehicle="ETS-VII", onboard_time_ns=10**18, time_scale=20.0, next_telemetry_seq=0)


async def _old_refuse(link: GroundLink, conn: Connection, exc: WireError, received: float) -> None:
    """The per-message handling main had: a reply and an audit row, waited for."""
    reason = str(exc)[:500]
    await link.send(encode(ErrorMsg(reason=reason, ref_type=exc.ref_type)))
    replied = LinkErrorReplied(actor=conn.actor, reason=reason, ref_type=exc.ref_type)
    await link._db.write(event_job(replied, link.clock))


def _pct(values: list[float], q: float) -> float:
    if not values:
        return 0.0
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(q * (len(ordered) - 1)))]


async def _run(tmp: Path, garbage: bool, old: bool) -> dict[str, Any]:
    engine = make_engine(sqlite_url(tmp))
    upgrade(engine)
    clock = SystemClock()
    live = build_live_path(
        sessions=session_factory(engine),
        settings=Settings(data_dir=tmp, malformed_unusable_after=10**9),
        clock=clock,
    )
    link = live.link
    if old:
        link._refuse = lambda conn, exc, received: _old_refuse(link, conn, exc, received)  # type: ignore[method-assign]

    async def send_text(text: str) -> None:
        await asyncio.sleep(0)

    async def close(code: int, reason: str) -> None:
        return None

    conn = Connection(actor="ets7", send_text=send_text, close=close)
    await link.attach(conn)
    await link.handle(conn, encode(HELLO))
    maker = GarbageMaker(seed=7)
    # the socket's stream: (arrival, text, is_ack)
    stream: list[tuple[float, str, bool]] = []
    if garbage:
        stream += [(i / RATE, maker.next(), False) for i in range(int(SECONDS * RATE))]
    for i in range(int(SECONDS / ACK_PERIOD_S)):
        ack = CommandAck(seq=i, stage=CommandStage.RECEIVED, onboard_time_ns=10**18 + i)
        stream.append((i * ACK_PERIOD_S + 1e-4, encode(ack), True))
    stream.sort(key=lambda item: item[0])
    queue: asyncio.Queue[tuple[float, str, bool]] = asyncio.Queue()
    ticks: list[float] = []
    ack_delays: list[float] = []
    t0 = time.monotonic()

    async def feed() -> None:
        for at, text, is_ack in stream:
            delay = t0 + at - time.monotonic()
            if delay > 0:
                await asyncio.sleep(delay)
            queue.put_nowait((t0 + at, text, is_ack))
        queue.put_nowait((0.0, "", True))

    async def read() -> None:
        while True:
            at, text, is_ack = await queue.get()
            if not text:
                return
            await link.handle(conn, text, clock.monotonic())
            if is_ack:
                ack_delays.append(time.monotonic() - at)

    async def tick() -> None:
        deadline = time.monotonic()
        while deadline < t0 + SECONDS:
            deadline += 0.25
            await clock.sleep_until(deadline)
            ticks.append(time.monotonic() - deadline)

    await asyncio.gather(feed(), read(), tick())
    # the link's own time per message, nothing else running: the best of 5 rounds of 400
    cost = {}
    for name, texts in (
        ("malformed_us", [maker.next() for _ in range(400)]),
        (
            "ack_us",
            [encode(CommandAck(seq=9, stage=CommandStage.EXECUTED, onboard_time_ns=10**18))] * 400,
        ),
    ):
        best = float("inf")
        for _ in range(5):
            await live.db.drain()
            start = time.perf_counter()
            for text in texts:
                await link.handle(conn, text, clock.monotonic())
            best = min(best, (time.perf_counter() - start) / len(texts))
        cost[name] = round(best * 1e6, 1)
    await live.db.drain()
    await live.close()
    engine.dispose()
    return {
        "ack_delay_ms": {
            "p50": round(statistics.median(ack_delays) * 1e3, 2),
            "p99": round(_pct(ack_delays, 0.99) * 1e3, 2),
            "max": round(max(ack_delays) * 1e3, 2),
        },
        "tick_late_ms": {
            "p99": round(_pct(ticks, 0.99) * 1e3, 2),
            "max": round(max(ticks) * 1e3, 2),
        },
        **cost,
    }


def main() -> None:
    figures: dict[str, Any] = {"seconds": SECONDS, "rate_per_s": RATE}
    for name, garbage, old in (
        ("baseline", False, False),
        ("flood", True, False),
        ("per_message_audit", True, True),
    ):
        with tempfile.TemporaryDirectory() as tmp:
            figures[name] = asyncio.run(_run(Path(tmp), garbage, old))
    base, flood = figures["baseline"], figures["flood"]
    figures["ack_p99_over_baseline_ms"] = round(
        flood["ack_delay_ms"]["p99"] - base["ack_delay_ms"]["p99"], 2
    )
    old_p99 = figures["per_message_audit"]["ack_delay_ms"]["p99"]
    figures["per_message_audit_ack_p99_over_flood"] = round(
        old_p99 / max(flood["ack_delay_ms"]["p99"], 1e-3), 1
    )
    emit(
        "link_noise",
        figures,
        {
            "acks_p99_within_10_ms_of_baseline": figures["ack_p99_over_baseline_ms"] <= 10.0,
            "uplink_tick_p99_under_20_ms": flood["tick_late_ms"]["p99"] < 20.0,
        },
    )


if __name__ == "__main__":
    sys.exit(main())
