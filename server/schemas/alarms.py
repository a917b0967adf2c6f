"""The REST API's alarms and their acknowledgement (``/api/alarms``, docs/alarms.md)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from server.schemas import SafeText

__all__ = [
    "AlarmAcknowledge",
    "AlarmPublic",
    "AlarmSeverity",
    "AlarmTimelineEntryPublic",
    "AlarmsPublic",
]


#: Yamcs's five levels, lowest first (``planner.limits.Severity``): docs/alarms.md.
AlarmSeverity = Literal["watch", "warning", "distress", "critical", "severe"]


class AlarmTimelineEntryPublic(BaseModel):
    """A change of band: ``severity`` null when back within limits. ``generation_time_ns``
    (onboard) and ``frame_seq`` are the frame's (null for the link's health, checked on the
    ground's timer); ``time_ns`` is when the ground saw it (ground)."""

    severity: AlarmSeverity | None
    generation_time_ns: int | None
    time_ns: int
    frame_seq: int | None
    value: float | None


class AlarmPublic(BaseModel):
    """An alarm (docs/alarms.md): ``severity`` the worst band reached, ``limit`` its
    threshold; ``current_severity`` null once back within limits (``state`` cleared).
    Active (listed) while triggered or not acknowledged. ``*_generation_time_ns`` are onboard
    times, the other ``*_ns`` ground times."""

    id: str
    pass_id: str | None
    quantity: str
    channel: str
    label: str
    unit: str
    direction: Literal["high", "low"]
    source: Literal["limit", "vehicle"]
    severity: AlarmSeverity
    current_severity: AlarmSeverity | None
    state: Literal["triggered", "cleared"]
    acknowledged: bool
    acknowledged_by: str | None
    acknowledged_time_ns: int | None
    comment: str | None
    limit: float | None
    trigger_value: float | None
    worst_value: float | None
    last_value: float | None
    count: int
    raised_frame_seq: int | None
    raised_generation_time_ns: int | None
    raised_time_ns: int
    updated_time_ns: int
    cleared_generation_time_ns: int | None
    cleared_time_ns: int | None
    timeline: list[AlarmTimelineEntryPublic]
    detail: str | None


class AlarmsPublic(BaseModel):
    """Alarms, newest raised first; ``count`` of all that match."""

    alarms: list[AlarmPublic]
    count: int


class AlarmAcknowledge(BaseModel):
    """An operator's acknowledgement of an alarm, with an optional comment."""

    model_config = ConfigDict(extra="forbid")
    comment: SafeText | None = Field(default=None, max_length=500)
