"""A live pass under viewer load, as a scenario shared by ``test_load.py`` and
``bench/bench_load.py``: ``hikoboshi serve`` and ``hikoboshi spacecraft`` as processes of
their own, and here the viewers, the probes an operator's screen makes and the operator.

- :func:`viewers`: ``tokens x clients`` viewers, each looping over the heaviest reads of an
  imported, analysed pass (its recording, the report as JSON and HTML, its analyses, raw
  telemetry), waiting out 429 and 503 for their ``Retry-After`` as the API asks.
- :class:`Probes`: liveness and the link status sampled on their own connections, and an
  operator's console websocket that opens while the load is on, subscribes, pings and
  reads until told to stop (whether it ever dropped is kept).
- :func:`fly` and :func:`abort_mid_pass`: a pass flown to ``complete``, and a second one
  aborted once a dozen commands executed (the abort's answer timed).

Everything is timed here, on this process's clock: the tests assert outcomes and only a
lenient lock-out guard on latencies, the benchmark reports them against a no-load phase.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import signal
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import httpx
import websockets

if TYPE_CHECKING:
    from sqlalchemy.orm import Session, sessionmaker

#: The longest a viewer waits on a Retry-After (s): the server says 1 s (busy) or 5 s (a
#: token's heavy reads); a longer wait would only lighten the load.
MAX_RETRY_WAIT_S = 5.0


def viewer_paths(pass_id: str) -> tuple[str, ...]:
    """The heaviest reads of a pass."""
    return (
        f"/api/passes/{pass_id}/recording.mcap",
        f"/api/passes/{pass_id}/report.html",
        f"/api/passes/{pass_id}/report",
        f"/api/passes/{pass_id}/analyses",
        f"/api/passes/{pass_id}/telemetry?limit=5000",
    )


@dataclass
class ViewerLoad:
    stop: asyncio.Event = field(default_factory=asyncio.Event)
    status: Counter[int] = field(default_factory=Counter)
    #: codes of the refusals (429 and 503) and failures (504)
    codes: Counter[str] = field(default_factory=Counter)
    complete: Counter[str] = field(default_factory=Counter)  # 200s by route's last part
    downloaded_bytes: int = 0
    #: requests on a kept-alive connection the server had closed as idle meanwhile
    stale_connections: int = 0


#: An operator's client lets an idle connection go after 2 s, before the server's 5 s
#: keep-alive timeout (``keep_alive_timeout_s``) can close it under a request: a POST (a
#: start, an abort) is not sent again on a reused connection that the server closed.
OPERATOR_LIMITS = httpx.Limits(keepalive_expiry=2.0)


async def _viewer(base: str, token: str, paths: tuple[str, ...], k: int, load: ViewerLoad) -> None:
    headers = {"Authorization": f"Bearer {token}"}
    async with httpx.AsyncClient(base_url=base, timeout=300.0, headers=headers) as client:
        while not load.stop.is_set():
            path = paths[k % len(paths)]
            k += 1
            try:
                wait = await _read(client, path, load)
            except (httpx.RemoteProtocolError, httpx.ReadError) as exc:
                # The server closes a connection idle for its keep-alive timeout (5 s); a
                # viewer starved of CPU for that long sends its next request as it closes
                # (the close or the reset is what it reads). A GET on a reused connection
                # is sent again (RFC 9112, 9.3.1); that it stays rare is asserted.
                if isinstance(exc, httpx.RemoteProtocolError) and (
                    "without sending a response" not in str(exc)
                ):
                    raise
                load.stale_connections += 1
                continue
            if wait:
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(load.stop.wait(), wait)


async def _read(client: httpx.AsyncClient, path: str, load: ViewerLoad) -> float:
    """One read; the time to wait before the next (a refusal's Retry-After)."""
    async with client.stream("GET", path) as response:
        body = bytearray()
        n = 0
        # the bytes as sent (gzip'd JSON over 1 KB), which Content-Length counts; an error's
        # body is under the compression threshold
        async for chunk in response.aiter_raw():
            n += len(chunk)
            if response.status_code != 200:
                body += chunk
    load.status[response.status_code] += 1
    load.downloaded_bytes += n
    if response.status_code == 200:
        if "content-length" in response.headers:
            assert n == int(response.headers["content-length"]), path
        load.complete[path.split("?")[0].rsplit("/", 1)[-1]] += 1
        return 0.0
    code = json.loads(body)["error"]["code"] if body.startswith(b"{") else "?"
    load.codes[f"{response.status_code} {code}"] += 1
    if response.status_code in (429, 503):
        return min(float(response.headers["Retry-After"]), MAX_RETRY_WAIT_S)
    return 0.0


def viewers(
    base: str, tokens: list[str], clients_per_token: int, pass_id: str, load: ViewerLoad
) -> list[asyncio.Task[None]]:
    """``len(tokens) x clients_per_token`` viewers, started at different routes."""
    paths = viewer_paths(pass_id)
    return [
        asyncio.create_task(_viewer(base, token, paths, t + c, load))
        for t, token in enumerate(tokens)
        for c in range(clients_per_token)
    ]


@dataclass
class Probes:
    """What an operator's screen asks while the pass flies; latencies in s."""

    base: str
    token: str
    stop: asyncio.Event = field(default_factory=asyncio.Event)
    health_s: list[float] = field(default_factory=list)
    link_s: list[float] = field(default_factory=list)
    #: (wall s, link status) of every sample during a pass
    link: list[tuple[float, dict[str, Any]]] = field(default_factory=list)
    unexpected: Counter[str] = field(default_factory=Counter)
    console_open_s: float | None = None
    console_pings_s: list[float] = field(default_factory=list)
    console_messages: Counter[str] = field(default_factory=Counter)
    #: why the console's socket ended before it was told to stop (None: it never did)
    console_dropped: str | None = None

    def start(self) -> list[asyncio.Task[None]]:
        return [asyncio.create_task(self._health()), asyncio.create_task(self._link())]

    async def _sample(self, path: str, headers: dict[str, str], into: list[float]) -> Any:
        async with httpx.AsyncClient(
            base_url=self.base, timeout=60.0, headers=headers, limits=OPERATOR_LIMITS
        ) as c:  # with httpx's default 5 s expiry, a probe stalled 5 s met the server's close
            while not self.stop.is_set():
                t0 = time.perf_counter()
                response = await c.get(path)
                into.append(time.perf_counter() - t0)
                if response.status_code != 200:
                    self.unexpected[f"{path} {response.status_code}"] += 1
                elif path == "/api/link/status" and response.json()["active_pass_id"]:
                    self.link.append((time.monotonic(), response.json()))
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self.stop.wait(), 0.25)

    async def _health(self) -> None:
        await self._sample("/api/health", {}, self.health_s)

    async def _link(self) -> None:
        headers = {"Authorization": f"Bearer {self.token}"}
        await self._sample("/api/link/status", headers, self.link_s)

    async def console(self, ws_url: str) -> None:
        """Open the console's websocket, subscribe to the link and the passes, ping twice a
        second and read everything until :attr:`stop`."""
        t0 = time.perf_counter()
        async with websockets.connect(
            ws_url,
            additional_headers={"Authorization": f"Bearer {self.token}"},
            open_timeout=60.0,
            max_size=None,
        ) as ws:
            self.console_open_s = time.perf_counter() - t0
            for topic in ("link", "passes", "commands"):
                await ws.send(json.dumps({"v": 1, "type": "subscribe", "topic": topic}))
            sent: dict[int, float] = {}

            async def ping() -> None:
                k = 0
                while not self.stop.is_set():
                    k += 1
                    sent[k] = time.perf_counter()
                    await ws.send(json.dumps({"v": 1, "type": "ping", "id": k}))
                    with contextlib.suppress(TimeoutError):
                        await asyncio.wait_for(self.stop.wait(), 0.5)

            pinger = asyncio.create_task(ping())
            try:
                while not self.stop.is_set():
                    try:
                        raw = await asyncio.wait_for(ws.recv(), 0.5)
                    except TimeoutError:
                        continue
                    message = json.loads(raw)
                    self.console_messages[message["type"]] += 1
                    if message["type"] == "pong" and message["id"] in sent:
                        self.console_pings_s.append(time.perf_counter() - sent.pop(message["id"]))
            except websockets.ConnectionClosed as exc:
                self.console_dropped = f"closed: {exc!r}"
            finally:
                pinger.cancel()
                with contextlib.suppress(asyncio.CancelledError, websockets.ConnectionClosed):
                    await pinger

    def ingest_lag(self) -> dict[str, float | None]:
        """The ground's worst lag behind the vehicle over the samples: frames generated
        onboard that it does not hold (estimated from the onboard clock: the link status's
        ``frames_behind``), and that in wall seconds at the frame rate over the samples
        (first to last: a backlog's catching up does not count as the rate)."""
        behind = [s["frames_behind"] for _, s in self.link if s["frames_behind"] is not None]
        worst = max(behind, default=None)
        rate = None
        if len(self.link) >= 2:
            (t0, first), (t1, last) = self.link[0], self.link[-1]
            if t1 > t0 and last["frames_received"] > first["frames_received"]:
                rate = (last["frames_received"] - first["frames_received"]) / (t1 - t0)
        return {
            "frames_behind_max": worst,
            "frames_per_wall_s": rate,
            "behind_max_wall_s": None if worst is None or not rate else worst / rate,
        }


async def until(predicate: Callable[[], bool], timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not await asyncio.to_thread(predicate):
        assert time.monotonic() < deadline, f"{what}: not within {timeout_s} s"
        await asyncio.sleep(0.2)


# The database and the planner are imported where they are used: the viewers' process
# (``python -m tests.server.link.load``) imports neither, and starts in a fraction of the time.


def state(readers: sessionmaker[Session], pass_id: str) -> str:
    from server.storage import repository as repo

    with readers() as session:
        return repo.get_pass(session=session, pass_id=pass_id, refresh=True).state


def count(readers: sessionmaker[Session], pass_id: str, stages: tuple[str, ...]) -> int:
    from server.storage import repository as repo

    with readers() as session:
        return len(repo.list_commands(session=session, pass_id=pass_id, stages=list(stages)))


OPEN_STAGES = ("queued", "released", "sent", "received")
#: The aborted pass's hold (onboard s, after 10 s of motion): the abort comes while the
#: pass runs however slowly its first stages are stored
CUT_HOLD_S = 600.0


def stored_pass(sessions: sessionmaker[Session], name: str, hold_s: float) -> str:
    """A scheduled pass of 10 s of motion (joints 1 and 4 by 10 degrees), then ``hold_s``
    onboard s holding; its id. Planning a long hold takes seconds of CPU: a scenario may
    store its passes while the server works on something else."""
    from tests.server.link.harness import store_pass

    return store_pass(sessions, name, (10.0, 0.0, 0.0, 10.0, 0.0, 0.0), hold_s)


async def fly(
    op: httpx.AsyncClient,
    sessions: sessionmaker[Session],
    readers: sessionmaker[Session],
    name: str,
    hold_s: float,
    flown: str | None = None,
) -> str:
    """Store and start a pass (10 s of motion, then ``hold_s`` onboard s holding; or start
    ``flown``, stored so by :func:`stored_pass`); its id once it is ``complete``."""
    if flown is None:
        flown = stored_pass(sessions, name, hold_s)
    response = await op.post(f"/api/passes/{flown}/start", json={"confirm": f"START {name}"})
    assert response.status_code == 200, response.text
    await until(lambda: state(readers, flown) == "complete", 300.0, f"{name} complete")
    return flown


async def abort_mid_pass(
    op: httpx.AsyncClient,
    sessions: sessionmaker[Session],
    readers: sessionmaker[Session],
    name: str,
    cut: str | None = None,
) -> tuple[str, httpx.Response, float]:
    """Start a long pass (``cut``, if stored already: :func:`stored_pass` with
    :data:`CUT_HOLD_S`), abort it once 12 commands executed: its id, the abort's answer
    and how long it took (s), once nothing of it is left open."""
    if cut is None:
        cut = stored_pass(sessions, name, CUT_HOLD_S)
    response = await op.post(f"/api/passes/{cut}/start", json={"confirm": f"START {name}"})
    assert response.status_code == 200, response.text
    await until(lambda: count(readers, cut, ("executed",)) >= 12, 120.0, "12 executed")
    assert state(readers, cut) == "running"
    t0 = time.perf_counter()
    response = await op.post(
        f"/api/passes/{cut}/abort", json={"confirm": f"ABORT {name}", "reason": "load"}
    )
    abort_s = time.perf_counter() - t0
    await until(lambda: count(readers, cut, OPEN_STAGES) == 0, 120.0, f"{name} resolved")
    return cut, response, abort_s


def spacecraft_process(
    port: int, token: str, scale: float, log: Path, seed: int = 4
) -> subprocess.Popen[bytes]:
    with log.open("ab") as out:
        return subprocess.Popen(
            [
                sys.executable,
                "-m",
                "hikoboshi",
                "spacecraft",
                "--ground",
                f"ws://127.0.0.1:{port}/api/link",
                "--token",
                token,
                "--time-scale",
                str(scale),
                "--seed",
                str(seed),
            ],
            stdout=out,
            stderr=subprocess.STDOUT,
        )


def peak_rss_bytes(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    raise AssertionError("no VmHWM")


def percentile(xs: list[float], q: float) -> float | None:
    if not xs:
        return None
    ordered = sorted(xs)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


@contextlib.contextmanager
def viewer_process(
    base: str, tokens: list[str], clients_per_token: int, pass_id: str, out: Path
) -> Iterator[ViewerLoad]:
    """:func:`viewers` in a process of their own (``python -m tests.server.link.load``), so
    that their own work never delays this process's probes: the probes then time the
    server, not a client starved by 200 others. Stopped (SIGTERM) on leaving, the reads in
    flight cut once every kind of read completed (:func:`_viewers_until_terminated`); the
    load's counts are read back into the
    :class:`ViewerLoad` yielded (meanwhile, ``out`` holds them so far:
    :func:`viewer_answers`)."""
    load = ViewerLoad()
    args = [base, pass_id, str(clients_per_token), str(out), *tokens]
    proc = subprocess.Popen([sys.executable, "-m", "tests.server.link.load", *args])
    try:
        yield load
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=300)
        counts = json.loads(out.read_text())
        load.status.update({int(k): v for k, v in counts["status"].items()})
        load.codes.update(counts["codes"])
        load.complete.update(counts["complete"])
        load.downloaded_bytes = counts["downloaded_bytes"]
        load.stale_connections = counts["stale_connections"]
        assert proc.returncode == 0 and not counts["errors"], counts["errors"]


def viewer_answers(out: Path) -> Counter[int]:
    """The viewers' answers by status so far, as their process last wrote them (every
    :data:`PROGRESS_S`; empty before the first time)."""
    try:
        counts = json.loads(out.read_text())
    except FileNotFoundError:
        return Counter()
    return Counter({int(k): v for k, v in counts["status"].items()})


#: How often the viewers' process writes its counts so far (wall s).
PROGRESS_S = 0.5


def _write_counts(load: ViewerLoad, out: Path, errors: list[str]) -> None:
    counts = {
        "status": load.status,
        "codes": load.codes,
        "complete": load.complete,
        "downloaded_bytes": load.downloaded_bytes,
        "stale_connections": load.stale_connections,
        "errors": errors[:5],
    }
    partial = out.with_suffix(".part")
    partial.write_text(json.dumps(counts))
    partial.replace(out)  # a reader never sees half a file


async def _viewers_until_terminated(
    base: str, pass_id: str, clients: int, out: Path, tokens: list[str]
) -> None:
    load = ViewerLoad()
    asyncio.get_running_loop().add_signal_handler(signal.SIGTERM, load.stop.set)
    tasks = viewers(base, tokens, clients, pass_id, load)
    while not load.stop.is_set():
        _write_counts(load, out, [])
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(load.stop.wait(), PROGRESS_S)
    # The reads in flight are waited for only until every kind of read has completed once
    # (most often it has already): then they are cut, and what they would have answered is
    # not counted (waiting them all out, heavy reads queued behind the others, took up to
    # 16 s more of wall).
    kinds = {path.split("?")[0].rsplit("/", 1)[-1] for path in viewer_paths(pass_id)}
    pending = set(tasks)
    while pending and not kinds <= set(load.complete):
        _, pending = await asyncio.wait(pending, timeout=PROGRESS_S)
    for task in pending:
        task.cancel()
    done = await asyncio.gather(*tasks, return_exceptions=True)
    errors = [
        repr(r)
        for r in done
        if isinstance(r, BaseException) and not isinstance(r, asyncio.CancelledError)
    ]
    _write_counts(load, out, errors)


if __name__ == "__main__":
    base, pass_id, clients, out, *tokens = sys.argv[1:]
    asyncio.run(_viewers_until_terminated(base, pass_id, int(clients), Path(out), tokens))
