"""``GET /api/windows`` and ``POST /api/passes`` naming a window (docs/missions.md): the
windows the library computes, by mission name (shipped or in the server's folder), the
refusals with their reasons, and a pass stored with its window, refused 409 when its plan
does not fit the window's net time. On SQLite and PostgreSQL. One application per module and
backend: its tests store plans and no pass, but the one that stores a pass, on its own."""

from __future__ import annotations

from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from mission import MISSIONS_DIR, compute_windows, load_mission
from planner.plan import Plan
from server.app import create_app
from server.operations.windows import start_lead_s
from server.services.clock import ManualClock
from server.settings import Settings
from server.storage import repository as repo
from tests.support.api import OPERATOR, TOKENS, VIEWER, sessions

ETS7 = MISSIONS_DIR / "ets7-1999.toml"
START = datetime(1999, 9, 30, tzinfo=UTC)


@pytest.fixture(scope="module")
def missions_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The server's own folder: ETS-VII's mission with margins that leave a few minutes."""
    folder = tmp_path_factory.mktemp("missions")
    text = ETS7.read_text()
    text = text.replace("aos_margin_s = 120.0", "aos_margin_s = 3400.0")
    (folder / "tight.toml").write_text(text)
    (folder / "broken.toml").write_text(text.replace("inclination_deg = 35.0", "x = 1"))
    return folder


def _client(database_url: str, data_dir: Path, missions_dir: Path) -> Iterator[TestClient]:
    settings = Settings(
        data_dir=data_dir, database_url=database_url, tokens=TOKENS, missions_dir=missions_dir
    )
    with TestClient(create_app(settings)) as c:
        yield c


@pytest.fixture(scope="module")
def client(
    module_database_url: str, tmp_path_factory: pytest.TempPathFactory, missions_dir: Path
) -> Iterator[TestClient]:
    """Shared by the module's tests, which store no pass."""
    yield from _client(module_database_url, tmp_path_factory.mktemp("app"), missions_dir)


@pytest.fixture()
def own_client(database_url: str, tmp_path: Path, missions_dir: Path) -> Iterator[TestClient]:
    """A fresh application, for the test that stores a pass."""
    yield from _client(database_url, tmp_path, missions_dir)


def _windows(client: TestClient, **query: Any) -> Any:
    params = {"mission": "ets7-1999", "start": "1999-09-30T00:00:00Z", "hours": 6, **query}
    return client.get("/api/windows", params=params, headers=VIEWER)


def test_the_windows_are_the_library_s(client: TestClient) -> None:
    response = _windows(client)
    assert response.status_code == 200, response.text
    body = response.json()
    expected = compute_windows(load_mission(ETS7), START, 6.0)
    assert body["count"] == len(body["data"]) == len(expected) == 7
    assert body["mission"] == "ets7-1999" and body["vehicle"] == "ETS-VII"
    assert (body["aos_margin_s"], body["los_margin_s"]) == (120.0, 60.0)
    for got, want in zip(body["data"], expected, strict=True):
        assert got["relay"] == want.relay
        assert datetime.fromisoformat(got["aos_time"]) == want.aos_utc
        assert datetime.fromisoformat(got["los_time"]) == want.los_utc
        assert datetime.fromisoformat(got["net_start_time"]) == want.net_start_utc
        assert got["net_s"] == pytest.approx(want.net_s)
        assert got["min_range_km"] == pytest.approx(want.min_range_km)
        assert got["light_time_max_s"] == pytest.approx(want.light_time_max_s)


def test_a_mission_in_the_server_s_folder_is_found_by_name(client: TestClient) -> None:
    body = _windows(client, mission="tight").json()
    assert body["mission"] == "tight" and body["aos_margin_s"] == 3400.0
    assert all(w["net_s"] < 300.0 for w in body["data"])


@pytest.mark.parametrize(
    ("query", "status", "code", "reason"),
    [
        ({"mission": "nope"}, 404, "unknown_mission", "it knows ['broken', 'ets7-1999', 'tight']"),
        ({"mission": "../ets7-1999"}, 422, "invalid_request", "mission"),
        ({"start": "1999-09-30T00:00:00"}, 422, "invalid_request", "start"),
        ({"start": "yesterday"}, 422, "invalid_request", "start"),
        ({"hours": 0}, 422, "invalid_request", "hours"),
        ({"hours": 169}, 422, "invalid_request", "hours"),
        ({"start": "2005-01-01T00:00:00Z"}, 422, "span_outside_elements", "over the 60 day"),
        # the ends of Python's datetimes, an offset away from overflowing
        ({"start": "0001-01-01T00:00:00+05:00"}, 422, "span_outside_elements", "60 day"),
        ({"start": "9999-12-31T23:59:00Z"}, 422, "span_outside_elements", "60 day"),
        ({"mission": "broken"}, 422, "invalid_mission", "vehicle.elements: missing"),
    ],
)
def test_refusals_say_why(
    client: TestClient, query: dict[str, Any], status: int, code: str, reason: str
) -> None:
    response = _windows(client, **query)
    assert response.status_code == status, response.text
    error = response.json()["error"]
    assert error["code"] == code
    assert reason in response.text


def test_windows_need_a_token(client: TestClient) -> None:
    response = client.get(
        "/api/windows", params={"mission": "ets7-1999", "start": "1999-09-30T00:00:00Z"}
    )
    assert response.status_code == 401


def _plan_id(client: TestClient, plan: Plan) -> str:
    with sessions(client)() as session:
        plan_id = repo.add_plan(session=session, plan=plan, created_at_ns=0).id
        session.commit()
    return plan_id


def _window_request(plan_id: str, mission: str, relay: str, aos: datetime) -> dict[str, Any]:
    return {
        "plan_id": plan_id,
        "name": "campaign pass 1",
        "window": {"mission": mission, "relay": relay, "aos_time": aos.isoformat()},
    }


def test_a_pass_named_by_its_window_runs_in_its_net_time_and_keeps_it(
    own_client: TestClient, ptp_plan: Plan
) -> None:
    client = own_client
    first = _windows(client).json()["data"][0]
    plan_id = _plan_id(client, ptp_plan)
    # the acquisition time as an operator would type it, to the minute
    typed = datetime.fromisoformat(first["aos_time"]).replace(second=0, microsecond=0)
    response = client.post(
        "/api/passes",
        json=_window_request(plan_id, "ets7-1999", first["relay"], typed),
        headers=OPERATOR,
    )
    assert response.status_code == 201, response.text
    body = response.json()
    assert body["relay"] == first["relay"] == "TDRS-West"
    assert body["aos_time"] == first["net_start_time"]
    assert body["los_time"] == first["net_end_time"]
    window = body["window"]
    assert window["mission"] == "ets7-1999" and len(window["mission_sha256"]) == 64
    assert window["aos_time"] == first["aos_time"] and window["los_time"] == first["los_time"]
    assert window["net_s"] == pytest.approx(first["net_s"])
    assert window["processing_delay_s"] == 2.75
    assert client.get(f"/api/passes/{body['id']}", headers=VIEWER).json() == body
    # a pass given by hand has no window
    listed = client.get("/api/passes", headers=VIEWER).json()["data"]
    assert [p["window"] is not None for p in listed] == [True]


def test_a_plan_longer_than_the_net_time_is_a_conflict(client: TestClient, ptp_plan: Plan) -> None:
    first = _windows(client, mission="tight").json()["data"][0]
    assert first["net_s"] < ptp_plan.duration_s + start_lead_s(Settings())
    plan_id = _plan_id(client, ptp_plan)
    aos = datetime.fromisoformat(first["aos_time"])
    response = client.post(
        "/api/passes", json=_window_request(plan_id, "tight", first["relay"], aos), headers=OPERATOR
    )
    assert response.status_code == 409, response.text
    error = response.json()["error"]
    assert error["code"] == "plan_exceeds_window"
    assert "3400 s after AOS" in error["message"]
    assert error["detail"]["net_s"] == pytest.approx(first["net_s"])
    needed_s = ptp_plan.duration_s + start_lead_s(Settings())
    assert error["detail"]["needed_s"] == pytest.approx(needed_s)
    assert _utc(error["detail"]["aos_time"]) == _utc(first["aos_time"])
    assert _utc(error["detail"]["los_time"]) == _utc(first["los_time"])
    assert client.get("/api/passes", headers=VIEWER).json()["count"] == 0
    assert client.get("/api/events", headers=VIEWER).json()["count"] == 0


@pytest.mark.parametrize(
    ("mission", "relay", "aos", "status", "code"),
    [
        ("nope", "TDRS-East", START, 404, "unknown_mission"),
        ("ets7-1999", "TDRS-North", START, 404, "unknown_relay"),
        # TDRS-West acquires at 00:25:14; nothing near 00:05
        ("ets7-1999", "TDRS-West", START + timedelta(minutes=5), 404, "no_such_window"),
        ("ets7-1999", "TDRS-West", datetime(2010, 1, 1, tzinfo=UTC), 422, "span_outside_elements"),
        ("ets7-1999", "TDRS-West", datetime(1, 1, 1, 0, 1, tzinfo=UTC), 422, "time_out_of_range"),
        ("ets7-1999", "TDRS-West", datetime(9999, 12, 31, tzinfo=UTC), 422, "time_out_of_range"),
    ],
)
def test_a_window_that_is_not_there_is_refused(
    client: TestClient,
    ptp_plan: Plan,
    mission: str,
    relay: str,
    aos: datetime,
    status: int,
    code: str,
) -> None:
    plan_id = _plan_id(client, ptp_plan)
    response = client.post(
        "/api/passes", json=_window_request(plan_id, mission, relay, aos), headers=OPERATOR
    )
    assert response.status_code == status, response.text
    assert response.json()["error"]["code"] == code
    assert client.get("/api/passes", headers=VIEWER).json()["count"] == 0


def test_times_and_a_window_together_are_refused(client: TestClient, ptp_plan: Plan) -> None:
    plan_id = _plan_id(client, ptp_plan)
    body = _window_request(plan_id, "ets7-1999", "TDRS-West", START)
    body["aos_time"] = START.isoformat()
    body["los_time"] = (START + timedelta(hours=1)).isoformat()
    response = client.post("/api/passes", json=body, headers=OPERATOR)
    assert response.status_code == 422
    assert response.json()["error"]["code"] == "invalid_request"


def test_the_server_s_folder_comes_from_the_environment_and_shadows_a_shipped_mission(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    from server.services.missions import known_missions

    monkeypatch.setenv("HIKOBOSHI_MISSIONS_DIR", str(tmp_path))
    settings = Settings.from_env()
    assert settings.missions_dir == tmp_path
    (tmp_path / "ets7-1999.toml").write_text(ETS7.read_text())
    (tmp_path / "not a name.toml").write_text(ETS7.read_text())
    known = known_missions(settings)
    assert known["ets7-1999"] == (tmp_path / "ets7-1999.toml").resolve()
    assert "not a name" not in known
    monkeypatch.delenv("HIKOBOSHI_MISSIONS_DIR")
    assert Settings.from_env().missions_dir is None
    assert known_missions(Settings())["ets7-1999"] == ETS7.resolve()


def _utc(text: str) -> datetime:
    return datetime.fromisoformat(text)


def _ground_time(client: TestClient, at: datetime) -> str:
    """The ground's injected clock (the routes' ClockDep) set to ``at``; ``at`` as the
    refusals write it."""
    wall_ns = (at - datetime(1970, 1, 1, tzinfo=UTC)) // timedelta(microseconds=1) * 1000
    client.app.state.clock = ManualClock(wall_ns=wall_ns)  # type: ignore[attr-defined]
    return at.isoformat().replace("+00:00", "Z")


def _start(client: TestClient, pass_id: str) -> Any:
    body = {"confirm": "START campaign pass 1"}
    return client.post(f"/api/passes/{pass_id}/start", json=body, headers=OPERATOR)


def test_a_pass_starts_only_inside_its_window_and_early_enough_for_its_plan(
    own_client: TestClient, ptp_plan: Plan
) -> None:
    """A pass scheduled in the 1999 window: at the ground's time (its injected clock) before
    the net time opens, after it closed, and too late in it for the plan's last command to
    fall before LOS less the margin, the start is refused naming the window and the ground's
    time, audited, and the pass stays scheduled; inside it, the window lets it by (to the
    next gate: this plan was never checked against the flight rules)."""
    client = own_client
    first = _windows(client).json()["data"][0]
    plan_id = _plan_id(client, ptp_plan)
    aos = datetime.fromisoformat(first["aos_time"])
    request = _window_request(plan_id, "ets7-1999", first["relay"], aos)
    pass_id = client.post("/api/passes", json=request, headers=OPERATOR).json()["id"]
    net_start = _utc(first["net_start_time"])
    net_end = _utc(first["net_end_time"])
    latest = net_end - timedelta(seconds=ptp_plan.duration_s + start_lead_s(Settings()))

    refused = []
    for at, code, says in [
        (datetime(2026, 5, 1, 12, tzinfo=UTC), "outside_window", "has closed"),
        (net_start - timedelta(seconds=1), "outside_window", "has not opened yet"),
        (net_end, "outside_window", "has closed"),
        (latest + timedelta(seconds=1), "plan_exceeds_window", "its last command would fall"),
    ]:
        ground_time = _ground_time(client, at)
        response = _start(client, pass_id)
        assert response.status_code == 409, response.text
        error = response.json()["error"]
        assert error["code"] == code and says in error["message"], error
        assert "TDRS-West's window of mission ets7-1999 (AOS 1999-09-30T00:25:" in error["message"]
        assert f"the ground's time is {ground_time}" in error["message"]
        assert error["detail"]["ground_time"] == ground_time
        assert _utc(error["detail"]["aos_time"]) == _utc(first["aos_time"])
        assert _utc(error["detail"]["los_time"]) == _utc(first["los_time"])
        refused.append((code, error["message"]))
    late = response.json()["error"]["detail"]
    assert late["needed_s"] > late["available_s"]
    assert abs(_utc(late["latest_start_time"]) - latest) < timedelta(milliseconds=1)

    events = client.get("/api/events?kind=pass_start_refused", headers=VIEWER).json()["data"]
    got = sorted((e["detail"]["reason"], e["detail"]["message"]) for e in events)
    assert got == sorted(refused)
    for e in events:  # the window it was judged by, and the ground's time, in the audit
        window = e["detail"]["window"]
        assert {"aos_time", "los_time"} <= set(window), window
        assert "ground_time" in window, window  # the test's ground judges on its own clock
    assert client.get(f"/api/passes/{pass_id}", headers=VIEWER).json()["state"] == "scheduled"

    for at in (net_start, latest - timedelta(seconds=1)):
        _ground_time(client, at)
        response = _start(client, pass_id)
        assert response.json()["error"]["code"] == "flight_rules_unchecked", response.text
