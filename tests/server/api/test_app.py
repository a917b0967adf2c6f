"""The application skeleton: lifespan, error shape, authentication and roles."""

from __future__ import annotations

import threading
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import get_args

import pytest
from fastapi.testclient import TestClient

from planner.description import default_robot
from server.api.deps import OperatorDep, ViewerDep
from server.app import create_app
from server.schemas import CommandStage, PassState
from server.services.robots import robot_urdf
from server.settings import ApiToken, Role, Settings
from server.storage.models import COMMAND_STAGES, PASS_STATES

TOKENS = {
    "v-token": ApiToken(name="vera", role=Role.VIEWER),
    "o-token": ApiToken(name="otto", role=Role.OPERATOR),
    "s-token": ApiToken(name="ets7", role=Role.SPACECRAFT),
}


@pytest.fixture()
def client(tmp_path: Path) -> TestClient:
    app = create_app(Settings(data_dir=tmp_path, tokens=TOKENS))

    @app.get("/api/_probe/operator")
    def operator_only(who: OperatorDep) -> dict[str, str]:
        return {"name": who.name}

    @app.get("/api/_probe/viewer")
    def viewer_ok(who: ViewerDep) -> dict[str, str]:
        return {"name": who.name}

    with TestClient(app) as c:
        yield c  # type: ignore[misc]


def test_lifespan_opens_a_migrated_sqlite_database(client: TestClient, tmp_path: Path) -> None:
    assert client.get("/api/health").json() == {"status": "ok", "command": "holder"}
    assert (tmp_path / "hikoboshi.sqlite3").exists()


def test_unknown_routes_use_the_one_error_shape(client: TestClient) -> None:
    body = client.get("/api/nothing-here").json()
    assert body["error"]["code"] == "not_found"


@pytest.mark.parametrize(
    ("path", "token", "status", "code"),
    [
        ("/api/_probe/viewer", None, 401, "unauthorized"),
        ("/api/_probe/viewer", "wrong", 401, "unauthorized"),
        ("/api/_probe/viewer", "v-token", 200, None),
        ("/api/_probe/viewer", "o-token", 200, None),
        ("/api/_probe/viewer", "s-token", 403, "forbidden"),
        ("/api/_probe/operator", "v-token", 403, "forbidden"),
        ("/api/_probe/operator", "o-token", 200, None),
    ],
)
def test_tokens_and_roles(
    client: TestClient, path: str, token: str | None, status: int, code: str | None
) -> None:
    headers = {"Authorization": f"Bearer {token}"} if token else {}
    response = client.get(path, headers=headers)
    assert response.status_code == status
    if code is not None:
        assert response.json()["error"]["code"] == code


def test_the_model_urdf_is_the_planner_s_and_needs_a_token(client: TestClient) -> None:
    assert client.get("/api/model/urdf").status_code == 401
    response = client.get("/api/model/urdf", headers={"Authorization": "Bearer v-token"})
    assert response.status_code == 200
    assert response.headers["content-type"].startswith("application/xml")
    assert response.text == robot_urdf(default_robot())
    links = {link.get("name") for link in ET.fromstring(response.text).iter("link")}
    assert {"base_link", "link1", "link6", "target_satellite"} <= links


def test_the_api_s_stage_and_state_names_are_the_archive_s() -> None:
    """The schemas' literal types name the command stages and pass states storage defines
    (mypy needs them written out; this holds the two spellings to one list)."""
    assert get_args(CommandStage) == COMMAND_STAGES
    assert get_args(PassState) == PASS_STATES


def _pool_threads() -> set[threading.Thread]:
    """The database worker's threads and the event loops' default executors' threads."""
    return {
        t for t in threading.enumerate() if t.name == "ground-db" or t.name.startswith("asyncio_")
    }


def test_the_lifespan_leaves_no_thread_and_no_connection_behind(
    database_url: str, tmp_path: Path
) -> None:
    """Once the lifespan has exited: the database worker's thread is joined, the loop's
    executor threads are gone and neither engine holds a connection (dozens of idle
    ``ground-db`` threads outlived their tests before the fixtures closed what they
    opened)."""
    before = _pool_threads()
    app = create_app(Settings(data_dir=tmp_path, database_url=database_url, tokens=TOKENS))
    with TestClient(app) as client:
        # the readers' pool, a route in a worker thread, the link's database worker
        assert client.get("/api/passes", headers={"Authorization": "Bearer v-token"}).is_success
        engines = (app.state.engine, app.state.link_engine)
        assert [t.name for t in _pool_threads() - before].count("ground-db") == 1
        assert all(engine.pool.checkedin() >= 1 for engine in engines)
    assert _pool_threads() - before == set()  # at once: joined, not left to end
    for engine in engines:
        assert engine.pool.checkedin() == 0 and engine.pool.checkedout() == 0
