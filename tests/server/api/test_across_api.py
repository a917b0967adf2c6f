"""``GET /api/telemetry/across``: one quantity across several passes, each on its own time
axis from its first frame, checked against numpy over the frames stored."""

from __future__ import annotations

import numpy as np
import pytest
from fastapi.testclient import TestClient

from server.api.lanes import is_heavy
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


def stored_pass(
    client: TestClient, name: str, frames: list[TelemetryFrame], n_joints: int = 6
) -> str:
    with sessions(client)() as session:
        key = store_pass(session, make_plan(n_joints=n_joints), name=name, frames=frames).id
        session.commit()
    return str(key)


@pytest.fixture()
def passes(client: TestClient) -> dict[str, list[TelemetryFrame]]:
    return _three_passes(client)


@pytest.fixture(scope="module")
def module_passes(module_client: TestClient) -> tuple[TestClient, str]:
    """The three passes on one application per backend, for the refusals (reads): its
    client and the first pass's id."""
    return module_client, next(iter(_three_passes(module_client)))


def _three_passes(client: TestClient) -> dict[str, list[TelemetryFrame]]:
    """Three passes: 40 frames from T0, 60 frames from 10 frames later (another axis
    origin), and one with none."""
    first = make_frames(range(40), seed=1)
    second = make_frames(range(10, 70), seed=2)
    return {
        stored_pass(client, "first", first): first,
        stored_pass(client, "second", second): second,
        stored_pass(client, "empty", []): [],
    }


def test_each_pass_on_its_own_axis_matches_numpy(
    client: TestClient, passes: dict[str, list[TelemetryFrame]]
) -> None:
    ids = list(passes)
    query = "&".join(f"pass_id={i}" for i in reversed(ids))
    response = client.get(f"/api/telemetry/across?field=hw2&buckets=4&{query}", headers=VIEWER)
    assert response.status_code == 200, response.text
    body = response.json()
    assert body["field"] == "hw2" and body["unit"] == "N m s" and body["buckets"] == 4
    assert [p["pass_id"] for p in body["passes"]] == list(reversed(ids)), "the order asked"
    by_id = {p["pass_id"]: p for p in body["passes"]}
    empty = by_id[ids[2]]
    assert empty["count"] == 0 and empty["buckets"] == [] and empty["mean"] is None
    for pass_id, frames in list(passes.items())[:2]:
        got = by_id[pass_id]
        values = np.array([f.wheel_momentum_nms[1] for f in frames])
        times = np.array([f.generation_time_ns for f in frames])
        assert got["count"] == len(frames)
        assert got["first_ns"] == times[0]
        assert got["duration_s"] == pytest.approx((times[-1] - times[0]) / 1e9)
        assert got["min"] == values.min() and got["max"] == values.max()
        assert got["mean"] == pytest.approx(values.mean(), rel=1e-12)
        # four equal spans of the pass's own [first, last] from t = 0
        width = -(-(int(times[-1] - times[0]) + 1) // 4)
        index = (times - times[0]) // width
        assert [b["t_s"] for b in got["buckets"]] == [k * width / 1e9 for k in range(4)]
        assert [b["count"] for b in got["buckets"]] == np.bincount(index).tolist()
        for k, bucket in enumerate(got["buckets"]):
            assert bucket["min"] == values[index == k].min()
            assert bucket["max"] == values[index == k].max()
            assert bucket["mean"] == pytest.approx(values[index == k].mean(), rel=1e-12)
    # the two non-empty passes' series start at t = 0 although 10 frames apart on board
    assert by_id[ids[1]]["first_ns"] - by_id[ids[0]]["first_ns"] == 10 * FRAME_PERIOD_NS
    assert by_id[ids[0]]["first_ns"] == T0_NS


def test_a_field_of_a_seven_joint_pass_only_where_it_exists(client: TestClient) -> None:
    seven = stored_pass(client, "seven", make_frames(range(20), layout=FrameLayout(7, 3)), 7)
    six = stored_pass(client, "six", make_frames(range(20)))
    ok = client.get(f"/api/telemetry/across?field=j7&pass_id={seven}", headers=VIEWER)
    assert ok.status_code == 200 and ok.json()["unit"] == "rad"
    response = client.get(
        f"/api/telemetry/across?field=j7&pass_id={seven}&pass_id={six}", headers=VIEWER
    )
    assert response.status_code == 422, response.text
    error = response.json()["error"]
    assert error["code"] == "unknown_field" and six in error["message"], error


@pytest.mark.parametrize(
    ("query", "status", "code"),
    [
        ("field=nope&pass_id={a}", 422, "unknown_field"),
        ("field=acs_mode&pass_id={a}", 422, "unknown_field"),  # not numeric
        ("field=hw1,hw2&pass_id={a}", 422, "one_field"),
        ("field=hw1&pass_id={a}&pass_id={a}", 422, "repeated_pass"),
        ("field=hw1&pass_id={a}&pass_id=" + "0" * 32, 404, "not_found"),
        ("field=hw1&" + "&".join(f"pass_id=p{i}" for i in range(21)), 422, "too_many_passes"),
        ("field=hw1", 422, "invalid_request"),
        ("field=hw1&pass_id={a}&buckets=0", 422, "invalid_request"),
    ],
)
def test_bad_queries_are_4xx_with_a_reason(
    module_passes: tuple[TestClient, str], query: str, status: int, code: str
) -> None:
    client, a = module_passes
    response = client.get(f"/api/telemetry/across?{query.format(a=a)}", headers=VIEWER)
    assert response.status_code == status, response.text
    assert response.json()["error"]["code"] == code


def test_it_needs_a_token_and_counts_as_a_heavy_read(client: TestClient) -> None:
    assert client.get("/api/telemetry/across?field=hw1&pass_id=x").status_code == 401
    assert is_heavy("GET", "/api/telemetry/across")
