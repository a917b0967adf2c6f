"""Heavy artifacts served from storage (server/services/artifacts.py): what 200 concurrent
viewers of the demo pass's recording (13.8 MB) and report cost, in worker jobs and time.

The ground service runs in this process (uvicorn in a thread, SQLite in a temporary
directory or ``--database-url``), so that its worker pool's job count can be read; the
viewers are ``httpx`` clients on loopback that stream each answer and drop it.

- **baseline**: one request for the recording when nothing is stored: one worker job,
  what every request cost before the store (each was a job of its own).
- **cold burst**: ``--viewers`` (200) concurrent requests for a second pass's recording,
  nothing stored: the jobs started (target: 1) and the wall time, as a ratio to the
  baseline.
- **warm burst**: the same number of requests for the report, its page, a figure and the
  recording, all stored: the jobs started (target: 0) and the wall time against the
  baseline.
- **revalidation**: the same number of requests with ``If-None-Match``: all 304, no job.
- **version query**: what each request costs the database before anything is served (the
  best of 5, per kind, on the demo pass).

    .venv/bin/python bench/bench_artifacts.py [--viewers 200] [--database-url URL]
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import httpx
import uvicorn
from _common import best_of, demo_mcap, emit, free_port
from bench_isolation import OPERATOR, OPERATOR_TOKEN, VIEWER, VIEWER_TOKEN

from server.app import create_app
from server.services.artifacts import content_version
from server.settings import ApiToken, Role, Settings


def _rss_mib() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


async def _burst(
    client: httpx.AsyncClient, paths: list[str], headers: dict[str, str]
) -> tuple[float, dict[str, int]]:
    async def one(path: str) -> int:
        async with client.stream("GET", path, headers={**VIEWER, **headers}) as response:
            async for _ in response.aiter_bytes():
                pass
            return response.status_code

    t0 = time.perf_counter()
    codes = await asyncio.gather(*(one(p) for p in paths))
    counts: dict[str, int] = {}
    for code in codes:
        counts[str(code)] = counts.get(str(code), 0) + 1
    return time.perf_counter() - t0, counts


async def _run(base: str, app: Any, recording: bytes, viewers: int) -> dict[str, Any]:
    pool = app.state.workers
    limits = httpx.Limits(max_connections=viewers + 10)
    async with httpx.AsyncClient(base_url=base, timeout=600.0, limits=limits) as client:
        ids = []
        for _ in range(2):
            response = await client.post("/api/passes/import", content=recording, headers=OPERATOR)
            assert response.status_code == 201, response.text
            ids.append(response.json()["imported"]["id"])
        first, second = ids
        response = await client.post(f"/api/passes/{first}/analyses", headers=OPERATOR)
        assert response.status_code == 201, response.text

        jobs = pool.started
        baseline_s, counts = await _burst(client, [f"/api/passes/{first}/recording.mcap"], {})
        assert counts == {"200": 1} and pool.started == jobs + 1, counts

        print(f"cold burst: {viewers} requests, nothing stored", file=sys.stderr)
        jobs = pool.started
        path = f"/api/passes/{second}/recording.mcap"
        cold_s, cold = await _burst(client, [path] * viewers, {})
        cold_jobs = pool.started - jobs

        report = (await client.get(f"/api/passes/{first}/report", headers=VIEWER)).json()
        figure = report["figures"][0]
        mixed = [
            f"/api/passes/{first}/report",
            f"/api/passes/{first}/report.html",
            f"/api/passes/{first}/report/figures/{figure}.png",
            f"/api/passes/{first}/recording.mcap",
        ]
        for p in mixed:  # stored once
            assert (await client.get(p, headers=VIEWER)).status_code == 200
        print(f"warm burst: {viewers} requests, all stored", file=sys.stderr)
        rss_before = _rss_mib()
        jobs = pool.started
        warm_s, warm = await _burst(client, [mixed[k % 4] for k in range(viewers)], {})
        warm_jobs = pool.started - jobs
        rss_after = _rss_mib()
        etag = (await client.get(mixed[3], headers=VIEWER)).headers["etag"]
        jobs = pool.started
        revalidate_s, revalidated = await _burst(
            client, [mixed[3]] * viewers, {"If-None-Match": etag}
        )
        revalidate_jobs = pool.started - jobs
    sessions = app.state.read_sessions

    def version_s(kind: Any) -> float:
        def read() -> None:
            with sessions() as session:
                content_version(session, kind, first)

        return best_of(read)

    return {
        "version_query_s": {kind: version_s(kind) for kind in ("recording", "report", "figure")},
        "viewers": viewers,
        "recording_bytes": len(recording),
        "baseline_one_job_s": baseline_s,
        "cold_burst": {"s": cold_s, "answers": cold, "jobs": cold_jobs},
        "cold_burst_over_baseline": cold_s / baseline_s,
        "warm_burst": {"s": warm_s, "answers": warm, "jobs": warm_jobs},
        "warm_burst_over_baseline": warm_s / baseline_s,
        "revalidation": {"s": revalidate_s, "answers": revalidated, "jobs": revalidate_jobs},
        "process_rss_mib_before_after_warm_burst": [rss_before, rss_after],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--viewers", type=int, default=200)
    parser.add_argument("--database-url", default=None, help="default: SQLite in a temp dir")
    args = parser.parse_args()
    print("flying the demo pass offline for a recording to serve", file=sys.stderr)
    recording = demo_mcap()
    with tempfile.TemporaryDirectory() as tmp:
        tokens = {
            OPERATOR_TOKEN: ApiToken(name="otto", role=Role.OPERATOR),
            VIEWER_TOKEN: ApiToken(name="vera", role=Role.VIEWER),
        }
        settings = Settings(data_dir=Path(tmp), database_url=args.database_url, tokens=tokens)
        app = create_app(settings)
        port = free_port()
        server = uvicorn.Server(
            uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning", backlog=2048)
        )
        thread = threading.Thread(target=server.run, daemon=True)
        thread.start()
        deadline = time.monotonic() + 60.0
        while not server.started:
            assert time.monotonic() < deadline and thread.is_alive(), "no server"
            time.sleep(0.1)
        try:
            result = asyncio.run(_run(f"http://127.0.0.1:{port}", app, recording, args.viewers))
        finally:
            server.should_exit = True
            thread.join(timeout=30)
    emit(
        "artifacts",
        result,
        {
            "cold burst: one job": result["cold_burst"]["jobs"] == 1,
            "warm burst: no job": result["warm_burst"]["jobs"] == 0,
            "revalidation: all 304, no job": result["revalidation"]["answers"]
            == {"304": args.viewers}
            and result["revalidation"]["jobs"] == 0,
        },
    )


if __name__ == "__main__":
    main()
