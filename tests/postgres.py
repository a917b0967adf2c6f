"""The tests' PostgreSQL, for every test directory (a pytest plugin of the root conftest):
the server of ``DATABASE_URL`` (when it names PostgreSQL) or
``postgresql://postgres@127.0.0.1:5432/test`` (trust auth), and a fresh schema per test
(``postgres_schema_url``) or per module, selected with ``search_path`` and dropped
afterwards. With no server answering, the tests that need it are skipped with the reason."""

from __future__ import annotations

import contextlib
import os
import uuid
from collections.abc import Iterator

import psycopg
import pytest
from sqlalchemy import URL, make_url

DEFAULT_POSTGRES_URL = "postgresql+psycopg://postgres@127.0.0.1:5432/test"


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


@contextlib.contextmanager
def own_schema(server: URL, prefix: str = "test") -> Iterator[str]:
    """A URL of ``server`` whose connections see only a fresh, empty schema of their own
    (named ``prefix`` and random hex digits), dropped after (the tests' and a benchmark's)."""
    schema = f"{prefix}_{uuid.uuid4().hex[:16]}"
    conninfo = libpq_conninfo(server)
    with psycopg.connect(conninfo, autocommit=True) as conn:
        conn.execute(f"CREATE SCHEMA {schema}")  # a name we made: hex digits only
    try:
        url = server.update_query_dict({"options": f"-csearch_path={schema}"})
        yield url.render_as_string(hide_password=False)
    finally:
        with psycopg.connect(conninfo, autocommit=True) as conn:
            conn.execute(f"DROP SCHEMA {schema} CASCADE")


@pytest.fixture()
def postgres_schema_url(postgres_server: URL) -> Iterator[str]:
    """A URL whose connections see only a fresh, empty schema (dropped after the test)."""
    with own_schema(postgres_server) as url:
        yield url


@pytest.fixture(scope="module")
def module_postgres_schema_url(postgres_server: URL) -> Iterator[str]:
    """``postgres_schema_url`` for a whole module (dropped after its last test)."""
    with own_schema(postgres_server) as url:
        yield url
