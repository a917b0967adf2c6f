"""The REST API's alarms and their acknowledgement (``/api/alarms``, docs/alarms.md). An
alarm is :class:`telemetry.alarm.AlarmPublic`, the one model of it (re-exported here)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from server.schemas import SafeText
from telemetry.alarm import AlarmPublic, AlarmTimelineEntryPublic

__all__ = [
    "AlarmAcknowledge",
    "AlarmPublic",
    "AlarmTimelineEntryPublic",
    "AlarmsPublic",
]


class AlarmsPublic(BaseModel):
    """Alarms, newest raised first; ``count`` of all that match."""

    alarms: list[AlarmPublic]
    count: int


class AlarmAcknowledge(BaseModel):
    """An operator's acknowledgement of an alarm, with an optional comment."""

    model_config = ConfigDict(extra="forbid")
    comment: SafeText | None = Field(default=None, max_length=500)
