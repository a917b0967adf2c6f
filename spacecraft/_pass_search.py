"""The attitude law searched on the demo pass itself (docs/spacecraft.md "How the law was
chosen"): SciPy's differential evolution over the law's design parameters, each candidate
flown through the vehicle on the whole pass schedule and analysed as the report does, scored
by its worst seed with a margin on every row of the paper the law shapes.

    python -m spacecraft._pass_search [--seeds 7,2] [--maxiter 12] [--popsize 8]
        [--workers 2] [--log search.jsonl]
    python -m spacecraft._pass_search --check 0.030,0.55,11,0.3,0.035 --seeds 1,2,3,5,7

A flight and its analysis take about 7 s (the plan's commands do not depend on the law, so
the pass is planned once); the search that chose the defaults flew 286 laws on two seeds,
about an hour on two cores. ``hikoboshi calibrate`` fits on the calibration plans through
the prediction instead (seconds per evaluation, one noise-free flight); this is the slower,
faithful score.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from multiprocessing import Pool
from typing import Any

import numpy as np
from scipy.optimize import differential_evolution

from planner.plan import Plan

__all__ = ["BOUNDS", "NAMES", "cost", "margins", "score_law", "values_of"]

#: The searched parameters, in the search's space (the torque limit as its logarithm).
NAMES = ("bandwidth_radps", "damping_ratio", "rate_filter_tau_s", "log_torque_limit_nm",
         "dead_band_deg")  # fmt: skip
BOUNDS = ((0.018, 0.040), (0.4, 1.2), (0.0, 25.0), (math.log(0.02), math.log(0.3)), (0.0, 0.08))

#: What a margin of 1 is worth in each row's unit: beyond it a row counts as comfortable.
_SCALE = {"s": 10.0, "deg": 0.05, "start_deg": 0.02, "leg_deg": 0.01, "leg_s": 1.0}


def values_of(x: Sequence[float]) -> dict[str, float]:
    """The law's design parameters (``spacecraft.calibration.gains_from_parameters``) of a
    point of the search."""
    v = dict(zip(NAMES, (float(c) for c in x), strict=True))
    v["torque_limit_nm"] = math.exp(v.pop("log_torque_limit_nm"))
    return v


def margins(analysis: Any) -> dict[str, float]:
    """Every row of the paper the law shapes, as a margin in units of ``_SCALE`` (positive:
    the row holds; 1 or more: comfortably), with the criteria of
    ``telemetry.analysis.paper.PAPER_RESULTS``. ``analysis``: a ``PassAnalysis``."""
    from telemetry.analysis.paper import PAPER_RESULTS

    lim = {r.id: r.limits for r in PAPER_RESULTS}
    reaction, plane = analysis.reaction, analysis.phase_plane
    (ptp,) = reaction.motion("ptp")
    legs = reaction.motion("reactionless")
    a, b, c = (plane.variant(v) for v in ("feedback", "feedforward", "offset"))
    out: dict[str, float] = {}

    p = lim["ptp_settling"]
    settle = math.inf if ptp.settling_time_s is None else ptp.settling_time_s
    lo, hi = (p["flight_s"] * (1 + k * p["relative_tolerance"]) for k in (-1, 1))
    out["ptp_settling"] = min(settle - lo, hi - settle) / _SCALE["s"]

    little = lim["reactionless_little_disturbance"]
    for leg in legs:
        peak = leg.peak_excursion_deg if leg.peak_excursion_deg is not None else math.inf
        leg_settle = leg.settling_time_s if leg.settling_time_s is not None else math.inf
        out["leg_peak"] = min(
            out.get("leg_peak", math.inf),
            (little["excursion_ratio"] * ptp.peak_excursion_deg - peak) / _SCALE["leg_deg"],
        )
        out["leg_settling"] = min(
            out.get("leg_settling", math.inf), (little["settling_s"] - leg_settle) / _SCALE["leg_s"]
        )

    fb = lim["coordination_feedback_range"]
    out["feedback_min"] = (fb["tolerance_deg"] - abs(a.pitch_min_deg - fb["min_deg"])) / _SCALE[
        "deg"
    ]
    out["feedback_max"] = (fb["tolerance_deg"] - abs(a.pitch_max_deg - fb["max_deg"])) / _SCALE[
        "deg"
    ]
    ff = lim["coordination_feedforward"]
    out["feedforward_dip"] = (b.first_dip_deg - ff["first_dip_deg"]) / _SCALE["deg"]
    over = b.pitch_max_deg - max(a.pitch_max_deg, c.pitch_max_deg)
    out["feedforward_overshoot"] = (over - ff["peak_margin_deg"]) / _SCALE["deg"]
    others = min(a.pitch_range_deg, b.pitch_range_deg)
    out["offset_range"] = (others - c.pitch_range_deg) / _SCALE["deg"]
    # A variant not settled by its window's end ranks slowest (settling_rank_s is inf); the
    # margin counts it as settling at its window's end.
    ranks = {v.label: (v.settling_rank_s, v.window_end_s - v.motion_end_s) for v in (a, b, c)}
    ranked = {k: r if r is not None and math.isfinite(r) else w for k, (r, w) in ranks.items()}
    c_rank = ranks["(c)"][0]
    out["offset_settling"] = (
        (min(ranked["(a)"], ranked["(b)"]) - ranked["(c)"]) / _SCALE["s"]
        if c_rank is not None and math.isfinite(c_rank)
        else -3.0
    )
    start = lim["coordination_start"]["max_deg"]
    for v in (a, b, c):
        s = v.start_pitch_deg if v.start_pitch_deg is not None else math.inf
        out[f"start_{v.label}"] = (start - abs(s)) / _SCALE["start_deg"]
    return out


def cost(per_seed: Iterable[Mapping[str, float]]) -> tuple[float, dict[str, float]]:
    """The worst margin of each row over the seeds, and the search's cost: the sum of the
    squared shortfalls below 1 (0: every row comfortable on every seed)."""
    worst: dict[str, float] = {}
    for m in per_seed:
        for k, v in m.items():
            worst[k] = min(worst.get(k, math.inf), v)
    return sum(max(0.0, 1.0 - v) ** 2 for v in worst.values()), worst


def score_law(plan: Plan, values: Mapping[str, float], seed: int) -> dict[str, float]:
    """Fly ``plan`` (the demo pass's) through the vehicle with the law of ``values`` and
    sensor noise seed ``seed``; the margins of its analysis."""
    from planner.dynamics import DynamicsWorkspace
    from planner.model import default_model
    from spacecraft.calibration import gains_from_parameters
    from spacecraft.offline import fly_offline
    from spacecraft.vehicle_config import VehicleConfig
    from telemetry.analysis import analyse_pass
    from telemetry.recording import PassRecording

    gains = gains_from_parameters(DynamicsWorkspace(default_model()), values)
    config = VehicleConfig(
        acs_gains=gains, initial_joints_rad=tuple(float(q) for q in plan.initial_joints_rad)
    )
    flight = fly_offline(plan, config, seed=seed)
    recording = PassRecording.from_frames("search", plan, flight.epoch_ns, flight.frames)
    return margins(analyse_pass(recording))


_PLAN: Plan | None = None
_SEEDS: tuple[int, ...] = ()


def _init(plan: Plan, seeds: tuple[int, ...]) -> None:
    global _PLAN, _SEEDS
    _PLAN, _SEEDS = plan, seeds


def _evaluate(x: Sequence[float]) -> tuple[float, dict[str, float], dict[str, float]]:
    assert _PLAN is not None
    values = values_of(x)
    total, worst = cost(score_law(_PLAN, values, seed) for seed in _SEEDS)
    return total, worst, values


class _Objective:
    """Differential evolution's objective and its log: one JSON line per law."""

    def __init__(self, log: Callable[[dict[str, Any]], None]) -> None:
        self.log = log
        self.best = math.inf

    def batch(self, func: Callable[..., Any], xs: Iterable[Sequence[float]]) -> list[float]:
        costs = []
        for total, worst, values in func(_evaluate, list(xs)):
            self.best = min(self.best, total)
            self.log({"values": values, "cost": total, "worst": worst})
            costs.append(total)
        return costs


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m spacecraft._pass_search", description=__doc__)
    ap.add_argument("--seeds", default="7,2", help="sensor-noise seeds, comma-separated")
    ap.add_argument("--maxiter", type=int, default=12)
    ap.add_argument("--popsize", type=int, default=8)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--log", default="pass_search.jsonl", help="one JSON line per law flown")
    ap.add_argument(
        "--check",
        help="score one law instead: wn (rad/s), zeta, tau (s), torque limit (N m), dead band "
        "(deg), comma-separated",
    )
    args = ap.parse_args(argv)
    seeds = tuple(int(s) for s in args.seeds.split(","))

    from planner.dynamics import DynamicsWorkspace
    from planner.model import default_model
    from planner.schedule import plan_pass

    plan = plan_pass(DynamicsWorkspace(default_model()))
    if args.check:
        wn, zeta, tau, torque, band = (float(v) for v in args.check.split(","))
        values = {"bandwidth_radps": wn, "damping_ratio": zeta, "rate_filter_tau_s": tau,
                  "torque_limit_nm": torque, "dead_band_deg": band}  # fmt: skip
        for seed in seeds:
            m = score_law(plan, values, seed)
            print(f"seed {seed}: " + ", ".join(f"{k} {v:+.2f}" for k, v in m.items()), flush=True)
        return

    started = time.monotonic()
    count = 0

    def log(row: dict[str, Any]) -> None:
        nonlocal count
        count += 1
        with open(args.log, "a", encoding="utf-8") as f:
            f.write(json.dumps(row) + "\n")
        print(
            f"\r{count} laws, best cost {objective.best:.3f}, {time.monotonic() - started:.0f} s",
            end="",
            file=sys.stderr,
            flush=True,
        )

    objective = _Objective(log)
    with Pool(args.workers, initializer=_init, initargs=(plan, seeds)) as pool:
        result = _run(objective, pool, args)
    print(file=sys.stderr)
    print(json.dumps({"values": values_of(result.x), "cost": float(result.fun)}))


def _run(objective: _Objective, pool: Any, args: argparse.Namespace) -> Any:
    def vectorised(xs: np.ndarray) -> np.ndarray:
        return np.array(objective.batch(pool.map, xs.T))

    return differential_evolution(
        vectorised,
        BOUNDS,
        popsize=args.popsize,
        maxiter=args.maxiter,
        vectorized=True,
        updating="deferred",
        seed=13,
        polish=False,
        tol=0,
        init="sobol",
    )


if __name__ == "__main__":
    main()
