"""The truth log: what really happened on board, for rehearsals and their analysis.

``hikoboshi spacecraft --truth-log PATH`` writes it (docs/spacecraft.md, "Truth log"): JSON
lines, one object per event, each with its ``event`` and its ``onboard_time_ns`` (the
onboard clock, as the telemetry's times):

- ``start``: the onboard clock at start (``onboard_time_ns``, the time faults' ``T`` counts
  from), the vehicle's name, the faults given (their specs) and whether on-board safing is
  on;
- ``fault``: a fault's onset (:meth:`spacecraft.faults.FaultInjector.begin`);
- ``safing_entry`` and ``safing_exit``: the vehicle entering SAFE (its trigger and the
  commands it dropped) and leaving it (the ``safe_exit`` request).

Nothing of it goes on the link: the ground learns of a fault from the telemetry alone.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import IO, Any

__all__ = ["TruthLog"]


class TruthLog:
    """An open truth log (a file truncated on opening); every record is flushed at once, so
    a reader sees each event as it happens."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._file: IO[str] | None = self.path.open("w", encoding="utf-8")

    def write(self, records: Iterable[Mapping[str, Any]]) -> None:
        if self._file is None:
            return
        wrote = False
        for record in records:
            self._file.write(json.dumps(record, separators=(",", ":")) + "\n")
            wrote = True
        if wrote:
            self._file.flush()

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None
