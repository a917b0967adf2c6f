"""Live limits on the ground: evaluating frames against their bands, against decoding them.

The frames: ETS-VII's nominal PTP (A -> B -> A and its settling, 174 s, about 1800 frames at
10 Hz) flown offline through the simulated vehicle (``spacecraft.nominal_limits``, seed 1),
so that the arm moves near the spacecraft for part of them (the live clearance's costly
case) and holds still for the rest. They are encoded as the spacecraft sends them
(``telemetry`` messages of 10 frames, 1 s at 10 Hz, and of 50, what a faster downlink
packs) and, in the same run, best of ``REPEAT``:

- decode: ``telemetry.wire.decode_spacecraft`` of every message with the robot's layout (the
  ground's first step of ingest, pydantic validation included);
- store: ``server.storage.repository.ingest_frames`` of the same frames, a message per
  transaction, into SQLite (the live path's group commit does at least this);
- evaluate: ``telemetry.limits.FrameEvaluator.evaluate`` of each message's frames (fresh
  evaluator, the plan's commanded targets, the clearance watch on the watch threshold), and
  the same without the clearance, and the clearance watch alone.

Figures per frame (µs) and the ratios evaluate / decode and evaluate / (decode + store),
for the whole PTP and for its settling alone (the arm still: what ``bench_downlink``'s
vehicle, which flies no plan, sends). Target (issue 25): checking costs under 10 % of
ingest, evaluate / (decode + store) < 0.10; the live path's own figure is
``bench_downlink``'s, with and without checking.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from _common import best_of, emit
from bench_ingest import new_pass

from planner.description import default_robot
from server.storage import repository as repo
from server.storage.db import make_engine, session_factory, sqlite_url, upgrade
from spacecraft.nominal_limits import nominal_plan
from spacecraft.offline import fly_offline
from telemetry.layout import DEFAULT_LAYOUT
from telemetry.limits import for_description, interpolated_commands
from telemetry.uplink import plan_commands
from telemetry.wire import JointCommandMsg, TelemetryFrame, TelemetryMsg, decode_spacecraft, encode

#: the PTP's motion ends 54 s into the flight; its settling follows
SETTLED_NS = 60_000_000_000
REPEAT = 7


def flown_frames() -> tuple[list[TelemetryFrame], Any]:
    description = default_robot()
    plan = nominal_plan(description, "ptp")
    flight = fly_offline(plan, robot=description, seed=1)
    joints = [
        c
        for c in plan_commands(plan, epoch_ns=flight.epoch_ns, first_seq=0)
        if isinstance(c, JointCommandMsg)
    ]
    commanded = interpolated_commands(
        np.array([c.execute_time_ns for c in joints], dtype=np.int64),
        np.array([c.joints_rad for c in joints]),
    )
    return flight.frames, (description, commanded)


def measure(
    frames: list[TelemetryFrame], description: Any, commanded: Any, batch: int
) -> dict[str, float]:
    """Seconds for all ``frames`` in messages of ``batch``: decode, store, evaluate."""
    batches = [frames[i : i + batch] for i in range(0, len(frames), batch)]
    messages = [encode(TelemetryMsg(frames=b)) for b in batches]
    joints = np.array([f.joints_rad for f in frames])

    def decode() -> None:
        for text in messages:
            decode_spacecraft(text, DEFAULT_LAYOUT)

    # built once (a pass builds its evaluator once); each run starts from a fresh state
    evaluator = for_description(description, commanded=commanded)
    watch = evaluator.clearance
    assert watch is not None
    watch.clearances_m(joints[:1])  # coal's shapes built

    def evaluate_with(clearance: bool) -> float:
        def run() -> None:
            evaluator.reset()
            watch.reset()
            evaluator.clearance = watch if clearance else None
            for b in batches:
                evaluator.evaluate(b)

        return best_of(run, repeat=REPEAT)

    def clearance_only() -> None:
        watch.reset()
        for i in range(0, len(frames), batch):
            watch.clearances_m(joints[i : i + batch])

    out = {
        "decode": best_of(decode, repeat=REPEAT),
        "evaluate": evaluate_with(True),
        "evaluate_without_clearance": evaluate_with(False),
        "clearance_watch": best_of(clearance_only, repeat=REPEAT),
    }
    with tempfile.TemporaryDirectory() as tmp:
        engine = make_engine(sqlite_url(Path(tmp)))
        upgrade(engine)
        factory = session_factory(engine)

        def store() -> None:
            pass_id = new_pass(factory)
            for b in batches:
                with factory() as session:
                    repo.ingest_frames(
                        session=session, pass_id=pass_id, frames=b, reception_time_ns=1
                    )
                    session.commit()

        out["store"] = best_of(store, repeat=REPEAT)
        engine.dispose()
    return out


def main() -> None:
    frames, (description, commanded) = flown_frames()
    # the PTP's settling: the arm holds still (the live clearance answers from its bounds)
    still = [f for f in frames if f.generation_time_ns >= frames[0].generation_time_ns + SETTLED_NS]
    figures: dict[str, Any] = {"frames": len(frames), "frames_arm_still": len(still)}
    ratios = {}
    for name, subset, batch in (
        ("ptp_batch_10", frames, 10),
        ("ptp_batch_50", frames, 50),
        ("arm_still_batch_50", still, 50),
    ):
        seconds = measure(subset, description, commanded, batch)
        ingest = seconds["decode"] + seconds["store"]
        ratios[name] = seconds["evaluate"] / ingest
        n = len(subset)
        figures[name] = {
            **{f"{k}_us_per_frame": round(v / n * 1e6, 2) for k, v in seconds.items()},
            "evaluate_vs_decode": round(seconds["evaluate"] / seconds["decode"], 3),
            "evaluate_vs_decode_and_store": round(ratios[name], 3),
        }
    emit(
        "limits",
        figures,
        {f"{name}_evaluate_lt_10pct_of_decode_and_store": r < 0.10 for name, r in ratios.items()},
    )


if __name__ == "__main__":
    main()
