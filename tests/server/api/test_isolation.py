"""The command path's own connections (#14): with every connection of the readers' pool
taken, a reader gets 503 ``busy`` after the pool's checkout timeout, and an operator's
control request (which goes through the link's database worker) is answered as usual."""

from __future__ import annotations

from pathlib import Path

from fastapi.testclient import TestClient
from sqlalchemy import Engine, text

from server.app import create_app
from server.settings import Settings
from server.storage.db import READ_ONLY_OPTION
from tests.support.api import OPERATOR, TOKENS, VIEWER, add_pass


def test_a_full_readers_pool_answers_busy_and_control_goes_on(
    database_url: str, tmp_path: Path
) -> None:
    settings = Settings(
        data_dir=tmp_path,
        database_url=database_url,
        tokens=TOKENS,
        api_pool_size=1,
        api_pool_overflow=0,
        api_pool_timeout_s=0.5,
    )
    with TestClient(create_app(settings)) as client:
        app = client.app
        pass_id = add_pass(client, "held")
        readers: Engine = app.state.engine  # type: ignore[attr-defined]
        # the readers' only connection, reading (on SQLite a plain BEGIN: no write lock)
        with readers.execution_options(**{READ_ONLY_OPTION: True}).connect() as held:
            held.execute(text("SELECT 1"))
            response = client.get("/api/passes", headers=VIEWER)
            assert response.status_code == 503, response.text
            assert response.json()["error"]["code"] == "busy"
            assert int(response.headers["retry-after"]) >= 1
            # the command path has connections of its own
            response = client.post(
                f"/api/passes/{pass_id}/abort",
                json={"confirm": "ABORT held", "reason": "pool test"},
                headers=OPERATOR,
            )
            assert response.status_code == 200, response.text
            assert response.json()["state"] == "aborted"
        assert client.get("/api/passes", headers=VIEWER).status_code == 200
