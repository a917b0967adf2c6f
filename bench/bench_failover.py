"""Fault scenarios on two grounds sharing one PostgreSQL, each run N times, and whether the
command lease keeps exactly one ground in command (docs/operations.md "One ground in
command"; issue 39, part 6).

The bench starts its own servers (:mod:`bench._servers`): a PostgreSQL cluster (or uses
``--database-url``) and a ``nats-server -js`` (unless ``--no-nats``), through which both
grounds publish their live messages, a stream per run. Each run gets a fresh schema on that
PostgreSQL, dropped afterwards; two
``hikoboshi serve`` processes, ``ground-a`` (the holder: started first) and ``ground-b``,
with a ``--lease-ttl`` lease (3 s) renewed every ``--lease-renew`` (ttl/6); the spacecraft
(in this process, given both grounds' URLs, at ``--scale``, 20x) and the demo pass (ETS-VII,
all experiments, ``planner.schedule.plan_pass``: 1544 s onboard, 6190 commands), or with
``--short`` the same plan of its first three experiments (PTP, reactionless, GJM: 570 s).
The fault falls at a random moment of the pass (``--seed``): a uniform fraction in
[0.05, 0.95) of the plan's duration after its epoch, onboard.

Scenarios:

- ``kill9-holder``: SIGKILL of ground A; B takes the lease once it expires and resumes.
- ``kill9-abort``: the same, and the operator aborts the pass on B as soon as B has written
  ``pass_resumed``; the abort's answer is timed (the pass ends ``aborted``, as asked).
- ``second-serve``: ground B is started by mistake at the fault moment (A keeps the pass),
  asked for its health, ``/api/command`` and a start (standby: 503, 409), left up
  ``--hold`` wall seconds (5) and stopped with SIGTERM.
- ``sigterm-holder``: SIGTERM to ground A with B waiting: A releases the lease at its stop.

Measured per run (the evidence, then what it shows):

- **sent**: the command messages the spacecraft's socket read, each logged with the ground
  it came from (the connection's port) and the wall clock at reading (loopback: the send).
  ``sent`` counts distinct commands, ``A`` and ``B`` those each ground sent, ``both`` those
  sent by A and then again by B (the resume sends again what was sent and not acknowledged:
  expected, the vehicle answers a copy with its stored acknowledgement).
- **2-gnd**, *sent by two grounds*: commands the old holder sent at or after the new
  holder took the lease (the lease row's ``acquired_s``, the database's clock, which is
  this host's) or sent its first command, whichever came first; in ``second-serve``, any
  command B sent. Must be 0. (After a SIGKILL the dead ground cannot send, so this is 0 by
  construction there; SIGTERM is where it can fail.)
- **at tag / exp / rej**: the pass summary's commands executed at their tag, expired,
  rejected; **!=veh**: commands whose stage differs from the vehicle's own record (or left
  open): must be 0.
- **frames / lost / twice**: the frames of the pass's telemetry window the spacecraft
  generated, those not stored, those stored more than once (rows per seq); both must be 0.
- **lease / send / resumed**: wall seconds from the fault (the signal) to B's lease
  acquisition, to B's first command sent, to ``pass_resumed`` (B's clock); ``-`` where B
  sent nothing (every command left was loaded and acknowledged before the fault).
- **health**: ``GET /api/health`` every 0.2 s on the ground that stays (B; A in
  ``second-serve``), from the fault to the takeover plus a second (in ``second-serve``
  B's life); p99 and worst in ms, and how many were not a 200.
- **abort**: the abort's answer on B (``kill9-abort``), ms.

A run breaks an invariant when a command was sent by two grounds, a frame was stored twice
or lost, a stage differs from the vehicle's record, a pass did not end ``complete`` (or
``aborted`` by the operator in ``kill9-abort``: a pass aborted by the vehicle's refusals
breaks it), or, in ``second-serve``, B wrote on the pass (``pass_resumed``,
``ground_stopped``, or the lease's token moved). The reasons are printed and the exit
status is 1. Progress goes to stderr, a table per scenario at the end, and the JSON to
stdout (``OUT/failover.json`` too); each run's ground logs stay under ``OUT``.

    PYTHONPATH=$PWD .venv/bin/python bench/bench_failover.py [--scenario kill9-holder]
        [--runs 3] [--scale 20] [--seed 1] [--lease-ttl 3] [--short] [--out out/bench/failover]
        [--database-url postgresql+psycopg://...] [--no-nats]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import random
import shutil
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import emit
from _failover import percentile
from _failover_runs import SCENARIOS, Options, Run, fly
from _servers import own_postgres

from tests.nats_server import nats_server

ROOT = Path(__file__).resolve().parents[1]
SHORT_EXPERIMENTS = ("ptp", "reactionless", "gjm")


def _ms(x: float | None) -> str:
    return "-" if x is None else f"{1000 * x:.0f}"


def _s(x: float | None) -> str:
    return "-" if x is None else f"{x:.1f}"


HEADER = (
    "run  fault  outcome    sent     A     B  both 2-gnd  at tag  exp  rej !=veh"
    "  frames lost twice  lease  send resumed  health p99/max (fail)  abort  ok"
)


def row(r: Run) -> str:
    health = f"{_ms(r.health_p99_s):>5}/{_ms(r.health_max_s):<5} ({r.health_failed})"
    return (
        f"{r.n:3d}  {r.fault_fraction:5.2f}  {r.outcome:<9} {r.sent:5d} {r.by_old:5d}"
        f" {r.by_new:5d} {r.resent:5d} {r.two_grounds:5d}  {r.at_tag:6d} {r.expired:4d}"
        f" {r.rejected:4d} {r.mismatched:5d}  {r.frames:6d} {r.lost:4d} {r.twice:5d}"
        f"  {_s(r.lease_s):>5} {_s(r.first_send_s):>5} {_s(r.resumed_s):>7}"
        f"  {health:>21}  {_ms(r.abort_s):>5}  {'yes' if not r.broken else 'NO'}"
    )


def describe(scenario: str, runs: Sequence[Run]) -> str:
    """The scenario's table and its takeover percentiles."""
    lines = [f"\n{scenario}: {len(runs)} runs", HEADER, *(row(r) for r in runs)]
    for what, label in (
        ("old_exit_s", "A's exit"),
        ("lease_s", "B's lease"),
        ("first_send_s", "B's first send"),
        ("resumed_s", "pass_resumed"),
    ):
        xs = [getattr(r, what) for r in runs if getattr(r, what) is not None]
        if xs:
            p50, p99 = percentile(xs, 0.5), percentile(xs, 0.99)
            lines.append(
                f"  fault to {label}: p50 {p50:.1f} s, p99 {p99:.1f} s,"
                f" max {max(xs):.1f} s ({len(xs)} runs)"
            )
    aborts = [r.abort_s for r in runs if r.abort_s is not None]
    if aborts:
        lines.append(
            f"  abort answered: p50 {_ms(percentile(aborts, 0.5))} ms, max {_ms(max(aborts))} ms"
        )
    broken = [r for r in runs if r.broken]
    lines.append(f"  runs that broke an invariant: {len(broken)} of {len(runs)}")
    for r in broken:
        lines.extend(f"    run {r.n}: {why}" for why in r.broken)
    return "\n".join(lines)


def plan_of(experiments: tuple[str, ...] | None) -> Any:
    """The demo's pass plan (or of ``experiments``), with its flight-rules report."""
    from planner.dynamics import DynamicsWorkspace
    from planner.model import default_model
    from planner.schedule import PassParams, plan_pass
    from tests.server.link.harness import with_flight_rules

    ws = DynamicsWorkspace(default_model())
    plan = (
        plan_pass(ws) if experiments is None else plan_pass(ws, PassParams(experiments=experiments))
    )
    return with_flight_rules(plan)


async def bench(options: Options, scenarios: Sequence[str], runs: int) -> dict[str, list[Run]]:
    experiments = SHORT_EXPERIMENTS if options.short else None
    t0 = time.monotonic()
    plan = await asyncio.to_thread(plan_of, experiments)
    print(
        f"plan: {'+'.join(experiments or ('all experiments',))}, {plan.duration_s:.0f} s onboard"
        f" ({plan.duration_s / options.scale:.0f} s at {options.scale:g}x), planned in"
        f" {time.monotonic() - t0:.0f} s; lease {options.lease_ttl_s:g} s renewed every"
        f" {options.lease_renew_s:g} s",
        file=sys.stderr,
        flush=True,
    )
    rng = random.Random(options.seed)
    results: dict[str, list[Run]] = {}
    for scenario in scenarios:
        results[scenario] = []
        for n in range(1, runs + 1):
            fraction = rng.uniform(0.05, 0.95)
            t_run = time.monotonic()
            try:
                result = await fly(options, plan, scenario, n, fraction)
            except Exception as exc:  # reported as a broken run, and the bench goes on
                result = Run.failed(scenario, n, fraction, f"{type(exc).__name__}: {exc}")
            result.wall_s = time.monotonic() - t_run
            results[scenario].append(result)
            print(
                f"{scenario} {n}/{runs} ({result.wall_s:.0f} s): {row(result)}",
                file=sys.stderr,
                flush=True,
            )
            steps = ", ".join(f"{k} {v:g}" for k, v in result.phases.items())
            for note in [*result.notes, *([f"wall s: {steps}"] if steps else [])]:
                print(f"  {note}", file=sys.stderr, flush=True)
            for why in result.broken:
                print(f"  BROKEN: {why}", file=sys.stderr, flush=True)
    return results


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--scenario", choices=(*SCENARIOS, "all"), action="append")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--scale", type=float, default=20.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--lease-ttl", type=float, default=3.0, help="wall s (the flight's: 10)")
    parser.add_argument("--lease-renew", type=float, default=None, help="wall s (ttl/6)")
    parser.add_argument("--short", action="store_true", help="PTP, reactionless, GJM only")
    parser.add_argument("--hold", type=float, default=5.0, help="second-serve: B's life, wall s")
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "bench" / "failover")
    parser.add_argument(
        "--database-url",
        default=None,
        help="a PostgreSQL server to use (default: a cluster of the bench's own, started here)",
    )
    parser.add_argument(
        "--no-nats", action="store_true", help="no JetStream (default: a nats-server of its own)"
    )
    args = parser.parse_args()
    if args.runs < 1:
        parser.error("--runs must be at least 1")
    chosen = args.scenario or ["all"]
    scenarios = list(SCENARIOS) if "all" in chosen else list(dict.fromkeys(chosen))
    renew = args.lease_renew if args.lease_renew is not None else min(1.0, args.lease_ttl / 6)
    args.out.mkdir(parents=True, exist_ok=True)
    with contextlib.ExitStack() as servers:
        server = args.database_url or servers.enter_context(own_postgres(args.out / "postgres"))
        nats = None
        if not args.no_nats:
            shutil.rmtree(args.out / "nats", ignore_errors=True)  # an earlier bench's streams
            (args.out / "nats").mkdir()
            nats = servers.enter_context(nats_server(args.out / "nats"))
        print(f"servers: PostgreSQL {server}, NATS {nats or '-'}", file=sys.stderr, flush=True)
        options = Options(
            scale=args.scale,
            seed=args.seed,
            lease_ttl_s=args.lease_ttl,
            lease_renew_s=renew,
            short=args.short,
            hold_s=args.hold,
            out=args.out,
            server_url=server,
            nats_url=nats,
        )
        results = asyncio.run(bench(options, scenarios, args.runs))
    for scenario, runs in results.items():
        print(describe(scenario, runs), file=sys.stderr)
    doc = {
        "options": {**asdict(options), "out": str(options.out)},
        "runs": {s: [asdict(r) for r in runs] for s, runs in results.items()},
    }
    (args.out / "failover.json").write_text(json.dumps(doc, indent=2))
    broken = {s: sum(1 for r in runs if r.broken) for s, runs in results.items()}
    takeover = [r.resumed_s for rs in results.values() for r in rs if r.resumed_s is not None]
    emit(
        "failover",
        {
            "runs": {s: len(rs) for s, rs in results.items()},
            "broken": broken,
            "resumed_p50_s": percentile(takeover, 0.5),
            "resumed_p99_s": percentile(takeover, 0.99),
        },
        {f"{s}_every_invariant": n == 0 for s, n in broken.items()},
    )
    if any(broken.values()):
        sys.exit(1)


if __name__ == "__main__":
    main()
