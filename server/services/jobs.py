"""The worker job's side of :mod:`server.services.workers`: what runs in the job process,
and the jobs the routes give it.

:func:`run_job` (the process's target) lowers its CPU priority, limits its address space,
runs the function and sends back ``("ok", result)`` or ``("error", exc)``: a service's
refusal (:mod:`server.services.errors`) or a storage error as raised, a planner error as
the invalid request it is (its type's name as the code), running out of memory as
``out_of_memory`` and anything else as a failed job (its traceback printed to the job's
stderr). The API answers these as it would have in-process (:mod:`server.api.errors`).

:func:`session_job`, :func:`read_session_job` and :func:`read_session_file_job` run a
service function on the job's own database connection; a large result goes to a temporary
file (:func:`temporary_path`) that the route streams (:func:`stream_file`) and deletes.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import resource
import select
import signal
import tempfile
import threading
import time
import traceback
from collections.abc import Callable, Iterator
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any, TypeVar

from server.logs import configure_logging
from server.services.errors import InvalidRequestError, JobFailedError, UnavailableError

__all__ = [
    "JOB_NICENESS",
    "jobs_dir",
    "read_session_file_job",
    "read_session_job",
    "run_job",
    "session_job",
    "stream_file",
    "temporary_path",
]

T = TypeVar("T")

#: How much lower a job's CPU priority is than the server's (``nice``).
JOB_NICENESS = 10


def _sendable(exc: BaseException) -> BaseException:
    """What the server is sent for ``exc`` raised in a job (see the module doc)."""
    from planner.errors import PlannerError
    from server.services.errors import DomainError
    from server.storage.errors import StorageError

    if isinstance(exc, DomainError | StorageError):
        return exc
    if isinstance(exc, PlannerError):
        # Its own class may not unpickle (JointLimitExceeded takes the values, not the text).
        return InvalidRequestError(type(exc).__name__, str(exc))
    if isinstance(exc, MemoryError):
        return UnavailableError(
            "the request needs more memory than one job may use", 10.0, "out_of_memory"
        )
    traceback.print_exception(exc)
    return JobFailedError("worker_failed", f"the job failed: {type(exc).__name__}: {exc}")


#: How often a job whose platform has no pidfd checks that the server is still there (s).
_WATCH_POLL_S = 1.0


def _end_with_server(server_pid: int | None) -> None:
    """End this job (SIGKILL itself) as soon as the server process ``server_pid`` has
    ended, however it ended: a daemon thread waits on a pidfd of the server (Linux), else
    polls. The pool kills and reaps its jobs when it stops; this is for a server killed
    without its shutdown, or one that ended while a job's start was under way, whose job
    would otherwise run on (and keep the pool's forkserver alive: it ends when its last
    client has) (docs/operations.md "Stopping with requests in flight")."""
    if server_pid is None:
        return
    try:
        pidfd: int | None = os.pidfd_open(server_pid)
    except (AttributeError, OSError):  # no pidfd here, or the server is gone already
        pidfd = None
        if not _alive(server_pid):
            os.kill(os.getpid(), signal.SIGKILL)

    def watch() -> None:
        if pidfd is not None:
            select.select([pidfd], [], [])  # readable once the server has ended
        else:
            while _alive(server_pid):
                time.sleep(_WATCH_POLL_S)
        os.kill(os.getpid(), signal.SIGKILL)

    threading.Thread(target=watch, name="hikoboshi-job-watch", daemon=True).start()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def run_job(
    conn: Connection,
    memory_bytes: int | None,
    fn: Callable[..., Any],
    args: tuple[Any, ...],
    kwargs: dict[str, Any],
    server_pid: int | None = None,
    log_config: tuple[str, str] | None = None,
) -> None:
    """The job process: end with the server (``server_pid``), log as the server does
    (``log_config``: :func:`server.logs.current_log_config`), lower its CPU priority,
    limit the address space, run ``fn``, send ``("ok", result)`` or ``("error", exc)`` (see
    the module doc)."""
    _end_with_server(server_pid)
    if log_config is not None:
        configure_logging(*log_config)
    # Below the server and the link: on a machine with few cores a download or a plan must
    # take the CPU the live pass leaves, not share it evenly (at equal priority two jobs
    # made an operator's abort wait seconds for the link's database worker).
    os.nice(JOB_NICENESS)
    if memory_bytes:
        resource.setrlimit(resource.RLIMIT_AS, (memory_bytes, memory_bytes))
    try:
        message: tuple[str, Any] = ("ok", fn(*args, **kwargs))
    except BaseException as exc:  # every failure goes back to the server
        message = ("error", _sendable(exc))
    try:
        conn.send(message)
    except MemoryError:
        conn.send(("error", _sendable(MemoryError())))
    except pickle.PicklingError as exc:  # a result or a detail that does not pickle
        conn.send(("error", _sendable(exc)))
    except (BrokenPipeError, ConnectionResetError):
        # The server stopped waiting (it closed the pool: shutting down): no one to tell,
        # and no traceback on its log (a JSON log takes one object a line).
        pass
    finally:
        conn.close()


def _on_own_engine(url: str, read_only: bool, fn: Callable[..., T], kwargs: dict[str, Any]) -> T:
    from server.storage.db import make_engine, read_session_factory, session_factory

    engine = make_engine(url)
    factory = read_session_factory if read_only else session_factory
    try:
        with factory(engine)() as session:
            return fn(session=session, **kwargs)
    finally:
        engine.dispose()


def session_job(url: str, fn: Callable[..., T], /, **kwargs: Any) -> T:
    """Run ``fn(session=..., **kwargs)`` on a session of a new engine for ``url`` (the job's
    own connection: nothing shared with the server's pool)."""
    return _on_own_engine(url, False, fn, kwargs)


def read_session_job(url: str, fn: Callable[..., T], /, **kwargs: Any) -> T:
    """:func:`session_job` with a read-only session (as the API gives GET requests)."""
    return _on_own_engine(url, True, fn, kwargs)


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
