"""End to end, a near miss watched live: the ground service (uvicorn, loopback) and the
spacecraft process at 10x fly a PTP motion whose predicted clearance keeps the flight rules
by 16 mm, with an offset injected into joint 2's servo that brings the hand 0.05 m nearer
the task board.

The ground's live clearance (``clearance_m``, the watch of planner.clearance_watch on every
frame's measured joints) raises its alarm during the pass, at the frame where the clearance
recomputed afterwards from the stored frames first falls to the watch band; the post-pass
``flown_clearance`` analysis finds the alarm's worst value again. Times are the vehicle's
(frame generation times, the pass's epoch, command tags), never the ground's wall clock.
"""

from __future__ import annotations

import asyncio
import json
import math
import time
from pathlib import Path

import httpx
import numpy as np
import pytest

from planner.clearance_watch import ClearanceWatch
from planner.collision import PoseChain
from planner.description import default_robot
from planner.dynamics import DynamicsWorkspace
from planner.experiments import PtpParams, plan_ptp
from planner.flight_rules import FlightRulesReport
from planner.plan import Plan
from planner.robot import RobotDescription
from server.services.recordings import load_recording
from server.storage import repository as repo
from server.storage.db import sqlite_url
from server.storage.models import AlarmRecord
from spacecraft.faults import parse_fault
from spacecraft.vehicle_config import VehicleConfig
from tests.server.link.harness import (
    OPERATOR,
    VIEWER,
    Ground,
    add_plan_and_pass,
    in_contact,
    running_ground,
    settled,
    spacecraft,
    start_pass,
    wait_for,
    with_flight_rules,
)

pytestmark = pytest.mark.realtime  # flies a vehicle and serves a live link in wall time

#: Joint 2 to 39.5 deg from the all-zero pose: the hand comes down over the task board; the
#: flight rules' predicted clearance is 0.1159 m (hand - task_board) against their 0.10 m.
GOAL_DEG = (0.0, 39.5, 0.0, 0.0, 0.0, 0.0)
#: How far the offset brings the hand's nearest point toward the board.
APPROACH_M = 0.05
#: The offset's onset, onboard s after the pass's first command (its tag is the epoch).
FAULT_AFTER_S = 5.0
FRAME_PERIOD_NS = 100_000_000  # the vehicle's 10 Hz telemetry


def _near_miss() -> tuple[RobotDescription, Plan, FlightRulesReport]:
    robot = default_robot()
    plan = plan_ptp(
        DynamicsWorkspace(robot.model), PtpParams(goal_joints_deg=GOAL_DEG, settle_s=2.0)
    )
    plan = with_flight_rules(plan)  # as the ground stores it
    assert plan.flight_rules is not None
    return robot, plan, FlightRulesReport.from_dict(plan.flight_rules)


def _offset_deg(robot: RobotDescription, report: FlightRulesReport) -> float:
    """The joint 2 offset that moves the hand's nearest point APPROACH_M toward the board's,
    from the geometry of the predicted worst (the goal pose: joint 1 stays at 0): turning
    joint 2 by ``d`` moves a point ``p`` by ``(axis x (p - c)) d`` (``axis`` and ``c`` joint
    2's axis and a point on it, posed by joint 1), of which ``n . (axis x (p - c)) d`` along
    the unit ``n`` from the hand's nearest point to the board's."""
    [row] = [r for r in report.rows if r.rule == "clearance"]
    assert row.bodies is not None and row.points_robot_m is not None
    points = dict(zip(row.bodies, (np.array(p) for p in row.points_robot_m), strict=True))
    hand, board = points["hand"], points["task_board"]
    R, t = PoseChain(robot.model).poses(np.radians(GOAL_DEG)[None, :])
    link = robot.model.links[1]
    axis = R[0, 1] @ link.joint_axis_robot
    centre = R[0, 1] @ link.joint_pos_robot_m + t[0, 1]
    n = (board - hand) / np.linalg.norm(board - hand)
    lever = float(np.cross(axis, hand - centre) @ n)  # m of approach per rad
    return math.degrees(APPROACH_M / lever)


def _clearance_alarm(ground: Ground, pass_id: str) -> AlarmRecord | None:
    with ground.readers() as session:
        rows = (
            session.query(AlarmRecord)
            .filter(AlarmRecord.pass_id == pass_id, AlarmRecord.quantity == "clearance_m")
            .all()
        )
    assert len(rows) <= 1, rows
    return rows[0] if rows else None


def test_a_servo_offset_on_a_near_miss_raises_the_live_clearance_alarm_at_the_crossing(
    tmp_path: Path,
) -> None:
    robot, plan, report = _near_miss()
    rows = {r.rule: r for r in report.rows}
    margin = rows["clearance"].value - rows["clearance"].limit
    assert all(r.passed for r in report.rows) and 0.0 < margin < 0.02  # a near miss
    offset_deg = _offset_deg(robot, report)
    assert 1.5 < offset_deg < 2.0  # the hand is 1.63 m from joint 2's axis, across n
    # the offset as the exact distance sees it: the hand about APPROACH_M nearer the board
    watch = ClearanceWatch(robot, math.inf)
    goal = np.radians(GOAL_DEG)
    nearer = goal + np.radians(offset_deg) * np.eye(6)[1]
    assert watch.exact_m(goal) - watch.exact_m(nearer) == pytest.approx(APPROACH_M, abs=1e-3)
    threshold = robot.limits["clearance_m"].least  # the watch band, 0.085 m
    red = robot.limits.safing_limits()["clearance_m"]

    fault = parse_fault(f"joint2-offset@cmd+{FAULT_AFTER_S:g},deg={offset_deg:.6f}")
    truth_log = tmp_path / "truth.jsonl"
    with running_ground(sqlite_url(tmp_path)) as ground:
        pass_id = add_plan_and_pass(
            ground.sessions, plan, "near-miss", now_ns=time.time_ns(), window_s=1200.0
        )
        process, _ = spacecraft(ground, vehicle=VehicleConfig(faults=(fault,)), truth_log=truth_log)

        async def fly() -> int:
            async with in_contact(process, ground.url) as client:
                started = await start_pass(client, pass_id, "near-miss")
                await wait_for(lambda: settled(ground, pass_id), 60.0, "the pass settled")
                return int(started.json()["epoch_ns"])

        epoch_ns = asyncio.run(fly())
        # the live alarm, before any analysis was asked for
        alarm = _clearance_alarm(ground, pass_id)
        with ground.readers() as session:
            record = repo.get_pass(session=session, pass_id=pass_id)
            commands = repo.list_commands(session=session, pass_id=pass_id)
            recording = load_recording(session=session, pass_id=pass_id)
            assert not repo.list_analyses(session=session, pass_id=pass_id)
        with httpx.Client(base_url=ground.url, timeout=120.0) as client:
            ran = client.post(f"/api/passes/{pass_id}/analyses", headers=OPERATOR)
            assert ran.status_code == 201, ran.text
            flown = client.get(
                f"/api/passes/{pass_id}/analyses/flown_clearance", headers=VIEWER
            ).json()

    # the pass flew to its end: the clearance never reached the red limit the vehicle safes at
    assert record.state == "complete", record.state_reason
    onset = next(
        e for e in map(json.loads, truth_log.read_text().splitlines()) if e["event"] == "fault"
    )
    assert onset["fault"] == "joint2-offset" and onset["deg"] == pytest.approx(offset_deg)
    # the stored frames' clearance, recomputed afterwards, exact at every frame
    joints = np.asarray(recording.frames.joints_rad)
    times = recording.frames.generation_time_ns
    exact = np.array([watch.exact_m(q) for q in joints])
    below = np.flatnonzero(exact <= threshold)
    assert below.size, f"the flown clearance never fell to {threshold} m: {exact.min()}"
    crossed_ns = int(times[below[0]])
    assert onset["onboard_time_ns"] < crossed_ns
    assert red < exact.min() < threshold

    # (a) raised live, during the pass's motion: between its epoch and its last command's tag
    assert alarm is not None and alarm.source == "limit" and alarm.severity == "watch"
    assert alarm.raised_generation_time_ns is not None
    last_tag_ns = max(c.execute_time_ns for c in commands)
    assert epoch_ns <= alarm.raised_generation_time_ns <= last_tag_ns
    # (b) at the crossing's frame, or at most one frame after it (never before it)
    late_ns = alarm.raised_generation_time_ns - crossed_ns
    assert 0 <= late_ns <= FRAME_PERIOD_NS, late_ns
    assert alarm.trigger_value == pytest.approx(exact[below[0]], abs=1e-9)
    # (c) the analysis's minimum is the live one (the watch is exact below its threshold)
    assert flown["status"] == "ok", flown
    analysed = flown["result"]["flown"]["value_m"]
    assert alarm.worst_value is not None
    assert abs(analysed - alarm.worst_value) <= 1e-3
    assert analysed == pytest.approx(float(exact.min()), abs=1e-9)
    assert flown["result"]["flown"]["bodies"] == ["hand", "task_board"]
    print(
        f"near miss: threshold {threshold} m, predicted {rows['clearance'].value:.4f} m, "
        f"offset {offset_deg:.4f} deg; crossing frame at {(crossed_ns - epoch_ns) / 1e9:.1f} s, "
        f"alarm frame at {(alarm.raised_generation_time_ns - epoch_ns) / 1e9:.1f} s "
        f"(plan clock); live min {alarm.worst_value:.6f} m, analysis min {analysed:.6f} m"
    )
