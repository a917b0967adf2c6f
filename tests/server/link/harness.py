"""The real ground service under uvicorn on loopback, and the spacecraft process in-process.

The server runs in a thread with its own event loop; the spacecraft, the REST client and the
assertions run in the test's loop. Both ends meet only on the wire, as in flight.
"""

from __future__ import annotations

import asyncio
import os
import subprocess
import tempfile
import threading
import time
from collections.abc import AsyncIterator, Callable, Iterator, Mapping
from contextlib import asynccontextmanager, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import uvicorn
from fastapi import FastAPI
from sqlalchemy.orm import Session, sessionmaker

from planner.dynamics import DynamicsWorkspace
from planner.experiments import PtpParams, plan_ptp
from planner.model import default_model
from planner.plan import Plan
from server.app import create_app
from server.settings import Settings
from server.storage import repository as repo
from server.storage.db import make_engine, read_session_factory, session_factory
from spacecraft.link import LinkConfig
from spacecraft.process import ProcessConfig, SpacecraftProcess
from spacecraft.vehicle_config import VehicleConfig
from telemetry.wire import TelemetryFrame

# the tokens and headers, as the link tests have always imported them from here
from tests.support.api import OPERATOR as OPERATOR
from tests.support.api import TOKENS
from tests.support.api import VIEWER as VIEWER
from tests.support.flight import flying
from tests.support.processes import free_port, health_when_up, serve_command

#: 10x: the server and the spacecraft share one process (and its GIL) here, and at 20x a
#: 50 ms stall of the ground's event loop on a loaded machine is a whole second onboard.
SCALE = 10.0


@dataclass
class Ground:
    app: FastAPI
    url: str
    sessions: sessionmaker[Session]
    #: for the tests' polling: a read takes no write lock on SQLite, so it never waits
    #: behind (or starves against) the ground's writer on a busy machine
    readers: sessionmaker[Session]

    @property
    def ws_url(self) -> str:
        return self.url.replace("http://", "ws://") + "/api/link"


@contextmanager
def running_ground(database_url: str, **overrides: Any) -> Iterator[Ground]:
    # The flight defaults (but for ``overrides``, settings): the ground and the spacecraft
    # share one process and its GIL here, and the windowed uplink loads every command up to
    # 120 s onboard ahead and sends it again until acknowledged, so a stalled ground event
    # loop delays nothing.
    scratch = None
    if "data_dir" not in overrides:  # its artifact cache, never the checkout's data/
        scratch = tempfile.TemporaryDirectory(prefix="hikoboshi-ground-")
        overrides["data_dir"] = Path(scratch.name)
    settings = Settings(database_url=database_url, tokens=TOKENS, **overrides)
    app = create_app(settings)
    port = free_port()
    config = uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning", lifespan="on")
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, name="uvicorn", daemon=True)
    thread.start()
    deadline = time.monotonic() + 20.0
    while not server.started:
        assert thread.is_alive() and time.monotonic() < deadline, "uvicorn did not start"
        time.sleep(0.01)
    engine = make_engine(database_url)
    try:
        yield Ground(
            app,
            f"http://127.0.0.1:{port}",
            session_factory(engine),
            read_session_factory(engine),
        )
    finally:
        server.should_exit = True
        thread.join(timeout=30.0)
        engine.dispose()
        if scratch is not None:
            scratch.cleanup()


@contextmanager
def serve_process(
    database_url: str, port: int, log: Path, env: Mapping[str, str]
) -> Iterator[subprocess.Popen[bytes]]:
    """``hikoboshi serve`` as a process of its own on ``port`` (output appended to
    ``log``), once its health answers; terminated afterwards."""
    environment = {**os.environ, "DATABASE_URL": database_url, **env}
    with log.open("ab") as out:
        proc = subprocess.Popen(
            serve_command(port), env=environment, stdout=out, stderr=subprocess.STDOUT
        )
    try:
        health_when_up(proc, f"http://127.0.0.1:{port}", output=lambda: log.read_text()[-3000:])
        yield proc
    finally:
        if proc.poll() is None:
            proc.terminate()
            # a guard against a hang only: a graceful stop flushes the writes queued, which
            # took over 30 s on a PostgreSQL shared by loaded test runs (test_restart.py)
            proc.wait(timeout=90)


def store_pass(
    sessions: sessionmaker[Session],
    name: str,
    goal_deg: tuple[float, ...],
    settle_s: float,
    edit: Callable[[Plan], Plan] | None = None,
) -> str:
    """A PTP plan (joints only moved by ``goal_deg``; changed by ``edit`` if given) and a
    scheduled pass of it."""
    plan = plan_ptp(
        DynamicsWorkspace(default_model()), PtpParams(goal_joints_deg=goal_deg, settle_s=settle_s)
    )
    # checked as the ground checks what it plans; an edit comes after (a test of what the
    # vehicle does with a plan the ground let through)
    plan = with_flight_rules(plan)
    if edit is not None:
        plan = edit(plan)
    return add_plan_and_pass(sessions, plan, name, now_ns=time.time_ns(), window_s=1200.0)


def with_flight_rules(plan: Plan) -> Plan:
    """``plan`` with the ground's flight-rules report (as ``POST /api/plans`` stores every
    plan; a pass's start refuses a plan without one), unless it has one already: checked
    against the shipped description its ``robot_hash`` names (a plan of no shipped robot, a
    made-up one, is stored as it is: a REST start refuses it as unchecked)."""
    if plan.flight_rules is not None:
        return plan
    from planner.description import EXAMPLES_DIR, load_robot

    for path in sorted(EXAMPLES_DIR.glob("*/*.toml")):
        description = load_robot(path)
        if description.content_sha256 == plan.robot_hash:
            return description.checked(plan)[0]
    return plan


def add_plan_and_pass(sessions: Any, plan: Plan, name: str, *, now_ns: int, window_s: float) -> str:
    """Store ``plan`` (with its flight-rules report: :func:`with_flight_rules`) and a pass of
    it scheduled from ``now_ns`` for ``window_s``; its id."""
    plan = with_flight_rules(plan)
    with sessions() as session:
        plan_record = repo.add_plan(session=session, plan=plan, created_at_ns=now_ns)
        record = repo.add_pass(
            session=session,
            name=name,
            plan_id=plan_record.id,
            aos_time_ns=now_ns,
            los_time_ns=now_ns + round(window_s * 1e9),
            relay="TDRS-W",
            created_at_ns=now_ns,
        )
        session.commit()
        return str(record.id)


def spacecraft(
    ground: Ground,
    *,
    vehicle: VehicleConfig | None = None,
    truth_log: Path | None = None,
    **link: Any,
) -> tuple[SpacecraftProcess, list[TelemetryFrame]]:
    """The spacecraft process at SCALE (flying ``vehicle``, faults included, and writing its
    truth log to ``truth_log`` if given), and the list every frame it generates is added
    to."""
    process = SpacecraftProcess(
        ProcessConfig(
            ground_url=ground.ws_url,
            token="s-token",
            time_scale=SCALE,
            vehicle=vehicle or VehicleConfig(),
            truth_log=truth_log,
            uplink=LinkConfig(seed=11, **link),
            downlink=LinkConfig(seed=12, **link),
            seed=3,
            backoff_initial_s=0.05,
            backoff_max_s=0.5,
            drain_timeout_s=30.0,
        )
    )
    return process, generated_frames(process)


def generated_frames(process: SpacecraftProcess) -> list[TelemetryFrame]:
    """The list every telemetry frame the process generates from now on is added to."""
    generated: list[TelemetryFrame] = []
    add = process.store.add

    def recording_add(frames: Any) -> None:
        frames = list(frames)
        generated.extend(frames)
        add(frames)

    process.store.add = recording_add  # type: ignore[method-assign]
    return generated


async def wait_for(predicate: Callable[[], Any], timeout_s: float, what: str) -> Any:
    deadline = time.monotonic() + timeout_s
    while True:
        value = await asyncio.to_thread(predicate)
        if value:
            return value
        if time.monotonic() > deadline:
            raise TimeoutError(f"{what}: not within {timeout_s} s")
        await asyncio.sleep(0.05)


def pass_state(ground: Ground, pass_id: str) -> str:
    with ground.readers() as session:
        return repo.get_pass(session=session, pass_id=pass_id).state


@asynccontextmanager
async def in_contact(
    process: SpacecraftProcess, url: str, *, timeout_s: float = 5.0, drain_s: float = 40.0
) -> AsyncIterator[httpx.AsyncClient]:
    """``process`` flying (:func:`tests.support.flight.flying`) and a REST client of the
    ground at ``url`` (``timeout_s`` a request), given once the spacecraft is connected."""
    async with (
        flying(process, drain_s),
        httpx.AsyncClient(base_url=url, timeout=timeout_s) as client,
    ):
        await connected(client)
        yield client


async def start_pass(client: httpx.AsyncClient, pass_id: str, name: str) -> httpx.Response:
    """The operator's confirmed start of the pass ``name``, which must be accepted."""
    response = await client.post(
        f"/api/passes/{pass_id}/start", json={"confirm": f"START {name}"}, headers=OPERATOR
    )
    assert response.status_code == 200, response.text
    return response


async def connected(client: httpx.AsyncClient) -> None:
    async def probe() -> bool:
        response = await client.get("/api/link/status", headers=VIEWER)
        return bool(response.json()["connected"])

    deadline = time.monotonic() + 20.0
    while not await probe():
        assert time.monotonic() < deadline, "the spacecraft did not connect"
        await asyncio.sleep(0.05)


def deleted_from_ns(ground: Ground, pass_id: str) -> int:
    """The tag from which the abort's ``schedule_delete`` deleted the schedule."""
    with ground.readers() as session:
        page = repo.list_events(session=session, pass_id=pass_id, kinds=["schedule_deleted"])
    [event] = page.items
    return int(event.detail["from_time_ns"])


def settled(ground: Ground, pass_id: str) -> bool:
    """The pass has ended, the spacecraft's frames reach past its telemetry window, and the
    ground is done asking about commands in flight (all answered, or the queries used up):
    stopping the spacecraft now loses nothing of the pass."""
    with ground.readers() as session:
        record = repo.get_pass(session=session, pass_id=pass_id)
        outstanding = repo.list_commands(
            session=session, pass_id=pass_id, stages=("sent", "received")
        )
    newest = ground.app.state.downlink.newest
    runner = ground.app.state.runner
    resolved = not outstanding or (runner.active_pass_id is None and not runner.resolving)
    return (
        record.state in ("complete", "aborted", "safed")
        and record.telemetry_end_ns is not None
        and newest is not None
        and newest[1] >= record.telemetry_end_ns
        and resolved
    )


# -- a pass across a ground's restart, takeover or database outage: what the vehicle did ---


def executed_on_board(
    readers: sessionmaker[Session], process: SpacecraftProcess, pass_id: str, n: int
) -> bool:
    """The vehicle's own record (the archive lags it on a loaded database): the pass's
    first ``n`` commands executed."""
    with readers() as session:
        first = repo.list_commands(session=session, pass_id=pass_id, limit=n)
    outcomes = [process.vehicle.outcome(c.seq) for c in first]
    return len(first) == n and all(a is not None and a.stage.value == "executed" for a in outcomes)


def pass_resolved(readers: sessionmaker[Session], pass_id: str) -> bool:
    """The pass has ended and none of its commands waits for its fate."""
    with readers() as session:
        ended = repo.get_pass(session=session, pass_id=pass_id).state in ("complete", "aborted")
        waiting = repo.list_commands(
            session=session, pass_id=pass_id, stages=("queued", "released", "sent", "received")
        )
    return ended and not waiting


def assert_stages_are_the_vehicles(commands: list[Any], process: SpacecraftProcess) -> None:
    """Command by command: the stage is the vehicle's own record (executed, at its tag, or
    rejected), or ``expired`` for one it never had; nothing left open."""
    for c in commands:
        ack = process.vehicle.outcome(c.seq)
        if c.stage == "expired":
            assert ack is None, (c.seq, c.stage, ack)
        else:
            assert ack is not None and c.stage == ack.stage.value, (c.seq, c.stage, ack)
            assert c.stage in ("executed", "rejected"), (c.seq, c.stage)
            if c.stage == "executed":
                assert c.executed_at_ns == c.execute_time_ns


def assert_every_frame_once(
    record: Any, frames: list[int], generated: list[TelemetryFrame]
) -> None:
    """Every frame the vehicle generated in the pass's telemetry window is archived, once
    (``frames``: the archive's seqs of the pass, in order)."""
    assert record.telemetry_start_ns is not None and record.telemetry_end_ns is not None
    window = sorted(
        f.seq
        for f in generated
        if record.telemetry_start_ns <= f.generation_time_ns < record.telemetry_end_ns
    )
    assert frames == window


def spacecraft_of_grounds(
    ports: tuple[int, ...], *, scale: float, seed: int, drain_timeout_s: float
) -> SpacecraftProcess:
    """The spacecraft process given the link of every ground on ``ports`` (a holder and its
    standbys, tried in order), reconnecting fast; its links seeded from ``seed``."""
    urls = [f"ws://127.0.0.1:{port}/api/link" for port in ports]
    return SpacecraftProcess(
        ProcessConfig(
            ground_url=urls[0],
            standby_urls=tuple(urls[1:]),
            token="s-token",
            time_scale=scale,
            uplink=LinkConfig(seed=10 * seed + 1),
            downlink=LinkConfig(seed=10 * seed + 2),
            seed=seed,
            backoff_initial_s=0.05,
            backoff_max_s=0.3,
            drain_timeout_s=drain_timeout_s,
        )
    )
