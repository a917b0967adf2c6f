"""What ``bench/bench_soak.py`` reads between passes: a process's resident memory, threads
and open descriptors (``/proc``), and the database's size and a frame row's size, on SQLite
(the file with its WAL, ``dbstat``) or on a fresh PostgreSQL schema of its own
(``pg_total_relation_size``, ``pg_column_size``; dropped on close)."""

from __future__ import annotations

import os
import sqlite3
import uuid
from pathlib import Path

__all__ = ["PostgresSize", "SqliteSize", "process_figures"]

DEFAULT_POSTGRES_URL = "postgresql+psycopg://postgres@127.0.0.1:5432/test"
SQLITE_FILENAME = "hikoboshi.sqlite3"


def process_figures(pid: int) -> tuple[int, int, int]:
    """A process's resident memory (bytes), threads and open file descriptors."""
    rss = 0
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            rss = int(line.split()[1]) * 1024
    threads = len(os.listdir(f"/proc/{pid}/task"))
    fds = len(os.listdir(f"/proc/{pid}/fd"))
    return rss, threads, fds


class SqliteSize:
    """The SQLite file's size with its WAL, and a frame record's size (``dbstat``)."""

    def __init__(self, data_dir: Path) -> None:
        self.path = data_dir / SQLITE_FILENAME

    def database_url(self) -> str | None:
        return None  # the server's default: SQLite under its data directory

    def db_bytes(self) -> int:
        wal = self.path.with_name(self.path.name + "-wal")
        return self.path.stat().st_size + (wal.stat().st_size if wal.exists() else 0)

    def frame_row_bytes(self) -> float:
        with sqlite3.connect(f"file:{self.path}?mode=ro", uri=True, timeout=30.0) as conn:
            (payload,) = conn.execute(
                "SELECT coalesce(sum(payload), 0) FROM dbstat WHERE name = 'telemetry_frames'"
            ).fetchone()
            (rows,) = conn.execute("SELECT count(*) FROM telemetry_frames").fetchone()
        conn.close()
        return float(payload) / rows if rows else 0.0

    def close(self) -> None:
        pass


class PostgresSize:
    """A fresh schema on the PostgreSQL server (dropped on close); its tables' total size and
    a frame row's size (``pg_column_size``)."""

    def __init__(self) -> None:
        import psycopg
        from sqlalchemy import make_url

        url = os.environ.get("DATABASE_URL", "")
        self.url = make_url(url if url.startswith("postgresql") else DEFAULT_POSTGRES_URL)
        self.schema = f"soak_{uuid.uuid4().hex[:16]}"
        conninfo = self.url.set(drivername="postgresql").render_as_string(hide_password=False)
        self.conn = psycopg.connect(conninfo, autocommit=True)
        self.conn.execute(f"CREATE SCHEMA {self.schema}")  # hex digits only: ours

    def database_url(self) -> str:
        url = self.url.update_query_dict({"options": f"-csearch_path={self.schema}"})
        return url.render_as_string(hide_password=False)

    def db_bytes(self) -> int:
        row = self.conn.execute(
            "SELECT coalesce(sum(pg_total_relation_size(c.oid)), 0) FROM pg_class c"
            " JOIN pg_namespace n ON n.oid = c.relnamespace"
            " WHERE n.nspname = %s AND c.relkind = 'r'",
            (self.schema,),
        ).fetchone()
        return int(row[0]) if row else 0

    def frame_row_bytes(self) -> float:
        row = self.conn.execute(
            f"SELECT avg(pg_column_size(t.*)) FROM {self.schema}.telemetry_frames t"
        ).fetchone()
        return float(row[0]) if row and row[0] is not None else 0.0

    def close(self) -> None:
        self.conn.execute(f"DROP SCHEMA {self.schema} CASCADE")
        self.conn.close()
