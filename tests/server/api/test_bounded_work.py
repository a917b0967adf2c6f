"""CPU-heavy requests run as bounded work in worker processes (server/services/workers.py):
a full pool answers 503 ``busy`` at once, a job is killed past its deadline or when its
client goes away, a crashed or killed worker leaves the pool working, a download is
streamed from the worker's file byte for byte, and the planner's work bounds are refused
with 422. No timing is asserted but generous upper bounds; waits are on state, not sleeps.
"""

from __future__ import annotations

import asyncio
import functools
import io
import os
import signal
import time
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from server.api.errors import status_of
from server.services import recordings as recordings_service
from server.services.errors import DomainError
from server.services.workers import WorkerPool
from server.storage.db import make_engine, read_session_factory
from telemetry.mcap import read_mcap
from tests.support.api import OPERATOR, VIEWER
from tests.support.processes import descendants, free_port, health_when_up, serve_command, serve_env

#: Generous: a loaded 2-core machine may be slow; nothing here should take near this.
PATIENCE_S = 60.0
#: Health and an abort answer in a fraction of a second beside the planning jobs; past this
#: they were locked out (a guard, not a timing: speed is measured in bench/).
LOCKED_OUT_S = 5.0


def _wait_for(condition: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + PATIENCE_S
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.02)


async def _await_for(condition: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + PATIENCE_S
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        await asyncio.sleep(0.02)


def _gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


def _running_pids(pool: WorkerPool) -> list[int]:
    return [p.pid for p in list(pool._running) if p.pid is not None]


# Job functions: module-level, so that the worker can import them.


def _exit_without_answer() -> None:
    os._exit(3)


def _kill_myself() -> None:
    os.kill(os.getpid(), signal.SIGKILL)


def _allocate(n_bytes: int) -> int:
    return len(bytearray(n_bytes))


class _Client:
    """A request whose client leaves when ``leave`` is set."""

    def __init__(self) -> None:
        self.leave = asyncio.Event()

    async def is_disconnected(self) -> bool:
        return self.leave.is_set()


def _run(coro: Any) -> Any:
    return asyncio.run(coro)


def test_a_full_pool_answers_busy_at_once() -> None:
    async def scenario() -> None:
        pool = WorkerPool(workers=1, queue=1)
        try:
            first = asyncio.create_task(pool.run(time.sleep, 60, deadline_s=120, what="hold"))
            waiting = asyncio.create_task(pool.run(os.getpid, deadline_s=120, what="wait"))
            await _await_for(lambda: pool.running == 1, "the first job")
            t0 = time.monotonic()
            with pytest.raises(DomainError) as refused:
                await pool.run(os.getpid, deadline_s=120, what="planning ptp")
            assert time.monotonic() - t0 < 5.0  # at once, not after the running job
            assert (status_of(refused.value), refused.value.code) == (503, "busy")
            assert "planning ptp" in refused.value.message
            assert refused.value.detail["retry_after_s"] > 0
            first.cancel()  # the running job is killed; the waiting one gets a worker
            assert isinstance(await waiting, int)
            with pytest.raises(asyncio.CancelledError):
                await first
        finally:
            await pool.close()

    _run(scenario())


def test_busy_over_http_has_retry_after(tmp_path: Path) -> None:
    from server.app import create_app
    from server.settings import Settings
    from tests.support.api import TOKENS

    settings = Settings(data_dir=tmp_path, tokens=TOKENS, worker_processes=1, worker_queue=0)
    with TestClient(create_app(settings)) as client:
        pool: WorkerPool = client.app.state.workers  # type: ignore[attr-defined]
        # done with: its process gone and its request too (else the pool of one is full)
        _wait_for(lambda: pool.admitted == 0 and pool.started >= 1, "the warm-up job")
        hold = functools.partial(pool.run, time.sleep, 60, deadline_s=120, what="hold")
        client.portal.start_task_soon(hold)  # type: ignore[union-attr]
        _wait_for(lambda: pool.running == 1, "the held worker")
        body = {"experiment": "ptp", "parameters": {"settle_s": 0.25}}
        response = client.post("/api/plans/validate", json=body, headers=OPERATOR)
        assert response.status_code == 503, response.text
        assert response.json()["error"]["code"] == "busy"
        assert "busy" in response.json()["error"]["message"]
        assert int(response.headers["retry-after"]) >= 1
        pids = _running_pids(pool)
    # Leaving the client closes the app: the held job is killed.
    for pid in pids:
        _wait_for(lambda pid=pid: _gone(pid), f"job {pid} to be killed")  # type: ignore[misc]


def test_a_job_past_its_deadline_is_killed() -> None:
    async def scenario() -> None:
        pool = WorkerPool(workers=1, queue=0)
        try:
            task = asyncio.create_task(pool.run(time.sleep, 120, deadline_s=1.0, what="plan"))
            await _await_for(lambda: pool.running == 1, "the job")
            (pid,) = _running_pids(pool)
            with pytest.raises(DomainError) as late:
                await task
            assert (status_of(late.value), late.value.code) == (504, "deadline_exceeded")
            assert "1 s" in late.value.message
            await _await_for(lambda: _gone(pid), "the killed job to go")
            assert pool.running == 0
            assert await pool.run(os.getpid, deadline_s=PATIENCE_S, what="next") != pid
        finally:
            await pool.close()

    _run(scenario())


def test_a_job_whose_client_leaves_is_killed() -> None:
    async def scenario() -> None:
        pool = WorkerPool(workers=1, queue=0)
        client = _Client()
        try:
            task = asyncio.create_task(
                pool.run(time.sleep, 120, deadline_s=PATIENCE_S, what="plan", client=client)
            )
            await _await_for(lambda: pool.running == 1, "the job")
            (pid,) = _running_pids(pool)
            client.leave.set()
            with pytest.raises(DomainError) as gone:
                await task
            assert gone.value.code == "client_closed"
            await _await_for(lambda: _gone(pid), "the killed job to go")
            assert pool.running == 0
        finally:
            await pool.close()

    _run(scenario())


def test_a_crashed_or_oversized_job_leaves_the_pool_working() -> None:
    async def scenario() -> None:
        pool = WorkerPool(workers=1, queue=0, memory_bytes=1 << 30)
        try:
            for crash, how in ((_exit_without_answer, "exit 3"), (_kill_myself, "signal 9")):
                with pytest.raises(DomainError) as crashed:
                    await pool.run(crash, deadline_s=PATIENCE_S, what="a crash")
                assert (status_of(crashed.value), crashed.value.code) == (503, "worker_crashed")
                assert how in crashed.value.message
                assert isinstance(await pool.run(os.getpid, deadline_s=PATIENCE_S, what="x"), int)
            with pytest.raises(DomainError) as oom:
                await pool.run(_allocate, 2 << 30, deadline_s=PATIENCE_S, what="a big job")
            assert (status_of(oom.value), oom.value.code) == (503, "out_of_memory")
            assert "1 GiB" in oom.value.message
            assert await pool.run(_allocate, 1 << 20, deadline_s=PATIENCE_S, what="x") == 1 << 20
        finally:
            await pool.close()

    _run(scenario())


@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_recording_download_is_streamed_byte_identical(
    client: TestClient,
    database_url: str,
    short_mcap: bytes,
    tmp_path: Path,
) -> None:
    upload = client.post("/api/passes/import", content=short_mcap, headers=OPERATOR)
    assert upload.status_code == 201, upload.text
    pass_id = upload.json()["imported"]["id"]

    response = client.get(f"/api/passes/{pass_id}/recording.mcap", headers=VIEWER)
    assert response.status_code == 200, response.text
    assert response.headers["content-length"] == str(len(response.content))
    engine = make_engine(database_url)
    try:
        with read_session_factory(engine)() as session:
            _, in_process = recordings_service.recording_mcap(session=session, pass_id=pass_id)
    finally:
        engine.dispose()
    assert response.content == in_process
    assert read_mcap(io.BytesIO(response.content)).name
    assert list((tmp_path / "jobs").iterdir()) == []  # the worker's file is gone

    missing = client.get("/api/passes/nope/recording.mcap", headers=VIEWER)
    assert missing.status_code == 404 and missing.json()["error"]["code"] == "not_found"
    assert list((tmp_path / "jobs").iterdir()) == []


@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
@pytest.mark.parametrize(
    ("experiment", "parameters", "reason"),
    [
        ("nonholonomic", {"path_steps": 10000}, "path_steps = 10000 exceeds the limit of 400"),
        ("nonholonomic", {"max_iterations": 10000}, "max_iterations = 10000 exceeds"),
        ("ptp", {"settle_s": 3600.0}, "settle_s = 3600.0 s exceeds the limit of 300 s"),
        ("reactionless", {"out_speed_mps": 1e-6}, "below the limit of 0.003 m/s"),
    ],
)
def test_work_beyond_the_bounds_is_refused(
    client: TestClient, experiment: str, parameters: dict[str, Any], reason: str
) -> None:
    body = {"experiment": experiment, "parameters": parameters}
    response = client.post("/api/plans", json=body, headers=OPERATOR)
    assert response.status_code == 422, response.text
    assert reason in response.json()["error"]["message"]
    assert response.json()["error"]["code"] == "InvalidInput"
    validation = client.post("/api/plans/validate", json=body, headers=OPERATOR).json()
    assert validation["valid"] is False and reason in validation["errors"][0]["message"]


def test_serve_stays_healthy_under_planning_load_and_stops_on_sigterm(tmp_path: Path) -> None:
    """``hikoboshi serve`` with 40 of the longest plans the bounds allow in flight: health
    answers within 1 s, the jobs go when their clients do, SIGTERM stops it within 5 s
    after the lifespan's shutdown (the runner's) ran."""
    import socket
    import subprocess

    import httpx

    port = free_port()
    env = serve_env(tmp_path, "v-tok=vera:viewer,o-tok=otto:operator")
    proc = subprocess.Popen(
        serve_command(port), env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
    )
    base = f"http://127.0.0.1:{port}"
    sockets: list[socket.socket] = []
    try:
        health_when_up(proc, base, guard_s=PATIENCE_S)
        # A scheduled pass to abort while the planning requests are in flight.
        operator = {"Authorization": "Bearer o-tok"}
        plan = httpx.post(
            f"{base}/api/plans",
            json={"experiment": "ptp", "parameters": {"settle_s": 0.25}},
            headers=operator,
            timeout=PATIENCE_S,
        )
        assert plan.status_code == 201, plan.text
        now = time.time()
        created = httpx.post(
            f"{base}/api/passes",
            json={
                "plan_id": plan.json()["id"],
                "name": "to-abort",
                "aos_time": datetime.fromtimestamp(now + 3600, UTC).isoformat(),
                "los_time": datetime.fromtimestamp(now + 7200, UTC).isoformat(),
            },
            headers=operator,
        )
        assert created.status_code == 201, created.text
        # The warm-up job has come and gone: what is left is the forkserver.
        time.sleep(3.0)
        baseline = len(descendants(proc.pid))
        body = (
            b'{"experiment": "nonholonomic", "parameters": {"attitude_end_deg": [90, 90, 90],'
            b' "max_iterations": 200, "path_steps": 400, "max_corrections": 20}}'
        )
        request = (
            b"POST /api/plans/validate HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer o-tok\r\n"
            b"Content-Type: application/json\r\nContent-Length: %d\r\n\r\n%s" % (len(body), body)
        )
        for _ in range(40):
            s = socket.create_connection(("127.0.0.1", port), timeout=10)
            s.sendall(request)
            sockets.append(s)
        _wait_for(lambda: len(descendants(proc.pid)) > baseline, "jobs to start")
        for _ in range(5):
            t0 = time.monotonic()
            health = httpx.get(f"{base}/api/health", timeout=10.0)
            assert health.status_code == 200
            # a lock-out guard, not a timing (a health answered by a busy thread pool had
            # waited for the planning jobs: tens of seconds)
            assert time.monotonic() - t0 < LOCKED_OUT_S
            time.sleep(0.2)
        # the operator's abort is not held up by the planning either
        t0 = time.monotonic()
        aborted = httpx.post(
            f"{base}/api/passes/{created.json()['id']}/abort",
            json={"confirm": "ABORT to-abort", "reason": "planning load"},
            headers=operator,
            timeout=10.0,
        )
        assert aborted.status_code == 200, aborted.text
        assert aborted.json()["state"] == "aborted"
        assert time.monotonic() - t0 < LOCKED_OUT_S
        for s in sockets:
            s.close()
        _wait_for(lambda: len(descendants(proc.pid)) <= baseline, "the jobs to be killed")
        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=30)
        stopped_s = time.monotonic() - t0
        _, stderr = proc.communicate(timeout=5)
        # uvicorn re-raises the signal after its clean shutdown (exit status -15); the
        # shutdown itself is what counts: the lifespan's finally (runner, link) completed.
        assert code in (0, -signal.SIGTERM), stderr.decode(errors="replace")[-2000:]
        assert stopped_s < 5.0
        assert b"Application shutdown complete" in stderr
    finally:
        for s in sockets:
            s.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
        if proc.stderr is not None:
            proc.stderr.close()
