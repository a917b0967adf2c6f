"""Errors of the mission package.

    MissionError
    ├── InvalidMission    a mission file that cannot be loaded: ``file: key: reason``
    └── InvalidSpan       a request for windows that cannot be answered (start, hours, epoch)

Messages name the bad value and the limit; the command line prints them on one line, the
ground service answers them 4xx.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["InvalidMission", "InvalidSpan", "MissionError"]


class MissionError(Exception):
    """Root of every error the mission package raises."""


class InvalidMission(MissionError, ValueError):
    """A mission file that cannot be loaded: ``file: key: reason``."""

    def __init__(self, path: Path | str, key: str, reason: str) -> None:
        self.path = str(path)
        self.key = key
        self.reason = reason
        super().__init__(f"{path}: {key}: {reason}")


class InvalidSpan(MissionError, ValueError):
    """A span of time the windows cannot be computed for (its reason in the message)."""
