"""Telemetry frames behind a burst of command-stage writes on the link's database worker
on one worker (SQLite's, and PostgreSQL's before) or on a worker of their own
(``frames_apart``, PostgreSQL's now), in the same run on one database.

A stored pass and 950 queued commands; every command's four stage moves (``released``,
``sent``, ``received``, ``executed``: what the uplink and the acknowledgements write, as
their batched moves, bench/bench_stage_writes.py) are queued at once, one job each, as
acknowledgements arrive under load;
meanwhile a telemetry message of 20 frames is handed to the worker every 0.1 s (200
frames/s: 10 Hz at 20x) until the stage writes are done. Figures per mode: each frame
job's wall time from hand-over to commit (p50, p99, max), the frames stored, and how long
the stage writes took; the ratio one worker / apart of the frames' p99.

    .venv/bin/python bench/bench_frames_apart.py [--database-url postgresql://...]
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import emit
from bench_ingest import make_frames
from bench_load import _own_schema
from bench_stage_writes import stage_job
from sqlalchemy.orm import Session, sessionmaker

from server.services.dbworker import Database, Publisher
from server.storage import repository as repo
from server.storage.db import make_engine, session_factory, sqlite_url, upgrade
from tests.server.link.harness import store_pass
from tests.server.link.load import percentile
from tests.server.storage.factories import make_commands

STAGES = ("released", "sent", "received", "executed")
COMMANDS = 950
MESSAGE_FRAMES = 20
MESSAGE_PERIOD_S = 0.1


async def _burst(sessions: sessionmaker[Session], pass_id: str, apart: bool) -> dict[str, Any]:
    with sessions() as session:  # queued, as a start queues them
        repo.add_commands(
            session=session, pass_id=pass_id, commands=make_commands(COMMANDS), queued_at_ns=0
        )
        session.commit()
    seqs = list(range(COMMANDS))
    frames = make_frames(20_000)
    db = Database(sessions, Publisher(), frames_apart=apart)
    latencies: list[float] = []
    stored = 0
    try:
        t0 = time.perf_counter()
        stage_jobs = []
        for stage in STAGES:
            for seq in seqs:
                job = stage_job(pass_id, seq, stage, batched=True)  # the live path's
                stage_jobs.append(asyncio.ensure_future(db.write(job)))
        stages = asyncio.gather(*stage_jobs)
        k = 0
        inflight: list[asyncio.Future[None]] = []
        while not stages.done():
            batch = frames[k : k + MESSAGE_FRAMES]
            k += MESSAGE_FRAMES
            handed = time.perf_counter()
            done: asyncio.Future[None] = asyncio.get_running_loop().create_future()

            def store(session: Session, batch: list[Any] = batch) -> int:
                result = repo.ingest_frames(
                    session=session, pass_id=pass_id, frames=batch, reception_time_ns=0
                )
                return result.inserted

            def then(n: int | None, handed: float = handed, done: Any = done) -> None:
                nonlocal stored
                latencies.append(time.perf_counter() - handed)
                stored += n or 0
                done.set_result(None)

            db.submit_then(store, then)
            inflight.append(done)
            await asyncio.sleep(MESSAGE_PERIOD_S)
        await stages  # a failed stage write fails the bench
        stages_s = time.perf_counter() - t0
        await asyncio.gather(*inflight)
    finally:
        await db.drain()
        db.close()
    if not latencies:
        stages.result()
    return {
        "stage_jobs": len(stage_jobs),
        "stage_writes_s": stages_s,
        "frames_stored": stored,
        "frame_commit_p50_s": statistics.median(latencies),
        "frame_commit_p99_s": percentile(latencies, 0.99),
        "frame_commit_max_s": max(latencies),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--database-url", default=None, help="default: SQLite in a temp dir")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp, _own_schema(args.database_url) as url:
        engine = make_engine(url or sqlite_url(Path(tmp)))
        upgrade(engine)
        sessions = session_factory(engine)
        figures: dict[str, Any] = {"backend": engine.dialect.name}
        try:
            for name, apart in (("one_worker", False), ("frames_apart", True)):
                print(f"{name}: a burst of stage writes with frames arriving", file=sys.stderr)
                pass_id = store_pass(sessions, name, (10.0, 0.0, 0.0, 10.0, 0.0, 0.0), 230.0)
                figures[name] = asyncio.run(_burst(sessions, pass_id, apart))
        finally:
            engine.dispose()
    one, apart = figures["one_worker"], figures["frames_apart"]
    figures["frame_commit_p99_ratio_one_to_apart"] = (
        one["frame_commit_p99_s"] / apart["frame_commit_p99_s"]
    )
    emit(
        "frames_apart",
        figures,
        {"frames_wait_less_apart": apart["frame_commit_p99_s"] < one["frame_commit_p99_s"]},
    )


if __name__ == "__main__":
    main()
