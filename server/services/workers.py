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
  is answered at once with 503 ``busy`` and ``Retry-After``.
- Each job has a deadline (``plan_deadline_s``, ``read_deadline_s``), counted from when it
  starts; past it the process is killed and the client gets 504 ``deadline_exceeded``.
  Waiting for a free worker is bounded by the same deadline (then 503 ``busy``).
- A job whose client disconnects is killed at once (polled every :data:`POLL_S`).
- A job's address space is limited (``worker_memory_bytes``, ``RLIMIT_AS``): a job that
  exceeds it fails with 503 ``out_of_memory``; one killed by a signal with 503
  ``worker_crashed``. Either way the next request gets a fresh process.
- Closing the pool (the app's lifespan) kills running jobs.

Errors raised by a job keep their meaning: a :class:`~server.errors.ServiceError`, a planner
error (422 with its type name) or a storage error (404/409/400) reach the client as they
would have in-process, through :class:`~server.errors.ServiceError`.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import multiprocessing
import os
import resource
import tempfile
import time
import traceback
from collections.abc import Callable, Coroutine, Iterator
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
from pathlib import Path
from typing import Annotated, Any, Protocol, TypeVar

from fastapi import Depends, Request, Response
from fastapi.responses import JSONResponse
from fastapi.routing import APIRoute

from server.errors import ServiceError, error_body

__all__ = [
    "POLL_S",
    "PRELOAD",
    "BoundedRoute",
    "Busy",
    "WorkerPool",
    "WorkersDep",
    "jobs_dir",
    "read_session_file_job",
    "read_session_job",
    "session_job",
    "stream_file",
    "temporary_path",
]

log = logging.getLogger("hikoboshi.ground.workers")

T = TypeVar("T")

#: How much lower a job's CPU priority is than the server's (``nice``).
JOB_NICENESS = 10

#: Modules the forkserver imports once, so that a job needs no imports of its own.
PRELOAD = (
    "numpy",
    "scipy.spatial.transform",
    "sqlalchemy",
    "planner.catalogue",
    "server.services.plans",
    "server.services.recordings",
    "server.services.reports",
    "server.services.telemetry",
    "server.storage.db",
    "server.services.workers",
    "telemetry.mcap",
    "hikoboshi.cli",
)

#: How often a waiting request checks whether its client is still there (s).
POLL_S = 0.2
#: How long a killed process may take to be reaped before it is left to the OS (s).
_REAP_S = 5.0


class _Disconnectable(Protocol):
    async def is_disconnected(self) -> bool: ...


class Busy(ServiceError):
    """503: the work cannot be done now; the answer carries ``Retry-After`` (see
    :class:`BoundedRoute`)."""

    def __init__(self, message: str, retry_after_s: float, code: str = "busy") -> None:
        super().__init__(503, code, message, {"retry_after_s": retry_after_s})
        self.retry_after_s = retry_after_s


def busy(message: str, retry_after_s: float, code: str = "busy") -> Busy:
    return Busy(message, retry_after_s, code)


class BoundedRoute(APIRoute):
    """A route whose :class:`Busy` refusals carry ``Retry-After`` (the app's error handler
    knows no headers): ``APIRouter(route_class=BoundedRoute)``."""

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = super().get_route_handler()

        async def bounded(request: Request) -> Response:
            try:
                return await handler(request)
            except Busy as exc:
                return JSONResponse(
                    status_code=exc.status,
                    content=error_body(exc.code, exc.message, exc.detail),
                    headers={"Retry-After": str(max(1, math.ceil(exc.retry_after_s)))},
                )

        return bounded


# ---------------------------------------------------------------------------------------
# The child's side


def _describe(exc: BaseException) -> tuple[int, str, str, Any]:
    """``(status, code, message, detail)`` for an exception raised in a job, as the
    server's error handlers would answer it in-process."""
    from planner.errors import PlannerError
    from server.storage.errors import Conflict, InvalidArgument, NotFound

    if isinstance(exc, ServiceError):
        return exc.status, exc.code, exc.message, exc.detail
    if isinstance(exc, PlannerError):
        return 422, type(exc).__name__, str(exc), None
    if isinstance(exc, NotFound):
        return 404, "not_found", str(exc), None
    if isinstance(exc, Conflict):
        return 409, "conflict", str(exc), None
    if isinstance(exc, InvalidArgument):
        return 400, "invalid_argument", str(exc), None
    if isinstance(exc, MemoryError):
        return 503, "out_of_memory", "the request needs more memory than one job may use", None
    traceback.print_exception(exc)
    return 500, "worker_failed", f"the job failed: {type(exc).__name__}: {exc}", None


def _child(
    conn: Connection,
    memory_bytes: int | None,
    fn: Callable[..., Any],
    args: tuple[Any, ...],
    kwargs: dict[str, Any],
) -> None:
    """The job process: lower its CPU priority, limit the address space, run ``fn``, send
    ``("ok", result)`` or ``("error", (status, code, message, detail))``."""
    # Below the server and the link: on a machine with few cores a download or a plan must
    # take the CPU the live pass leaves, not share it evenly (at equal priority two jobs
    # made an operator's abort wait seconds for the link's database worker).
    os.nice(JOB_NICENESS)
    if memory_bytes:
        resource.setrlimit(resource.RLIMIT_AS, (memory_bytes, memory_bytes))
    try:
        message: tuple[str, Any] = ("ok", fn(*args, **kwargs))
    except BaseException as exc:  # every failure goes back to the server
        message = ("error", _describe(exc))
    try:
        conn.send(message)
    except MemoryError:
        conn.send(("error", _describe(MemoryError())))
    finally:
        conn.close()


def session_job(url: str, fn: Callable[..., T], /, **kwargs: Any) -> T:
    """Run ``fn(session=..., **kwargs)`` on a session of a new engine for ``url`` (the job's
    own connection: nothing shared with the server's pool)."""
    from server.storage.db import make_engine, session_factory

    engine = make_engine(url)
    try:
        with session_factory(engine)() as session:
            return fn(session=session, **kwargs)
    finally:
        engine.dispose()


def read_session_job(url: str, fn: Callable[..., T], /, **kwargs: Any) -> T:
    """:func:`session_job` with a read-only session (as the API gives GET requests)."""
    from server.storage.db import make_engine, read_session_factory

    engine = make_engine(url)
    try:
        with read_session_factory(engine)() as session:
            return fn(session=session, **kwargs)
    finally:
        engine.dispose()


def read_session_file_job(
    url: str, path: str, fn: Callable[..., str | bytes], /, **kwargs: Any
) -> int:
    """:func:`read_session_job`, whose result (text as UTF-8, or bytes) is written to the
    file ``path``; its size in bytes."""
    result = read_session_job(url, fn, **kwargs)
    data = result.encode("utf-8") if isinstance(result, str) else result
    with open(path, "wb") as stream:
        stream.write(data)
    return len(data)


# ---------------------------------------------------------------------------------------
# Temporary files: a job writes its large result there, the route streams and deletes it


def jobs_dir(data_dir: Path) -> Path:
    """Where jobs write their result files: ``DATA_DIR/jobs``."""
    return Path(data_dir) / "jobs"


def temporary_path(directory: Path | None, suffix: str) -> Path:
    """A new, empty file for a job's result, under ``directory`` (created) or the system's
    temporary directory."""
    if directory is not None:
        directory.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix="hikoboshi-job-", suffix=suffix, dir=directory)
    os.close(fd)
    return Path(name)


def stream_file(path: Path, chunk_bytes: int = 1 << 20) -> tuple[Iterator[bytes], int]:
    """An iterator over the file's bytes and its size. The file is opened and deleted at
    once (the open descriptor keeps the data until the iterator is done or dropped), so no
    file is left behind whatever happens to the response."""
    handle = path.open("rb")
    with contextlib.suppress(FileNotFoundError):
        path.unlink()
    size = os.fstat(handle.fileno()).st_size

    def chunks() -> Iterator[bytes]:
        with handle:
            while chunk := handle.read(chunk_bytes):
                yield chunk

    return chunks(), size


# ---------------------------------------------------------------------------------------
# The server's side


def get_workers(request: Request) -> WorkerPool:
    workers: WorkerPool = request.app.state.workers
    return workers


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
    ) -> None:
        if workers < 1 or queue < 0:
            raise ValueError(f"workers {workers} must be >= 1 and queue {queue} >= 0")
        self.workers = workers
        self.queue = queue
        self.memory_bytes = memory_bytes
        self._ctx = multiprocessing.get_context(context)
        if context == "forkserver":
            self._ctx.set_forkserver_preload(list(preload))
        self._slots = asyncio.Semaphore(workers)
        self._admitted = 0
        self._running: set[BaseProcess] = set()
        self._closed = False
        self._warm_up: asyncio.Task[None] | None = None
        #: Jobs started, and the start latency of the last one (s): process up to running.
        self.started = 0
        self.last_start_s = 0.0

    @property
    def running(self) -> int:
        return len(self._running)

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

    async def close(self) -> None:
        """Refuse new jobs and kill the running ones."""
        self._closed = True
        if self._warm_up is not None:
            self._warm_up.cancel()
        for process in list(self._running):
            with contextlib.suppress(Exception):
                process.kill()

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
            return await self._admit(fn, args, kwargs, deadline_s, what, client)
        except BaseException:
            if cleanup is not None:
                with contextlib.suppress(OSError):
                    cleanup.unlink()
            raise

    async def _admit(
        self,
        fn: Callable[..., T],
        args: tuple[Any, ...],
        kwargs: dict[str, Any],
        deadline_s: float,
        what: str,
        request: _Disconnectable | None,
    ) -> T:
        if self._closed:
            raise busy(f"{what}: the service is stopping", 5.0)
        if self._admitted >= self.workers + self.queue:
            raise busy(
                f"{what}: all {self.workers} workers are busy and {self.queue} requests "
                "are waiting; try again later",
                min(deadline_s, 10.0),
            )
        self._admitted += 1
        try:
            acquired = await _race(
                self._slots.acquire(), deadline_s, request, lost=self._slots.release
            )
            if acquired is _GONE:
                raise _client_gone(what)
            if acquired is _LATE:
                raise busy(f"{what}: no worker became free within {deadline_s:g} s", 10.0)
            try:
                return await self._run(fn, args, kwargs, deadline_s, what, request)
            finally:
                self._slots.release()
        finally:
            self._admitted -= 1

    async def _run(
        self,
        fn: Callable[..., T],
        args: tuple[Any, ...],
        kwargs: dict[str, Any],
        deadline_s: float,
        what: str,
        request: _Disconnectable | None,
    ) -> T:
        if self._closed:
            raise busy(f"{what}: the service is stopping", 5.0)
        loop = asyncio.get_running_loop()
        receiver, sender = self._ctx.Pipe(duplex=False)
        process: BaseProcess = self._ctx.Process(  # type: ignore[attr-defined]
            target=_child,
            args=(sender, self.memory_bytes, fn, args, kwargs),
            name=f"hikoboshi-job: {what}",
            daemon=True,
        )
        t0 = time.perf_counter()
        try:
            await asyncio.to_thread(process.start)
        except BaseException:
            sender.close()
            receiver.close()
            raise
        self.last_start_s = time.perf_counter() - t0
        self.started += 1
        sender.close()
        self._running.add(process)
        ready: asyncio.Future[None] = loop.create_future()

        def wake() -> None:
            if not ready.done():
                ready.set_result(None)

        loop.add_reader(receiver.fileno(), wake)
        loop.add_reader(process.sentinel, wake)
        outcome: Any = None
        try:
            outcome = await _race(asyncio.shield(ready), deadline_s, request)
            loop.remove_reader(receiver.fileno())
            loop.remove_reader(process.sentinel)
            if outcome is _GONE:
                raise _client_gone(what)
            if outcome is _LATE:
                raise ServiceError(
                    504,
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
            self._running.discard(process)
            if process.is_alive():
                process.kill()
            await _reap(process)
        kind, value = message
        if kind == "ok":
            result: T = value
            return result
        status, code, text, detail = value
        if code == "out_of_memory":
            limit = f"{self.memory_bytes / 2**30:.3g} GiB" if self.memory_bytes else "the limit"
            raise busy(f"{what} needs more than {limit} of memory", 10.0, "out_of_memory")
        raise ServiceError(status, code, text, detail)


_GONE = object()
_LATE = object()


WorkersDep = Annotated[WorkerPool, Depends(get_workers)]


async def _race(
    awaitable: Any,
    timeout_s: float,
    request: _Disconnectable | None,
    lost: Callable[[], None] | None = None,
) -> Any:
    """``awaitable``'s result, or :data:`_LATE` after ``timeout_s``, or :data:`_GONE` once
    ``request``'s client has disconnected; the awaitable is cancelled if it lost (and
    ``lost()`` called if it had completed all the same)."""
    task = asyncio.ensure_future(awaitable)
    deadline = time.monotonic() + timeout_s
    won = False
    try:
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return _LATE
            done, _ = await asyncio.wait({task}, timeout=min(POLL_S, left))
            if done:
                won = True
                return task.result()
            if request is not None and await request.is_disconnected():
                return _GONE
    finally:
        if not task.done():
            task.cancel()
            with contextlib.suppress(BaseException):
                await task
        finished = task.done() and not task.cancelled() and task.exception() is None
        if not won and lost is not None and finished:
            lost()


def _client_gone(what: str) -> ServiceError:
    # Nobody reads this answer; it ends the request (499 as nginx names it).
    return ServiceError(499, "client_closed", f"{what}: the client went away; the job was stopped")


def _crashed(what: str, exitcode: int | None) -> Busy:
    how = f"signal {-exitcode}" if exitcode is not None and exitcode < 0 else f"exit {exitcode}"
    return busy(
        f"{what}: the worker process ended without an answer ({how})", 5.0, "worker_crashed"
    )


async def _reap(process: BaseProcess) -> None:
    with contextlib.suppress(Exception):
        await asyncio.to_thread(process.join, _REAP_S)
    if process.exitcode is not None:
        with contextlib.suppress(ValueError):
            process.close()
