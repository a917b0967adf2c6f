"""``hikoboshi plan campaign``: the experiments over consecutive contact windows, one plan
file per pass and a campaign file (server/operations/campaign.py; docs/missions.md, Campaigns)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any, NoReturn

import typer
from rich.markup import escape
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from hikoboshi.output import make_console

__all__ = ["DEFAULT_OUT", "run_campaign"]

#: Where the files go without ``--out``.
DEFAULT_OUT = Path("out/campaign")

console = make_console()
err_console = make_console(stderr=True)


def _fail(reason: str) -> NoReturn:
    err_console.print(f"error: {reason}", markup=False, highlight=False, soft_wrap=True)
    raise typer.Exit(code=2)


def run_campaign(
    *,
    mission_file: Path | None,
    start: str | None,
    out: Path | None,
    robot: Any,
    assignment: str | None,
    as_json: bool,
) -> None:
    """Plan the campaign, write its files, print the passes (exit 3 when a plan fails a
    flight rule: the files are still written, with each plan's rules table)."""
    from mission import MissionError, load_mission, parse_utc
    from server.operations.campaign import parse_assignment, plan_campaign

    if mission_file is None:
        _fail("plan campaign needs --mission FILE (a mission file, docs/missions.md)")
    if start is None:
        _fail("plan campaign needs --start ISO8601 (e.g. 1999-09-30T00:00:00Z)")
    out_dir = DEFAULT_OUT if out is None else out
    if out_dir.exists() and not out_dir.is_dir():
        _fail(f"--out {out_dir} is not a directory")
    try:
        start_utc = parse_utc(start)
        mission = load_mission(mission_file)
        passes = None if assignment is None else parse_assignment(assignment)
        with Progress(
            TextColumn(f"[bold]campaign of {escape(mission.name)}"),
            BarColumn(),
            TextColumn("{task.description}"),
            TimeElapsedColumn(),
            console=err_console,
            disable=as_json or not err_console.is_terminal,
        ) as progress:
            task = progress.add_task("starting", total=1.0)

            def on_progress(done: int, total: int, what: str) -> None:
                progress.update(task, completed=done, total=total, description=escape(what))

            campaign = plan_campaign(
                mission, start_utc, robot=robot, assignment=passes, on_progress=on_progress
            )
    except MissionError as exc:
        _fail(str(exc))
    try:
        path = write_campaign(campaign, out_dir)
    except OSError as exc:
        _fail(f"cannot write to {out_dir}: {exc.strerror}")
    if as_json:
        doc = {"out": str(path), **campaign.to_dict()}
        for p in doc["passes"]:
            p["plan_file"] = str(out_dir / p["plan_file"])
        sys.stdout.write(json.dumps(doc, allow_nan=False) + "\n")
    else:
        _print(campaign, path)
    if not campaign.passed:
        raise typer.Exit(code=3)


def write_campaign(campaign: Any, out_dir: Path) -> Path:
    """``pass-N.plan.json`` for each pass (the plan format ``hikoboshi plan pass`` writes)
    and ``campaign.json``, in ``out_dir``; campaign.json's path."""
    from hikoboshi.planning_cli import write_atomically

    out_dir = Path(out_dir)
    for p in campaign.passes:
        write_atomically(out_dir / p.plan_file, p.plan.to_json())
    path = out_dir / "campaign.json"
    write_atomically(path, json.dumps(campaign.to_dict(), allow_nan=False, indent=1) + "\n")
    return path


def _print(campaign: Any, path: Path) -> None:
    table = Table(
        box=None,
        pad_edge=False,
        title=f"{campaign.mission.vehicle}: {len(campaign.passes)} passes from "
        f"{campaign.start_utc:%Y-%m-%dT%H:%M:%SZ}",
    )
    for column in (
        "pass",
        "relay",
        "AOS UTC",
        "first cmd",
        "plan s",
        "net s",
        "gap min",
        "experiments",
        "wheels at start N m s",
        "rules",
    ):
        table.add_column(column, no_wrap=True)
    for p in campaign.passes:
        rules = p.flight_rules
        table.add_row(
            str(p.index),
            p.window.relay,
            p.window.aos_utc.strftime("%H:%M:%S"),
            p.plan_start_utc.strftime("%H:%M:%S"),
            f"{p.plan.duration_s:.1f}",
            f"{p.window.net_s:.1f}",
            f"{p.gap_s / 60.0:.1f}",
            ",".join(p.experiments),
            "(" + ", ".join(f"{v:+.3f}" for v in p.start_state.wheel_momentum_nms) + ")",
            "-" if rules is None else ("pass" if rules.passed else "[bold red]FAIL[/bold red]"),
        )
    console.print(table)
    console.print(
        "wheels at start: the wheel momentum (base x, y, z) each pass starts with, the gaps' "
        "gravity gradient included; plan files beside the campaign file",
        highlight=False,
    )
    console.print(f"wrote {path}", highlight=False)
