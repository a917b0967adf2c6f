"""What a transaction writes is published once, after its commit, typed
(server.services.event_log.publish_on_commit): never on a rollback, a savepoint's rollback
keeps the transaction's, and from a thread that is not the event loop's it reaches the
subscribers on the loop (SQLite and PostgreSQL)."""

from __future__ import annotations

import asyncio
import threading

import pytest
from sqlalchemy.engine import Engine

from server.services.events import PlanCreated, Recorded, on_commit, publish_on_commit, record
from server.services.publisher import Publisher
from server.storage.db import session_factory
from telemetry.alarm import AlarmPublic

PLAN = "0f0e0d0c-0000-4000-8000-00000000000a"


def _created(n: int) -> PlanCreated:
    return PlanCreated(
        actor=f"otto{n}", plan_id=PLAN, experiment="ptp", robot="ets7", robot_hash="h"
    )


def test_published_after_the_commit_once_and_never_on_a_rollback(engine: Engine) -> None:
    sessions = session_factory(engine)
    publisher = Publisher()
    got: list[Recorded] = []
    publisher.subscribe(got.append)
    publish_on_commit(sessions, publisher)
    publish_on_commit(sessions, publisher)  # hooked once, whatever the calls
    with sessions() as session:
        record(session, _created(1), 10)
        assert got == []  # written, not committed
        session.rollback()
        record(session, _created(2), 20)
        with session.begin_nested():
            record(session, _created(3), 30)
        savepoint = session.begin_nested()
        record(session, _created(4), 40)
        savepoint.rollback()  # its event goes, the transaction's stay
        session.commit()
        session.commit()  # nothing new: nothing again
    assert [(r.actor, r.time_ns) for r in got] == [("otto2", 20), ("otto3", 30)]
    assert all(isinstance(r.event, PlanCreated) and r.id > 0 for r in got)
    assert got[0].document()["detail"]["plan_id"] == PLAN


def test_a_commit_on_another_thread_is_published_on_the_loop(engine: Engine) -> None:
    sessions = session_factory(engine)

    async def scenario() -> tuple[list[str], set[int]]:
        publisher = Publisher()  # made on the loop: it delivers there
        got: list[str] = []
        threads: set[int] = set()
        alarms: list[AlarmPublic] = []

        def seen(r: Recorded) -> None:
            got.append(r.kind)
            threads.add(threading.get_ident())

        publisher.subscribe(seen)
        publisher.subscribe_alarms(alarms.append)
        publish_on_commit(sessions, publisher)

        def write() -> None:
            with sessions() as session:
                record(session, _created(5), 50)
                session.commit()

        await asyncio.to_thread(write)
        await asyncio.sleep(0)  # the loop runs what the thread handed it
        assert alarms == []
        return got, threads

    got, threads = asyncio.run(scenario())
    assert got == ["plan_created"]
    assert threads == {threading.get_ident()}  # asyncio.run's loop is this thread's


def test_anything_else_than_an_event_or_an_alarm_is_refused() -> None:
    with pytest.raises(TypeError, match="dict is not published"):
        Publisher().publish([{"kind": "pass_state"}])


def test_on_commit_keeps_items_in_order_after_the_events(engine: Engine) -> None:
    sessions = session_factory(engine)
    publisher = Publisher()
    order: list[str] = []
    publisher.subscribe(lambda r: order.append(r.kind))
    publisher.subscribe_alarms(lambda a: order.append(f"alarm {a.quantity}"))
    publish_on_commit(sessions, publisher)
    alarm = AlarmPublic.model_validate(
        {
            "id": "a", "pass_id": None, "quantity": "frame_age_s", "channel": "", "label": "age",
            "unit": "s", "direction": "high", "source": "limit", "severity": "watch",
            "current_severity": "watch", "state": "triggered", "acknowledged": False,
            "acknowledged_by": None, "acknowledged_time_ns": None, "comment": None,
            "limit": 10.0, "trigger_value": 11.0, "worst_value": 11.0, "last_value": 11.0,
            "count": 1, "raised_frame_seq": None, "raised_generation_time_ns": None,
            "raised_time_ns": 1, "updated_time_ns": 1, "cleared_generation_time_ns": None,
            "cleared_time_ns": None, "timeline": [], "detail": None,
        }
    )  # fmt: skip
    with sessions() as session:
        record(session, _created(6), 60)
        on_commit(session, alarm)
        assert order == []
        session.commit()
    assert order == ["plan_created", "alarm frame_age_s"]
