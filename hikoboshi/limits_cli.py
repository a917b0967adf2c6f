"""``hikoboshi model limits``: a robot's live limits, and with ``--fly`` the nominal worst each
band keeps clear of (spacecraft.nominal_limits; docs/robots.md, "Limits")."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Any, NoReturn

import typer

from hikoboshi.output import make_console

__all__ = ["register"]

err_console = make_console(stderr=True)


def _fail(reason: str) -> NoReturn:
    err_console.print(f"error: {reason}", markup=False, highlight=False, soft_wrap=True)
    raise typer.Exit(code=2)


def _seeds(text: str) -> tuple[int, ...]:
    try:
        seeds = tuple(int(s) for s in text.split(",") if s.strip())
    except ValueError:
        _fail(f"--seeds {text!r}: comma-separated whole numbers, e.g. 1,2,3")
    if not seeds or any(s < 0 for s in seeds):
        _fail(f"--seeds {text!r}: at least one seed, none negative")
    return seeds


def limits(
    robot: Annotated[
        Path | None,
        typer.Option(
            "--robot",
            help="Robot description (TOML, docs/robots.md); default: ETS-VII's shipped file.",
        ),
    ] = None,
    fly: Annotated[
        bool,
        typer.Option(
            "--fly",
            help="Fly the nominal pass offline (one flight per seed) and show each quantity's "
            "nominal worst and every band's margin over it.",
        ),
    ] = False,
    seeds: Annotated[
        str, typer.Option("--seeds", help="Sensor-noise seeds flown, comma-separated.")
    ] = "1,2,3,4,5",
    experiment: Annotated[
        str,
        typer.Option(
            "--experiment",
            help="What is flown: the whole pass (default) or one experiment (ptp, gjm, ...).",
        ),
    ] = "pass",
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """The robot's live limits (its [limits] over the built-in defaults); with --fly, the
    nominal worst of each quantity over a flown nominal pass and each band's margin."""
    from planner.description import default_robot, load_robot
    from planner.errors import PlannerError
    from spacecraft.nominal_limits import (
        fly_nominal,
        format_table,
        limits_table,
        nominal_plan,
    )

    flown = _seeds(seeds) if fly else ()
    try:
        description = default_robot() if robot is None else load_robot(robot)
        flights = []
        if flown:
            plan = nominal_plan(description, experiment)
            for seed in flown:
                err_console.print(
                    f"flying {description.name}'s {experiment} ({plan.duration_s:.0f} s), "
                    f"seed {seed}",
                    highlight=False,
                )
                flights.append(fly_nominal(description, plan, seed=seed))
    except PlannerError as exc:
        _fail(str(exc))
    rows = limits_table(description, flights)
    if as_json:
        doc: dict[str, Any] = {
            "robot": description.name,
            "experiment": experiment if flown else None,
            "seeds": list(flown),
            "rejected": [f.rejected for f in flights],
            "frames": [f.frames for f in flights],
            "quantities": [row.to_dict() for row in rows],
        }
        sys.stdout.write(json.dumps(doc, allow_nan=False) + "\n")
        return
    sys.stdout.write(f"{description.name}: live limits ({description.path})\n")
    if flown:
        rejected = sum(f.rejected for f in flights)
        sys.stdout.write(
            f"nominal worst over {experiment}, seeds {','.join(map(str, flown))} "
            f"({rejected} commands refused)\n"
        )
    sys.stdout.write(format_table(rows) + "\n")


def register(model_app: typer.Typer) -> None:
    """Add ``limits`` to ``hikoboshi model``."""
    model_app.command("limits")(limits)
