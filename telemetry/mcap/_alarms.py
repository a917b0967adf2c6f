"""The ``/alarms`` channel: a pass's alarms as ``foxglove.Log`` messages, so Foxglove's Log
panel lists them beside the plots (derived on export, never read back: the alarms
themselves round-trip in the metadata record, ``alarms_json``).

One message per change of an alarm's band (its ``timeline``) and one per acknowledgement.
The log time is onboard, as the plots': a band change's frame's ``generation_time_ns``; a
ground-timed entry (the link's health, an acknowledgement) is put at the onboard time of the
newest frame the ground had received at that ground time, plus the time since (what the
operator was looking at). Levels: watch and a return within limits ``INFO``, warning and
distress ``WARNING``, critical ``ERROR``, severe ``FATAL``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from planner.limits import Severity
from telemetry.alarm import AlarmPublic
from telemetry.foxglove import LOG_LEVELS
from telemetry.recording import FrameArrays

__all__ = ["ALARM_LOG_NAME", "TOPIC_ALARMS", "alarm_logs"]

TOPIC_ALARMS = "/alarms"
#: The ``name`` of every ``/alarms`` message (Foxglove's Log panel filters by it).
ALARM_LOG_NAME = "hikoboshi.alarms"
_LEVEL: dict[Severity | None, str] = {
    None: "INFO",
    Severity.WATCH: "INFO",
    Severity.WARNING: "WARNING",
    Severity.DISTRESS: "WARNING",
    Severity.CRITICAL: "ERROR",
    Severity.SEVERE: "FATAL",
}


class _GroundToOnboard:
    """Ground ns -> onboard ns by the frames' receptions (see the module docstring)."""

    def __init__(self, frames: FrameArrays, epoch_ns: int) -> None:
        order = np.argsort(frames.reception_time_ns, kind="stable")
        self._received = frames.reception_time_ns[order]
        self._generated = frames.generation_time_ns[order]
        self._epoch_ns = epoch_ns

    def __call__(self, ground_ns: int) -> int:
        if len(self._received) == 0:
            return self._epoch_ns
        k = max(0, int(np.searchsorted(self._received, ground_ns, side="right")) - 1)
        return max(0, int(self._generated[k]) + ground_ns - int(self._received[k]))


def _number(value: Any, unit: str) -> str:
    if value is None:
        return "?"
    return f"{value:.4g}" + (f" {unit}" if unit and unit != "1" else "")


def _log(log_ns: int, level: str, message: str, line: int) -> dict[str, Any]:
    return {
        "timestamp": {"sec": log_ns // 10**9, "nsec": log_ns % 10**9},
        "level": LOG_LEVELS[level],
        "message": message,
        "name": ALARM_LOG_NAME,
        "file": "",
        "line": max(0, line),
    }


def alarm_logs(
    alarms: Sequence[AlarmPublic], frames: FrameArrays, epoch_ns: int
) -> tuple[list[int], list[dict[str, Any]]]:
    """The ``/alarms`` messages of ``alarms`` and their log times (onboard ns), in time
    order."""
    onboard = _GroundToOnboard(frames, epoch_ns)
    out: list[tuple[int, int, dict[str, Any]]] = []
    for a in alarms:
        what, unit, short = a.what, a.unit, a.id[:8]
        for entry in a.timeline:
            severity = entry.severity
            gen = entry.generation_time_ns
            log_ns = gen if gen is not None else onboard(entry.time_ns)
            value = _number(entry.value, unit)
            if severity is None:
                text = f"{what} back within limits: {value} (alarm {short})"
            else:
                text = (
                    f"[{severity}] {what}: {value} beyond {a.direction} limits "
                    f"(alarm {short}, {a.source})"
                )
                if a.detail:
                    text += f": {a.detail}"
            seq = entry.frame_seq
            out.append((log_ns, len(out), _log(log_ns, _LEVEL[severity], text, seq or 0)))
        if a.acknowledged and a.acknowledged_time_ns is not None:
            log_ns = onboard(a.acknowledged_time_ns)
            comment = a.comment
            text = f"{what} acknowledged by {a.acknowledged_by} (alarm {short})"
            text += f": {comment}" if comment else ""
            out.append((log_ns, len(out), _log(log_ns, "INFO", text, 0)))
    out.sort(key=lambda item: (item[0], item[1]))
    return [t for t, _, _ in out], [m for _, _, m in out]
