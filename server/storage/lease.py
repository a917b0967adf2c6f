"""The command lease: exactly one ground commands a vehicle, and a ground that lost the
authority has its writes refused by the database (docs/operations.md "One ground in command").

One row of ``ground_leases`` per lease (a vehicle). A ground **acquires** it when it is free
(no holder, or its expiry has passed on the *database's* clock), which raises the row's
**fencing token** by one; the holder **renews** it (the expiry moves ``ttl_s`` past the
database's now) while its token is still the row's; a graceful stop **releases** it (expiry
now), so a standby takes over at once. Every transaction of a holder's command path first
calls :func:`fence` with its token: a stale token (another ground acquired the lease since)
raises :class:`~server.storage.errors.LeaseLost` and the transaction is rolled back, whatever
the stale ground believes about itself (it was paused, partitioned, or restarted).

Locking (PostgreSQL, READ COMMITTED): :func:`fence` reads the row ``FOR KEY SHARE`` and
:func:`acquire` takes it ``FOR UPDATE`` before it raises the token, so an acquisition waits
for the writes in flight under the old token to commit and every write after it sees the new
token; a renewal (``UPDATE`` of non-key columns) conflicts with neither. On SQLite every
transaction is ``BEGIN IMMEDIATE`` (one writer at a time), which gives the same order.

Times are the database's own (:func:`database_now_s`): grounds whose clocks disagree still
agree on who holds the lease. Nothing here commits: the caller's transaction does.
"""

from __future__ import annotations

from dataclasses import dataclass

from sqlalchemy import Update, select, text, update
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.orm import Session

from server.storage.errors import InvalidArgument, LeaseLost
from server.storage.models import GroundLease

__all__ = [
    "Lease",
    "LeaseRow",
    "acquire",
    "database_now_s",
    "fence",
    "read",
    "release",
    "renew",
]


@dataclass(frozen=True)
class LeaseRow:
    """A lease as stored, read at the database's ``now_s``."""

    name: str
    holder: str
    token: int
    expires_s: float
    now_s: float

    @property
    def held(self) -> bool:
        """Whether some ground holds it now (a holder, not yet expired)."""
        return bool(self.holder) and self.expires_s > self.now_s


@dataclass(frozen=True)
class Lease:
    """A lease this ground holds: its fencing token, and the database's now at the write."""

    name: str
    holder: str
    token: int
    now_s: float
    expires_s: float


def database_now_s(session: Session) -> float:
    """The database's clock, seconds since the Unix epoch (sub-millisecond)."""
    if session.get_bind().dialect.name == "postgresql":
        value = session.execute(text("SELECT EXTRACT(EPOCH FROM clock_timestamp())")).scalar()
    else:  # SQLite: julianday('now') is milliseconds
        value = session.execute(text("SELECT (julianday('now') - 2440587.5) * 86400.0")).scalar()
    return float(value)  # type: ignore[arg-type]


def _check(name: str, holder: str, ttl_s: float | None = None) -> None:
    if not 0 < len(name) <= 64:
        raise InvalidArgument(f"lease name {name!r} must have 1 to 64 characters")
    if not 0 < len(holder) <= 128:
        raise InvalidArgument(f"lease holder {holder!r} must have 1 to 128 characters")
    if ttl_s is not None and not 0 < ttl_s <= 3600:
        raise InvalidArgument(f"lease ttl_s = {ttl_s} must lie in (0, 3600]")


def read(session: Session, name: str) -> LeaseRow | None:
    """The lease ``name`` as stored (None: never acquired)."""
    row = session.get(GroundLease, name, populate_existing=True)
    if row is None:
        return None
    return LeaseRow(row.name, row.holder, row.token, row.expires_s, database_now_s(session))


def acquire(
    session: Session, name: str, holder: str, ttl_s: float, *, force: bool = False
) -> Lease | LeaseRow:
    """Take the lease ``name`` for ``holder`` if it is free (or ``force``: the caller knows
    the holder of record is gone, as an exclusive lock on an SQLite file proves): the token
    is raised by one. Else the row as it stands (who holds it, until when)."""
    _check(name, holder, ttl_s)
    dialect = session.get_bind().dialect.name
    insert = postgresql.insert if dialect == "postgresql" else sqlite.insert
    blank = {"holder": "", "token": 0, "acquired_s": 0.0, "renewed_s": 0.0, "expires_s": 0.0}
    session.execute(insert(GroundLease).values(name=name, **blank).on_conflict_do_nothing())
    if not force:  # a standby asks every second: no row lock while the lease is held
        seen = session.get(GroundLease, name, populate_existing=True)
        now = database_now_s(session)
        if seen is not None and seen.holder and seen.expires_s > now:
            return LeaseRow(seen.name, seen.holder, seen.token, seen.expires_s, now)
    row = session.scalars(
        select(GroundLease)
        .where(GroundLease.name == name)
        .with_for_update()
        .execution_options(populate_existing=True)
    ).one()
    now = database_now_s(session)
    if not force and row.holder and row.expires_s > now:
        return LeaseRow(row.name, row.holder, row.token, row.expires_s, now)
    row.holder, row.token = holder, row.token + 1
    row.acquired_s = row.renewed_s = now
    row.expires_s = now + ttl_s
    session.flush()
    return Lease(name, holder, row.token, now, row.expires_s)


def _ours(lease: Lease) -> Update:
    """An update of the lease's row while it is still ``lease`` (its holder and token)."""
    return (
        update(GroundLease)
        .where(
            GroundLease.name == lease.name,
            GroundLease.holder == lease.holder,
            GroundLease.token == lease.token,
        )
        .execution_options(synchronize_session=False)
    )


def renew(session: Session, lease: Lease, ttl_s: float) -> Lease | None:
    """Move the lease's expiry to ``ttl_s`` past the database's now, if its token is still
    the row's (None: another ground acquired it since; the lease is lost)."""
    _check(lease.name, lease.holder, ttl_s)
    now = database_now_s(session)
    done = session.execute(_ours(lease).values(renewed_s=now, expires_s=now + ttl_s))
    if done.rowcount != 1:  # type: ignore[attr-defined]
        return None
    return Lease(lease.name, lease.holder, lease.token, now, now + ttl_s)


def release(session: Session, lease: Lease) -> bool:
    """Give the lease up (a graceful stop): it expires now, so a standby takes it at once;
    the token stays, so the next holder's is still higher. Whether it was still ours."""
    now = database_now_s(session)
    done = session.execute(_ours(lease).values(holder="", expires_s=now))
    return bool(done.rowcount == 1)  # type: ignore[attr-defined]


def fence(session: Session, lease: Lease) -> None:
    """At the start of a command-path transaction: raise
    :class:`~server.storage.errors.LeaseLost` unless ``lease``'s token is still the row's
    (see the module docstring for the locking). An expired lease nobody took is still
    this ground's: the token, not the clock, fences the writes."""
    row = session.execute(
        select(GroundLease.holder, GroundLease.token)
        .where(GroundLease.name == lease.name)
        .with_for_update(read=True, key_share=True)
    ).one_or_none()
    if row is None or row.token != lease.token or row.holder != lease.holder:
        now = "nobody" if row is None or not row.holder else f"{row.holder!r} (token {row.token})"
        raise LeaseLost(
            f"this ground ({lease.holder!r}, token {lease.token}) no longer holds the command "
            f"lease {lease.name!r}: {now} holds it; the write was refused"
        )
