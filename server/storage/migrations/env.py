"""Alembic environment: run by :func:`server.storage.db.upgrade` on an open connection.

Without one (``alembic`` run by hand with :func:`server.storage.db.alembic_config`), it
connects to the configured ``sqlalchemy.url`` through :func:`server.storage.db.make_engine`,
so SQLite gets the same pragmas and transactions as the service. Offline mode writes SQL.
"""

from __future__ import annotations

from alembic import context
from sqlalchemy import Connection

from server.storage.db import make_engine
from server.storage.models import Base

config = context.config
target_metadata = Base.metadata


def _configure(connection: Connection) -> None:
    context.configure(
        connection=connection,
        target_metadata=target_metadata,
        compare_type=True,
        # SQLite cannot ALTER most things: later revisions rebuild tables in batch mode.
        render_as_batch=connection.dialect.name == "sqlite",
    )
    with context.begin_transaction():
        context.run_migrations()


def run_migrations_offline() -> None:
    context.configure(
        url=config.get_main_option("sqlalchemy.url"),
        target_metadata=target_metadata,
        literal_binds=True,
    )
    with context.begin_transaction():
        context.run_migrations()


def run_migrations_online() -> None:
    connection = config.attributes.get("connection")
    if connection is not None:
        _configure(connection)
        return
    url = config.get_main_option("sqlalchemy.url")
    if not url:
        raise RuntimeError("no connection and no sqlalchemy.url: use server.storage.db.upgrade")
    engine = make_engine(url)
    try:
        with engine.begin() as connection:
            _configure(connection)
    finally:
        engine.dispose()


if context.is_offline_mode():
    run_migrations_offline()
else:
    run_migrations_online()
