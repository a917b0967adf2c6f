"""Jobs of the database worker (:class:`~server.services.dbworker.Database`) whose statements
a group commit batches: :class:`Batched`.

A group commit saves commits, not statements: a group of 64 acknowledgements, one job each,
still made three round trips each (read the row, update it, insert the event). Under 80
viewer reads at 20x the ground's worker thread then waited for the event loop's thread at
every round trip (the interpreter's lock, up to its 5 ms switch interval each time) and
filed some 25 jobs a second while the pass asked for some 150: after an abort the last
stages reached the database minutes late. Consecutive :class:`Batched` jobs of one kind in
a group run in one call of that kind, which reads every row they touch in one statement and
writes them in a few (:mod:`server.services.stage_writes`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from typing import Any, Generic, TypeVar

from sqlalchemy.orm import Session

__all__ = ["Batched", "run_jobs", "runs"]

P = TypeVar("P")
T = TypeVar("T")


class Batched(Generic[P, T]):
    """A job (a callable of a session) that the group's consecutive jobs of the same
    ``kind`` run with: ``kind(session, payloads)`` returns each payload's result, in order.
    Alone (a failed group runs again one job per transaction) it is ``kind(session,
    [payload])``."""

    __slots__ = ("kind", "payload")

    def __init__(self, kind: Callable[[Session, list[P]], list[T]], payload: P) -> None:
        self.kind = kind
        self.payload = payload

    def __call__(self, session: Session) -> T:
        [result] = self.kind(session, [self.payload])
        return result


def runs(fns: Sequence[Callable[[Session], Any]]) -> Iterator[Sequence[Callable[[Session], Any]]]:
    """``fns`` in order, cut into runs: consecutive :class:`Batched` jobs of an equal kind
    together, every other job alone."""
    lo = 0
    while lo < len(fns):
        hi = lo + 1
        first = fns[lo]
        if isinstance(first, Batched):
            while hi < len(fns):
                fn = fns[hi]
                if not (isinstance(fn, Batched) and fn.kind == first.kind):
                    break
                hi += 1
        yield fns[lo:hi]
        lo = hi


def run_jobs(session: Session, run: Sequence[Callable[[Session], Any]]) -> list[Any]:
    """One run's results, in order (see :func:`runs`)."""
    first = run[0]
    if len(run) > 1 and isinstance(first, Batched):
        results = first.kind(session, [fn.payload for fn in run])  # type: ignore[attr-defined]
        if len(results) != len(run):
            raise RuntimeError(f"a batch of {len(run)} jobs gave {len(results)} results")
        return results
    return [fn(session) for fn in run]
