"""Helpers shared by the benchmarks: best-of-N timing and the JSON they print."""

from __future__ import annotations

import json
import platform
import resource
import time
from collections.abc import Callable
from typing import Any


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
