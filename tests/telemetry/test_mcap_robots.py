"""The MCAP's URDF attachment is its robot's, under its robot's name (``orihime.urdf``), and
readers find it; ETS-VII's stays ``ets7.urdf``, and files written before still read."""

from __future__ import annotations

import io
import json
import xml.etree.ElementTree as ET
from typing import Any

import pytest
from mcap.reader import make_reader

from planner.description import EXAMPLES_DIR, load_robot
from planner.model import default_model
from planner.plan import plan_for_robot
from planner.urdf import urdf_xml
from server.services.robots import robot_urdf
from telemetry.layout import FrameLayout
from telemetry.mcap import (
    METADATA_NAME,
    TOPIC_ROBOT_DESCRIPTION,
    URDF_ATTACHMENT,
    RecordingFileError,
    read_mcap,
    read_urdf,
    urdf_attachment_name,
    write_mcap,
)
from telemetry.recording import PassRecording
from tests.server.storage.factories import make_frames, make_plan

ORIHIME = EXAMPLES_DIR / "orihime" / "orihime.toml"


def _orihime_recording() -> PassRecording:
    frames = make_frames(range(20), seed=3, layout=FrameLayout(7, 3))
    plan = plan_for_robot(make_plan(n_joints=7), load_robot(ORIHIME))
    return PassRecording.from_frames("orihime-pass", plan, frames[0].generation_time_ns, frames)


def _attachments(data: bytes) -> dict[str, str]:
    return {a.name: a.data.decode() for a in make_reader(io.BytesIO(data)).iter_attachments()}


def _metadata(data: bytes) -> dict[str, str]:
    reader = make_reader(io.BytesIO(data))
    (meta,) = [m for m in reader.iter_metadata() if m.name == METADATA_NAME]
    return dict(meta.metadata)


def test_an_orihime_recording_attaches_its_urdf_under_its_name() -> None:
    orihime = load_robot(ORIHIME)
    buf = io.BytesIO()
    write_mcap(_orihime_recording(), buf, model=orihime.model)
    data = buf.getvalue()
    attachments = _attachments(data)
    assert list(attachments) == ["orihime.urdf"]
    urdf = attachments["orihime.urdf"]
    assert urdf == urdf_xml(orihime.model, name="orihime")
    root = ET.fromstring(urdf)
    assert root.get("name") == "orihime"
    assert len([j for j in root.iter("joint") if j.get("type") == "revolute"]) == 7
    assert _metadata(data)["urdf_attachment"] == "orihime.urdf"
    reader = make_reader(io.BytesIO(data))
    (description,) = list(reader.iter_messages(topics=[TOPIC_ROBOT_DESCRIPTION]))
    assert json.loads(description[2].data) == {"data": urdf}
    assert read_urdf(io.BytesIO(data)) == ("orihime.urdf", urdf)
    assert read_mcap(io.BytesIO(data)).plan.robot == "orihime"


def test_the_ground_attaches_the_descriptions_own_urdf() -> None:
    # What the ground's recordings pass (server.services.robots.urdf_for_plan): the URDF
    # `hikoboshi model urdf --robot FILE` prints, its base box included.
    orihime = load_robot(ORIHIME)
    document = robot_urdf(orihime)
    assert document != urdf_xml(orihime.model, name="orihime")  # its own base box
    buf = io.BytesIO()
    write_mcap(_orihime_recording(), buf, model=orihime.model, urdf=document)
    assert _attachments(buf.getvalue()) == {"orihime.urdf": document}
    assert read_urdf(io.BytesIO(buf.getvalue())) == ("orihime.urdf", document)


def test_ets7s_recording_keeps_ets7_urdf() -> None:
    frames = make_frames(range(5))
    recording = PassRecording.from_frames("ets7", make_plan(), frames[0].generation_time_ns, frames)
    buf = io.BytesIO()
    write_mcap(recording, buf)
    assert urdf_attachment_name(recording.plan.robot) == URDF_ATTACHMENT == "ets7.urdf"
    assert _attachments(buf.getvalue()) == {"ets7.urdf": urdf_xml(default_model())}
    assert read_urdf(io.BytesIO(buf.getvalue())) == ("ets7.urdf", urdf_xml(default_model()))


def test_a_file_of_before_is_read_by_its_ets7_urdf(monkeypatch: pytest.MonkeyPatch) -> None:
    """Files written before the attachment took its robot's name: ``ets7.urdf``, and (an
    older writer still) no ``urdf_attachment`` in the metadata."""
    from telemetry.mcap import _write

    metadata = _write._metadata

    def old_metadata(recording: PassRecording) -> dict[str, Any]:
        meta = metadata(recording)
        del meta["urdf_attachment"]
        return meta

    monkeypatch.setattr(_write, "_metadata", old_metadata)
    monkeypatch.setattr(_write, "urdf_attachment_name", lambda robot: "ets7.urdf")
    orihime = load_robot(ORIHIME)
    buf = io.BytesIO()
    write_mcap(_orihime_recording(), buf, model=orihime.model)
    monkeypatch.undo()
    data = buf.getvalue()
    assert "urdf_attachment" not in _metadata(data)
    assert list(_attachments(data)) == ["ets7.urdf"]
    name, urdf = read_urdf(io.BytesIO(data))
    assert name == "ets7.urdf" and ET.fromstring(urdf).get("name") == "orihime"


def test_a_recording_without_its_urdf_is_refused_with_the_reason(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from telemetry.mcap import _write

    # the metadata names orihime.urdf, the file attaches something else
    monkeypatch.setattr(_write, "urdf_attachment_name", lambda robot: f"{robot}.txt")
    metadata = _write._metadata

    def named(recording: PassRecording) -> dict[str, Any]:
        return {**metadata(recording), "urdf_attachment": "orihime.urdf"}

    monkeypatch.setattr(_write, "_metadata", named)
    buf = io.BytesIO()
    write_mcap(_orihime_recording(), buf, model=load_robot(ORIHIME).model)
    monkeypatch.undo()
    with pytest.raises(RecordingFileError, match=r"no URDF attachment.*orihime\.urdf"):
        read_urdf(io.BytesIO(buf.getvalue()))
    with pytest.raises(RecordingFileError, match="not an MCAP file"):
        read_urdf(io.BytesIO(b"not mcap"))


def test_an_attachment_name_is_always_a_plain_file_name() -> None:
    assert urdf_attachment_name("orihime") == "orihime.urdf"
    assert urdf_attachment_name("../etc/passwd") == "_etc_passwd.urdf"
    assert "/" not in urdf_attachment_name("a/b") and urdf_attachment_name("") == "robot.urdf"
