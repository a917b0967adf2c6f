"""The REST API's telemetry (a pass's frames raw or decimated, one quantity across passes:
``/api/passes/{id}/telemetry``, ``/api/telemetry/across``) and the audit log's events
(``/api/events``)."""

from __future__ import annotations

from datetime import datetime
from typing import Any, Literal

from pydantic import BaseModel

__all__ = [
    "EventPublic",
    "EventsPublic",
    "QuantityAcrossPublic",
    "QuantityBucketPublic",
    "QuantityPassPublic",
    "TelemetryBucketPublic",
    "TelemetryPublic",
    "TelemetryRowPublic",
]


class TelemetryRowPublic(BaseModel):
    seq: int
    generation_time_ns: int
    generation_time: datetime
    values: dict[str, float | int | bool | str | None]


class TelemetryBucketPublic(BaseModel):
    """Frames with ``t_start_ns <= generation_time_ns < t_start_ns + width_ns``."""

    t_start_ns: int
    t_start: datetime
    count: int
    min: dict[str, float]
    max: dict[str, float]
    mean: dict[str, float]


class TelemetryPublic(BaseModel):
    """Raw frames (``mode == "raw"``: ``rows``) or decimated buckets (``"buckets"``)."""

    pass_id: str
    mode: Literal["raw", "buckets"]
    fields: list[str]
    t0_ns: int
    t1_ns: int
    #: Raw rows returned, or buckets (the non-empty ones).
    count: int
    #: Raw mode: more frames lie in the range than ``limit``; ask again from the last one.
    truncated: bool = False
    width_ns: int | None = None
    rows: list[TelemetryRowPublic] | None = None
    buckets: list[TelemetryBucketPublic] | None = None


class QuantityBucketPublic(BaseModel):
    """Frames of one pass generated in ``[t_s, t_s + width_s)`` after its first frame."""

    t_s: float
    count: int
    min: float
    max: float
    mean: float


class QuantityPassPublic(BaseModel):
    """One pass's series of the quantity, on a time axis from its own first frame."""

    pass_id: str
    name: str
    state: str
    #: Frames stored (0: the pass has none, and no statistics).
    count: int
    first_ns: int | None = None
    first: datetime | None = None
    duration_s: float | None = None
    width_s: float | None = None
    min: float | None = None
    max: float | None = None
    mean: float | None = None
    buckets: list[QuantityBucketPublic] = []


class QuantityAcrossPublic(BaseModel):
    """One telemetry quantity across several passes, each decimated into ``buckets``
    equal spans of its own stored duration (``GET /api/telemetry/across``)."""

    field: str
    unit: str
    buckets: int
    passes: list[QuantityPassPublic]


# --- events --------------------------------------------------------------------------------


class EventPublic(BaseModel):
    id: int
    pass_id: str | None
    time: datetime
    time_ns: int
    kind: str
    actor: str
    detail: dict[str, Any]


class EventsPublic(BaseModel):
    data: list[EventPublic]
    count: int
