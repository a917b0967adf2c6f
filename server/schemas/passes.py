"""The REST API's passes (``/api/passes``: a pass scheduled by hand or in a computed window,
its start and abort, its summary) and the contact windows and missions they are scheduled
in (``/api/windows``, ``/api/missions``, docs/missions.md)."""

from __future__ import annotations

from datetime import datetime
from typing import Literal

from pydantic import AwareDatetime, BaseModel, ConfigDict, Field

from server.schemas import DisplayName, FromRecord, Name, SafeText

__all__ = [
    "MissionPublic",
    "MissionRelayPublic",
    "MissionUnloadablePublic",
    "MissionsPublic",
    "PassControlPublic",
    "PassCreate",
    "PassCreateFromWindow",
    "PassPublic",
    "PassSummaryPublic",
    "PassWindowPublic",
    "PassesPublic",
    "WindowPublic",
    "WindowRef",
    "WindowsPublic",
]


class PassCreate(BaseModel):
    """A pass in a window given by hand (``aos_time``, ``los_time``)."""

    model_config = ConfigDict(extra="forbid")

    plan_id: SafeText = Field(max_length=64)
    name: DisplayName = Field(min_length=1, max_length=128)
    #: Acquisition and loss of signal, ISO-8601 with a zone (UTC).
    aos_time: AwareDatetime
    los_time: AwareDatetime
    relay: SafeText = Field(default="TDRS", min_length=1, max_length=64)


class WindowRef(BaseModel):
    """A computed contact window, named: the mission, the relay and its acquisition time
    (within ``WINDOW_MATCH_S`` of the computed one, docs/missions.md)."""

    model_config = ConfigDict(extra="forbid")

    mission: Name
    relay: Name
    aos_time: AwareDatetime


class PassCreateFromWindow(BaseModel):
    """A pass in a computed window: its AOS and LOS are the window's net time (less the
    mission's margins), and the window is stored with the pass."""

    model_config = ConfigDict(extra="forbid")

    plan_id: SafeText = Field(max_length=64)
    name: DisplayName = Field(min_length=1, max_length=128)
    window: WindowRef


class PassWindowPublic(BaseModel):
    """The computed window a pass was scheduled in, as it was computed then."""

    mission: str
    mission_sha256: str
    relay: str
    aos_time: datetime
    los_time: datetime
    aos_margin_s: float
    los_margin_s: float
    net_s: float
    min_range_km: float
    max_range_km: float
    light_time_min_s: float
    light_time_max_s: float
    processing_delay_s: float


class PassPublic(FromRecord):
    id: str
    name: str
    plan_id: str
    aos_time: datetime
    los_time: datetime
    relay: str
    state: str
    state_reason: str | None
    #: Onboard time of the plan's t = 0, once known (ns, onboard clock).
    epoch_ns: int | None
    created_at: datetime
    updated_at: datetime
    version: int
    #: The computed window, when the pass was scheduled in one (``aos_time`` and
    #: ``los_time`` are then its net time).
    window: PassWindowPublic | None = None


class PassesPublic(BaseModel):
    data: list[PassPublic]
    count: int


#: A pass after ``POST /api/passes/{id}/start`` or ``/abort``.
class PassControlPublic(BaseModel):
    pass_id: str
    name: str
    state: str
    state_reason: str | None
    version: int
    epoch_ns: int | None


# --- contact windows -----------------------------------------------------------------------


class WindowPublic(BaseModel):
    """A contact window (docs/missions.md): the vehicle sees ``relay`` from ``aos_time`` to
    ``los_time``; a pass may use ``net_start_time`` to ``net_end_time``. Ranges are vehicle
    to relay; light times one way, vehicle -> relay -> the relay's ground terminal; the
    one-way delay adds the mission's ``processing_delay_s``."""

    relay: str
    aos_time: datetime
    los_time: datetime
    duration_s: float
    net_start_time: datetime
    net_end_time: datetime
    net_s: float
    min_range_km: float
    max_range_km: float
    light_time_min_s: float
    light_time_max_s: float


class WindowsPublic(BaseModel):
    """The windows whose acquisition falls in ``[start, start + hours)``, by AOS."""

    mission: str
    mission_sha256: str
    vehicle: str
    start: datetime
    hours: float
    processing_delay_s: float
    aos_margin_s: float
    los_margin_s: float
    data: list[WindowPublic]
    count: int


class MissionRelayPublic(BaseModel):
    """A geostationary relay of a mission: its name in requests, the satellite, its east
    longitude."""

    name: str
    satellite: str
    longitude_deg: float


class MissionPublic(BaseModel):
    """A mission the server computes windows for (docs/missions.md): a request names it by
    ``name``. ``windows_from`` .. ``windows_until`` is the span ``GET /api/windows`` accepts
    (the elements' epoch, less and plus the propagation's limit)."""

    name: str
    description: str
    vehicle: str
    mission_sha256: str
    #: The epoch of the vehicle's elements (a TLE's or the mean elements').
    epoch: datetime
    windows_from: datetime
    windows_until: datetime
    relays: list[MissionRelayPublic]
    station: str
    processing_delay_s: float
    aos_margin_s: float
    los_margin_s: float


class MissionUnloadablePublic(BaseModel):
    """A mission file the server has that does not load: its name and why."""

    name: str
    reason: str


class MissionsPublic(BaseModel):
    """The missions by name; ``unloadable`` the files that do not load (never listed in
    ``data``); ``max_hours`` the longest span one ``GET /api/windows`` computes."""

    data: list[MissionPublic]
    count: int
    unloadable: list[MissionUnloadablePublic]
    max_hours: float


class PassSummaryPublic(BaseModel):
    """What a pass delivered: the frames of its telemetry window and its commands' fates.

    ``frames_expected`` counts the frame slots of the window (onboard ``[start, end)``) at
    the rate the stored frames show; ``None`` until a frame is stored. ``duplicates_dropped``
    counts the copies the ground threw away since the service started; ``duplicates_stored``
    is what the archive holds twice (it must stay 0).
    """

    pass_id: str
    name: str
    state: str
    state_reason: str | None
    epoch_ns: int | None
    telemetry_start_ns: int | None
    telemetry_end_ns: int | None
    frames_expected: int | None
    frames_stored: int
    frames_missing: int | None
    gaps_open: int | None
    duplicates_stored: int
    duplicates_dropped: int
    commands_total: int
    commands_sent: int
    commands_executed: int
    #: executed on board exactly at their time tag (all executed ones, when the vehicle
    #: keeps its rule)
    commands_executed_at_tag: int
    #: executed on board after their time tag
    commands_executed_late: int
    commands_rejected: dict[str, int]
    commands_expired: int
    commands_cancelled: int
    commands_retransmitted: int
    #: the least time (onboard s) by which a command the vehicle received was ahead of its
    #: tag: how full the windowed uplink kept the onboard schedule
    min_command_lead_s: float | None
    #: sent and not acknowledged final (``sent``, ``released``, ``received``)
    commands_outstanding: int
    #: not final at all (``commands_outstanding`` and those still ``queued``)
    commands_unresolved: int
    #: once the pass has ended: ``nominal`` when every command executed at its tag,
    #: ``degraded`` otherwise (docs/operations.md); None before
    outcome: Literal["nominal", "degraded"] | None
    #: the outcome with its counts: ``degraded: 393 of 6190 commands expired``
    outcome_text: str | None
