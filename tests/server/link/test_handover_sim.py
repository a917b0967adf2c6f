"""A stop of the ground mid-pass, in simulated time: a graceful stop hands the pass to the
vehicle and the next process resumes it; after any stop every command's stage ends as the
vehicle's word; a pass whose commands did not all execute at their tags ends ``degraded``.

The rules: ``PassRunner.shutdown`` and ``recover`` (server/services/runner.py), the
decisions of server/services/recovery.py, the outcome of server/services/summary.py.
"""

from __future__ import annotations

import asyncio
import time
from pathlib import Path
from typing import Any

from server.services.clock import ManualClock
from server.services.report_tables import build_report
from server.services.summary import CommandOutcome, pass_summary
from server.storage import repository as repo
from tests.server.link.harness import add_plan_and_pass
from tests.server.link.simulated import (
    Ground,
    SimulatedSpacecraft,
    commands,
    ground,
    kill_ground,
    make_sessions,
    pass_state,
    simulated,
    store_pass,
)
from tests.server.storage.factories import make_plan

#: The uplink's lead window here (onboard s): a 100 s pass stopped 30-40 s in still has
#: commands never sent.
LEAD_S = 40.0


def _stages(rows: list[Any]) -> dict[str, int]:
    out: dict[str, int] = {}
    for row in rows:
        out[row.stage] = out.get(row.stage, 0) + 1
    return out


def _as_the_vehicle_did(sc: SimulatedSpacecraft, rows: list[Any]) -> None:
    """Each command's stage is what the vehicle did: executed (once, at its tag) exactly
    when the vehicle executed it; the others never reached it."""
    executed = sc.vehicle.executed
    for r in rows:
        if r.seq in executed:
            assert r.stage == "executed" and executed[r.seq] == [r.execute_time_ns], r.seq
            assert r.executed_at_ns == r.execute_time_ns
        else:
            assert r.stage in ("expired", "cancelled"), (r.seq, r.stage)
            assert r.seq not in sc.vehicle.outcomes  # never on board


def _events(g: Ground, pass_id: str, kind: str) -> list[Any]:
    with g.sessions() as session:
        return list(repo.list_events(session=session, pass_id=pass_id, kinds=[kind]).items)


@simulated
async def test_a_graceful_stop_hands_the_pass_to_the_vehicle_and_the_next_ground_resumes_it(
    tmp_path: Path,
) -> None:
    clock = ManualClock()
    sessions = make_sessions(tmp_path)
    first = ground(sessions, clock, uplink_lead_window_s=LEAD_S)
    sc = SimulatedSpacecraft(clock, loss=0.1, seed=3)
    await sc.connect(first)
    pass_id = store_pass(sessions, 400, clock)
    await first.runner.start(pass_id, "otto")
    await sc.run(40.0)
    held = {seq for seq in sc.vehicle.schedule}
    assert len(held) > 4 * LEAD_S / 2  # the lead window loaded on board
    # the lifespan's order: the runner's shutdown, then the link's socket closed
    await first.runner.shutdown()
    await first.link.close()
    sc.lose_ground()
    # nothing cancelled, the pass left running, the handover audited after the writes
    rows = commands(sessions, pass_id)
    assert "cancelled" not in _stages(rows)
    assert pass_state(sessions, pass_id) == "running"
    assert first.runner.active_pass_id is None
    [stopped] = _events(first, pass_id, "ground_stopped")
    detail = stopped.detail
    assert detail["state"] == "running" and detail["los_policy"] == "continue"
    assert detail["loaded"] == sum(1 for r in rows if r.stage in ("sent", "received"))
    assert detail["unsent"] == sum(1 for r in rows if r.stage == "queued") > 0
    assert detail["loaded"] >= len(held) - 10
    assert "pass handed to the vehicle at onboard" in detail["reason"]
    # the vehicle flies what it holds while the ground is away
    await sc.run(15.0)
    second = ground(sessions, clock, uplink_lead_window_s=LEAD_S)
    await second.restarted()
    await sc.connect(second)
    await sc.run(120.0)
    rows = commands(sessions, pass_id)
    assert pass_state(sessions, pass_id) == "complete"
    assert _stages(rows) == {"executed": len(rows)}
    _as_the_vehicle_did(sc, rows)
    with sessions() as session:
        summary = pass_summary(session=session, pass_id=pass_id)
        reason = repo.get_pass(session=session, pass_id=pass_id).state_reason
    assert summary.outcome == "nominal" and summary.commands_unresolved == 0
    assert reason == f"complete, nominal: all {len(rows)} commands executed at their tags"
    assert len(_events(second, pass_id, "pass_resumed")) == 1


@simulated
async def test_a_ground_down_longer_than_the_lead_window_ends_the_pass_degraded_with_counts(
    tmp_path: Path,
) -> None:
    clock, sessions, sc, pass_id = await _killed_40_s_into_a_pass(tmp_path, lead_s=10.0)
    await sc.run(30.0)  # three lead windows without a ground
    second = ground(sessions, clock, uplink_lead_window_s=10.0)
    await second.restarted()
    await sc.connect(second)
    await sc.run(100.0)
    rows = commands(sessions, pass_id)
    stages = _stages(rows)
    assert pass_state(sessions, pass_id) == "complete"
    # the gap is in the motion: the rest of it is held, not sent (test_resume_hold_sim.py)
    assert set(stages) == {"executed", "expired", "cancelled"} and stages["expired"] > 50
    _as_the_vehicle_did(sc, rows)
    with sessions() as session:
        summary = pass_summary(session=session, pass_id=pass_id)
        reason = repo.get_pass(session=session, pass_id=pass_id).state_reason
    assert summary.outcome == "degraded"
    assert summary.commands_expired == stages["expired"]
    assert summary.commands_cancelled == stages["cancelled"]
    assert summary.commands_executed_at_tag == stages["executed"]
    assert summary.outcome_text == (
        f"degraded: {stages['expired']} of {len(rows)} commands expired, "
        f"{stages['cancelled']} cancelled"
    )
    assert reason == f"complete, {summary.outcome_text}"


@simulated
async def test_commands_left_unresolved_by_an_aborted_pass_are_asked_about_when_the_vehicle_is_back(
    tmp_path: Path,
) -> None:
    """Killed mid-pass, the ground comes back after the pass's LOS with no spacecraft: the
    pass is aborted (what was never sent is cancelled), and the commands it had sent, which
    the vehicle executed meanwhile, read ``executed`` once the vehicle is back."""
    clock = ManualClock()
    sessions = make_sessions(tmp_path)
    first = ground(sessions, clock, uplink_lead_window_s=LEAD_S)
    sc = SimulatedSpacecraft(clock)
    await sc.connect(first)
    pass_id = add_plan_and_pass(
        sessions, make_plan(400), "short", now_ns=clock.time_ns(), window_s=150.0
    )
    await first.runner.start(pass_id, "otto")
    await sc.run(30.0)
    await kill_ground(first, sc)
    await sc.run(160.0)  # past the pass's LOS: the vehicle flew what it held
    second = ground(sessions, clock)
    await second.restarted()
    await sc.run(5.0)
    # the recovery's decision waits on real threads (the alarms' evaluator is built in one),
    # not on the simulated clock: wait for it (a guard, not a timing assertion)
    deadline = time.monotonic() + 60.0
    while pass_state(sessions, pass_id) != "aborted":
        assert time.monotonic() < deadline, pass_state(sessions, pass_id)
        await asyncio.sleep(0.02)
        await second.db.drain()
    waiting = [r for r in commands(sessions, pass_id) if r.stage in ("sent", "received")]
    assert len(waiting) > 100  # the ground does not know yet
    assert second.runner.resolving
    await sc.connect(second)
    await sc.run(30.0)
    rows = commands(sessions, pass_id)
    stages = _stages(rows)
    assert set(stages) == {"executed", "cancelled"}, stages
    _as_the_vehicle_did(sc, rows)
    assert not second.runner.resolving
    with sessions() as session:
        summary = pass_summary(session=session, pass_id=pass_id)
    assert (summary.outcome, summary.commands_unresolved) == ("degraded", 0)
    assert summary.outcome_text == (
        f"degraded: {stages['cancelled']} of {len(rows)} commands cancelled"
    )
    # a third ground finds nothing left to ask about
    await second.runner.shutdown()
    third = ground(sessions, clock)
    await third.restarted()
    assert not third.runner.resolving


def test_the_outcome_is_nominal_only_when_every_command_executed_at_its_tag() -> None:
    nominal = CommandOutcome(10, 10, 0, 0, 0, 0, 0)
    assert (nominal.word, nominal.sentence()) == (
        "nominal",
        "nominal: all 10 commands executed at their tags",
    )
    late = CommandOutcome(10, 9, 1, 0, 0, 0, 0)
    assert (late.word, late.sentence()) == ("degraded", "degraded: 1 of 10 commands executed late")
    mixed = CommandOutcome(6190, 5790, 0, 393, 2, 0, 5)
    assert mixed.sentence() == "degraded: 393 of 6190 commands expired, 2 rejected, 5 unresolved"
    # the report's table of it, after the paper's
    report = build_report(
        pass_id=None,
        name="p",
        state="complete",
        experiment="ptp",
        imported=False,
        documents={},
        figure_names=[],
        commands=mixed.document(),
    )
    assert [t.id for t in report.tables[:2]] == ["flight_against_ours", "commands"]
    table = report.tables[1]
    assert table.rows == [["degraded", 6190, 5790, 0, 393, 2, 0, 5]]
    assert table.notes == [mixed.sentence()]


async def _killed_40_s_into_a_pass(
    tmp_path: Path, lead_s: float = LEAD_S
) -> tuple[ManualClock, Any, SimulatedSpacecraft, str]:
    """A ground with an uplink lead window of ``lead_s`` (onboard s) flies a 400-command
    pass for 40 s of simulated time and is killed."""
    clock = ManualClock()
    sessions = make_sessions(tmp_path)
    first = ground(sessions, clock, uplink_lead_window_s=lead_s)
    sc = SimulatedSpacecraft(clock)
    await sc.connect(first)
    pass_id = store_pass(sessions, 400, clock)
    await first.runner.start(pass_id, "otto")
    await sc.run(40.0)
    await kill_ground(first, sc)
    return clock, sessions, sc, pass_id


@simulated
async def test_an_abort_after_a_takeover_leaves_what_the_vehicle_holds_to_its_word(
    tmp_path: Path,
) -> None:
    """The holder is killed before it filed the sends of the commands it loaded (their rows
    still read ``queued``); the ground that takes over resumes the pass and is told to
    abort at once. Those commands are on board all the same (the vehicle's ``hello``
    names the last it received): the abort's ``schedule_delete`` still goes up, the ones
    tagged before its ``T`` are not cancelled but asked about, and every stage ends as the
    vehicle's word (found by bench/bench_failover.py's kill9-abort: executed commands
    filed ``cancelled``)."""
    clock, sessions, sc, pass_id = await _killed_40_s_into_a_pass(tmp_path)
    held = sorted(sc.vehicle.schedule)
    assert len(held) > 20
    with sessions() as session:  # the killed ground's sends never reached the database
        for seq in held:
            row = repo.get_command(session=session, pass_id=pass_id, seq=seq)
            row.stage, row.transmissions = "queued", 0
            row.released_at_ns = row.sent_at_ns = row.received_at_ns = None
        session.commit()
    second = ground(sessions, clock, uplink_lead_window_s=LEAD_S)
    await second.restarted()
    await sc.connect(second)
    while second.runner.active_pass_id != pass_id:  # resumed, nothing sent again yet
        await sc.run(0.01)
    uplink = second.runner._active.uplink  # type: ignore[union-attr]
    assert all(c.transmissions == 0 for c in uplink.commands if c.seq in held)
    await second.runner.abort(pass_id, "otto", "test abort after a takeover")
    await sc.run(150.0)
    rows = commands(sessions, pass_id)
    assert pass_state(sessions, pass_id) == "aborted"
    stages = _stages(rows)
    assert not set(stages) & {"queued", "released", "sent", "received"}, stages
    executed = sc.vehicle.executed
    assert executed  # the vehicle flew some of what it held before the delete's T
    for r in rows:
        if r.seq in executed:
            assert r.stage == "executed", (r.seq, r.stage)
        else:
            assert r.stage in ("cancelled", "expired"), (r.seq, r.stage)
    [deleted] = _events(second, pass_id, "schedule_deleted")
    assert deleted.detail["from_time_ns"] > 0


@simulated
async def test_an_abort_after_a_takeover_files_what_the_vehicle_executed_during_the_gap(
    tmp_path: Path,
) -> None:
    """As above, but the new ground comes a few seconds after the kill: commands the
    killed holder loaded (their sends never filed) ran on board meanwhile, their
    ``executed`` lost with no ground to hear it. The resumed uplink takes them as
    ``expired`` (their tags have passed, no send on file); the abort right after the
    resume must still ask the vehicle, whose word is ``executed`` (found by
    bench/bench_failover.py's kill9-abort: 77-465 commands archived ``expired`` that the
    vehicle had executed)."""
    clock, sessions, sc, pass_id = await _killed_40_s_into_a_pass(tmp_path)
    held = sorted(sc.vehicle.schedule)
    # the killed ground's sends (and the vehicle's receipts of them) never reached the
    # database: its queued stage writes are lost from some point on
    with sessions() as session:
        for row in repo.list_commands(session=session, pass_id=pass_id):
            if row.stage in ("released", "sent", "received"):
                row.stage, row.transmissions = "queued", 0
                row.released_at_ns = row.sent_at_ns = row.received_at_ns = None
        session.commit()
    await sc.run(8.0)  # the vehicle flies what it holds; acks of the first 5 s reach no one
    ran_alone = {s for s in held if s in sc.vehicle.executed}
    assert len(ran_alone) > 10
    second = ground(sessions, clock, uplink_lead_window_s=LEAD_S)
    await second.restarted()
    await sc.connect(second)
    for _ in range(100):  # the resumed uplink's first step
        active = second.runner._active
        if active is not None and active.tracker.in_stage("expired"):
            break
        await sc.run(0.01)
    assert active is not None and active.pass_id == pass_id
    # the ground's guess, for now: no send on file, their tags passed
    assert ran_alone & set(active.tracker.in_stage("expired"))
    await second.runner.abort(pass_id, "otto", "test abort after a takeover")
    await sc.run(150.0)
    assert not second.runner.resolving
    rows = commands(sessions, pass_id)
    assert pass_state(sessions, pass_id) == "aborted"
    stages = _stages(rows)
    assert not set(stages) & {"queued", "released", "sent", "received"}, stages
    executed = sc.vehicle.executed
    wrong = {
        r.seq: r.stage
        for r in rows
        if (r.stage == "executed") != (r.seq in executed)
        or (r.seq not in executed and r.stage not in ("cancelled", "expired"))
    }
    assert not wrong, f"{len(wrong)} stages differ from the vehicle's record: {wrong}"
    assert ran_alone <= {r.seq for r in rows if r.stage == "executed"}
