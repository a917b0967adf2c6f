"""A pass's alarms in its MCAP recording: ``foxglove.Log`` messages on ``/alarms`` (what
Foxglove's Log panel shows), and the alarms themselves read back exactly."""

from __future__ import annotations

import io
import json
from typing import Any

import jsonschema_rs
import pytest
from mcap.reader import make_reader

from planner.plan import Plan
from spacecraft.offline import OfflineFlight, fly_offline
from telemetry.alarm import AlarmPublic
from telemetry.mcap import METADATA_NAME, TOPIC_ALARMS, RecordingFileError, read_mcap, write_mcap
from telemetry.mcap._alarms import ALARM_LOG_NAME
from telemetry.recording import PassRecording
from tests.server.storage.factories import make_plan
from tests.support.alarms import cleared_alarm
from tests.support.foxglove_schemas import FOXGLOVE_LOG


@pytest.fixture(scope="module")
def flown() -> tuple[Plan, OfflineFlight]:
    plan = make_plan(17)
    return plan, fly_offline(plan, after_s=1.0)


def _alarms(flight: OfflineFlight) -> tuple[dict[str, Any], dict[str, Any]]:
    """A tracking alarm raised at frame 10, escalated at 12, cleared at 20, acknowledged;
    and a link alarm (ground-timed entries: no frame)."""
    gen = [f.generation_time_ns for f in flight.frames]
    entry = {"time_ns": 1_000, "value": 2.5}
    tracking = cleared_alarm(
        None,
        id="0f0e0d0c-0000-4000-8000-000000000001",
        acknowledged_by="olga",
        acknowledged_time_ns=2_000,
        comment="joint 3 stuck",
        worst_value=6.0,
        last_value=0.1,
        count=10,
        raised_frame_seq=10,
        raised_generation_time_ns=gen[10],
        raised_time_ns=1_000,
        updated_time_ns=2_000,
        cleared_generation_time_ns=gen[20],
        cleared_time_ns=1_500,
        timeline=[
            {**entry, "severity": "watch", "generation_time_ns": gen[10], "frame_seq": 10},
            {**entry, "severity": "critical", "generation_time_ns": gen[12], "frame_seq": 12},
            {**entry, "severity": None, "generation_time_ns": gen[20], "frame_seq": 20},
        ],
    )
    link = {
        **tracking,
        "id": "0f0e0d0c-0000-4000-8000-000000000002",
        "quantity": "frame_age_s",
        "channel": "",
        "label": "frame age",
        "unit": "s",
        "severity": "warning",
        "current_severity": "warning",
        "state": "triggered",
        "acknowledged": False,
        "acknowledged_by": None,
        "acknowledged_time_ns": None,
        "comment": None,
        "raised_frame_seq": None,
        "raised_generation_time_ns": None,
        "timeline": [
            {
                "severity": "warning",
                "generation_time_ns": None,
                "time_ns": 1_700,
                "frame_seq": None,
                "value": 31.0,
            }
        ],
    }
    return tracking, link


def _recording(flown: tuple[Plan, OfflineFlight], *alarms: dict[str, Any]) -> PassRecording:
    plan, flight = flown
    recording = PassRecording.from_frames("alarmed", plan, flight.epoch_ns, flight.frames)
    # every frame received at ground time 1000 + its index (ns): the ground-timed entries map
    # onto the frame received last before them
    frames = recording.frames
    received = frames.reception_time_ns
    received[:] = 1_000 + (frames.seq - frames.seq[0])
    return PassRecording(
        recording.name,
        recording.plan,
        recording.epoch_ns,
        frames,
        alarms=tuple(AlarmPublic.model_validate(a) for a in alarms),
    )


def _write(recording: PassRecording) -> bytes:
    buffer = io.BytesIO()
    write_mcap(recording, buffer)
    return buffer.getvalue()


def test_alarms_become_foxglove_logs_and_read_back(flown: tuple[Plan, OfflineFlight]) -> None:
    tracking, link = _alarms(flown[1])
    recording = _recording(flown, tracking, link)
    data = _write(recording)
    read = read_mcap(io.BytesIO(data)).alarms
    assert [a.model_dump(mode="json") for a in read] == [tracking, link]

    reader = make_reader(io.BytesIO(data))
    validator = jsonschema_rs.validator_for(FOXGLOVE_LOG)
    logs = []
    for schema, channel, message in reader.iter_messages(topics=[TOPIC_ALARMS]):
        assert schema is not None and schema.name == "foxglove.Log"
        assert channel.metadata["clock"] == "onboard"
        doc = json.loads(message.data)
        validator.validate(doc)
        assert doc["timestamp"]["sec"] * 10**9 + doc["timestamp"]["nsec"] == message.log_time
        logs.append(doc)
    gen = recording.frames.generation_time_ns
    assert all(d["name"] == ALARM_LOG_NAME for d in logs)
    by_text = {d["message"].split(":")[0]: d for d in logs}
    watch = by_text["[watch] joint tracking error joint3"]
    critical = by_text["[critical] joint tracking error joint3"]
    assert (watch["level"], critical["level"]) == (2, 4)  # INFO, ERROR
    assert (watch["line"], critical["line"]) == (10, 12)  # the frame's seq
    times = {d["message"]: d["timestamp"]["sec"] * 10**9 + d["timestamp"]["nsec"] for d in logs}
    assert times[watch["message"]] == gen[10] and times[critical["message"]] == gen[12]
    cleared = next(d for d in logs if "back within limits" in d["message"])
    assert times[cleared["message"]] == gen[20] and cleared["level"] == 2
    # ground-timed: at the onboard time of the frame received last before, plus the time since
    acked = next(d for d in logs if "acknowledged by olga" in d["message"])
    assert "joint 3 stuck" in acked["message"]
    last = len(gen) - 1  # ground 2000 is after every reception (1000 + index)
    assert times[acked["message"]] == gen[last] + 2_000 - (1_000 + last)
    age = by_text["[warning] frame age"]
    k = min(700, last)  # ground 1700: the frame received last before it
    assert times[age["message"]] == gen[k] + 1_700 - (1_000 + k)
    assert age["level"] == 3 and age["line"] == 0
    assert [d["timestamp"] for d in logs] == sorted(
        (d["timestamp"] for d in logs), key=lambda t: (t["sec"], t["nsec"])
    )


def test_a_recording_without_alarms_has_no_alarm_channel(
    flown: tuple[Plan, OfflineFlight],
) -> None:
    data = _write(_recording(flown))
    reader = make_reader(io.BytesIO(data))
    summary = reader.get_summary()
    assert summary is not None
    assert TOPIC_ALARMS not in {c.topic for c in summary.channels.values()}
    (meta,) = [m for m in reader.iter_metadata() if m.name == METADATA_NAME]
    assert "alarms_json" not in meta.metadata
    assert read_mcap(io.BytesIO(data)).alarms == ()


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        ({"alarms": "3"}, "says 3 alarms, alarms_json holds 2"),
        ({"alarms_json": "{}", "alarms": "0"}, "alarms_json is not a list of objects"),
        ({"alarms_json": "[{"}, "alarms_json: "),
    ],
)
def test_alarms_the_metadata_cannot_carry_are_refused(
    flown: tuple[Plan, OfflineFlight],
    monkeypatch: pytest.MonkeyPatch,
    edit: dict[str, str],
    match: str,
) -> None:
    from telemetry.mcap import _write as writer

    metadata = writer._metadata
    monkeypatch.setattr(writer, "_metadata", lambda r: {**metadata(r), **edit})
    data = _write(_recording(flown, *_alarms(flown[1])))
    with pytest.raises(RecordingFileError, match=match):
        read_mcap(io.BytesIO(data))
