"""The ground flies a plan only on the robot it was made for (issue 12), in simulated time.

The vehicle's ``hello`` names its robot (the description's name, hash and joint count; a
``hello`` naming none is ETS-VII's); a plan records the robot it was made for. A start
against another robot is refused 409 ``robot_mismatch`` and audited, and the pass stays
scheduled; a vehicle of another robot greeting mid-pass gets no command of the plan and the
pass is aborted. The scripted relay and vehicle of ``simulated.py`` run on a ManualClock.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import select

from planner.plan import ETS7_ROBOT_HASH, Plan
from server.api.errors import status_of
from server.services.clock import ManualClock
from server.services.errors import DomainError
from server.storage.models import EventRecord
from telemetry.wire import AcsCommandMsg, JointCommandMsg, decode_ground
from tests.server.link.harness import add_plan_and_pass
from tests.server.link.simulated import (
    SimulatedSpacecraft,
    commands,
    ground,
    make_sessions,
    pass_state,
    simulated,
)
from tests.server.storage.factories import make_plan

ORIHIME_HASH = "3b" * 32  # any description hash other than ETS-VII's
OTHER_HASH = "c0" * 32
ORIHIME = {"robot": "orihime", "robot_hash": ORIHIME_HASH, "n_joints": 7}


class RecordingSpacecraft(SimulatedSpacecraft):
    """Keeps every message the ground sends, with the simulated instant it was sent."""

    def __init__(self, clock: ManualClock, **kw: Any) -> None:
        super().__init__(clock, **kw)
        self.sent_by_ground: list[tuple[float, Any]] = []

    def _relay(self, to: str, payload: Any) -> None:
        if to == "vehicle":
            self.sent_by_ground.append((self.clock.monotonic(), decode_ground(payload)))
        super()._relay(to, payload)

    def commands_sent(self, since: float = float("-inf")) -> list[Any]:
        return [
            m
            for t, m in self.sent_by_ground
            if t >= since and isinstance(m, JointCommandMsg | AcsCommandMsg)
        ]


def _orihime_plan(n_commands: int = 80) -> Plan:
    return replace(make_plan(n_commands, n_joints=7), robot="orihime", robot_hash=ORIHIME_HASH)


async def _setup(
    tmp_path: Path, plan: Plan, **hello: Any
) -> tuple[ManualClock, Any, RecordingSpacecraft, str]:
    clock = ManualClock()
    sessions = make_sessions(tmp_path)
    g = ground(sessions, clock)
    sc = RecordingSpacecraft(clock)
    await sc.connect(g, **hello)
    pass_id = add_plan_and_pass(sessions, plan, "robot-pass", now_ns=clock.time_ns(), window_s=3600)
    return clock, g, sc, pass_id


def _events(g: Any, kind: str) -> list[EventRecord]:
    with g.sessions() as session:
        return list(session.scalars(select(EventRecord).where(EventRecord.kind == kind)).all())


async def _refused(g: Any, sc: RecordingSpacecraft, pass_id: str) -> DomainError:
    with pytest.raises(DomainError) as caught:
        await g.runner.start(pass_id, "otto")
    await sc.run(10.0)
    await g.db.drain()
    assert status_of(caught.value) == 409 and caught.value.code == "robot_mismatch"
    # nothing started, nothing stored, nothing sent: the pass can still be flown later
    assert pass_state(g.sessions, pass_id) == "scheduled"
    assert commands(g.sessions, pass_id) == []
    assert sc.commands_sent() == [] and g.runner.active_pass_id is None
    assert g.downlink.windows == [] or all(w.pass_id != pass_id for w in g.downlink.windows)
    return caught.value


@simulated
async def test_a_plan_for_orihime_is_refused_by_an_ets7_vehicle(tmp_path: Path) -> None:
    _, g, sc, pass_id = await _setup(tmp_path, _orihime_plan())  # hello names no robot
    error = await _refused(g, sc, pass_id)
    assert error.message.startswith(
        "the plan was made for robot 'orihime' (7 joints, description 3b3b3b3b3b3b) but the "
        "connected vehicle flies 'ets7' (6 joints, description "
        f"{ETS7_ROBOT_HASH[:12]})"
    )
    refused = _events(g, "pass_start_refused")
    assert len(refused) == 1 and refused[0].actor == "otto" and refused[0].pass_id == pass_id
    assert refused[0].detail["plan_robot_hash"] == ORIHIME_HASH
    assert refused[0].detail["vehicle_robot_hash"] == ETS7_ROBOT_HASH
    assert (refused[0].detail["plan_n_joints"], refused[0].detail["vehicle_n_joints"]) == (7, 6)
    assert error.detail == refused[0].detail


@simulated
async def test_a_plan_for_ets7_is_refused_by_an_orihime_vehicle(tmp_path: Path) -> None:
    _, g, sc, pass_id = await _setup(tmp_path, make_plan(80), **ORIHIME)
    error = await _refused(g, sc, pass_id)
    assert "made for robot 'ets7' (6 joints" in error.message
    assert "vehicle flies 'orihime' (7 joints" in error.message
    # the link status names the vehicle's robot
    status = g.link.status()
    assert (status.robot, status.robot_hash, status.n_joints) == ("orihime", ORIHIME_HASH, 7)


@simulated
async def test_the_same_joint_count_but_another_description_is_refused(tmp_path: Path) -> None:
    plan = replace(make_plan(80), robot="ets7-modified", robot_hash=OTHER_HASH)
    _, g, sc, pass_id = await _setup(tmp_path, plan)
    error = await _refused(g, sc, pass_id)
    assert "'ets7-modified' (6 joints, description c0c0c0c0c0c0)" in error.message


@simulated
async def test_a_plan_for_orihime_flies_on_the_orihime_vehicle(tmp_path: Path) -> None:
    _, g, sc, pass_id = await _setup(tmp_path, _orihime_plan(), **ORIHIME)
    await g.runner.start(pass_id, "otto")
    await sc.run(90.0)
    await g.db.drain()
    rows = commands(g.sessions, pass_id)
    assert pass_state(g.sessions, pass_id) == "complete"
    assert {r.stage for r in rows} == {"executed"} and len(rows) == 81  # 80 joint + 1 ACS
    joints = [m for m in sc.commands_sent() if isinstance(m, JointCommandMsg)]
    assert len(joints) == 80 and all(len(m.joints_rad) == 7 for m in joints)
    assert _events(g, "pass_start_refused") == []


@simulated
async def test_an_ets7_plan_flies_on_a_vehicle_that_names_no_robot(tmp_path: Path) -> None:
    """A hello without robot fields (a vehicle that predates them) is ETS-VII's."""
    _, g, sc, pass_id = await _setup(tmp_path, make_plan(40))
    status = g.link.status()
    assert (status.robot, status.robot_hash, status.n_joints) == ("ets7", ETS7_ROBOT_HASH, 6)
    await g.runner.start(pass_id, "otto")
    await sc.run(60.0)
    await g.db.drain()
    assert pass_state(g.sessions, pass_id) == "complete"


@simulated
async def test_another_robot_greeting_mid_pass_gets_no_command_and_the_pass_aborts(
    tmp_path: Path,
) -> None:
    # 400 commands (100 s): the lead window keeps loading them while the pass runs
    clock, g, sc, pass_id = await _setup(tmp_path, _orihime_plan(400), **ORIHIME)
    await g.runner.start(pass_id, "otto")
    await sc.run(20.0)
    before = len(sc.commands_sent())
    assert before > 0
    await sc.disconnect()
    await sc.run(2.0)
    reconnected = clock.monotonic()
    await sc.connect(g)  # a vehicle that names no robot: ETS-VII
    await sc.run(150.0)
    await g.db.drain()
    assert sc.commands_sent(since=reconnected) == []
    assert pass_state(g.sessions, pass_id) == "aborted"
    aborted = [e for e in _events(g, "pass_state") if e.detail["to"] == "aborted"]
    assert len(aborted) == 1
    assert (
        aborted[0]
        .detail["reason"]
        .startswith("another robot connected mid-pass: the plan was made for robot 'orihime'")
    )
    assert g.runner.active_pass_id is None
