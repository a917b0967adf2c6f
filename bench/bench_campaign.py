"""The short campaign of ``tests/test_campaign_demo.py`` (tests/support/campaign.py) on the
shipped geometry: two ptp passes at 10x with 10 % loss, TDRS-West's first window of
1999-09-30 after 00:24 and then TDRS-East's where it flew (41 deg W), 34 minutes of onboard
time later; a 60 s acquisition margin (``--aos-margin-s``). The test flies TDRS-East moved
to 140 deg W (a 4-minute gap) and a 30 s margin; this is the long form, its gaps flown fast
by the spacecraft process at the vehicle's full rate.

Prints the campaign's verdict, each pass's state and counts, each gap flown fast (onboard
s, the wall s it took and their ratio: how many times real time the vehicle was simulated)
and the whole run's wall time, as JSON.

    PYTHONPATH=. .venv/bin/python bench/bench_campaign.py [--aos-margin-s 60] [--east-deg -41]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import emit

from hikoboshi.campaign_demo import run_campaign_demo
from tests.support.campaign import short_campaign


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--aos-margin-s", type=float, default=60.0)
    parser.add_argument(
        "--east-deg", type=float, default=None, help="TDRS-East's longitude (default: 41 W)"
    )
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        options = short_campaign(Path(tmp), aos_margin_s=args.aos_margin_s, east_deg=args.east_deg)
        began = time.monotonic()
        doc = run_campaign_demo(options)
        wall_s = time.monotonic() - began
    passes = [
        {k: p[k] for k in ("state", "commands_total", "commands_executed_at_tag", "frames_missing")}
        | {"relay": p["window"]["relay"], "aos_utc": p["window"]["aos_utc"]}
        for p in doc["passes"]
    ]
    gaps = [
        g | {"times_real_time": round(g["onboard_s"] / g["wall_s"], 1) if g["wall_s"] else None}
        for g in doc["fast_gaps"]
    ]
    emit(
        "campaign",
        {"wall_s": round(wall_s, 1), "passes": passes, "fast_gaps": gaps, "gaps": doc["gaps"]},
        {"verdict_ok": bool(doc["verdict"]["ok"])},
    )


if __name__ == "__main__":
    main()
