"""Operators' control under viewer load (#29): what an operator's screen and the link
measure during a live pass with no load, then with 200 concurrent viewer reads, in the same
run on one server.

The scenario is ``tests/server/link/test_load.py``'s (tests/server/link/load.py):
``hikoboshi serve`` and ``hikoboshi spacecraft`` (``--scale``, 20x) as processes of their
own; the demo pass imported and analysed for the viewers to read. Each phase flies a pass
to ``complete`` (10 s of motion, 230 s holding) and aborts a second once 12 commands
executed, while liveness and the link status are sampled every 0.25 s and an operator's
console (opened in the phase) pings twice a second. The loaded phase adds ``--tokens`` x
``--clients`` viewers (20 x 10) looping over the pass's recording, report (JSON and HTML),
analyses and raw telemetry, waiting out 429 and 503 for their ``Retry-After``, in a
process of their own (so that the probes time the server, not a client process starved by
200 others).

Figures per phase: health p50 and p99, link status p99, the abort's answer, console ping
p99 (and its handshake), the ground's worst lag behind the vehicle (the link status's
``frames_behind``, and in wall seconds at the measured frame rate), the viewers' answers;
and the ratios loaded / idle. Targets (the issue's): under load, health p99 and the abort
under 1 s, ingest never more than 2 s behind.

    .venv/bin/python bench/bench_load.py [--database-url postgresql://...] [--tokens 20]
        [--clients 10] [--scale 20]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import statistics
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import httpx
from _common import demo_mcap, emit, serve_process
from sqlalchemy.orm import Session, sessionmaker

from server.settings import Settings
from server.storage.db import make_engine, read_session_factory, session_factory
from tests.server.link.load import (
    OPERATOR_LIMITS,
    Probes,
    ViewerLoad,
    abort_mid_pass,
    fly,
    peak_rss_bytes,
    percentile,
    spacecraft_process,
    viewer_process,
)

OPERATOR_TOKEN = "bench-operator-token-0123456789"
SPACECRAFT_TOKEN = "bench-spacecraft-token-0123456"


async def _phase(
    name: str,
    base: str,
    sessions: sessionmaker[Session],
    readers: sessionmaker[Session],
    load: ViewerLoad | None,
) -> dict[str, Any]:
    """Fly a pass and abort another with the probes on (under ``load``, if any)."""
    print(f"{name}: flying a pass and aborting another", file=sys.stderr)
    probes = Probes(base, OPERATOR_TOKEN)
    tasks = probes.start()
    tasks.append(asyncio.create_task(probes.console(base.replace("http", "ws") + "/api/console")))
    async with httpx.AsyncClient(base_url=base, timeout=300.0, limits=OPERATOR_LIMITS) as op:
        op.headers["Authorization"] = f"Bearer {OPERATOR_TOKEN}"
        try:
            await fly(op, sessions, readers, f"{name}-flown", 230.0)
            _, answer, abort_s = await abort_mid_pass(op, sessions, readers, f"{name}-cut")
            assert answer.status_code == 200, answer.text
        finally:
            probes.stop.set()
            await asyncio.gather(*tasks)
    return {
        "health_p50_s": statistics.median(probes.health_s),
        "health_p99_s": percentile(probes.health_s, 0.99),
        "health_max_s": max(probes.health_s),
        "link_status_p99_s": percentile(probes.link_s, 0.99),
        "abort_s": abort_s,
        "console_open_s": probes.console_open_s,
        "console_ping_p99_s": percentile(probes.console_pings_s, 0.99),
        "console_dropped": probes.console_dropped,
        "samples": {"health": len(probes.health_s), "console_pings": len(probes.console_pings_s)},
        **probes.ingest_lag(),
    }


async def _run(
    base: str, port: int, url: str, recording: bytes, args: argparse.Namespace, tmp: Path
) -> dict[str, Any]:
    engine = make_engine(url)
    sessions, readers = session_factory(engine), read_session_factory(engine)
    tokens = [f"bench-viewer-{k:02d}-0123456789" for k in range(args.tokens)]
    async with httpx.AsyncClient(base_url=base, timeout=600.0, limits=OPERATOR_LIMITS) as op:
        op.headers["Authorization"] = f"Bearer {OPERATOR_TOKEN}"
        response = await op.post("/api/passes/import", content=recording)
        assert response.status_code == 201, response.text
        demo_id = response.json()["imported"]["id"]
        response = await op.post(f"/api/passes/{demo_id}/analyses")
        assert response.status_code == 201, response.text
        vehicle = spacecraft_process(port, SPACECRAFT_TOKEN, args.scale, tmp / "spacecraft.log")
        try:
            while not (await op.get("/api/link/status")).json()["connected"]:
                assert vehicle.poll() is None, "the spacecraft exited"
                await asyncio.sleep(0.1)
            idle = await _phase("idle", base, sessions, readers, None)
            # the viewers in a process of their own: the probes here time the server
            out = tmp / "viewers.json"
            with viewer_process(base, tokens, args.clients, demo_id, out) as load:
                await asyncio.sleep(3.0)  # the load is on before the probes and the pass
                loaded = await _phase("loaded", base, sessions, readers, load)
            loaded["viewer_answers"] = dict(load.status)
            loaded["viewer_refusals"] = dict(load.codes)
            loaded["viewer_complete_reads"] = dict(load.complete)
        finally:
            vehicle.terminate()
            vehicle.wait(timeout=30)
            engine.dispose()
    return {"idle": idle, "loaded": loaded}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--database-url", default=None, help="default: SQLite in a temp dir")
    parser.add_argument("--tokens", type=int, default=20, help="viewer tokens")
    parser.add_argument("--clients", type=int, default=10, help="viewers per token")
    parser.add_argument("--scale", type=float, default=20.0, help="the spacecraft's time scale")
    args = parser.parse_args()
    print("flying the demo pass offline for a recording to serve", file=sys.stderr)
    recording = demo_mcap()
    with _own_schema(args.database_url) as database_url:
        _bench(args, recording, database_url)


@contextlib.contextmanager
def _own_schema(url: str | None) -> Iterator[str | None]:
    """A PostgreSQL URL whose connections see only a fresh schema of their own (dropped
    after), as the tests' fixture makes; SQLite (None) as it is."""
    if not url:
        yield None
        return
    from sqlalchemy import make_url

    from tests.postgres import own_schema

    with own_schema(make_url(url), "bench_load") as scoped:
        yield scoped


def _bench(args: argparse.Namespace, recording: bytes, database_url: str | None) -> None:
    with tempfile.TemporaryDirectory() as tmp_dir:
        tmp = Path(tmp_dir)
        viewer_tokens = [
            f"bench-viewer-{k:02d}-0123456789=viewer{k:02d}:viewer" for k in range(args.tokens)
        ]
        env = {
            **os.environ,
            "HIKOBOSHI_DATA_DIR": str(tmp),
            "HIKOBOSHI_TOKENS": ",".join(
                [
                    f"{OPERATOR_TOKEN}=otto:operator",
                    f"{SPACECRAFT_TOKEN}=ets7:spacecraft",
                    *viewer_tokens,
                ]
            ),
        }
        env.pop("DATABASE_URL", None)
        if database_url:
            env["DATABASE_URL"] = database_url
        url = database_url or Settings(data_dir=tmp).resolved_database_url()
        with serve_process(env, tmp / "server.log") as (server, base):
            port = int(base.rsplit(":", 1)[1])
            result = asyncio.run(_run(base, port, url, recording, args, tmp))
            result["server_peak_rss_mib"] = peak_rss_bytes(server.pid) / 2**20
    idle, loaded = result["idle"], result["loaded"]
    quantities = (
        "health_p50_s",
        "health_p99_s",
        "link_status_p99_s",
        "abort_s",
        "console_ping_p99_s",
        "frames_behind_max",
        "behind_max_wall_s",
    )
    ratios = {
        f"{q}_ratio": loaded[q] / idle[q] if loaded[q] is not None and idle[q] else None
        for q in quantities
    }
    lag = loaded["behind_max_wall_s"]
    emit(
        "load",
        {**result, "ratios_loaded_to_idle": ratios, "backend": url.split(":", 1)[0]},
        {
            "health_p99_under_load_below_1s": loaded["health_p99_s"] < 1.0,
            "abort_under_load_below_1s": loaded["abort_s"] < 1.0,
            "ingest_never_2s_behind": lag is not None and lag < 2.0,
            "console_never_dropped": loaded["console_dropped"] is None,
        },
    )


if __name__ == "__main__":
    main()
