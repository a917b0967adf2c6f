"""The ground's database worker (its publish hook: :mod:`server.services.publisher`).

Every database write of the live path (link, runner) goes through :class:`Database`: one
worker thread, so writes keep their order and an SQLite commit never stalls the event loop
(and with it the uplink); on PostgreSQL the telemetry frames have a second worker thread
and connection of their own, so storing them never waits behind the command stages.
:class:`Publisher` hands committed events, newly archived telemetry frames and the alarms
as written to the consoles.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import itertools
import logging
import queue
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

from sqlalchemy.orm import Session, sessionmaker

from server.services.db_batch import run_jobs, runs
from server.services.db_outage import RETRY_FIRST_S, RETRY_MAX_S, JournalFull, Outage
from server.services.event_log import publish_on_commit
from server.services.publisher import AlarmCallback, FrameCallback, Publisher
from server.storage.db import database_unreachable
from server.storage.errors import LeaseLost

__all__ = [
    "AlarmCallback",
    "Database",
    "FrameCallback",
    "JournalFull",
    "Outage",
    "Publisher",
    "done_unless",
    "frames_apart_for",
]

log = logging.getLogger("hikoboshi.ground.db")

T = TypeVar("T")


class Database:
    """Transactions on one worker thread, in the order they were asked for (see the module
    docstring), with group commit: the jobs waiting when the worker comes round run in one
    transaction, so a burst of acknowledgements costs one commit, not hundreds. A job that
    fails rolls its whole group back; the group is then run again one job per transaction,
    so only the failing job fails. Consecutive :class:`~server.services.db_batch.Batched`
    jobs of a kind (the command stages' writes) also share their statements: one read and a
    few writes for the run, not three round trips a job (:mod:`server.services.db_batch`).

    What a job writes to publish (its events, :func:`~server.services.event_log.record`) is
    published once its transaction has committed, by the hook on ``sessions``
    (:func:`~server.services.event_log.publish_on_commit`, installed here), typed.

    An operator's control requests (``run(..., control=True)``: confirm, abort, the state
    after it) go before everything, in a transaction of their own; a group in progress
    commits early when one arrives, so an abort waits for one job, not a group of them.

    Telemetry frames (:meth:`submit_then`) go ahead of the jobs already waiting: their
    acknowledgement waits on the commit, and a spacecraft that hears none sends them again.
    At 60x a pass changes some 700 command stages a second, and frames queued behind that
    backlog waited seconds (60 000 copies in one demo). Frames and command stages touch
    different tables, so the order between them is free; each kind keeps its own order.

    With ``frames_apart`` (PostgreSQL: :func:`frames_apart_for`), the frames do not share the
    worker at all: a second thread stores them, one job after another in a transaction
    each, on a connection of its own. On one worker a frame job still waited for the group
    in progress; under 200 viewer reads a loaded PostgreSQL took seconds over a group of
    acknowledgements (three statements each), and at 20x the frames of those seconds
    outgrew what one job stores (:data:`~server.services.downlink.MAX_INGEST_FRAMES`): the
    ground fell 25 s behind the vehicle. SQLite keeps one worker (one writer at a time:
    a second would only wait for the database's lock).

    **A database outage is ridden through** (docs/operations.md "A database outage"): a
    transaction that fails because the database cannot be reached
    (:func:`~server.storage.db.database_unreachable`) settles nothing; its jobs, and every
    job queued behind them, stay queued in order (the journal) and the worker tries again,
    backing off from :data:`RETRY_FIRST_S` to :data:`RETRY_MAX_S`, until the database
    answers; then the journal is replayed in order before anything queued later. No caller
    sees the outage as a failure: a pass's write waits for the database instead of
    killing its task. The journal is bounded (``journal_max`` jobs): past it a new job
    fails at once with :class:`JournalFull`, logged and counted (never silently), and the
    command path's recovery asks the vehicle for the fates it could not file. At a stop
    (:meth:`give_up`) a journal the database cannot take fails loudly rather than hang.
    """

    #: A group runs at most this many jobs: frames arriving meanwhile wait for the whole
    #: group (at 60x, groups of 256 command-stage jobs still made the spacecraft resend 70 %
    #: of its frames; with 64, none).
    MAX_GROUP = 64

    def __init__(
        self,
        sessions: sessionmaker[Session],
        publisher: Publisher,
        *,
        frames_apart: bool = False,
        journal_max: int = 200_000,
    ) -> None:
        self._sessions = sessions
        publish_on_commit(sessions, publisher)
        self.journal_max = journal_max
        self.outage = Outage()
        self._publisher = publisher
        self._counts = threading.Lock()  # groups and jobs, counted by both workers
        self._queue: queue.SimpleQueue[_Job | None] = queue.SimpleQueue()
        #: jobs to run before the queue's (thread-safe appends and pops); a queue entry of
        #: ``_URGENT`` wakes the worker for them
        self._urgent: collections.deque[_Job] = collections.deque()
        #: control jobs (an operator waits): run before anything else, alone
        self._control: collections.deque[_Job] = collections.deque()
        self._thread = threading.Thread(target=self._worker, name="ground-db", daemon=True)
        self._thread.start()
        #: the frames' own worker (``frames_apart``): its queue and thread
        self._frames: queue.SimpleQueue[_Job | None] | None = None
        self._frames_thread: threading.Thread | None = None
        if frames_apart:
            self._frames = queue.SimpleQueue()
            self._frames_thread = threading.Thread(
                target=self._frames_worker, name="ground-db-frames", daemon=True
            )
            self._frames_thread.start()
        self._pending: set[asyncio.Future[Any]] = set()
        self._closed = False
        self._give_up_at: float | None = None
        self.groups = 0
        self.jobs = 0
        #: Run first in every transaction (the command lease's fencing check,
        #: :meth:`server.services.authority.CommandAuthority.fence`): a write of a ground that
        #: no longer holds the lease fails there and is rolled back. None: no lease (tests).
        self.fence: Callable[[Session], None] | None = None
        #: Told each commit's duration (wall s, measured, not the injected clock: it is a
        #: latency): the metrics' histogram (server/services/metrics.py), or no one.
        self.on_commit: Callable[[float], None] | None = None

    def _transaction(self, job: Callable[[Session], T]) -> T:
        with self._sessions() as session:
            try:
                if self.fence is not None:
                    self.fence(session)
                result = job(session)
                self._commit(session)
            except BaseException:
                session.rollback()
                raise
            return result

    def _commit(self, session: Session) -> None:
        began = time.perf_counter()
        session.commit()
        if self.on_commit is not None:
            self.on_commit(time.perf_counter() - began)

    # -- a database outage ---------------------------------------------------------------

    def _unreachable(self, error: BaseException | None) -> bool:
        """Whether ``error`` is the database not being there (and this worker should keep
        its jobs and try again): the outage begins, or goes on."""
        if error is None or not database_unreachable(error) or self._given_up():
            return False
        with self._counts:
            began = self.outage.down_since is None
            if began:
                self.outage.begin(time.monotonic(), len(self._pending))
        if began:
            log.error(
                "the database does not answer (%s): keeping the command path's writes in "
                "order until it does (%d waiting)",
                type(error).__name__,
                len(self._pending),
                extra={"fields": {"event": "database_outage", "error": type(error).__name__}},
            )
        return True

    def _back_off(self) -> None:
        """Before trying again during an outage: wait, longer each time (this worker's
        thread only; the event loop goes on)."""
        self.outage.tried += 1
        time.sleep(min(RETRY_MAX_S, RETRY_FIRST_S * 2 ** min(self.outage.tried, 8)))

    def _reached(self, tried_at: float) -> None:
        """A transaction tried at ``tried_at`` (monotonic) reached the database: an outage
        that began before it ends (its journal is replayed from here, in order), and a
        replay in progress finishes once nothing is waiting. One that began after it was
        tried goes on: the other worker's commit that finished as the connection was cut
        ended an outage the moment it began (the consoles read "reachable" mid-outage)."""
        outage = self.outage
        if outage.down_since is None and outage.replay_since is None:
            return
        now = time.monotonic()
        with self._counts:
            if outage.down_since is not None and outage.down_since > tried_at:
                return
            if outage.down_since is not None:
                waited = outage.end(now, len(self._pending), self.jobs)
                log.warning(
                    "the database answers again after %.1f s: replaying %d writes in order",
                    waited,
                    outage.journal_at_return,
                    extra={"fields": {"event": "database_back", "down_s": round(waited, 3)}},
                )
            elif self._queue.empty() and not self._urgent and not self._control:
                replayed = outage.replayed(now, self.jobs)
                log.warning(
                    "the database's journal is replayed: %d jobs in %.1f s",
                    replayed,
                    outage.last_replay_s,
                    extra={"fields": {"event": "database_replayed", "jobs": replayed}},
                )

    def _given_up(self) -> bool:
        return self._give_up_at is not None and time.monotonic() >= self._give_up_at

    def give_up(self, after_s: float) -> None:
        """At a stop: once ``after_s`` has passed, a write the database cannot take fails
        (each logged) instead of waiting for it (the earliest deadline asked holds)."""
        at = time.monotonic() + after_s
        if self._give_up_at is None or at < self._give_up_at:
            self._give_up_at = at

    @property
    def journal(self) -> int:
        """Jobs waiting for the database (queued, or in a transaction)."""
        return len(self._pending)

    @staticmethod
    def _take(jobs: collections.deque[_Job]) -> list[_Job]:
        out = []
        while jobs:
            out.append(jobs.popleft())
        return out

    def _worker(self) -> None:
        carry: collections.deque[_Job] = collections.deque()  # taken, not yet run
        stop = False
        while True:
            if not carry and not self._urgent and not self._control:
                if stop:
                    return
                item = self._queue.get()
                if item is None:
                    return
                if item is not _URGENT:
                    carry.append(item)
            control = self._take(self._control)
            if control:  # alone: an operator waits for them
                ran = self._run_group(control)
                if ran < len(control):  # not all run (the database away): first again
                    self._control.extendleft(reversed(control[ran:]))
                continue
            while len(carry) < self.MAX_GROUP and not stop:
                try:
                    item = self._queue.get_nowait()
                except queue.Empty:
                    break
                if item is None:
                    stop = True
                elif item is not _URGENT:
                    carry.append(item)
            frames = self._take(self._urgent)
            group = frames + list(itertools.islice(carry, self.MAX_GROUP))
            if not group:
                continue
            ran = self._run_group(group, yield_to_control=True)
            if ran < len(frames):  # cut short: the frames not run go first next time
                self._urgent.extendleft(reversed(frames[ran:]))
            for _ in range(max(0, ran - len(frames))):
                carry.popleft()

    def _frames_worker(self) -> None:
        """The frames' worker (``frames_apart``): each job in a transaction of its own, in
        the order they came (the downlink has one in flight at a time)."""
        assert self._frames is not None
        while (job := self._frames.get()) is not None:
            while not self._run_group([job]):  # the database is not there: again
                pass

    def _run_group(self, group: list[_Job], *, yield_to_control: bool = False) -> int:
        """Run ``group``'s jobs in one transaction and settle them; with
        ``yield_to_control``, stop after the job during which a control job arrived and
        commit what ran (the rest stays queued). How many jobs ran."""
        outcomes: list[tuple[bool, Any]] = []
        ran = 0
        if self.outage.down_since is not None:
            self._back_off()
        tried_at = time.monotonic()
        try:
            with self._sessions() as session:
                try:
                    if self.fence is not None:
                        self.fence(session)
                except BaseException:
                    session.rollback()
                    raise
                try:
                    results = []
                    for run in runs([job.fn for job in group]):  # Batched neighbours together
                        ran += len(run)
                        results += run_jobs(session, run)
                        if yield_to_control and self._control:
                            break
                    self._commit(session)
                except BaseException:
                    session.rollback()
                    raise
            outcomes = [(True, r) for r in results]
        except Exception:
            error = sys.exc_info()[1]
            if self._unreachable(error):  # nothing settled: the whole group runs again
                return 0
            if ran == 0 and isinstance(error, LeaseLost):  # the fence: every job refused
                ran = len(group)
                outcomes = [(False, error)] * ran
            elif ran <= 1:  # the first job failed (or the fence could not ask): that job
                ran = 1
                outcomes = [(False, error)]
            else:
                for job in group[:ran]:  # isolate the failure: one transaction each
                    try:
                        outcomes.append((True, self._transaction(job.fn)))
                    except Exception as exc:
                        if self._unreachable(exc):  # the rest stays queued
                            ran = len(outcomes)
                            break
                        outcomes.append((False, exc))
        self._reached(tried_at)
        with self._counts:
            self.groups += 1
            self.jobs += ran
        for job, (ok, value) in zip(group[:ran], outcomes, strict=True):
            # A loop closed meanwhile has nobody left to wait for the result (the committed
            # work stands).
            with contextlib.suppress(RuntimeError):
                job.loop.call_soon_threadsafe(_settle, job.future, ok, value)
        return ran

    def _enqueue(
        self, job: Callable[[Session], T], *, urgent: bool = False, control: bool = False
    ) -> asyncio.Future[T]:
        loop = asyncio.get_running_loop()
        future: asyncio.Future[T] = loop.create_future()
        if self._closed:  # no worker will ever run it: fail now rather than hang
            future.set_exception(RuntimeError("the database worker is closed"))
            return future
        if self.outage.down_since is not None and len(self._pending) >= self.journal_max:
            self.outage.refused += 1
            future.set_exception(
                JournalFull(
                    f"the database has not answered for "
                    f"{time.monotonic() - self.outage.down_since:.0f} s and {self.journal_max} "
                    "writes wait for it: this one is refused"
                )
            )
            return future
        if urgent and self._frames is not None:
            self._frames.put(_Job(job, future, loop))
        elif urgent or control:
            (self._control if control else self._urgent).append(_Job(job, future, loop))
            self._queue.put(_URGENT)
        else:
            self._queue.put(_Job(job, future, loop))
        self._pending.add(future)
        future.add_done_callback(self._pending.discard)
        return future

    async def run(self, job: Callable[[Session], T], *, control: bool = False) -> T:
        """Run ``job`` in its turn; a ``control`` job (an operator's request: a short read
        or write that someone is waiting for) goes before everything else, alone."""
        return await self._enqueue(job, control=control)

    async def write(self, job: Callable[[Session], object], *, control: bool = False) -> None:
        """Run ``job`` (its events are published when it commits) and wait for it."""
        await self.run(job, control=control)

    def submit(self, job: Callable[[Session], object]) -> None:
        """Queue ``job`` without waiting (the emitter must not wait for a commit); its
        events are published when it commits, a failure is logged."""
        future = self._enqueue(job)

        def done(f: asyncio.Future[object]) -> None:
            if not f.cancelled() and (exc := f.exception()) is not None:
                log.error("database write failed: %r", exc)

        future.add_done_callback(done)

    def submit_then(self, job: Callable[[Session], T], then: Callable[[T | None], None]) -> None:
        """Queue ``job`` without waiting; ``then`` gets its result once it has committed, or
        None if it failed (the failure is logged). The emitter goes on at once: the downlink
        reads the next message while this one's frames are being stored. It runs ahead of the
        jobs already waiting, or on the frames' own worker (see the class docstring)."""
        future = self._enqueue(job, urgent=True)

        def done(f: asyncio.Future[T]) -> None:
            if f.cancelled():
                return
            if (exc := f.exception()) is not None:
                log.error("database write failed: %r", exc)
                then(None)
                return
            then(f.result())

        future.add_done_callback(done)

    async def barrier(self, until: asyncio.Event | None = None) -> None:
        """Wait for the jobs queued so far, not for those queued meanwhile: with telemetry
        arriving all the time, :meth:`drain` may not return while the link is up. With
        ``until``, stop waiting as soon as it is set (the jobs go on)."""
        pending = list(self._pending)
        if not pending:
            return
        # asyncio.wait, not gather: giving up the wait must not cancel the jobs' futures
        everything = asyncio.ensure_future(asyncio.wait(pending))
        if until is None:
            await everything
            return
        await done_unless(everything, until)
        everything.cancel()

    async def drain(self) -> None:
        """Wait for every job queued so far (and those their completions queue): until the
        worker is idle (shutdown, tests)."""
        while self._pending:
            await asyncio.gather(*list(self._pending), return_exceptions=True)

    def close(self) -> None:
        self._closed = True
        if self._give_up_at is None:
            self._give_up_at = time.monotonic()
        self._queue.put(None)
        if self._frames is not None and self._frames_thread is not None:
            self._frames.put(None)
            self._frames_thread.join()
        self._thread.join()


def frames_apart_for(sessions: sessionmaker[Session]) -> bool:
    """Whether the frames get a worker of their own on these sessions' database: on every
    backend but SQLite (see :class:`Database`)."""
    bind = sessions.kw.get("bind")
    return bind is not None and bind.dialect.name != "sqlite"


@dataclass
class _Job:
    fn: Callable[[Session], Any]
    future: asyncio.Future[Any]
    loop: asyncio.AbstractEventLoop


async def done_unless(future: asyncio.Future[Any], until: asyncio.Event) -> bool:
    """Wait for ``future`` unless ``until`` is set first; whether ``future`` is done (it is
    left as it is either way)."""
    if not until.is_set():
        interrupt = asyncio.ensure_future(until.wait())
        try:
            await asyncio.wait((future, interrupt), return_when=asyncio.FIRST_COMPLETED)
        finally:
            interrupt.cancel()
    return future.done()


def _settle(future: asyncio.Future[Any], ok: bool, value: Any) -> None:
    if future.cancelled():
        return
    if ok:
        future.set_result(value)
    else:
        future.set_exception(value)


#: A queue entry that only wakes the worker for :attr:`Database._urgent`.
_URGENT: Any = _Job(fn=lambda session: None, future=None, loop=None)  # type: ignore[arg-type]
