"""Missions: a vehicle's orbit, its relays and its ground, read from a file, and the contact
windows they give (docs/missions.md, SPEC section 8).

    load_mission(path) -> Mission                      file.py: read and check a TOML file
    compute_windows(mission, start, hours) -> [Window] windows.py: skyfield + sgp4
    light_times(mission, window) -> (s, light s)       windows.py: the path's light time

The package imports nothing else of ours (an import contract in pyproject.toml says so);
the command line and the ground service use it. skyfield is imported when windows are
computed, not when the package is.
"""

from mission.errors import InvalidMission, InvalidSpan, MissionError
from mission.file import MISSIONS_DIR, NAME, Mission, load_mission
from mission.windows import (
    MAX_HOURS,
    Window,
    compute_windows,
    format_utc,
    light_times,
    parse_utc,
)

__all__ = [
    "MAX_HOURS",
    "MISSIONS_DIR",
    "NAME",
    "InvalidMission",
    "InvalidSpan",
    "Mission",
    "MissionError",
    "Window",
    "compute_windows",
    "format_utc",
    "light_times",
    "load_mission",
    "parse_utc",
]
