"""The link's hot path with a contact plan: ``LinkEmulator.send`` when its windows and its
delay come from the mission's geometry (spacecraft/contact.py), against the same emulator
with a fixed delay and no windows, in the same process.

- contact: a link whose plan holds TDRS-West's windows of 24 h from 1999-09-30T00:00Z
  (delay sampled every 10 s), ``N`` sends spread over those 24 h (windows and gaps);
- baseline: the same ``N`` sends on a link with the fixed 3 s delay of SPEC 6.

Both draw the same random numbers; the ratio contact / baseline is what the per-message
window look-up (a bisection) and the delay interpolation cost. Also: the time to build the
plan (the geometry, once per run), which the hot path never pays again.

    PYTHONPATH=. .venv/bin/python bench/bench_link_contact.py
"""

from __future__ import annotations

import time

import numpy as np
from _common import best_of, emit

from mission import MISSIONS_DIR, compute_windows, load_mission, parse_utc
from spacecraft.contact import contact_plan
from spacecraft.link import LinkConfig, LinkEmulator

N = 100_000
REPEAT = 5
START = parse_utc("1999-09-30T00:00:00Z")


def main() -> None:
    mission = load_mission(MISSIONS_DIR / "ets7-1999.toml")
    windows = [w for w in compute_windows(mission, START, 24.0) if w.relay == "TDRS-West"]
    began = time.perf_counter()
    plan = contact_plan(mission, START, windows)
    build_s = time.perf_counter() - began
    times = np.sort(np.random.default_rng(0).uniform(0.0, 24 * 3600.0, N)).tolist()

    def run(config: LinkConfig) -> None:
        link = LinkEmulator(config)
        for t in times:
            link.send(t, 200)

    contact_s = best_of(lambda: run(LinkConfig(contact=plan, loss=0.1)), repeat=REPEAT)
    baseline_s = best_of(lambda: run(LinkConfig(loss=0.1)), repeat=REPEAT)
    ratio = contact_s / baseline_s
    emit(
        "link_contact",
        {
            "windows": len(plan.windows),
            "sends": N,
            "plan_build_s": round(build_s, 4),
            "contact_us_per_send": round(contact_s / N * 1e6, 3),
            "baseline_us_per_send": round(baseline_s / N * 1e6, 3),
            "contact_over_baseline": round(ratio, 3),
        },
        # our target: following the geometry costs the link's hot path under a third more
        {"contact_under_1_33x_the_fixed_delay": ratio < 1.33},
    )


if __name__ == "__main__":
    main()
