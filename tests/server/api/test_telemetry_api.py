"""``/api/passes/{id}/telemetry``: raw rows and decimation against frames ingested through
the storage, compared with NumPy. The tests only read: one application and one stored pass
per module and backend."""

from __future__ import annotations

import numpy as np
import pytest
from fastapi.testclient import TestClient

from planner.plan import Plan
from telemetry.layout import FrameLayout
from telemetry.wire import TelemetryFrame
from tests.server.storage.factories import (
    FRAME_PERIOD_NS,
    T0_NS,
    make_frames,
    make_plan,
    store_pass,
)
from tests.support.api import VIEWER, sessions

N_FRAMES = 95


@pytest.fixture(scope="module")
def client(module_client: TestClient) -> TestClient:
    return module_client


@pytest.fixture(scope="module")
def pass_with_frames(client: TestClient, ptp_plan: Plan) -> tuple[str, list[TelemetryFrame]]:
    frames = make_frames(range(N_FRAMES), seed=7)
    with sessions(client)() as session:
        pass_id = store_pass(session, ptp_plan, frames=frames).id
        session.commit()
    return pass_id, frames


def test_raw_rows_in_a_time_range(
    client: TestClient, pass_with_frames: tuple[str, list[TelemetryFrame]]
) -> None:
    pass_id, frames = pass_with_frames
    t0, t1 = T0_NS + 10 * FRAME_PERIOD_NS, T0_NS + 20 * FRAME_PERIOD_NS
    body = client.get(
        f"/api/passes/{pass_id}/telemetry?t0={t0}&t1={t1}&fields=j1,acs_mode,buffer_queued",
        headers=VIEWER,
    ).json()
    assert body["mode"] == "raw" and body["buckets"] is None and body["truncated"] is False
    assert body["fields"] == ["j1", "acs_mode", "buffer_queued"]
    assert [r["seq"] for r in body["rows"]] == list(range(10, 20)) and body["count"] == 10
    for row, frame in zip(body["rows"], frames[10:20], strict=True):
        assert row["generation_time_ns"] == frame.generation_time_ns
        assert row["values"] == {
            "j1": frame.joints_rad[0],
            "acs_mode": str(frame.acs_mode),
            "buffer_queued": frame.buffer.queued,
        }
    assert body["rows"][0]["generation_time"] == "1970-01-01T01:23:21Z"  # T0_NS + 1 s


def test_raw_rows_are_limited(
    client: TestClient, pass_with_frames: tuple[str, list[TelemetryFrame]]
) -> None:
    pass_id, _ = pass_with_frames
    body = client.get(f"/api/passes/{pass_id}/telemetry?limit=7", headers=VIEWER).json()
    assert body["count"] == 7 and body["truncated"] is True
    assert [r["seq"] for r in body["rows"]] == list(range(7))
    assert "reception_time_ns" in body["rows"][0]["values"]  # every field by default


def test_buckets_without_a_range_span_the_stored_frames(
    client: TestClient, pass_with_frames: tuple[str, list[TelemetryFrame]]
) -> None:
    """``?buckets=10`` alone: ten spans of the pass's frames (its first to its last), not of
    [0, 2**63) (one bucket of 29 years dated 1999-03-25); an open end alone is the frames'."""
    pass_id, frames = pass_with_frames
    first, last = frames[0].generation_time_ns, frames[-1].generation_time_ns
    url = f"/api/passes/{pass_id}/telemetry?fields=j2&buckets=10"
    body = client.get(url, headers=VIEWER).json()
    assert (body["t0_ns"], body["t1_ns"]) == (first, last + 1)
    assert body["count"] == 10 and sum(b["count"] for b in body["buckets"]) == len(frames)
    assert body["buckets"][0]["t_start_ns"] == first
    half = first + (last - first) // 2
    later = client.get(f"{url}&t0={half}", headers=VIEWER).json()
    assert (later["t0_ns"], later["t1_ns"]) == (half, last + 1)
    assert sum(b["count"] for b in later["buckets"]) == sum(
        1 for f in frames if f.generation_time_ns >= half
    )


def test_buckets_match_numpy(
    client: TestClient, pass_with_frames: tuple[str, list[TelemetryFrame]]
) -> None:
    pass_id, frames = pass_with_frames
    t0, t1, n = T0_NS, T0_NS + N_FRAMES * FRAME_PERIOD_NS, 10
    body = client.get(
        f"/api/passes/{pass_id}/telemetry?t0={t0}&t1={t1}&fields=j2,wz,buffer_queued&buckets={n}",
        headers=VIEWER,
    ).json()
    assert body["mode"] == "buckets" and body["rows"] is None
    width = body["width_ns"]
    assert width == -(-(t1 - t0) // n)
    times = np.array([f.generation_time_ns for f in frames])
    values = {
        "j2": np.array([f.joints_rad[1] for f in frames]),
        "wz": np.array([f.omega_base_in_base_radps[2] for f in frames]),
        "buffer_queued": np.array([f.buffer.queued for f in frames], dtype=np.float64),
    }
    index = (times - t0) // width
    assert [b["t_start_ns"] for b in body["buckets"]] == [t0 + k * width for k in range(n)]
    for k, bucket in enumerate(body["buckets"]):
        inside = index == k
        assert bucket["count"] == int(inside.sum())
        for name, v in values.items():
            assert bucket["min"][name] == v[inside].min()
            assert bucket["max"][name] == v[inside].max()
            # SQL sums in its own order: equal to a few ulps, not bit for bit
            assert bucket["mean"][name] == pytest.approx(v[inside].mean(), rel=1e-12, abs=1e-15)


@pytest.mark.parametrize(
    ("query", "needle"),
    [
        ("fields=j1,j9", "'j9'"),  # stored for robots of 9+ joints: not this pass's
        ("fields=j1,j13", "'j13'"),  # no robot's
        ("fields=acs_mode&buckets=3", "'acs_mode'"),
        ("fields=j1,j1", "repeat"),
        ("t0=5&t1=5", "empty"),
        ("buckets=0", "buckets"),
        ("t1=-1", "t1"),
    ],
)
def test_bad_queries_are_422_naming_the_culprit(
    client: TestClient, pass_with_frames: tuple[str, list[TelemetryFrame]], query: str, needle: str
) -> None:
    pass_id, _ = pass_with_frames
    response = client.get(f"/api/passes/{pass_id}/telemetry?{query}", headers=VIEWER)
    assert response.status_code == 422, response.text
    assert needle in response.json()["error"]["message"]


def test_unknown_pass_and_missing_token(client: TestClient) -> None:
    url = "/api/passes/00000000-0000-0000-0000-000000000000/telemetry"
    assert client.get(url, headers=VIEWER).status_code == 404
    assert client.get(url).status_code == 401
    assert client.get(f"{url}?buckets=4", headers=VIEWER).status_code == 404
    assert (
        client.get(
            "/api/events?pass_id=00000000-0000-0000-0000-000000000000", headers=VIEWER
        ).status_code
        == 404
    )


def test_a_seven_joint_pass_answers_its_own_fields_raw_and_decimated(client: TestClient) -> None:
    seven = FrameLayout(7, 3)
    frames = make_frames(range(40), seed=2, layout=seven)
    with sessions(client)() as session:
        pass_id = store_pass(session, make_plan(n_joints=7), name="seven", frames=frames).id
        session.commit()
    body = client.get(f"/api/passes/{pass_id}/telemetry", headers=VIEWER).json()
    assert body["fields"] == list(seven.fields) and body["count"] == 40
    assert [r["values"]["t7"] for r in body["rows"]] == [f.joint_targets_rad[6] for f in frames]
    t0, t1 = T0_NS, T0_NS + 40 * FRAME_PERIOD_NS
    body = client.get(
        f"/api/passes/{pass_id}/telemetry?t0={t0}&t1={t1}&fields=j7&buckets=4", headers=VIEWER
    ).json()
    j7 = np.array([f.joints_rad[6] for f in frames]).reshape(4, 10)
    assert [b["min"]["j7"] for b in body["buckets"]] == j7.min(axis=1).tolist()
    assert [b["max"]["j7"] for b in body["buckets"]] == j7.max(axis=1).tolist()
    response = client.get(f"/api/passes/{pass_id}/telemetry?fields=j8", headers=VIEWER)
    assert response.status_code == 422 and "'j8'" in response.json()["error"]["message"]
