"""``POST /api/plans/documents``: a plan document as ``hikoboshi plan --out`` writes it,
stored with its commands as they are and the ground's flight-rules report in place of its
own; hostile documents refused with 422 and the reason, nothing stored."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from planner.description import default_robot
from planner.plan import DOCUMENT_KEYS, Plan
from server.app import create_app
from server.operations.planning import check
from server.settings import Settings
from tests.support.api import OPERATOR, TOKENS, VIEWER

ROUTE = "/api/plans/documents"


def _nothing_stored(client: TestClient) -> None:
    assert client.get("/api/plans", headers=VIEWER).json()["count"] == 0
    assert client.get("/api/events", headers=VIEWER).json()["count"] == 0


@pytest.fixture(scope="module")
def grounds_report(ptp_plan: Plan) -> dict[str, Any]:
    """What the ground's own check says of the plan (the one call every caller makes)."""
    return dict(check(ptp_plan, default_robot()).report.to_dict())


def test_a_document_is_stored_as_flown_with_the_grounds_report_not_its_own(
    client: TestClient, ptp_plan: Plan, grounds_report: dict[str, Any]
) -> None:
    document = json.loads(ptp_plan.to_json())
    assert grounds_report["passed"] is True
    # a lie: the document says it fails, with no rows at all
    document["flight_rules"] = {**grounds_report, "passed": False, "rows": []}
    response = client.post(ROUTE, content=json.dumps(document), headers=OPERATOR)
    assert response.status_code == 201, response.text
    body = response.json()
    assert body["flight_rules"]["passed"] is True
    assert [r["rule"] for r in body["flight_rules"]["rows"]] == [
        r["rule"] for r in grounds_report["rows"]
    ]
    stored = json.loads(client.get(f"/api/plans/{body['id']}/document", headers=VIEWER).text)
    assert stored["flight_rules"] == grounds_report
    for part in ("commands", "acs_commands", "initial_joints_rad", "robot_hash", "prediction"):
        assert stored[part] == document[part], part
    events = client.get("/api/events", headers=VIEWER).json()["data"]
    assert [(e["kind"], e["actor"], e["detail"]["plan_id"]) for e in events] == [
        ("plan_created", "otto", body["id"])
    ]


def test_the_declared_keys_are_the_documents(
    module_client: TestClient, ptp_plan: Plan, grounds_report: dict[str, Any]
) -> None:
    checked = json.loads(check(ptp_plan, default_robot()).plan.to_json())
    assert tuple(checked) == DOCUMENT_KEYS
    openapi = module_client.app.openapi()  # type: ignore[attr-defined]
    body = openapi["paths"][ROUTE]["post"]["requestBody"]["content"]["application/json"]
    assert tuple(body["schema"]["properties"]) == DOCUMENT_KEYS
    assert body["schema"]["additionalProperties"] is False


def test_a_document_for_a_robot_the_server_does_not_know_is_422(
    client: TestClient, ptp_plan: Plan
) -> None:
    document = json.loads(ptp_plan.to_json())
    document["robot"], document["robot_hash"] = "ghost", "0" * 64
    response = client.post(ROUTE, content=json.dumps(document), headers=OPERATOR)
    assert response.status_code == 422, response.text
    error = response.json()["error"]
    assert error["code"] == "unknown_robot"
    assert "'ghost'" in error["message"] and "000000000000" in error["message"]
    _nothing_stored(client)


def _edit(change: Callable[[dict[str, Any]], None]) -> Callable[[str], bytes]:
    def edited(text: str) -> bytes:
        document = json.loads(text)
        change(document)
        return json.dumps(document).encode()

    return edited


def _joint0(value: str) -> Callable[[str], bytes]:
    """The first command's first angle written as ``value`` (NaN, 1e999: no json.dumps)."""

    def edited(text: str) -> bytes:
        head, tail = text.split('"joints_rad": [', 1)
        return (head + '"joints_rad": [' + value + tail[tail.index(",") :]).encode()

    return edited


def _swap_tags(doc: dict[str, Any]) -> None:
    commands = doc["commands"]
    commands[1]["t_s"], commands[2]["t_s"] = commands[2]["t_s"], commands[1]["t_s"]


def _off_grid(doc: dict[str, Any]) -> None:
    for c in doc["commands"]:
        c["t_s"] += 0.1
    doc["prediction"]["t_s"] = [c["t_s"] for c in doc["commands"]]


def _seven_joints(doc: dict[str, Any]) -> None:
    for c in doc["commands"]:
        c["joints_rad"].append(0.0)


def _acs_after_end(doc: dict[str, Any]) -> None:
    doc["acs_commands"][-1]["t_s"] = doc["commands"][-1]["t_s"] + 1.0


def _short_prediction(doc: dict[str, Any]) -> None:
    doc["prediction"]["wheel_momentum_nms"].pop()


def _deep(doc: dict[str, Any]) -> None:
    nested: Any = 0
    for _ in range(40):
        nested = [nested]
    doc["parameters"]["nest"] = nested


@pytest.mark.parametrize(
    ("hostile", "needle"),
    [
        (lambda _: b"{", "not JSON"),
        (lambda _: b"[]", "a JSON object"),
        (lambda _: b"\xff\xfe", "not JSON"),
        (_joint0("NaN"), "NaN is not a number"),
        (_joint0("-Infinity"), "Infinity is not a number"),
        (_joint0("1e999"), "too large for a float"),
        (_joint0("1" * 5000), "not JSON"),
        (_edit(_swap_tags), "0.25 s apart"),
        (_edit(_off_grid), "off the 0.25 s grid"),
        (_edit(lambda d: d["commands"].clear()), "plan commands"),
        (_edit(lambda d: d.pop("commands")), "malformed"),
        (_edit(lambda d: d.update(format_version=2)), "format_version"),
        (_edit(lambda d: d["acs_commands"][0].update(mode="warp")), "warp"),
        (_edit(lambda d: d["segments"][0].update(kind="teleport")), "teleport"),
        (_edit(_seven_joints), "initial_joints_rad"),
        (_edit(_acs_after_end), "acs_commands"),
        (_edit(_short_prediction), "wheel_momentum_nms"),
        (_edit(lambda d: d.update(robot_hash="ABC")), "robot_hash"),
        (_edit(lambda d: d.update(trusted=True)), "unknown keys ['trusted']"),
        (_edit(lambda d: d.update(experiment="ptp\u0000")), "U+0000"),
        (_edit(_deep), "nested deeper"),
    ],
)
def test_a_hostile_document_is_422_with_its_reason_and_nothing_is_stored(
    module_client: TestClient,
    ptp_plan: Plan,
    hostile: Callable[[str], bytes],
    needle: str,
) -> None:
    response = module_client.post(ROUTE, content=hostile(ptp_plan.to_json()), headers=OPERATOR)
    assert response.status_code == 422, response.text
    error = response.json()["error"]
    assert error["code"] == "invalid_plan_document", error
    assert needle in error["message"], error["message"]
    _nothing_stored(module_client)


def _small_client(tmp_path: Path, **limits: int) -> TestClient:
    """Request bodies at most 50 kB (the ptp document is about 180 kB)."""
    settings = Settings(data_dir=tmp_path, tokens=TOKENS, max_request_bytes=50_000, **limits)
    return TestClient(create_app(settings))


def test_a_document_over_its_own_limit_is_413_and_nothing_is_stored(
    tmp_path: Path, ptp_plan: Plan
) -> None:
    document = ptp_plan.to_json().encode()
    assert len(document) > 100_000

    def chunks() -> Iterator[bytes]:  # no Content-Length: refused as it grows past the limit
        for k in range(0, len(document), 65536):
            yield document[k : k + 65536]

    with _small_client(tmp_path, max_plan_document_bytes=100_000) as client:
        for body in (document, chunks()):
            response = client.post(ROUTE, content=body, headers=OPERATOR)
            assert response.status_code == 413, response.text
            assert response.json()["error"]["code"] == "request_too_large"
            assert "100000 bytes" in response.json()["error"]["message"]
        _nothing_stored(client)


def test_a_document_within_its_limit_passes_the_edges_smaller_one(
    tmp_path: Path, ptp_plan: Plan
) -> None:
    document = ptp_plan.to_json().encode()
    with _small_client(tmp_path) as client:
        # any other route refuses the same body at the edge
        assert client.post("/api/plans", content=document, headers=OPERATOR).status_code == 413
        response = client.post(ROUTE, content=document, headers=OPERATOR)
        assert response.status_code == 201, response.text
        assert response.json()["n_commands"] == ptp_plan.command_times_s.size + len(
            ptp_plan.acs_commands
        )
