"""Contact windows over 7 days: ``mission.compute_windows`` on ETS-VII's 1999 mission,
against the raw propagation of the same scan grid in the same process.

- windows: ``compute_windows(ets7-1999, 1999-09-30T00:00Z, 168 h)``, both relays; the 60 s
  scan, each change bracketed to 1 ms, the ranges sampled every 10 s (best of ``REPEAT``);
- baseline: ``sgp4``'s own ``Satrec.sgp4_array`` over the scan's grid (the 168 h and the two
  orbits either side at 60 s, once per relay: the propagation the scan cannot avoid), TEME
  positions, nothing else.

The ratio windows / baseline is what the geometry, the frames and the root finding cost
over the bare propagation. The windows are computed with every socket refused (``socket``
patched to raise), so the figure is also proof that the computation runs offline.

    PYTHONPATH=. .venv/bin/python bench/bench_windows.py
"""

from __future__ import annotations

import math
import socket
from datetime import UTC, datetime, timedelta

import numpy as np
from _common import best_of, emit
from sgp4.api import jday

from mission import MISSIONS_DIR, compute_windows, load_mission
from mission.windows import SCAN_STEP_S

REPEAT = 5
HOURS = 168.0
START = datetime(1999, 9, 30, tzinfo=UTC)


class _NoNetwork(socket.socket):
    def __init__(self, *args: object, **kwargs: object) -> None:
        raise OSError("network unreachable (bench_windows)")


def main() -> None:
    mission = load_mission(MISSIONS_DIR / "ets7-1999.toml")
    satrec = mission.orbit.satrec()
    period_s = 2.0 * math.pi / satrec.no_kozai * 60.0
    first = START - timedelta(seconds=2.0 * period_s)
    span_s = HOURS * 3600.0 + 4.0 * period_s
    jd0, fr0 = jday(first.year, first.month, first.day, first.hour, first.minute, first.second)
    fr = fr0 + np.arange(0.0, span_s + SCAN_STEP_S, SCAN_STEP_S) / 86400.0
    jd = np.full_like(fr, jd0)

    def baseline() -> None:
        for _ in mission.relays:
            errors, _, _ = satrec.sgp4_array(jd, fr)
            assert not errors.any()

    found: list[object] = []

    def windows() -> None:
        found[:] = compute_windows(mission, START, HOURS)

    real_socket = socket.socket
    socket.socket = _NoNetwork  # type: ignore[misc]
    try:
        windows()  # the imports and the builtin time scale, once, offline
        windows_s = best_of(windows, repeat=REPEAT)
    finally:
        socket.socket = real_socket  # type: ignore[misc]
    baseline_s = best_of(baseline, repeat=REPEAT)
    ratio = windows_s / baseline_s
    emit(
        "windows",
        {
            "hours": HOURS,
            "windows": len(found),
            "scan_points_per_relay": int(fr.size),
            "windows_s": round(windows_s, 4),
            "baseline_sgp4_grid_s": round(baseline_s, 5),
            "windows_over_baseline": round(ratio, 1),
            "network": "refused (socket patched)",
        },
        # our target: a week of windows is interactive (a console request), and stays within
        # a few hundred bare propagations of its grid
        {"a_week_of_windows_under_300x_the_bare_propagation": ratio < 300.0},
    )


if __name__ == "__main__":
    main()
