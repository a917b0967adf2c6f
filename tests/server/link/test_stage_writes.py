"""The command stages' writes share their statements within a group commit
(server/services/stage_writes.py, server/services/db_batch.py).

The defect: every acknowledgement was a job of three round trips (read the row, update it,
insert the event); under 80 viewer reads at 20x on PostgreSQL the ground's database worker
filed some 25 a second while the pass asked for 150, and after an abort the last stages
reached the database minutes late (tests/server/link/test_load.py). Counted here in
statements, not timed: a group of acknowledgements costs a few statements, whatever its size,
and files exactly what one job each filed.
"""

from __future__ import annotations

import asyncio
import threading
from typing import Any

from sqlalchemy import Engine, event
from sqlalchemy.orm import Session, sessionmaker

from server.services.clock import ManualClock
from server.services.command_fates import CommandFates
from server.services.command_stages import set_command_stage
from server.services.dbworker import Database, Publisher, frames_apart_for
from server.services.stage_writes import StageMove, StageWrites
from server.storage import repository as repo
from server.storage.db import session_factory
from telemetry.wire import CommandAck, CommandStage
from tests.server.storage.factories import make_commands, store_pass

#: A hang guard, not a timing: how long the test waits for a job that must finish.
HANG_GUARD_S = 60.0
ACKS = 128


def _pass(sessions: sessionmaker[Session], n: int) -> str:
    with sessions() as session:
        record = store_pass(session, relay="TDRS-W")
        repo.add_commands(
            session=session, pass_id=record.id, commands=make_commands(n), queued_at_ns=0
        )
        session.commit()
        return record.id


def test_a_group_of_acknowledgements_costs_a_few_statements_not_three_each(
    engine: Engine,
) -> None:
    """128 acknowledgements queued behind a held job, so that they run in groups: far fewer
    statements than three a job, every stage and event filed in order."""
    sessions = session_factory(engine)
    pass_id = _pass(sessions, ACKS)
    db = Database(sessions, Publisher(), frames_apart=frames_apart_for(sessions))
    clock = ManualClock()
    fates = CommandFates(db=db, clock=clock)
    fates.expect(pass_id, list(range(ACKS)))
    held, release = threading.Event(), threading.Event()
    statements: list[str] = []

    def hold(session: Session) -> list[dict[str, Any]]:
        held.set()
        assert release.wait(HANG_GUARD_S), "never released"
        return []

    def count(conn: Any, cursor: Any, statement: str, *args: Any) -> None:
        if threading.current_thread().name == "ground-db":
            statements.append(statement)

    async def scenario() -> None:
        held_job = asyncio.ensure_future(db.write(hold))
        assert await asyncio.to_thread(held.wait, HANG_GUARD_S)
        for seq in range(ACKS):
            fates.file_ack(
                CommandAck(seq=seq, stage=CommandStage.RECEIVED, onboard_time_ns=1000 + seq), "sc"
            )
        event.listen(engine, "before_cursor_execute", count)
        release.set()
        await asyncio.wait_for(held_job, HANG_GUARD_S)
        await asyncio.wait_for(db.drain(), HANG_GUARD_S)

    try:
        asyncio.run(scenario())
    finally:
        release.set()
        event.remove(engine, "before_cursor_execute", count)
        db.close()
    groups = -(-ACKS // Database.MAX_GROUP)
    # per group: the rows read, their update, the events' insert (and the transaction's
    # own few); one job each took three statements a job: 384. SQLite inserts the events
    # one statement each (SQLAlchemy cannot tell their ids apart in one there), in process.
    per_event = 1 if engine.dialect.name == "sqlite" else 0
    assert len(statements) <= 8 * groups + per_event * ACKS, statements
    with sessions() as session:
        commands = repo.list_commands(session=session, pass_id=pass_id)
        events = repo.list_events(session=session, pass_id=pass_id, limit=ACKS + 1)
    assert len(commands) == ACKS and {c.stage for c in commands} == {"received"}
    assert all(c.received_at_ns == 1000 + c.seq for c in commands)
    assert [e.detail["seq"] for e in events.items] == list(range(ACKS))


def test_batched_moves_file_what_one_job_each_filed(engine: Engine) -> None:
    """The same moves (first sends, a retransmission's count, acknowledgements in and out of
    order, a refusal, the vehicle's word over an expiry, a seq no pass holds) filed one
    ``set_command_stage`` at a time on one pass and batched on another: the same rows, the
    same events in the same order."""
    sessions = session_factory(engine)
    one, batched = _pass(sessions, 6), _pass(sessions, 6)
    clock = ManualClock()

    def moves(pass_id: str) -> list[list[StageMove]]:
        first = [
            StageMove(pass_id, seq, stage, 10 + seq, transmissions=1)
            for seq in range(6)
            for stage in ("released", "sent")
        ]
        sc = "sc"
        return [
            first,
            [StageMove(pass_id, 1, None, transmissions=3),
             StageMove(pass_id, 2, None, transmissions=1)],
            [StageMove(pass_id, 0, "executed", 30, sc), StageMove(pass_id, 0, "received", 20, sc)],
            [StageMove(pass_id, 1, "received", 21, sc)],
            [StageMove(pass_id, 2, "rejected", 22, sc, reason="out_of_limits", detail="j3")],
            [StageMove(pass_id, 3, "expired", 23, detail="late"),
             StageMove(pass_id, 3, "executed", 33, sc)],
            [StageMove(pass_id, 4, "executed", 34, sc, transmissions=2)],
            [StageMove(None, 999, "executed", 35, sc, acked="executed")],
        ]  # fmt: skip

    with sessions() as session:
        for job in moves(one):
            for m in job:
                if m.pass_id is None:
                    continue  # the unknown seq: audited by the batch only, checked below
                row = repo.get_command(session=session, pass_id=one, seq=m.seq)
                if m.stage is None:
                    row.transmissions = max(row.transmissions, m.transmissions or 0)
                    continue
                set_command_stage(
                    session, clock=clock, pass_id=one, seq=m.seq, stage=m.stage, time_ns=m.time_ns,
                    actor=m.actor, reason=m.reason, detail=m.detail, transmissions=m.transmissions,
                )  # fmt: skip
        session.commit()
    with sessions() as session:
        results = StageWrites(clock)(session, [tuple(job) for job in moves(batched)])
        session.commit()
    assert [len(r) for r in results] == [12, 0, 1, 1, 1, 2, 1, 1]  # received after executed: none
    assert results[-1][0].kind == "command_ack_unknown"
    columns = ["seq", "stage", "reject_reason", "transmissions", "cancelled_at_ns"]
    columns += [f"{s}_at_ns" for s in ("released", "sent", "received", "executed", "rejected")]
    columns += ["expired_at_ns"]

    def stored(pass_id: str) -> tuple[list[tuple[Any, ...]], list[tuple[Any, ...]]]:
        with sessions() as session:
            rows = repo.list_commands(session=session, pass_id=pass_id)
            events = repo.list_events(session=session, pass_id=pass_id, limit=100).items
        return (
            [tuple(getattr(r, c) for c in columns) for r in rows],
            [(e.kind, e.actor, e.time_ns, e.detail) for e in sorted(events, key=lambda e: e.id)],
        )

    assert stored(batched) == stored(one)
    assert [e.id for r in results for e in r] == sorted(e.id for r in results for e in r)
