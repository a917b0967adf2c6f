"""The live pass view in a browser: frame times with a whole 20-minute pass on the plots.

The ground service runs under uvicorn on loopback (SQLite in a scratch directory) and the
spacecraft process at time scale 1, so telemetry streams to the console at the real 10 Hz
through the real link (3 s delay). Debian's Chromium (headless, Playwright) opens the live
view of the running pass; once live frames arrive, 20 minutes of earlier frames (12,000 at
10 Hz, synthetic, before the first live one) are put into the page's store, so every plot
holds a whole pass while the stream goes on.

Measured for ``DURATION_S`` each, in the same browser and run:

- baseline: an empty page, ``requestAnimationFrame`` deltas (the display's own cadence);
- console: the live view streaming at 10 Hz with a whole pass of points: rAF deltas, and
  the cost of each 10 Hz update (plots, phase plane, 3D, values) in the page.

Target (console issue): p99 frame time under 50 ms (no visible stall), update p99 under
16 ms (fits one 60 Hz frame).
"""

from __future__ import annotations

import asyncio
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench._common import emit
from server.storage.db import sqlite_url
from spacecraft.link import LinkConfig
from spacecraft.process import ProcessConfig, SpacecraftProcess
from tests.server.link.harness import OPERATOR, VIEWER, running_ground, store_pass

CHROMIUM = "/usr/bin/chromium"
DURATION_S = 15.0
HISTORY_FRAMES = 12_000  # 20 minutes at 10 Hz

RAF = """(seconds) => new Promise((resolve) => {
  const deltas = []; let last = performance.now(); const end = last + seconds * 1000;
  const step = (t) => { deltas.push(t - last); last = t;
    if (t < end) requestAnimationFrame(step); else resolve(deltas); };
  requestAnimationFrame(step);
})"""

# 12,000 frames before the first live one: smooth joint motion, attitude and momentum.
INJECT = """(n) => {
  const s = window.hikoboshiLive.store();
  const g0 = s.first.genNs;
  const names = ["j1","j2","j3","j4","j5","j6","t1","t2","t3","t4","t5","t6",
                 "qx","qy","qz","qw","wx","wy","wz","hw1","hw2","hw3"];
  const cols = {seq: [], generation_time_ns: []};
  for (const k of names) cols[k] = [];
  for (let k = 0; k < n; k++) {
    const t = (k - n) * 0.1;
    cols.seq.push(-n + k); cols.generation_time_ns.push(g0 + t * 1e9);
    for (let i = 0; i < 6; i++) {
      const a = 0.3 * Math.sin(t / (60 + 10 * i));
      cols["j" + (i + 1)].push(a + 1e-4 * Math.sin(7 * t));
      cols["t" + (i + 1)].push(a);
    }
    const p = 1e-3 * Math.sin(t / 90);
    cols.qx.push(0); cols.qy.push(p / 2); cols.qz.push(0); cols.qw.push(1);
    cols.wx.push(0); cols.wy.push(1e-3 / 90 * Math.cos(t / 90)); cols.wz.push(0);
    cols.hw1.push(0.1 * Math.sin(t / 50)); cols.hw2.push(0.1 * Math.cos(t / 50)); cols.hw3.push(0);
  }
  s.addColumns(cols, false);
  return s.count;
}"""


def _stats(values: list[float]) -> dict[str, float]:
    ordered = sorted(values)
    if not ordered:
        return {"n": 0}

    def pct(q: float) -> float:
        return ordered[min(len(ordered) - 1, int(q * len(ordered)))]

    return {
        "n": len(ordered),
        "p50_ms": round(statistics.median(ordered), 2),
        "p99_ms": round(pct(0.99), 2),
        "max_ms": round(ordered[-1], 2),
        "over_50ms": sum(1 for v in ordered if v > 50.0),
    }


class Spacecraft:
    def __init__(self, url: str):
        self.process = SpacecraftProcess(
            ProcessConfig(
                ground_url=url,
                token="s-token",
                time_scale=1.0,
                uplink=LinkConfig(seed=11),
                downlink=LinkConfig(seed=12),
                seed=3,
            )
        )
        self.loop: asyncio.AbstractEventLoop | None = None
        self.stop_event: asyncio.Event | None = None
        ready = threading.Event()

        async def main() -> None:
            self.loop = asyncio.get_running_loop()
            self.stop_event = asyncio.Event()
            ready.set()
            await self.process.run(self.stop_event)

        self.thread = threading.Thread(target=lambda: asyncio.run(main()), daemon=True)
        self.thread.start()
        ready.wait(10.0)

    def stop(self) -> None:
        if self.loop and self.stop_event:
            self.loop.call_soon_threadsafe(self.stop_event.set)
        self.thread.join(timeout=20.0)


def main() -> None:
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory() as tmp, running_ground(sqlite_url(Path(tmp))) as ground:
        pass_id = store_pass(ground.sessions, "bench", (10.0, 5.0, 0.0, 0.0, 0.0, 0.0), 1200.0)
        craft = Spacecraft(ground.ws_url)
        try:
            deadline = time.monotonic() + 20.0
            while not httpx.get(f"{ground.url}/api/link/status", headers=VIEWER).json()[
                "connected"
            ]:
                assert time.monotonic() < deadline, "the spacecraft did not connect"
                time.sleep(0.1)
            started = httpx.post(
                f"{ground.url}/api/passes/{pass_id}/start",
                json={"confirm": "START bench"},
                headers=OPERATOR,
            )
            assert started.status_code == 200, started.text
            figures = _measure(sync_playwright, ground.url, pass_id)
        finally:
            craft.stop()
    emit(
        "console_page",
        figures,
        {
            "frame_p99_under_50ms": figures["console"]["frame"]["p99_ms"] < 50.0,
            "update_p99_under_16ms": figures["console"]["update"]["p99_ms"] < 16.0,
        },
    )


def _measure(sync_playwright: Any, url: str, pass_id: str) -> dict[str, Any]:
    with sync_playwright() as pw:
        browser = pw.chromium.launch(
            executable_path=CHROMIUM, headless=True, args=["--no-sandbox", "--use-gl=swiftshader"]
        )
        page = browser.new_page(viewport={"width": 1600, "height": 1000})
        page.set_default_timeout(60_000)
        page.goto(f"{url}/api/health")  # a page of ours, nearly empty
        baseline = page.evaluate(RAF, DURATION_S)[1:]

        page.goto(url)
        page.fill("[data-test=token]", "v-token")
        page.click("[data-test=signin]")
        page.wait_for_selector("[data-test=role]")
        page.goto(f"{url}/#/live/{pass_id}")
        page.wait_for_function("() => window.hikoboshiLive && window.hikoboshiLive.frames() > 5")
        held = page.evaluate(INJECT, HISTORY_FRAMES)
        page.wait_for_function(f"() => window.hikoboshiLive.pointCounts()[0] > {HISTORY_FRAMES}")
        page.wait_for_timeout(2000)
        page.evaluate("() => window.hikoboshiLive.tickMs()")  # drop the settling ticks
        frames_before = page.evaluate("() => window.hikoboshiLive.frames()")
        deltas = page.evaluate(RAF, DURATION_S)[1:]
        updates = page.evaluate("() => window.hikoboshiLive.tickMs()")
        frames_after = page.evaluate("() => window.hikoboshiLive.frames()")
        points = page.evaluate("() => window.hikoboshiLive.pointCounts()")
        browser.close()
    return {
        "duration_s": DURATION_S,
        "history_frames": HISTORY_FRAMES,
        "frames_held": held,
        "plots": len(points),
        "points_per_plot_min": min(points),
        "live_frames_per_s": round((frames_after - frames_before) / DURATION_S, 2),
        "baseline": {"frame": _stats(baseline)},
        "console": {"frame": _stats(deltas), "update": _stats(updates)},
    }


if __name__ == "__main__":
    main()
