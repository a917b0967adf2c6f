"""Every experiment plans on a real vendor arm (issue 28, part 3): the UR5 and the Franka Panda
as example-robot-data ships them, each on a 300 kg cube (tests/planner/vendor/), with the
defaults the tool derives where the description gives none (docs/robots.md, "Experiment
defaults").

Each experiment and the pass are planned once per arm by the command line (``hikoboshi plan
--robot FILE --json``, in process: exit 0 means planned and every flight rule kept; its
contract as a real subprocess is tests/test_cli_plan.py's), and the plan file it writes is
checked against physics here: the reactionless motion leaves the base still with the wheels
off, the GJM hand reaches its target on its line, the non-holonomic plan ends at its
attitude, every joint within the mission's angle and rate limits. Failures name the
experiment, the time, the quantity and a parameter to change.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner, Result

from hikoboshi.cli import app
from planner.catalogue import experiments, parameters_from_values, plan_experiment, resolve
from planner.description import ETS7_DESCRIPTION, load_robot
from planner.dynamics import DynamicsWorkspace
from planner.errors import DidNotConverge, InfeasibleGoal, PlannerError
from planner.gjm import GjmParams, hand_positions_orbit_m
from planner.model import arm_reach_m
from planner.plan import Plan, check_plan_limits
from planner.prediction import predict
from planner.robot import RobotDescription, derived_experiment_defaults
from planner.schedule import EXPERIMENTS
from planner.state import State
from tests.support.vendor import URDFS, copy_robot

pytestmark = pytest.mark.slow

ROBOTS = list(URDFS)


@pytest.fixture(scope="module")
def vendor(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, RobotDescription]]:
    out = {}
    for robot in ROBOTS:
        toml = copy_robot(tmp_path_factory.mktemp(robot), robot)
        out[robot] = (toml, load_robot(toml))
    return out


_PLANNED: dict[tuple[str, str], tuple[Result, Path]] = {}


def planned(
    vendor: dict[str, tuple[Path, RobotDescription]], robot: str, experiment: str
) -> tuple[Result, Plan]:
    """``hikoboshi plan EXPERIMENT --robot FILE --json`` (once per module and pair)."""
    toml, _ = vendor[robot]
    if (robot, experiment) not in _PLANNED:
        out = toml.parent / f"{experiment}.json"
        result = CliRunner().invoke(
            app, ["plan", experiment, "--robot", str(toml), "--out", str(out), "--json"]
        )
        _PLANNED[robot, experiment] = (result, out)
    result, out = _PLANNED[robot, experiment]
    assert result.exit_code == 0, (result.stderr, result.exception)
    return result, Plan.from_json(out.read_text(encoding="utf-8"))


def _ws(vendor: dict[str, tuple[Path, RobotDescription]], robot: str) -> DynamicsWorkspace:
    return DynamicsWorkspace(vendor[robot][1].model)


def _check_stream(description: RobotDescription, plan: Plan) -> None:
    """Angles and 4 Hz steps inside the mission's limits; the plan stamped with the robot."""
    check_plan_limits(description.model, plan)
    rates = np.abs(np.diff(plan.command_joints_rad, axis=0)) / 0.25
    assert np.all(rates <= description.model.joint_rate_limit_radps * (1 + 1e-9))
    # the mission's 3 deg/s, well inside the vendor's 2.2-3.2 rad/s
    assert description.vendor_joint_rate_limit_radps is not None
    assert np.all(
        description.model.joint_rate_limit_radps < description.vendor_joint_rate_limit_radps
    )
    assert (plan.robot, plan.robot_hash) == (description.name, description.content_sha256)


@pytest.mark.parametrize("experiment", [*EXPERIMENTS, "pass"])
@pytest.mark.parametrize("robot", ROBOTS)
def test_every_experiment_plans_from_the_command_line_with_every_flight_rule_kept(
    vendor: dict[str, tuple[Path, RobotDescription]], robot: str, experiment: str
) -> None:
    result, plan = planned(vendor, robot, experiment)
    summary = json.loads(result.stdout)
    assert summary["flight_rules"]["passed"] is True
    assert plan.experiment == experiment
    _check_stream(vendor[robot][1], plan)
    if experiment == "pass":
        for name in EXPERIMENTS:
            assert f"{name}.start_s" in plan.metrics
        assert plan.metrics["duration_s"] <= plan.parameters["window_s"]


@pytest.mark.parametrize("robot", ROBOTS)
def test_ptp_goes_from_pose_a_to_pose_b(
    vendor: dict[str, tuple[Path, RobotDescription]], robot: str
) -> None:
    description = vendor[robot][1]
    _, plan = planned(vendor, robot, "ptp")
    np.testing.assert_array_equal(plan.initial_joints_rad, description.pose_joints_rad("A"))
    np.testing.assert_allclose(plan.command_joints_rad[-1], description.pose_joints_rad("B"))
    # the wheels bring the base back: its attitude ends inside the settling band
    assert plan.metrics["final_attitude_deg"] < plan.metrics["settle_band_deg"]


@pytest.mark.parametrize("robot", ROBOTS)
def test_reactionless_leaves_the_base_still_and_the_hand_near_its_line(
    vendor: dict[str, tuple[Path, RobotDescription]], robot: str
) -> None:
    ws = _ws(vendor, robot)
    _, plan = planned(vendor, robot, "reactionless")
    # ideal tracking with the wheels off: nothing hides a reaction
    free = predict(ws, plan.command_times_s, plan.command_joints_rad)
    turned_deg = np.degrees(Rotation.from_quat(free.quat_orbit_from_base_xyzw).magnitude())
    assert np.max(turned_deg) < 0.01, np.max(turned_deg)  # measured: about 1e-5 deg
    # a PTP between the same joints turns the base by tenths of a degree
    c_row = round(plan.segment("B->C").t_end_s / 0.25)
    straight = np.linspace(plan.initial_joints_rad, plan.command_joints_rad[c_row], c_row + 1)
    ptp = predict(ws, plan.command_times_s[: c_row + 1], straight)
    assert np.max(np.degrees(Rotation.from_quat(ptp.quat_orbit_from_base_xyzw).magnitude())) > (
        100 * np.max(turned_deg)
    )
    distance = plan.parameters["distance_m"]
    assert plan.metrics["hand_travel_m"] == pytest.approx(distance, rel=0.05)
    assert plan.metrics["hand_lateral_max_m"] <= 0.3 * distance
    assert plan.metrics["hand_orientation_change_max_deg"] <= 30.0
    # the hand's line measured on the plan's own commands, not the planner's path
    hands = np.array(
        [
            ws.hand_pose(State(joints_rad=q)).pos_robot_m
            for q in plan.command_joints_rad[: c_row + 1]
        ]
    )
    direction = np.array(plan.parameters["direction_robot"], dtype=float)
    direction /= np.linalg.norm(direction)
    moved = hands - hands[0]
    off_line = moved - np.outer(moved @ direction, direction)
    assert np.max(np.linalg.norm(off_line, axis=1)) <= 0.3 * distance
    np.testing.assert_array_equal(plan.command_joints_rad[-1], plan.initial_joints_rad)


@pytest.mark.parametrize("robot", ROBOTS)
def test_gjm_hand_reaches_its_target_on_its_line(
    vendor: dict[str, tuple[Path, RobotDescription]], robot: str
) -> None:
    ws = _ws(vendor, robot)
    _, plan = planned(vendor, robot, "gjm")
    distance = plan.parameters["approach_distance_m"]
    assert distance == pytest.approx(0.22 * arm_reach_m(ws.model) / 2.6494, abs=0.001)
    pos = hand_positions_orbit_m(ws, plan.prediction)
    rot_hand = Rotation.from_quat(plan.prediction.quat_orbit_from_hand_xyzw)
    axis_hand = np.array(plan.parameters["approach_axis_hand"], dtype=float)
    axis = rot_hand[0].as_matrix() @ (axis_hand / np.linalg.norm(axis_hand))
    end = round(plan.segment("approach").t_end_s / 0.25)
    target = pos[0] + distance * axis
    # the prediction (free drift, the base turning) meets the target: the hand's line is
    # fixed in the orbit frame whatever the base does
    assert np.linalg.norm(pos[end] - target) < 1e-6
    assert np.max((rot_hand[0].inv() * rot_hand).magnitude()) < 1e-6
    assert plan.metrics["base_attitude_change_deg"] > 0.01  # the base did turn
    # the approach is the hand's tool axis (the description's [experiments.gjm])
    assert plan.parameters["approach_axis_hand"] == [0.0, 0.0, 1.0]


@pytest.mark.parametrize("robot", ROBOTS)
def test_nonholonomic_ends_at_its_attitude_and_joints(
    vendor: dict[str, tuple[Path, RobotDescription]], robot: str
) -> None:
    description = vendor[robot][1]
    _, plan = planned(vendor, robot, "nonholonomic")
    goal = np.radians(plan.parameters["phi_end_deg"])
    np.testing.assert_allclose(goal, description.pose_joints_rad("A"), atol=1e-7)
    np.testing.assert_allclose(plan.prediction.joints_rad[-1], goal, atol=1e-12)
    # the prediction's end attitude within the planner's tolerance (1e-7 rad) of the target
    rot_end = Rotation.from_euler("ZYX", plan.parameters["attitude_end_deg"][::-1], degrees=True)
    end = Rotation.from_quat(plan.prediction.quat_orbit_from_base_xyzw[-1])
    assert (rot_end.inv() * end).magnitude() < 2e-7
    # ... though the base turned on the way
    assert plan.metrics["peak_attitude_change_deg"] > 0.1


@pytest.mark.parametrize("robot", ROBOTS)
def test_coordination_flies_the_configured_line_from_the_reference_pose(
    vendor: dict[str, tuple[Path, RobotDescription]], robot: str
) -> None:
    ws = _ws(vendor, robot)
    description = vendor[robot][1]
    _, plan = planned(vendor, robot, "coordination")
    np.testing.assert_array_equal(plan.initial_joints_rad, description.model.reference_joints)
    forward = plan.segment("(a) feedback: forward")
    k0, k1 = round(forward.t_start_s / 0.25), round(forward.t_end_s / 0.25)
    start = ws.hand_pose(State(joints_rad=plan.command_joints_rad[k0])).pos_robot_m
    end = ws.hand_pose(State(joints_rad=plan.command_joints_rad[k1])).pos_robot_m
    direction = np.array(plan.parameters["direction_robot"], dtype=float)
    np.testing.assert_allclose(end - start, plan.parameters["distance_m"] * direction, atol=1e-3)


def _params(description: RobotDescription, experiment: str, **values: Any) -> Any:
    return parameters_from_values(
        resolve(experiment)[0], values, defaults=description.experiment_defaults(experiment)
    )


@pytest.mark.parametrize(
    ("experiment", "values", "error", "pattern"),
    [
        (
            "reactionless",
            {"max_hand_lateral_m": 0.001},
            InfeasibleGoal,
            r"^reactionless: at t = \d+\.\d\d s of the B->C leg the hand is 0\.0\d\d m off its "
            r"line, more than max_hand_lateral_m = 0\.001 m: lower orientation_weight_m",
        ),
        (
            "reactionless",
            {"max_hand_orientation_change_deg": 0.5},
            InfeasibleGoal,
            r"^reactionless: at t = .* s of the B->C leg the hand has turned \d+\.\d deg, more "
            r"than max_hand_orientation_change_deg = 0\.5 deg: raise orientation_weight_m",
        ),
        (
            "gjm",
            {"approach_distance_m": 0.3},
            PlannerError,
            r"^gjm: joint \d moves at \d+\.\d+ deg/s exceeds limit 3\.000 deg/s during the "
            r"approach at t = \d+\.\d\d s: shorten approach_distance_m",
        ),
        (
            "nonholonomic",
            {"max_corrections": 0},
            DidNotConverge,
            r"^nonholonomic: at t = \d+\.\d\d s \(the motion's end\) the 4 Hz commands end "
            r".* rad from the target attitude after 0 corrections .*: raise max_corrections",
        ),
        (
            "coordination",
            {"speed_mps": 0.05},
            PlannerError,
            r"^coordination: joint \d moves at \d+\.\d+ deg/s exceeds limit 3\.000 deg/s at "
            r"t = \d+\.\d\d s \(segment '\(a\) feedback: forward'\): lower speed_mps",
        ),
    ],
)
def test_a_failure_names_the_experiment_the_time_the_quantity_and_a_parameter(
    vendor: dict[str, tuple[Path, RobotDescription]],
    experiment: str,
    values: dict[str, Any],
    error: type[PlannerError],
    pattern: str,
) -> None:
    description = vendor["ur5"][1]
    with pytest.raises(error, match=pattern) as caught:
        plan_experiment(experiment, _params(description, experiment, **values), robot=description)
    assert "\n" not in str(caught.value)


def test_the_pass_names_its_failing_experiment(
    vendor: dict[str, tuple[Path, RobotDescription]], tmp_path: Path
) -> None:
    toml, _ = vendor["panda"]
    folder = tmp_path / "panda"
    folder.mkdir()
    for file in toml.parent.iterdir():
        if file.suffix in (".toml", ".urdf"):
            (folder / file.name).write_bytes(file.read_bytes())
    text = (folder / "panda.toml").read_text()
    (folder / "panda.toml").write_text(
        text.replace(
            "approach_axis_hand = [0.0, 0.0, 1.0]",
            "approach_axis_hand = [0.0, 0.0, 1.0]\napproach_distance_m = 0.3",
        )
    )
    result = CliRunner().invoke(
        app,
        ["plan", "pass", "--robot", str(folder / "panda.toml"), "--out", str(tmp_path / "p.json")],
    )
    assert result.exit_code == 2, (result.stdout, result.stderr)
    (line,) = result.stderr.strip().splitlines()
    assert line.startswith(
        "error: pass: the gjm experiment failed (its parameters: the description's "
        "[experiments.gjm] table; or drop it from experiments): gjm: joint "
    )
    assert "during the approach at t = " in line and "shorten approach_distance_m" in line


def test_ets7_s_derived_defaults_are_its_own_numbers() -> None:
    """What the tool derives for ETS-VII is what the planners' defaults already are (its
    description gives the rest), so its plans do not change."""
    ets7 = load_robot(ETS7_DESCRIPTION)
    assert ets7.reach_ratio == 1.0
    for experiment in experiments():
        table = dict(ets7.experiments.get(experiment, {}))
        derived = derived_experiment_defaults(ets7, experiment, given=table)
        params_type = resolve(experiment)[0]
        defaults = params_type()
        for key, value in derived.items():
            assert getattr(defaults, key) == value, (experiment, key)
    assert derived_experiment_defaults(ets7, "gjm") == {
        "approach_distance_m": GjmParams().approach_distance_m
    }
