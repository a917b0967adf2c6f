"""The robots the ground plans for: a plan request names one (``"robot": NAME``), never a path.

The server knows the descriptions shipped under ``examples/robots/`` (a source checkout) and
those it was given at start (``hikoboshi serve --robot FILE``, ``HIKOBOSHI_ROBOTS``:
:attr:`server.settings.Settings.robot_files`; one of these shadows a shipped one of the same
name). A client chooses among them by the description's ``name``; it cannot make the server
read any other file. Resolving reads each TOML's ``name`` only (milliseconds, no URDF): the
planning worker loads and validates the description it is handed.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

from planner.description import EXAMPLES_DIR, MAX_FILE_BYTES
from server.errors import ServiceError
from server.settings import Settings

__all__ = ["known_robots", "resolve_robot"]


def _name_of(path: Path) -> str | None:
    try:
        if path.stat().st_size > MAX_FILE_BYTES:
            return None
        with path.open("rb") as f:
            name = tomllib.load(f).get("name")
    except (OSError, tomllib.TOMLDecodeError):
        return None
    return name if isinstance(name, str) and name else None


def known_robots(settings: Settings) -> dict[str, Path]:
    """Robot name -> its description file: the shipped ones, then the server's own."""
    found: dict[str, Path] = {}
    shipped = sorted(EXAMPLES_DIR.glob("*/*.toml")) if EXAMPLES_DIR.is_dir() else []
    for path in [*shipped, *settings.robot_files]:
        name = _name_of(path)
        if name is not None:
            found[name] = path.resolve()
    return found


def resolve_robot(settings: Settings, name: str | None) -> Path | None:
    """The description file of the robot a request names (None: ETS-VII as built in);
    422 ``unknown_robot`` naming the known ones."""
    if name is None:
        return None
    robots = known_robots(settings)
    if name not in robots:
        raise ServiceError(
            422,
            "unknown_robot",
            f"no robot named {name!r} on this server; it knows {sorted(robots)} (a server "
            "flies other descriptions given at its start: hikoboshi serve --robot FILE)",
        )
    return robots[name]
