"""The ground service's storage: SQLAlchemy models, repository functions, Alembic migrations.

    models.py      the tables (typed ORM) and their conventions: clocks, ids, keys
    db.py          make_engine (SQLite WAL file or PostgreSQL), session_factory, upgrade
    repository.py  keyword-only read/write functions over a Session; they never commit
    alarms.py      the same for the alarms table (save, list, acknowledge)
    errors.py      StorageError and its subclasses
    migrations/    Alembic environment and revisions (run through db.upgrade)

SQLite is the default (one file under the data directory); PostgreSQL when the database URL
names one. The schema stays compatible with TimescaleDB hypertables (models docstring).
"""
