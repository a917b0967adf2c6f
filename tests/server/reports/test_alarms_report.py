"""A pass's alarms in its report (the alarms and their timeline as tables, the timeline as a
figure) and in its recording: imported with it, exported again (SQLite and PostgreSQL)."""

from __future__ import annotations

import io
from dataclasses import replace
from typing import Any

from fastapi.testclient import TestClient

from server.services.report_tables import build_report
from telemetry.alarm import AlarmPublic
from telemetry.mcap import TOPIC_ALARMS, read_mcap
from telemetry.recording import PassRecording
from tests.support.alarms import cleared_alarm
from tests.support.api import OPERATOR, VIEWER
from tests.support.recordings import mcap_bytes


def _alarms(recording: PassRecording) -> tuple[dict[str, Any], dict[str, Any]]:
    """Joint 3's tracking error: watch at frame 100, critical at 110, cleared at 130,
    acknowledged; the vehicle's safing, still triggered."""
    gen = recording.frames.generation_time_ns
    seq = recording.frames.seq

    def at(k: int, severity: str | None, value: float) -> dict[str, Any]:
        return {
            "severity": severity,
            "generation_time_ns": int(gen[k]),
            "time_ns": 10_000 + k,
            "frame_seq": int(seq[k]),
            "value": value,
        }

    tracking = cleared_alarm(
        recording.meta.get("pass_id"),
        id="a1a1a1a1-0000-4000-8000-000000000001",
        acknowledged_by="otto",
        acknowledged_time_ns=20_000,
        comment="stuck joint",
        trigger_value=2.1,
        worst_value=6.5,
        last_value=0.3,
        count=30,
        raised_frame_seq=int(seq[100]),
        raised_generation_time_ns=int(gen[100]),
        raised_time_ns=10_100,
        updated_time_ns=20_000,
        cleared_generation_time_ns=int(gen[130]),
        cleared_time_ns=10_130,
        timeline=[at(100, "watch", 2.1), at(110, "critical", 5.5), at(130, None, 0.3)],
    )
    safing = {
        **tracking,
        "id": "a1a1a1a1-0000-4000-8000-000000000002",
        "quantity": "vehicle_safing",
        "channel": "",
        "label": "vehicle safing: joint tracking error",
        "source": "vehicle",
        "current_severity": "critical",
        "state": "triggered",
        "acknowledged": False,
        "acknowledged_by": None,
        "acknowledged_time_ns": None,
        "comment": None,
        "raised_time_ns": 10_111,
        "raised_frame_seq": None,
        "raised_generation_time_ns": int(gen[111]),
        "cleared_generation_time_ns": None,
        "cleared_time_ns": None,
        "timeline": [{**at(111, "critical", 6.5), "frame_seq": None}],
        "detail": "the vehicle safed itself: joint_tracking_error_deg joint3 at 6.5 deg",
    }
    return tracking, safing


def test_the_report_lists_the_alarms_with_their_timeline_and_the_recording_keeps_them(
    client: TestClient, short_recording: PassRecording
) -> None:
    tracking, safing = _alarms(short_recording)
    models = (AlarmPublic.model_validate(tracking), AlarmPublic.model_validate(safing))
    recording = replace(short_recording, alarms=models)
    reply = client.post("/api/passes/import", content=mcap_bytes(recording), headers=OPERATOR)
    assert reply.status_code == 201, reply.text
    pass_id = reply.json()["imported"]["id"]

    listed = client.get("/api/alarms", params={"pass": pass_id}, headers=VIEWER).json()
    assert {a["quantity"] for a in listed["alarms"]} == {tracking["quantity"], "vehicle_safing"}
    assert all(a["pass_id"] == pass_id for a in listed["alarms"])
    assert not {a["id"] for a in listed["alarms"]} & {tracking["id"], safing["id"]}  # new ids

    assert client.post(f"/api/passes/{pass_id}/analyses", headers=OPERATOR).status_code == 201
    report = client.get(f"/api/passes/{pass_id}/report", headers=VIEWER).json()
    tables = {t["id"]: t for t in report["tables"]}
    alarms, timeline = tables["alarms"], tables["alarm_timeline"]
    rows = [dict(zip(alarms["columns"], r, strict=True)) for r in alarms["rows"]]
    assert [(r["alarm"], r["severity"], r["state"]) for r in rows] == [
        ("1: joint_tracking_error_deg joint3", "critical", "cleared"),
        ("2: vehicle_safing", "critical", "triggered"),
    ]
    t_s = short_recording.t_s()
    assert rows[0]["raised_t_s"] == float(t_s[100])
    assert rows[0]["cleared_t_s"] == float(t_s[130])
    assert (rows[0]["acknowledged_by"], rows[0]["comment"], rows[0]["worst_value"]) == (
        "otto",
        "stuck joint",
        6.5,
    )
    assert "2 alarms: 2 critical" in alarms["notes"][0]
    bands = [(r[0], r[1], r[3]) for r in timeline["rows"]]
    first = "1: joint_tracking_error_deg joint3"
    assert bands == [
        (first, "watch", int(short_recording.frames.seq[100])),
        (first, "critical", int(short_recording.frames.seq[110])),
        (first, "within limits", int(short_recording.frames.seq[130])),
        (first, "acknowledged by otto: stuck joint", None),
        ("2: vehicle_safing", "critical", None),
    ]
    assert "alarm_timeline" in report["figures"]
    png = client.get(f"/api/passes/{pass_id}/report/figures/alarm_timeline.png", headers=VIEWER)
    assert png.status_code == 200 and png.content.startswith(b"\x89PNG")
    page = client.get(f"/api/passes/{pass_id}/report.html", headers=VIEWER).text
    assert 'id="alarms"' in page and "acknowledged by otto: stuck joint" in page

    exported = client.get(f"/api/passes/{pass_id}/recording.mcap", headers=VIEWER).content
    again = read_mcap(io.BytesIO(exported))
    assert [a.quantity for a in again.alarms] == [tracking["quantity"], "vehicle_safing"]
    assert again.alarms[0].model_dump(mode="json")["timeline"] == tracking["timeline"]
    from mcap.reader import make_reader

    logs = list(make_reader(io.BytesIO(exported)).iter_messages(topics=[TOPIC_ALARMS]))
    assert len(logs) == 3 + 1 + 1  # three band changes, an acknowledgement, the safing


def test_a_report_without_alarms_has_empty_alarm_tables() -> None:
    report = build_report(
        pass_id=None,
        name="quiet",
        state="complete",
        experiment="ptp",
        imported=False,
        documents={},
        figure_names=[],
    )
    tables = {t.id: t for t in report.tables}
    assert tables["alarms"].rows == [] and tables["alarm_timeline"].rows == []
    assert tables["alarms"].notes[0].startswith("0 alarms: none")
