"""A pass's audit events in its MCAP recording as ``foxglove.Log`` on ``/events`` (what
Foxglove's Log panel shows), checked against Foxglove's published schema and the SDK's own
``foxglove.messages.Log``; the events themselves still read back exactly from our channel."""

from __future__ import annotations

import io
import json
from typing import Any

import jsonschema_rs
import pytest
from mcap.reader import make_reader

from spacecraft.offline import fly_offline
from telemetry.foxglove import LOG_LEVELS, event_level, event_log
from telemetry.mcap import TOPIC_EVENT_LOG, TOPIC_EVENTS, read_mcap, write_mcap
from telemetry.recording import EventRow, PassRecording
from tests.server.storage.factories import make_plan
from tests.support.foxglove_schemas import FOXGLOVE_LOG

EVENTS = (
    EventRow(1_700_000_000_123_456_789, "pass_state", "otto", {"from": "aos", "to": "running"}),
    EventRow(1_700_000_001_000_000_000, "alarm_raised", "ground", {"quantity": "frame_age_s"}),
    EventRow(1_700_000_002_000_000_001, "pass_state", "otto", {"from": "running", "to": "aborted"}),
    EventRow(1_700_000_003_000_000_000, "plan_created", "vera", {"experiment": "ptp", "n": 3}),
)


@pytest.fixture(scope="module")
def recording() -> PassRecording:
    plan = make_plan(5)
    flight = fly_offline(plan, after_s=0.5)
    return PassRecording.from_frames(
        "events", plan, flight.epoch_ns, flight.frames[:20], events=EVENTS
    )


def _logs(data: bytes) -> list[tuple[int, dict[str, Any]]]:
    out = []
    for schema, channel, message in make_reader(io.BytesIO(data)).iter_messages(
        topics=[TOPIC_EVENT_LOG]
    ):
        assert schema is not None and schema.name == "foxglove.Log"
        assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
        assert channel.metadata["clock"] == "ground"
        out.append((message.log_time, json.loads(message.data)))
    return out


def test_events_are_foxglove_logs_and_still_read_back(recording: PassRecording) -> None:
    buffer = io.BytesIO()
    write_mcap(recording, buffer)
    data = buffer.getvalue()
    assert read_mcap(io.BytesIO(data)).events == EVENTS  # our channel, exactly as before

    logs = _logs(data)
    validator = jsonschema_rs.validator_for(FOXGLOVE_LOG)
    for _, doc in logs:
        validator.validate(doc)
    assert [t for t, _ in logs] == [e.time_ns for e in EVENTS]
    for (log_ns, doc), event in zip(logs, EVENTS, strict=True):
        assert doc["timestamp"]["sec"] * 10**9 + doc["timestamp"]["nsec"] == log_ns
        assert doc["name"] == event.actor
        kind, _, detail = doc["message"].partition(": ")
        assert kind == event.kind and json.loads(detail) == event.detail
    levels = [doc["level"] for _, doc in logs]
    assert levels == [LOG_LEVELS[n] for n in ("INFO", "WARNING", "ERROR", "INFO")]

    # and in the SDK's own type: every field of ours is a field of foxglove.Log, every
    # level one of its LogLevel's, by name and number
    messages = pytest.importorskip("foxglove.messages", reason="the foxglove extra")
    for _, doc in logs:
        [name] = [n for n, v in LOG_LEVELS.items() if v == doc["level"]]
        level = getattr(messages.LogLevel, name.capitalize())
        assert level.value == doc["level"]
        official = messages.Log(
            timestamp=messages.Timestamp(doc["timestamp"]["sec"], doc["timestamp"]["nsec"]),
            level=level,
            message=doc["message"],
            name=doc["name"],
            file=doc["file"],
            line=doc["line"],
        )
        assert doc["message"].encode() in official.encode()


def test_a_pass_without_events_has_no_events_channel(recording: PassRecording) -> None:
    quiet = PassRecording("quiet", recording.plan, recording.epoch_ns, recording.frames)
    buffer = io.BytesIO()
    write_mcap(quiet, buffer)
    summary = make_reader(io.BytesIO(buffer.getvalue())).get_summary()
    assert summary is not None
    topics = {c.topic for c in summary.channels.values()}
    assert TOPIC_EVENTS in topics and TOPIC_EVENT_LOG not in topics


@pytest.mark.parametrize(
    ("kind", "detail", "level"),
    [
        ("pass_state", {"from": "running", "to": "safed"}, "ERROR"),
        ("pass_state", {"from": "los", "to": "complete"}, "INFO"),
        ("vehicle_safed", {}, "ERROR"),
        ("command_stage", {"seq": 3, "stage": "rejected"}, "WARNING"),
        ("command_stage", {"seq": 3, "stage": "executed"}, "INFO"),
        ("link_disconnected", {}, "WARNING"),
    ],
)
def test_event_levels(kind: str, detail: dict[str, Any], level: str) -> None:
    assert event_level(kind, detail) == LOG_LEVELS[level]
    assert event_log(5, kind, "a", detail)["level"] == LOG_LEVELS[level]
