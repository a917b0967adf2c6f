"""Telemetry storage: ingest of a 20-minute pass against the raw driver, and decimation.

The pass: 12 000 frames (10 Hz for 1200 s), every value of each frame in its own column
(38 values a frame: the 34 measured numbers, seq, generation and reception times, pass id).
On each backend, in the same run and the same database:

- raw: the driver's own bulk insert of the same rows, prebuilt as tuples, into a plain
  table (same columns, no key, no index, no foreign key): ``sqlite3`` ``executemany`` /
  psycopg binary ``COPY`` (what the storage uses too); one transaction.
- ingest, bulk: ``repository.ingest_frames`` with all 12 000 frames, one transaction
  (frame -> row conversion, keys, indexes, foreign key and dedupe included).
- ingest, live: the same frames 50 per call, one transaction per call, as they arrive.
- re-ingest: the bulk call again (every frame a duplicate).
- queries on the stored pass, each in its own session like a request: the decimated view
  (500 buckets x 6 fields, min/max/mean), the raw rows of 6 fields, the gap search.

PostgreSQL: the server of ``DATABASE_URL`` (when it names one) or
``postgresql://postgres@127.0.0.1:5432/test``, in a scratch schema dropped at the end;
skipped (and said so) when none answers.

Targets (ground-server issue): bulk ingest >= 0.5x the raw insert on each backend;
>= 1 million values per second on PostgreSQL; the decimated 20-minute query < 30 ms.
"""

from __future__ import annotations

import os
import tempfile
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import psycopg
from _common import best_of, emit
from sqlalchemy import URL, Engine, make_url
from sqlalchemy.orm import Session, sessionmaker

from server.storage import repository as repo
from server.storage._telemetry import statements
from server.storage.db import make_engine, session_factory, sqlite_url, upgrade
from server.storage.models import PlanRecord
from telemetry.layout import DEFAULT_LAYOUT
from telemetry.wire import TelemetryFrame

N_FRAMES = 12_000  # 20 min at 10 Hz
LIVE_BATCH = 50
#: ETS-VII's frames, as the storage inserts them (its layout's columns, after the pass id).
_SQL = statements(DEFAULT_LAYOUT)
_COLUMNS = _SQL.columns
_PG_TYPES = _SQL.pg_types
VALUES_PER_FRAME = len(_COLUMNS)
T0_NS = 1_000_000_000_000
PERIOD_NS = 100_000_000
BUCKET_FIELDS = ["j1", "j2", "j3", "wx", "wy", "wz"]
REPEAT = 5
DEFAULT_POSTGRES_URL = "postgresql+psycopg://postgres@127.0.0.1:5432/test"


def make_frames(n: int) -> list[TelemetryFrame]:
    """ETS-VII frames of random values (rows of its layout read as wire frames)."""
    rng = np.random.default_rng(0)
    values = rng.normal(size=(n, len(DEFAULT_LAYOUT.float_fields))).tolist()
    return [
        DEFAULT_LAYOUT.frame(
            (i, T0_NS + i * PERIOD_NS, *v, "feedback", False, i % 9, T0_NS + i, i, 0)
        )
        for i, v in enumerate(values)
    ]


def _rows(pass_key: object, frames: list[TelemetryFrame], rx: int) -> list[tuple[Any, ...]]:
    return [(pass_key, *DEFAULT_LAYOUT.row(frame, rx)) for frame in frames]


def best_with_setup(setup: Callable[[], None], run: Callable[[], None]) -> float:
    """Like ``best_of``, timing ``run`` only (``setup`` before each run is not counted)."""
    best = float("inf")
    for _ in range(REPEAT):
        setup()
        start = time.perf_counter()
        run()
        best = min(best, time.perf_counter() - start)
    return best


def new_pass(
    factory: sessionmaker[Session], *, duration_s: float = 1200.0, name: str = "bench"
) -> str:
    """A pass (of a bare plan of ``duration_s``, no commands) to write frames into."""
    with factory() as session:
        plan = PlanRecord(
            id=str(uuid.uuid4()),
            experiment="bench",
            parameters={},
            document="{}",
            duration_s=duration_s,
            n_commands=0,
            created_at_ns=0,
        )
        session.add(plan)
        session.flush()
        record = repo.add_pass(
            session=session,
            name=name,
            plan_id=plan.id,
            aos_time_ns=0,
            los_time_ns=1,
            relay="TDRS",
            created_at_ns=0,
        )
        session.commit()
        return record.id


def raw_insert_s(
    engine: Engine,
    make_rows: Callable[[], list[tuple[Any, ...]]],
    *,
    table: str = "raw_frames",
    binary: bool = True,
) -> float:
    """The driver's own bulk insert of prebuilt rows, best of REPEAT (setup not timed).

    ``raw_frames`` is made afresh before each run: telemetry_frames' columns and types, no
    key, index or foreign key. Into ``telemetry_frames`` itself, ``make_rows`` must give
    rows of a new pass each time (a plain INSERT / COPY does not skip duplicates).
    PostgreSQL: ``COPY`` binary, or text (psycopg's default) when not ``binary``.
    """
    columns = ", ".join(_COLUMNS)
    is_pg = engine.dialect.name == "postgresql"
    create = (
        "CREATE TABLE raw_frames (LIKE telemetry_frames)"
        if is_pg
        else "CREATE TABLE raw_frames AS SELECT * FROM telemetry_frames WHERE 0"
    )
    copy_sql = f"COPY {table} ({columns}) FROM STDIN" + (" (FORMAT BINARY)" if binary else "")
    insert_sql = f"INSERT INTO {table} ({columns}) VALUES ({', '.join('?' * len(_COLUMNS))})"
    raw = engine.raw_connection()
    rows: list[tuple[Any, ...]] = []
    try:
        dbapi: Any = raw.driver_connection

        def setup() -> None:
            rows[:] = make_rows()
            if table != "raw_frames":
                return
            cursor = dbapi.cursor()
            if not is_pg:
                cursor.execute("BEGIN")
            cursor.execute("DROP TABLE IF EXISTS raw_frames")
            cursor.execute(create)
            dbapi.commit()

        def run_sqlite() -> None:
            cursor = dbapi.cursor()
            cursor.execute("BEGIN")
            cursor.executemany(insert_sql, rows)
            dbapi.commit()

        def run_pg() -> None:
            with dbapi.cursor() as cursor, cursor.copy(copy_sql) as copy:
                if binary:
                    copy.set_types(_PG_TYPES)
                for row in rows:
                    copy.write_row(row)
            dbapi.commit()

        seconds = best_with_setup(setup, run_pg if is_pg else run_sqlite)
        if table == "raw_frames":
            cursor = dbapi.cursor()
            if not is_pg:
                cursor.execute("BEGIN")
            cursor.execute("DROP TABLE raw_frames")
            dbapi.commit()
    finally:
        raw.close()
    return seconds


def bench_backend(engine: Engine, frames: list[TelemetryFrame]) -> dict[str, Any]:
    upgrade(engine)
    factory = session_factory(engine)
    n_values = len(frames) * VALUES_PER_FRAME

    is_pg = engine.dialect.name == "postgresql"

    def rows_of_new_pass() -> list[tuple[Any, ...]]:
        # As the storage writes them: the pass id in the backend's form.
        pass_id = uuid.UUID(new_pass(factory))
        return list(_rows(pass_id if is_pg else pass_id.hex, frames, 1))

    same_rows = rows_of_new_pass()
    raw_s = raw_insert_s(engine, lambda: same_rows)
    raw_keyed_s = raw_insert_s(engine, rows_of_new_pass, table="telemetry_frames")
    raw_text_s = raw_insert_s(engine, lambda: same_rows, binary=False) if is_pg else None

    pass_ids: list[str] = []

    def fresh_pass() -> None:
        pass_ids.append(new_pass(factory))

    def bulk() -> None:
        with factory() as session:
            result = repo.ingest_frames(
                session=session, pass_id=pass_ids[-1], frames=frames, reception_time_ns=1
            )
            session.commit()
        assert result.inserted == len(frames), result

    def live() -> None:
        for start in range(0, len(frames), LIVE_BATCH):
            with factory() as session:
                repo.ingest_frames(
                    session=session,
                    pass_id=pass_ids[-1],
                    frames=frames[start : start + LIVE_BATCH],
                    reception_time_ns=1,
                )
                session.commit()

    bulk_s = best_with_setup(fresh_pass, bulk)
    live_s = best_with_setup(fresh_pass, live)
    stored_pass = pass_ids[0]

    def reingest() -> None:
        with factory() as session:
            result = repo.ingest_frames(
                session=session, pass_id=stored_pass, frames=frames, reception_time_ns=2
            )
            session.commit()
        assert result.duplicates == len(frames), result

    reingest_s = best_of(reingest, repeat=REPEAT)

    t1_ns = T0_NS + len(frames) * PERIOD_NS

    def buckets() -> None:
        with factory() as session:
            out = repo.telemetry_buckets(
                session=session,
                pass_id=stored_pass,
                t0_ns=T0_NS,
                t1_ns=t1_ns,
                fields=BUCKET_FIELDS,
                buckets=500,
            )
        assert len(out) == 500

    def raw_range() -> None:
        with factory() as session:
            out = repo.telemetry_range(
                session=session, pass_id=stored_pass, t0_ns=T0_NS, t1_ns=t1_ns, fields=BUCKET_FIELDS
            )
        assert len(out) == len(frames)

    def gaps() -> None:
        with factory() as session:
            assert (
                repo.missing_seqs(session=session, pass_id=stored_pass, up_to_seq=len(frames) - 1)
                == []
            )

    buckets()  # warm the caches the way a console's repeated views would
    figures: dict[str, Any] = {
        "frames": len(frames),
        "values_per_frame": VALUES_PER_FRAME,
        "raw_insert_s": raw_s,
        "raw_values_per_s": n_values / raw_s,
    }
    if raw_text_s is not None:
        figures["raw_text_copy_s"] = raw_text_s
    figures |= {
        # The driver's insert into telemetry_frames itself: what its key, index and foreign
        # key cost, before any of the repository's work.
        "raw_into_keyed_table_s": raw_keyed_s,
        "ingest_bulk_s": bulk_s,
        "ingest_bulk_values_per_s": n_values / bulk_s,
        "ingest_bulk_vs_raw": raw_s / bulk_s,
        "ingest_live_s": live_s,
        "ingest_live_batch_frames": LIVE_BATCH,
        "ingest_live_values_per_s": n_values / live_s,
        "ingest_live_vs_raw": raw_s / live_s,
        "reingest_duplicates_s": reingest_s,
        "buckets_500x6_ms": 1e3 * best_of(buckets, repeat=20),
        "range_6_fields_ms": 1e3 * best_of(raw_range, repeat=5),
        "missing_seqs_ms": 1e3 * best_of(gaps, repeat=20),
    }
    if raw_text_s is not None:
        figures["ingest_bulk_vs_raw_text_copy"] = raw_text_s / bulk_s
    figures["ingest_bulk_vs_raw_into_keyed_table"] = raw_keyed_s / bulk_s
    return figures


def postgres_url() -> URL:
    url = os.environ.get("DATABASE_URL", "")
    return make_url(url if url.startswith("postgresql") else DEFAULT_POSTGRES_URL)


def bench_postgresql(frames: list[TelemetryFrame]) -> dict[str, Any]:
    url = postgres_url()
    conninfo = url.set(drivername="postgresql").render_as_string(hide_password=False)
    try:
        admin = psycopg.connect(conninfo, connect_timeout=3, autocommit=True)
    except psycopg.Error as exc:
        return {"skipped": f"no PostgreSQL server answers: {str(exc).strip()[:200]}"}
    schema = f"bench_{uuid.uuid4().hex[:16]}"
    with admin:
        admin.execute(f"CREATE SCHEMA {schema}")
        engine = make_engine(url.update_query_dict({"options": f"-csearch_path={schema}"}))
        try:
            figures = bench_backend(engine, frames)
            figures["server"] = str(admin.execute("SHOW server_version").fetchone()[0])  # type: ignore[index]
            return figures
        finally:
            engine.dispose()
            admin.execute(f"DROP SCHEMA {schema} CASCADE")


def main() -> None:
    frames = make_frames(N_FRAMES)
    with tempfile.TemporaryDirectory() as tmp:
        engine = make_engine(sqlite_url(Path(tmp)))
        try:
            sqlite = bench_backend(engine, frames)
        finally:
            engine.dispose()
    postgresql = bench_postgresql(frames)
    targets = {
        "sqlite_ingest_ge_0.5x_raw": sqlite["ingest_bulk_vs_raw"] >= 0.5,
        "sqlite_buckets_lt_30ms": sqlite["buckets_500x6_ms"] < 30.0,
    }
    if "skipped" not in postgresql:
        targets |= {
            "postgresql_ingest_ge_0.5x_raw": postgresql["ingest_bulk_vs_raw"] >= 0.5,
            "postgresql_ge_1M_values_per_s": postgresql["ingest_bulk_values_per_s"] >= 1e6,
            "postgresql_buckets_lt_30ms": postgresql["buckets_500x6_ms"] < 30.0,
        }
    emit("ingest", {"sqlite": sqlite, "postgresql": postgresql}, targets)


if __name__ == "__main__":
    main()
