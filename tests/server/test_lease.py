"""The command lease (server/storage/lease.py, server/services/authority.py): one holder at a
time, its fencing token raised at every acquisition, a stale ground's writes refused by the
database and never applied, a standby taking a lease that expired or was released, and on
SQLite a second ground refused at its start. Expiry is made by writing the row's expiry into
the past, never by waiting for the wall clock."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from sqlalchemy import Engine, update
from sqlalchemy.exc import DBAPIError
from sqlalchemy.orm import Session

from server.services.authority import (
    CommandAuthority,
    LeasePolicy,
    SecondGround,
    hold_sqlite_file,
)
from server.services.dbworker import Database, Publisher
from server.storage import lease as leases
from server.storage import repository as repo
from server.storage.db import make_engine, session_factory, upgrade
from server.storage.errors import LeaseLost
from server.storage.lease import Lease, LeaseRow
from server.storage.models import GroundLease

NAME = "vehicle"


def _acquire(engine: Engine, holder: str, *, ttl_s: float = 30.0) -> Lease | LeaseRow:
    with session_factory(engine)() as session:
        got = leases.acquire(session, NAME, holder, ttl_s)
        session.commit()
        return got


def _expire(engine: Engine) -> None:
    """The holder died long ago: its expiry lies in the past on the database's clock."""
    with session_factory(engine)() as session:
        session.execute(update(GroundLease).values(expires_s=0.0))
        session.commit()


def test_one_holder_at_a_time_and_each_acquisition_raises_the_token(engine: Engine) -> None:
    a = _acquire(engine, "ground-a")
    assert isinstance(a, Lease) and a.token == 1 and a.expires_s > a.now_s
    b = _acquire(engine, "ground-b")
    assert isinstance(b, LeaseRow) and b.held and b.holder == "ground-a" and b.token == 1
    _expire(engine)
    b = _acquire(engine, "ground-b")
    assert isinstance(b, Lease) and b.token == 2
    with session_factory(engine)() as session:
        # the old holder's renewal finds another token: the lease is lost
        assert leases.renew(session, a, 30.0) is None
        renewed = leases.renew(session, b, 30.0)
        session.commit()
    assert renewed is not None and renewed.token == 2 and renewed.expires_s >= b.expires_s


def test_a_released_lease_is_taken_at_once_with_a_higher_token(engine: Engine) -> None:
    a = _acquire(engine, "ground-a")
    assert isinstance(a, Lease)
    with session_factory(engine)() as session:
        assert leases.release(session, a)
        session.commit()
    with session_factory(engine)() as session:
        row = leases.read(session, NAME)
    assert row is not None and not row.held and row.token == 1
    b = _acquire(engine, "ground-b")
    assert isinstance(b, Lease) and b.token == 2


def test_a_stale_ground_s_writes_are_refused_and_never_applied(engine: Engine) -> None:
    """The database worker fences every transaction: once another ground acquired the
    lease, the old holder's jobs all fail with LeaseLost and nothing of them is stored;
    the new holder's are."""
    a = _acquire(engine, "ground-a")
    assert isinstance(a, Lease)

    def plan_writer(name: str) -> Callable[[Session], list[dict[str, object]]]:
        """A write of the command path: an audit row naming ``name``."""

        def job(session: Session) -> list[dict[str, object]]:
            repo.add_event(session=session, time_ns=1, kind="test_write", actor=name)
            return []

        return job

    async def scenario() -> tuple[list[BaseException | None], list[BaseException | None]]:
        stale = Database(session_factory(engine), Publisher())
        fresh = Database(session_factory(engine), Publisher())
        try:
            stale.fence = lambda session: leases.fence(session, a)
            ok = await stale.run(plan_writer("before"))  # still the holder: applied
            assert ok == []
            _expire(engine)
            b = _acquire(engine, "ground-b")
            assert isinstance(b, Lease) and b.token == 2
            fresh.fence = lambda session: leases.fence(session, b)
            refused = await asyncio.gather(
                *(stale.run(plan_writer(f"stale-{i}")) for i in range(5)), return_exceptions=True
            )
            applied = await asyncio.gather(fresh.run(plan_writer("fresh")), return_exceptions=True)
            return [r if isinstance(r, BaseException) else None for r in refused], [
                r if isinstance(r, BaseException) else None for r in applied
            ]
        finally:
            stale.close()
            fresh.close()

    refused, applied = asyncio.run(scenario())
    assert all(isinstance(r, LeaseLost) for r in refused), refused
    assert "ground-b" in str(refused[0]) and "token 1" in str(refused[0])
    assert applied == [None]
    with session_factory(engine)() as session:
        names = {e.actor for e in repo.list_events(session=session, kinds=["test_write"]).items}
    assert names == {"before", "fresh"}


@pytest.fixture()
def postgres_engine(postgres_schema_url: str) -> Iterator[Engine]:
    engine = make_engine(postgres_schema_url)
    upgrade(engine)
    try:
        yield engine
    finally:
        engine.dispose()


def test_an_acquisition_waits_for_the_writes_in_flight_under_the_old_token(
    postgres_engine: Engine,
) -> None:
    """PostgreSQL's locking (FOR KEY SHARE in the fence, FOR UPDATE in the acquisition):
    a takeover cannot slip between a stale ground's fence and its commit. (SQLite gets the
    same order from BEGIN IMMEDIATE: one writer at a time.)"""
    engine = postgres_engine
    a = _acquire(engine, "ground-a")
    assert isinstance(a, Lease)
    _expire(engine)
    taken = threading.Event()
    result: list[Lease | LeaseRow] = []
    with session_factory(engine)() as writer:
        leases.fence(writer, a)  # the old holder's transaction is in flight

        def take_over() -> None:
            result.append(_acquire(engine, "ground-b"))
            taken.set()

        thread = threading.Thread(target=take_over)
        thread.start()
        # blocked behind the write in flight, however long we look
        assert not taken.wait(0.5)
        writer.commit()
    thread.join(30.0)
    assert taken.is_set() and isinstance(result[0], Lease) and result[0].token == 2
    with session_factory(engine)() as session, pytest.raises(LeaseLost):
        leases.fence(session, a)


class _Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def test_the_holder_commands_only_while_its_last_renewal_is_recent(engine: Engine) -> None:
    """may_command on the ground's own monotonic clock: valid for ttl - renew after the
    start of the last successful renewal; a standby is refused with the holder named."""
    clock = _Clock()
    policy_a = LeasePolicy(name=NAME, holder="ground-a", ttl_s=5.0, renew_s=1.0)
    a = CommandAuthority(session_factory(engine), policy_a, monotonic=clock)
    b = CommandAuthority(
        session_factory(engine), LeasePolicy(name=NAME, holder="ground-b"), monotonic=clock
    )
    assert a.try_acquire() and a.may_command() and a.refusal() is None
    assert not b.try_acquire() and not b.may_command()
    refusal = b.refusal()
    assert refusal is not None and refusal.code == "standby" and "ground-a" in refusal.message
    assert b.status()["role"] == "standby" and b.status()["lease_holder"] == "ground-a"
    clock.now += 3.9
    assert a.may_command()
    clock.now += 0.2  # 4.1 s since the renewal began: past ttl - renew
    assert not a.may_command() and a.holder
    lapsing = a.refusal()
    assert lapsing is not None and lapsing.code == "command_lease_lapsing"
    a._renew()  # the database answers again, the token unchanged: valid again
    assert a.may_command()
    # a standby reads the record, and the database refuses its writes (SQLite has no
    # standby: a ground without the lease is refused every transaction)
    with session_factory(engine)() as session:
        if engine.dialect.name == "sqlite":
            with pytest.raises(LeaseLost, match="does not hold"):
                b.fence(session)
        else:
            b.fence(session)
            assert leases.read(session, NAME) is not None
            with pytest.raises(DBAPIError, match=r"read-only transaction"):
                repo.add_event(session=session, time_ns=1, kind="test_write", actor="standby")
    with session_factory(engine)() as session:
        a.fence(session)
        repo.add_event(session=session, time_ns=1, kind="test_write", actor="holder")
        session.commit()
        assert [e.actor for e in repo.list_events(session=session).items] == ["holder"]


def test_a_takeover_takes_no_link_until_its_first_steps_have_settled(engine: Engine) -> None:
    """A standby whose keeper takes a released lease over commands at once, but refuses the
    vehicle's link (and starts) with ``taking_over`` until its takeover callback says it has
    settled (what the ground gone left unpublished goes out first: docs/operations.md)."""
    if engine.dialect.name == "sqlite":
        pytest.skip("one ground a file: no standby to take over")
    a = CommandAuthority(session_factory(engine), LeasePolicy(name=NAME, holder="ground-a"))
    assert a.try_acquire()
    b = CommandAuthority(
        session_factory(engine), LeasePolicy(name=NAME, holder="ground-b", ttl_s=3, renew_s=0.1)
    )
    seen: list[tuple[bool, str | None]] = []

    async def scenario() -> None:
        took_over = asyncio.Event()

        async def on_acquired() -> None:
            refusal = b.refusal()
            seen.append((b.may_command(), refusal.code if refusal else None))
            b.settled()
            refusal = b.refusal()
            seen.append((b.may_command(), refusal.code if refusal else None))
            took_over.set()

        async def on_lost(_: str) -> None:
            raise AssertionError("b held nothing to lose")

        b.start(on_acquired=on_acquired, on_lost=on_lost)
        try:
            refusal = b.refusal()
            assert refusal is not None and refusal.code == "standby"
            await a.close()  # a graceful stop: released
            await asyncio.wait_for(took_over.wait(), 30.0)  # a guard, not a timing
        finally:
            await b.close()

    asyncio.run(scenario())
    assert seen == [(True, "taking_over"), (True, None)]


def test_a_ground_stopped_and_released_refuses_its_queued_writes_at_once(engine: Engine) -> None:
    """After a graceful stop's release, the command path's writes still queued are refused by
    the fence as a whole (LeaseLost), not tried one by one as a standby's read-only ones."""
    a = CommandAuthority(session_factory(engine), LeasePolicy(name=NAME, holder="ground-a"))
    assert a.try_acquire()
    a.stop_commanding()
    refusal = a.refusal()
    assert not a.may_command() and refusal is not None and refusal.code == "stopping"
    asyncio.run(a.close())
    with session_factory(engine)() as session, pytest.raises(LeaseLost, match="released"):
        a.fence(session)


def test_sqlite_refuses_a_second_ground_on_the_same_file(tmp_path: Path) -> None:
    database = tmp_path / "hikoboshi.sqlite3"
    first = hold_sqlite_file(database)
    try:
        with pytest.raises(SecondGround, match=r"pid \d+ .*PostgreSQL"):
            hold_sqlite_file(database)
    finally:
        first.close()
    hold_sqlite_file(database).close()  # released with the file: the next ground starts


def test_the_lease_policy_refuses_a_renewal_too_slow_for_its_time_to_live() -> None:
    with pytest.raises(ValueError, match="under half"):
        LeasePolicy(name=NAME, holder="g", ttl_s=2.0, renew_s=1.5)


def test_the_one_ground_of_an_sqlite_file_takes_the_lease_and_never_lapses(
    engine: Engine,
) -> None:
    """``exclusive`` (the file lock held): the lease is taken whoever the row names (a ground
    killed with it), with a higher token, and commanding never waits for a renewal."""
    dead = _acquire(engine, "killed-ground")
    assert isinstance(dead, Lease)
    clock = _Clock()
    policy = LeasePolicy(name=NAME, holder="ground-a", exclusive=True)
    a = CommandAuthority(session_factory(engine), policy, monotonic=clock)
    assert a.try_acquire() and a.lease is not None and a.lease.token == dead.token + 1
    clock.now += 3600.0  # no renewal for an hour
    assert a.may_command() and a.refusal() is None
