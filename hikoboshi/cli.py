"""``hikoboshi``: the command line. Each command group is a module of its own that adds its
commands to :data:`app` (its ``register``); ``--help`` lists them in the order they are
added here. What the groups share is in :mod:`hikoboshi.cli_common`."""

from __future__ import annotations

import importlib.metadata
from typing import Annotated

import typer

from hikoboshi import (
    calibrate_cli,
    demo_cli,
    model_cli,
    planning_cli,
    post_cli,
    robot_cli,
    serve_cli,
    spacecraft_cli,
    windows_cli,
)
from hikoboshi.output import HELP_MARKUP

__all__ = ["app", "main"]

#: The top-level help (the module docstring is for readers of the code).
HELP = (
    "Hikoboshi, the ground system for the ETS-VII space robot: plan experiments, fly them "
    "against the simulated spacecraft through the ground service, and analyse, report and "
    "export the passes. Commands that report something take --json."
)

app = typer.Typer(
    rich_markup_mode=HELP_MARKUP, no_args_is_help=True, add_completion=False, help=HELP
)
model_cli.register(app)  # model urdf|mjcf|quantities|limits
post_cli.register(app)  # report, mcap export|import, export telemetry
windows_cli.register(app)  # windows
robot_cli.register(app)  # robot check
planning_cli.register(app)  # plan
demo_cli.register(app)  # demo, ptp-demo
spacecraft_cli.register(app)  # spacecraft
serve_cli.register(app)  # serve
calibrate_cli.register(app)  # calibrate


def _version(shown: bool) -> None:
    if shown:
        typer.echo(f"hikoboshi {importlib.metadata.version('hikoboshi')}")
        raise typer.Exit()


@app.callback()
def _options(
    version: Annotated[
        bool,
        typer.Option(
            "--version", callback=_version, is_eager=True, help="Print the version and exit."
        ),
    ] = False,
) -> None:
    """The options of the command line as a whole."""


def main() -> None:
    app()
