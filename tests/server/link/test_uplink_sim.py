"""The windowed uplink, the runner and the link in simulated time (issue 11).

No test here sleeps on the wall clock: a :class:`ManualClock` drives the ground, and the
scripted relay and vehicle of ``simulated.py`` run on it. Each test names the rule of
``server/services/runner.py`` / ``uplink.py`` it checks.
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import select

from server.services.clock import ManualClock
from server.services.pass_states import MAX_REFUSED_IN_A_ROW, RefusalStreak
from server.services.uplink import RttEstimator, Uplink
from server.storage.models import EventRecord
from telemetry.wire import JointCommandMsg
from tests.server.link.sim_runs import run_pass
from tests.server.link.simulated import (
    Outage,
    SimulatedSpacecraft,
    commands,
    ground,
    kill_ground,
    make_sessions,
    pass_state,
    simulated,
    store_pass,
)


def _joints(n: int, first_tag_ns: int = 100 * 10**9) -> list[JointCommandMsg]:
    return [
        JointCommandMsg(seq=k, execute_time_ns=first_tag_ns + k * 250_000_000, joints_rad=[0.0] * 6)
        for k in range(n)
    ]


# --- the uplink's bookkeeping --------------------------------------------------------------


def _uplink(n: int = 1000, **kw: float) -> Uplink:
    args = dict(one_way_delay_s=3.0, margin_s=2.0, lead_window_s=120.0, capacity=1024)
    args.update(kw)
    return Uplink(_joints(n), time_scale=1.0, **args)  # type: ignore[arg-type]


@simulated
async def test_the_window_admits_commands_up_to_the_lead_window_and_the_capacity() -> None:
    up = _uplink()
    onboard = 50 * 10**9  # the first tag 50 s ahead: 70 s of commands fit the window
    admitted = up.due(0.0, onboard)
    assert len(admitted) == 70 * 4 + 1  # tags 100 s .. 170 s inclusive
    for cmd in admitted:
        up.sent(cmd, 0.0, onboard)
    assert up.due(0.0, onboard) == []
    # a second later four more tags enter the window
    assert [c.seq for c in up.due(1.0, onboard + 10**9)] == [281, 282, 283, 284]
    small = _uplink(capacity=50)
    batch = small.due(0.0, onboard)
    assert len(batch) == 50 and small.onboard_load(onboard) == 50
    for cmd in batch:
        small.sent(cmd, 0.0, onboard)
    # as tags pass onboard, room opens for as many
    assert len(small.due(0.0, 100 * 10**9 + 10**9)) == 5


@simulated
async def test_an_unacknowledged_command_is_sent_again_on_its_timer_until_acknowledged() -> None:
    up = _uplink(10)
    onboard = 50 * 10**9  # the first tag 50 s ahead: no last chance is near
    [first, *_] = batch = up.due(0.0, onboard)
    for cmd in batch:
        up.sent(cmd, 0.0, onboard)
    rto = up.rtt.rto_s
    assert rto == pytest.approx(6.5)  # the nominal 6 s round trip + 0.5 s before any sample
    assert up.due(rto - 0.01, onboard) == []
    again = up.due(rto, onboard)
    assert [c.seq for c in again] == list(range(10))
    for cmd in again:
        assert up.sent(cmd, rto, onboard)  # a retransmission
    # an acknowledgement of a command sent twice is no round-trip sample (Karn)
    assert up.on_ack(first.seq, None, onboard, rto + 6.0)
    assert up.rtt.samples == 0
    # the others go again one timeout later: no backoff (random loss, not congestion)
    assert up.due(rto * 2 - 0.01, onboard + 10**9) == []
    assert {c.seq for c in up.due(rto * 2, onboard + 10**9)} == set(range(1, 10))
    assert up.retransmissions == 10


@simulated
async def test_a_timer_past_the_last_chance_runs_out_at_the_last_chance() -> None:
    up = _uplink(1)
    onboard = 80 * 10**9  # the tag 20 s ahead; its last chance 4.25 s before it, at 15.75 s
    [cmd] = up.due(0.0, onboard)
    up.sent(cmd, 0.0, onboard)
    for t in (6.5, 13.0):
        [cmd] = up.due(t, onboard + round(t * 1e9))
        up.sent(cmd, t, onboard + round(t * 1e9))
    # the timer would run out at 13 + 6.5 = 19.5 s, after the tag's last chance
    assert up.due(15.74, onboard + 15_740_000_000) == []
    [last] = up.due(15.75, onboard + 15_750_000_000)
    assert last is cmd and up.can_arrive(cmd, onboard + 15_750_000_000)
    up.sent(cmd, 15.75, onboard + 15_750_000_000)
    assert up.due(1000.0, onboard + 1000 * 10**9) == []  # too late for another one


@simulated
async def test_round_trip_samples_set_the_timer_never_below_the_nominal_round_trip() -> None:
    rtt = RttEstimator(6.0)
    for _ in range(20):
        rtt.sample(6.05)
    assert 6.05 < rtt.rto_s < 6.6  # srtt + 4 rttvar, converged
    assert rtt.rto_s >= rtt.floor_s
    for _ in range(20):
        rtt.sample(1.0)  # implausibly fast: the floor holds
    assert rtt.rto_s == pytest.approx(6.1)


@simulated
async def test_a_command_never_sent_that_can_no_longer_arrive_expires() -> None:
    up = _uplink(8)
    # onboard 3.9 s before the first tag: (delay + margin / 2) = 4 s is needed
    expired = up.expire(100 * 10**9 - 3_900_000_000)
    assert [c.seq for c in expired] == [0]
    assert up.due(0.0, 100 * 10**9 - 3_900_000_000)[0].seq == 1


@simulated
async def test_restored_commands_go_again_at_once_and_new_ones_follow_in_tag_order() -> None:
    up = _uplink(10)
    up.restore({0: (1, True), 1: (2, False), 2: (1, False)})
    batch = up.due(0.0, 90 * 10**9)
    assert [c.seq for c in batch] == [1, 2, 3, 4, 5, 6, 7, 8, 9]
    onboard = 90 * 10**9
    assert up.sent(batch[0], 0.0, onboard) and up.sent(batch[1], 0.0, onboard)
    assert not up.sent(batch[2], 0.0, onboard)


# --- the runner and the link, in simulated time ----------------------------------------------


def _stages(sessions: object, pass_id: str) -> dict[str, int]:
    out: dict[str, int] = {}
    for row in commands(sessions, pass_id):  # type: ignore[arg-type]
        out[row.stage] = out.get(row.stage, 0) + 1
    return out


def _every_command_executed_once_at_its_tag(sc: SimulatedSpacecraft, rows: list) -> None:
    executed = sc.vehicle.executed
    assert sorted(executed) == sorted(r.seq for r in rows)
    assert all(executed[r.seq] == [r.execute_time_ns] for r in rows)


@simulated
async def test_a_nominal_pass_loads_ahead_and_every_command_executes_at_its_tag(
    tmp_path: Path,
) -> None:
    sc, g, pass_id = await run_pass(tmp_path, 400, seconds=160)
    rows = commands(g.sessions, pass_id)  # type: ignore[attr-defined]
    assert pass_state(g.sessions, pass_id) == "complete"  # type: ignore[attr-defined]
    assert _stages(g.sessions, pass_id) == {"executed": len(rows)}  # type: ignore[attr-defined]
    _every_command_executed_once_at_its_tag(sc, rows)
    margins = g.runner.fill_margins_s  # type: ignore[attr-defined]
    assert len(margins) == len(rows) and min(margins) >= 10.0  # acknowledged >= 10 s ahead
    assert sc.vehicle.copies_received == 0  # no retransmission without loss
    assert all(r.transmissions == 1 for r in rows)


@simulated
async def test_under_loss_and_an_outage_every_command_still_executes_at_its_tag(
    tmp_path: Path,
) -> None:
    sc, g, pass_id = await run_pass(
        tmp_path, 600, seconds=240, loss=0.2, outages=(Outage(60.0, 120.0),), seed=4
    )
    rows = commands(g.sessions, pass_id)  # type: ignore[attr-defined]
    assert sc.lost > 100
    assert pass_state(g.sessions, pass_id) == "complete"  # type: ignore[attr-defined]
    assert _stages(g.sessions, pass_id) == {"executed": len(rows)}  # type: ignore[attr-defined]
    _every_command_executed_once_at_its_tag(sc, rows)
    assert sum(r.transmissions for r in rows) > len(rows)  # the losses were made up by copies
    status = g.runner.uplink_status()  # type: ignore[attr-defined]
    assert status is None  # the pass is over


@simulated
async def test_a_ground_stalled_for_5_s_loses_and_delays_nothing_loaded_ahead(
    tmp_path: Path,
) -> None:
    sc, g, pass_id = await run_pass(tmp_path, 400, seconds=160, stall=(40.0, 5.0))
    rows = commands(g.sessions, pass_id)  # type: ignore[attr-defined]
    assert _stages(g.sessions, pass_id) == {"executed": len(rows)}  # type: ignore[attr-defined]
    _every_command_executed_once_at_its_tag(sc, rows)


@simulated
async def test_the_schedule_never_exceeds_the_capacity_the_vehicle_announces(
    tmp_path: Path,
) -> None:
    sc, g, pass_id = await run_pass(tmp_path, 400, seconds=160, capacity=60)
    rows = commands(g.sessions, pass_id)  # type: ignore[attr-defined]
    assert sc.vehicle.max_queued <= 60 and sc.vehicle.schedule_full == 0
    assert _stages(g.sessions, pass_id) == {"executed": len(rows)}  # type: ignore[attr-defined]
    _every_command_executed_once_at_its_tag(sc, rows)


@simulated
async def test_abort_deletes_the_schedule_from_the_next_grid_tag_and_cancels_the_rest(
    tmp_path: Path,
) -> None:
    sc, g, pass_id = await run_pass(tmp_path, 400, seconds=160, abort_at_s=50.0, loss=0.1, seed=2)
    assert pass_state(g.sessions, pass_id) == "aborted"  # type: ignore[attr-defined]
    with g.sessions() as session:  # type: ignore[attr-defined]
        events = session.scalars(select(EventRecord).where(EventRecord.pass_id == pass_id)).all()
    deleted = [e for e in events if e.kind == "schedule_deleted"]
    assert len(deleted) == 1
    from_ns = deleted[0].detail["from_time_ns"]
    cancelled = [e for e in events if e.kind == "commands_cancelled"]
    assert cancelled and all("operator abort" in e.detail["reason"] for e in cancelled)
    rows = commands(g.sessions, pass_id)  # type: ignore[attr-defined]
    after = [r for r in rows if r.execute_time_ns >= from_ns]
    before = [r for r in rows if r.execute_time_ns < from_ns]
    assert after and before
    # nothing executes from the abort's tag on; everything before it does
    assert not any(r.seq in sc.vehicle.executed for r in after)
    assert all(r.stage == "cancelled" for r in after)
    assert all(r.stage == "executed" for r in before)
    assert sc.vehicle.barrier == (from_ns, max(r.seq for r in rows))
    # the abort's tag is the next grid tag at least (delay + margin) after the abort
    abort_onboard_ns = sc.onboard_ns(sc.mono0 + 50.0)
    assert 5e9 <= from_ns - abort_onboard_ns < 5.25e9 + 1e8


@simulated
async def test_a_pass_logs_its_start_and_its_abort_with_its_id(tmp_path: Path) -> None:
    """The runner's start and abort lines name the pass and carry their fields
    (server/logs.py, docs/operations.md "Logs")."""
    import json
    import logging

    from server.logs import JsonFormatter

    records: list[logging.LogRecord] = []

    class Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            records.append(record)

    runner_log = logging.getLogger("hikoboshi.ground.runner")
    keep, level = Keep(level=logging.INFO), runner_log.level
    runner_log.addHandler(keep)
    runner_log.setLevel(logging.INFO)
    try:
        _, g, pass_id = await run_pass(tmp_path, 100, seconds=60, abort_at_s=20.0)
    finally:
        runner_log.removeHandler(keep)
        runner_log.setLevel(level)
    lines = [json.loads(JsonFormatter().format(r)) for r in records]
    by_event = {line.get("event"): line for line in lines}
    started, aborted = by_event["pass_started"], by_event["pass_aborted"]
    assert started["pass_id"] == aborted["pass_id"] == pass_id
    stored = commands(g.sessions, pass_id)  # type: ignore[attr-defined]
    assert started["commands"] == len(stored) and started["level"] == "INFO"
    assert aborted["reason"] == "operator abort" and aborted["actor"] == "otto"
    assert aborted["message"] == "pass aborted by otto: operator abort"


@simulated
async def test_a_dropped_socket_leaves_the_loaded_schedule_running(tmp_path: Path) -> None:
    """LOS policy ``continue``: what was loaded ahead executes while the ground is away;
    the rest goes up when the link is back."""
    sc, g, pass_id = await run_pass(tmp_path, 400, seconds=170, drop=(30.0, 40.0))
    rows = commands(g.sessions, pass_id)  # type: ignore[attr-defined]
    assert _stages(g.sessions, pass_id) == {"executed": len(rows)}  # type: ignore[attr-defined]
    _every_command_executed_once_at_its_tag(sc, rows)


@simulated
async def test_commands_that_cannot_be_loaded_in_time_expire_and_the_rest_executes(
    tmp_path: Path,
) -> None:
    sc, g, pass_id = await run_pass(
        tmp_path,
        400,
        seconds=170,
        drop=(30.0, 40.0),
        settings={"uplink_lead_window_s": 10.0},
    )
    rows = commands(g.sessions, pass_id)  # type: ignore[attr-defined]
    stages = _stages(g.sessions, pass_id)  # type: ignore[attr-defined]
    assert set(stages) == {"executed", "expired"} and stages["expired"] > 100
    expired = [r for r in rows if r.stage == "expired"]
    assert not any(r.seq in sc.vehicle.executed for r in expired)
    back_ns = sc.onboard_ns(sc.mono0 + 70.0)
    assert all(r.execute_time_ns < back_ns + 4 * 10**9 + 250_000_000 for r in expired)


@simulated
async def test_after_a_restart_the_pass_resumes_and_a_late_hello_is_corrected(
    tmp_path: Path,
) -> None:
    clock = ManualClock()
    sessions = make_sessions(tmp_path)
    first = ground(sessions, clock)
    sc = SimulatedSpacecraft(clock, loss=0.1, seed=7)
    await sc.connect(first)
    pass_id = store_pass(sessions, 400, clock)
    await first.runner.start(pass_id, "otto")
    await sc.run(40.0)
    await kill_ground(first, sc)  # no shutdown, nothing more from this process
    await sc.run(3.0)
    second = ground(sessions, clock)
    await second.runner.recover()
    # the new process reads the hello 2 s after it was sent: its onboard clock starts 2 s
    # behind, and the stamps of later messages move it forward
    await sc.connect(second, hello_read_late_s=2.0)
    behind = sc.onboard_ns() - second.link.onboard_now_ns()
    assert behind == pytest.approx(2e9, abs=1e6)
    await sc.run(140.0)
    error_s = abs(sc.onboard_ns() - second.link.onboard_now_ns()) / 1e9
    assert error_s <= 0.5 + 1e-3
    assert second.link.onboard_clock.corrections >= 1
    rows = commands(sessions, pass_id)
    assert pass_state(sessions, pass_id) == "complete"
    assert _stages(sessions, pass_id) == {"executed": len(rows)}
    _every_command_executed_once_at_its_tag(sc, rows)


def test_late_refusals_of_commands_sent_on_an_unconfirmed_clock_do_not_end_the_pass() -> None:
    """A hello read late (a loop stalled on a reconnection) puts the onboard clock behind
    until a relayed stamp corrects it: commands sent meanwhile at the edge of their last
    chance arrive late. Their ``late`` refusals say the hello was read late, not that the arm
    no longer follows the plan: they neither count nor end a streak. (A restarted ground
    waits for that stamp before it sends anything: the next test.)"""
    streak = RefusalStreak()
    for seq in range(MAX_REFUSED_IN_A_ROW):
        streak.sent_unconfirmed(seq)
        assert streak.observe("rejected", "late", seq) is None
    assert (streak.count, streak.excused) == (0, MAX_REFUSED_IN_A_ROW)
    refusals = [streak.observe("rejected", "late", 100 + i) for i in range(MAX_REFUSED_IN_A_ROW)]
    assert refusals[:-1] == [None] * (MAX_REFUSED_IN_A_ROW - 1) and refusals[-1] is not None


@simulated
async def test_a_ground_restarted_past_the_lead_window_sends_nothing_late_on_a_late_hello(
    tmp_path: Path,
) -> None:
    """A ground killed mid-pass comes back after more than its lead window and reads the
    hello 3 s after it was sent (a process still starting): it resumes only once a relayed
    stamp has confirmed the onboard clock, so nothing goes up too late; the gap in the
    motion holds the rest of it (server/services/continuity.py)."""
    clock = ManualClock()
    sessions = make_sessions(tmp_path)
    first = ground(sessions, clock, uplink_lead_window_s=10.0)
    sc = SimulatedSpacecraft(clock)
    await sc.connect(first)
    pass_id = store_pass(sessions, 400, clock)
    await first.runner.start(pass_id, "otto")
    await sc.run(40.0)
    await kill_ground(first, sc)  # no shutdown, nothing more from this process
    await sc.run(20.0)
    second = ground(sessions, clock, uplink_lead_window_s=10.0)
    await second.runner.recover()
    await sc.connect(second, hello_read_late_s=3.0)
    assert not second.link.clock_confirmed
    await sc.run(120.0)
    assert second.link.clock_confirmed
    assert not [a for a in sc.vehicle.outcomes.values() if a.stage.value == "rejected"]
    assert pass_state(sessions, pass_id) == "complete"
    assert set(_stages(sessions, pass_id)) == {"executed", "expired", "cancelled"}


@simulated
async def test_an_abort_at_los_does_not_wait_for_the_database_backlog(tmp_path: Path) -> None:
    """The pass's task waits at LOS for the stage writes queued so far; an abort then stops
    that wait instead of waiting for the backlog (on a loaded PostgreSQL it took seconds).
    The database worker is held by two jobs: the first until the abort's own transaction is
    queued, the second until the abort has answered, which it could not do if it waited."""
    clock = ManualClock()
    sessions = make_sessions(tmp_path)
    g = ground(sessions, clock)
    sc = SimulatedSpacecraft(clock)
    await sc.connect(g)
    pass_id = store_pass(sessions, 40, clock)
    await g.runner.start(pass_id, "otto")
    db = g.db
    first, second = threading.Event(), threading.Event()
    ran: list[str] = []

    def held(gate: threading.Event, name: str) -> Callable[[Any], list[dict[str, Any]]]:
        def job(session: Any) -> list[dict[str, Any]]:
            assert gate.wait(60.0), f"{name} was never released"
            ran.append(name)
            return []

        return job

    db.submit(held(first, "first"))
    db.submit(held(second, "second"))
    try:
        # the last tag (about 41 s) and the settling: the pass is at LOS
        await sc.run(80.0, drain=False)
        task = g.runner._active.task
        assert task is not None and not task.done()
        assert pass_state(sessions, pass_id) == "running"  # its LOS write is queued too
        abort = asyncio.ensure_future(g.runner.abort(pass_id, "otto", "operator abort"))
        deadline = time.monotonic() + 30.0
        while not db._control:  # the abort's transaction, queued ahead of the backlog
            assert not abort.done() and time.monotonic() < deadline, "the abort waited"
            await asyncio.sleep(0.01)
        first.set()
        await asyncio.wait_for(abort, 30.0)
        assert ran == ["first"]  # answered with the backlog still held
        assert pass_state(sessions, pass_id) == "aborted"
        assert task.done()
    finally:
        first.set()
        second.set()
    await db.drain()
    assert ran == ["first", "second"]
