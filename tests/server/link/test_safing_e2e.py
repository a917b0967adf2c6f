"""End to end, a real fault: the ground service (uvicorn, loopback) and the spacecraft
process at 10x, joint 3 stuck during a PTP motion.

The vehicle's own check trips at its red tracking-error limit and it safes itself (arm
held, schedule dropped, ``safing`` report); the ground hears it, stops the uplink, files
the pass ``safed`` with the trigger, raises the critical alarm, and no command executes
after the safing. Then no pass starts until an operator's confirmed exit, which the vehicle
answers. Nothing of the fault reaches the ground but what the telemetry and the vehicle's
report show; the truth log says when it began.
"""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path

import pytest

from server.storage import repository as repo
from server.storage.models import AlarmRecord
from spacecraft.faults import parse_fault
from spacecraft.vehicle_config import VehicleConfig
from tests.server.link.harness import (
    OPERATOR,
    VIEWER,
    Ground,
    in_contact,
    running_ground,
    settled,
    spacecraft,
    start_pass,
    store_pass,
    wait_for,
)

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time

#: Joint 3 by 60 deg: a 41.75 s motion (the plan keeps the flight rules).
GOAL_DEG = (0.0, 0.0, 60.0, 0.0, 0.0, 0.0)
MOTION_S = 41.75
#: The fault, 20 s into the motion: counted on board from the pass's first command (its
#: tag is the pass's epoch), whenever the ground starts it. (As onboard seconds from the
#: spacecraft's start, a loaded machine's later start put it 3.75 s before the epoch.)
FAULT_AFTER_S = 20.0


def _alarms(ground: Ground, pass_id: str) -> list[AlarmRecord]:
    with ground.readers() as session:
        return list(session.query(AlarmRecord).filter(AlarmRecord.pass_id == pass_id))


def test_a_joint_stuck_mid_motion_safes_the_vehicle_and_the_ground_files_the_pass_safed(
    database_url: str, tmp_path: Path
) -> None:
    truth_log = tmp_path / "truth.jsonl"
    fault = parse_fault(f"joint3-stuck@cmd+{FAULT_AFTER_S:g}")
    with running_ground(database_url) as ground:
        pass_id = store_pass(ground.sessions, "stuck", GOAL_DEG, 2.0)
        other = store_pass(ground.sessions, "after", (0.0, 0.0, 0.0, 5.0, 0.0, 0.0), 1.0)
        process, _ = spacecraft(ground, vehicle=VehicleConfig(faults=(fault,)), truth_log=truth_log)

        async def scenario() -> dict[str, object]:
            async with in_contact(process, ground.url) as client:
                started = await start_pass(client, pass_id, "stuck")
                epoch_ns = int(started.json()["epoch_ns"])
                await wait_for(lambda: settled(ground, pass_id), 60.0, "the pass settled")
                status = (await client.get("/api/link/status", headers=VIEWER)).json()
                # while safe, no pass starts
                refused = await client.post(
                    f"/api/passes/{other}/start", json={"confirm": "START after"},
                    headers=OPERATOR,
                )  # fmt: skip
                assert refused.status_code == 409, refused.text
                assert refused.json()["error"]["code"] == "vehicle_safe"
                # the operator's exit: the vehicle answers, the link says nominal
                exit_ = await client.post(
                    "/api/vehicle/safe-exit",
                    json={"confirm": "EXIT SAFE ETS-VII"},
                    headers=OPERATOR,
                )
                assert exit_.status_code == 202, exit_.text

                async def nominal() -> bool:
                    reply = await client.get("/api/link/status", headers=VIEWER)
                    return bool(reply.json()["vehicle_mode"] == "nominal")

                deadline = time.monotonic() + 30.0  # a guard, not a timing assertion
                while not await nominal():
                    assert time.monotonic() < deadline, "the vehicle never left SAFE"
                    await asyncio.sleep(0.05)
                return {"epoch_ns": epoch_ns, "status": status, "exit": exit_.json()}

        result = asyncio.run(scenario())
        with ground.readers() as session:
            record = repo.get_pass(session=session, pass_id=pass_id)
            commands = repo.list_commands(session=session, pass_id=pass_id)
            exited = repo.list_events(session=session, kinds=["vehicle_safe_exited"]).items
        alarms = _alarms(ground, pass_id)

    truth = [json.loads(line) for line in truth_log.read_text().splitlines()]
    [onset] = [r for r in truth if r["event"] == "fault"]
    [entry] = [r for r in truth if r["event"] == "safing_entry"]
    [left] = [r for r in truth if r["event"] == "safing_exit"]
    epoch_ns = int(result["epoch_ns"])  # type: ignore[call-overload]
    motion_end_ns = epoch_ns + round(MOTION_S * 1e9)
    # the fault began 20 s into the PTP motion (its first command's tag is the epoch; the
    # truth simulation's 10 ms grid), and the vehicle safed itself before the motion ended
    assert 0 <= onset["onboard_time_ns"] - (epoch_ns + round(FAULT_AFTER_S * 1e9)) < 10_000_000
    assert onset["onboard_time_ns"] < entry["onboard_time_ns"] < motion_end_ns
    assert entry["quantity"] == "joint_tracking_error_deg" and entry["channel"] == "joint3"
    assert entry["value"] >= entry["limit"]
    # the ground: safed, naming the trigger; the window runs on past the safing
    assert record.state == "safed"
    assert "joint_tracking_error_deg joint3" in (record.state_reason or "")
    assert record.telemetry_end_ns is not None
    assert record.telemetry_end_ns > entry["onboard_time_ns"]
    # no command executed after the safing; the dropped ones filed cancelled / safing; all
    # final (the vehicle's own word, or the ground's for those it never sent)
    since = entry["onboard_time_ns"]
    executed = [c for c in commands if c.stage == "executed"]
    assert executed and all(c.execute_time_ns <= since for c in executed)
    assert all(c.executed_at_ns is not None and c.executed_at_ns <= since for c in executed)
    dropped = [c for c in commands if c.reject_reason == "safing"]
    assert len(dropped) == entry["cancelled"] > 0
    assert {c.stage for c in dropped} == {"cancelled"}
    assert {c.stage for c in commands} <= {"executed", "cancelled"}
    # the alarms: the ground's own on the joint, at red, and the vehicle's critical one
    by_quantity = {(a.quantity, a.channel): a for a in alarms}
    joint = by_quantity[("joint_tracking_error_deg", "joint3")]
    assert joint.severity == "critical" and joint.source == "limit"
    assert joint.raised_generation_time_ns is not None
    assert onset["onboard_time_ns"] < joint.raised_generation_time_ns <= since
    vehicle = by_quantity[("vehicle_safing", "")]
    assert (vehicle.severity, vehicle.source) == ("critical", "vehicle")
    # the link status while safe; then the exit, answered by the vehicle
    status = result["status"]
    assert isinstance(status, dict)
    assert status["vehicle_mode"] == "safe"
    assert status["safing"]["since_time_ns"] == since
    assert status["safing"]["pass_id"] == pass_id
    request_id = result["exit"]["request_id"]  # type: ignore[index]
    assert left["request_id"] == request_id
    assert [e.detail["request_id"] for e in exited] == [request_id]
