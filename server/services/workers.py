"""A bounded pool of worker processes for CPU-heavy requests: planning, MCAP downloads,
reports and long telemetry reads.

Why: the ground runs the 4 Hz uplink and the telemetry link in the server's event loop.
Heavy work in threads of the same process holds the GIL and starves that loop (a live pass
lost commands and its link); it also cannot be stopped, so it ran on after its client left
and kept the server from stopping on SIGTERM.

How: one process per job, started from a ``forkserver`` that has already imported the
planner, NumPy, SQLAlchemy and the MCAP writer (:data:`PRELOAD`), so a job starts in
tens of milliseconds instead of seconds of imports (the server process itself is never
forked: it has threads, sockets and an event loop). The job's result comes back over a
pipe; a large one (a recording, an HTML report) is written by the job to a temporary file
whose path the route streams from and deletes.

The limits (see :class:`~server.settings.Settings`):

- ``worker_processes`` jobs run at once, ``worker_queue`` more may wait; past that a request
  is refused at once as unavailable (``busy``, with the time to retry after).
- Each job has a deadline (``plan_deadline_s``, ``read_deadline_s``), counted from when it
  starts; past it the process is killed and the request fails with ``deadline_exceeded``.
  Waiting for a free worker is bounded by the same deadline (then ``busy``).
- A job whose client disconnects is killed at once (polled every :data:`POLL_S`).
- A job's address space is limited (``worker_memory_bytes``, ``RLIMIT_AS``): a job that
  exceeds it fails as unavailable with ``out_of_memory``; one killed by a signal with
  ``worker_crashed``. Either way the next request gets a fresh process.
- Stopping the pool (:meth:`WorkerPool.close`: on SIGTERM, before the HTTP server waits
  for its requests, and again in the app's lifespan) answers every admitted request, waiting
  or running, as unavailable with ``shutting_down`` at once, and kills and reaps every job
  process (one still starting: its request, once it has started); and a job ends by itself
  once the server process has ended, however it ended (:func:`~server.services.jobs.run_job`):
  none outlives the server (docs/operations.md "Stopping with requests in flight").

The job's side (what runs in the process, the session jobs, the result files) is
:mod:`server.services.jobs`. Errors raised by a job keep their meaning: they reach the
server as the errors they are (a planner error as the invalid request it is) and the API
answers them as it would have in-process. The pool's own refusals are
:class:`~server.services.errors.UnavailableError` (the API adds ``Retry-After``),
:class:`~server.services.errors.DeadlineExceededError` and
:class:`~server.services.errors.ClientGoneError`; their statuses: :mod:`server.api.errors`.
"""

from __future__ import annotations

import asyncio
import contextlib
import multiprocessing
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from multiprocessing.process import BaseProcess
from pathlib import Path
from typing import TYPE_CHECKING, Any, Generic, Protocol, TypeVar

from server.logs import current_log_config
from server.services.errors import (
    ClientGoneError,
    DeadlineExceededError,
    DomainError,
    UnavailableError,
)
from server.services.jobs import run_job

if TYPE_CHECKING:
    from server.services.publisher import Publisher

__all__ = [
    "POLL_S",
    "PRELOAD",
    "STOPPING_RETRY_AFTER_S",
    "WorkerPool",
    "busy",
]

T = TypeVar("T")

#: Modules the forkserver imports once, so that a job needs no imports of its own.
PRELOAD = (
    "numpy",
    "scipy.spatial.transform",
    "scipy.signal",  # the flight rules' servo response (about 0.8 s to import)
    "coal",  # the flight rules' distances
    "planner.flight_rules",
    "planner.description",
    "sqlalchemy",
    "planner.catalogue",
    "server.operations.plans",
    "server.services.recordings",
    "server.services.reports",
    "server.services.telemetry",
    "server.storage.db",
    "server.services.workers",
    "telemetry.mcap",
    "skyfield.api",  # contact windows (server.services.missions; about 0.17 s to import)
    "skyfield.searchlib",
    "mission.windows",
    "hikoboshi.cli",
)

#: How often a waiting request checks whether its client is still there (s).
POLL_S = 0.2
#: How long a killed process may take to be reaped before it is left to the OS (s).
_REAP_S = 5.0


class _Disconnectable(Protocol):
    async def is_disconnected(self) -> bool: ...


def busy(message: str, retry_after_s: float, code: str = "busy") -> UnavailableError:
    """The work cannot be done now: retry after ``retry_after_s``."""
    return UnavailableError(message, retry_after_s, code)


class WorkerPool:
    """At most ``workers`` job processes at once and ``queue`` requests waiting for one.

    :meth:`run` is awaited by an ``async`` route; see the module doc for the limits.
    """

    def __init__(
        self,
        *,
        workers: int = 2,
        queue: int = 8,
        memory_bytes: int | None = 2 << 30,
        context: str = "forkserver",
        preload: tuple[str, ...] = PRELOAD,
        publisher: Publisher | None = None,
    ) -> None:
        if workers < 1 or queue < 0:
            raise ValueError(f"workers {workers} must be >= 1 and queue {queue} >= 0")
        self.workers = workers
        self.queue = queue
        #: gets what a job wrote to publish (:meth:`run_written`)
        self.publisher = publisher
        self.memory_bytes = memory_bytes
        self._ctx = multiprocessing.get_context(context)
        if context == "forkserver":
            self._ctx.set_forkserver_preload(list(preload))
        self._slots = asyncio.Semaphore(workers)
        self._admitted = 0
        #: job processes from before their start until they are reaped
        self._running: set[BaseProcess] = set()
        self._closed = False
        #: set when the pool stops: wakes every admitted request (see :meth:`close`)
        self._stopping: asyncio.Event | None = None
        self._warm_up: asyncio.Task[None] | None = None
        #: reaping of job processes whose request was cancelled (kept from the collector)
        self._reapers: set[asyncio.Task[None]] = set()
        #: Jobs started, and the start latency of the last one (s): process up to running.
        self.started = 0
        self.last_start_s = 0.0

    @property
    def running(self) -> int:
        """Job processes started and not yet reaped."""
        return sum(_started(p) for p in self._running)

    @property
    def admitted(self) -> int:
        """Requests admitted: running, starting or waiting for a worker (a job's process
        may be gone a moment before its request is done with)."""
        return self._admitted

    async def start(self) -> None:
        """Start the forkserver and, in the background, one empty job: the forkserver
        imports :data:`PRELOAD` (about 2 s) before the first request needs it."""
        if self._ctx.get_start_method() == "forkserver":
            from multiprocessing import forkserver

            await asyncio.to_thread(forkserver.ensure_running)
        self._warm_up = asyncio.create_task(self._warm())

    async def _warm(self) -> None:
        with contextlib.suppress(Exception):
            await self.run(os.getpid, deadline_s=60.0, what="warm-up")

    @property
    def closed(self) -> bool:
        return self._closed

    def _stop_event(self) -> asyncio.Event:
        if self._stopping is None:
            self._stopping = asyncio.Event()
            if self._closed:
                self._stopping.set()
        return self._stopping

    async def close(self) -> None:
        """Refuse new jobs, answer every admitted request (waiting for a worker or running)
        as unavailable, ``shutting_down``, and kill and reap every job process. Idempotent;
        returns once the processes are gone (or :data:`_REAP_S` has passed for one that
        will not go)."""
        self._closed = True
        self._stop_event().set()
        if self._warm_up is not None:
            self._warm_up.cancel()
        for process in list(self._running):
            with contextlib.suppress(Exception):
                if process.is_alive():
                    process.kill()
        # The requests woken above reap their own; wait (bounded) until they have, then
        # reap whatever a request did not (its task gone without its cleanup). A process
        # still starting is not waited for (a first start waits for the forkserver's
        # imports): its request kills it once started, and a job ends by itself once the
        # server has ended (:func:`server.services.jobs.run_job`).
        deadline = time.monotonic() + _REAP_S
        while any(map(_started, self._running)) and time.monotonic() < deadline:
            await asyncio.sleep(0.02)
        for process in [p for p in self._running if _started(p)]:
            await _kill_and_reap(process)
            self._running.discard(process)

    async def run(
        self,
        fn: Callable[..., T],
        /,
        *args: Any,
        deadline_s: float,
        what: str,
        client: _Disconnectable | None = None,
        cleanup: Path | None = None,
        **kwargs: Any,
    ) -> T:
        """``fn(*args, **kwargs)`` in a job process (``fn`` and its arguments are pickled:
        module-level functions and plain data). ``what`` names the work in messages;
        ``client`` (the Starlette request) is watched for a disconnect; ``cleanup`` is a
        file deleted if the job fails (its result file)."""
        try:
            return await self._admit(_Job(fn, args, kwargs, deadline_s, what, client))
        except BaseException:
            if cleanup is not None:
                with contextlib.suppress(OSError):
                    cleanup.unlink()
            raise

    async def run_written(
        self, fn: Callable[..., tuple[T, Sequence[Any]]], /, *args: Any, **kwargs: Any
    ) -> T:
        """:meth:`run` of a job that commits on its own connection and returns ``(result,
        what it wrote to publish)`` (``event_log.with_written``): that is published here (the
        job's process has no publisher), the result returned."""
        result, written = await self.run(fn, *args, **kwargs)
        if self.publisher is not None:
            self.publisher.deliver(written)
        return result

    async def _admit(self, job: _Job[T]) -> T:
        what, deadline_s = job.what, job.deadline_s
        if self._closed:
            raise _stopping(what)
        if self._admitted >= self.workers + self.queue:
            raise busy(
                f"{what}: all {self.workers} workers are busy and {self.queue} requests "
                "are waiting; try again later",
                min(deadline_s, 10.0),
            )
        self._admitted += 1
        try:
            acquired = job.raced(
                await _race(
                    self._slots.acquire(),
                    deadline_s,
                    job.client,
                    lost=self._slots.release,
                    stop=self._stop_event(),
                )
            )
            if acquired is _LATE:
                raise busy(f"{what}: no worker became free within {deadline_s:g} s", 10.0)
            try:
                return await self._run(job)
            finally:
                self._slots.release()
        finally:
            self._admitted -= 1

    async def _run(self, job: _Job[T]) -> T:
        what, deadline_s = job.what, job.deadline_s
        if self._closed:
            raise _stopping(what)
        loop = asyncio.get_running_loop()
        receiver, sender = self._ctx.Pipe(duplex=False)
        process: BaseProcess = self._ctx.Process(  # type: ignore[attr-defined]
            target=run_job,
            args=(sender, self.memory_bytes, *job.call, os.getpid(), current_log_config()),
            name=f"hikoboshi-job: {what}",
            daemon=True,
        )
        t0 = time.perf_counter()
        # Known before it starts: a pool that stops while it starts kills it all the same.
        self._running.add(process)
        starting = asyncio.ensure_future(asyncio.to_thread(process.start))
        try:
            await asyncio.shield(starting)
        except BaseException:
            # Cancelled (the server stopping, the client gone) while the thread still starts
            # the process: once started, it is killed and reaped outside this request (a
            # cancelled request may not await again: anyio cancels every later await).
            sender.close()
            receiver.close()
            self._reap_later(process, starting)
            raise
        self.last_start_s = time.perf_counter() - t0
        self.started += 1
        sender.close()
        if self._closed:
            receiver.close()
            await _kill_and_reap(process)
            self._running.discard(process)
            raise _stopping(what)
        ready: asyncio.Future[None] = loop.create_future()

        def wake() -> None:
            if not ready.done():
                ready.set_result(None)

        loop.add_reader(receiver.fileno(), wake)
        loop.add_reader(process.sentinel, wake)
        outcome: Any = None
        try:
            outcome = await _race(
                asyncio.shield(ready), deadline_s, job.client, stop=self._stop_event()
            )
            loop.remove_reader(receiver.fileno())
            loop.remove_reader(process.sentinel)
            if job.raced(outcome) is _LATE:
                raise DeadlineExceededError(
                    "deadline_exceeded",
                    f"{what} did not finish within {deadline_s:g} s and was stopped",
                    {"deadline_s": deadline_s},
                )
            try:
                if not receiver.poll():
                    raise EOFError
                message = await asyncio.to_thread(receiver.recv)
            except (EOFError, OSError):
                await asyncio.to_thread(process.join, _REAP_S)
                raise _crashed(what, process.exitcode) from None
        finally:
            with contextlib.suppress(Exception):
                loop.remove_reader(receiver.fileno())
                loop.remove_reader(process.sentinel)
            receiver.close()
            try:
                await _kill_and_reap(process)  # killed before its first await
            except BaseException:
                self._reap_later(process)  # cancelled while reaping: reaped all the same
                raise
            self._running.discard(process)
        kind, value = message
        if kind == "ok":
            result: T = value
            return result
        error: BaseException = value
        if isinstance(error, DomainError) and error.code == "out_of_memory":
            limit = f"{self.memory_bytes / 2**30:.3g} GiB" if self.memory_bytes else "the limit"
            raise busy(f"{what} needs more than {limit} of memory", 10.0, "out_of_memory")
        raise error

    def _reap_later(
        self, process: BaseProcess, starting: asyncio.Future[Any] | None = None
    ) -> None:
        """Kill and reap ``process`` (once ``starting`` is done) in a task of its own, and
        only then forget it: :attr:`running` and :meth:`close` count it until then."""

        async def reap() -> None:
            if starting is not None:
                with contextlib.suppress(BaseException):
                    await starting
            try:
                await _kill_and_reap(process)
            finally:
                self._running.discard(process)

        task = asyncio.ensure_future(reap())
        self._reapers.add(task)
        task.add_done_callback(self._reapers.discard)


_GONE = object()
_LATE = object()
_STOPPED = object()


@dataclass(frozen=True)
class _Job(Generic[T]):
    """A request's ``fn(*args, **kwargs)``, named ``what``; its client watched (:meth:`run`)."""

    fn: Callable[..., T]
    args: tuple[Any, ...]
    kwargs: dict[str, Any]
    deadline_s: float
    what: str
    client: _Disconnectable | None

    @property
    def call(self) -> tuple[Callable[..., T], tuple[Any, ...], dict[str, Any]]:
        return self.fn, self.args, self.kwargs

    def raced(self, outcome: Any) -> Any:
        """:func:`_race`'s outcome, or the refusal it is: the pool stopping, the client gone."""
        if outcome is _STOPPED:
            raise _stopping(self.what)
        if outcome is _GONE:
            raise _client_gone(self.what)
        return outcome


async def _race(
    awaitable: Any,
    timeout_s: float,
    request: _Disconnectable | None,
    lost: Callable[[], None] | None = None,
    stop: asyncio.Event | None = None,
) -> Any:
    """``awaitable``'s result, or :data:`_LATE` after ``timeout_s``, or :data:`_GONE` once
    ``request``'s client has disconnected, or :data:`_STOPPED` once ``stop`` is set; the
    awaitable is cancelled if it lost (and ``lost()`` called if it had completed all the
    same)."""
    task = asyncio.ensure_future(awaitable)
    stopped = asyncio.ensure_future(stop.wait()) if stop is not None else None
    deadline = time.monotonic() + timeout_s
    won = False
    try:
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return _LATE
            waiting = {task} if stopped is None else {task, stopped}
            done, _ = await asyncio.wait(
                waiting, timeout=min(POLL_S, left), return_when=asyncio.FIRST_COMPLETED
            )
            if stopped is not None and stopped in done:
                return _STOPPED
            if task in done:
                won = True
                return task.result()
            if request is not None and await request.is_disconnected():
                return _GONE
    finally:
        if stopped is not None and not stopped.done():
            stopped.cancel()
        if not task.done():
            task.cancel()
            with contextlib.suppress(BaseException):
                await task
        finished = task.done() and not task.cancelled() and task.exception() is None
        if not won and lost is not None and finished:
            lost()


def _client_gone(what: str) -> ClientGoneError:
    # Nobody reads this answer; it ends the request.
    return ClientGoneError("client_closed", f"{what}: the client went away; the job was stopped")


#: How long a client refused because the service is stopping is told to wait (s): about a
#: restart of ``hikoboshi serve``.
STOPPING_RETRY_AFTER_S = 10.0


def _stopping(what: str) -> UnavailableError:
    return busy(
        f"{what}: the service is shutting down; the work was stopped, try again after it restarts",
        STOPPING_RETRY_AFTER_S,
        "shutting_down",
    )


def _crashed(what: str, exitcode: int | None) -> UnavailableError:
    how = f"signal {-exitcode}" if exitcode is not None and exitcode < 0 else f"exit {exitcode}"
    return busy(
        f"{what}: the worker process ended without an answer ({how})", 5.0, "worker_crashed"
    )


def _started(process: BaseProcess) -> bool:
    try:
        return process.pid is not None
    except ValueError:  # closed: started, and reaped
        return False


async def _kill_and_reap(process: BaseProcess) -> None:
    """Kill ``process`` if it runs, and reap it (a process never started: nothing)."""
    with contextlib.suppress(Exception):
        if process.is_alive():
            process.kill()
    await _reap(process)


async def _reap(process: BaseProcess) -> None:
    with contextlib.suppress(Exception):
        await asyncio.to_thread(process.join, _REAP_S)
    with contextlib.suppress(ValueError):  # closed already
        if process.exitcode is not None:
            process.close()
