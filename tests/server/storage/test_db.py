"""Engines from URLs: which databases and drivers, and where the SQLite file goes."""

from __future__ import annotations

from pathlib import Path

import pytest

from server.storage.db import SQLITE_FILENAME, make_engine, sqlite_url
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
