"""The 4 Hz uplink: how late each command's release is after its monotonic deadline.

A real ground service (uvicorn on loopback in this process, SQLite in a temporary
directory) and the real spacecraft process (``hikoboshi spacecraft``, its own process) fly a
PTP pass; the runner records, for every command, the wall time between its release deadline
(tag - (delay + margin), mapped to ``time.monotonic``) and the moment the emitter woke to
release it (``PassRunner.emission_lags_s``).

Baseline, same run and same process: a bare asyncio loop that sleeps to the same kind of
absolute monotonic deadlines at the same rate and records its own lateness; it shows what
the interpreter and the machine give before the service adds anything.

Two runs: real time (4 Hz on the wall, the flight rate) and 20x (80 Hz on the wall, the
demo's rate). Target (ground-server issue): emission jitter p99 < 2 ms.
"""

from __future__ import annotations

import argparse
import asyncio
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import httpx
import uvicorn
from _common import emit

from planner.dynamics import DynamicsWorkspace
from planner.experiments import PtpParams, plan_ptp
from planner.model import default_model
from server.app import create_app
from server.settings import ApiToken, Role, Settings
from server.storage import repository as repo
from server.storage.db import make_engine, session_factory, sqlite_url

TOKENS = {
    "o": ApiToken(name="bench", role=Role.OPERATOR),
    "s": ApiToken(name="ets7", role=Role.SPACECRAFT),
}


def _percentiles(values: list[float]) -> dict[str, float]:
    ordered = sorted(values)
    pick = lambda q: ordered[min(len(ordered) - 1, int(q * (len(ordered) - 1)))]  # noqa: E731
    return {
        "n": len(ordered),
        "p50_ms": pick(0.50) * 1e3,
        "p99_ms": pick(0.99) * 1e3,
        "max_ms": ordered[-1] * 1e3,
    }


async def _baseline(rate_hz: float, n: int) -> list[float]:
    lags = []
    start = time.monotonic() + 0.1
    for k in range(n):
        deadline = start + k / rate_hz
        delay = deadline - time.monotonic()
        if delay > 0:
            await asyncio.sleep(delay)
        lags.append(time.monotonic() - deadline)
    return lags


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _run(scale: float, motion_deg: float, settle_s: float) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        url = sqlite_url(Path(tmp))
        app = create_app(Settings(database_url=url, tokens=TOKENS))
        port = _free_port()
        server = uvicorn.Server(
            uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning")
        )
        thread = threading.Thread(target=server.run, daemon=True)
        thread.start()
        while not server.started:
            time.sleep(0.01)
        engine = make_engine(url)
        sessions = session_factory(engine)
        plan = plan_ptp(
            DynamicsWorkspace(default_model()),
            PtpParams(
                goal_joints_deg=(motion_deg, 0.0, 0.0, motion_deg, 0.0, 0.0), settle_s=settle_s
            ),
        )
        now = time.time_ns()
        with sessions() as session:
            plan_id = repo.add_plan(session=session, plan=plan, created_at_ns=now).id
            pass_id = repo.add_pass(
                session=session,
                name="bench",
                plan_id=plan_id,
                aos_time_ns=now,
                los_time_ns=now + 3600 * 10**9,
                relay="TDRS",
                created_at_ns=now,
            ).id
            session.commit()

        args = [
            sys.executable,
            "-m",
            "hikoboshi",
            "spacecraft",
            "--ground",
            f"ws://127.0.0.1:{port}/api/link",
            "--token",
            "s",
            "--time-scale",
            repr(scale),
        ]
        headers = {"Authorization": "Bearer o"}
        base = f"http://127.0.0.1:{port}"
        with subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) as proc:
            try:
                while not httpx.get(f"{base}/api/link/status", headers=headers).json()["connected"]:
                    time.sleep(0.05)
                httpx.post(
                    f"{base}/api/passes/{pass_id}/start",
                    json={"confirm": "START bench"},
                    headers=headers,
                ).raise_for_status()
                while httpx.get(f"{base}/api/passes/{pass_id}", headers=headers).json()[
                    "state"
                ] not in ("complete", "aborted"):
                    time.sleep(0.2)
            finally:
                proc.send_signal(signal.SIGTERM)
                proc.wait(timeout=60)
        lags = list(app.state.runner.emission_lags_s)
        n = len(lags)
        baseline = asyncio.run(_baseline(4.0 * scale, n))
        server.should_exit = True
        thread.join(timeout=30)
        engine.dispose()
    return {
        "time_scale": scale,
        "release_rate_hz_wall": 4.0 * scale,
        "emission_lateness": _percentiles(lags),
        "baseline_asyncio_sleep_lateness": _percentiles(baseline),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="shorter passes")
    args = parser.parse_args()
    settle = 10.0 if args.quick else 40.0
    real_time = _run(1.0, 4.0, settle)
    fast = _run(20.0, 10.0, settle * 10)
    figures = {"real_time": real_time, "20x": fast}
    targets = {
        "emission_p99_below_2ms_real_time": real_time["emission_lateness"]["p99_ms"] < 2.0,
        "emission_p99_below_2ms_20x": fast["emission_lateness"]["p99_ms"] < 2.0,
    }
    emit("uplink_emission", figures, targets)


if __name__ == "__main__":
    main()
