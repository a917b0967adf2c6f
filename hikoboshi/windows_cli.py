"""``hikoboshi windows``: a mission's contact windows over a span (mission.windows;
docs/missions.md)."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Annotated, Any, NoReturn

import typer
from rich.markup import escape
from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from hikoboshi.output import make_console

__all__ = ["register"]

console = make_console()
err_console = make_console(stderr=True)


def _fail(reason: str) -> NoReturn:
    err_console.print(f"error: {reason}", highlight=False, soft_wrap=True)
    raise typer.Exit(code=2)


def windows(
    mission_file: Annotated[
        Path,
        typer.Option(
            "--mission",
            help="Mission file (TOML, docs/missions.md), or a shipped mission's name (ets7-1999).",
        ),
    ],
    start: Annotated[
        str, typer.Option("--start", help="Start of the span, ISO 8601 with offset (…Z).")
    ],
    hours: Annotated[float, typer.Option("--hours", help="Length of the span, hours.")] = 24.0,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """The windows in which the vehicle sees each relay, acquisition in [start, start +
    hours): AOS and LOS (UTC), duration, net time after the pass margins, range and the
    one-way light time (vehicle, relay, ground terminal)."""
    from mission import MAX_HOURS, MissionError, compute_windows, load_mission, parse_utc

    if not math.isfinite(hours) or not 0.0 < hours <= MAX_HOURS:
        _fail(f"--hours {hours:g} is outside (0, {MAX_HOURS:g}]")
    try:
        start_utc = parse_utc(start)
        mission = load_mission(mission_file)
        with Progress(
            TextColumn(f"[bold]windows of {escape(mission.name)}"),
            BarColumn(),
            TextColumn("{task.fields[hours_done]:.0f}/{task.fields[hours_total]:.0f} h scanned"),
            TimeRemainingColumn(),
            console=err_console,
            disable=as_json or not err_console.is_terminal,
        ) as progress:
            task = progress.add_task("scan", total=1.0, hours_done=0.0, hours_total=hours)

            def on_progress(done_s: float, total_s: float) -> None:
                progress.update(
                    task,
                    completed=done_s,
                    total=total_s,
                    hours_done=done_s / 3600.0,
                    hours_total=total_s / 3600.0,
                )

            found = compute_windows(mission, start_utc, hours, on_progress)
    except MissionError as exc:
        _fail(str(exc))
    doc: dict[str, Any] = {
        "mission": mission.name,
        "vehicle": mission.vehicle,
        "start_utc": start_utc.strftime("%Y-%m-%dT%H:%M:%SZ"),
        "hours": hours,
        "processing_delay_s": mission.ground.processing_delay_s,
        "aos_margin_s": mission.margins.aos_margin_s,
        "los_margin_s": mission.margins.los_margin_s,
        "windows": [w.to_dict() for w in found],
    }
    if as_json:
        sys.stdout.write(json.dumps(doc, allow_nan=False) + "\n")
        return
    table = Table(
        box=None,
        pad_edge=False,
        title=f"{mission.vehicle}: {len(found)} windows from {doc['start_utc']}, {hours:g} h",
    )
    for column in ("relay", "day", "AOS UTC", "LOS UTC", "dur", "net", "range km", "light s"):
        table.add_column(column, no_wrap=True)
    for w in found:
        table.add_row(
            w.relay,
            w.aos_utc.strftime("%m-%d"),
            w.aos_utc.strftime("%H:%M:%S"),
            w.los_utc.strftime("%H:%M:%S") + ("+1" if w.los_utc.day != w.aos_utc.day else ""),
            f"{w.duration_s / 60.0:.1f}",
            f"{w.net_s / 60.0:.1f}",
            f"{w.min_range_km:.0f}-{w.max_range_km:.0f}",
            f"{w.light_time_min_s:.3f}-{w.light_time_max_s:.3f}",
        )
    console.print(table)
    console.print(
        "dur and net in minutes (+1: the next day); "
        f"net: less {mission.margins.aos_margin_s:g} s after AOS and "
        f"{mission.margins.los_margin_s:g} s before LOS; light time one way, vehicle -> relay "
        f"-> {mission.ground.terminal.name}; to the millisecond with --json",
        highlight=False,
    )


def register(app: typer.Typer) -> None:
    """Add ``windows`` to ``hikoboshi``."""
    app.command("windows")(windows)
