"""Telemetry on the console: columns a browser can plot, per pass, decimated on request."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from telemetry.layout import DEFAULT_LAYOUT, FrameLayout
from tests.server.storage.factories import FRAME_PERIOD_NS, make_frames
from tests.support.api import add_pass
from tests.support.console import (
    AS_VIEWER,
    CONSOLE,
    FakeSpacecraft,
    drain,
    frames_of,
    subscribe,
    welcome,
)

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time

#: ETS-VII's telemetry fields: the frames these tests fly.
TELEMETRY_FIELDS = DEFAULT_LAYOUT.fields

VIEWER = {"Authorization": "Bearer v-token"}


def test_frames_arrive_as_columns_equal_to_what_is_stored(client: TestClient) -> None:
    pass_id = add_pass(client)
    other = add_pass(client, "pass-2")
    spacecraft = FakeSpacecraft(client, pass_id)
    frames = make_frames(range(12))
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        welcome(ws)
        reply = subscribe(ws, topic="telemetry", pass_id=pass_id.upper())  # any UUID spelling
        assert reply["pass_id"] == pass_id and reply["seq"] == 0
        subscribe(ws, topic="telemetry", pass_id=other)  # no frames of that pass
        for lo in range(0, 12, 4):
            spacecraft.send(frames[lo : lo + 4])
        messages = drain(ws)
    assert [(m["type"], m["pass_id"], m["seq"]) for m in messages] == [
        ("telemetry", pass_id, 1),
        ("telemetry", pass_id, 2),
        ("telemetry", pass_id, 3),
    ]
    assert list(messages[0]["columns"]) == ["seq", "generation_time_ns", *TELEMETRY_FIELDS]
    got = frames_of(messages)
    assert sorted(got) == list(range(12))
    for frame in frames:
        row = got[frame.seq]
        assert row["generation_time_ns"] == frame.generation_time_ns
        assert [row[f"j{i}"] for i in range(1, 7)] == frame.joints_rad
        assert [row[n] for n in ("qx", "qy", "qz", "qw")] == frame.quat_orbit_from_base_xyzw
        assert row["acs_mode"] == frame.acs_mode.value
        assert row["buffer_next_execute_time_ns"] == frame.buffer.next_execute_time_ns
    # The same numbers as the archive gives over REST.
    fields = ",".join(TELEMETRY_FIELDS)
    response = client.get(f"/api/passes/{pass_id}/telemetry?fields={fields}", headers=VIEWER)
    assert response.status_code == 200, response.text
    for stored in response.json()["rows"]:
        assert got[stored["seq"]] == {
            "seq": stored["seq"],
            "generation_time_ns": stored["generation_time_ns"],
            **stored["values"],
        }


def test_max_rate_decimates_by_generation_time_and_fields_trim_columns(client: TestClient) -> None:
    pass_id = add_pass(client)
    spacecraft = FakeSpacecraft(client, pass_id)
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        welcome(ws)
        # j7: the archive has the column, this 6-joint pass does not: left out
        subscribe(
            ws, topic="telemetry", pass_id=pass_id, max_rate_hz=2.5, fields=["j1", "j7", "wz"]
        )
        for lo in range(0, 30, 3):  # 10 Hz frames, three a message
            spacecraft.send(make_frames(range(lo, lo + 3)))
        messages = drain(ws)
    got = frames_of(messages)
    # One frame per 0.4 s of generation time: every fourth.
    assert FRAME_PERIOD_NS * 4 == 400_000_000
    assert sorted(got) == list(range(0, 30, 4))
    assert all(
        list(m["columns"]) == ["seq", "generation_time_ns", "reception_time_ns", "j1", "wz"]
        for m in messages
    )
    # Messages all of whose frames are decimated away are not sent; seqs still increase.
    seqs = [m["seq"] for m in messages]
    assert seqs == sorted(set(seqs)) and len(seqs) < 10


def test_a_seven_joint_pass_streams_its_own_columns(client: TestClient) -> None:
    seven = FrameLayout(7, 3)
    pass_id = add_pass(client, "seven", n_joints=7)
    ets7 = add_pass(client, "ets7")
    spacecraft = FakeSpacecraft(client, pass_id)
    frames = make_frames(range(6), seed=9, layout=seven)
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        welcome(ws)
        subscribe(ws, topic="telemetry", pass_id=pass_id)
        subscribe(ws, topic="telemetry", pass_id=ets7, fields=["j1", "j7"])
        spacecraft.send(frames[:3])
        spacecraft.send(frames[3:])
        messages = drain(ws)
    assert messages and all(m["pass_id"] == pass_id for m in messages)
    assert all(list(m["columns"]) == list(seven.columns) for m in messages)
    got = frames_of(messages)
    assert [got[f.seq]["j7"] for f in frames] == [f.joints_rad[6] for f in frames]
    assert [got[f.seq]["t7"] for f in frames] == [f.joint_targets_rad[6] for f in frames]
    # The archive answers the same values, and its default fields are the pass's robot's.
    response = client.get(f"/api/passes/{pass_id}/telemetry", headers=VIEWER)
    assert response.status_code == 200, response.text
    body = response.json()
    assert body["fields"] == list(seven.fields)
    stored = {row["seq"]: row["values"] for row in body["rows"]}
    for seq, values in got.items():
        assert {k: v for k, v in values.items() if k in stored[seq]} == stored[seq]
    # ETS-VII's pass answers as before: no j7 in its fields, and asking for it is a 422.
    response = client.get(f"/api/passes/{ets7}/telemetry", headers=VIEWER)
    assert response.json()["fields"] == list(TELEMETRY_FIELDS)
    response = client.get(f"/api/passes/{ets7}/telemetry?fields=j1,j7", headers=VIEWER)
    assert response.status_code == 422 and "'j7'" in response.text
