"""Helpers shared by the repository modules."""

from __future__ import annotations

import uuid
from collections.abc import Collection, Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from sqlalchemy import ColumnElement, func, insert, select
from sqlalchemy.exc import IntegrityError, StatementError
from sqlalchemy.orm import InstrumentedAttribute, Session

from server.storage.errors import Conflict, InvalidArgument, NotFound
from server.storage.models import Base, PassRecord

T = TypeVar("T")
R = TypeVar("R", bound=Base)

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


def stored(session: Session, model: type[R], value: str, *, what: str, **options: Any) -> R:
    """The ``model`` row of id ``value`` (``options``: :meth:`Session.get`'s), or
    :class:`NotFound` naming it as ``what``."""
    record = session.get(model, canonical_id(value, what=what), **options)
    if record is None:
        raise NotFound(f"{what} {value!r} not found")
    return record


def require_pass(session: Session, pass_id: str) -> str:
    """``pass_id`` canonical, or :class:`NotFound` when no such pass is stored."""
    return stored(session, PassRecord, pass_id, what="pass").id


def paged(
    session: Session,
    model: type[R],
    where: Sequence[ColumnElement[bool]],
    order_by: Sequence[Any],
    offset: int,
    limit: int,
    options: Sequence[Any] = (),
) -> Page[R]:
    """One page of the ``model`` rows that match ``where``, in ``order_by``, and how many
    match in all (the caller checks the page: :func:`check_page`)."""
    query = (
        select(model)
        .where(*where)
        .options(*options)
        .order_by(*order_by)
        .offset(offset)
        .limit(limit)
    )
    count = session.scalar(select(func.count()).select_from(model).where(*where)) or 0
    return Page(items=list(session.scalars(query)), count=count)


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


def within(
    column: ColumnElement[int] | InstrumentedAttribute[int], t0_ns: int | None, t1_ns: int | None
) -> list[ColumnElement[bool]]:
    """The conditions that ``column`` is in ``[t0_ns, t1_ns)``, for the bounds given."""
    where = [] if t0_ns is None else [column >= t0_ns]
    return where if t1_ns is None else [*where, column < t1_ns]


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


def insert_rows(
    session: Session, model: type[Base], rows: list[dict[str, Any]], *, what: str
) -> int:
    """Insert ``rows`` into ``model``'s table in one statement; the number inserted. A row a
    constraint refuses (a key already stored) is :class:`Conflict` naming ``what``."""
    if rows:
        try:
            session.execute(insert(model), rows)
        except IntegrityError as exc:
            raise Conflict(f"{what}: {exc.orig}") from exc
    return len(rows)
