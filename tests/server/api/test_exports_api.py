"""``/api/passes/{id}/telemetry.csv`` and ``.parquet`` read back by other readers (the
``csv`` module, arro3's Parquet reader) against the REST JSON of the same frames; the
command history and the audit log searched by kind, stage, actor and time range. The tests
only read (or add a pass of their own): one application and one stored pass per module and
backend."""

from __future__ import annotations

import csv
import gzip
import io
import json
from typing import Any

import pandas as pd
import pyarrow.parquet as pq
import pytest
from arro3.io import read_parquet
from fastapi.testclient import TestClient

from planner.plan import Plan
from server.api.lanes import is_heavy
from server.services import exports
from server.storage import repository as repo
from telemetry.layout import DEFAULT_LAYOUT
from tests.server.storage.factories import (
    T0_NS,
    make_commands,
    make_frames,
    store_pass,
)
from tests.support.api import VIEWER, sessions

N_FRAMES = 23


@pytest.fixture(scope="module")
def client(module_client: TestClient) -> TestClient:
    return module_client


@pytest.fixture()
def pass_id(stored_pass_id: str, monkeypatch: pytest.MonkeyPatch) -> str:
    """``stored_pass_id``, which exports read 5 frames a page (several pages, the last one
    short)."""
    monkeypatch.setattr(exports, "PAGE_ROWS", 5)
    return stored_pass_id


@pytest.fixture(scope="module")
def stored_pass_id(client: TestClient, ptp_plan: Plan) -> str:
    """A pass with N_FRAMES frames, 9 commands and events of three kinds by two actors."""
    frames = make_frames(range(N_FRAMES), seed=3)
    with sessions(client)() as session:
        key = store_pass(session, ptp_plan, name="export me", frames=frames).id
        repo.add_commands(session=session, pass_id=key, commands=make_commands(9), queued_at_ns=0)
        for i, (kind, actor) in enumerate(
            [
                ("pass_state", "runner"),
                ("command_stage", "link"),
                ("pass_state", "otto"),
                ("command_stage", "link"),
                ("link_hello", "link"),
            ]
        ):
            repo.add_event(
                session=session, time_ns=1000 * (i + 1), kind=kind, actor=actor, pass_id=key
            )
        session.commit()
    return key


def rest_rows(client: TestClient, pass_id: str) -> list[dict[str, Any]]:
    body = client.get(f"/api/passes/{pass_id}/telemetry?limit=10000", headers=VIEWER).json()
    assert body["count"] == N_FRAMES and not body["truncated"]
    rows: list[dict[str, Any]] = body["rows"]
    return rows


def test_csv_reads_back_with_the_rest_json_values(client: TestClient, pass_id: str) -> None:
    response = client.get(f"/api/passes/{pass_id}/telemetry.csv", headers=VIEWER)
    assert response.status_code == 200, response.text
    assert response.headers["content-type"] == "text/csv; charset=utf-8"
    assert f'filename="pass-{pass_id}-telemetry.csv"' in response.headers["content-disposition"]
    reader = csv.reader(io.StringIO(response.text))
    header = next(reader)
    assert header[:4] == ["seq", "generation_time_ns [ns]", "j1 [rad]", "j2 [rad]"]
    assert "wx [rad/s]" in header and "hw1 [N m s]" in header and "qw [1]" in header
    assert "acs_mode" in header and "buffer_next_execute_time_ns [ns]" in header
    names = [h.split(" [")[0] for h in header]
    assert names == list(DEFAULT_LAYOUT.columns)
    lines = list(reader)
    expected = rest_rows(client, pass_id)
    assert len(lines) == len(expected) == N_FRAMES  # every page, none twice
    for line, row in zip(lines, expected, strict=True):
        cells = dict(zip(names, line, strict=True))
        assert int(cells["seq"]) == row["seq"]
        assert int(cells["generation_time_ns"]) == row["generation_time_ns"]
        for name, value in row["values"].items():
            cell = cells[name]
            if value is None:
                assert cell == ""
            elif isinstance(value, bool):
                assert cell == ("true" if value else "false")
            elif isinstance(value, str):
                assert cell == value
            elif isinstance(value, int):
                assert int(cell) == value
            else:
                assert float(cell) == value, name  # bit for bit: shortest round-trip text


def test_parquet_reads_back_with_the_rest_json_values_and_units(
    client: TestClient, pass_id: str
) -> None:
    response = client.get(f"/api/passes/{pass_id}/telemetry.parquet", headers=VIEWER)
    assert response.status_code == 200, response.text
    assert response.headers["content-type"] == "application/vnd.apache.parquet"
    assert "content-encoding" not in response.headers  # compressed inside already
    assert int(response.headers["content-length"]) == len(response.content)
    reader = read_parquet(response.content)
    schema = reader.schema
    assert schema.names == list(DEFAULT_LAYOUT.columns)
    assert schema.field("j1").metadata_str == {"unit": "rad"}
    assert schema.field("wz").metadata_str == {"unit": "rad/s"}
    assert schema.field("seq").metadata_str == {}
    meta = schema.metadata_str
    assert meta["hikoboshi.pass_id"] == pass_id
    assert json.loads(meta["hikoboshi.units"]) == DEFAULT_LAYOUT.units
    # as the outside readers users take show it: pyarrow's table metadata (from the Arrow
    # schema stored in the file) and pandas' attrs, each column's unit on its field
    arrow = pq.read_table(io.BytesIO(response.content))
    assert arrow.schema.metadata[b"hikoboshi.pass_id"] == pass_id.encode()
    assert json.loads(arrow.schema.metadata[b"hikoboshi.units"]) == DEFAULT_LAYOUT.units
    assert arrow.schema.field("j1").metadata == {b"unit": b"rad"}
    frame = pd.read_parquet(io.BytesIO(response.content))
    assert frame.attrs["pass_id"] == pass_id and frame.attrs["units"] == DEFAULT_LAYOUT.units
    assert frame["seq"].tolist() == arrow["seq"].to_pylist()
    table = reader.read_all()
    columns = {name: table[name].to_pylist() for name in schema.names}
    expected = rest_rows(client, pass_id)
    assert columns["seq"] == [r["seq"] for r in expected]
    assert columns["generation_time_ns"] == [r["generation_time_ns"] for r in expected]
    for name in DEFAULT_LAYOUT.fields:
        assert columns[name] == [r["values"][name] for r in expected], name


def test_csv_is_gzipped_when_asked(client: TestClient, pass_id: str) -> None:
    with client.stream(
        "GET",
        f"/api/passes/{pass_id}/telemetry.csv",
        headers={**VIEWER, "Accept-Encoding": "gzip"},
    ) as response:
        assert response.headers["content-encoding"] == "gzip"
        raw = b"".join(response.iter_raw())
    plain = client.get(
        f"/api/passes/{pass_id}/telemetry.csv", headers={**VIEWER, "Accept-Encoding": "identity"}
    ).content
    assert gzip.decompress(raw) == plain and len(raw) < len(plain)


@pytest.mark.parametrize("suffix", ["csv", "parquet"])
def test_exports_refuse_like_the_other_reads(client: TestClient, suffix: str) -> None:
    unknown = client.get(
        f"/api/passes/00000000-0000-4000-8000-000000000000/telemetry.{suffix}", headers=VIEWER
    )
    assert unknown.status_code == 404 and unknown.json()["error"]["code"] == "not_found"
    assert client.get(f"/api/passes/x/telemetry.{suffix}").status_code == 401
    assert is_heavy("GET", f"/api/passes/x/telemetry.{suffix}")  # the heavy reads' limit


def test_an_empty_pass_exports_its_header_only(client: TestClient, ptp_plan: Plan) -> None:
    with sessions(client)() as session:
        key = store_pass(session, ptp_plan, name="empty").id
        session.commit()
    text = client.get(f"/api/passes/{key}/telemetry.csv", headers=VIEWER).text
    assert text.count("\n") == 1 and text.startswith("seq,generation_time_ns [ns],")
    body = client.get(f"/api/passes/{key}/telemetry.parquet", headers=VIEWER).content
    assert read_parquet(body).read_all().num_rows == 0


# --- searching the command history and the audit log -------------------------------------


def seqs(client: TestClient, pass_id: str, query: str) -> list[int]:
    response = client.get(f"/api/passes/{pass_id}/commands?{query}", headers=VIEWER)
    assert response.status_code == 200, response.text
    body = response.json()
    assert body["count"] == len(body["data"])
    return [c["seq"] for c in body["data"]]


def test_commands_by_kind_and_time_tag(client: TestClient, pass_id: str) -> None:
    assert seqs(client, pass_id, "") == list(range(9))
    assert seqs(client, pass_id, "kind=acs") == [0]
    assert seqs(client, pass_id, "kind=joints") == list(range(1, 9))
    assert seqs(client, pass_id, "kind=joints&kind=acs") == list(range(9))
    # time tags T0 + i * 0.25 s: [T0 + 0.5 s, T0 + 1.25 s) holds seq 2, 3, 4
    t0, t1 = T0_NS + 500_000_000, T0_NS + 1_250_000_000
    assert seqs(client, pass_id, f"t0={t0}&t1={t1}") == [2, 3, 4]
    assert seqs(client, pass_id, f"t0={t0}&t1={t1}&stage=queued&kind=joints") == [2, 3, 4]
    assert seqs(client, pass_id, f"t0={t0}&stage=executed") == []


def kinds_and_actors(client: TestClient, query: str) -> list[tuple[str, str]]:
    response = client.get(f"/api/events?{query}", headers=VIEWER)
    assert response.status_code == 200, response.text
    return [(e["kind"], e["actor"]) for e in response.json()["data"]]


def test_events_by_kind_actor_and_time_range(client: TestClient, pass_id: str) -> None:
    scope = f"pass_id={pass_id}"
    assert len(kinds_and_actors(client, scope)) == 5
    assert kinds_and_actors(client, f"{scope}&kind=pass_state") == [
        ("pass_state", "runner"),
        ("pass_state", "otto"),
    ]
    assert kinds_and_actors(client, f"{scope}&actor=link&kind=command_stage") == [
        ("command_stage", "link"),
        ("command_stage", "link"),
    ]
    assert kinds_and_actors(client, f"{scope}&actor=otto&actor=runner") == [
        ("pass_state", "runner"),
        ("pass_state", "otto"),
    ]
    # stamped 1000, 2000, ... 5000 ns: [2000, 4000) holds the second and the third
    assert kinds_and_actors(client, f"{scope}&t0=2000&t1=4000") == [
        ("command_stage", "link"),
        ("pass_state", "otto"),
    ]
    assert kinds_and_actors(client, f"{scope}&t0=5000") == [("link_hello", "link")]
    assert kinds_and_actors(client, f"{scope}&kind=no_such_kind") == []


@pytest.mark.parametrize(
    ("path", "status", "code"),
    [
        ("/api/events?t0=5&t1=5", 422, "empty_range"),
        ("/api/events?t0=-1", 422, "invalid_request"),
        ("/api/events?kind=Pass-State", 422, "invalid_request"),
        ("/api/events?actor=", 422, "invalid_request"),
        ("/api/events?actor=a%00b", 400, "invalid_text"),
        ("/api/passes/{id}/commands?kind=thrusters", 422, "invalid_request"),
        ("/api/passes/{id}/commands?t0=9&t1=3", 422, "empty_range"),
        ("/api/passes/{id}/commands?t1=x", 422, "invalid_request"),
    ],
)
def test_bad_searches_are_4xx_with_the_reason(
    client: TestClient, pass_id: str, path: str, status: int, code: str
) -> None:
    response = client.get(path.replace("{id}", pass_id), headers=VIEWER)
    assert response.status_code == status, response.text
    assert response.json()["error"]["code"] == code
