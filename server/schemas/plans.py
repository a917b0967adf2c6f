"""The REST API's plans, their flight rules and the robots they are made for
(``/api/plans``, ``/api/robots``)."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import (
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
from server.schemas import NAME_RULE, FromRecord, SafeText

__all__ = [
    "ClearanceTracePublic",
    "FlightRuleName",
    "FlightRuleRowPublic",
    "FlightRulesPublic",
    "ParameterName",
    "ParameterScalar",
    "ParameterValue",
    "PlanBrief",
    "PlanCreate",
    "PlanPublic",
    "PlanSummary",
    "PlanValidation",
    "PlansPublic",
    "RobotPosePublic",
    "RobotPublic",
    "RobotsPublic",
    "SegmentPublic",
    "ValidationIssue",
]


#: A planner parameter's name (``settle_s``): the planner refuses the names it does not know.
ParameterName = Annotated[SafeText, StringConstraints(max_length=64)]
#: A parameter's value as JSON carries it: a number, boolean, string or null, or a list of
#: them for a tuple (at most ``planner.parameters.MAX_ITEMS`` items, the planner's bound). A
#: string is read as text (the console sends ``"10, 20, 30"``) or is a name (a ``label``,
#: shown and quoted to operators: a name's characters).
#: Strict: a string that breaks its rule is refused, not read as a number.
ParameterScalar = (
    Annotated[str, StringConstraints(max_length=1000), Strict(), NAME_RULE[0], NAME_RULE[1]]
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


class SegmentPublic(FromRecord):
    name: str
    kind: str
    t_start_s: float
    t_end_s: float


class PlanBrief(FromRecord):
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
