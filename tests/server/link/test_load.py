"""A live pass under load (#14): 30 viewers downloading recordings and reports and 4
anonymous clients posting 30 MB bodies while the ground flies a pass at 20x. Every command
must execute at its tag, no frame may be missing, an abort must answer within a second and
the server's memory must stay bounded.

Everything is a real process on loopback: ``hikoboshi serve`` (so the load generator in
this process does not share the server's interpreter), ``hikoboshi spacecraft`` at 20x,
and the clients here. The viewers behave as the API tells them: a 503 ``busy`` is waited
out for its ``Retry-After``. The anonymous clients come from another loopback address
(127.0.0.2), as an outside attacker would: failed authentication is rate-limited per
address, and an operator on the same address as an attacker would be refused too.

Bounded: one imported demo pass (13.8 MB of MCAP) to download, a pass of about 260 s
onboard (13 s of wall) and a short aborted one; the server's peak resident memory must
stay under :data:`SERVER_RSS_BOUND` (each worker process is bounded by its own
``RLIMIT_AS``, ``worker_memory_bytes``, 2 GiB by default, and at most two run at once).
"""

from __future__ import annotations

import asyncio
import contextlib
import io
import json
import subprocess
import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import pytest
from sqlalchemy.orm import Session, sessionmaker

from server.services.summary import pass_summary
from server.storage import repository as repo
from server.storage.db import make_engine, read_session_factory, session_factory
from telemetry.mcap import write_mcap
from telemetry.recording import PassRecording
from tests.server.link.harness import _free_port, serve_process, store_pass

SCALE = 20.0
OPERATOR_TOKEN = "operator-token-0123456789"
VIEWER_TOKEN = "viewer-token-0123456789ab"
SPACECRAFT_TOKEN = "spacecraft-token-01234567"
TOKENS = (
    f"{OPERATOR_TOKEN}=otto:operator,{VIEWER_TOKEN}=vera:viewer,{SPACECRAFT_TOKEN}=ets7:spacecraft"
)
OPERATOR = {"Authorization": f"Bearer {OPERATOR_TOKEN}"}
VIEWER = {"Authorization": f"Bearer {VIEWER_TOKEN}"}
N_VIEWERS = 30
N_ANONYMOUS = 4
ANONYMOUS_BODY = 30 * 1024 * 1024
#: The server process's peak resident set (VmHWM): its own, the work runs in worker
#: processes. Measured about 330 MB under this load.
SERVER_RSS_BOUND = 768 * 1024 * 1024
#: The abort's answer under this load (#14). It took 2.5-23.5 s while the pass's task waited
#: at LOS for the database backlog and a backlog of telemetry (one write per message) held
#: the operator's control job for seconds on PostgreSQL; measured 0.2-0.4 s with one core
#: busy since those were fixed.
ABORT_ANSWER_S = 1.0


@dataclass
class Load:
    stop: asyncio.Event = field(default_factory=asyncio.Event)
    viewer_status: Counter[int] = field(default_factory=Counter)
    downloaded_bytes: int = 0
    complete_downloads: int = 0
    #: requests on a kept-alive connection the server had closed as idle meanwhile
    stale_connections: int = 0
    anonymous_status: Counter[str] = field(default_factory=Counter)


async def _viewer(base: str, pass_id: str, size: int, load: Load) -> None:
    paths = (f"/api/passes/{pass_id}/recording.mcap", f"/api/passes/{pass_id}/report.html")
    async with httpx.AsyncClient(base_url=base, timeout=300.0, headers=VIEWER) as client:
        k = 0
        while not load.stop.is_set():
            path = paths[k % 2]
            k += 1
            try:
                await _download(client, path, size, load)
            except httpx.RemoteProtocolError as exc:
                # The server closes a connection idle for its keep-alive timeout (5 s); a
                # viewer starved of CPU for that long sends its next request as it closes.
                # A GET on a reused connection is sent again (RFC 9112, 9.3.1), as browsers
                # do; that it stays rare is asserted.
                if "without sending a response" not in str(exc):
                    raise
                load.stale_connections += 1


async def _download(client: httpx.AsyncClient, path: str, size: int, load: Load) -> None:
    async with client.stream("GET", path) as response:
        n = 0
        body = bytearray()
        async for chunk in response.aiter_bytes():
            n += len(chunk)
            if response.status_code != 200:
                body += chunk
        load.viewer_status[response.status_code] += 1
        load.downloaded_bytes += n
        if response.status_code == 200:
            assert n == int(response.headers["Content-Length"])
            assert n > (size // 2 if path.endswith(".mcap") else 100_000)
            load.complete_downloads += 1
        elif response.status_code == 504:
            assert json.loads(body)["error"]["code"] == "deadline_exceeded", body
        elif response.status_code == 503:
            wait = min(float(response.headers["Retry-After"]), 2.0)
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(load.stop.wait(), wait)


async def _anonymous(port: int, load: Load) -> None:
    """POST a 30 MB JSON body with no token, a megabyte at a time, until answered."""
    head = (
        "POST /api/plans HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
        f"Content-Length: {ANONYMOUS_BODY}\r\n\r\n"
    ).encode()
    chunk = b"[" * (1024 * 1024)
    while not load.stop.is_set():
        reader, writer = await asyncio.open_connection(
            "127.0.0.1", port, local_addr=("127.0.0.2", 0)
        )
        try:
            writer.write(head)
            answer = asyncio.ensure_future(reader.readline())
            for _ in range(ANONYMOUS_BODY // len(chunk)):
                if answer.done():
                    break
                writer.write(chunk)
                try:
                    await writer.drain()
                except ConnectionError:
                    break
            status = await asyncio.wait_for(answer, 30.0)
            load.anonymous_status[status.split(b" ")[1].decode() if status else "closed"] += 1
        except ConnectionError:
            load.anonymous_status["reset"] += 1
        finally:
            writer.close()
            with contextlib.suppress(ConnectionError):
                await writer.wait_closed()
        await asyncio.sleep(0.05)


def _state(sessions: sessionmaker[Session], pass_id: str) -> str:
    with sessions() as session:
        return repo.get_pass(session=session, pass_id=pass_id, refresh=True).state


def _open(sessions: sessionmaker[Session], pass_id: str) -> int:
    """Commands of the pass not yet in a final stage."""
    with sessions() as session:
        stages = ("queued", "released", "sent", "received")
        return len(repo.list_commands(session=session, pass_id=pass_id, stages=stages))


def _executed(sessions: sessionmaker[Session], pass_id: str) -> int:
    with sessions() as session:
        return len(repo.list_commands(session=session, pass_id=pass_id, stages=["executed"]))


async def _until(predicate: object, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not await asyncio.to_thread(predicate):  # type: ignore[arg-type]
        assert time.monotonic() < deadline, f"{what}: not within {timeout_s} s"
        await asyncio.sleep(0.2)


def _peak_rss_bytes(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    raise AssertionError("no VmHWM")


@pytest.mark.slow
def test_a_pass_flies_untouched_while_viewers_download_and_anonymous_clients_flood(
    database_url: str, tmp_path: Path, demo_recording: PassRecording
) -> None:
    buffer = io.BytesIO()
    write_mcap(demo_recording, buffer)
    recording = buffer.getvalue()
    port = _free_port()
    base = f"http://127.0.0.1:{port}"
    engine = make_engine(database_url)
    sessions = session_factory(engine)
    readers = read_session_factory(engine)  # polling takes no write lock on SQLite
    env = {"HIKOBOSHI_TOKENS": TOKENS, "HIKOBOSHI_DATA_DIR": str(tmp_path / "data")}
    spacecraft_log = tmp_path / "spacecraft.log"

    async def scenario(server_pid: int) -> tuple[Load, str, str, float, int]:
        load = Load()
        async with httpx.AsyncClient(base_url=base, timeout=300.0, headers=OPERATOR) as op:
            # the pass the viewers download: the demo pass, imported, with its analyses
            response = await op.post("/api/passes/import", content=recording)
            assert response.status_code == 201, response.text
            demo_id = response.json()["imported"]["id"]
            response = await op.post(f"/api/passes/{demo_id}/analyses")
            assert response.status_code == 201, response.text
            with spacecraft_log.open("ab") as out:
                vehicle = subprocess.Popen(
                    [
                        sys.executable,
                        "-m",
                        "hikoboshi",
                        "spacecraft",
                        "--ground",
                        f"ws://127.0.0.1:{port}/api/link",
                        "--token",
                        SPACECRAFT_TOKEN,
                        "--time-scale",
                        str(SCALE),
                        "--seed",
                        "4",
                    ],
                    stdout=out,
                    stderr=subprocess.STDOUT,
                )
            try:
                while not (await op.get("/api/link/status")).json()["connected"]:
                    assert vehicle.poll() is None, spacecraft_log.read_text()[-2000:]
                    await asyncio.sleep(0.1)
                tasks = [
                    asyncio.create_task(_viewer(base, demo_id, len(recording), load))
                    for _ in range(N_VIEWERS)
                ] + [asyncio.create_task(_anonymous(port, load)) for _ in range(N_ANONYMOUS)]
                try:
                    await asyncio.sleep(3.0)  # the load is on before the pass starts
                    # 10 s of motion, then 230 s holding: 13 s of wall at 20x
                    flown = store_pass(sessions, "loaded", (10.0, 0.0, 0.0, 10.0, 0.0, 0.0), 230.0)
                    response = await op.post(
                        f"/api/passes/{flown}/start", json={"confirm": "START loaded"}
                    )
                    assert response.status_code == 200, response.text
                    await _until(lambda: _state(readers, flown) == "complete", 240.0, "complete")
                    # and an abort under the same load
                    # 10 s of motion and 600 s of holding (30 s of wall): the abort comes
                    # while the pass runs however slowly its first stages are stored
                    aborted = store_pass(sessions, "cut", (10.0, 0.0, 0.0, 10.0, 0.0, 0.0), 600.0)
                    response = await op.post(
                        f"/api/passes/{aborted}/start", json={"confirm": "START cut"}
                    )
                    assert response.status_code == 200, response.text
                    await _until(lambda: _executed(readers, aborted) >= 12, 120.0, "12 executed")
                    assert _state(readers, aborted) == "running"
                    t0 = time.monotonic()
                    response = await op.post(
                        f"/api/passes/{aborted}/abort",
                        json={"confirm": "ABORT cut", "reason": "load test"},
                    )
                    abort_s = time.monotonic() - t0
                    assert response.status_code == 200, response.text
                    assert response.json()["state"] == "aborted"
                    await _until(lambda: _open(readers, aborted) == 0, 120.0, "cut resolved")
                finally:
                    load.stop.set()
                    done = await asyncio.gather(*tasks, return_exceptions=True)
                errors = [r for r in done if isinstance(r, BaseException)]
                assert not errors, errors[:3]
                peak = _peak_rss_bytes(server_pid)
            finally:
                vehicle.terminate()
                vehicle.wait(timeout=30)
        return load, flown, aborted, abort_s, peak

    try:
        with serve_process(database_url, port, tmp_path / "server.log", env) as server:
            load, flown, aborted, abort_s, peak = asyncio.run(scenario(server.pid))
        with sessions() as session:
            commands = repo.list_commands(session=session, pass_id=flown)
            summary = pass_summary(session=session, pass_id=flown)
            cut = repo.list_commands(session=session, pass_id=aborted)
    finally:
        engine.dispose()

    # the pass flew untouched: every command executed at its tag, no frame missing
    assert len(commands) > 900
    assert {c.stage for c in commands} == {"executed"}
    assert all(c.executed_at_ns == c.execute_time_ns for c in commands)
    assert summary.frames_missing == 0 and summary.gaps_open == 0
    assert summary.commands_expired == 0
    # the load was real: downloads completed, others were told to come back, and every
    # anonymous body was refused unread: 401, then 429 once the address is blocked (a
    # reset when the refusal and close overtook the body still being sent). On a machine
    # busy with other work a download can outlive its read deadline: it is stopped and
    # answered 504 deadline_exceeded (checked in _viewer), bounded work doing its job.
    assert load.complete_downloads >= 4, load
    assert set(load.viewer_status) <= {200, 503, 504}, load.viewer_status
    assert load.stale_connections <= max(3, sum(load.viewer_status.values()) // 20), load
    assert load.anonymous_status["401"] >= 1, load
    assert set(load.anonymous_status) <= {"401", "429", "reset"}, load
    # the abort answered at once; nothing of the cut pass was lost or left open
    assert abort_s < ABORT_ANSWER_S, f"abort answered in {abort_s:.2f} s"
    assert {c.stage for c in cut} <= {"executed", "cancelled"}
    assert peak < SERVER_RSS_BOUND, f"server peak RSS {peak / 2**20:.0f} MiB"
    print(f"abort {abort_s:.3f} s, peak RSS {peak / 2**20:.0f} MiB, {load}")
