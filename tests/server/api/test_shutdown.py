"""Stopping with work in flight: SIGTERM to ``hikoboshi serve`` while planning requests run
and wait answers every one of them 503 ``shutting_down`` in the JSON error shape (never a
plain-text 500), and no process the server started (the worker jobs, the forkserver)
outlives it. The worker pool's own stop: waiting and running jobs answered at once, every
job process reaped, one still starting included.
"""

from __future__ import annotations

import asyncio
import json
import signal
import socket
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from starlette.types import Message, Receive, Scope, Send

from server.api.stopping import AnswerWhenStopping
from server.services.errors import UnavailableError
from server.services.workers import WorkerPool
from server.storage.db import sqlite_url
from tests.server.link.harness import serve_process
from tests.support.processes import descendants, free_port

#: A guard against a hang, not a timing: the stop itself takes uvicorn's graceful timeout
#: (3 s) at most, with the pool stopped first it answers at once.
PATIENCE_S = 60.0
#: The longest plan the bounds allow (tests/server/api/test_bounded_work.py): it runs for
#: tens of seconds, so it is still running when the signal comes.
SLOW_PLAN = (
    b'{"experiment": "nonholonomic", "parameters": {"attitude_end_deg": [90, 90, 90],'
    b' "max_iterations": 200, "path_steps": 400, "max_corrections": 20}}'
)
IN_FLIGHT = 6  # 2 running (worker_processes), 4 waiting for a worker


def _wait_for(condition: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + PATIENCE_S
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.05)


def _alive(pid: int) -> bool:
    """The process runs (a zombie, dead but not yet reaped by its new parent, does not)."""
    try:
        with open(f"/proc/{pid}/stat") as stat:
            state = stat.read().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _answer(sock: socket.socket) -> bytes:
    chunks = []
    while chunk := sock.recv(65536):
        chunks.append(chunk)
    return b"".join(chunks)


@pytest.mark.slow
def test_sigterm_answers_waiting_plans_in_json_and_leaves_no_process(tmp_path: Path) -> None:
    port = free_port()
    env = {
        "HIKOBOSHI_DATA_DIR": str(tmp_path),
        "HIKOBOSHI_TOKENS": "o-tok=otto:operator",
        "HIKOBOSHI_WORKER_PROCESSES": "2",
        "HIKOBOSHI_WORKER_QUEUE": "8",
    }
    request = (
        b"POST /api/plans/validate HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer o-tok\r\n"
        b"Content-Type: application/json\r\nContent-Length: %d\r\n\r\n%s"
        % (len(SLOW_PLAN), SLOW_PLAN)
    )
    log = tmp_path / "serve.log"
    sockets: list[socket.socket] = []
    with serve_process(sqlite_url(tmp_path), port, log, env) as proc:
        try:
            time.sleep(3.0)  # the warm-up job has come and gone: the forkserver is left
            baseline = descendants(proc.pid)
            for _ in range(IN_FLIGHT):
                s = socket.create_connection(("127.0.0.1", port), timeout=PATIENCE_S)
                s.sendall(request)
                sockets.append(s)
            # both workers run a plan: their processes are below the server's
            _wait_for(lambda: len(descendants(proc.pid) - baseline) >= 2, "jobs to start")
            seen = descendants(proc.pid)
            jobs = seen - baseline
            proc.send_signal(signal.SIGTERM)
            answers = [_answer(s) for s in sockets]
            code = proc.wait(timeout=PATIENCE_S)
        finally:
            for s in sockets:
                s.close()
    output = log.read_text(errors="replace")
    # uvicorn re-raises the signal after its shutdown: the process ends by SIGTERM
    assert code in (0, -signal.SIGTERM), output[-3000:]
    assert "Application shutdown complete" in output, output[-3000:]
    assert "Cancel" not in output, output[-3000:]  # no request was left for uvicorn to cut
    assert len(jobs) >= 2
    for raw in answers:
        head, _, body = raw.partition(b"\r\n\r\n")
        status_line, *headers = head.decode().split("\r\n")
        fields = {k.lower(): v.strip() for k, _, v in (h.partition(":") for h in headers)}
        assert status_line.split()[1] == "503", raw[:500]
        assert fields["content-type"] == "application/problem+json", raw[:500]
        assert int(fields["retry-after"]) > 0
        error = json.loads(body)["error"]
        assert error["code"] == "shutting_down", error
        assert "shutting down" in error["message"]
    # Nothing the server started outlives it (the forkserver and its helpers notice the
    # server gone on their own pipe; a guard, not a timing).
    _wait_for(lambda: not any(_alive(p) for p in seen), "the server's processes to end")
    assert not any(_alive(p) for p in jobs)


def _sleep(seconds: float) -> float:
    time.sleep(seconds)
    return seconds


def test_the_pool_answers_waiting_and_running_jobs_when_it_stops() -> None:
    async def run() -> tuple[list[BaseException | float], set[int], int]:
        # every pool's preload: this process's forkserver is shared with later tests' pools
        pool = WorkerPool(workers=1, queue=4, memory_bytes=None)
        await pool.start()
        try:
            tasks = [
                asyncio.ensure_future(pool.run(_sleep, 600.0, deadline_s=900.0, what="sleep"))
                for _ in range(3)
            ]
            deadline = time.monotonic() + PATIENCE_S

            def sleeping() -> set[int]:
                return {
                    p.pid for p in pool._running if p.name.endswith("sleep") and p.pid is not None
                }

            while not sleeping() or pool.admitted < 3:
                assert time.monotonic() < deadline, "the job did not start"
                await asyncio.sleep(0.02)
            pids = sleeping()
            await pool.close()
            results = await asyncio.wait_for(
                asyncio.gather(*tasks, return_exceptions=True), PATIENCE_S
            )
            late: BaseException | None = None
            try:
                await pool.run(_sleep, 0.0, deadline_s=10.0, what="late")
            except UnavailableError as exc:
                late = exc
            assert late is not None and late.code == "shutting_down"
            return list(results), pids, pool.running
        finally:
            await pool.close()

    results, pids, running = asyncio.run(run())
    assert len(pids) == 1 and running == 0
    for result in results:
        assert isinstance(result, UnavailableError), result
        assert result.code == "shutting_down" and result.retry_after_s > 0
    assert not any(_alive(p) for p in pids)


_ABANDON = """
import asyncio, os, time
from server.services.workers import WorkerPool

async def main() -> None:
    pool = WorkerPool(workers=1, queue=4, memory_bytes=None, preload=())
    await pool.start()
    job = asyncio.ensure_future(pool.run(time.sleep, 600.0, deadline_s=900.0, what="sleep"))
    while not [p for p in pool._running if p.name.endswith("sleep") and p.pid]:
        await asyncio.sleep(0.02)
    [process] = [p for p in pool._running if p.name.endswith("sleep")]
    from multiprocessing import forkserver
    print(process.pid, forkserver._forkserver._forkserver_pid, flush=True)
    os._exit(0)  # no cleanup at all: as if the server were killed

asyncio.run(main())
"""


def test_a_job_dies_with_a_server_that_ends_without_cleaning_up(tmp_path: Path) -> None:
    """However the server ends (here: ``os._exit``, no shutdown at all), its jobs end with
    it: each watches the server's process (server/services/jobs.py), and the forkserver
    ends once its last job has."""
    import subprocess
    import sys

    out = tmp_path / "out.txt"
    with out.open("wb") as stdout:  # a file, not a pipe: an orphan would hold a pipe open
        code = subprocess.run(
            [sys.executable, "-c", _ABANDON],
            stdout=stdout,
            stderr=subprocess.STDOUT,
            timeout=PATIENCE_S,
            cwd=Path(__file__).resolve().parents[3],
        ).returncode
    text = out.read_text(errors="replace")
    assert code == 0, text[-2000:]
    pid, forkserver = (int(word) for word in text.split()[:2])
    _wait_for(lambda: not _alive(pid), "the abandoned job to end")
    _wait_for(lambda: not _alive(forkserver), "the forkserver to end")


def test_a_request_cut_short_by_the_stop_answers_json() -> None:
    """uvicorn cancels what is left after its graceful timeout: a request whose response had
    not started is answered 503 ``shutting_down`` in the JSON shape; one whose response had
    started is cut (the cancellation goes on)."""

    async def hang(scope: Scope, receive: Receive, send: Send) -> None:
        if scope["path"] == "/started":
            await send({"type": "http.response.start", "status": 200, "headers": []})
        await asyncio.Event().wait()

    async def call(path: str) -> tuple[list[Message], bool]:
        sent: list[Message] = []

        async def send(message: Message) -> None:
            sent.append(message)

        async def receive() -> Message:
            return {"type": "http.request", "body": b"", "more_body": False}

        app = AnswerWhenStopping(hang)
        task = asyncio.ensure_future(app({"type": "http", "path": path}, receive, send))
        await asyncio.sleep(0.05)
        task.cancel()
        try:
            await task
        except asyncio.CancelledError:
            return sent, True
        return sent, False

    sent, cancelled = asyncio.run(call("/waiting"))
    assert not cancelled
    start, body = sent
    assert start["status"] == 503
    headers = dict(start["headers"])
    assert headers[b"content-type"] == b"application/problem+json"
    assert int(headers[b"retry-after"]) > 0
    assert json.loads(body["body"])["error"]["code"] == "shutting_down"
    sent, cancelled = asyncio.run(call("/started"))
    assert cancelled and [m["status"] for m in sent] == [200]


class _Step:
    """A stand-in for one of the services a stop goes through: it notes its step."""

    def __init__(self, steps: list[str], name: str, **attrs: object) -> None:
        self._steps, self._name = steps, name
        self.__dict__.update(attrs)

    async def _note(self, *_: object) -> None:
        self._steps.append(self._name)

    close = shutdown = drain = going_away = _note

    def give_up(self, _: float) -> None:
        pass

    def stop_commanding(self) -> None:
        self._steps.append("stop commanding")


def test_a_graceful_stop_beside_a_standby_releases_the_lease_after_the_last_write() -> None:
    """SIGTERM of the holder: nothing more is commanded (the vehicle's link, refused from
    now on, goes to the next ground), the link closes, the pass is handed to the vehicle,
    the alarms' and the command path's last writes are flushed, and only then is the lease
    released, all before uvicorn waits for its requests (``begin_shutdown``), so a standby
    takes over within its next renewal, not after the whole stop. SQLite (one ground a
    file, the lease its lock) releases nothing there."""
    from fastapi import FastAPI

    from server.services.authority import LeasePolicy
    from server.stopping import begin_shutdown

    def app_of(exclusive: bool) -> tuple[FastAPI, list[str]]:
        steps: list[str] = []
        app = FastAPI()
        policy = LeasePolicy(name="ets7", holder="a", ttl_s=3.0, renew_s=0.5, exclusive=exclusive)
        app.state.authority = _Step(steps, "release", policy=policy, holder=True)
        app.state.db = _Step(steps, "flush")
        app.state.workers = _Step(steps, "workers")
        app.state.link = _Step(steps, "link")
        app.state.runner = _Step(steps, "hand over")
        app.state.alarms = _Step(steps, "alarms")
        return app, steps

    app, steps = app_of(exclusive=False)
    asyncio.run(begin_shutdown(app))
    assert steps == [
        "workers", "stop commanding", "link", "hand over", "alarms", "flush", "release"
    ]  # fmt: skip
    app, steps = app_of(exclusive=True)
    asyncio.run(begin_shutdown(app))
    assert steps == ["workers", "stop commanding", "link"]
