"""The command path's database worker rides a database outage through
(server/services/dbworker.py, docs/operations.md "A database outage"): PostgreSQL behind a
proxy that the test cuts (every connection reset, new ones refused) and restores. No write
fails for the outage, every one is applied once when the database is back, in order, and
the outage is counted; past the journal's bound a write is refused loudly, never dropped in
silence; at a stop a journal the database cannot take fails rather than hangs."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable
from typing import Any

import pytest
from sqlalchemy import select
from sqlalchemy.orm import Session

from server.services.dbworker import Database, JournalFull, Publisher
from server.storage import repository as repo
from server.storage.db import make_engine, session_factory, upgrade
from server.storage.models import EventRecord
from tests.server.cut_proxy import cut_proxy


def _write(i: int) -> Callable[[Session], list[dict[str, Any]]]:
    def job(session: Session) -> list[dict[str, Any]]:
        repo.add_event(session=session, time_ns=i, kind="test_write", actor=f"w{i}")
        return []

    return job


async def _until(predicate: Callable[[], bool], timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        await asyncio.sleep(0.02)


@pytest.fixture()
def migrated(postgres_schema_url: str) -> str:
    engine = make_engine(postgres_schema_url)
    upgrade(engine)
    engine.dispose()
    return postgres_schema_url


def test_writes_made_while_the_database_is_away_are_applied_once_in_order(
    migrated: str,
) -> None:
    with cut_proxy(migrated) as (proxy, through):
        engine = make_engine(through)
        db = Database(session_factory(engine), Publisher())

        async def scenario() -> list[BaseException | None]:
            before = [db.run(_write(i)) for i in range(20)]
            await asyncio.gather(*before)
            proxy.cut()
            during = [asyncio.ensure_future(db.run(_write(i))) for i in range(20, 320)]
            await _until(lambda: db.outage.down_since is not None, 30.0)
            await asyncio.sleep(1.0)  # the worker keeps trying; nothing fails meanwhile
            assert not any(f.done() for f in during)
            assert db.journal >= 300 - 64  # a group may be in its transaction
            proxy.restore()
            results = await asyncio.wait_for(asyncio.gather(*during, return_exceptions=True), 60.0)
            return [r if isinstance(r, BaseException) else None for r in results]

        try:
            failures = asyncio.run(scenario())
        finally:
            db.close()
            engine.dispose()
    assert failures == [None] * 300
    outage = db.outage.status(0)
    assert outage["reachable"] and outage["outages"] == 1
    assert outage["journal_peak"] >= 300 - 64 and outage["last_down_s"] >= 1.0
    reader = make_engine(migrated)
    with session_factory(reader)() as session:
        rows = session.execute(
            select(EventRecord.time_ns).where(EventRecord.kind == "test_write")
        ).all()
    reader.dispose()
    times = sorted(t for (t,) in rows)
    assert times == list(range(320))  # every write once


def test_a_full_journal_refuses_a_write_loudly_and_a_stop_does_not_hang(migrated: str) -> None:
    with cut_proxy(migrated) as (proxy, through):
        engine = make_engine(through)
        db = Database(session_factory(engine), Publisher(), journal_max=10)

        async def scenario() -> tuple[list[Any], BaseException | None]:
            await db.run(_write(0))
            proxy.cut()
            waiting = [asyncio.ensure_future(db.run(_write(i))) for i in range(1, 11)]
            await _until(lambda: db.outage.down_since is not None, 30.0)
            refused: BaseException | None = None
            try:
                await db.run(_write(99))
            except JournalFull as exc:
                refused = exc
            db.give_up(0.0)  # a stop with the database still away
            results = await asyncio.wait_for(asyncio.gather(*waiting, return_exceptions=True), 30.0)
            return results, refused

        try:
            results, refused = asyncio.run(scenario())
        finally:
            db.close()
            engine.dispose()
    assert isinstance(refused, JournalFull) and "10 writes wait" in str(refused)
    assert db.outage.refused == 1
    assert all(isinstance(r, Exception) for r in results)  # failed, each one, not hung


def test_a_frame_commit_that_finishes_as_the_outage_begins_does_not_end_it(
    migrated: str,
) -> None:
    """The frames' worker (PostgreSQL's own) commits, the connection is cut, the command
    worker's next write finds the database away, and only then does the frames' worker
    report its commit: the outage goes on (it ended at once, and a console read the database
    reachable mid-outage: the suite's failure of test_db_outage_e2e.py)."""
    with cut_proxy(migrated) as (proxy, through):
        engine = make_engine(through)
        db = Database(session_factory(engine), Publisher(), frames_apart=True)
        committed, outage_seen = threading.Event(), threading.Event()

        def on_commit(_seconds: float) -> None:  # after a commit, before it is reported
            if threading.current_thread().name == "ground-db-frames":
                committed.set()
                assert outage_seen.wait(30.0)

        db.on_commit = on_commit

        async def scenario() -> dict[str, Any]:
            done: asyncio.Future[None] = asyncio.get_running_loop().create_future()
            loop = asyncio.get_running_loop()
            db.submit_then(_write(0), lambda _: loop.call_soon_threadsafe(done.set_result, None))
            await _until(committed.is_set, 30.0)
            proxy.cut()
            write = asyncio.ensure_future(db.run(_write(1)))
            await _until(lambda: db.outage.down_since is not None, 30.0)
            outage_seen.set()
            await asyncio.wait_for(done, 30.0)  # the frame's commit, reported
            during = db.outage.status(db.journal)
            proxy.restore()
            await asyncio.wait_for(write, 60.0)
            return during

        try:
            during = asyncio.run(scenario())
        finally:
            db.close()
            engine.dispose()
    assert during["reachable"] is False, during
    after = db.outage.status(0)
    assert after["reachable"] and after["outages"] == 1, after
