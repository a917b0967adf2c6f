"""Engines from URLs: which databases and drivers, and where the SQLite file goes."""

from __future__ import annotations

from pathlib import Path

import pytest
import sqlalchemy.exc
from sqlalchemy import text

from server.storage.db import (
    SQLITE_FILENAME,
    PoolSizes,
    make_engine,
    read_session_factory,
    session_factory,
    sqlite_url,
)
from server.storage.errors import InvalidArgument


def test_the_default_sqlite_file_lives_under_the_data_directory(tmp_path: Path) -> None:
    data_dir = tmp_path / "not" / "yet" / "there"
    engine = make_engine(sqlite_url(data_dir))
    try:
        with engine.connect() as conn:
            conn.exec_driver_sql("SELECT 1")
        assert (data_dir / SQLITE_FILENAME).is_file()
    finally:
        engine.dispose()


def test_postgresql_urls_use_psycopg_whatever_they_name() -> None:
    engine = make_engine("postgresql://postgres@127.0.0.1:1/test")  # no connection made
    try:
        assert engine.dialect.driver == "psycopg"
    finally:
        engine.dispose()
    with pytest.raises(InvalidArgument, match="'psycopg2'"):
        make_engine("postgresql+psycopg2://postgres@127.0.0.1/test")
    with pytest.raises(InvalidArgument, match="'mysql'"):
        make_engine("mysql://root@127.0.0.1/test")


def test_a_read_session_reads_while_a_writer_holds_the_sqlite_write_lock(tmp_path: Path) -> None:
    """The ground's database worker commits back to back at high time scales; a GET must not
    wait for its lock (it did, and a 60x demo got a 500 after the 10 s busy timeout)."""
    engine = make_engine(sqlite_url(tmp_path))
    try:
        with engine.begin() as conn:
            conn.execute(text("CREATE TABLE t (x INTEGER)"))
            conn.execute(text("INSERT INTO t VALUES (1)"))
        with session_factory(engine)() as writer:
            writer.execute(text("INSERT INTO t VALUES (2)"))  # BEGIN IMMEDIATE: lock held
            with read_session_factory(engine)() as reader:
                # the committed snapshot, at once (a locking BEGIN would wait 10 s and fail)
                assert reader.scalars(text("SELECT x FROM t")).all() == [1]
            writer.commit()
        with read_session_factory(engine)() as reader:
            assert reader.scalars(text("SELECT x FROM t ORDER BY x")).all() == [1, 2]
    finally:
        engine.dispose()


def test_a_readers_pool_on_postgresql_keeps_the_urls_options_and_ends_long_statements(
    postgres_schema_url: str,
) -> None:
    """The readers' pool sets a statement timeout beside the URL's own options (the
    schema's search_path here): a statement longer than it is ended by the server."""
    engine = make_engine(
        postgres_schema_url,
        pool=PoolSizes(size=1, overflow=0, timeout_s=1.0, statement_timeout_s=0.5),
    )
    try:
        with engine.connect() as connection:
            assert connection.exec_driver_sql("SHOW statement_timeout").scalar() == "500ms"
            search_path = str(connection.exec_driver_sql("SHOW search_path").scalar())
            assert search_path.startswith("test_")
            with pytest.raises(sqlalchemy.exc.OperationalError, match="statement timeout"):
                connection.exec_driver_sql("SELECT pg_sleep(5)")
    finally:
        engine.dispose()


def test_a_full_pool_refuses_a_checkout_after_its_timeout(tmp_path: Path) -> None:
    engine = make_engine(sqlite_url(tmp_path), pool=PoolSizes(size=1, overflow=0, timeout_s=0.2))
    try:
        with engine.connect(), pytest.raises(sqlalchemy.exc.TimeoutError):
            engine.connect()
    finally:
        engine.dispose()
