"""Rehearse each fault kind inside the PTP motion: one ``hikoboshi demo --experiments ptp
--fault SPEC`` per fault, and one table of what each run showed.

When the PTP motion runs: the plan's own timing (its ``ptp: A->B`` segment, planned here as
the ground plans it) after the plan's ``t = 0``, which the ground puts
:func:`hikoboshi.demo.expected_epoch_s` onboard seconds after the spacecraft's start at the
demo's speed (its start lead). Each fault goes ``--at`` of the way through that motion (a
stuck joint needs the motion still ahead of it). Each row then says where the fault really
began (the truth log) against where the motion really ran (the summary's segments).

    .venv/bin/python scripts/fault_rehearsal.py [--speed 20] [--out out/rehearsal]
        [--at 0.2] [--fault joint3-stuck --fault bump,nms=30,axis=y ...]

A fault is given without its time (``NAME[,key=value...]``); by default one of each kind,
with parameters that show something in a PTP motion (docs/spacecraft.md, "Faults": the
default attitude bias of 3 deg sits on the red limit, 4 deg is past it; a 30 N m s bump).
Each run's summary, report and recording are under ``OUT/<fault>/``; ``OUT/rehearsal.json``
holds the rows. Columns: the fault and the onboard s it began; the alarm that tells it
(the vehicle's safing trigger's, else the worst limit alarm from a frame) with the onboard s
each band was crossed, when the ground raised it (the frame's time, then the ground's on the
onboard clock); when the vehicle safed; the commands executed after safing; the pass's final
state; the demo's exit status. Heavy: a whole PTP pass per fault (about 40 s each at 20x on
two busy cores).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from planner.limits import SEVERITY_RANK, Severity

#: One fault of each kind (without its time), with parameters that show in a PTP motion.
DEFAULT_FAULTS = (
    "joint3-stuck",
    "joint3-drift",
    "wheel1-fail",
    "attitude-bias,deg=4",
    "bump,nms=30,axis=y",
)
#: The PTP experiment's motion among the plan's segments.
PTP_MOTION = "ptp: A->B"


def ptp_motion_plan_s() -> tuple[float, float]:
    """The PTP motion's start and end, plan s (the plan ``demo --experiments ptp`` asks for)."""
    from planner.dynamics import DynamicsWorkspace
    from planner.model import default_model
    from planner.schedule import PassParams, plan_pass

    plan = plan_pass(DynamicsWorkspace(default_model()), PassParams(experiments=("ptp",)))
    segment = next(s for s in plan.segments if s.name == PTP_MOTION)
    return segment.t_start_s, segment.t_end_s


def spec_at(fault: str, t_s: float) -> str:
    """``NAME[,key=value...]`` with its time: ``bump,nms=30`` at 90 -> ``bump@90,nms=30``."""
    name, sep, params = fault.partition(",")
    return f"{name.strip()}@{t_s:.2f}" + (f",{params}" if sep else "")


def _where(alarm: Mapping[str, Any]) -> str:
    return " ".join(p for p in (alarm["quantity"], alarm["channel"]) if p)


def primary_alarm(summary: Mapping[str, Any]) -> dict[str, Any] | None:
    """The alarm that tells the fault: the limit alarm of the vehicle's safing trigger, else
    the worst limit alarm raised on a frame (the earliest of equals); None when none was."""
    items = [
        a
        for a in summary["alarms"]["items"]
        if a["source"] == "limit" and a["raised_frame_s"] is not None
    ]
    trigger = summary["safing"]["trigger"]
    if trigger:
        for alarm in items:
            if (alarm["quantity"], alarm["channel"]) == (trigger["quantity"], trigger["channel"]):
                return dict(alarm)
    if not items:
        return None
    worst = min(items, key=lambda a: (-SEVERITY_RANK[Severity(a["severity"])], a["raised_frame_s"]))
    return dict(worst)


def row(summary: Mapping[str, Any], exit_status: int | None = None) -> dict[str, Any]:
    """One run's key numbers (onboard s from the spacecraft's start)."""
    safing = summary["safing"]
    began = safing["truth_faults"][0] if safing["truth_faults"] else None
    ptp = next((s for s in summary["segments"] if s["name"] == PTP_MOTION), None)
    fault_s = None if began is None else began["onboard_s"]
    inside = None
    if ptp is not None and fault_s is not None and ptp["onboard_start_s"] is not None:
        inside = ptp["onboard_start_s"] <= fault_s <= ptp["onboard_end_s"]
    alarm = primary_alarm(summary)
    return {
        "fault": ", ".join(summary["faults"]),
        "fault_s": fault_s,
        "ptp_s": None if ptp is None else [ptp["onboard_start_s"], ptp["onboard_end_s"]],
        "inside_ptp": inside,
        "alarm": None if alarm is None else _where(alarm),
        "severity": None if alarm is None else alarm["severity"],
        "crossings": {} if alarm is None else alarm["crossings"],
        "raised_frame_s": None if alarm is None else alarm["raised_frame_s"],
        "raised_ground_s": None if alarm is None else alarm["raised_ground_s"],
        "safed_s": safing["since_s"],
        "safing_trigger": None if not safing["trigger"] else _where(safing["trigger"]),
        "ground_heard_safing_s": safing["ground_heard_s"],
        "commands_executed_after_safing": safing["commands_executed_after_safing"],
        "final_state": summary["final_state"],
        "alarms_above_watch": summary["alarms"]["above_watch"],
        "ok": summary["verdict"]["ok"],
        "exit_status": exit_status,
    }


def _s(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def table(rows: Sequence[Mapping[str, Any]]) -> str:
    """The rows as a plain-text table (onboard s from the spacecraft's start)."""
    header = (
        "fault",
        "began (in PTP)",
        "alarm",
        "bands crossed",
        "raised frame/ground",
        "safed",
        "cmds after",
        "state",
        "exit",
    )
    lines = [header]
    for r in rows:
        inside = {True: "yes", False: "NO", None: "?"}[r["inside_ptp"]]
        lines.append(
            (
                r["fault"],
                f"{_s(r['fault_s'])} ({inside})",
                "-" if r["alarm"] is None else f"{r['alarm']} {r['severity']}",
                " ".join(f"{band} {_s(t)}" for band, t in r["crossings"].items()) or "-",
                f"{_s(r['raised_frame_s'])}/{_s(r['raised_ground_s'])}",
                _s(r["safed_s"]),
                "-"
                if r["commands_executed_after_safing"] is None
                else str(r["commands_executed_after_safing"]),
                r["final_state"],
                "-" if r["exit_status"] is None else str(r["exit_status"]),
            )
        )
    widths = [max(len(line[i]) for line in lines) for i in range(len(header))]
    return "\n".join(
        "  ".join(cell.ljust(width) for cell, width in zip(line, widths, strict=True)).rstrip()
        for line in lines
    )


def run_one(spec: str, out: Path, speed: float) -> tuple[dict[str, Any] | None, int]:
    """One demo run with ``spec``: its summary (None when it stopped before writing one)
    and exit status."""
    command = [
        sys.executable,
        "-m",
        "hikoboshi",
        "demo",
        "--experiments",
        "ptp",
        "--speed",
        repr(speed),
        "--port",
        "0",
        "--json",
        "--out",
        str(out),
        "--fault",
        spec,
    ]
    summary_path = out / "summary.json"
    summary_path.unlink(missing_ok=True)
    result = subprocess.run(command, capture_output=True, text=True, timeout=1800)
    if not summary_path.exists():
        sys.stderr.write(f"{spec}: the demo stopped (status {result.returncode}):\n")
        sys.stderr.write(result.stderr[-2000:] + "\n")
        return None, result.returncode
    summary: dict[str, Any] = json.loads(summary_path.read_text())
    return summary, result.returncode


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--speed", type=float, default=20.0, help="the demo's --speed")
    parser.add_argument("--out", type=Path, default=Path("out/rehearsal"))
    parser.add_argument(
        "--at", type=float, default=0.2, help="how far through the PTP motion (0..1)"
    )
    parser.add_argument(
        "--fault",
        action="append",
        help="NAME[,key=value...] without its time; repeatable (default: one of each kind)",
    )
    args = parser.parse_args(argv)
    if not 0.0 <= args.at <= 1.0:
        parser.error(f"--at {args.at} must lie in [0, 1]")
    from hikoboshi.demo import expected_epoch_s

    start_s, end_s = ptp_motion_plan_s()
    epoch_s = expected_epoch_s(args.speed)
    t_s = epoch_s + start_s + args.at * (end_s - start_s)
    print(
        f"PTP motion: plan t {start_s:.2f}-{end_s:.2f} s; the plan's t = 0 expected at onboard "
        f"{epoch_s:.2f} s at {args.speed:g}x, so the motion at onboard "
        f"{epoch_s + start_s:.2f}-{epoch_s + end_s:.2f} s; each fault at {t_s:.2f} s",
        flush=True,
    )
    rows = []
    for fault in args.fault or DEFAULT_FAULTS:
        spec = spec_at(fault, t_s)
        name = fault.partition(",")[0].strip()
        print(f"running the demo with --fault {spec} ...", flush=True)
        summary, status = run_one(spec, args.out / name, args.speed)
        if summary is None:
            continue
        rows.append(row(summary, status))
        print(table(rows[-1:]).splitlines()[-1], flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "rehearsal.json").write_text(json.dumps(rows, indent=2) + "\n")
    print("\nTimes: onboard s from the spacecraft's start\n" + table(rows))
    return 0 if len(rows) == len(args.fault or DEFAULT_FAULTS) else 1


if __name__ == "__main__":
    sys.exit(main())
