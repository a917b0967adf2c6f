"""The ground's side of on-board safing, in simulated time (server/services/runner.py,
safing.py): a ``safing`` report mid-pass makes the pass ``safed`` and stops the uplink; the
vehicle's dropped commands are ``cancelled`` with the reason ``safing``; no pass starts while
the vehicle is safe; the ``safe_exit`` telecommand goes up again until the vehicle answers.
The scripted vehicle of ``simulated.py`` safes itself on the test's word; the real vehicle's
safing is tested in tests/spacecraft and end to end in test_e2e.py."""

from __future__ import annotations

import asyncio
import logging
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import select

from server.services.clock import ManualClock
from server.services.errors import ConflictError
from server.services.link import LinkUnavailable, SafeExitRefused
from server.services.runner import SAFED_TAIL_S
from server.services.safing import VehicleSafingState
from server.storage import repository as repo
from server.storage.models import AlarmRecord, EventRecord
from telemetry.wire import SafingTrigger
from tests.server.link.simulated import (
    EPOCH_NS,
    SimulatedSpacecraft,
    commands,
    ground,
    make_sessions,
    pass_state,
    simulated,
    store_pass,
)

TRIGGER = SafingTrigger(quantity="joint_tracking_error_deg", channel="joint3", value=6.2, limit=5.0)


def _events(g: Any, kind: str) -> list[EventRecord]:
    with g.sessions() as session:
        return list(session.scalars(select(EventRecord).where(EventRecord.kind == kind)))


async def _safed_pass(
    tmp_path: Path, *, loss: float = 0.0, seed: int = 0
) -> tuple[SimulatedSpacecraft, Any, str, int]:
    """A 400-command pass (100 s of commands from about 31 s on, a 30 s lead window: the
    last ones not sent yet) whose vehicle safes itself 60 s in; (spacecraft, ground, pass
    id, onboard ns of the safing)."""
    clock = ManualClock()
    sessions = make_sessions(tmp_path)
    g = ground(sessions, clock, uplink_lead_window_s=30.0)
    sc = SimulatedSpacecraft(clock, loss=loss, seed=seed)
    await sc.connect(g)
    pass_id = store_pass(sessions, 400, clock)
    await g.runner.start(pass_id, "otto")
    await sc.run(60.0)
    safed_at = sc.onboard_ns()
    sc.safe(TRIGGER)
    # the report is down 3 s later; what the ground sent before it is up 3 s after that
    await sc.run(7.0)
    heard = (len(sc.vehicle.contents), sc.vehicle.copies_received)
    for _ in range(10):  # the vehicle's 1 s repeats
        await sc.run(1.0)
        sc.report_safing()
    await sc.run(20.0)
    # once the ground knew, nothing more went up: no new command, no copy
    assert (len(sc.vehicle.contents), sc.vehicle.copies_received) == heard
    return sc, g, pass_id, safed_at


@simulated
async def test_a_safing_report_makes_the_pass_safed_and_stops_the_uplink(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="hikoboshi.ground.events")
    sc, g, pass_id, safed_at = await _safed_pass(tmp_path)
    assert pass_state(g.sessions, pass_id) == "safed"
    with g.sessions() as session:
        record = repo.get_pass(session=session, pass_id=pass_id, refresh=True)
        assert "joint_tracking_error_deg joint3 6.2 beyond its red limit 5" in (
            record.state_reason or ""
        )
        # the aftermath stays the pass's: its window ends SAFED_TAIL_S after the safing
        assert record.telemetry_end_ns == safed_at + round(SAFED_TAIL_S * 1e9)
    rows = commands(g.sessions, pass_id)
    executed = [r for r in rows if r.stage == "executed"]
    assert executed and all(r.execute_time_ns <= safed_at for r in executed)
    # nothing executed after the safing; every command is final
    assert not [s for s, tags in sc.vehicle.executed.items() if max(tags) > safed_at]
    assert {r.stage for r in rows} <= {"executed", "cancelled"}
    # the vehicle's dropped commands: cancelled, the reason safing
    dropped = [r for r in rows if r.stage == "cancelled" and r.reject_reason == "safing"]
    # those it dropped, and the copies still in flight that it refused while safe
    refused = [a for a in sc.vehicle.outcomes.values() if a.reason == "safing"]
    assert len(dropped) == len(refused) >= sc.vehicle.cancelled_on_safing > 0
    # the never-sent rest: cancelled on the ground, in one event naming the safing
    ground_cancelled = [r for r in rows if r.stage == "cancelled" and r.reject_reason is None]
    assert ground_cancelled and all(r.transmissions == 0 for r in ground_cancelled)
    (event,) = _events(g, "commands_cancelled")
    assert event.detail["count"] == len(ground_cancelled)
    assert "safed itself" in event.detail["reason"]
    # no schedule_delete: the vehicle emptied its own schedule
    assert not _events(g, "schedule_deleted") and sc.vehicle.barrier is None
    safed = _events(g, "vehicle_safed")
    assert len(safed) == 1  # the repeats are one episode
    assert safed[0].pass_id == pass_id
    assert safed[0].detail["trigger"]["channel"] == "joint3"
    # the alarms raised the vehicle's critical alarm, once, for the pass
    await g.db.drain()
    with g.sessions() as session:
        alarms = list(
            session.scalars(select(AlarmRecord).where(AlarmRecord.quantity == "vehicle_safing"))
        )
    assert len(alarms) == 1
    assert (alarms[0].source, alarms[0].severity, alarms[0].state) == (
        "vehicle",
        "critical",
        "triggered",
    )
    assert alarms[0].pass_id == pass_id and alarms[0].trigger_value == 6.2
    status = g.link.status()
    assert status.vehicle_mode == "safe"
    assert status.safing is not None and status.safing["pass_id"] == pass_id
    assert status.safing["cancelled"] == sc.vehicle.cancelled_on_safing
    # the ground's log says each once, as an operator must hear it (server.services.event_lines)
    lines = [
        r.getMessage()
        for r in caplog.records
        if r.name == "hikoboshi.ground.events" and getattr(r, "pass_id", None) == pass_id
    ]
    said = [
        "vehicle SAFE (on-board safing): joint_tracking_error_deg joint3 6.2",
        "running -> safed: ",
        "alarm CRITICAL: vehicle_safing",
    ]
    assert [sum(line.startswith(s) for line in lines) for s in said] == [1, 1, 1], lines


@simulated
async def test_safe_exit_needs_the_confirmation_and_a_safe_vehicle(tmp_path: Path) -> None:
    sc, g, pass_id, _ = await _safed_pass(tmp_path)
    link = g.link
    other = store_pass(g.sessions, 40, link.clock)
    with pytest.raises(ConflictError) as refused:  # no pass starts while the vehicle is safe
        await g.runner.start(other, "otto")
    assert refused.value.code == "vehicle_safe"
    assert pass_state(g.sessions, other) == "scheduled"
    with pytest.raises(SafeExitRefused) as wrong:
        await link.request_safe_exit("otto", "EXIT SAFE ETS-8")
    assert wrong.value.code == "confirmation_mismatch"
    assert "'EXIT SAFE ETS-VII'" in str(wrong.value)
    assert sc.vehicle.safe_exits_received == 0
    request_id = await link.request_safe_exit("otto", "EXIT SAFE ETS-VII")
    await sc.run(10.0)
    assert sc.vehicle.safe_since_ns is None
    assert link.status().vehicle_mode == "nominal"
    exited = _events(g, "vehicle_safe_exited")
    assert len(exited) == 1 and exited[0].detail["request_id"] == request_id
    assert exited[0].pass_id == pass_id
    await g.db.drain()
    with g.sessions() as session:
        alarm = session.scalars(
            select(AlarmRecord).where(AlarmRecord.quantity == "vehicle_safing")
        ).one()
    assert alarm.state == "cleared" and not alarm.acknowledged  # latched until acknowledged
    requested = _events(g, "vehicle_safe_exit_requested")
    assert [e.actor for e in requested] == ["otto"]
    with pytest.raises(SafeExitRefused) as nominal:
        await link.request_safe_exit("otto", "EXIT SAFE ETS-VII")
    assert nominal.value.code == "vehicle_not_safe"
    # the pass stays safed; a new pass may start
    assert pass_state(g.sessions, pass_id) == "safed"
    await g.runner.start(other, "otto")
    assert pass_state(g.sessions, other) == "running"


@simulated
async def test_safe_exit_is_sent_again_until_the_vehicle_answers(tmp_path: Path) -> None:
    """Under 60 % loss each way the telecommand or its answer is lost often: the same
    request goes up again until the vehicle's nominal report naming it comes down."""
    sc, g, _, _ = await _safed_pass(tmp_path)
    sc.loss = 0.6
    request_id = await g.link.request_safe_exit("otto", "EXIT SAFE ETS-VII")
    for _ in range(30):
        await sc.run(10.0)
        if g.link.status().vehicle_mode == "nominal":
            break
    assert g.link.status().vehicle_mode == "nominal", (
        sc.vehicle.safe_exits_received,
        sc.vehicle.exits,
    )
    assert sc.vehicle.safe_since_ns is None
    assert list(sc.vehicle.exits) == [request_id]  # one request, however many copies
    assert sc.vehicle.safe_exits_received >= 1


@simulated
async def test_safe_exit_without_a_link_is_refused(tmp_path: Path) -> None:
    clock = ManualClock()
    g = ground(make_sessions(tmp_path), clock)
    with pytest.raises(LinkUnavailable):
        await g.link.request_safe_exit("otto", "EXIT SAFE spacecraft")


@simulated
async def test_a_vehicle_safe_outside_a_pass_is_filed_without_one(tmp_path: Path) -> None:
    clock = ManualClock()
    g = ground(make_sessions(tmp_path), clock)
    sc = SimulatedSpacecraft(clock)
    await sc.connect(g)
    await sc.run(5.0)
    sc.safe(TRIGGER)
    await sc.run(5.0)
    safed = _events(g, "vehicle_safed")
    assert len(safed) == 1 and safed[0].pass_id is None
    assert g.link.status().vehicle_mode == "safe"
    # a reconnection: nominal until the vehicle says otherwise
    await sc.connect(g)
    assert g.link.status().vehicle_mode == "nominal"
    sc.report_safing()
    await sc.run(5.0)
    assert g.link.status().vehicle_mode == "safe"
    assert len(_events(g, "vehicle_safed")) == 1  # the same episode goes on


def _report(state: str, since_s: float | None, at_s: float, exit_id: int | None = None) -> Any:
    from telemetry.wire import Safing

    since = None if since_s is None else EPOCH_NS + round(since_s * 1e9)
    return Safing(
        state=state,  # type: ignore[arg-type]
        since_time_ns=since,
        trigger=TRIGGER if state == "safe" else None,
        cancelled=3 if state == "safe" else 0,
        exit_request_id=exit_id,
        onboard_time_ns=EPOCH_NS + round(at_s * 1e9),
    )


def test_one_episode_through_repeats_a_reconnection_and_a_late_repeat() -> None:
    state = VehicleSafingState()
    assert state.on_report(_report("safe", 10.0, 10.0)) == (True, False)
    assert state.on_report(_report("safe", 10.0, 11.0)) == (False, False)  # the 1 s repeat
    state.on_hello()  # a new connection: nominal until the vehicle says otherwise
    assert state.mode == "nominal"
    assert state.on_report(_report("safe", 10.0, 15.0)) == (False, False)  # the same episode
    assert state.status() is not None and state.status()["state"] == "safe"  # type: ignore[index]
    assert state.on_report(_report("nominal", 10.0, 20.0, exit_id=7)) == (False, True)
    # a repeat sent before the exit, delivered after its answer: stale, nothing changes
    assert state.on_report(_report("safe", 10.0, 19.5)) is None
    assert state.mode == "nominal" and state.last is not None
    assert state.last.exit_request_id == 7
    # a copy of the exit's answer ends nothing more; a later SAFE is a new episode
    assert state.on_report(_report("nominal", 10.0, 20.0, exit_id=7)) == (False, False)
    assert state.on_report(_report("safe", 30.0, 30.0)) == (True, False)


@simulated
async def test_the_fates_of_the_dropped_commands_are_asked_for_at_once(tmp_path: Path) -> None:
    """Under 10 % loss each way some of the vehicle's ``rejected`` ``safing`` acks are lost;
    the ground asks about every command not final at once (a safed vehicle executes none),
    not only once each tag has passed: they are filed long before their tags."""
    clock = ManualClock()
    sessions = make_sessions(tmp_path)
    g = ground(sessions, clock)  # the flight's 120 s lead window: every command goes up early
    sc = SimulatedSpacecraft(clock, loss=0.1, seed=3)
    await sc.connect(g)
    pass_id = store_pass(sessions, 400, clock)
    await g.runner.start(pass_id, "otto")
    await sc.run(60.0)
    sc.safe(TRIGGER)
    for _ in range(10):
        await sc.run(1.0)
        sc.report_safing()
    assert g.link.status().vehicle_mode == "safe"
    await sc.run(30.0)
    now_ns = sc.onboard_ns()
    rows = commands(sessions, pass_id)
    assert pass_state(sessions, pass_id) == "safed"
    # the acks of the vehicle's refusals that the relay lost
    refused = {s for s, a in sc.vehicle.outcomes.items() if a.reason == "safing"}
    ahead = [r for r in rows if r.execute_time_ns > now_ns + 10 * 10**9 and r.seq in refused]
    assert len(ahead) > 80  # tags still well ahead
    assert sc.lost > 20
    # every one the vehicle refused is filed so, those with tags ahead included
    assert {r.seq for r in rows if r.reject_reason == "safing"} == refused
    assert {r.stage for r in ahead} == {"cancelled"}
    # what stays open never reached the vehicle (each copy lost on the uplink: it expires
    # once its tag has passed) or is executed and its answers lost again (the queries go on)
    open_ = [r for r in rows if r.stage in ("released", "sent", "received")]
    assert len(open_) < 5 and not [r for r in open_ if r.seq in refused]


async def _killed(g: Any, sc: SimulatedSpacecraft) -> None:
    """The ground process dies: no shutdown, nothing more from it."""
    active = g.runner._active
    if active is not None and active.task is not None:
        active.task.cancel()
        await asyncio.gather(active.task, return_exceptions=True)
    for task in list(g.runner._background):
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
    await g.db.drain()
    g.db.close()
    sc.lose_ground()


@simulated
async def test_after_a_restart_a_safed_pass_stays_safed_and_the_episode_goes_on(
    tmp_path: Path,
) -> None:
    sc, first, pass_id, safed_at = await _safed_pass(tmp_path)
    with first.sessions() as session:
        before = repo.get_pass(session=session, pass_id=pass_id, refresh=True)
        window = (before.telemetry_start_ns, before.telemetry_end_ns)
    await _killed(first, sc)
    await sc.run(3.0)
    second = ground(first.sessions, sc.clock)
    await second.restarted()
    assert second.runner.active_pass_id is None  # final: not resumed
    await sc.connect(second)
    sc.report_safing()  # the real vehicle sends it right after hello
    await sc.run(10.0)
    assert pass_state(second.sessions, pass_id) == "safed"
    with second.sessions() as session:
        after = repo.get_pass(session=session, pass_id=pass_id, refresh=True)
        assert (after.telemetry_start_ns, after.telemetry_end_ns) == window
        assert after.state_reason == before.state_reason
    # the same episode: no second vehicle_safed, the pass it stopped still named
    assert len(_events(second, "vehicle_safed")) == 1
    status = second.link.status()
    assert status.vehicle_mode == "safe"
    assert status.safing is not None and status.safing["pass_id"] == pass_id
    assert status.safing["since_time_ns"] == safed_at
    await second.db.drain()
    with second.sessions() as session:
        alarms = list(
            session.scalars(select(AlarmRecord).where(AlarmRecord.quantity == "vehicle_safing"))
        )
    assert len(alarms) == 1 and alarms[0].pass_id == pass_id  # updated, not raised again
    other = store_pass(second.sessions, 40, sc.clock)
    with pytest.raises(ConflictError) as refused:
        await second.runner.start(other, "otto")
    assert refused.value.code == "vehicle_safe"
    await second.link.request_safe_exit("otto", "EXIT SAFE ETS-VII")
    await sc.run(10.0)
    assert second.link.status().vehicle_mode == "nominal"
    assert pass_state(second.sessions, pass_id) == "safed"


@simulated
async def test_a_pass_whose_safing_the_dead_ground_missed_ends_safed_after_the_restart(
    tmp_path: Path,
) -> None:
    """The vehicle safes itself while the ground is down: the pass left ``running`` is
    resumed, and the vehicle's report right after its hello makes it ``safed``; no
    command executes after the safing."""
    clock = ManualClock()
    sessions = make_sessions(tmp_path)
    first = ground(sessions, clock)
    sc = SimulatedSpacecraft(clock)
    await sc.connect(first)
    pass_id = store_pass(sessions, 400, clock)
    await first.runner.start(pass_id, "otto")
    await sc.run(50.0)
    await _killed(first, sc)
    await sc.run(5.0)
    safed_at = sc.onboard_ns()
    sc.safe(TRIGGER)  # nobody hears it
    await sc.run(5.0)
    assert pass_state(sessions, pass_id) == "running"
    second = ground(sessions, clock)
    await second.restarted()
    await sc.connect(second)
    sc.report_safing()
    await sc.run(30.0)
    assert pass_state(sessions, pass_id) == "safed"
    with sessions() as session:
        record = repo.get_pass(session=session, pass_id=pass_id, refresh=True)
        assert "joint_tracking_error_deg joint3" in (record.state_reason or "")
    assert not [s for s, tags in sc.vehicle.executed.items() if max(tags) > safed_at]
    (safed,) = _events(second, "vehicle_safed")
    assert safed.pass_id == pass_id
    rows = commands(sessions, pass_id)
    assert {r.stage for r in rows} <= {"executed", "cancelled"}
