"""The command stages' writes through the ground's database worker: the live path's batched
moves (:class:`~server.services.stage_writes.StageWrites`: the consecutive jobs of a group
commit read their rows in one statement and write them in a few) against the same moves one
job each (:func:`~server.services.command_stages.set_command_stage` in a closure: a read, an
update and an insert each, the live path's jobs before), in the same run on one database.

A stored pass with 950 queued commands; every command's four stage moves (``released``,
``sent``, ``received``, ``executed``) queued at once, one job each, as acknowledgements arrive
under load. With ``--hog`` a second thread keeps the interpreter busy meanwhile (the ground's
event loop under viewer load: the worker waits for the GIL at every statement's round trip).
Figures per mode: the wall time from the first job queued to the last committed, jobs a
second; the ratio batched / one job each (more is better) is the figure to compare.

    .venv/bin/python bench/bench_stage_writes.py [--database-url postgresql://...] [--hog]
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import emit
from bench_load import _own_schema
from sqlalchemy.orm import Session, sessionmaker

from server.services.clock import SystemClock
from server.services.command_stages import set_command_stage
from server.services.dbworker import Database, Publisher, frames_apart_for
from server.services.stage_writes import StageMove, StageWrites
from server.storage import repository as repo
from server.storage.db import make_engine, session_factory, sqlite_url, upgrade
from tests.server.link.harness import store_pass
from tests.server.storage.factories import make_commands

STAGES = ("released", "sent", "received", "executed")
COMMANDS = 950


def stage_job(pass_id: str, seq: int, stage: str, *, batched: bool) -> Any:
    """The job that moves command ``seq`` of the pass to ``stage`` now: the live path's
    (a batched :class:`StageMove`) or one :func:`set_command_stage` a job (before)."""
    clock = SystemClock()
    if batched:
        return StageWrites(clock).job([StageMove(pass_id, seq, stage, clock.time_ns(), "bench")])

    def job(session: Session) -> list[Any]:
        return set_command_stage(
            session,
            clock=clock,
            pass_id=pass_id,
            seq=seq,
            stage=stage,
            time_ns=clock.time_ns(),
            actor="bench",
        )

    return job


async def _burst(sessions: sessionmaker[Session], pass_id: str, batched: bool) -> dict[str, Any]:
    with sessions() as session:  # queued, as a start queues them
        repo.add_commands(
            session=session, pass_id=pass_id, commands=make_commands(COMMANDS), queued_at_ns=0
        )
        session.commit()
    db = Database(sessions, Publisher(), frames_apart=frames_apart_for(sessions))
    try:
        t0 = time.perf_counter()
        jobs = []
        for stage in STAGES:
            for seq in range(COMMANDS):
                job = stage_job(pass_id, seq, stage, batched=batched)
                jobs.append(asyncio.ensure_future(db.write(job)))
        await asyncio.gather(*jobs)  # a failed write fails the bench
        wall_s = time.perf_counter() - t0
    finally:
        await db.drain()
        db.close()
    with sessions() as session:
        stages = {c.stage for c in repo.list_commands(session=session, pass_id=pass_id)}
    return {"jobs": len(jobs), "wall_s": wall_s, "jobs_per_s": len(jobs) / wall_s, "stages": stages}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--database-url", default=None, help="default: SQLite in a temp dir")
    parser.add_argument("--hog", action="store_true", help="a thread keeps the GIL busy")
    args = parser.parse_args()
    stop = threading.Event()
    if args.hog:

        def spin() -> None:
            while not stop.is_set():
                sum(range(1000))

        threading.Thread(target=spin, name="hog", daemon=True).start()
    with tempfile.TemporaryDirectory() as tmp, _own_schema(args.database_url) as url:
        engine = make_engine(url or sqlite_url(Path(tmp)))
        upgrade(engine)
        sessions = session_factory(engine)
        figures: dict[str, Any] = {"backend": engine.dialect.name, "hog": args.hog}
        try:
            for name, batched in (("one_job_each", False), ("batched", True)):
                print(f"{name}: {4 * COMMANDS} stage moves", file=sys.stderr)
                pass_id = store_pass(sessions, name, (10.0, 0.0, 0.0, 10.0, 0.0, 0.0), 230.0)
                figures[name] = asyncio.run(_burst(sessions, pass_id, batched))
        finally:
            stop.set()
            engine.dispose()
    one, batched_ = figures["one_job_each"], figures["batched"]
    figures["ratio_batched_to_one_each"] = batched_["jobs_per_s"] / one["jobs_per_s"]
    for mode in (one, batched_):
        mode["stages"] = sorted(mode["stages"])
    emit(
        "stage_writes",
        figures,
        {
            "every_command_executed": one["stages"] == batched_["stages"] == ["executed"],
            "batched_faster": figures["ratio_batched_to_one_each"] > 1.0,
        },
    )


if __name__ == "__main__":
    main()
