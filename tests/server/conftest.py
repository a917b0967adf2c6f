"""Database fixtures: every test gets a fresh database, on SQLite and on PostgreSQL.

SQLite: a file in ``tmp_path``. PostgreSQL: a new schema per test on the server of
``DATABASE_URL`` (when it names PostgreSQL) or of ``postgresql://postgres@127.0.0.1:5432/test``
(trust auth), selected with ``search_path`` and dropped afterwards. With no server
answering, the PostgreSQL variants are skipped with the reason.

``module_database_url``: one fresh database per module and backend, for modules whose tests
only read what they share (a file in a module's temporary directory; a schema dropped after
the module's last test).
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterator
from pathlib import Path

import psycopg
import pytest
from sqlalchemy import URL, Engine, make_url
from sqlalchemy.orm import Session

from server.storage.db import make_engine, session_factory, sqlite_url, upgrade

DEFAULT_POSTGRES_URL = "postgresql+psycopg://postgres@127.0.0.1:5432/test"
BACKENDS = ("sqlite", "postgresql")


def postgres_url() -> URL:
    """The PostgreSQL server the tests (and the benchmark) use."""
    url = os.environ.get("DATABASE_URL", "")
    return make_url(url if url.startswith("postgresql") else DEFAULT_POSTGRES_URL)


def libpq_conninfo(url: URL) -> str:
    return url.set(drivername="postgresql").render_as_string(hide_password=False)


@pytest.fixture(scope="session")
def postgres_server() -> URL:
    """The server's URL, or skip: probed once per run."""
    url = postgres_url()
    try:
        with psycopg.connect(libpq_conninfo(url), connect_timeout=3) as conn:
            conn.execute("SELECT 1")
    except psycopg.Error as exc:
        where = url.render_as_string(hide_password=True)
        pytest.skip(f"no PostgreSQL server answers at {where}: {str(exc).strip()[:200]}")
    return url


def _schema_url(postgres_server: URL) -> Iterator[str]:
    schema = f"test_{uuid.uuid4().hex[:16]}"
    conninfo = libpq_conninfo(postgres_server)
    with psycopg.connect(conninfo, autocommit=True) as conn:
        conn.execute(f"CREATE SCHEMA {schema}")  # a name we made: hex digits only
    try:
        url = postgres_server.update_query_dict({"options": f"-csearch_path={schema}"})
        yield url.render_as_string(hide_password=False)
    finally:
        with psycopg.connect(conninfo, autocommit=True) as conn:
            conn.execute(f"DROP SCHEMA {schema} CASCADE")


@pytest.fixture()
def postgres_schema_url(postgres_server: URL) -> Iterator[str]:
    """A URL whose connections see only a fresh, empty schema (dropped after the test)."""
    yield from _schema_url(postgres_server)


@pytest.fixture(scope="module")
def module_postgres_schema_url(postgres_server: URL) -> Iterator[str]:
    """``postgres_schema_url`` for a whole module (dropped after its last test)."""
    yield from _schema_url(postgres_server)


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
