"""Helpers shared by the benchmarks: best-of-N timing and the JSON they print."""

from __future__ import annotations

import contextlib
import io
import json
import platform
import resource
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from tests.support.processes import free_port as free_port
from tests.support.processes import health_when_up, serve_command


def best_of(fn: Callable[[], object], *, repeat: int = 5) -> float:
    """The fastest of ``repeat`` runs, in seconds (the least disturbed by the machine)."""
    best = float("inf")
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def emit(name: str, figures: dict[str, Any], targets: dict[str, bool]) -> None:
    """Print one JSON document: figures, whether each target is met, and the machine."""
    doc = {
        "benchmark": name,
        "figures": figures,
        "targets_met": targets,
        "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "python": platform.python_version(),
        "machine": platform.machine(),
    }
    print(json.dumps(doc, indent=2))


def demo_mcap() -> bytes:
    """The demo pass (ETS-VII's whole pass, flown offline, seed 7) as MCAP bytes."""
    from planner.dynamics import DynamicsWorkspace
    from planner.model import default_model
    from planner.schedule import plan_pass
    from spacecraft.offline import fly_offline
    from telemetry.mcap import write_mcap
    from telemetry.recording import PassRecording

    plan = plan_pass(DynamicsWorkspace(default_model()))
    flight = fly_offline(plan, seed=7)
    recording = PassRecording.from_frames("demo", plan, flight.epoch_ns, flight.frames, meta={})
    buffer = io.BytesIO()
    write_mcap(recording, buffer)
    return buffer.getvalue()


@contextlib.contextmanager
def serve_process(env: dict[str, str], log: Path) -> Iterator[tuple[subprocess.Popen[bytes], str]]:
    """``hikoboshi serve`` on a free loopback port with ``env`` (its output to ``log``), up
    once its health answers; the process and its base URL, terminated after."""
    port = free_port()
    with log.open("wb") as out:
        server = subprocess.Popen(
            serve_command(port), env=env, stdout=out, stderr=subprocess.STDOUT
        )
    base = f"http://127.0.0.1:{port}"
    try:
        health_when_up(server, base, output=lambda: log.read_text()[-3000:])
        yield server, base
    finally:
        server.terminate()
        server.wait(timeout=30)
