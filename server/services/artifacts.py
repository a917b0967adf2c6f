"""A pass's heavy artifacts (its MCAP recording, its report as JSON and as one HTML page,
the report's figures) computed once per content version and served from files.

Why: every viewer's download of these used to be a worker job of its own (seconds of
database reads and encoding each); 200 viewers during a pass kept both workers busy and
the server's memory at 1.1 GB, for the same bytes over and over.

How (docs/security.md "Artifacts"):

- **Version.** Before anything is computed, a few cheap aggregate queries
  (:mod:`server.storage.fingerprints`, where the argument for their sufficiency is) give
  the artifact's *content version*: a hash of what its worker function reads.
  The recording: the pass row's version, its frames (count, last seq), commands (counts
  and last times per stage), events (count, last id), its alarms' documents, and the
  robot description files (path, size, mtime). The report (JSON, HTML): the pass row's
  version, its analyses (count, last id), its ``pass_imported`` events and its alarms.
  A figure: the figure rows (count, last id). The version is the ETag.
- **Store.** A computed artifact is written by the job to a temporary file under
  ``data_dir/artifacts/<pass_id>/`` and renamed to ``<kind>-<version>.<ext>``: a file of
  that name is always whole. Storing a version deletes the artifact's older one; past
  ``artifact_cache_bytes`` in all, the least recently served are deleted. The directory
  is emptied when the service starts: a stored file is only as good as the code that
  wrote it.
- **Single flight.** Requests for a version being computed wait for that one job; the
  job is not tied to any one request (the last waiter leaving stops it). A failed job is
  not stored: its error goes to every waiter and the next request tries again. Each
  waiter gets its own open handle on the file when the job is done, so a file deleted
  later (evicted, superseded) still streams whole to those already reading it.
- **Live passes.** A pass not yet ended changes as frames arrive, so its recording's
  version changes every few frames; a request for it joins the computation in flight for
  the same artifact whatever its version (the answer is then a snapshot at most one job
  older than the request, and carries that snapshot's ETag), so at most one job per
  artifact runs however many viewers ask.
- Version queries of one pass are coalesced: one runs at a time, and the requests that
  arrive during it share the next (never the one in flight: a version read before a
  request arrived could miss a write the requester already saw).
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import itertools
import json
import os
import shutil
import weakref
from collections import OrderedDict
from collections.abc import Awaitable, Callable, Hashable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, Generic, Literal, Protocol, TypeVar

from sqlalchemy.orm import Session, sessionmaker

from server.services import analyses, recordings, reports
from server.services.errors import ClientGoneError
from server.services.jobs import read_session_file_job, read_session_job, temporary_path
from server.services.workers import POLL_S, WorkerPool
from server.storage import fingerprints

__all__ = [
    "FINISHED_STATES",
    "ArtifactRef",
    "ArtifactStore",
    "Served",
    "Version",
    "content_version",
]

Kind = Literal["recording", "report", "report_html", "figure"]
#: A pass in one of these has ended: its artifacts change only after the pass (analyses
#: run again, a late acknowledgement, an alarm acknowledged), each time with a new version.
FINISHED_STATES = ("complete", "aborted", "safed")
_SUFFIX: dict[Kind, str] = {
    "recording": ".mcap",
    "report": ".json",
    "report_html": ".html",
    "figure": ".png",
}
_WHAT: dict[Kind, str] = {
    "recording": "the recording of pass {}",
    "report": "the report of pass {}",
    "report_html": "the report page of pass {}",
    "figure": "a figure of pass {}",
}

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")


class _Disconnectable(Protocol):
    async def is_disconnected(self) -> bool: ...


@dataclass(frozen=True)
class ArtifactRef:
    """Which artifact: its kind, the pass (as asked) and, for a figure, its name."""

    kind: Kind
    pass_id: str
    figure: str = ""


@dataclass(frozen=True)
class Version:
    """The content version of an artifact: the pass's canonical id, the key (the ETag)
    and whether the pass is still live (not in :data:`FINISHED_STATES`)."""

    pass_id: str
    key: str
    live: bool


@dataclass
class Served:
    """An artifact to send: an open handle on its file (the caller's to read and close),
    its size, its version and its label (a recording's pass name)."""

    handle: BinaryIO
    size: int
    version: str
    label: str

    def chunks(self, chunk_bytes: int = 256 * 1024) -> Iterator[bytes]:
        """The file's bytes; the handle is closed at its end, and also if the response
        never reads it to the end or never starts (a client gone before its first byte)."""
        return _Chunks(self.handle, chunk_bytes)


class _Chunks:
    """An open file as chunks, closed at its end or when the iterator is dropped (a
    generator that never started would leave its file for the garbage collector)."""

    def __init__(self, handle: BinaryIO, chunk_bytes: int) -> None:
        self._handle = handle
        self._chunk_bytes = chunk_bytes
        weakref.finalize(self, handle.close)

    def __iter__(self) -> _Chunks:
        return self

    def __next__(self) -> bytes:
        chunk = self._handle.read(self._chunk_bytes) if not self._handle.closed else b""
        if not chunk:
            self._handle.close()
            raise StopIteration
        return chunk


@dataclass
class _Entry:
    slot: tuple[str, Kind, str]
    version: str
    path: Path
    size: int
    label: str
    serial: int


@dataclass
class _Flight:
    slot: tuple[str, Kind, str]
    version: str
    serial: int
    task: asyncio.Task[_Entry] | None = None
    waiters: int = 0
    handles: list[BinaryIO] = field(default_factory=list)


class _Rounds(Generic[K, V]):
    """``fn(key)`` shared by concurrent callers: one run per key at a time; a caller gets
    the result of a run that started after it asked (those who ask during a run share the
    next one)."""

    def __init__(self, fn: Callable[[K], Awaitable[V]]) -> None:
        self._fn = fn
        self._running: dict[K, asyncio.Future[V]] = {}
        self._next: dict[K, asyncio.Future[V]] = {}

    async def __call__(self, key: K) -> V:
        future = self._next.get(key)
        if future is None:
            if key in self._running:
                future = self._next[key] = asyncio.get_running_loop().create_future()
            else:
                future = self._launch(key)
        return await asyncio.shield(future)

    def _launch(self, key: K) -> asyncio.Future[V]:
        task = asyncio.ensure_future(self._fn(key))
        self._running[key] = task
        task.add_done_callback(lambda done: self._done(key, done))
        return task

    def _done(self, key: K, task: asyncio.Future[V]) -> None:
        del self._running[key]
        if not task.cancelled():
            task.exception()  # retrieved: the callers have it
        waiting = self._next.pop(key, None)
        if waiting is not None:
            self._launch(key).add_done_callback(lambda done: _copy(done, waiting))


def _copy(source: asyncio.Future[V], target: asyncio.Future[V]) -> None:
    if target.done():
        return
    if source.cancelled():
        target.cancel()
    elif (error := source.exception()) is not None:
        target.set_exception(error)
    else:
        target.set_result(source.result())


def _unlink(path: Path) -> None:
    with contextlib.suppress(OSError):
        path.unlink()
    with contextlib.suppress(OSError):
        path.parent.rmdir()  # the pass's directory, once empty


def _file_stats(paths: tuple[str, ...]) -> list[Any]:
    out: list[Any] = []
    for name in paths:
        try:
            stat = os.stat(name)
        except OSError:
            out.append([name, None])
        else:
            out.append([name, stat.st_size, stat.st_mtime_ns])
    return out


def content_version(
    session: Session, kind: Kind, pass_id: str, robot_files: tuple[str, ...] = ()
) -> Version:
    """The version of the ``kind`` artifact of the pass (see the module doc). Refuses as
    the worker function would where the answer is plain from the version's own reads:
    an unknown pass (``NotFound``), a recording of a pass not flown, a report before the
    analyses ran."""
    record = fingerprints.pass_row(session, pass_id)
    key = record.id
    parts: list[Any] = [kind, key]
    if kind == "recording":
        if record.epoch_ns is None:
            raise recordings.not_flown(record.name, record.state)
        parts += [
            record.version,
            fingerprints.frames_summary(session, key),
            fingerprints.commands_summary(session, key),
            fingerprints.events_summary(session, key),
            fingerprints.alarms_digest(session, key),
            _file_stats(robot_files),
        ]
    elif kind == "figure":
        parts.append(fingerprints.analyses_summary(session, key, analyses.FIGURES_KIND))
    else:
        runs = fingerprints.analyses_summary(session, key)
        if runs[0] == 0:
            raise reports.analyses_not_run(key)
        parts += [
            record.version,
            runs,
            fingerprints.events_summary(session, key, "pass_imported"),
            fingerprints.alarms_digest(session, key),
        ]
    digest = hashlib.sha256(json.dumps(parts).encode("utf-8")).hexdigest()[:32]
    return Version(pass_id=key, key=digest, live=record.state not in FINISHED_STATES)


class ArtifactStore:
    """The artifacts of every pass, under ``root`` (``data_dir/artifacts``), at most
    ``max_bytes`` in all, computed by ``workers`` on the database ``url``; versions are
    read on ``sessions`` (the readers' pool) in a thread."""

    def __init__(
        self,
        *,
        root: Path,
        max_bytes: int,
        sessions: sessionmaker[Session],
        workers: WorkerPool,
        url: str,
        deadline_s: float,
        robot_files: tuple[str, ...] = (),
    ) -> None:
        self._root = Path(root)
        self._max_bytes = max_bytes
        self._sessions = sessions
        self._workers = workers
        self._url = url
        self._deadline_s = deadline_s
        self._robot_files = robot_files
        self._index: OrderedDict[tuple[str, Kind, str], _Entry] = OrderedDict()
        self._flights: dict[tuple[str, Kind, str], dict[str, _Flight]] = {}
        self._serials = itertools.count(1)
        self._rounds: _Rounds[tuple[Kind, str], Version] = _Rounds(self._read_version)
        #: Bytes of the stored files; artifacts computed (jobs that succeeded).
        self.stored_bytes = 0
        self.computed = 0

    def start(self) -> None:
        """Empty the store's directory (what an earlier run left)."""
        shutil.rmtree(self._root, ignore_errors=True)
        self._root.mkdir(parents=True, exist_ok=True)

    async def close(self) -> None:
        """Stop the computations in flight (their jobs are killed)."""
        tasks = [f.task for fs in self._flights.values() for f in fs.values() if f.task]
        self._flights.clear()
        for task in tasks:
            task.cancel()
        for task in tasks:
            with contextlib.suppress(BaseException):
                await task

    @property
    def waiting(self) -> int:
        """Requests waiting for a computation in flight."""
        return sum(f.waiters for fs in self._flights.values() for f in fs.values())

    def stored(self) -> list[Path]:
        """The stored files, least recently served first."""
        return [entry.path for entry in self._index.values()]

    async def version(self, ref: ArtifactRef) -> Version:
        """The artifact's current content version (see the module doc)."""
        return await self._rounds((ref.kind, ref.pass_id))

    async def _read_version(self, key: tuple[Kind, str]) -> Version:
        kind, pass_id = key

        def read() -> Version:
            with self._sessions() as session:
                return content_version(session, kind, pass_id, self._robot_files)

        return await asyncio.to_thread(read)

    async def fetch(
        self, ref: ArtifactRef, version: Version, *, client: _Disconnectable | None = None
    ) -> Served:
        """The artifact at ``version``: the stored file, or the one job computing it (see
        the module doc); the job's error as it is. ``client`` (the request) is watched: a
        waiter whose client left stops waiting (``client_closed``)."""
        slot = (version.pass_id, ref.kind, ref.figure)
        entry = self._index.get(slot)
        if entry is not None and entry.version == version.key:
            try:
                handle = entry.path.open("rb")
            except OSError:  # gone from under us: computed again
                self._drop(slot)
            else:
                self._index.move_to_end(slot)
                return Served(handle, entry.size, entry.version, entry.label)
        return await self._join(self._flight(slot, ref, version), ref, client)

    def _flight(self, slot: tuple[str, Kind, str], ref: ArtifactRef, version: Version) -> _Flight:
        flights = self._flights.setdefault(slot, {})
        flight = flights.get(version.key)
        if flight is None and version.live and flights:
            flight = max(flights.values(), key=lambda f: f.serial)
        if flight is None:
            flight = _Flight(slot, version.key, next(self._serials))
            flight.task = asyncio.create_task(self._compute(ref, version, flight))
            flight.task.add_done_callback(_retrieve)
            flights[version.key] = flight
        return flight

    def _forget(self, flight: _Flight) -> None:
        flights = self._flights.get(flight.slot, {})
        if flights.get(flight.version) is flight:
            del flights[flight.version]
        if not flights:
            self._flights.pop(flight.slot, None)

    async def _join(
        self, flight: _Flight, ref: ArtifactRef, client: _Disconnectable | None
    ) -> Served:
        task = flight.task
        assert task is not None
        flight.waiters += 1
        served: Served | None = None
        try:
            while not task.done():
                await asyncio.wait({task}, timeout=POLL_S)
                if not task.done() and client is not None and await client.is_disconnected():
                    what = _WHAT[ref.kind].format(ref.pass_id)
                    raise ClientGoneError("client_closed", f"{what}: the client went away")
            entry = task.result()
            served = Served(flight.handles.pop(), entry.size, entry.version, entry.label)
            return served
        finally:
            if served is None:
                if not task.done():
                    flight.waiters -= 1
                    if flight.waiters == 0:  # nobody wants it any more: stop the job
                        self._forget(flight)
                        task.cancel()
                elif flight.handles:
                    flight.handles.pop().close()

    async def _compute(self, ref: ArtifactRef, version: Version, flight: _Flight) -> _Entry:
        directory = self._root / version.pass_id
        directory.mkdir(parents=True, exist_ok=True)
        temporary = temporary_path(directory, ".part")
        try:
            label = await self._run_job(ref, version.pass_id, temporary)
            stem = ref.kind if not ref.figure else f"figure-{_name_hash(ref.figure)}"
            path = directory / f"{stem}-{version.key}{_SUFFIX[ref.kind]}"
            os.replace(temporary, path)
        except BaseException:
            _unlink(temporary)
            self._forget(flight)
            raise
        # No await from here on: the flight ends, its waiters get their handles and the
        # file is stored in one step.
        self._forget(flight)
        entry = _Entry(flight.slot, version.key, path, path.stat().st_size, label, flight.serial)
        flight.handles = [path.open("rb") for _ in range(flight.waiters)]
        self.computed += 1
        self._store(entry)
        return entry

    async def _run_job(self, ref: ArtifactRef, pass_id: str, path: Path) -> str:
        common: dict[str, Any] = {
            "deadline_s": self._deadline_s,
            "what": _WHAT[ref.kind].format(pass_id),
            "cleanup": path,
        }
        run = self._workers.run
        if ref.kind == "recording":
            name: str = await run(
                read_session_job,
                self._url,
                recordings.write_recording,
                pass_id=pass_id,
                path=str(path),
                robot_files=self._robot_files,
                **common,
            )
            return name
        fn: Callable[..., str | bytes]
        extra: dict[str, Any] = {}
        if ref.kind == "report":
            fn = reports.pass_report_json
        elif ref.kind == "report_html":
            fn = reports.pass_report_html
        else:
            fn, extra = analyses.figure_png, {"name": ref.figure}
        await run(
            read_session_file_job, self._url, str(path), fn, pass_id=pass_id, **extra, **common
        )
        return ""

    def _store(self, entry: _Entry) -> None:
        old = self._index.get(entry.slot)
        if old is not None and old.serial > entry.serial:
            _unlink(entry.path)  # a newer version is stored: this one only goes to its waiters
            return
        if old is not None:
            self._drop(entry.slot)
        self._index[entry.slot] = entry
        self.stored_bytes += entry.size
        while self.stored_bytes > self._max_bytes and self._index:
            self._drop(next(iter(self._index)))

    def _drop(self, slot: tuple[str, Kind, str]) -> None:
        entry = self._index.pop(slot)
        self.stored_bytes -= entry.size
        _unlink(entry.path)


def _name_hash(name: str) -> str:
    return hashlib.sha256(name.encode("utf-8", "surrogateescape")).hexdigest()[:16]


def _retrieve(task: asyncio.Task[_Entry]) -> None:
    if not task.cancelled():
        task.exception()  # the waiters have it; nobody else is to be told
