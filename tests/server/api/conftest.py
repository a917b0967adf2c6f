"""An application per test on a fresh database, SQLite and PostgreSQL (see
``tests/server/conftest.py``), with a viewer and an operator token; one real plan."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy.orm import Session, sessionmaker

from planner.catalogue import parameters_from_values, plan_experiment
from planner.experiments import PtpParams
from planner.plan import Plan
from server.app import create_app
from server.settings import ApiToken, Role, Settings

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


def sessions(client: TestClient) -> sessionmaker[Session]:
    """The application's own session factory: to store and inspect rows directly."""
    factory: sessionmaker[Session] = client.app.state.sessions  # type: ignore[attr-defined]
    return factory


@pytest.fixture(scope="session")
def ptp_plan() -> Plan:
    """A real planner output, planned once for the run."""
    params = parameters_from_values(PtpParams, CHEAP_PTP["parameters"])
    return plan_experiment("ptp", params)
