"""An application per test on a fresh database, SQLite and PostgreSQL (see
``tests/server/conftest.py``), with a viewer and an operator token; one real plan.
``module_client``: one application per module and backend, for tests that share what they read."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy.orm import Session, sessionmaker
from starlette.types import ASGIApp, Receive, Scope, Send

from planner.catalogue import parameters_from_values, plan_experiment
from planner.experiments import PtpParams
from planner.plan import Plan
from server.app import create_app
from server.settings import ApiToken, Role, Settings
from server.storage import repository as repo
from tests.server.storage.factories import make_plan

TOKENS = {
    "v-token": ApiToken(name="vera", role=Role.VIEWER),
    "o-token": ApiToken(name="otto", role=Role.OPERATOR),
    "s-token": ApiToken(name="ets7", role=Role.SPACECRAFT),
}
VIEWER = {"Authorization": "Bearer v-token"}
OPERATOR = {"Authorization": "Bearer o-token"}
#: The cheapest real plan: PTP A -> B with a quarter-second settle (about 0.6 s to plan).
CHEAP_PTP: dict[str, Any] = {"experiment": "ptp", "parameters": {"settle_s": 0.25}}


@pytest.fixture()
def client(database_url: str, tmp_path: Path) -> Iterator[TestClient]:
    settings = Settings(data_dir=tmp_path, database_url=database_url, tokens=TOKENS)
    with TestClient(create_app(settings)) as c:
        yield c


@pytest.fixture(scope="module")
def module_client(
    module_database_url: str, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[TestClient]:
    data_dir = tmp_path_factory.mktemp("module_app")
    settings = Settings(data_dir=data_dir, database_url=module_database_url, tokens=TOKENS)
    with TestClient(create_app(settings)) as c:
        yield c


def sessions(client: TestClient) -> sessionmaker[Session]:
    """The application's own session factory: to store and inspect rows directly."""
    factory: sessionmaker[Session] = client.app.state.sessions  # type: ignore[attr-defined]
    return factory


@pytest.fixture(scope="session")
def ptp_plan() -> Plan:
    """A real planner output, planned once for the run."""
    params = parameters_from_values(PtpParams, CHEAP_PTP["parameters"])
    return plan_experiment("ptp", params)


def add_pass(client: TestClient, name: str) -> str:
    """A scheduled pass of a small plan (stored directly), from now for 1000 s; its id."""
    with sessions(client)() as session:
        plan = repo.add_plan(session=session, plan=make_plan(), created_at_ns=0)
        record = repo.add_pass(
            session=session,
            name=name,
            plan_id=plan.id,
            aos_time_ns=time.time_ns(),
            los_time_ns=time.time_ns() + 10**12,
            relay="TDRS-W",
            created_at_ns=0,
        )
        session.commit()
        return str(record.id)


class ClientAddress:
    """Puts the ``x-test-client`` header's address (else ``default``) in the scope as the
    client's: the test client has one address, the edge counts by address."""

    def __init__(self, app: ASGIApp, default: str) -> None:
        self.app = app
        self.default = default

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] in ("http", "websocket"):
            headers = dict(scope["headers"])
            address = headers.get(b"x-test-client", self.default.encode()).decode()
            scope = {**scope, "client": (address, 5555)}
        await self.app(scope, receive, send)
