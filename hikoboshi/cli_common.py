"""What the command groups of ``hikoboshi`` share: the consoles they print through, the one
way a command fails (an error line on stderr, exit status 2: STYLE.md), the options several
commands take (``--robot``, ``--log-format``/``--log-level``, ``--foxglove-port``) and their
checks."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, NoReturn

import typer

from hikoboshi.output import make_console

console = make_console()
err_console = make_console(stderr=True)


def _fail(reason: str) -> NoReturn:
    """One line on stderr, exit status 2."""
    err_console.print(f"error: {reason}", markup=False, highlight=False, soft_wrap=True)
    raise typer.Exit(code=2)


LogFormatOption = Annotated[
    str,
    typer.Option(
        envvar="HIKOBOSHI_LOG_FORMAT",
        help="Log lines as text or json (one object a line); docs/operations.md, Logs",
    ),
]
LogLevelOption = Annotated[
    str,
    typer.Option(
        envvar="HIKOBOSHI_LOG_LEVEL", help="Least level logged: debug, info, warning, error"
    ),
]


FoxglovePortOption = Annotated[
    int | None,
    typer.Option(
        help="Stream the live pass to Foxglove on this port (ws://HOST:PORT, docs/mcap.md); "
        "needs the hikoboshi[foxglove] extra",
        show_default=False,
    ),
]


def _check_foxglove(port: int) -> None:
    """One error line and status 2 for a port out of range or the extra missing."""
    from server.services.foxglove_live import foxglove_missing

    if not 0 <= port <= 65535:
        _fail(f"--foxglove-port {port} must lie in [0, 65535]")
    missing = foxglove_missing()
    if missing is not None:
        _fail(f"--foxglove-port: {missing}")


def _configure_logging(log_format: str, log_level: str, stream: Any = None) -> None:
    """The one logging configuration (server/logs.py), or one error line and status 2."""
    from server.logs import configure_logging

    try:
        configure_logging(log_format, log_level, stream=stream)
    except ValueError as exc:
        _fail(str(exc))


RobotOption = Annotated[
    Path | None,
    typer.Option(
        "--robot",
        help="Robot description (TOML, docs/robots.md) or a shipped robot's name (ets7, "
        "orihime); default: ETS-VII as built in.",
    ),
]


def _load(robot: Path) -> Any:
    """The robot description at ``robot``, or one error line and exit status 2."""
    from planner.description import load_robot
    from planner.errors import PlannerError

    try:
        return load_robot(robot)
    except PlannerError as exc:
        _fail(str(exc))
