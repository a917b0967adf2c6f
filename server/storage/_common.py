"""Helpers shared by the repository modules."""

from __future__ import annotations

import uuid
from collections.abc import Collection, Iterable
from dataclasses import dataclass
from typing import Generic, TypeVar

from sqlalchemy.exc import IntegrityError, StatementError
from sqlalchemy.orm import Session

from server.storage.errors import Conflict, InvalidArgument, NotFound
from server.storage.models import PassRecord

T = TypeVar("T")

#: The most rows a list call returns at once.
MAX_LIMIT = 10_000


@dataclass(frozen=True)
class Page(Generic[T]):
    """One page of a listing and the number of rows that match in all."""

    items: list[T]
    count: int


def canonical_id(value: str, *, what: str) -> str:
    """The canonical (dashed, lower-case) UUID; anything that is not one is not stored."""
    try:
        return str(uuid.UUID(value))
    except (ValueError, AttributeError, TypeError):
        raise NotFound(f"{what} {value!r} not found (not a UUID)") from None


def new_id() -> str:
    return str(uuid.uuid4())


def require_pass(session: Session, pass_id: str) -> str:
    """``pass_id`` canonical, or :class:`NotFound` when no such pass is stored."""
    key = canonical_id(pass_id, what="pass")
    if session.get(PassRecord, key) is None:
        raise NotFound(f"pass {pass_id!r} not found")
    return key


def check_one_of(value: str, allowed: Collection[str], *, what: str) -> None:
    if value not in allowed:
        raise InvalidArgument(f"{what} {value!r} is not one of {tuple(allowed)}")


def check_page(offset: int, limit: int) -> None:
    if offset < 0:
        raise InvalidArgument(f"offset {offset} is negative")
    if not 1 <= limit <= MAX_LIMIT:
        raise InvalidArgument(f"limit {limit} is outside 1..{MAX_LIMIT}")


def check_fields(fields: Iterable[str], allowed: Collection[str]) -> tuple[str, ...]:
    """The requested column names, each checked against the whitelist ``allowed``."""
    if isinstance(fields, str):
        raise InvalidArgument(f"fields must be a sequence of names, not the string {fields!r}")
    names = tuple(fields)
    if not names:
        raise InvalidArgument("no fields requested")
    for name in names:
        if name not in allowed:
            raise InvalidArgument(f"telemetry field {name!r} is not one of {tuple(allowed)}")
    if len(set(names)) != len(names):
        raise InvalidArgument(f"telemetry fields {names} repeat a name")
    return names


def check_time_range(t0_ns: int, t1_ns: int) -> None:
    if not t1_ns > t0_ns:
        raise InvalidArgument(f"time range [{t0_ns}, {t1_ns}) ns is empty or reversed")


def flush(session: Session, what: str) -> None:
    """Flush the session's writes of ``what``: a constraint broken is :class:`Conflict`, a
    value JSON cannot take (NaN) :class:`InvalidArgument`."""
    try:
        session.flush()
    except IntegrityError as exc:
        raise Conflict(f"{what}: {exc.orig}") from exc
    except StatementError as exc:
        if isinstance(exc.orig, ValueError):  # a value JSON cannot take (NaN), on SQLite
            raise InvalidArgument(f"{what}: {exc.orig}") from exc
        raise
    except ValueError as exc:  # the same from psycopg, which dumps JSON itself
        raise InvalidArgument(f"{what}: {exc}") from exc
