"""A shipped mission by its name: wherever a command takes a mission file, ``ets7-1999``
names the one shipped in the checkout's ``examples/missions/`` (or an installed wheel's
copy), as ``ets7`` names a shipped robot (planner.description.shipped_robots)."""

from __future__ import annotations

from pathlib import Path

from mission.errors import InvalidMission

__all__ = ["mission_file"]


def mission_file(given: Path | str, folder: Path) -> Path:
    """``given``, or, when it names no file and is a bare name (no folder, no suffix), the
    mission of that name in ``folder``; a bare name that is neither is refused naming the
    shipped ones."""
    path = Path(given)
    if path.exists() or path.parent != Path(".") or path.suffix:
        return path
    shipped = {p.stem: p for p in sorted(folder.glob("*.toml"))} if folder.is_dir() else {}
    if path.name in shipped:
        return shipped[path.name]
    known = ", ".join(shipped) or "none here"
    raise InvalidMission(path, "file", f"no such file, nor a shipped mission ({known})")
