"""Telemetry frames: idempotent bulk ingest, gap detection, raw ranges and decimation.

Ingest keeps the first copy of each ``(pass_id, seq)`` (docs/protocol.md) and says how many
frames were new and how many were already stored:

- SQLite: one ``INSERT ... ON CONFLICT DO NOTHING`` run by ``executemany``.
- PostgreSQL: binary ``COPY`` into a session-local staging table, then one statement moves the
  batch over, ``WITH staged AS (DELETE FROM stage RETURNING ...) INSERT ... SELECT ...
  ON CONFLICT DO NOTHING``, which leaves the stage empty for the next call.

Both run inside the caller's transaction: a batch that fails half way is undone by the
rollback. The SQL text is built from the layout's fixed column names
(:class:`telemetry.layout.FrameLayout`, one per robot: its joints' columns only) and never
from arguments; field names asked for by callers are checked against the pass's layout
(a subset of :data:`models.TELEMETRY_FIELDS`).
"""

from __future__ import annotations

import functools
import uuid
from collections.abc import Collection, Sequence
from dataclasses import dataclass
from typing import Any

from sqlalchemy import BigInteger, Boolean, Double, Row, String, Uuid, cast, func, select
from sqlalchemy.exc import DBAPIError
from sqlalchemy.orm import Session

from server.storage._common import check_fields, check_time_range, require_pass
from server.storage.errors import InvalidArgument, NotFound
from server.storage.models import (
    BUCKET_FIELDS,
    STORAGE_LAYOUT,
    TELEMETRY_FIELDS,
    PassRecord,
    PlanRecord,
    TelemetryFrameRecord,
    stored_layout,
)
from telemetry.layout import FrameLayout, FrameLayoutError
from telemetry.wire import TelemetryFrame

__all__ = [
    "MAX_BUCKETS",
    "Bucket",
    "Extent",
    "IngestResult",
    "count_frames",
    "frame_seqs",
    "ingest_frames",
    "ingest_messages",
    "missing_seqs",
    "pass_layout",
    "telemetry_buckets",
    "telemetry_extent",
    "telemetry_range",
]

#: The most buckets one decimation may ask for.
MAX_BUCKETS = 20_000

_TABLE = TelemetryFrameRecord.__table__
_FRAME = TelemetryFrameRecord
FlatRow = tuple[Any, ...]

_PG_STAGE = "hikoboshi_telemetry_stage"
# Temporary: private to the connection, never WAL-logged; emptied at every commit.
_PG_CREATE_STAGE = (
    f"CREATE TEMPORARY TABLE IF NOT EXISTS {_PG_STAGE} "
    f"(LIKE telemetry_frames INCLUDING DEFAULTS) ON COMMIT DELETE ROWS"
)
_PG_TYPE_NAMES = {
    Uuid: "uuid",
    BigInteger: "int8",
    Double: "float8",
    String: "text",
    Boolean: "bool",
}
assert set(STORAGE_LAYOUT.columns) | {"pass_id"} == set(_TABLE.columns.keys())


@dataclass(frozen=True)
class Statements:
    """The insert statements of one layout: its columns only (a robot of fewer joints than
    the table has leaves the others NULL). Built from the layout's fixed names, never from
    arguments."""

    columns: tuple[str, ...]
    sqlite_insert: str
    pg_copy: str
    pg_types: list[str]
    pg_move: str
    pg_statements: str


@functools.cache
def statements(layout: FrameLayout) -> Statements:
    columns = ("pass_id", *layout.columns)
    listed = ", ".join(columns)
    # Binary: ten times faster than text for doubles (no formatting and parsing of numbers).
    pg_copy = f"COPY {_PG_STAGE} ({listed}) FROM STDIN (FORMAT BINARY)"
    pg_move = (
        f"WITH staged AS (DELETE FROM {_PG_STAGE} RETURNING {listed}) "
        f"INSERT INTO telemetry_frames ({listed}) SELECT {listed} FROM staged "
        f"ON CONFLICT DO NOTHING"
    )
    return Statements(
        columns=columns,
        sqlite_insert=(
            f"INSERT INTO telemetry_frames ({listed}) "
            f"VALUES ({', '.join('?' * len(columns))}) ON CONFLICT DO NOTHING"
        ),
        pg_copy=pg_copy,
        pg_types=[_PG_TYPE_NAMES[type(_TABLE.c[name].type)] for name in columns],
        pg_move=pg_move,
        pg_statements=f"{_PG_CREATE_STAGE}; {pg_copy}; {pg_move}",
    )


def pass_layout(session: Session, pass_key: str) -> FrameLayout:
    """The telemetry layout of a stored pass: its plan's robot (``plans.n_joints``)."""
    n_joints = session.scalar(
        select(PlanRecord.n_joints)
        .join(PassRecord, PassRecord.plan_id == PlanRecord.id)
        .where(PassRecord.id == pass_key)
    )
    if n_joints is None:
        raise NotFound(f"pass {pass_key!r} not found")
    try:
        return stored_layout(n_joints)
    except ValueError as exc:
        raise InvalidArgument(f"pass {pass_key}: {exc}") from None


def write_rows(session: Session, layout: FrameLayout, rows: Sequence[FlatRow]) -> int:
    """Insert rows of ``layout.columns`` each led by the pass id as given (a ``uuid.UUID``);
    ``ON CONFLICT DO NOTHING``; the number inserted."""
    sql = statements(layout)
    connection = session.connection()
    dialect = connection.dialect
    if dialect.name == "postgresql":
        driver_connection: Any = connection.connection.driver_connection
        try:
            with driver_connection.cursor() as cursor:
                cursor.execute(_PG_CREATE_STAGE)
                with cursor.copy(sql.pg_copy) as copy:
                    copy.set_types(sql.pg_types)
                    for row in rows:
                        copy.write_row(row)
                cursor.execute(sql.pg_move)
                return int(cursor.rowcount)
        except dialect.loaded_dbapi.Error as exc:
            # Raised by the driver directly: wrap it as SQLAlchemy would (IntegrityError, ...).
            raise DBAPIError.instance(
                sql.pg_statements, None, exc, dialect.loaded_dbapi.Error
            ) from exc
    # The id as SQLite stores a Uuid column: 32 hex digits.
    hex_rows = [(row[0].hex, *row[1:]) for row in rows]
    return int(connection.exec_driver_sql(sql.sqlite_insert, hex_rows).rowcount)


@dataclass(frozen=True)
class IngestResult:
    """Frames of one call newly stored, and those already stored (or repeated in the call)."""

    inserted: int
    duplicates: int


@dataclass(frozen=True)
class Bucket:
    """Frames with ``t_start_ns <= generation_time_ns < t_start_ns + width``: their count
    and, per requested field, the minimum, maximum and mean."""

    t_start_ns: int
    count: int
    min: dict[str, float]
    max: dict[str, float]
    mean: dict[str, float]


def ingest_frames(
    *,
    session: Session,
    pass_id: str,
    frames: Sequence[TelemetryFrame],
    reception_time_ns: int,
) -> IngestResult:
    """Store ``frames`` of the pass, received at ``reception_time_ns`` (ground clock).

    Idempotent: a frame whose ``seq`` the pass already has is counted as a duplicate and
    left as first stored. Raises :class:`NotFound` for an unknown pass and
    :class:`InvalidArgument` (nothing stored) for a frame whose vectors do not fit the
    pass's robot (its plan's joint count). A database error part way (SQLAlchemy's
    ``IntegrityError`` and kin, on both backends) may leave part of the batch in the open
    transaction: the caller rolls back, and nothing of it stays.
    """
    return ingest_messages(session=session, pass_id=pass_id, messages=[(frames, reception_time_ns)])


def ingest_messages(
    *,
    session: Session,
    pass_id: str,
    messages: Sequence[tuple[Sequence[TelemetryFrame], int]],
) -> IngestResult:
    """:func:`ingest_frames` for several messages of the pass at once, each ``(frames,
    reception_time_ns)``: one write for all of them (the live link stores a backlog of
    messages so; one write each cost milliseconds apiece on a loaded PostgreSQL)."""
    key = require_pass(session, pass_id)
    total = sum(len(frames) for frames, _ in messages)
    if not total:
        return IngestResult(inserted=0, duplicates=0)
    layout = pass_layout(session, key)
    pass_key = uuid.UUID(key)
    try:
        rows = [
            (pass_key, *layout.row(frame, reception_ns))
            for frames, reception_ns in messages
            for frame in frames
        ]
    except FrameLayoutError as exc:
        raise InvalidArgument(f"pass {key}: {exc}") from None
    inserted = write_rows(session, layout, rows)
    return IngestResult(inserted=inserted, duplicates=total - inserted)


def count_frames(*, session: Session, pass_id: str) -> int:
    key = require_pass(session, pass_id)
    return session.scalar(select(func.count()).where(_FRAME.pass_id == key)) or 0


def frame_seqs(*, session: Session, pass_id: str) -> list[int]:
    """The stored frame numbers of the pass, ascending."""
    key = require_pass(session, pass_id)
    query = select(_FRAME.seq).where(_FRAME.pass_id == key).distinct().order_by(_FRAME.seq)
    return list(session.scalars(query))


def stored_among(*, session: Session, pass_id: str, seqs: Collection[int]) -> set[int]:
    """Which of the frame numbers ``seqs`` the pass already has stored (a retransmission's
    frames, before they are written: the copies are not new to anyone)."""
    if not seqs:
        return set()
    key = require_pass(session, pass_id)
    query = select(_FRAME.seq).where(
        _FRAME.pass_id == key, _FRAME.seq.between(min(seqs), max(seqs)), _FRAME.seq.in_(seqs)
    )
    return set(session.scalars(query))


def missing_seqs(*, session: Session, pass_id: str, up_to_seq: int) -> list[tuple[int, int]]:
    """The gaps in ``0..up_to_seq`` as inclusive ``(lo, hi)`` ranges, ascending: what to
    ask the spacecraft to ``retransmit`` (docs/protocol.md)."""
    key = require_pass(session, pass_id)
    if up_to_seq < 0:
        return []
    seq = _FRAME.seq
    in_range = (_FRAME.pass_id == key, seq <= up_to_seq)
    lowest, highest = session.execute(select(func.min(seq), func.max(seq)).where(*in_range)).one()
    if lowest is None:
        return [(0, up_to_seq)]
    following = func.lead(seq).over(order_by=seq)
    pairs = select(seq.label("seq"), following.label("next_seq")).where(*in_range).subquery()
    inner = (
        select(pairs.c.seq + 1, pairs.c.next_seq - 1)
        .where(pairs.c.next_seq > pairs.c.seq + 1)
        .order_by(pairs.c.seq)
    )
    gaps = [(int(lo), int(hi)) for lo, hi in session.execute(inner)]
    if lowest > 0:
        gaps.insert(0, (0, int(lowest) - 1))
    if highest < up_to_seq:
        gaps.append((int(highest) + 1, up_to_seq))
    return gaps


def telemetry_range(
    *,
    session: Session,
    pass_id: str,
    t0_ns: int,
    t1_ns: int,
    fields: Sequence[str],
    limit: int | None = None,
) -> list[Row[Any]]:
    """Frames with ``t0_ns <= generation_time_ns < t1_ns`` in time order, as rows of
    ``(seq, generation_time_ns, *fields)`` (each also by name); the first ``limit`` only,
    if given (the database stops there: a whole pass is not read for a page of it)."""
    check_fields(fields, TELEMETRY_FIELDS)
    check_time_range(t0_ns, t1_ns)
    key = require_pass(session, pass_id)
    names = check_fields(fields, pass_layout(session, key).fields)
    gen = _FRAME.generation_time_ns
    query = (
        select(_FRAME.seq, gen, *(_TABLE.c[name] for name in names))
        .where(_FRAME.pass_id == key, gen >= t0_ns, gen < t1_ns)
        .order_by(gen, _FRAME.seq)
    )
    if limit is not None:
        query = query.limit(limit)
    return list(session.execute(query))


@dataclass(frozen=True)
class Extent:
    """A pass's stored frames: how many, and the first and last generation times."""

    count: int
    first_ns: int
    last_ns: int


def telemetry_extent(*, session: Session, pass_id: str) -> Extent | None:
    """The stored frames' count and generation-time span of a pass; None when it has none."""
    key = require_pass(session, pass_id)
    gen = _FRAME.generation_time_ns
    count, first, last = session.execute(
        select(func.count(), func.min(gen), func.max(gen)).where(_FRAME.pass_id == key)
    ).one()
    if not count:
        return None
    return Extent(count=int(count), first_ns=int(first), last_ns=int(last))


def telemetry_buckets(
    *,
    session: Session,
    pass_id: str,
    t0_ns: int,
    t1_ns: int,
    fields: Sequence[str],
    buckets: int,
) -> list[Bucket]:
    """Decimate ``[t0_ns, t1_ns)`` into ``buckets`` equal spans (the last may be short) and
    give each non-empty one's count and min / max / mean per field, computed in SQL.

    Bucket ``k`` starts at ``t0_ns + k * width`` with ``width = ceil((t1_ns - t0_ns) /
    buckets)`` ns; empty buckets (a gap, LOS) are left out.
    """
    check_fields(fields, BUCKET_FIELDS)
    check_time_range(t0_ns, t1_ns)
    if not 1 <= buckets <= MAX_BUCKETS:
        raise InvalidArgument(f"{buckets} buckets is outside 1..{MAX_BUCKETS}")
    key = require_pass(session, pass_id)
    names = check_fields(fields, pass_layout(session, key).bucket_fields)
    width = -(-(t1_ns - t0_ns) // buckets)
    gen = _FRAME.generation_time_ns
    # Integer division of int64 on both backends; grouped in an outer query so PostgreSQL's
    # server-side parameters need not be matched between SELECT and GROUP BY.
    indexed = (
        select(((gen - t0_ns) // width).label("bucket"), *(_TABLE.c[name] for name in names))
        .where(_FRAME.pass_id == key, gen >= t0_ns, gen < t1_ns)
        .subquery()
    )
    aggregates = []
    for name in names:
        column = indexed.c[name]
        aggregates += [func.min(column), func.max(column), func.avg(cast(column, Double))]
    query = (
        select(indexed.c.bucket, func.count(), *aggregates)
        .group_by(indexed.c.bucket)
        .order_by(indexed.c.bucket)
    )
    out = []
    for row in session.execute(query):
        stats = row[2:]
        out.append(
            Bucket(
                t_start_ns=t0_ns + int(row[0]) * width,
                count=int(row[1]),
                min={name: float(stats[3 * i]) for i, name in enumerate(names)},
                max={name: float(stats[3 * i + 1]) for i, name in enumerate(names)},
                mean={name: float(stats[3 * i + 2]) for i, name in enumerate(names)},
            )
        )
    return out
