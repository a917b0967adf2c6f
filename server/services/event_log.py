"""The audit log's writing: :class:`Event`, the frozen base class of every event kind, and
the one way an event is written, :func:`record` (the row stamped by the injected
:class:`~server.services.clock.Clock` of its writer, never by the process's own clock).

**Published once, after the commit, typed.** :func:`record` returns the event as written,
a :class:`Recorded` (the typed event, its row's time and id), and keeps it on the session;
whatever else a transaction wants published once it commits (an alarm as written) is kept
there too (:func:`on_commit`). The session factories the ground writes with are hooked
(:func:`publish_on_commit`): when a transaction commits, what it kept goes to the
:class:`~server.services.publisher.Publisher`, in the order it was kept; when it rolls
back, it is dropped. So the place that commits publishes: the command path's database
worker, a route's session, the edge's; a worker process's job (another process: no
publisher there) hands what it wrote back (:func:`with_written`) and the worker pool
publishes it. No route publishes by hand.

``detail`` is each class's fields but ``actor`` and ``pass_id``, named as the stored and
published detail has always named them (``from`` for ``PassState``'s ``from_state``). The
kinds are in :mod:`server.services.events_link` and :mod:`server.services.events_passes`;
:mod:`server.services.events` re-exports all of it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any, ClassVar, TypeVar

from sqlalchemy import event as sa_event
from sqlalchemy.orm import Session, SessionTransaction, sessionmaker

from server.services.clock import Clock
from server.storage import repository as repo

if TYPE_CHECKING:
    from server.services.publisher import Publisher

__all__ = [
    "Event",
    "Recorded",
    "event_job",
    "on_commit",
    "publish_on_commit",
    "record",
    "record_many",
    "with_written",
    "written",
]

T = TypeVar("T")
#: ``Session.info`` key of what a transaction publishes once it commits.
_WRITTEN = "hikoboshi.events"
#: ``Session.info`` key of each open savepoint's count of items kept before it.
_MARKS = "hikoboshi.savepoints"
#: The attribute of a hooked session factory: the publisher its commits go to.
_PUBLISHER = "_hikoboshi_publisher"
#: Fields that are not part of ``detail``.
_ENVELOPE = ("actor", "pass_id")


@dataclass(frozen=True, kw_only=True)
class Event:
    """One audit-log event: who (``actor``), about which pass (if any), and its detail."""

    kind: ClassVar[str]
    #: field name -> the detail's key, where they differ
    keys: ClassVar[Mapping[str, str]] = {}
    #: fields left out of the detail when None
    optional: ClassVar[tuple[str, ...]] = ()

    actor: str
    pass_id: str | None = None

    def detail(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for f in fields(self):
            if f.name in _ENVELOPE:
                continue
            value = getattr(self, f.name)
            if value is None and f.name in self.optional:
                continue
            out[self.keys.get(f.name, f.name)] = value
        return out


@dataclass(frozen=True)
class Recorded:
    """An event as written: the typed event, its row's time (ground ns) and id. What every
    subscriber of the publisher gets (they match on ``type(recorded.event)`` and its
    fields); :meth:`document` is the console protocol's ``event``."""

    event: Event
    time_ns: int
    id: int

    @property
    def kind(self) -> str:
        return self.event.kind

    @property
    def actor(self) -> str:
        return self.event.actor

    @property
    def pass_id(self) -> str | None:
        return self.event.pass_id

    def document(self) -> dict[str, Any]:
        """``kind, actor, detail, pass_id, time_ns, id``: the stored row, as consoles get it."""
        return {
            "kind": self.kind,
            "actor": self.actor,
            "detail": self.event.detail(),
            "pass_id": self.pass_id,
            "time_ns": self.time_ns,
            "id": self.id,
        }


def on_commit(session: Session, *items: object) -> None:
    """Publish ``items`` once the session's transaction commits (dropped if it rolls back)."""
    session.info.setdefault(_WRITTEN, []).extend(items)


def publish_on_commit(sessions: sessionmaker[Session], publisher: Publisher) -> None:
    """Hook ``sessions``: what a transaction of theirs kept (:func:`record`,
    :func:`on_commit`) goes to ``publisher`` when it commits (from the committing thread:
    :meth:`~server.services.publisher.Publisher.deliver` hands it to the event loop), and is
    dropped when it rolls back. Hooking again changes the publisher (a restarted ground)."""
    hooked = getattr(sessions, _PUBLISHER, None) is not None
    setattr(sessions, _PUBLISHER, publisher)
    if hooked:
        return

    def committed(session: Session) -> None:
        session.info.pop(_MARKS, None)
        items = session.info.pop(_WRITTEN, None)
        if items:
            getattr(sessions, _PUBLISHER).deliver(items)

    def began(session: Session, transaction: SessionTransaction) -> None:
        if transaction.nested:  # a savepoint: what was kept before it stays if it rolls back
            marks = session.info.setdefault(_MARKS, {})
            marks[transaction] = len(session.info.get(_WRITTEN, ()))

    def rolled_back(session: Session, previous: SessionTransaction) -> None:
        if previous.nested:
            kept = session.info.get(_MARKS, {}).pop(previous, None)
            if kept is not None and _WRITTEN in session.info:
                del session.info[_WRITTEN][kept:]
        else:
            session.info.pop(_WRITTEN, None)
            session.info.pop(_MARKS, None)

    sa_event.listen(sessions, "after_transaction_create", began)
    sa_event.listen(sessions, "after_commit", committed)
    sa_event.listen(sessions, "after_soft_rollback", rolled_back)


def record(session: Session, event: Event, time_ns: int) -> Recorded:
    """Add ``event``'s row stamped ``time_ns`` (read off the writer's injected clock: the
    command path's when it writes, the request's when a route took it); the event as
    written, published once the transaction commits (:func:`publish_on_commit`)."""
    row = repo.add_event(
        session=session,
        time_ns=time_ns,
        kind=event.kind,
        actor=event.actor,
        detail=event.detail(),
        pass_id=event.pass_id,
    )
    out = Recorded(event, time_ns, row.id)
    on_commit(session, out)
    return out


def record_many(session: Session, stamped: list[tuple[Event, int]]) -> list[Recorded]:
    """:func:`record` of each (event, its time) in order, the rows in one statement."""
    ids = repo.add_events(
        session=session,
        rows=[
            {
                "time_ns": time_ns,
                "kind": event.kind,
                "actor": event.actor,
                "detail": event.detail(),
                "pass_id": event.pass_id,
            }
            for event, time_ns in stamped
        ],
    )
    out = [Recorded(event, time_ns, i) for (event, time_ns), i in zip(stamped, ids, strict=True)]
    on_commit(session, *out)
    return out


def event_job(event: Event, clock: Clock) -> Callable[[Session], list[Recorded]]:
    """A database job (:class:`~server.services.dbworker.Database`) that records ``event``,
    stamped when it runs."""
    return lambda session: [record(session, event, clock.time_ns())]


def written(session: Session) -> list[Any]:
    """What ``session`` keeps to publish (:func:`record`, :func:`on_commit`), taken off it:
    for a session no publisher is hooked to (a worker process's)."""
    items: list[Any] = session.info.pop(_WRITTEN, [])
    return items


def with_written(
    fn: Callable[..., T], /, *, session: Session, **kwargs: Any
) -> tuple[T, Sequence[Any]]:
    """``fn(session=session, **kwargs)`` and what it wrote to publish (for a job of a worker
    process: ``partial(with_written, fn)`` goes there; the worker pool publishes what comes
    back, :meth:`~server.services.workers.WorkerPool.run_written`). ``fn`` commits."""
    return fn(session=session, **kwargs), written(session)
