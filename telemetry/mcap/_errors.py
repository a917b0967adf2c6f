"""The package's one exception (see :mod:`telemetry.mcap`)."""

from __future__ import annotations

__all__ = ["RecordingFileError"]


class RecordingFileError(ValueError):
    """A file that is not a readable Hikoboshi pass recording, or a recording that cannot be
    written as one; the text names what is wrong."""
