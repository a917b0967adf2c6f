"""Topics, JSON schemas and the metadata record of our own channels (the ones read back).

Each schema is written into the file (``jsonschema`` encoding) and compiled by
:mod:`telemetry.mcap._jsonschema` for the reader, so the file and the reader agree by
construction.
"""

from __future__ import annotations

import json
import re
from typing import Any

from telemetry.layout import DEFAULT_LAYOUT, FrameLayout
from telemetry.mcap._jsonschema import Validator, compile_schema

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "METADATA_NAME",
    "OWN_SCHEMAS",
    "PLAN_SCHEMA_BEFORE_FLIGHT_RULES",
    "PLAN_SCHEMA_BEFORE_ROBOTS",
    "SCHEMA_ENCODING",
    "TOPIC_COMMANDS",
    "TOPIC_EVENTS",
    "TOPIC_PLAN",
    "TOPIC_TELEMETRY",
    "URDF_ATTACHMENT",
    "layout_of_telemetry_schema",
    "schema_bytes",
    "telemetry_schema",
    "urdf_attachment_name",
    "validators",
]

FORMAT = "hikoboshi.pass-recording"
FORMAT_VERSION = 1
#: The MCAP metadata record that marks a file as ours and holds the recording's scalars.
METADATA_NAME = "hikoboshi.recording"
#: The URDF attachment of ETS-VII's recordings, and of every recording written before the
#: attachment took its robot's name (:func:`urdf_attachment_name`); readers still accept it.
URDF_ATTACHMENT = "ets7.urdf"
_UNSAFE_IN_NAME = re.compile(r"[^A-Za-z0-9_.-]")


def urdf_attachment_name(robot: str) -> str:
    """The URDF attachment's name for a recording of ``robot`` (its plan's robot, a
    description's ``name``: ``orihime`` -> ``orihime.urdf``; ETS-VII's is
    :data:`URDF_ATTACHMENT`). Characters a description's name cannot hold become ``_``."""
    safe = _UNSAFE_IN_NAME.sub("_", robot)[:64].lstrip(".") or "robot"
    return f"{safe}.urdf"


SCHEMA_ENCODING = "jsonschema"

TOPIC_TELEMETRY = "/hikoboshi/telemetry"
TOPIC_COMMANDS = "/hikoboshi/commands"
TOPIC_EVENTS = "/hikoboshi/events"
TOPIC_PLAN = "/hikoboshi/plan"

_INT: dict[str, Any] = {"type": "integer"}
_TIME_NS: dict[str, Any] = {"type": "integer", "minimum": 0}
_STR: dict[str, Any] = {"type": "string"}
_NUMBERS: dict[str, Any] = {"type": "array", "items": {"type": "number"}}


def _numbers(n: int) -> dict[str, Any]:
    return {"type": "array", "items": {"type": "number"}, "minItems": n, "maxItems": n}


def _object(title: str, description: str, **properties: dict[str, Any]) -> dict[str, Any]:
    return {
        "title": title,
        "description": description,
        "type": "object",
        "properties": properties,
        "required": list(properties),
        "additionalProperties": False,
    }


# Width-1 frame columns that are not int64 (the others are; wider ones are float64 rows).
_FRAME_SCALARS: dict[str, dict[str, Any]] = {
    "acs_mode": _STR,
    "acs_feedforward": {"type": "boolean"},
    "generation_time_ns": _TIME_NS,
    "seq": {"type": "integer", "minimum": 0},
}


def telemetry_schema(layout: FrameLayout = DEFAULT_LAYOUT) -> dict[str, Any]:
    """The telemetry channel's schema for a robot's frames: each vector's length is the
    layout's (ETS-VII's schema is the same as before layouts existed)."""
    return _object(
        "hikoboshi.TelemetryFrame",
        "One telemetry frame as archived (telemetry.recording.FRAME_ARRAYS). Onboard clock "
        "except reception_time_ns (ground). rad, rad/s, N m s; quaternions x, y, z, w. "
        "buffer_next_execute_time_ns is -1 where nothing was queued.",
        **{
            name: (_numbers(width) if width > 1 else _FRAME_SCALARS.get(name, _INT))
            for name, width in layout.arrays.items()
        },
    )


def layout_of_telemetry_schema(schema: Any) -> FrameLayout | None:
    """The layout a telemetry schema was written for (from its joint and wheel-speed
    lengths), or None when it is not one :func:`telemetry_schema` writes."""
    try:
        properties = schema["properties"]
        layout = FrameLayout(
            properties["joints_rad"]["minItems"], properties["wheel_speeds_radps"]["minItems"]
        )
    except (TypeError, KeyError, ValueError):
        return None
    return layout if telemetry_schema(layout) == schema else None


TELEMETRY_SCHEMA = telemetry_schema(DEFAULT_LAYOUT)

COMMAND_SCHEMA = _object(
    "hikoboshi.Command",
    "A command of the pass and the time it reached each stage (null: never). "
    "execute_time_ns and the received/executed/rejected stages are onboard time, the "
    "other stages ground time.",
    seq={"type": "integer", "minimum": 0},
    kind=_STR,
    execute_time_ns=_TIME_NS,
    payload={"type": "object"},
    stage=_STR,
    reject_reason={"type": ["string", "null"]},
    stage_times_ns={"type": "object", "additionalProperties": {"type": ["integer", "null"]}},
)

EVENT_SCHEMA = _object(
    "hikoboshi.Event",
    "An audit event: actor did kind at time_ns (ground clock).",
    time_ns=_TIME_NS,
    kind=_STR,
    actor=_STR,
    detail={"type": "object"},
)

_PREDICTION_COLUMNS: dict[str, Any] = {
    "t_s": _NUMBERS,
    **{
        name: {"type": "array", "items": _NUMBERS}
        for name in (
            "joints_rad",
            "quat_orbit_from_base_xyzw",
            "rpy_base_rad",
            "omega_base_orbit_radps",
            "hand_pos_orbit_m",
            "quat_orbit_from_hand_xyzw",
            "reaction_momentum_orbit_nms",
            "wheel_momentum_nms",
        )
    },
}
_PREDICTION = {
    "type": "object",
    "properties": _PREDICTION_COLUMNS,
    "required": list(_PREDICTION_COLUMNS),
}

PLAN_SCHEMA: dict[str, Any] = {
    "title": "hikoboshi.Plan",
    "description": "The uplinked plan, exactly planner.plan.Plan.to_json(): joint commands "
    "(t_s from the plan's t = 0), ACS commands, segments, the prediction under ideal "
    "tracking and metrics. Its log time is the plan's t = 0 on the onboard clock.",
    "type": "object",
    "properties": {
        "format_version": _INT,
        "experiment": _STR,
        "parameters": {"type": "object"},
        "initial_joints_rad": _NUMBERS,
        "initial_quat_orbit_from_base_xyzw": _numbers(4),
        "commands": {
            "type": "array",
            "items": {
                "type": "object",
                "properties": {"t_s": {"type": "number"}, "joints_rad": _NUMBERS},
                "required": ["t_s", "joints_rad"],
                "additionalProperties": False,
            },
        },
        "acs_commands": {"type": "array", "items": {"type": "object"}},
        "segments": {"type": "array", "items": {"type": "object"}},
        "prediction": _PREDICTION,
        "metrics": {"type": "object", "additionalProperties": {"type": "number"}},
        # the robot the plan is for (its description's name and content hash); absent in
        # plans written before robots were described: ETS-VII's
        "robot": _STR,
        "robot_hash": _STR,
        # the flight-rules report on the plan (planner.flight_rules.FlightRulesReport.to_dict);
        # absent in plans never checked and in files written before the rules
        "flight_rules": {"type": "object"},
    },
    "required": [
        "format_version",
        "experiment",
        "parameters",
        "initial_joints_rad",
        "initial_quat_orbit_from_base_xyzw",
        "commands",
        "acs_commands",
        "segments",
        "prediction",
        "metrics",
    ],
    "additionalProperties": False,
}

#: The plan schema before plans carried their flight-rules report: files written with it are
#: read too.
PLAN_SCHEMA_BEFORE_FLIGHT_RULES: dict[str, Any] = {
    **PLAN_SCHEMA,
    "properties": {k: v for k, v in PLAN_SCHEMA["properties"].items() if k != "flight_rules"},
}

#: The plan schema before plans named their robot: a file written with it is read too (its
#: plans are ETS-VII's).
PLAN_SCHEMA_BEFORE_ROBOTS: dict[str, Any] = {
    **PLAN_SCHEMA,
    "properties": {
        k: v
        for k, v in PLAN_SCHEMA["properties"].items()
        if k not in ("robot", "robot_hash", "flight_rules")
    },
}

#: topic -> schema of the channels :func:`read_mcap` needs (the telemetry's: ETS-VII's; another
#: robot's is :func:`telemetry_schema` of its layout).
OWN_SCHEMAS: dict[str, dict[str, Any]] = {
    TOPIC_TELEMETRY: TELEMETRY_SCHEMA,
    TOPIC_COMMANDS: COMMAND_SCHEMA,
    TOPIC_EVENTS: EVENT_SCHEMA,
    TOPIC_PLAN: PLAN_SCHEMA,
}


def schema_bytes(schema: dict[str, Any]) -> bytes:
    return json.dumps(schema, separators=(",", ":")).encode()


def validators(layout: FrameLayout = DEFAULT_LAYOUT) -> dict[str, Validator]:
    """topic -> compiled validator of its messages (the telemetry's for ``layout``)."""
    schemas = {**OWN_SCHEMAS, TOPIC_TELEMETRY: telemetry_schema(layout)}
    return {topic: compile_schema(s, name=s["title"]) for topic, s in schemas.items()}
