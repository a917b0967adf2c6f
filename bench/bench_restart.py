"""A graceful restart (SIGTERM) of the ground mid-motion, down for a chosen wall time, at 20x:
what became of the pass (docs/protocol.md, "Resuming after a gap").

A real ``hikoboshi serve`` (the signal is real) and the spacecraft process in this one's
event loop (it reconnects by itself); a slow PTP motion long enough that a restart of 10 s
(200 s onboard at 20x, past the 120 s lead window) lands in mid-motion. Prints the outcome
sentence, the stages' counts, the vehicle's refusals by reason and the cancellation's
reason, as JSON.

    PYTHONPATH=. .venv/bin/python bench/bench_restart.py --down-s 10
    PYTHONPATH=. .venv/bin/python bench/bench_restart.py --down-s 60 \\
        --database-url postgresql+psycopg://postgres@127.0.0.1:5432/test
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import signal
import tempfile
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import sqlalchemy

from planner.dynamics import DynamicsWorkspace
from planner.experiments import PtpParams, plan_ptp
from planner.model import default_model
from server.storage import repository as repo
from server.storage.db import (
    make_engine,
    read_session_factory,
    session_factory,
    sqlite_url,
    upgrade,
)
from server.storage.models import EventRecord
from spacecraft.link import LinkConfig
from spacecraft.process import ProcessConfig, SpacecraftProcess
from tests.server.link.harness import (
    OPERATOR,
    add_plan_and_pass,
    serve_process,
    wait_for,
)
from tests.support.processes import free_port

TOKENS = "o-token=otto:operator,v-token=vera:viewer,s-token=ets7:spacecraft"


def run(
    database_url: str, down_s: float, scale: float, stop_after: int, log: Path
) -> dict[str, Any]:
    port = free_port()
    engine = make_engine(database_url)
    upgrade(engine)
    sessions, readers = session_factory(engine), read_session_factory(engine)
    # 60 deg on joints 1 and 4 at 4 % of the rate limit: some 20 minutes of motion onboard
    plan = plan_ptp(
        DynamicsWorkspace(default_model()),
        PtpParams(
            goal_joints_deg=(60.0, 0.0, 0.0, 60.0, 0.0, 0.0), rate_fraction=0.04, settle_s=30.0
        ),
    )
    pass_id = add_plan_and_pass(
        sessions, plan, f"restart-{time.time_ns()}", now_ns=time.time_ns(), window_s=7200.0
    )
    process = SpacecraftProcess(
        ProcessConfig(
            ground_url=f"ws://127.0.0.1:{port}/api/link",
            token="s-token",
            time_scale=scale,
            uplink=LinkConfig(seed=21),
            downlink=LinkConfig(seed=22),
            seed=5,
            backoff_initial_s=0.05,
            backoff_max_s=0.3,
            drain_timeout_s=90.0,
        )
    )
    env = {"HIKOBOSHI_TOKENS": TOKENS}

    def executed_on_board(n: int) -> bool:
        with readers() as session:
            first = repo.list_commands(session=session, pass_id=pass_id, limit=n)
        outcomes = [process.vehicle.outcome(c.seq) for c in first]
        return len(first) == n and all(
            a is not None and a.stage.value == "executed" for a in outcomes
        )

    def ended() -> bool:
        with readers() as session:
            state = repo.get_pass(session=session, pass_id=pass_id).state
            waiting = repo.list_commands(
                session=session, pass_id=pass_id, stages=("queued", "released", "sent", "received")
            )
        return state in ("complete", "aborted", "safed") and not waiting

    async def scenario() -> None:
        stop = asyncio.Event()
        task = asyncio.create_task(process.run(stop))
        try:
            with serve_process(database_url, port, log, env) as first:
                async with httpx.AsyncClient(
                    base_url=f"http://127.0.0.1:{port}", timeout=30.0
                ) as c:
                    while not (await c.get("/api/link/status", headers=OPERATOR)).json()[
                        "connected"
                    ]:
                        await asyncio.sleep(0.05)
                    r = await c.post(
                        f"/api/passes/{pass_id}/start",
                        json={"confirm": f"START {plan_name}"},
                        headers=OPERATOR,
                    )
                    assert r.status_code == 200, r.text
                await wait_for(lambda: executed_on_board(stop_after), 120.0, "commands executed")
                first.send_signal(signal.SIGTERM)
                await asyncio.to_thread(first.wait, 90.0)
            await asyncio.sleep(down_s)
            with serve_process(database_url, port, log, env):
                await wait_for(ended, 3600.0, "the pass ended, resolved")
                stop.set()
                await asyncio.wait_for(task, 100.0)
        finally:
            stop.set()
            await asyncio.wait_for(task, 100.0)

    with readers() as session:
        plan_name = repo.get_pass(session=session, pass_id=pass_id).name
    started = time.monotonic()
    asyncio.run(scenario())
    with sessions() as session:
        record = repo.get_pass(session=session, pass_id=pass_id)
        rows = repo.list_commands(session=session, pass_id=pass_id)
        cancelled = repo.list_events(
            session=session, pass_id=pass_id, kinds=["commands_cancelled"]
        ).items
        out = {
            "database": database_url.split(":")[0],
            "down_s": down_s,
            "scale": scale,
            "wall_s": round(time.monotonic() - started, 1),
            "state": record.state,
            "reason": record.state_reason,
            "commands": len(rows),
            "stages": dict(Counter(r.stage for r in rows)),
            "rejected_by_reason": dict(
                Counter(r.reject_reason for r in rows if r.stage == "rejected")
            ),
            "vehicle_refusals": dict(
                Counter(
                    a.reason.value
                    for a in (process.vehicle.outcome(r.seq) for r in rows)
                    if a is not None and a.stage.value == "rejected" and a.reason is not None
                )
            ),
            "cancelled_reasons": [e.detail.get("reason") for e in cancelled],
            "away_onboard_s": _away_onboard_s(session, pass_id),
        }
    engine.dispose()
    return out


def _away_onboard_s(session: Any, pass_id: str) -> float | None:
    """Onboard s from the handover (``ground_stopped``) to the next ``hello`` read."""
    [stopped] = repo.list_events(session=session, pass_id=pass_id, kinds=["ground_stopped"]).items
    at_ns = stopped.detail.get("onboard_time_ns")
    hellos = session.scalars(
        sqlalchemy.select(EventRecord).where(EventRecord.kind == "link_hello")
    ).all()
    later = sorted(
        h.detail["onboard_time_ns"] for h in hellos if h.detail["onboard_time_ns"] > at_ns
    )
    return None if at_ns is None or not later else round((later[0] - at_ns) / 1e9, 1)


@contextlib.contextmanager
def fresh_database(url: str | None, tmp: Path) -> Iterator[str]:
    """``url``'s server with a database of its own for this run (PostgreSQL: created and
    dropped), or a SQLite file under ``tmp``."""
    if url is None:
        yield sqlite_url(tmp)
        return
    name = f"bench_restart_{time.time_ns()}"
    admin = sqlalchemy.create_engine(url, isolation_level="AUTOCOMMIT")
    with admin.connect() as conn:
        conn.execute(sqlalchemy.text(f"CREATE DATABASE {name}"))
    try:
        yield sqlalchemy.make_url(url).set(database=name).render_as_string(hide_password=False)
    finally:
        with admin.connect() as conn:
            conn.execute(sqlalchemy.text(f"DROP DATABASE {name} WITH (FORCE)"))
        admin.dispose()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--database-url", default=None)
    parser.add_argument("--down-s", type=float, default=10.0)
    parser.add_argument("--scale", type=float, default=20.0)
    parser.add_argument(
        "--stop-after", type=int, default=200, help="commands executed before SIGTERM"
    )
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp, fresh_database(args.database_url, Path(tmp)) as url:
        result = run(url, args.down_s, args.scale, args.stop_after, Path(tmp) / "serve.log")
        print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
