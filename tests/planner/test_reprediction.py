"""planner.reprediction: a plan's prediction made again from its commands and stated start
equals the planner's own, and a prediction edited anywhere is caught at its first change."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from planner.catalogue import parameters_from_values, plan_experiment
from planner.description import default_robot
from planner.dynamics import DynamicsWorkspace
from planner.errors import InvalidInput
from planner.experiments import ReactionlessParams
from planner.plan import Plan, Prediction
from planner.reprediction import PREDICTION_TOLERANCE, prediction_difference, repredict
from planner.robot import RobotDescription
from planner.schedule import PassParams


@pytest.fixture(scope="module")
def robot() -> RobotDescription:
    return default_robot()


def _again(plan: Plan, robot: RobotDescription) -> Prediction:
    ws = DynamicsWorkspace(robot.model)
    return repredict(plan, ws, acs_gains=robot.acs_gains(ws), servo_gains=robot.servo_gains())


def _columns(prediction: Prediction) -> dict[str, list[object]]:
    return prediction.to_dict()


@pytest.fixture(scope="module")
def started_pass(robot: RobotDescription) -> Plan:
    """A short pass (one PTP) from a carried start: joints, attitude, rate, wheels, and
    the gravity-gradient torque on; read back from its document as an upload is."""
    params = parameters_from_values(
        PassParams,
        {
            "experiments": ["ptp"],
            "ptp_settle_s": 0.25,
            "transfer_settle_s": 0.25,
            "start_joints_rad": [0.1, 0.0, 0.0, 0.0, 0.0, 0.0],
            "start_quat_orbit_from_base_xyzw": [0.0, 0.0, 0.0998, 0.995],
            "start_omega_base_orbit_radps": [1e-4, -2e-4, 5e-5],
            "start_wheel_momentum_nms": [0.5, -0.3, 0.2],
            "gravity_gradient_radius_m": 6.9e6,
        },
        defaults=robot.experiment_defaults("pass"),
    )
    return Plan.from_json(plan_experiment("pass", params, robot=robot).to_json())


def test_a_pass_from_a_carried_start_is_predicted_again_exactly(
    started_pass: Plan, robot: RobotDescription
) -> None:
    assert np.any(started_pass.prediction.wheel_momentum_nms[0] != 0.0)
    again = _again(started_pass, robot)
    assert _columns(again) == _columns(started_pass.prediction)
    assert prediction_difference(started_pass.prediction, again, tolerance=0.0) is None


def test_the_orbit_the_parameters_name_is_the_one_predicted_with(
    started_pass: Plan, robot: RobotDescription
) -> None:
    # the same document saying no gravity gradient: the ground's prediction is another one
    without = dataclasses.replace(
        started_pass, parameters={**started_pass.parameters, "gravity_gradient_radius_m": 0.0}
    )
    found = prediction_difference(started_pass.prediction, _again(without, robot), tolerance=0.0)
    assert found is not None and found.t_s > 0.0


def test_an_edited_start_is_caught_where_it_leads(
    started_pass: Plan, robot: RobotDescription
) -> None:
    """Row 0 is the plan's stated start: edited alone, the rows after it no longer follow."""
    wheels = started_pass.prediction.wheel_momentum_nms.copy()
    wheels[0, 1] += 0.05
    forged = dataclasses.replace(
        started_pass,
        prediction=dataclasses.replace(started_pass.prediction, wheel_momentum_nms=wheels),
    )
    found = prediction_difference(forged.prediction, _again(forged, robot))
    assert found is not None
    assert (found.quantity, found.component, found.t_s) == ("wheel_momentum_nms", 1, 0.25)
    assert found.document == pytest.approx(started_pass.prediction.wheel_momentum_nms[1, 1])
    assert abs(found.ground - found.document) > PREDICTION_TOLERANCE
    assert "wheel_momentum_nms[1] at t = 0.25 s" in str(found)


@pytest.fixture(scope="module")
def preshaped(robot: RobotDescription) -> Plan:
    params = parameters_from_values(
        ReactionlessParams,
        {"compensate_servo_lag": True, "pause_s": 0.0, "tail_s": 0.0},
        defaults=robot.experiment_defaults("reactionless"),
    )
    return plan_experiment("reactionless", params, robot=robot)


def test_a_preshaped_plan_is_predicted_along_the_path_it_is_shaped_for(
    preshaped: Plan, robot: RobotDescription
) -> None:
    assert not np.array_equal(preshaped.prediction.joints_rad, preshaped.command_joints_rad)
    assert _columns(_again(preshaped, robot)) == _columns(preshaped.prediction)


def test_a_path_the_commands_are_not_shaped_for_is_refused(
    preshaped: Plan, robot: RobotDescription
) -> None:
    path = preshaped.prediction.joints_rad.copy()
    path[40, 2] += 1e-3
    forged = dataclasses.replace(
        preshaped, prediction=dataclasses.replace(preshaped.prediction, joints_rad=path)
    )
    with pytest.raises(InvalidInput, match="pre-shaped") as refused:
        _again(forged, robot)
    assert "joint 3" in str(refused.value)
