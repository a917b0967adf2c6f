"""``GET /api/ready``: 200 only when the database answers at the head migration, 503 with
the reason otherwise; public, like ``/api/health``, which stays liveness."""

from __future__ import annotations

import asyncio
import logging
import threading

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import text

from server.services.readiness import Readiness, ReadinessProbe
from server.storage.db import head_revisions
from tests.support.api import sessions

#: A PostgreSQL no one listens on: the connection is refused at once.
NOWHERE = "postgresql://hikoboshi@127.0.0.1:1/none"


def test_ready_at_the_head_migration_without_a_token(client: TestClient) -> None:
    response = client.get("/api/ready")
    assert response.status_code == 200, response.text
    assert response.json() == {
        "status": "ready",
        "migration": list(head_revisions()),
        "command": "holder",
    }
    # the one ground of its database commands the vehicle (a load balancer's probe)
    command = client.get("/api/command")
    assert command.status_code == 200, command.text
    assert command.json()["role"] == "holder" and command.json()["token"] >= 1


def test_a_schema_behind_the_head_is_not_ready(client: TestClient) -> None:
    head = head_revisions()
    with sessions(client)() as session:
        older = session.execute(text("SELECT version_num FROM alembic_version")).scalar_one()
        assert (older,) == head
        session.execute(text("UPDATE alembic_version SET version_num = '0005'"))
        session.commit()
    response = client.get("/api/ready")
    assert response.status_code == 503
    assert response.headers["Retry-After"] == "5"
    error = response.json()["error"]
    assert error["code"] == "schema_not_at_head"
    assert error["detail"] == {"current": ["0005"], "head": list(head)}
    assert "0005" in error["message"]
    assert client.get("/api/health").json()["status"] == "ok"  # liveness is not readiness


def test_a_database_that_does_not_answer_is_not_ready(
    client: TestClient, caplog: pytest.LogCaptureFixture
) -> None:
    app = client.app
    own = app.state.readiness  # type: ignore[attr-defined]
    app.state.readiness = ReadinessProbe(NOWHERE)  # type: ignore[attr-defined]
    try:
        with caplog.at_level(logging.WARNING, logger="hikoboshi.ground.readiness"):
            first = client.get("/api/ready")
            second = client.get("/api/ready")
    finally:
        app.state.readiness.close()  # type: ignore[attr-defined]
        app.state.readiness = own  # type: ignore[attr-defined]
    for response in (first, second):
        assert response.status_code == 503
        error = response.json()["error"]
        assert error["code"] == "database_unavailable"
        assert error["message"] == "the database does not answer"
        assert "127.0.0.1" not in response.text  # the error's text stays in the log
    warned = [r for r in caplog.records if r.name == "hikoboshi.ground.readiness"]
    assert len(warned) == 1 and "127.0.0.1" in warned[0].getMessage()  # once, not per probe
    assert client.get("/api/health").status_code == 200


def test_a_hung_database_answers_within_the_timeout_and_holds_one_thread(
    monkeypatch: pytest.MonkeyPatch, tmp_path: object
) -> None:
    probe = ReadinessProbe("sqlite://", timeout_s=0.2)
    release = threading.Event()
    asked: list[int] = []

    def hangs() -> Readiness:
        asked.append(1)
        release.wait(60.0)  # a guard, not a timing assertion
        return Readiness(True, "ready", "ready", {"migration": ["x"]})

    monkeypatch.setattr(probe, "check_now", hangs)

    async def three_probes() -> list[Readiness]:
        return list(await asyncio.gather(probe.check(), probe.check(), probe.check()))

    try:
        answers = asyncio.run(three_probes())
        assert [a.code for a in answers] == ["database_timeout"] * 3
        assert "did not answer within 0.2 s" in answers[0].message
        assert len(asked) == 1  # the probes shared the one question in flight
    finally:
        release.set()
        probe.close()
