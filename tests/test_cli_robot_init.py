"""``hikoboshi robot init --urdf VENDOR.urdf --hand FRAME --out FILE.toml [--base-mass KG
--base-size M] [--json]`` (issue 28, part 6), run as a real subprocess on the vendor URDFs of
the PyPI package example-robot-data (UR5 and Panda, a dev dependency): the file it writes
loads, ``robot check``s clean, and its choices hold against the physics recomputed here
(poses inside the mission limits and away from singularities, the reaction-momentum bound
above what the PTP it writes carries, the servos under the integrator's bound over the
range); every experiment as written plans and passes the flight rules, except those marked
strict xfail with the numbers (issue 28, part 3: another branch)."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from planner.catalogue import parameters_from_values, plan_experiment, resolve
from planner.description import load_robot
from planner.dynamics import DynamicsWorkspace
from planner.robot import RobotDescription
from planner.state import State
from tests.planner.test_vendor_urdf import vendor_urdf

HIKOBOSHI = [sys.executable, "-m", "hikoboshi"]
HANDS = {"ur5": "tool0", "panda": "panda_hand_tcp"}
GUARD_S = 600  # a guard against a hang, not a timing assertion


def run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*HIKOBOSHI, *args], capture_output=True, text=True, timeout=GUARD_S)


@pytest.fixture(scope="module", params=list(HANDS))
def scaffolded(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> tuple[str, Path, dict[str, Any], RobotDescription]:
    robot = request.param
    out = tmp_path_factory.mktemp(robot) / "desc" / f"{robot}.toml"
    urdf = vendor_urdf(robot)
    result = run("robot", "init", "--urdf", str(urdf), "--hand", HANDS[robot], "--out", str(out),
                 "--json")  # fmt: skip
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    return robot, out, report, load_robot(out)


@pytest.mark.slow
def test_the_description_loads_with_the_vendor_file_unchanged(
    scaffolded: tuple[str, Path, dict[str, Any], RobotDescription],
) -> None:
    robot, out, report, description = scaffolded
    copied = out.parent / vendor_urdf(robot).name
    assert report["copied_urdf"] == str(copied)
    assert copied.read_bytes() == vendor_urdf(robot).read_bytes()
    assert description.n_joints == {"ur5": 6, "panda": 7}[robot]
    assert description.hand_link == HANDS[robot]
    assert description.reference_pose == "A"
    assert description.model.base_mass_kg > 300.0  # the cube and the vendor's root lumped
    check = run("robot", "check", str(out), "--json")
    assert check.returncode == 0, check.stderr
    servo = json.loads(check.stdout)["servo"]
    # the servos hold over 68 poses inside the limits, not only at the named poses
    assert servo["holds_over_range"], servo
    assert servo["fastest_over_range_per_s"] <= 0.81 * servo["limit_per_s"]


@pytest.mark.slow
def test_limits_and_poses_hold_against_the_physics(
    scaffolded: tuple[str, Path, dict[str, Any], RobotDescription],
) -> None:
    _, _, report, description = scaffolded
    model = description.model
    vendor = description.vendor_joint_limit_rad
    assert vendor is not None and description.vendor_joint_rate_limit_radps is not None
    assert np.all(model.joint_limit_rad[:, 0] >= vendor[:, 0])
    assert np.all(model.joint_limit_rad[:, 1] <= vendor[:, 1])
    assert np.all(model.joint_rate_limit_radps <= math.radians(3.0) + 1e-12)
    ws = DynamicsWorkspace(model)
    reach = report["reach_m"]
    margin = math.radians(2.0)  # the flight rules' joint-limit margin
    for name in "ABC":
        q = description.pose_joints_rad(name)
        assert np.all(q >= model.joint_limit_rad[:, 0] + margin), name
        assert np.all(q <= model.joint_limit_rad[:, 1] - margin), name
        J_g = ws.evaluate(State(joints_rad=q)).J_g.copy()
        J_g[3:] *= reach
        sigma = float(np.linalg.svd(J_g, compute_uv=False)[-1])
        # away from singularities: the stretched all-zero UR5 has sigma 0 (to round-off)
        assert sigma == pytest.approx(report["sigma_min_Jg"][name], rel=1e-3)
        assert sigma > 0.1, (name, sigma)
    zero = ws.evaluate(State(joints_rad=np.zeros(model.n_joints))).J_g.copy()
    zero[3:] *= reach
    assert float(np.linalg.svd(zero, compute_uv=False)[-1]) < 0.5 * min(
        report["sigma_min_Jg"].values()
    )


@pytest.mark.slow
def test_wheels_hold_the_arm_s_reaction(
    scaffolded: tuple[str, Path, dict[str, Any], RobotDescription],
) -> None:
    """The bound is above the reaction the written PTP carries (its prediction), and the
    wheels' capacity 2.5x the bound; the PTP's predicted wheel momentum stays inside the
    flight rules' 0.8 of it."""
    _, _, report, description = scaffolded
    bound = report["reaction_momentum_bound_nms"]
    capacity = min(w.momentum_limit_nms for w in description.wheel_limits)
    assert capacity >= 2.5 * bound
    params = parameters_from_values(
        resolve("ptp")[0], {}, defaults=description.experiment_defaults("ptp")
    )
    plan = plan_experiment("ptp", params, robot=description)
    carried = np.linalg.norm(plan.prediction.reaction_momentum_orbit_nms, axis=1)
    assert 0.0 < float(np.max(carried)) <= bound
    assert float(np.max(np.abs(plan.prediction.wheel_momentum_nms))) <= 0.8 * capacity


#: What does not plan yet as written (issue 28, part 3: branch ``planners``), measured.
NOT_YET: dict[tuple[str, str], str] = {
    ("ur5", "nonholonomic"): (
        "planned, but its path takes wrist_2_link into the base "
        "box: clearance -0.1256 m at t = 51.42 s against the flight rules' 0.05 m (with the "
        "offset reversed or halved, as measured on the earlier A: -0.105 and -0.040 m; issue 28 "
        "part 3, branch planners)"
    ),
}


@pytest.mark.slow
@pytest.mark.parametrize("experiment", ["ptp", "reactionless", "gjm", "coordination",
                                        "nonholonomic"])  # fmt: skip
def test_every_experiment_plans_as_written(
    scaffolded: tuple[str, Path, dict[str, Any], RobotDescription],
    experiment: str,
    request: pytest.FixtureRequest,
) -> None:
    robot, _, _, description = scaffolded
    reason = NOT_YET.get((robot, experiment))
    if reason is not None:
        request.applymarker(pytest.mark.xfail(strict=True, reason=reason))
    params = parameters_from_values(
        resolve(experiment)[0], {}, defaults=description.experiment_defaults(experiment)
    )
    plan = plan_experiment(experiment, params, robot=description)
    report = description.check_plan(plan)
    failing = [row for row in report.rows if row.verdict != "pass"]
    assert report.passed, failing
    rates = (
        np.abs(np.diff(plan.command_joints_rad, axis=0)) / np.diff(plan.command_times_s)[:, None]
    )
    assert np.all(rates <= description.model.joint_rate_limit_radps * (1 + 1e-6))


# --- refusals: exit 2, one line naming what is wrong ----------------------------------------


def _refused(result: subprocess.CompletedProcess[str], *needles: str) -> None:
    assert result.returncode == 2, (result.stdout, result.stderr)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]


def test_refusals_name_what_is_wrong(tmp_path: Path) -> None:
    urdf = vendor_urdf("ur5")
    out = tmp_path / "ur5.toml"
    args = ["robot", "init", "--urdf", str(urdf), "--out", str(out)]
    _refused(run(*args, "--hand", "no_such_link"), "no_such_link", "ur5_robot.urdf")
    _refused(run(*args, "--hand", "tool0", "--base-mass", "-3"), "--base-mass", "-3")
    _refused(run(*args, "--hand", "tool0", "--base-size", "0"), "--base-size")
    _refused(
        run("robot", "init", "--urdf", str(tmp_path / "none.urdf"), "--hand", "tool0",
            "--out", str(out)),
        "none.urdf",
    )  # fmt: skip
    out.write_text("# mine\n")
    _refused(run(*args, "--hand", "tool0"), str(out), "exists")
    assert out.read_text() == "# mine\n"  # left alone
    other = tmp_path / "b" / "ur5.toml"
    other.parent.mkdir()
    (other.parent / urdf.name).write_text("<robot name='else'/>")
    _refused(
        run("robot", "init", "--urdf", str(urdf), "--hand", "tool0", "--out", str(other)),
        "in the way",
    )
    assert not other.exists()


@pytest.mark.slow
def test_a_urdf_inside_the_folder_is_named_not_copied(tmp_path: Path) -> None:
    folder = tmp_path / "arm"
    (folder / "urdf").mkdir(parents=True)
    urdf = folder / "urdf" / "ur5_robot.urdf"
    shutil.copyfile(vendor_urdf("ur5"), urdf)
    out = folder / "ur5.toml"
    result = run("robot", "init", "--urdf", str(urdf), "--hand", "tool0", "--out", str(out),
                 "--base-mass", "500", "--base-size", "1.2")  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in folder.iterdir()) == ["ur5.toml", "urdf"]
    description = load_robot(out)
    assert description.urdf_path == urdf
    # a 500 kg cube of 1.2 m: its mass and its drawn box
    assert description.base_box_size_m == (1.2, 1.2, 1.2)
    assert description.model.base_mass_kg == pytest.approx(500.0 + 4.0, abs=1e-9)  # + base_link
    assert "wrote" in result.stdout and "robot check" in result.stdout
