"""An alarm's document (docs/alarms.md): the one model of it, for the REST API
(``GET /api/alarms``'s items), the consoles' ``alarm`` message, the MCAP recording (its
``alarms_json`` and ``/alarms`` logs), the pass report and the ground's alarm book, which
holds these and changes them in place.

Here, below the server, because the recording (:mod:`telemetry.recording`, the MCAP writer)
carries alarms and may not import the server. Severities are :class:`planner.limits.Severity`.
The class names are the REST API's (its OpenAPI schema names them; clients depend on them).
"""

from __future__ import annotations

from typing import Literal, get_args

from pydantic import BaseModel, ConfigDict

from planner.limits import Severity

__all__ = [
    "ALARM_DIRECTIONS",
    "ALARM_FIELDS",
    "ALARM_SOURCES",
    "ALARM_STATES",
    "AlarmDirection",
    "AlarmPublic",
    "AlarmSource",
    "AlarmState",
    "AlarmTimelineEntryPublic",
]

#: ``limit``: the ground's limit check of a quantity; ``vehicle``: the vehicle's safing.
AlarmSource = Literal["limit", "vehicle"]
AlarmState = Literal["triggered", "cleared"]
AlarmDirection = Literal["high", "low"]
ALARM_SOURCES: tuple[str, ...] = get_args(AlarmSource)
ALARM_STATES: tuple[str, ...] = get_args(AlarmState)
ALARM_DIRECTIONS: tuple[str, ...] = get_args(AlarmDirection)


class AlarmTimelineEntryPublic(BaseModel):
    """A change of band: ``severity`` null when back within limits. ``generation_time_ns``
    (onboard) and ``frame_seq`` are the frame's (null for the link's health, checked on the
    ground's timer); ``time_ns`` is when the ground saw it (ground)."""

    model_config = ConfigDict(extra="forbid")

    severity: Severity | None
    generation_time_ns: int | None
    time_ns: int
    frame_seq: int | None
    value: float | None


class AlarmPublic(BaseModel):
    """An alarm (docs/alarms.md): ``severity`` the worst band reached, ``limit`` its
    threshold; ``current_severity`` null once back within limits (``state`` cleared).
    Active (listed) while triggered or not acknowledged. ``*_generation_time_ns`` are onboard
    times, the other ``*_ns`` ground times."""

    model_config = ConfigDict(extra="forbid")

    id: str
    pass_id: str | None
    quantity: str
    channel: str
    label: str
    unit: str
    direction: AlarmDirection
    source: AlarmSource
    severity: Severity
    current_severity: Severity | None
    state: AlarmState
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

    @property
    def active(self) -> bool:
        """Listed: triggered, or cleared and not yet acknowledged (latching)."""
        return self.state == "triggered" or not self.acknowledged

    @property
    def what(self) -> str:
        """Its quantity's label (else name) and its channel, as messages name it."""
        return f"{self.label or self.quantity}{' ' + self.channel if self.channel else ''}"


#: The fields of an alarm's document, in the order the JSON gives them.
ALARM_FIELDS: tuple[str, ...] = tuple(AlarmPublic.model_fields)
