"""The link's database worker (server/services/dbworker.py): on PostgreSQL the telemetry
frames are stored on a worker and connection of their own, so that a frame job never waits
behind the command stages' writes (under 200 viewer reads a loaded PostgreSQL took
seconds over a group of them, and the ground fell 25 s behind the vehicle); SQLite keeps
one worker, frames first in its queue."""

from __future__ import annotations

import asyncio
import threading

import pytest
from sqlalchemy import Engine, text
from sqlalchemy.orm import Session

from server.services.dbworker import Database, Publisher, frames_apart_for
from server.storage.db import session_factory

#: A hang guard, not a timing: how long the test waits for a job that must finish.
HANG_GUARD_S = 60.0


def test_frames_have_their_own_worker_on_postgresql_only(engine: Engine) -> None:
    assert frames_apart_for(session_factory(engine)) is (engine.dialect.name != "sqlite")


def test_a_frame_job_commits_while_the_command_stages_worker_is_held(engine: Engine) -> None:
    """A stage write holds the main worker (it waits on an event, as a write waits on a
    loaded database); a frame job submitted after it still commits, on its own connection,
    and the stage write then commits too."""
    if engine.dialect.name == "sqlite":
        pytest.skip("SQLite keeps one worker: one writer at a time")
    sessions = session_factory(engine)
    db = Database(sessions, Publisher(), frames_apart=frames_apart_for(sessions))
    held = threading.Event()
    release = threading.Event()
    stage_backend: list[int] = []

    def stage_write(session: Session) -> list[dict[str, object]]:
        stage_backend.append(int(session.execute(text("SELECT pg_backend_pid()")).scalar_one()))
        held.set()
        assert release.wait(HANG_GUARD_S), "never released"
        return []

    def frame_job(session: Session) -> tuple[str, int]:
        backend = session.execute(text("SELECT pg_backend_pid()")).scalar_one()
        return threading.current_thread().name, int(backend)

    async def scenario() -> tuple[tuple[str, int] | None, bool]:
        stage = asyncio.ensure_future(db.write(stage_write))
        assert await asyncio.to_thread(held.wait, HANG_GUARD_S)
        stored: asyncio.Future[tuple[str, int] | None] = asyncio.get_running_loop().create_future()
        db.submit_then(frame_job, stored.set_result)
        frame = await asyncio.wait_for(stored, HANG_GUARD_S)
        stage_pending = not stage.done()  # the stage write still holds its worker
        release.set()
        await asyncio.wait_for(stage, HANG_GUARD_S)
        return frame, stage_pending

    try:
        frame, stage_pending = asyncio.run(scenario())
    finally:
        release.set()
        db.close()
    assert frame is not None
    thread, frame_backend = frame
    assert thread == "ground-db-frames"
    assert stage_pending
    assert stage_backend and frame_backend != stage_backend[0]  # a connection of its own
