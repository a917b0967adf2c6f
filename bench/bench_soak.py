"""Soak: passes flown back to back on one ground process, and whether its memory,
threads, open files and database stay flat.

``hikoboshi serve`` runs as its own process on loopback, with one ``hikoboshi spacecraft``
at ``--time-scale`` (20x). This process flies ``--passes`` (30) short passes one after the
other as an operator would, through the REST API: two PTP plans (A -> B and B -> A, joints
1 and 4 by 10 degrees, a quarter-second settle: 7.25 s onboard each) planned once, then
for each pass ``POST /api/passes`` of the next one, ``POST .../start`` with its
confirmation, the pass polled until it ends, its telemetry and commands settled, its
summary read and its recording downloaded once.

After each pass it records the server process's resident memory (``VmRSS``), threads
(``/proc/PID/task``), open files (``/proc/PID/fd``), the database's size (SQLite: the file
and its WAL; PostgreSQL: ``pg_total_relation_size`` over the schema's tables) and the
pass's outcome. A frame's row size is the database's own measure of a stored frame record
(SQLite: the ``dbstat`` payload of ``telemetry_frames`` per row; PostgreSQL:
``pg_column_size`` of the row, averaged), without its indexes.

The verdict, after ``--warmup`` passes (5): each quantity's least-squares slope per pass,
and the change it makes over the window against its own level. Flat (our choice): threads
and open files average less than one more over the window's second half than over its
first (:func:`halves_change`: a pool's connection that opens once is a step, not a
trend); resident memory grows by less than
:data:`RSS_FLAT_FRACTION` of its level per pass. The database must grow, by what the passes
store: its slope per pass is compared with the frames a pass stored times their row size
(the ratio is the cost of indexes, pages, commands and events on top of the frame rows).

Every pass must end ``complete`` with every command executed at its tag and no frame
missing. The per-pass table and the verdict go to stderr, the JSON to stdout, and
``OUT/soak.png`` plots the four series (``OUT/soak.json`` keeps every sample).

    PYTHONPATH=$PWD .venv/bin/python bench/bench_soak.py [--backend sqlite|postgresql|both]
        [--passes 30] [--time-scale 20] [--warmup 5] [--out out/bench/soak] [--no-recording]

PostgreSQL: a fresh schema on the server of ``DATABASE_URL`` (or
``postgresql+psycopg://postgres@127.0.0.1:5432/test``), dropped afterwards.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import httpx
from _common import emit, free_port
from _soak_probes import PostgresSize, SqliteSize, process_figures

ROOT = Path(__file__).resolve().parents[1]
OPERATOR_TOKEN = "soak-operator-token-0123456789"
SPACECRAFT_TOKEN = "soak-spacecraft-token-01234567"
TOKENS = f"{OPERATOR_TOKEN}=otto:operator,{SPACECRAFT_TOKEN}=ets7:spacecraft"
OPERATOR = {"Authorization": f"Bearer {OPERATOR_TOKEN}"}
POSE_A = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
POSE_B = (10.0, 0.0, 0.0, 10.0, 0.0, 0.0)
TERMINAL_STATES = ("complete", "aborted", "safed")
#: Resident memory is flat when it grows by less than this fraction of its level per pass
#: (our choice: 0.2 % a pass is 1.06x over 30 passes, and would show at once as a leak of a
#: pass's frames or commands, some megabytes each).
RSS_FLAT_FRACTION = 0.002
#: Guards against a hang (wall s), not timing assertions.
PASS_GUARD_S = 300.0
SETTLE_GUARD_S = 60.0


@dataclass
class Sample:
    """One pass as flown, and the server's figures after it."""

    n: int
    state: str
    state_reason: str | None
    wall_s: float
    #: wall s from the start to the pass's end, from there to settled, and the download
    phases: dict[str, float]
    commands_total: int
    commands_executed_at_tag: int
    commands_expired: int
    frames_stored: int
    frames_missing: int | None
    recording_bytes: int
    rss_bytes: int
    threads: int
    open_files: int
    db_bytes: int
    frame_row_bytes: float

    @property
    def clean(self) -> bool:
        return (
            self.state == "complete"
            and self.commands_executed_at_tag == self.commands_total > 0
            and self.frames_missing == 0
        )


@contextmanager
def _process(
    args: Sequence[str], env: dict[str, str], log: Path
) -> Iterator[subprocess.Popen[bytes]]:
    with log.open("ab") as out:
        proc = subprocess.Popen(args, env=env, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT)
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def _until(what: str, guard_s: float, check: Any, *alive: subprocess.Popen[bytes]) -> Any:
    """Poll ``check`` until it returns something true (returned); a guard against a hang."""
    deadline = time.monotonic() + guard_s
    while not (value := check()):
        for proc in alive:
            if proc.poll() is not None:
                raise RuntimeError(f"{what}: a process exited with {proc.returncode}")
        if time.monotonic() > deadline:
            raise RuntimeError(f"{what}: not within {guard_s:.0f} s")
        time.sleep(0.1)
    return value


def _plan(api: httpx.Client, start: tuple[float, ...], goal: tuple[float, ...]) -> dict[str, Any]:
    parameters = {"start_joints_deg": start, "goal_joints_deg": goal, "settle_s": 0.25}
    response = api.post("/api/plans", json={"experiment": "ptp", "parameters": parameters})
    assert response.status_code == 201, response.text
    plan: dict[str, Any] = response.json()
    assert (plan.get("flight_rules") or {}).get("passed"), plan.get("flight_rules")
    return plan


def fly_pass(
    api: httpx.Client,
    plan: dict[str, Any],
    name: str,
    procs: Sequence[subprocess.Popen[bytes]],
    *,
    recording: bool,
) -> dict[str, Any]:
    """Schedule, start and follow one pass until it has ended and settled (the onboard clock
    past its telemetry window, no command outstanding, every frame of it stored or the
    guard run out); its summary, and the recording's size."""
    now = datetime.now(UTC)
    response = api.post(
        "/api/passes",
        json={
            "plan_id": plan["id"],
            "name": name,
            "aos_time": now.isoformat(),
            "los_time": (now + timedelta(seconds=float(plan["duration_s"]) + 600.0)).isoformat(),
            "relay": "TDRS (emulated)",
        },
    )
    assert response.status_code == 201, response.text
    pass_id = response.json()["id"]
    response = api.post(f"/api/passes/{pass_id}/start", json={"confirm": f"START {name}"})
    assert response.status_code == 200, response.text

    def ended() -> bool:
        return api.get(f"/api/passes/{pass_id}").json()["state"] in TERMINAL_STATES

    t0 = time.monotonic()
    _until(f"{name} ended", PASS_GUARD_S, ended, *procs)
    t1 = time.monotonic()

    def settled() -> dict[str, Any] | None:
        summary: dict[str, Any] = api.get(f"/api/passes/{pass_id}/summary").json()
        onboard = api.get("/api/link/status").json().get("onboard_time_ns")
        end = summary["telemetry_end_ns"]
        done = (
            end is not None
            and onboard is not None
            and onboard >= end
            and summary["commands_outstanding"] == 0
            and summary["frames_missing"] == 0
        )
        return summary if done else None

    try:
        summary = _until(f"{name} settled", SETTLE_GUARD_S, settled, *procs)
    except RuntimeError:  # reported as it is: the sample says what is missing
        summary = api.get(f"/api/passes/{pass_id}/summary").json()
    t2 = time.monotonic()
    size = 0
    if recording:
        with api.stream("GET", f"/api/passes/{pass_id}/recording.mcap", timeout=600.0) as r:
            assert r.status_code == 200, r.read()
            for chunk in r.iter_bytes():
                size += len(chunk)
    phases = {"flown_s": t1 - t0, "settled_s": t2 - t1, "downloaded_s": time.monotonic() - t2}
    return {**summary, "recording_bytes": size, "phases": phases}


def soak(
    backend: str, passes: int, time_scale: float, recording: bool, log_dir: Path
) -> list[Sample]:
    """Fly ``passes`` passes on one server on ``backend``; one sample per pass."""
    samples: list[Sample] = []
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp)
        size: SqliteSize | PostgresSize = (
            SqliteSize(data) if backend == "sqlite" else PostgresSize()
        )
        try:
            port = free_port()
            env = {
                **os.environ,
                "PYTHONPATH": str(ROOT),
                "HIKOBOSHI_DATA_DIR": str(data),
                "HIKOBOSHI_TOKENS": TOKENS,
            }
            env.pop("DATABASE_URL", None)
            if (url := size.database_url()) is not None:
                env["DATABASE_URL"] = url
            serve = [sys.executable, "-m", "hikoboshi", "serve", "--port", str(port)]
            base = f"http://127.0.0.1:{port}"
            with (
                _process(serve, env, log_dir / f"server-{backend}.log") as server,
                httpx.Client(base_url=base, headers=OPERATOR, timeout=120.0) as api,
            ):

                def healthy() -> bool:
                    try:
                        return api.get("/api/health").status_code == 200
                    except httpx.TransportError:
                        return False

                _until("the server's health", 60.0, healthy, server)
                there, back = _plan(api, POSE_A, POSE_B), _plan(api, POSE_B, POSE_A)
                vehicle = [
                    sys.executable, "-m", "hikoboshi", "spacecraft",
                    "--ground", f"ws://127.0.0.1:{port}/api/link", "--token", SPACECRAFT_TOKEN,
                    "--time-scale", repr(time_scale), "--seed", "4",
                ]  # fmt: skip
                with _process(vehicle, env, log_dir / f"spacecraft-{backend}.log") as craft:

                    def connected() -> bool:
                        return bool(api.get("/api/link/status").json()["connected"])

                    _until("the spacecraft's link", 60.0, connected, server, craft)
                    for n in range(1, passes + 1):
                        t0 = time.monotonic()
                        plan = there if n % 2 else back
                        summary = fly_pass(
                            api, plan, f"soak {n:02d}", (server, craft), recording=recording
                        )
                        rss, threads, fds = process_figures(server.pid)
                        sample = Sample(
                            n=n,
                            state=summary["state"],
                            state_reason=summary["state_reason"],
                            wall_s=time.monotonic() - t0,
                            phases=summary["phases"],
                            commands_total=summary["commands_total"],
                            commands_executed_at_tag=summary["commands_executed_at_tag"],
                            commands_expired=summary["commands_expired"],
                            frames_stored=summary["frames_stored"],
                            frames_missing=summary["frames_missing"],
                            recording_bytes=summary["recording_bytes"],
                            rss_bytes=rss,
                            threads=threads,
                            open_files=fds,
                            db_bytes=size.db_bytes(),
                            frame_row_bytes=size.frame_row_bytes(),
                        )
                        samples.append(sample)
                        phases = " ".join(f"{k} {v:.1f}" for k, v in sample.phases.items())
                        print(
                            f"{backend:>10} {_row(sample)}  ({phases})", file=sys.stderr, flush=True
                        )
        finally:
            size.close()
    return samples


HEADER = "pass  outcome    wall s  cmds at tag  frames  missing  RSS MiB  threads  fds  DB MiB"


def _row(s: Sample) -> str:
    outcome = s.state if s.clean else f"{s.state}!"
    missing = "-" if s.frames_missing is None else str(s.frames_missing)
    return (
        f"{s.n:4d}  {outcome:<9} {s.wall_s:6.1f}"
        f"  {s.commands_executed_at_tag:4d}/{s.commands_total:<4d}"
        f"  {s.frames_stored:6d}  {missing:>7}  {s.rss_bytes / 2**20:7.1f}  {s.threads:7d}"
        f"  {s.open_files:3d}  {s.db_bytes / 2**20:6.2f}"
    )


def slope(ys: Sequence[float]) -> float:
    """The least-squares slope of ``ys`` against 0, 1, 2, ... (per step)."""
    n = len(ys)
    if n < 2:
        return 0.0
    mean_x = (n - 1) / 2
    mean_y = sum(ys) / n
    sxx = sum((x - mean_x) ** 2 for x in range(n))
    return sum((x - mean_x) * (y - mean_y) for x, y in enumerate(ys)) / sxx


def halves_change(ys: Sequence[float]) -> float:
    """The mean of the window's second half less that of its first half. The rule for
    counts (threads, open files): a leak climbs through the window, while a pooled database
    connection that opens once (two files on SQLite: the database and its WAL) or a
    keep-alive socket that comes and goes steps or jitters by one to three. A least-squares
    line through such a step reads it as a trend: two 30-pass runs with the SQLite pool
    stepping from 18 to 21 files at pass 9 and staying there gave +1.2 over the window."""
    half = len(ys) // 2
    first, second = ys[:half], ys[len(ys) - half :]
    return sum(second) / len(second) - sum(first) / len(first)


def verdict(samples: Sequence[Sample], warmup: int) -> dict[str, Any]:
    """Slopes after ``warmup`` passes, each against its level; whether each holds."""
    window = list(samples[warmup:])
    if len(window) < 2:
        raise ValueError(f"need at least {warmup + 2} passes for a verdict after {warmup}")
    span = len(window) - 1
    out: dict[str, Any] = {"passes": len(samples), "window": [window[0].n, window[-1].n]}
    for key in ("rss_bytes", "threads", "open_files", "db_bytes"):
        ys = [float(getattr(s, key)) for s in window]
        level = sum(ys) / len(ys)
        k = slope(ys)
        out[key] = {
            "level": level,
            "slope_per_pass": k,
            "slope_per_pass_of_level": k / level if level else 0.0,
            "change_over_window": k * span,
            "first": ys[0],
            "last": ys[-1],
            "halves_change": halves_change(ys),
        }
    stored = [s.frames_stored * s.frame_row_bytes for s in window]
    db = out["db_bytes"]
    db["frame_bytes_per_pass"] = sum(stored) / len(stored)
    db["growth_over_frame_bytes"] = db["slope_per_pass"] / db["frame_bytes_per_pass"]
    db["frame_row_bytes"] = window[-1].frame_row_bytes
    out["flat"] = {
        "rss": out["rss_bytes"]["slope_per_pass_of_level"] < RSS_FLAT_FRACTION,
        "threads": abs(out["threads"]["halves_change"]) < 1.0,
        "open_files": abs(out["open_files"]["halves_change"]) < 1.0,
        "every_pass_clean": all(s.clean for s in samples),
    }
    return out


def _describe(backend: str, v: dict[str, Any]) -> str:
    rss, th, fd, db = v["rss_bytes"], v["threads"], v["open_files"], v["db_bytes"]
    lo, hi = v["window"]
    return "\n".join(
        [
            f"{backend}: passes {lo}-{hi} (after the first {lo - 1})",
            f"  RSS      {rss['level'] / 2**20:7.1f} MiB, {rss['slope_per_pass'] / 2**10:+8.1f}"
            f" KiB/pass ({100 * rss['slope_per_pass_of_level']:+.3f} % of level)"
            f" -> {'flat' if v['flat']['rss'] else 'GROWS'}",
            f"  threads  {th['level']:7.1f}, {th['slope_per_pass']:+.3f}/pass,"
            f" {th['first']:.0f} -> {th['last']:.0f}, halves {th['halves_change']:+.2f}"
            f" -> {'flat' if v['flat']['threads'] else 'GROWS'}",
            f"  fds      {fd['level']:7.1f}, {fd['slope_per_pass']:+.3f}/pass,"
            f" {fd['first']:.0f} -> {fd['last']:.0f}, halves {fd['halves_change']:+.2f}"
            f" -> {'flat' if v['flat']['open_files'] else 'GROWS'}",
            f"  database {db['slope_per_pass'] / 2**10:+8.1f} KiB/pass against"
            f" {db['frame_bytes_per_pass'] / 2**10:.1f} KiB of frame rows a pass"
            f" ({db['frame_row_bytes']:.0f} B each): x{db['growth_over_frame_bytes']:.2f}",
            f"  every pass complete, every command at its tag, no frame missing:"
            f" {v['flat']['every_pass_clean']}",
        ]
    )


def plot(runs: dict[str, list[Sample]], warmup: int, path: Path) -> None:
    """The four series per pass, a line per backend, the warm-up shaded."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10.0, 7.0), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, 2, sharex=True)
    series = (
        ("rss_bytes", "resident memory (MiB)", 2**20),
        ("threads", "threads", 1),
        ("open_files", "open files", 1),
        ("db_bytes", "database size (MiB)", 2**20),
    )
    for ax, (key, label, unit) in zip(axes.flat, series, strict=True):
        for backend, samples in runs.items():
            xs = [s.n for s in samples]
            ax.plot(xs, [getattr(s, key) / unit for s in samples], marker=".", label=backend)
        ax.axvspan(0.5, warmup + 0.5, color="0.92", zorder=0)
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("pass")
    axes[0][0].legend()
    fig.suptitle("hikoboshi serve: passes back to back (warm-up shaded)")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format="png")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--backend", choices=("sqlite", "postgresql", "both"), default="both")
    parser.add_argument("--passes", type=int, default=30)
    parser.add_argument("--time-scale", type=float, default=20.0)
    parser.add_argument("--warmup", type=int, default=5, help="passes left out of the slopes")
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "bench" / "soak")
    parser.add_argument("--no-recording", action="store_true", help="skip the downloads")
    args = parser.parse_args()
    if args.passes < args.warmup + 2:
        parser.error(f"--passes must be at least --warmup + 2 ({args.warmup + 2})")
    args.out.mkdir(parents=True, exist_ok=True)
    backends = ("sqlite", "postgresql") if args.backend == "both" else (args.backend,)
    runs: dict[str, list[Sample]] = {}
    verdicts: dict[str, dict[str, Any]] = {}
    for backend in backends:
        print(f"{backend}: {args.passes} passes at {args.time_scale:g}x", file=sys.stderr)
        print(f"{'backend':>10} {HEADER}", file=sys.stderr)
        runs[backend] = soak(backend, args.passes, args.time_scale, not args.no_recording, args.out)
        verdicts[backend] = verdict(runs[backend], args.warmup)
    for backend in backends:
        print(f"\n{backend}\n{HEADER}", file=sys.stderr)
        for sample in runs[backend]:
            print(_row(sample), file=sys.stderr)
        print(_describe(backend, verdicts[backend]), file=sys.stderr)
    plot(runs, args.warmup, args.out / "soak.png")
    doc = {
        "time_scale": args.time_scale,
        "warmup": args.warmup,
        "samples": {b: [asdict(s) for s in runs[b]] for b in backends},
        "verdicts": verdicts,
    }
    (args.out / "soak.json").write_text(json.dumps(doc, indent=2))
    print(f"wrote {args.out / 'soak.png'} and {args.out / 'soak.json'}", file=sys.stderr)
    emit(
        "soak",
        {"time_scale": args.time_scale, "verdicts": verdicts},
        {
            f"{backend}_{what}": ok
            for backend, v in verdicts.items()
            for what, ok in v["flat"].items()
        },
    )


if __name__ == "__main__":
    main()
