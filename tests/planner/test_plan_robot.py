"""The plan document names the robot it was made for (issue 12): ``robot`` and
``robot_hash`` round-trip through JSON, and a document without them is ETS-VII's."""

from __future__ import annotations

import json

import numpy as np
import pytest

from planner.description import ETS7_DESCRIPTION, EXAMPLES_DIR, load_robot
from planner.dynamics import DynamicsWorkspace
from planner.errors import InvalidInput
from planner.model import RobotModel
from planner.plan import ETS7_ROBOT_HASH, ETS7_ROBOT_NAME, Plan, Segment, plan_for_robot
from planner.prediction import predict
from planner.ptp import ptp_commands

ORIHIME = EXAMPLES_DIR / "orihime" / "orihime.toml"


def _plan(model: RobotModel) -> Plan:
    ws = DynamicsWorkspace(model)
    times, joints = ptp_commands(model, np.zeros(6), np.radians([10.0, 0, 0, 0, 0, 0]))
    return Plan(
        experiment="ptp",
        parameters={},
        initial_joints_rad=joints[0],
        command_times_s=times,
        command_joints_rad=joints,
        segments=(Segment("A->B", "ptp", 0.0, float(times[-1])),),
        prediction=predict(ws, times, joints),
        metrics={},
    )


def test_the_ets7_defaults_are_the_ets7_file() -> None:
    robot = load_robot(ETS7_DESCRIPTION)
    assert (robot.name, robot.content_sha256) == (ETS7_ROBOT_NAME, ETS7_ROBOT_HASH)


def test_robot_fields_round_trip_and_default_to_ets7(model: RobotModel) -> None:
    plan = _plan(model)
    assert (plan.robot, plan.robot_hash) == (ETS7_ROBOT_NAME, ETS7_ROBOT_HASH)
    orihime = load_robot(ORIHIME)
    stamped = plan_for_robot(plan, orihime)
    assert (stamped.robot, stamped.robot_hash) == ("orihime", orihime.content_sha256)
    doc = json.loads(stamped.to_json())
    assert (doc["robot"], doc["robot_hash"]) == ("orihime", orihime.content_sha256)
    again = Plan.from_json(stamped.to_json())
    assert (again.robot, again.robot_hash) == ("orihime", orihime.content_sha256)
    assert again.to_json() == stamped.to_json()
    # a document written before the fields existed is ETS-VII's
    del doc["robot"], doc["robot_hash"]
    old = Plan.from_dict(doc)
    assert (old.robot, old.robot_hash) == (ETS7_ROBOT_NAME, ETS7_ROBOT_HASH)


def test_bad_robot_fields_are_refused(model: RobotModel) -> None:
    doc = json.loads(_plan(model).to_json())
    for key, value in (("robot", ""), ("robot", 7), ("robot_hash", "abc"), ("robot_hash", None)):
        bad = {**doc, key: value}
        with pytest.raises(InvalidInput, match=key):
            Plan.from_dict(bad)
