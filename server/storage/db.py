"""Engines, sessions and migrations.

- :func:`make_engine`: SQLite (a file, WAL) or PostgreSQL (psycopg 3) from one URL.
- :func:`session_factory`: the ``sessionmaker`` the service opens its transactions with.
- :func:`upgrade`: Alembic migrations to ``head``, programmatically (no ``alembic.ini``).
- :func:`schema_diff`: what Alembic's autogenerate sees between the models and a database;
  empty after :func:`upgrade` (a test holds it so).

SQLite transactions. The ``sqlite3`` driver's legacy mode starts a transaction only before
DML and autocommits DDL; here SQLAlchemy emits ``BEGIN IMMEDIATE`` itself, so every session
is one real transaction (migrations included) that takes the write lock up front. A deferred
``BEGIN`` would let a session read, then fail at once with ``SQLITE_BUSY`` when it tries to
write after another writer committed (WAL cannot upgrade a stale snapshot); taking the lock
at ``BEGIN`` makes such sessions wait (``busy_timeout``) instead. WAL still lets readers
outside a transaction (the driver's own connections, backups) proceed. Keep sessions short.

Read-only sessions (:func:`read_session_factory`, for the API's GET requests) begin with a
plain deferred ``BEGIN``: a WAL reader needs no lock, so a reader is never starved by the
ground's database worker, which commits back to back at high time scales and won the
write lock from a waiting GET for over 10 s in a 60x demo (a 500).

Pools. The service opens two engines on one database (:func:`server.app.create_app`): the
command path's (the link's database worker, the runner, abort; a pool of its own, small
and never shared) and the readers' (REST routes and consoles; bounded, with a short
``pool_timeout`` so a flood of readers gets 503 instead of a connection the link needs,
and on PostgreSQL a ``statement_timeout``). :class:`PoolSizes` says how big each is.

PostgreSQL URLs may name the driver or not: ``postgresql://`` is taken as
``postgresql+psycopg://`` (psycopg 3 is the only PostgreSQL driver installed).
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from alembic import command
from alembic.autogenerate import compare_metadata
from alembic.config import Config
from alembic.migration import MigrationContext
from sqlalchemy import URL, Connection, Engine, create_engine, event, make_url
from sqlalchemy.orm import Session, sessionmaker

from server.storage.errors import InvalidArgument
from server.storage.models import Base

__all__ = [
    "READ_ONLY_OPTION",
    "SQLITE_FILENAME",
    "PoolSizes",
    "alembic_config",
    "current_revisions",
    "database_unreachable",
    "head_revisions",
    "make_engine",
    "read_session_factory",
    "schema_diff",
    "session_factory",
    "sqlite_url",
    "upgrade",
]

SQLITE_FILENAME = "hikoboshi.sqlite3"
MIGRATIONS_DIR = Path(__file__).resolve().parent / "migrations"

#: Execution option of the engine behind :func:`read_session_factory`.
READ_ONLY_OPTION = "hikoboshi_read_only"

#: Applied to every new SQLite connection. WAL: readers do not block the writer; with WAL,
#: synchronous=NORMAL is durable across an application crash (a power cut may lose the last
#: commits, never the file). busy_timeout: wait for the write lock rather than fail.
SQLITE_PRAGMAS = (
    "PRAGMA journal_mode = WAL",
    "PRAGMA synchronous = NORMAL",
    "PRAGMA foreign_keys = ON",
    "PRAGMA busy_timeout = 10000",
    "PRAGMA cache_size = -65536",  # KiB: 64 MiB of page cache
    "PRAGMA temp_store = MEMORY",
)

#: libpq's connection liveness (see make_engine): a dead server is noticed within ~15 s.
PG_LIVENESS = {
    "connect_timeout": 5,
    "keepalives": 1,
    "keepalives_idle": 5,
    "keepalives_interval": 2,
    "keepalives_count": 3,
    "tcp_user_timeout": 10_000,  # ms
}

# NaN/inf are not JSON (and jsonb refuses them): fail at the write, on every backend alike.
_json_dumps = functools.partial(json.dumps, allow_nan=False)


def sqlite_url(data_dir: Path) -> str:
    """The URL of the default database: one SQLite file under ``data_dir``."""
    return URL.create("sqlite", database=str(Path(data_dir) / SQLITE_FILENAME)).render_as_string()


@dataclass(frozen=True)
class PoolSizes:
    """A connection pool's bounds: ``size`` kept open, ``overflow`` more when busy, and how
    long a checkout waits (``timeout_s``) before ``sqlalchemy.exc.TimeoutError``;
    ``statement_timeout_s`` (PostgreSQL only) ends a statement that runs longer."""

    size: int = 5
    overflow: int = 10
    timeout_s: float = 30.0
    statement_timeout_s: float | None = None


def make_engine(url: str | URL, *, echo: bool = False, pool: PoolSizes | None = None) -> Engine:
    """An engine for ``url``: ``sqlite:///PATH`` or ``postgresql[+psycopg]://...``.

    SQLite gets WAL, foreign keys, a busy timeout and ``BEGIN IMMEDIATE`` transactions (see
    the module docstring), and the file's directory is created. Anything else is refused.
    ``pool`` bounds the connection pool (SQLAlchemy's defaults without it).
    """
    parsed = make_url(url)
    backend = parsed.get_backend_name()
    pool = pool or PoolSizes()
    pooling: dict[str, Any] = {
        "pool_size": pool.size,
        "max_overflow": pool.overflow,
        "pool_timeout": pool.timeout_s,
    }
    if backend == "sqlite":
        if parsed.database in (None, "", ":memory:") or str(parsed.database).startswith("file:"):
            pooling = {}  # one in-memory database: SQLAlchemy's own pool for it
        return _sqlite_engine(parsed, echo=echo, pooling=pooling)
    if backend == "postgresql":
        if parsed.drivername == "postgresql":
            parsed = parsed.set(drivername="postgresql+psycopg")
        if parsed.get_driver_name() != "psycopg":
            raise InvalidArgument(
                f"PostgreSQL driver {parsed.get_driver_name()!r} is not supported; use psycopg"
            )
        # A server gone without a word (a partition, a host down) must not hold a
        # connection's caller forever: unacknowledged data fails after tcp_user_timeout,
        # an idle wait for an answer after the keepalives' probes, a connect after 5 s
        # (the URL's own values win).
        connect_args: dict[str, Any] = {
            key: value for key, value in PG_LIVENESS.items() if key not in parsed.query
        }
        if pool.statement_timeout_s is not None:
            ms = max(1, round(pool.statement_timeout_s * 1000))
            # beside any options the URL gives (a search_path, say), not instead of them
            given = parsed.query.get("options", "")
            given = given if isinstance(given, str) else " ".join(given)
            connect_args["options"] = f"{given} -c statement_timeout={ms}".strip()
        return create_engine(
            parsed,
            echo=echo,
            pool_pre_ping=True,
            json_serializer=_json_dumps,
            connect_args=connect_args,
            **pooling,
        )
    raise InvalidArgument(f"database {backend!r} is not supported; use sqlite or postgresql")


def _sqlite_engine(url: URL, *, echo: bool, pooling: dict[str, Any]) -> Engine:
    database = url.database or ""
    if database and database != ":memory:" and not database.startswith("file:"):
        Path(database).parent.mkdir(parents=True, exist_ok=True)
    engine = create_engine(url, echo=echo, json_serializer=_json_dumps, **pooling)

    @event.listens_for(engine, "connect")
    def _on_connect(dbapi_connection: Any, _record: Any) -> None:
        # Take transaction control from the driver (emitted on "begin" below).
        dbapi_connection.isolation_level = None
        cursor = dbapi_connection.cursor()
        try:
            for pragma in SQLITE_PRAGMAS:
                cursor.execute(pragma)
        finally:
            cursor.close()

    @event.listens_for(engine, "begin")
    def _on_begin(connection: Connection) -> None:
        read_only = connection.get_execution_options().get(READ_ONLY_OPTION, False)
        connection.exec_driver_sql("BEGIN" if read_only else "BEGIN IMMEDIATE")

    return engine


#: SQLSTATE classes of PostgreSQL errors that say the server is not there (for now):
#: connection exceptions, and the server shutting down or starting up.
_UNREACHABLE_SQLSTATES = ("08", "57P01", "57P02", "57P03", "53300")
#: SQLite's errors that pass: another writer holds the lock, the file cannot be opened or
#: read for now.
_SQLITE_TRANSIENT = ("database is locked", "unable to open database", "disk i/o error")


def database_unreachable(exc: BaseException) -> bool:
    """Whether ``exc`` says the database cannot be reached now (a connection refused,
    dropped or timed out; the server shutting down; a pool with no connection to give),
    rather than refusing the statement: a write that failed so may be run again later."""
    from sqlalchemy import exc as sa_exc

    if isinstance(exc, sa_exc.TimeoutError):  # the pool: no connection to be had
        return True
    if isinstance(exc, sa_exc.PendingRollbackError):  # its connection was lost mid-way
        return "invalid transaction" in str(exc)
    if not isinstance(exc, sa_exc.DBAPIError):
        return False
    if exc.connection_invalidated:
        return True
    orig = exc.orig
    if orig is not None and type(orig).__module__.startswith("psycopg"):
        state = getattr(orig, "sqlstate", None)
        if state is None:  # no answer from a server at all
            return isinstance(exc, sa_exc.OperationalError)
        return str(state).startswith(_UNREACHABLE_SQLSTATES)
    if isinstance(exc, sa_exc.OperationalError):  # sqlite3
        return any(text in str(orig).lower() for text in _SQLITE_TRANSIENT)
    return False


def session_factory(engine: Engine) -> sessionmaker[Session]:
    """Sessions on ``engine``; objects stay readable after commit (responses are built then)."""
    return sessionmaker(engine, expire_on_commit=False)


def read_session_factory(engine: Engine) -> sessionmaker[Session]:
    """Sessions that only read: on SQLite they take no lock (see the module docstring); a
    write in one may fail with ``SQLITE_BUSY`` at once. The same as
    :func:`session_factory` on PostgreSQL."""
    return sessionmaker(
        engine.execution_options(**{READ_ONLY_OPTION: True}), expire_on_commit=False
    )


def alembic_config(connection: Connection | None = None, *, url: str | None = None) -> Config:
    """An Alembic configuration for our migrations, on an open ``connection`` or a ``url``.

    For a new revision: ``alembic.command.revision(alembic_config(url=...),
    message="...", autogenerate=True)`` against a database at ``head``.
    """
    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS_DIR))
    if url is not None:
        # ConfigParser interpolation: a literal % must be doubled.
        config.set_main_option("sqlalchemy.url", url.replace("%", "%%"))
    if connection is not None:
        config.attributes["connection"] = connection
    return config


def upgrade(engine: Engine, revision: str = "head") -> None:
    """Migrate the database to ``revision`` in one transaction (DDL included, both backends)."""
    with engine.begin() as connection:
        command.upgrade(alembic_config(connection), revision)


def head_revisions() -> tuple[str, ...]:
    """The head migration(s) of our Alembic scripts (one, unless a branch is left open)."""
    from alembic.script import ScriptDirectory

    return tuple(sorted(ScriptDirectory.from_config(alembic_config()).get_heads()))


def current_revisions(connection: Connection) -> tuple[str, ...]:
    """The migration(s) the database at ``connection`` is at (none: never migrated)."""
    return tuple(sorted(MigrationContext.configure(connection).get_current_heads()))


def schema_diff(engine: Engine) -> list[Any]:
    """Alembic autogenerate's differences between the models and the database (types too)."""
    with engine.connect() as connection:
        context = MigrationContext.configure(
            connection, opts={"compare_type": True, "compare_server_default": True}
        )
        return list(compare_metadata(context, Base.metadata))
