"""End to end: the ground service (uvicorn, loopback) and the spacecraft process at 10x.

What an operator would check: every command executed at its tag with its stages stored,
every telemetry frame of the pass stored once, the pass's transitions in the audit log.
"""

from __future__ import annotations

import asyncio
import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from planner.plan import Plan
from server.services.summary import pass_summary
from server.storage import repository as repo
from server.storage.db import sqlite_url
from spacecraft.link import Outage
from spacecraft.process import SpacecraftProcess
from telemetry.wire import TelemetryFrame
from tests.server.link.harness import (
    OPERATOR,
    Ground,
    deleted_from_ns,
    in_contact,
    running_ground,
    settled,
    spacecraft,
    start_pass,
    store_pass,
    wait_for,
)

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time

TARGETS = tuple(f"t{i}" for i in range(1, 7))


def _window_frames(ground: Ground, generated: list[TelemetryFrame]) -> list[int]:
    [window] = ground.app.state.downlink.windows
    assert window.end_ns is not None
    return sorted(f.seq for f in generated if window.contains(f.generation_time_ns))


def _pass_events(ground: Ground, pass_id: str) -> list[tuple[str, str, str]]:
    with ground.readers() as session:
        page = repo.list_events(session=session, pass_id=pass_id, kinds=["pass_state"])
        return [(e.detail["from"], e.detail["to"], e.actor) for e in page.items]


async def _fly(
    ground: Ground,
    pass_id: str,
    name: str,
    timeout_s: float,
    started: Callable[[SpacecraftProcess, dict[str, Any]], None] | None = None,
    **link: object,
) -> tuple[list[TelemetryFrame], SpacecraftProcess]:
    """Start the pass over REST (``started`` is given the process and the started pass),
    wait for it to complete, stop the spacecraft (drain)."""
    process, generated = spacecraft(ground, **link)
    async with in_contact(process, ground.url) as client:
        response = await start_pass(client, pass_id, name)
        assert response.json()["state"] == "running"
        if started is not None:
            started(process, response.json())
        await wait_for(lambda: settled(ground, pass_id), timeout_s, "the pass settled")
    assert process.store.unacked == 0  # drained: every frame acknowledged
    return generated, process


def test_a_pass_executes_every_command_at_its_tag_and_stores_every_frame_once(
    database_url: str,
) -> None:
    with running_ground(database_url) as ground:
        pass_id = store_pass(ground.sessions, "nominal-1", (6.0, -3.0, 0.0, 6.0, 0.0, 0.0), 4.0)
        generated, _ = asyncio.run(_fly(ground, pass_id, "nominal-1", 30.0))
        expected = _window_frames(ground, generated)
        with ground.readers() as session:
            commands = repo.list_commands(session=session, pass_id=pass_id)
            stored = repo.frame_seqs(session=session, pass_id=pass_id)
            summary = pass_summary(session=session, pass_id=pass_id)
            n_rows = repo.count_frames(session=session, pass_id=pass_id)
            record = repo.get_pass(session=session, pass_id=pass_id)
            summary = pass_summary(session=session, pass_id=pass_id)
        status = ground.app.state.link.status()
        transitions = _pass_events(ground, pass_id)
    assert len(commands) == 35  # 34 joint commands and one ACS command
    assert [c.stage for c in commands] == ["executed"] * len(commands)
    assert all(c.executed_at_ns == c.execute_time_ns for c in commands)  # onboard, at the tag
    for c in commands:
        assert c.queued_at_ns <= c.released_at_ns <= c.sent_at_ns  # type: ignore[operator]
        assert c.received_at_ns is not None and c.received_at_ns < c.execute_time_ns
    assert record.epoch_ns is not None and record.epoch_ns % 250_000_000 == 0
    assert commands[0].execute_time_ns == record.epoch_ns
    # every frame generated in the pass's window stored exactly once
    assert len(expected) > 100
    assert stored == expected == list(range(expected[0], expected[-1] + 1))
    assert n_rows == len(stored)
    assert (summary.frames_expected, summary.frames_stored) == (len(expected), len(expected))
    assert (summary.frames_missing, summary.gaps_open, summary.duplicates_stored) == (0, 0, 0)
    assert summary.commands_executed == summary.commands_sent == summary.commands_total == 35
    assert summary.commands_rejected == {} and summary.commands_outstanding == 0
    assert transitions == [
        ("scheduled", "aos", "otto"),
        ("aos", "running", "otto"),
        ("running", "los", "ground"),
        ("los", "complete", "ground"),
    ]
    assert status.frames_missing == 0 and status.round_trip_s is not None
    # 2 x 3 s of relay (onboard s), plus however long the pong queued behind telemetry writes
    assert status.round_trip_s > 5.5
    # (how late each release was after its deadline is measured in bench/bench_uplink.py)


#: LOS from 10 s to 40 s of the plan (onboard): the arm is moving, its commands up to 44 s
#: must already be on board, the ones after it go again once the relay is back.
OUTAGE_IN_PLAN_S = (10.0, 40.0)


@pytest.mark.slow
def test_loss_and_a_30_s_outage_lose_no_frame_and_no_command_of_the_pass(tmp_path: Path) -> None:
    outages: list[Outage] = []

    def los_mid_pass(process: SpacecraftProcess, started: dict[str, Any]) -> None:
        # Placed on the pass's epoch, known only once it started, so that the scenario is the
        # same however long the ground took to get there: the schedule was loaded from the
        # start (the 52 s plan is within the 120 s lead window), 40 s before the first tag,
        # and the outage comes in the middle of the motion, as the flight's did.
        epoch_s = (started["epoch_ns"] - process.epoch_ns) / 1e9
        outage = Outage(epoch_s + OUTAGE_IN_PLAN_S[0], epoch_s + OUTAGE_IN_PLAN_S[1])
        process.add_outage(outage)
        outages.append(outage)

    with running_ground(sqlite_url(tmp_path)) as ground:
        # 52 s of plan at 10x under 10 % loss each way
        pass_id = store_pass(ground.sessions, "lossy", (10.0, 0.0, 0.0, 10.0, 0.0, 0.0), 45.0)
        generated, process = asyncio.run(
            _fly(ground, pass_id, "lossy", 60.0, started=los_mid_pass, loss=0.1)
        )
        expected = _window_frames(ground, generated)
        with ground.readers() as session:
            commands = repo.list_commands(session=session, pass_id=pass_id)
            stored = repo.frame_seqs(session=session, pass_id=pass_id)
            summary = pass_summary(session=session, pass_id=pass_id)
            record = repo.get_pass(session=session, pass_id=pass_id)
            retransmits = repo.list_events(session=session, kinds=["retransmit_requested"]).count
        status = ground.app.state.link.status()
    assert len(expected) > 500
    assert stored == expected  # frames missing == 0 after the drain
    assert summary.frames_expected == len(expected) and summary.frames_missing == 0
    assert summary.gaps_open == 0 and summary.duplicates_stored == 0
    assert status.frames_missing == 0
    assert retransmits > 0 and status.duplicates >= 0
    # The windowed uplink sent again what the relay lost and what went up into the outage:
    # every command executed on board at its tag, none expired or refused.
    assert record.state == "complete"
    assert summary.commands_expired == 0 and summary.commands_rejected == {}
    assert summary.commands_outstanding == 0
    assert summary.commands_executed == summary.commands_total == len(commands) > 50
    assert summary.commands_retransmitted > 0
    assert sum(c.transmissions for c in commands) > len(commands)
    # the outage happened, in the motion, and cost messages both ways
    [outage] = outages
    assert process.uplink.stats.dropped_outage > 0
    assert process.downlink_link.stats.dropped_outage > 0
    tags_s = [(c.execute_time_ns - process.epoch_ns) / 1e9 for c in commands]
    assert min(tags_s) < outage.start_s and max(tags_s) > outage.end_s
    # every command's stage on the ground is what became of it on board
    for c in commands:
        ack = process.vehicle.outcome(c.seq)
        assert ack is not None and c.stage == ack.stage.value == "executed", (c, ack)
        assert c.executed_at_ns == c.execute_time_ns


def test_a_plan_the_vehicle_refuses_is_stopped_and_the_arm_held(tmp_path: Path) -> None:
    def too_fast(plan: Plan) -> Plan:
        # Ten times the planned motion in the same time: beyond the 3 deg/s joint limit.
        q0 = plan.command_joints_rad[0]
        return dataclasses.replace(
            plan, command_joints_rad=q0 + 10.0 * (plan.command_joints_rad - q0)
        )

    with running_ground(sqlite_url(tmp_path)) as ground:
        pass_id = store_pass(
            ground.sessions, "refused", (4.0, 0.0, 0.0, 4.0, 0.0, 0.0), 30.0, edit=too_fast
        )
        generated, process = asyncio.run(_fly(ground, pass_id, "refused", 60.0))
        with ground.readers() as session:
            commands = repo.list_commands(session=session, pass_id=pass_id)
            record = repo.get_pass(session=session, pass_id=pass_id)
    refused = [c for c in commands if c.reject_reason == "out_of_limits"]
    assert len(refused) >= 8
    assert record.state == "aborted"
    assert "refused 8 commands in a row" in (record.state_reason or "")
    # The abort deleted the schedule; nothing of the plan ran, and every command is final
    # with what the vehicle said of it (refused) or the abort (cancelled).
    assert {c.stage for c in commands} <= {"rejected", "cancelled"}
    for c in commands:
        ack = process.vehicle.outcome(c.seq)
        if ack is not None:  # a command the delete removed is rejected `cancelled` on board
            deleted = ack.reason is not None and ack.reason.value == "cancelled"
            assert c.stage == ("cancelled" if deleted else ack.stage.value), (c, ack)
    # the arm never left where it was: its servo target never moved
    start = generated[0].joint_targets_rad
    assert len(generated) > 100
    assert all(f.joint_targets_rad == start for f in generated)


def test_abort_mid_pass_deletes_the_schedule_and_holds_the_arm(tmp_path: Path) -> None:
    async def scenario(ground: Ground, pass_id: str) -> SpacecraftProcess:
        process, _ = spacecraft(ground, loss=0.1)
        async with in_contact(process, ground.url) as client:
            await start_pass(client, pass_id, "abortive")

            def executed() -> int:
                with ground.readers() as session:
                    rows = repo.list_commands(session=session, pass_id=pass_id, stages=["executed"])
                    return len(rows)

            await wait_for(lambda: executed() >= 12, 30.0, "12 commands executed")
            response = await client.post(
                f"/api/passes/{pass_id}/abort",
                json={"confirm": "ABORT abortive", "reason": "test abort"},
                headers=OPERATOR,
            )
            assert response.status_code == 200, response.text
            assert response.json()["state"] == "aborted"

            def verified() -> bool:
                with ground.readers() as session:
                    page = repo.list_events(
                        session=session, pass_id=pass_id, kinds=["schedule_deleted"]
                    )
                return page.count > 0

            await wait_for(verified, 30.0, "the schedule_delete verified")
            from_ns = deleted_from_ns(ground, pass_id)

            def seen_past_the_delete() -> bool:
                newest = ground.app.state.downlink.newest
                return newest is not None and newest[1] >= from_ns + 5 * 10**9

            await wait_for(seen_past_the_delete, 30.0, "telemetry past the delete")
            await wait_for(lambda: not ground.app.state.runner.resolving, 30.0, "resolved")
        return process

    with running_ground(sqlite_url(tmp_path)) as ground:
        # 74 s of plan (14 s of motion, 60 s of settle): the abort comes with most of the
        # plan loaded on board
        pass_id = store_pass(ground.sessions, "abortive", (20.0, 0.0, 0.0, 20.0, 0.0, 0.0), 60.0)
        process = asyncio.run(scenario(ground, pass_id))
        from_ns = deleted_from_ns(ground, pass_id)
        with ground.readers() as session:
            commands = repo.list_commands(session=session, pass_id=pass_id)
            after = repo.telemetry_range(
                session=session,
                pass_id=pass_id,
                t0_ns=from_ns,
                t1_ns=from_ns + 10**12,
                fields=TARGETS,
            )
            record = repo.get_pass(session=session, pass_id=pass_id)
        transitions = _pass_events(ground, pass_id)
    assert record.state == "aborted" and record.state_reason == "test abort"
    assert from_ns % 250_000_000 == 0
    later = [c for c in commands if c.execute_time_ns >= from_ns]
    earlier = [c for c in commands if c.execute_time_ns < from_ns]
    assert len(later) > 10 and len(earlier) >= 12
    # Nothing executes from the abort's tag on: deleted on board or never sent, cancelled
    # with the reason; everything before it ran at its tag.
    assert {c.stage for c in later} == {"cancelled"}
    outcomes = [process.vehicle.outcome(c.seq) for c in later]
    assert not any(a is not None and a.stage.value == "executed" for a in outcomes)
    assert {c.stage for c in earlier} == {"executed"}
    assert all(c.executed_at_ns == c.execute_time_ns for c in earlier)
    # the arm holds at the last joint target before the delete's tag
    last = [c for c in earlier if c.kind == "joints"][-1]
    assert len(after) >= 10
    targets = np.array([row[2:] for row in after])
    hold_target = np.tile(last.payload["joints_rad"], (len(after), 1))
    np.testing.assert_allclose(targets, hold_target, rtol=0, atol=1e-12)
    assert transitions[-1] == ("running", "aborted", "otto")


def test_a_plan_into_the_base_is_refused_with_the_vehicle_connected_and_it_never_moves(
    database_url: str,
) -> None:
    """Issue #24's plan, stored with its rules table, against a live vehicle: start is 409
    ``flight_rule_violation`` naming the pair, the pass stays scheduled, no command reaches
    the vehicle, and its arm stays where it was while telemetry keeps coming."""

    async def attempt(ground: Ground, pass_id: str) -> tuple[httpx.Response, list[Any]]:
        process, generated = spacecraft(ground)
        async with in_contact(process, ground.url) as client:
            response = await client.post(
                f"/api/passes/{pass_id}/start",
                json={"confirm": "START into-the-base"},
                headers=OPERATOR,
            )
            seen = len(generated)
            # 20 onboard seconds of telemetry after the refusal
            await wait_for(lambda: len(generated) >= seen + 40, 30.0, "telemetry")
        return response, list(generated)

    with running_ground(database_url) as ground:
        pass_id = store_pass(
            ground.sessions, "into-the-base", (90.0, 120.0, 60.0, 0.0, 0.0, 0.0), 4.0
        )
        response, frames = asyncio.run(attempt(ground, pass_id))
        with ground.readers() as session:
            commands = repo.list_commands(session=session, pass_id=pass_id)
            record = repo.get_pass(session=session, pass_id=pass_id)
            refused = repo.list_events(
                session=session, pass_id=pass_id, kinds=["pass_start_refused"]
            ).items
    assert response.status_code == 409, response.text
    body = response.json()["error"]
    assert body["code"] == "flight_rule_violation"
    [row] = body["detail"]["rows"]
    assert row["rule"] == "clearance" and set(row["bodies"]) == {"base_link", "hand"}
    assert record.state == "scheduled" and commands == []
    assert len(refused) == 1 and refused[0].actor == "otto"
    joints = np.array([f.joints_rad for f in frames])
    assert len(joints) > 40
    assert np.max(np.abs(joints - joints[0])) < np.radians(0.1)  # sensor noise only
