"""The import spools' disk budget (``import_spool_budget_bytes``): imports in flight hold at
most that many bytes on disk together; one that would take them past it is refused with 503
``busy`` and ``Retry-After`` (before its first byte is read when it declares its length),
nothing is stored and no spool file is left; the budget is given back on every path. On
SQLite and PostgreSQL."""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy.orm import Session, sessionmaker

from server.app import create_app
from server.services.imports import SpoolBudget
from server.settings import Settings
from tests.server.link.harness import running_ground
from tests.support.api import OPERATOR, TOKENS
from tests.support.archive import row_counts


def _spools(client: TestClient) -> SpoolBudget:
    budget: SpoolBudget = client.app.state.import_spools  # type: ignore[attr-defined]
    return budget


def _rows(client: TestClient) -> dict[str, int]:
    factory: sessionmaker[Session] = client.app.state.sessions  # type: ignore[attr-defined]
    with factory() as session:
        return row_counts(session)


def _spool_files(data_dir: Path) -> list[Path]:
    jobs = data_dir / "jobs"
    return sorted(jobs.glob("*.mcap")) if jobs.exists() else []


@pytest.fixture()
def budget_client(database_url: str, tmp_path: Path, short_mcap: bytes) -> Iterator[TestClient]:
    """A server whose spools may hold one and a half short recordings together."""
    settings = Settings(
        data_dir=tmp_path,
        database_url=database_url,
        tokens=TOKENS,
        import_spool_budget_bytes=len(short_mcap) * 3 // 2,
    )
    with TestClient(create_app(settings)) as c:
        yield c


def test_a_declared_upload_past_the_budget_is_refused_unread(
    budget_client: TestClient, short_mcap: bytes, tmp_path: Path
) -> None:
    spools = _spools(budget_client)
    before = _rows(budget_client)
    with spools.hold() as other:  # another import in flight holds half the budget
        other.take(len(short_mcap) // 2 + 1)
        response = budget_client.post("/api/passes/import", content=short_mcap, headers=OPERATOR)
        assert response.status_code == 503, response.text
        error = response.json()["error"]
        assert error["code"] == "busy"
        assert "budget" in error["message"] and str(spools.budget_bytes) in error["message"]
        assert error["detail"]["upload_bytes"] == len(short_mcap)
        assert error["detail"]["held_bytes"] == len(short_mcap) // 2 + 1
        assert int(response.headers["retry-after"]) > 0
        assert spools.held_bytes == len(short_mcap) // 2 + 1  # the refused one holds nothing
    assert spools.held_bytes == 0 and spools.imports == 0
    assert _rows(budget_client) == before
    assert _spool_files(tmp_path) == []
    # With the other import done, the same upload fits, and gives its share back.
    ok = budget_client.post("/api/passes/import", content=short_mcap, headers=OPERATOR)
    assert ok.status_code == 201, ok.text
    assert spools.held_bytes == 0 and spools.imports == 0
    assert _spool_files(tmp_path) == []


def test_an_undeclared_upload_is_refused_when_it_reaches_the_budget(
    budget_client: TestClient, short_mcap: bytes, tmp_path: Path
) -> None:
    spools = _spools(budget_client)
    before = _rows(budget_client)
    step = 4096

    def chunks() -> Iterator[bytes]:  # no Content-Length: chunked transfer encoding
        for at in range(0, len(short_mcap), step):
            yield short_mcap[at : at + step]

    with spools.hold() as other:
        other.take(len(short_mcap) // 2 + 1)
        response = budget_client.post("/api/passes/import", content=chunks(), headers=OPERATOR)
        assert response.status_code == 503, response.text
        assert response.json()["error"]["code"] == "busy"
        assert "retry-after" in response.headers
        assert spools.held_bytes == len(short_mcap) // 2 + 1
    assert spools.held_bytes == 0 and spools.imports == 0
    assert _rows(budget_client) == before
    assert _spool_files(tmp_path) == []  # the partial spool is gone
    ok = budget_client.post("/api/passes/import", content=chunks(), headers=OPERATOR)
    assert ok.status_code == 201, ok.text
    assert spools.held_bytes == 0


def test_a_failed_import_gives_its_share_back(
    budget_client: TestClient, short_mcap: bytes, tmp_path: Path
) -> None:
    spools = _spools(budget_client)
    response = budget_client.post(
        "/api/passes/import", content=b"not an mcap file" * 100, headers=OPERATOR
    )
    assert response.status_code == 422, response.text
    assert spools.held_bytes == 0 and spools.imports == 0
    assert _spool_files(tmp_path) == []


async def _exchange(port: int, body: bytes, go: asyncio.Event) -> tuple[int, dict[str, Any], bool]:
    """A raw HTTP import: the head (declaring the length) at once, the body only once ``go``
    is set; the status, the JSON answer and whether the answer came before the body."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    head = (
        "POST /api/passes/import HTTP/1.1\r\nHost: 127.0.0.1\r\n"
        f"Authorization: {OPERATOR['Authorization']}\r\n"
        "Content-Type: application/octet-stream\r\n"
        f"Content-Length: {len(body)}\r\nConnection: close\r\n\r\n"
    )
    writer.write(head.encode())
    await writer.drain()
    answer = asyncio.ensure_future(reader.read())  # to EOF: Connection: close
    started = asyncio.ensure_future(go.wait())
    await asyncio.wait({answer, started}, return_when=asyncio.FIRST_COMPLETED)
    early = answer.done()
    if not early:
        writer.write(body)
        await writer.drain()
    raw = await asyncio.wait_for(answer, 120.0)  # a guard, not a timing assertion
    started.cancel()
    writer.close()
    status_line, _, rest = raw.partition(b"\r\n")
    payload = rest.partition(b"\r\n\r\n")[2]
    return int(status_line.split()[1]), json.loads(payload), early


@pytest.mark.slow
def test_four_concurrent_imports_fit_in_the_budget_or_are_refused(
    database_url: str, tmp_path: Path, short_mcap: bytes
) -> None:
    """The issue's case, scaled down: four uploads at once against a budget of two; two are
    admitted and stored, two refused before they send a byte of their bodies."""

    async def run(port: int, spools: SpoolBudget) -> list[tuple[int, dict[str, Any], bool]]:
        go = asyncio.Event()
        tasks = [asyncio.ensure_future(_exchange(port, short_mcap, go)) for _ in range(4)]
        deadline = time.monotonic() + 30.0  # a guard, not a timing assertion
        while sum(t.done() for t in tasks) < 2:
            assert time.monotonic() < deadline, "no refusals"
            await asyncio.sleep(0.02)
        assert spools.held_bytes == 2 * len(short_mcap) and spools.imports == 2
        go.set()
        return list(await asyncio.gather(*tasks))

    with running_ground(
        database_url, data_dir=tmp_path, import_spool_budget_bytes=2 * len(short_mcap)
    ) as ground:
        spools: SpoolBudget = ground.app.state.import_spools
        port = int(ground.url.rsplit(":", 1)[1])
        answers = asyncio.run(run(port, spools))
        held_after = (spools.held_bytes, spools.imports)
        with ground.readers() as session:
            passes = row_counts(session)["passes"]
    refused = [a for a in answers if a[0] == 503]
    stored = [a for a in answers if a[0] == 201]
    assert len(refused) == 2 and len(stored) == 2, [a[:2] for a in answers]
    assert all(early and body["error"]["code"] == "busy" for _, body, early in refused)
    assert not any(early for *_, early in stored)
    assert held_after == (0, 0)
    assert passes == 2
    assert _spool_files(tmp_path) == []
