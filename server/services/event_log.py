"""The audit log's writing: :class:`Event`, the frozen base class of every event kind, and
the one way an event is written, :func:`record` (the row stamped by the injected
:class:`~server.services.clock.Clock` of its writer, never by the process's own clock), and
published to the consoles, the dict :func:`record` returns (``kind, actor, detail, pass_id,
time_ns, id``, the console protocol's ``event``): through the command path's
:class:`~server.services.dbworker.Database` once its transaction commits, or, for the REST
side's own transactions, by the route through the publisher once the route's service has
committed (:func:`written`; :func:`with_written` for a job of a worker process).

``detail`` is each class's fields but ``actor`` and ``pass_id``, named as the stored and
published detail has always named them (``from`` for ``PassState``'s ``from_state``). The
kinds are in :mod:`server.services.events_link` and :mod:`server.services.events_passes`;
:mod:`server.services.events` re-exports all of it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields
from typing import Any, ClassVar, TypeVar

from sqlalchemy.orm import Session

from server.services.clock import Clock
from server.storage import repository as repo

__all__ = [
    "Event",
    "event_job",
    "published",
    "record",
    "record_many",
    "with_written",
    "written",
]

T = TypeVar("T")
#: ``Session.info`` key of the events recorded on it.
_WRITTEN = "hikoboshi.events"
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


def published(event: Event, time_ns: int, event_id: int) -> dict[str, Any]:
    """The dict the consoles get for a stored event."""
    return {
        "kind": event.kind,
        "actor": event.actor,
        "detail": event.detail(),
        "pass_id": event.pass_id,
        "time_ns": time_ns,
        "id": event_id,
    }


def record(session: Session, event: Event, time_ns: int) -> dict[str, Any]:
    """Add ``event``'s row stamped ``time_ns`` (read off the writer's injected clock: the
    command path's when it writes, the request's when a route took it), and return it as the
    dict to publish once the transaction commits (kept on the session too:
    :func:`written`)."""
    row = repo.add_event(
        session=session,
        time_ns=time_ns,
        kind=event.kind,
        actor=event.actor,
        detail=event.detail(),
        pass_id=event.pass_id,
    )
    out = published(event, time_ns, row.id)
    session.info.setdefault(_WRITTEN, []).append(out)
    return out


def record_many(session: Session, stamped: list[tuple[Event, int]]) -> list[dict[str, Any]]:
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
    out = [published(event, time_ns, i) for (event, time_ns), i in zip(stamped, ids, strict=True)]
    session.info.setdefault(_WRITTEN, []).extend(out)
    return out


def event_job(event: Event, clock: Clock) -> Callable[[Session], list[dict[str, Any]]]:
    """A database job (:class:`~server.services.dbworker.Database`) that records ``event``,
    stamped when it runs."""
    return lambda session: [record(session, event, clock.time_ns())]


def written(session: Session) -> list[dict[str, Any]]:
    """The events :func:`record` wrote on ``session`` since the last call (to publish once
    it has committed)."""
    events: list[dict[str, Any]] = session.info.pop(_WRITTEN, [])
    return events


def with_written(
    fn: Callable[..., T], /, *, session: Session, **kwargs: Any
) -> tuple[T, list[dict[str, Any]]]:
    """``fn(session=session, **kwargs)`` and the events it wrote (for a job a worker process
    runs: ``partial(with_written, fn)`` goes there, the server publishes what comes back)."""
    return fn(session=session, **kwargs), written(session)
