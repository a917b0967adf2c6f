"""``GET /api/missions`` (docs/missions.md): the missions the server knows by name, shipped
and in its own folder, with what the console's timeline needs (relays, margins, the span
the elements reach, which ``GET /api/windows`` holds to); a file that does not load is
listed apart with its reason, never a 500."""

from __future__ import annotations

from collections.abc import Iterator
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from mission import MISSIONS_DIR, load_mission
from server.app import create_app
from server.settings import Settings
from tests.support.api import TOKENS, VIEWER

ETS7 = MISSIONS_DIR / "ets7-1999.toml"


@pytest.fixture()
def client(tmp_path: Path) -> Iterator[TestClient]:
    folder = tmp_path / "missions"
    folder.mkdir()
    text = ETS7.read_text()
    shifted = text.replace('epoch = "1999-09-30T00:00:00Z"', 'epoch = "2026-01-15T12:00:00Z"')
    assert shifted != text
    (folder / "later.toml").write_text(shifted)
    (folder / "broken.toml").write_text(text.replace("inclination_deg = 35.0", "x = 1"))
    settings = Settings(
        data_dir=tmp_path,
        database_url=f"sqlite:///{tmp_path / 'db.sqlite'}",
        tokens=TOKENS,
        missions_dir=folder,
    )
    with TestClient(create_app(settings)) as c:
        yield c


def _missions(client: TestClient) -> dict[str, Any]:
    response = client.get("/api/missions", headers=VIEWER)
    assert response.status_code == 200, response.text
    body: dict[str, Any] = response.json()
    return body


def test_the_missions_are_listed_by_name_with_their_relays_and_margins(
    client: TestClient,
) -> None:
    body = _missions(client)
    assert [m["name"] for m in body["data"]] == ["ets7-1999", "later"]
    assert body["count"] == 2
    assert body["max_hours"] == 168.0
    ets7 = body["data"][0]
    mission = load_mission(ETS7)
    assert ets7["vehicle"] == "ETS-VII" == mission.vehicle
    assert ets7["mission_sha256"] == mission.content_sha256
    assert [r["name"] for r in ets7["relays"]] == ["TDRS-East", "TDRS-West"]
    assert [r["longitude_deg"] for r in ets7["relays"]] == [-41.0, -174.0]
    assert ets7["relays"][0]["satellite"].startswith("TDRS-4")
    assert (ets7["aos_margin_s"], ets7["los_margin_s"]) == (120.0, 60.0)
    assert ets7["processing_delay_s"] == 2.75
    assert ets7["station"].startswith("Tsukuba")
    epoch = datetime.fromisoformat(ets7["epoch"])
    assert epoch == mission.orbit.epoch_utc
    assert datetime.fromisoformat(ets7["windows_from"]) == epoch - timedelta(days=60)
    assert datetime.fromisoformat(ets7["windows_until"]) == epoch + timedelta(days=60)
    assert body["data"][1]["epoch"].startswith("2026-01-15T12:00:00")


def test_a_file_that_does_not_load_is_listed_apart_with_its_reason(client: TestClient) -> None:
    body = _missions(client)
    assert body["unloadable"] == [
        {"name": "broken", "reason": "vehicle.elements: missing inclination_deg"}
    ]


def test_the_span_listed_is_the_one_the_windows_accept(client: TestClient) -> None:
    ets7 = _missions(client)["data"][0]
    until = datetime.fromisoformat(ets7["windows_until"])
    inside = (until - timedelta(hours=1)).isoformat()
    outside = (until + timedelta(minutes=1)).isoformat()
    query: dict[str, Any] = {"mission": "ets7-1999", "hours": 1}
    ok = client.get("/api/windows", params={**query, "start": inside}, headers=VIEWER)
    assert ok.status_code == 200, ok.text
    refused = client.get("/api/windows", params={**query, "start": outside}, headers=VIEWER)
    assert refused.status_code == 422
    assert refused.json()["error"]["code"] == "span_outside_elements"


def test_missions_need_a_token_and_have_a_readable_operation_id(client: TestClient) -> None:
    assert client.get("/api/missions").status_code == 401
    document = client.get("/openapi.json").json()
    assert document["paths"]["/api/missions"]["get"]["operationId"] == "list_missions"
