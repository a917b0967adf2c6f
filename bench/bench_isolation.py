"""The command path under read load (#14): how much slower an operator's control request
and the event loop answer while viewers download recordings and reports.

``hikoboshi serve`` runs as its own process on loopback (SQLite in a temporary directory,
or ``--database-url``) with the demo pass imported and analysed. Two probes, each timed
from this process:

- **control**: ``POST /api/passes/{id}/start`` with a wrong confirmation, answered 422
  ``confirmation_mismatch``. It takes the path an abort takes: the token check, a control
  job on the link's database worker (which writes a ``pass_control_refused`` audit event)
  and the answer.
- **health**: ``GET /api/health``, the event loop alone.

Baseline, same run: the probes with nothing else going on. Then the same probes while
``--viewers`` clients (30) loop on the demo pass's ``recording.mcap`` (13.8 MB) and
``report.html``, waiting out 503 ``busy`` for its ``Retry-After``. The figures are the
median and 95th percentile latency in each phase and their ratios under load to the
baseline. Target: the control probe's 95th percentile under load stays under 1 s (the
issue's bound for an abort) and within 10x its baseline.

``--busy-cores N`` adds N processes spinning on a core each during the loaded phase (as a
shared CI machine has): the viewers and the server then also compete for the CPU.

    .venv/bin/python bench/bench_isolation.py [--viewers 30] [--seconds 20] [--busy-cores 1]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx
from _common import demo_mcap, emit, serve_process

OPERATOR_TOKEN = "bench-operator-token-0123456789"
VIEWER_TOKEN = "bench-viewer-token-0123456789a"
OPERATOR = {"Authorization": f"Bearer {OPERATOR_TOKEN}"}
VIEWER = {"Authorization": f"Bearer {VIEWER_TOKEN}"}


async def _probe(client: httpx.AsyncClient, pass_id: str, seconds: float) -> dict[str, Any]:
    control: list[float] = []
    health: list[float] = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        t0 = time.perf_counter()
        response = await client.post(
            f"/api/passes/{pass_id}/start", json={"confirm": "START wrong"}, headers=OPERATOR
        )
        control.append(time.perf_counter() - t0)
        assert response.status_code == 422, response.text
        t0 = time.perf_counter()
        response = await client.get("/api/health")
        health.append(time.perf_counter() - t0)
        assert response.status_code == 200
        await asyncio.sleep(0.2)

    def stats(xs: list[float]) -> dict[str, float]:
        ordered = sorted(xs)
        return {
            "n": len(xs),
            "p50_s": statistics.median(ordered),
            "p95_s": ordered[min(len(ordered) - 1, int(0.95 * len(ordered)))],
        }

    return {"control": stats(control), "health": stats(health)}


async def _viewer(base: str, pass_id: str, stop: asyncio.Event, counts: dict[str, int]) -> None:
    paths = (f"/api/passes/{pass_id}/recording.mcap", f"/api/passes/{pass_id}/report.html")
    async with httpx.AsyncClient(base_url=base, timeout=300.0, headers=VIEWER) as client:
        k = 0
        while not stop.is_set():
            async with client.stream("GET", paths[k % 2]) as response:
                async for _ in response.aiter_bytes():
                    pass
            k += 1
            counts[str(response.status_code)] = counts.get(str(response.status_code), 0) + 1
            if response.status_code == 503:
                with contextlib.suppress(TimeoutError):
                    wait = min(float(response.headers["Retry-After"]), 2.0)
                    await asyncio.wait_for(stop.wait(), wait)


@contextlib.contextmanager
def _busy(cores: int) -> Any:
    """``cores`` processes, each keeping a core busy, for the duration."""
    spinners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(cores)]
    try:
        yield
    finally:
        for spinner in spinners:
            spinner.kill()
            spinner.wait()


async def _run(
    base: str, recording: bytes, viewers: int, seconds: float, busy_cores: int
) -> dict[str, Any]:
    async with httpx.AsyncClient(base_url=base, timeout=300.0) as client:
        response = await client.post("/api/passes/import", content=recording, headers=OPERATOR)
        assert response.status_code == 201, response.text
        imported = response.json()["imported"]
        response = await client.post(f"/api/passes/{imported['id']}/analyses", headers=OPERATOR)
        assert response.status_code == 201, response.text
        print(f"baseline: {seconds:.0f} s of probes", file=sys.stderr)
        idle = await _probe(client, imported["id"], seconds)
        stop = asyncio.Event()
        counts: dict[str, int] = {}
        tasks = [
            asyncio.create_task(_viewer(base, imported["id"], stop, counts)) for _ in range(viewers)
        ]
        await asyncio.sleep(2.0)
        print(
            f"under load: {viewers} viewers, {busy_cores} busy cores, {seconds:.0f} s of probes",
            file=sys.stderr,
        )
        with _busy(busy_cores):
            loaded = await _probe(client, imported["id"], seconds)
        stop.set()
        await asyncio.gather(*tasks)
    return {"idle": idle, "loaded": loaded, "viewer_answers": counts, "busy_cores": busy_cores}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--viewers", type=int, default=30)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--database-url", default=None, help="default: SQLite in a temp dir")
    parser.add_argument(
        "--busy-cores", type=int, default=0, help="processes spinning during the loaded phase"
    )
    args = parser.parse_args()
    print("flying the demo pass offline for a recording to serve", file=sys.stderr)
    recording = demo_mcap()
    with tempfile.TemporaryDirectory() as tmp:
        env = {
            **os.environ,
            "HIKOBOSHI_DATA_DIR": tmp,
            "HIKOBOSHI_TOKENS": f"{OPERATOR_TOKEN}=otto:operator,{VIEWER_TOKEN}=vera:viewer",
        }
        env.pop("DATABASE_URL", None)
        if args.database_url:
            env["DATABASE_URL"] = args.database_url
        with serve_process(env, Path(tmp) / "server.log") as (_, base):
            result = asyncio.run(_run(base, recording, args.viewers, args.seconds, args.busy_cores))
    idle, loaded = result["idle"], result["loaded"]
    ratios = {
        f"{probe}_{q}_ratio": loaded[probe][q] / idle[probe][q]
        for probe in ("control", "health")
        for q in ("p50_s", "p95_s")
    }
    emit(
        "isolation",
        {**result, **ratios},
        {
            "control_p95_under_load_below_1s": loaded["control"]["p95_s"] < 1.0,
            "control_p95_within_10x_of_idle": ratios["control_p95_s_ratio"] < 10.0,
        },
    )


if __name__ == "__main__":
    main()
