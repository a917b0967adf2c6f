"""Database fixtures: every test gets a fresh database, on SQLite and on PostgreSQL.

SQLite: a file in ``tmp_path``. PostgreSQL: a new schema per test on the server of
``DATABASE_URL`` (when it names PostgreSQL) or of ``postgresql://postgres@127.0.0.1:5432/test``
(trust auth), selected with ``search_path`` and dropped afterwards. With no server
answering, the PostgreSQL variants are skipped with the reason.

``module_database_url``: one fresh database per module and backend, for modules whose tests
only read what they share (a file in a module's temporary directory; a schema dropped after
the module's last test).

``client``: an application per test on a fresh database of each backend, with a viewer's,
an operator's and a spacecraft's token (tests/support/api.py); ``module_client``: one
application per module and backend, for tests that share what they read; ``ptp_plan``: one
real plan, planned once for the run.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine
from sqlalchemy.orm import Session

from planner.catalogue import parameters_from_values, plan_experiment
from planner.experiments import PtpParams
from planner.plan import Plan
from server.app import create_app
from server.settings import Settings
from server.storage.db import make_engine, session_factory, sqlite_url, upgrade
from telemetry.recording import PassRecording
from tests.support.api import CHEAP_PTP, TOKENS
from tests.support.recordings import mcap_bytes, short_recording_of

BACKENDS = ("sqlite", "postgresql")


@pytest.fixture(params=BACKENDS)
def empty_engine(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Engine]:
    """An engine on a fresh, empty database (no migrations run)."""
    if request.param == "sqlite":
        url = sqlite_url(tmp_path)
    else:
        url = request.getfixturevalue("postgres_schema_url")
    engine = make_engine(url)
    try:
        yield engine
    finally:
        engine.dispose()


@pytest.fixture()
def engine(empty_engine: Engine) -> Engine:
    """An engine on a fresh database migrated to head."""
    upgrade(empty_engine)
    return empty_engine


@pytest.fixture()
def session(engine: Engine) -> Iterator[Session]:
    with session_factory(engine)() as session:
        yield session


@pytest.fixture(params=BACKENDS)
def database_url(request: pytest.FixtureRequest, tmp_path: Path) -> str:
    """A fresh database's URL, on each backend (PostgreSQL skipped when none answers)."""
    if request.param == "sqlite":
        return sqlite_url(tmp_path)
    url: str = request.getfixturevalue("postgres_schema_url")
    return url


@pytest.fixture(scope="module", params=BACKENDS)
def module_database_url(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> str:
    """``database_url`` shared by a module's tests, on each backend."""
    if request.param == "sqlite":
        return sqlite_url(tmp_path_factory.mktemp("module_db"))
    url: str = request.getfixturevalue("module_postgres_schema_url")
    return url


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


@pytest.fixture(scope="session")
def ptp_plan() -> Plan:
    """A real planner output, planned once for the run."""
    params = parameters_from_values(PtpParams, CHEAP_PTP["parameters"])
    return plan_experiment("ptp", params)


@pytest.fixture(scope="session")
def short_recording(ptp_plan: Plan) -> PassRecording:
    """The short recording (tests/support/recordings.py), made once for the run."""
    return short_recording_of(ptp_plan)


@pytest.fixture(scope="session")
def short_mcap(short_recording: PassRecording) -> bytes:
    return mcap_bytes(short_recording)
