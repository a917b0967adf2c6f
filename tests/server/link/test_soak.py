"""Passes back to back on one ground process: the server's threads, open files and
memory stay flat after the first few, and every pass completes.

Real processes on loopback: ``hikoboshi serve`` and ``hikoboshi spacecraft`` at 20x; this
process flies :data:`PASSES` short passes through the REST API as an operator does (two
PTP plans there and back, each pass scheduled, started with its confirmation, followed to
its end and its summary read) and reads ``/proc`` of the server after each. The 30-pass
version with the database's size and a plot is ``bench/bench_soak.py``.

On SQLite (:data:`BACKENDS`; both: ``HIKOBOSHI_TEST_SOAK_BACKENDS=sqlite,postgresql``), its
WAL's handles the open files that come and go. The leak this caught (each ended pass's
telemetry ring held) was the console's, the same on both backends; on PostgreSQL the
passes back to back with the server's peak memory bounded are test_load.py's (two passes,
under load), the 30-pass trend ``bench/bench_soak.py --backend postgresql``'s, and no
pooled connection left behind by the lifespan tests/server/api/test_app.py's. Each backend
ran 46 s of the suite's real-time chain with one core busy.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import httpx
import pytest

from tests.server.link.harness import serve_process
from tests.support.processes import free_port

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time

#: The backends flown (see the module's docstring)
BACKENDS = os.environ.get("HIKOBOSHI_TEST_SOAK_BACKENDS", "sqlite").split(",")
SCALE = 20.0
PASSES = 6
#: The passes compared: after the warm-up (the first passes import, plan and fill caches),
#: three passes apart (the 30-pass trend is bench/bench_soak.py's).
EARLY, LATE = 3, PASSES
OPERATOR_TOKEN = "operator-token-0123456789"
SPACECRAFT_TOKEN = "spacecraft-token-01234567"
TOKENS = f"{OPERATOR_TOKEN}=otto:operator,{SPACECRAFT_TOKEN}=ets7:spacecraft"
#: Threads that come and go with the requests, not with the passes: the worker threads of
#: the synchronous routes (anyio's, each ends after 10 s idle) and of ``asyncio.to_thread``.
#: Measured 7-9 in all over 30 passes on both backends (bench/bench_soak.py).
THREADS_SLACK = 2
#: Descriptors that come and go with the requests: keep-alive HTTP connections (closed by
#: the server after 5 s idle) and the SQLite WAL's handles. Measured 18-19 (SQLite) and
#: 14-15 (PostgreSQL) from pass 4 on over 30 passes.
FDS_SLACK = 3
#: Resident memory over the last three passes: measured +0.13-0.16 MiB a pass over 30; each
#: pass's telemetry ring held for good cost +2.3 MiB a pass (6.9 MiB over three) before the
#: console let ended passes' streams go.
RSS_GROWTH_BOUND = 5 * 2**20
#: Guards against a hang (wall s), not timing assertions.
GUARD_S = 120.0


def _figures(pid: int) -> tuple[int, int, int]:
    """The process's resident memory (bytes), threads and open descriptors at rest: the
    least of five readings a tenth of a second apart (a request's worker thread or socket
    caught in one reading is not a leak; a leak raises the least reading too)."""
    readings = []
    for _ in range(5):
        rss = next(
            int(line.split()[1]) * 1024
            for line in Path(f"/proc/{pid}/status").read_text().splitlines()
            if line.startswith("VmRSS:")
        )
        readings.append(
            (rss, len(os.listdir(f"/proc/{pid}/task")), len(os.listdir(f"/proc/{pid}/fd")))
        )
        time.sleep(0.1)
    return min(r[0] for r in readings), min(r[1] for r in readings), min(r[2] for r in readings)


def _until(check: Callable[[], Any], what: str, *procs: subprocess.Popen[bytes]) -> Any:
    deadline = time.monotonic() + GUARD_S  # a guard, not a timing assertion
    while not (value := check()):
        assert all(p.poll() is None for p in procs), f"{what}: a process exited"
        assert time.monotonic() < deadline, f"{what}: not within {GUARD_S} s"
        time.sleep(0.1)
    return value


def _plan(api: httpx.Client, start: list[float], goal: list[float]) -> dict[str, Any]:
    parameters = {"start_joints_deg": start, "goal_joints_deg": goal, "settle_s": 0.25}
    response = api.post("/api/plans", json={"experiment": "ptp", "parameters": parameters})
    assert response.status_code == 201, response.text
    plan: dict[str, Any] = response.json()
    return plan


def _fly(
    api: httpx.Client, plan: dict[str, Any], name: str, *procs: subprocess.Popen[bytes]
) -> dict[str, Any]:
    """One pass scheduled, started and followed until it has ended and settled; its
    summary."""
    now = datetime.now(UTC)
    response = api.post(
        "/api/passes",
        json={
            "plan_id": plan["id"],
            "name": name,
            "aos_time": now.isoformat(),
            "los_time": (now + timedelta(seconds=600.0)).isoformat(),
        },
    )
    assert response.status_code == 201, response.text
    pass_id = response.json()["id"]
    response = api.post(f"/api/passes/{pass_id}/start", json={"confirm": f"START {name}"})
    assert response.status_code == 200, response.text
    ended = ("complete", "aborted", "safed")
    _until(lambda: api.get(f"/api/passes/{pass_id}").json()["state"] in ended, name, *procs)

    def settled() -> dict[str, Any] | None:
        summary: dict[str, Any] = api.get(f"/api/passes/{pass_id}/summary").json()
        onboard = api.get("/api/link/status").json()["onboard_time_ns"]
        end = summary["telemetry_end_ns"]
        done = summary["commands_outstanding"] == 0 and summary["frames_missing"] == 0
        return summary if done and end is not None and onboard >= end else None

    summary: dict[str, Any] = _until(settled, f"{name} settled", *procs)
    return summary


@pytest.mark.slow
@pytest.mark.parametrize("database_url", BACKENDS, indirect=True)
def test_passes_back_to_back_leave_threads_files_and_memory_flat(
    database_url: str, tmp_path: Path
) -> None:
    port = free_port()
    env = {"HIKOBOSHI_TOKENS": TOKENS, "HIKOBOSHI_DATA_DIR": str(tmp_path / "data")}
    figures: dict[int, tuple[int, int, int]] = {}
    summaries: list[dict[str, Any]] = []
    with (
        serve_process(database_url, port, tmp_path / "server.log", env) as server,
        httpx.Client(
            base_url=f"http://127.0.0.1:{port}",
            headers={"Authorization": f"Bearer {OPERATOR_TOKEN}"},
            timeout=60.0,
        ) as api,
    ):
        with (tmp_path / "spacecraft.log").open("ab") as out:  # it starts while we plan
            vehicle = subprocess.Popen(
                [
                    *(sys.executable, "-m", "hikoboshi", "spacecraft"),
                    *("--ground", f"ws://127.0.0.1:{port}/api/link"),
                    *("--token", SPACECRAFT_TOKEN, "--time-scale", str(SCALE), "--seed", "4"),
                ],
                stdout=out,
                stderr=subprocess.STDOUT,
            )
        try:
            there = _plan(api, [0.0] * 6, [10.0, 0.0, 0.0, 10.0, 0.0, 0.0])
            back = _plan(api, [10.0, 0.0, 0.0, 10.0, 0.0, 0.0], [0.0] * 6)
            _until(lambda: api.get("/api/link/status").json()["connected"], "link", vehicle)
            for n in range(1, PASSES + 1):
                plan = there if n % 2 else back
                summaries.append(_fly(api, plan, f"soak {n}", server, vehicle))
                figures[n] = _figures(server.pid)
        finally:
            vehicle.terminate()
            vehicle.wait(timeout=30)

    for summary in summaries:
        assert summary["state"] == "complete", summary
        assert summary["commands_total"] > 20
        assert summary["commands_executed_at_tag"] == summary["commands_total"], summary
        assert summary["frames_stored"] > 0 and summary["frames_missing"] == 0, summary
    (rss_early, threads_early, fds_early), (rss_late, threads_late, fds_late) = (
        figures[EARLY],
        figures[LATE],
    )
    table = {n: (f"{r / 2**20:.1f} MiB", t, f) for n, (r, t, f) in figures.items()}
    assert abs(threads_late - threads_early) <= THREADS_SLACK, table
    assert abs(fds_late - fds_early) <= FDS_SLACK, table
    assert rss_late - rss_early < RSS_GROWTH_BOUND, table
