"""What the REST API reads and writes (pydantic): ``XCreate`` in, ``XPublic`` out,
``XsPublic(data, count)`` for a page of a listing.

Times: ground times are ISO-8601 UTC (``created_at``, ``aos_time``); onboard times, which
the spacecraft stamps, are integer ns (``execute_time_ns``) with an ISO rendering beside
them where a client plots them. Tables live apart, in :mod:`server.storage.models`.

Text a client sends is typed so that the OpenAPI document states the edge's rule
(server/api/edge.py, docs/security.md): :data:`SafeText` for strings of a JSON body (no C0
control character but tab, newline and carriage return, no DEL), :data:`SafeLine` for path
and query parameters (no C0 control character at all, no DEL), each with the ``maxLength``
the server enforces where it is used. The patterns are written for ECMA-262 and Python alike
(``\\xHH`` escapes and one character class), so a JSON Schema validator, schemathesis's
generator and pydantic read them the same.
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from typing import Annotated, Any, Literal

from pydantic import (
    AwareDatetime,
    BaseModel,
    ConfigDict,
    Field,
    Strict,
    StrictBool,
    StrictFloat,
    StrictInt,
    StringConstraints,
)

from planner.parameters import MAX_ITEMS

__all__ = [
    "ERROR_RESPONSES",
    "LINE_PATTERN",
    "TEXT_PATTERN",
    "AlarmAcknowledge",
    "AlarmPublic",
    "AlarmSeverity",
    "AlarmTimelineEntryPublic",
    "AlarmsPublic",
    "AnalysesPublic",
    "AnalysisErrorPublic",
    "AnalysisKind",
    "AnalysisPublic",
    "ClearanceTracePublic",
    "CommandPublic",
    "CommandsPublic",
    "ErrorPublic",
    "EventPublic",
    "EventsPublic",
    "FlightRuleRowPublic",
    "FlightRulesPublic",
    "MissionPublic",
    "MissionRelayPublic",
    "MissionUnloadablePublic",
    "MissionsPublic",
    "ParameterValue",
    "PassControlPublic",
    "PassCreate",
    "PassCreateFromWindow",
    "PassImportPublic",
    "PassPublic",
    "PassWindowPublic",
    "PassesPublic",
    "PlanBrief",
    "PlanCreate",
    "PlanPublic",
    "PlanSummary",
    "PlanValidation",
    "PlansPublic",
    "QuantityAcrossPublic",
    "QuantityBucketPublic",
    "QuantityPassPublic",
    "ReportAnalysisPublic",
    "ReportPublic",
    "ReportTablePublic",
    "RobotPosePublic",
    "RobotPublic",
    "RobotsPublic",
    "SafeLine",
    "SafeText",
    "SegmentPublic",
    "TelemetryBucketPublic",
    "TelemetryPublic",
    "TelemetryRowPublic",
    "ValidationIssue",
    "WindowPublic",
    "WindowRef",
    "WindowsPublic",
    "iso_from_ns",
    "ns_from_datetime",
]

_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
#: Ground times a client may give: int64 ns reach 2262; keep well inside.
EARLIEST = datetime(1970, 1, 1, tzinfo=UTC)
LATEST = datetime(2200, 1, 1, tzinfo=UTC)
#: The largest int64, the upper bound of every ``*_ns`` a client may give.
MAX_NS = 2**63 - 1

#: A JSON body's strings (and keys): any character but the C0 controls other than tab (09),
#: newline (0A) and carriage return (0D), and DEL (7F). The edge refuses the others, and
#: lone surrogates (which no UTF-8 encoder produces), 400 ``invalid_text``.
TEXT_PATTERN = r"^[^\x00-\x08\x0b\x0c\x0e-\x1f\x7f]*$"
#: A path or query parameter: no C0 control character at all, and no DEL.
LINE_PATTERN = r"^[^\x00-\x1f\x7f]*$"
#: Free text in a JSON body; give it its ``max_length`` where it is used.
SafeText = Annotated[str, StringConstraints(pattern=TEXT_PATTERN)]
#: Free text in a path or query parameter; give it its ``max_length`` where it is used.
SafeLine = Annotated[str, StringConstraints(pattern=LINE_PATTERN)]
#: A mission's or a relay's name (``mission.file.NAME``): a request names one, never a file.
NAME_PATTERN = r"^[A-Za-z0-9_.\-]+$"
Name = Annotated[str, StringConstraints(pattern=NAME_PATTERN, min_length=1, max_length=64)]

PassState = Literal["scheduled", "aos", "running", "los", "complete", "aborted", "safed"]
CommandStage = Literal[
    "queued", "released", "sent", "received", "executed", "rejected", "expired", "cancelled"
]
#: What a command moves (server/storage/models.py ``COMMAND_KINDS``).
CommandKind = Literal["joints", "acs"]
#: An audit-log event's kind as a filter: a snake_case name (server/services/events.py).
EventKind = Annotated[str, StringConstraints(pattern=r"^[a-z][a-z0-9_]*$", max_length=64)]


def iso_from_ns(time_ns: int) -> datetime:
    """A UTC datetime (microsecond resolution) for ns since the Unix epoch."""
    return _EPOCH + timedelta(microseconds=time_ns // 1000)


def ns_from_datetime(value: datetime) -> int:
    """ns since the Unix epoch for an aware datetime, exactly."""
    return (value - _EPOCH) // timedelta(microseconds=1) * 1000


class _Out(BaseModel):
    model_config = ConfigDict(from_attributes=True)


# --- plans ---------------------------------------------------------------------------------


#: A planner parameter's name (``settle_s``): the planner refuses the names it does not know.
ParameterName = Annotated[SafeText, StringConstraints(max_length=64)]
#: A parameter's value as JSON carries it: a number, boolean, string or null, or a list of
#: them for a tuple (at most ``planner.parameters.MAX_ITEMS`` items, the planner's bound). A
#: string is read as text (the console sends ``"10, 20, 30"``).
#: Strict: a string that breaks its rule is refused, not read as a number.
ParameterScalar = (
    Annotated[SafeText, StringConstraints(max_length=1000), Strict()]
    | StrictBool
    | StrictInt
    | StrictFloat
    | None
)
ParameterValue = ParameterScalar | Annotated[list[ParameterScalar], Field(max_length=MAX_ITEMS)]


def _names_in_property_names(schema: dict[str, Any]) -> None:
    """pydantic writes a dict's key pattern as ``patternProperties``, which leaves keys that
    do not match it allowed (as additional properties); state it in ``propertyNames``."""
    patterns = schema.pop("patternProperties", None)
    if patterns:
        ((pattern, values),) = patterns.items()
        schema["propertyNames"] = {**schema.get("propertyNames", {}), "pattern": pattern}
        schema["additionalProperties"] = values


class PlanCreate(BaseModel):
    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={"examples": [{"experiment": "ptp", "parameters": {"settle_s": 0.25}}]},
    )

    experiment: SafeText = Field(
        max_length=64,
        description="ptp, reactionless, gjm, coordination, nonholonomic, pass",
    )
    #: As JSON carries them: numbers, booleans, strings, lists for tuples, null for None.
    parameters: dict[ParameterName, ParameterValue] = Field(
        default_factory=dict, json_schema_extra=_names_in_property_names
    )
    #: The robot's name (its description's ``name``): one shipped under ``examples/robots/``
    #: or given to the server at start; null: ETS-VII as built in.
    robot: SafeText | None = Field(default=None, min_length=1, max_length=64)


class SegmentPublic(_Out):
    name: str
    kind: str
    t_start_s: float
    t_end_s: float


class PlanBrief(_Out):
    """A plan in a listing: its summary without metrics and segments."""

    id: str
    experiment: str
    parameters: dict[str, Any]
    duration_s: float
    n_commands: int
    created_at: datetime


FlightRuleName = Literal[
    "clearance",
    "self_clearance",
    "attitude_excursion_feedback",
    "attitude_excursion_free_drift",
    "wheel_momentum",
    "joint_limit_margin",
    "hand_speed",
    "fits_pass",
]


class FlightRuleRowPublic(BaseModel):
    """One flight rule on one plan (``planner.flight_rules.RuleRow``): the worst value of
    the plan's predicted motion, its limit (``bound`` "min": the value must be at least the
    limit; "max": at most), the verdict and when the worst value happens (s from the plan's
    start; null where the rule has no time). Clearance only: the two bodies (link names) and
    their nearest points in the robot frame (origin at joint 1, base axes)."""

    model_config = ConfigDict(frozen=True)

    rule: FlightRuleName
    value: float
    limit: float
    unit: Literal["m", "deg", "of limit", "m/s", "s"]
    bound: Literal["min", "max"]
    verdict: Literal["pass", "fail"]
    t_s: float | None = None
    bodies: tuple[str, str] | None = None
    points_robot_m: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    detail: str = ""


class ClearanceTracePublic(BaseModel):
    """The least clearance over every checked pair of bodies in each command period:
    ``min_m[k]`` is the least over the fine samples since the command before ``t_s[k]``."""

    model_config = ConfigDict(frozen=True)

    t_s: list[float]
    min_m: list[float]


class FlightRulesPublic(BaseModel):
    """A plan's flight-rules report (``planner.flight_rules.FlightRulesReport``; the
    ``flight_rules`` object of its document): ``passed`` when every row passes. How it was
    checked: the fine grid's step, the samples, the checked pairs of bodies and the
    distance queries made."""

    model_config = ConfigDict(frozen=True)

    passed: bool
    robot: str
    step_s: float
    n_samples: int
    n_pairs: int
    n_queries: int
    rows: list[FlightRuleRowPublic]
    clearance: ClearanceTracePublic


class PlanPublic(PlanBrief):
    metrics: dict[str, float]
    segments: list[SegmentPublic]
    #: The plan's flight-rules report; null for a plan stored before the rules existed
    #: (checked, and the report stored, when a pass of it is started).
    flight_rules: FlightRulesPublic | None = None


class PlansPublic(BaseModel):
    data: list[PlanBrief]
    count: int


class ValidationIssue(BaseModel):
    code: str
    message: str


class PlanSummary(BaseModel):
    """A plan as it would be stored: no id and no creation time yet."""

    experiment: str
    parameters: dict[str, Any]
    duration_s: float
    n_commands: int
    metrics: dict[str, float]
    segments: list[SegmentPublic]


class PlanValidation(BaseModel):
    """``valid`` when the request plans and the plan keeps every flight rule; a plan that
    fails a rule is not valid (an error ``flight_rule_violation``) and carries its
    ``summary`` and full ``flight_rules`` table all the same."""

    valid: bool
    errors: list[ValidationIssue]
    summary: PlanSummary | None = None
    flight_rules: FlightRulesPublic | None = None


# --- robots --------------------------------------------------------------------------------


class RobotPosePublic(BaseModel):
    """A named pose of a robot (``[poses.NAME]``): ``joints_deg`` are the joints the
    experiments take for it (the IK solution of its hand pose nearest its written joints when
    it has a hand pose); its written joints when the hand pose cannot be reached, null when
    it has none either."""

    name: str
    description: str
    joints_deg: list[float] | None
    hand_pos_robot_m: list[float] | None
    hand_rpy_deg: list[float] | None


class RobotPublic(BaseModel):
    """A robot the server plans for: a plan request names it (``"robot": name``)."""

    name: str
    description: str
    n_joints: int
    #: The description's ``content_sha256``: the ``robot_hash`` of the plans made for it.
    robot_hash: str
    #: True for ETS-VII, the robot a plan request without ``robot`` is for.
    default: bool
    #: Per joint: lower, upper (deg).
    joint_limits_deg: list[list[float]]
    poses: list[RobotPosePublic]
    #: The experiments' default parameters from the description (``[experiments.NAME]``,
    #: raw values), under which the catalogue's own defaults apply.
    experiments: dict[str, dict[str, Any]]
    #: Per experiment of the catalogue, the defaults a plan for this robot takes where the
    #: request leaves a parameter out: ``experiments``' values over those the tool derives
    #: for the keys the description leaves out (``RobotDescription.experiment_defaults``:
    #: distances scaled by the arm's reach, pose A as the start...); a parameter in neither
    #: takes the catalogue's default (ETS-VII's number). Null: the robot's own pose or the
    #: planner's choice (as a request that leaves the parameter out).
    experiment_defaults: dict[str, dict[str, Any]]
    #: Per experiment: the keys of ``experiment_defaults`` the tool derived for this robot
    #: (not in its description), sorted.
    derived_defaults: dict[str, list[str]]
    #: ``GET`` this for the robot's URDF.
    urdf_url: str


class RobotsPublic(BaseModel):
    data: list[RobotPublic]
    count: int


# --- passes --------------------------------------------------------------------------------


class PassCreate(BaseModel):
    """A pass in a window given by hand (``aos_time``, ``los_time``)."""

    model_config = ConfigDict(extra="forbid")

    plan_id: SafeText = Field(max_length=64)
    name: SafeText = Field(min_length=1, max_length=128)
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
    name: SafeText = Field(min_length=1, max_length=128)
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


class PassPublic(_Out):
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


# --- commands ------------------------------------------------------------------------------


class CommandPublic(BaseModel):
    """A command and when it reached each stage: ground stages (``queued`` ... ``sent``,
    ``expired``, ``cancelled``) as ISO-8601 UTC, onboard stages (``received``,
    ``executed``, ``rejected``) as ns on the onboard clock; ``transmissions``, how many
    times it went up (the uplink retransmits until the vehicle acknowledges)."""

    seq: int
    kind: str
    execute_time_ns: int
    payload: dict[str, Any]
    stage: str
    reject_reason: str | None
    queued_at: datetime
    released_at: datetime | None
    sent_at: datetime | None
    expired_at: datetime | None
    cancelled_at: datetime | None
    transmissions: int
    received_at_ns: int | None
    executed_at_ns: int | None
    rejected_at_ns: int | None


class CommandsPublic(BaseModel):
    data: list[CommandPublic]
    count: int


# --- telemetry -----------------------------------------------------------------------------


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


# --- alarms --------------------------------------------------------------------------------

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


# --- errors --------------------------------------------------------------------------------


class ErrorDetail(BaseModel):
    code: str
    message: str
    detail: Any = None


class ErrorPublic(BaseModel):
    """The one error shape (:mod:`server.api.errors`)."""

    error: ErrorDetail


#: Documented on every router, so the OpenAPI document describes the replies clients get.
ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {
    status: {"model": ErrorPublic, "description": description}
    for status, description in (
        (400, "Invalid argument"),
        (401, "No or unknown API token"),
        (403, "The token's role may not do this"),
        (404, "Not found"),
        (409, "Conflict"),
        (413, "The request body exceeds the size limit"),
        (422, "Invalid request, or a plan that cannot be made"),
        (
            429,
            "Too many failed authentications from this address, or too many heavy reads of"
            " this token in flight (Retry-After)",
        ),
        (
            503,
            "Busy: the viewers' share of requests in flight, the bounded work pool, the"
            " readers' database connections or a deadline (Retry-After)",
        ),
        (504, "The work did not finish within its deadline"),
    )
}


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


# --- analyses, reports, recordings -------------------------------------------------------

#: The stored post-pass analyses (server.services.analyses), one row of each per run.
AnalysisKind = Literal[
    "pass_analysis", "inertia_identification", "gravity_gradient_resim", "flown_clearance"
]
ReportCell = float | int | str | bool | None


class AnalysisErrorPublic(BaseModel):
    """Why an analysis gave no result: the exception's class and message."""

    type: str
    message: str


class AnalysisPublic(BaseModel):
    """One stored analysis run of a pass: its numbers (``status == "ok"``) or why it failed.
    ``result`` holds the analysis's ``to_dict()`` without its per-sample series."""

    id: int
    pass_id: str
    kind: str
    created_at: datetime
    status: Literal["ok", "failed"]
    error: AnalysisErrorPublic | None = None
    result: dict[str, Any] | None = None


class AnalysesPublic(BaseModel):
    data: list[AnalysisPublic]
    count: int


class ReportTablePublic(BaseModel):
    """One table of a report: ``rows`` of cells in ``columns`` order (units in the names)."""

    id: str
    title: str
    columns: list[str]
    rows: list[list[ReportCell]]
    notes: list[str] = Field(default_factory=list)


class ReportAnalysisPublic(BaseModel):
    kind: str
    status: Literal["ok", "failed", "absent"]
    created_at: datetime | None = None
    error: str | None = None


class ReportPublic(BaseModel):
    """A pass report: the newest stored analyses as tables, and the figures' names
    (``GET /api/passes/{id}/report/figures/{name}.png``)."""

    pass_id: str | None
    name: str
    state: str | None
    experiment: str
    imported: bool
    analyses: list[ReportAnalysisPublic]
    tables: list[ReportTablePublic]
    figures: list[str]


class PassImportPublic(BaseModel):
    """The pass an uploaded recording became, and what was stored of it."""

    imported: PassPublic
    frames: int
    commands: int
    events: int
