"""MCAP export and import of a pass: exact round trips, a file other tools can read, Foxglove
frame transforms that match the model, and a clear error for every kind of bad file."""

from __future__ import annotations

import io
import json
import xml.etree.ElementTree as ET
from collections import defaultdict
from pathlib import Path
from typing import Any

import jsonschema_rs
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from planner.description import load_robot
from planner.dynamics import DynamicsWorkspace
from planner.frames import matrix_from_quat_xyzw
from planner.model import RobotModel
from planner.state import State
from planner.urdf import urdf_xml
from telemetry.layout import FrameLayout
from telemetry.mcap import (
    METADATA_NAME,
    PLOT_TOPICS,
    TOPIC_COMMANDS,
    TOPIC_EVENTS,
    TOPIC_PLAN,
    TOPIC_ROBOT_DESCRIPTION,
    TOPIC_TELEMETRY,
    TOPIC_TF,
    URDF_ATTACHMENT,
    RecordingFileError,
    read_mcap,
    write_mcap,
)
from telemetry.mcap._schemas import TELEMETRY_SCHEMA, telemetry_schema
from telemetry.recording import CommandRow, EventRow, PassRecording
from tests.server.storage.factories import make_frames, make_plan
from tests.support.foxglove_schemas import FOXGLOVE_FRAME_TRANSFORMS


def pose_in_orbit(transforms: list[dict[str, Any]], name: str) -> tuple[np.ndarray, np.ndarray]:
    """Position and rotation of frame ``name`` in "orbit", composing the chain of parents."""
    by_child = {t["child_frame_id"]: t for t in transforms}
    pos, rot = np.zeros(3), np.eye(3)
    for _ in range(len(transforms)):
        if name == "orbit":
            return pos, rot
        tr = by_child[name]
        rot_parent_from_child = matrix_from_quat_xyzw(np.array([tr["rotation"][k] for k in "xyzw"]))
        pos_in_parent = np.array([tr["translation"][k] for k in "xyz"])
        pos, rot = pos_in_parent + rot_parent_from_child @ pos, rot_parent_from_child @ rot
        name = tr["parent_frame_id"]
    assert name == "orbit", f"the chain of parents does not reach the orbit frame: {name}"
    return pos, rot


def assert_same_recording(got: PassRecording, want: PassRecording) -> None:
    assert got.name == want.name
    assert got.epoch_ns == want.epoch_ns
    assert got.frames.layout == want.frames.layout
    for name in want.frames.layout.arrays:
        a, b = getattr(got.frames, name), getattr(want.frames, name)
        assert a.dtype == b.dtype, name
        assert a.shape == b.shape, name
        assert a.tobytes() == b.tobytes(), name  # bitwise, -0.0 and all
    assert got.plan.to_json() == want.plan.to_json()
    assert got.commands == want.commands
    assert got.events == want.events
    assert dict(got.meta) == dict(want.meta)


def small_recording(demo: PassRecording, n: int = 40) -> PassRecording:
    """The demo's first frames with commands in every stage and a few audit events."""
    t0 = int(demo.frames.generation_time_ns[0])
    commands = (
        CommandRow(
            seq=0,
            kind="joints",
            execute_time_ns=t0 + 250_000_000,
            payload={"joints_rad": [0.1, -0.0, 0.3, 1e-300, -2.5, 3.0]},
            stage="executed",
            stage_times_ns={
                "queued": 10,
                "released": 11,
                "sent": 12,
                "received": t0 + 1,
                "executed": t0 + 250_000_000,
                "rejected": None,
                "expired": None,
            },
        ),
        CommandRow(
            seq=1,
            kind="acs",
            execute_time_ns=t0 + 100_000_000,  # tags need not ascend with seq
            payload={
                "mode": "free_drift",
                "target_quat_orbit_from_base_xyzw": [0.0, 0.0, 0.0, 1.0],
                "feedforward": True,
            },
            stage="rejected",
            reject_reason="late",
            stage_times_ns={"queued": 13, "rejected": t0 + 2},
        ),
        CommandRow(seq=2, kind="joints", execute_time_ns=t0, payload={}, stage="queued"),
    )
    events = (
        EventRow(time_ns=5, kind="pass.start", actor="opérateur", detail={"relay": "TDRS"}),
        EventRow(time_ns=3, kind="note", actor="ops", detail={"text": "earlier, listed later"}),
    )
    return PassRecording(
        name="small ✓",
        plan=demo.plan,
        epoch_ns=demo.epoch_ns,
        frames=demo.frames.take(slice(0, n)),
        commands=commands,
        events=events,
        meta={"source": "test", "nested": {"aos_ns": 1, "list": [1, 2.5, None]}},
    )


@pytest.fixture(scope="module")
def demo_file(demo_mcap_file: Path) -> Path:
    """The demo pass as ``write_mcap`` wrote it (tests/conftest.py: once per run, shared
    with the report tests)."""
    return demo_mcap_file


@pytest.fixture(scope="module")
def small_bytes(demo_recording: PassRecording) -> bytes:
    buf = io.BytesIO()
    write_mcap(small_recording(demo_recording), buf)
    return buf.getvalue()


# --- round trips ---------------------------------------------------------------------------


@pytest.mark.slow
def test_demo_pass_round_trips_bitwise(demo_recording: PassRecording, demo_file: Path) -> None:
    assert_same_recording(read_mcap(demo_file), demo_recording)


def test_commands_events_and_meta_round_trip(
    demo_recording: PassRecording, small_bytes: bytes
) -> None:
    want = small_recording(demo_recording)
    got = read_mcap(io.BytesIO(small_bytes))
    assert_same_recording(got, want)
    assert [c.seq for c in got.commands] == [0, 1, 2]  # the recording's order, not tag order
    assert got.commands[0].payload["joints_rad"][1] == 0.0
    assert np.signbit(got.commands[0].payload["joints_rad"][1])


def test_empty_recording_round_trips(demo_recording: PassRecording, tmp_path: Path) -> None:
    empty = PassRecording("empty", demo_recording.plan, 7, demo_recording.frames.take(slice(0, 0)))
    write_mcap(empty, tmp_path / "empty.mcap")
    assert_same_recording(read_mcap(tmp_path / "empty.mcap"), empty)


def test_write_refuses_what_json_cannot_carry(demo_recording: PassRecording) -> None:
    frames = demo_recording.frames.take(slice(0, 5))
    frames.joints_rad[2, 3] = np.nan  # take() copies: the fixture is untouched
    bad = PassRecording("bad", demo_recording.plan, demo_recording.epoch_ns, frames)
    with pytest.raises(RecordingFileError, match="joints_rad is not finite at row 2"):
        write_mcap(bad, io.BytesIO())


# --- the file as other tools see it --------------------------------------------------------


@pytest.mark.slow
def test_every_message_validates_against_its_channel_schema(demo_file: Path) -> None:
    with open(demo_file, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        assert summary.chunk_indexes, "no chunk index: readers could not seek"
        assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
        assert all(c.message_index_offsets for c in summary.chunk_indexes)
        validators: dict[int, Any] = {}
        for channel_id, channel in summary.channels.items():
            schema = summary.schemas[channel.schema_id]
            assert channel.message_encoding == "json"
            assert schema.encoding == "jsonschema"
            assert channel.metadata["clock"]
            validators[channel_id] = jsonschema_rs.validator_for(json.loads(schema.data))
        topics = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
        counts: dict[str, int] = defaultdict(int)
        foxglove = jsonschema_rs.validator_for(FOXGLOVE_FRAME_TRANSFORMS)
        for _, channel, message in reader.iter_messages():
            doc = json.loads(message.data)
            validators[channel.id].validate(doc)
            if channel.topic == TOPIC_TF:
                foxglove.validate(doc)
            counts[channel.topic] += 1
    assert topics[TOPIC_TF] == "foxglove.FrameTransforms"
    assert set(topics) == {
        TOPIC_TELEMETRY,
        TOPIC_COMMANDS,
        TOPIC_EVENTS,
        TOPIC_PLAN,
        TOPIC_TF,
        TOPIC_ROBOT_DESCRIPTION,
        *PLOT_TOPICS,
    }
    n = counts[TOPIC_TELEMETRY]
    assert n > 12_000
    assert counts[TOPIC_TF] == n
    assert counts[TOPIC_PLAN] == 1
    assert counts[TOPIC_COMMANDS] == counts[TOPIC_EVENTS] == 0


def test_log_times_attachment_and_metadata(
    demo_recording: PassRecording, small_bytes: bytes, model: RobotModel
) -> None:
    reader = make_reader(io.BytesIO(small_bytes))
    small = small_recording(demo_recording)
    gen = small.frames.generation_time_ns.tolist()
    log_times: dict[str, list[int]] = defaultdict(list)
    for _, channel, message in reader.iter_messages(log_time_order=False):
        assert message.publish_time == message.log_time
        log_times[channel.topic].append(message.log_time)
    assert sorted(log_times[TOPIC_TELEMETRY]) == gen
    assert sorted(log_times[TOPIC_TF]) == gen
    assert sorted(log_times[TOPIC_COMMANDS]) == sorted(c.execute_time_ns for c in small.commands)
    assert sorted(log_times[TOPIC_EVENTS]) == [3, 5]
    assert log_times[TOPIC_PLAN] == [small.epoch_ns]
    (attachment,) = list(reader.iter_attachments())
    assert attachment.name == URDF_ATTACHMENT
    assert attachment.data.decode() == urdf_xml(model)
    (description,) = list(reader.iter_messages(topics=[TOPIC_ROBOT_DESCRIPTION]))
    assert json.loads(description[2].data) == {"data": urdf_xml(model)}
    (meta,) = [m for m in reader.iter_metadata() if m.name == METADATA_NAME]
    assert meta.metadata["frames"] == str(len(small.frames))
    # Seeking by time: the index gives exactly the frames from the 10th on.
    later = reader.iter_messages(topics=[TOPIC_TELEMETRY], starting_at=gen[10])
    assert [json.loads(m.data)["seq"] for _, _, m in later] == small.frames.seq[10:].tolist()


def test_frame_transforms_follow_the_recording_and_the_urdf(
    demo_recording: PassRecording, demo_file: Path, model: RobotModel
) -> None:
    rows = np.arange(0, len(demo_recording.frames), 97)  # ~130 frames across the whole pass
    want_t = demo_recording.frames.generation_time_ns[rows]
    with open(demo_file, "rb") as f:
        messages = {
            m.log_time: json.loads(m.data)
            for _, _, m in make_reader(f).iter_messages(topics=[TOPIC_TF])
            if m.log_time in set(want_t.tolist())
        }
    urdf_links = {link.get("name") for link in ET.fromstring(urdf_xml(model)).iter("link")}
    workspace = DynamicsWorkspace(model)
    for row, t_ns in zip(rows, want_t.tolist(), strict=True):
        transforms = messages[t_ns]["transforms"]
        parent_of = {tr["child_frame_id"]: tr["parent_frame_id"] for tr in transforms}
        assert len(parent_of) == len(transforms), "a frame has two parents"
        assert set(parent_of) == urdf_links
        for tr in transforms:
            assert tr["timestamp"] == {"sec": t_ns // 10**9, "nsec": t_ns % 10**9}
            q = [tr["rotation"][k] for k in "xyzw"]
            if tr["child_frame_id"] != "base_link":
                assert abs(np.linalg.norm(q) - 1.0) < 1e-12
        base = next(t for t in transforms if t["child_frame_id"] == "base_link")
        assert base["parent_frame_id"] == "orbit"
        recorded = demo_recording.frames.quat_orbit_from_base_xyzw[row].tolist()
        assert [base["rotation"][k] for k in "xyzw"] == recorded  # exactly, not approximately
        assert [base["translation"][k] for k in "xyz"] == [0.0, 0.0, 0.0]
        # The chain to the hand is the planner's forward kinematics.
        hand = workspace.hand_pose(
            State(
                joints_rad=demo_recording.frames.joints_rad[row],
                quat_orbit_from_base_xyzw=demo_recording.frames.quat_orbit_from_base_xyzw[row],
            )
        )
        for name in urdf_links:
            pose_in_orbit(transforms, name)  # every chain ends at the orbit frame
        pos_hand, rot_hand = pose_in_orbit(transforms, "hand")
        np.testing.assert_allclose(pos_hand, hand.pos_orbit_m, atol=1e-12)
        np.testing.assert_allclose(rot_hand, hand.rot_orbit_from_hand, atol=1e-12)


# --- bad files -----------------------------------------------------------------------------


def rewrite(
    data: bytes,
    *,
    drop_topic: str | None = None,
    edit: Any = None,
    drop_message: tuple[str, int] | None = None,
    keep_metadata: bool = True,
) -> bytes:
    """A copy of an MCAP file, with one thing changed."""
    reader = make_reader(io.BytesIO(data))
    summary = reader.get_summary()
    assert summary is not None
    out = io.BytesIO()
    writer = Writer(out)
    writer.start()
    schema_ids = {
        sid: writer.register_schema(s.name, s.encoding, s.data)
        for sid, s in summary.schemas.items()
    }
    channel_ids = {
        cid: writer.register_channel(c.topic, c.message_encoding, schema_ids[c.schema_id])
        for cid, c in summary.channels.items()
        if c.topic != drop_topic
    }
    for _, channel, m in reader.iter_messages(log_time_order=False):
        if channel.topic == drop_topic or drop_message == (channel.topic, m.sequence):
            continue
        payload = m.data
        if edit is not None and edit[0] == channel.topic and edit[1] == m.sequence:
            payload = json.dumps(edit[2](json.loads(payload))).encode()
        writer.add_message(channel_ids[channel.id], m.log_time, payload, m.publish_time, m.sequence)
    if keep_metadata:
        for record in reader.iter_metadata():
            writer.add_metadata(record.name, record.metadata)
    writer.finish()
    return out.getvalue()


def test_an_unchanged_rewrite_still_reads(small_bytes: bytes) -> None:
    # The helper itself changes nothing unless asked: the failures below are its edits'.
    assert_same_recording(
        read_mcap(io.BytesIO(rewrite(small_bytes))), read_mcap(io.BytesIO(small_bytes))
    )


def _set(key: str, value: Any) -> Any:
    def edit(doc: dict[str, Any]) -> dict[str, Any]:
        return doc | {key: value}

    return edit


@pytest.mark.parametrize(
    ("case", "match"),
    [
        ("garbage", "not an MCAP file"),
        ("empty", "not an MCAP file"),
        ("truncated_half", "damaged or truncated"),
        ("truncated_tail", "damaged or truncated"),
        ("corrupt_chunk", "damaged or truncated"),
        ("not_ours", "not a Hikoboshi pass recording"),
        ("no_events_channel", "required channel /hikoboshi/events is missing"),
        ("no_plan_channel", "required channel /hikoboshi/plan is missing"),
        ("five_joints", r"joints_rad: 5 items, expected 6"),
        ("string_seq", r"\.seq: expected integer, got str"),
        ("extra_field", "unexpected field 'surprise'"),
        ("float_time", r"generation_time_ns: expected integer, got float"),
        ("bad_command", r"\.stage_times_ns\.sent: expected integer or null, got str"),
        ("bad_plan", r"hikoboshi.Plan: missing required field 'prediction'"),
        ("lost_frame", r"/hikoboshi/telemetry lacks messages \[7\]"),
        ("lost_last_frame", "/hikoboshi/telemetry holds 39 messages, metadata says 40"),
        ("seq_backwards", "ascending seq"),
    ],
)
def test_bad_files_raise_the_domain_error(small_bytes: bytes, case: str, match: str) -> None:
    data = {
        "garbage": lambda: b"this is not an mcap file at all" * 10,
        "empty": lambda: b"",
        "truncated_half": lambda: small_bytes[: len(small_bytes) // 2],
        "truncated_tail": lambda: small_bytes[:-20],
        "corrupt_chunk": lambda: small_bytes[:400] + bytes(64) + small_bytes[464:],
        "not_ours": lambda: rewrite(small_bytes, keep_metadata=False),
        "no_events_channel": lambda: rewrite(small_bytes, drop_topic=TOPIC_EVENTS),
        "no_plan_channel": lambda: rewrite(small_bytes, drop_topic=TOPIC_PLAN),
        "five_joints": lambda: rewrite(
            small_bytes, edit=(TOPIC_TELEMETRY, 3, _set("joints_rad", [0.0] * 5))
        ),
        "string_seq": lambda: rewrite(small_bytes, edit=(TOPIC_TELEMETRY, 0, _set("seq", "0"))),
        "extra_field": lambda: rewrite(small_bytes, edit=(TOPIC_TELEMETRY, 1, _set("surprise", 1))),
        "float_time": lambda: rewrite(
            small_bytes, edit=(TOPIC_TELEMETRY, 2, _set("generation_time_ns", 1.5e9))
        ),
        "bad_command": lambda: rewrite(
            small_bytes, edit=(TOPIC_COMMANDS, 0, _set("stage_times_ns", {"sent": "soon"}))
        ),
        "bad_plan": lambda: rewrite(
            small_bytes,
            edit=(TOPIC_PLAN, 0, lambda d: {k: v for k, v in d.items() if k != "prediction"}),
        ),
        "lost_frame": lambda: rewrite(small_bytes, drop_message=(TOPIC_TELEMETRY, 7)),
        "lost_last_frame": lambda: rewrite(small_bytes, drop_message=(TOPIC_TELEMETRY, 39)),
        "seq_backwards": lambda: rewrite(small_bytes, edit=(TOPIC_TELEMETRY, 5, _set("seq", 0))),
    }[case]()
    with pytest.raises(RecordingFileError, match=match):
        read_mcap(io.BytesIO(data))


ORIHIME = Path(__file__).resolve().parents[2] / "examples" / "robots" / "orihime" / "orihime.toml"


def test_a_seven_joint_recording_round_trips_with_its_robots_schema_and_urdf() -> None:
    model = load_robot(ORIHIME).model
    assert model.n_joints == 7
    layout = FrameLayout(7, 3)
    frames = make_frames(range(30), seed=5, layout=layout)
    recording = PassRecording.from_frames(
        "seven", make_plan(n_joints=7), frames[0].generation_time_ns, frames
    )
    buf = io.BytesIO()
    write_mcap(recording, buf, model=model)
    buf.seek(0)
    got = read_mcap(buf)
    assert_same_recording(got, recording)
    assert got.frames.joints_rad.shape == (30, 7)
    buf.seek(0)
    reader = make_reader(buf)
    summary = reader.get_summary()
    assert summary is not None
    written = {
        c.topic: json.loads(summary.schemas[c.schema_id].data) for c in summary.channels.values()
    }
    schema = written[TOPIC_TELEMETRY]
    assert schema == telemetry_schema(layout) and schema != TELEMETRY_SCHEMA
    assert schema["properties"]["joints_rad"]["minItems"] == 7
    assert schema["properties"]["joint_targets_rad"]["maxItems"] == 7


def test_a_seven_joint_recording_is_not_written_with_ets7s_model() -> None:
    frames = make_frames(range(3), layout=FrameLayout(7, 3))
    recording = PassRecording.from_frames("seven", make_plan(n_joints=7), 0, frames)
    with pytest.raises(RecordingFileError, match="7 joints, the robot model 6"):
        write_mcap(recording, io.BytesIO())


def test_a_file_written_before_plans_named_their_robot_is_read_as_ets7s(
    demo_recording: PassRecording, monkeypatch: pytest.MonkeyPatch
) -> None:
    from planner.plan import Plan
    from telemetry.mcap import _write
    from telemetry.mcap._schemas import PLAN_SCHEMA, PLAN_SCHEMA_BEFORE_ROBOTS

    assert "robot" in PLAN_SCHEMA["properties"]
    assert "robot" not in PLAN_SCHEMA_BEFORE_ROBOTS["properties"]
    recording = small_recording(demo_recording)
    document = json.loads(recording.plan.to_json())
    assert document["robot"] == "ets7"
    old_document = json.dumps(
        {k: v for k, v in document.items() if k not in ("robot", "robot_hash")}
    )
    # Written as before: the plan without its robot, under the schema of then.
    monkeypatch.setattr(Plan, "to_json", lambda self: old_document)
    monkeypatch.setattr(_write, "PLAN_SCHEMA", PLAN_SCHEMA_BEFORE_ROBOTS)
    buf = io.BytesIO()
    write_mcap(recording, buf)
    monkeypatch.undo()
    buf.seek(0)
    back = read_mcap(buf)
    assert back.plan.robot == "ets7"
    assert back.plan.to_json() == recording.plan.to_json()
