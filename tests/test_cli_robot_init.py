"""``hikoboshi robot init --urdf VENDOR.urdf --hand FRAME --out FILE.toml [--base-mass KG
--base-size M] [--json]`` (issue 28, part 6), run as a real subprocess on the vendor URDFs of
the PyPI package example-robot-data (UR5 and Panda, a dev dependency): the file it writes
loads, ``robot check``s clean, and its choices hold against the physics recomputed here
(poses inside the mission limits and away from singularities, the reaction-momentum bound
above what the PTP it writes carries, the servos under the integrator's bound over the
range); every experiment as written plans and passes the flight rules, as the scaffold's
report says, and the non-holonomic start it chose is the first of its candidates whose plan
passes them.

Each arm is scaffolded once per test run (:func:`scaffold_once`, shared with
tests/planner/test_vendor_pinocchio.py and across xdist's workers): the UR5 on the default
cube with its URDF inside the description's folder (named, not copied), the Panda on a
500 kg cube of 1.2 m with its URDF elsewhere (copied beside the description)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest
from typer.testing import CliRunner, Result

from hikoboshi import robot_cli
from hikoboshi.cli import app
from planner.catalogue import parameters_from_values, plan_experiment, resolve
from planner.description import load_robot, scaffold_experiments, scaffold_text
from planner.description.scaffold_experiments import NONHOLONOMIC_SCALES, nonholonomic_candidates
from planner.dynamics import DynamicsWorkspace
from planner.flight_rules import FlightRulesReport
from planner.plan import Plan
from planner.robot import RobotDescription
from planner.state import State
from tests.support.scaffold import CUBES, HANDS, INSIDE, run, scaffold_once
from tests.support.vendor import vendor_urdf

if TYPE_CHECKING:
    from tests.support.made_once import MadeOnce

#: The vendor's links lumped with the cube, their URDF <mass> (kg): the UR5's base_link (its
#: root, world, has none), the Panda's panda_link0.
LUMPED_KG = {"ur5": 4.0, "panda": 0.629769}


@pytest.fixture(scope="module", params=list(HANDS))
def scaffolded(
    request: pytest.FixtureRequest, made_once: MadeOnce
) -> tuple[str, Path, dict[str, Any], RobotDescription]:
    robot = request.param
    done = scaffold_once(made_once, robot)
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    return robot, done.out, report, load_robot(done.out)


_AS_WRITTEN: dict[tuple[Path, str], tuple[Plan, FlightRulesReport]] = {}


def as_written(description: RobotDescription, experiment: str) -> tuple[Plan, FlightRulesReport]:
    """``experiment`` with the description's defaults, planned and checked here (once per
    module and description: several tests read the same plan)."""
    key = (description.path, experiment)
    if key not in _AS_WRITTEN:
        params = parameters_from_values(
            resolve(experiment)[0], {}, defaults=description.experiment_defaults(experiment)
        )
        plan = plan_experiment(experiment, params, robot=description)
        _AS_WRITTEN[key] = (plan, description.check_plan(plan))
    return _AS_WRITTEN[key]


@pytest.mark.slow
def test_the_description_loads_with_the_vendor_file_unchanged(
    scaffolded: tuple[str, Path, dict[str, Any], RobotDescription],
) -> None:
    robot, out, report, description = scaffolded
    if robot == "ur5":  # a URDF inside the description's folder is named, not copied
        named = out.parent / INSIDE
        assert report["copied_urdf"] is None and report["urdf"] == INSIDE.as_posix()
        assert sorted(p.name for p in out.parent.iterdir()) == ["ur5.toml", "urdf"]
    else:  # one elsewhere is copied beside it
        named = out.parent / vendor_urdf(robot).name
        assert report["copied_urdf"] == str(named) and report["urdf"] == named.name
    assert description.urdf_path == named
    assert named.read_bytes() == vendor_urdf(robot).read_bytes()
    assert description.n_joints == {"ur5": 6, "panda": 7}[robot]
    assert description.hand_link == HANDS[robot]
    assert description.reference_pose == "A"
    # the cube asked for (--base-mass, --base-size; the UR5's the defaults) with the vendor's
    # links at the root lumped into it, and its drawn box
    mass, size = CUBES[robot]
    assert description.model.base_mass_kg == pytest.approx(mass + LUMPED_KG[robot], abs=1e-9)
    assert description.base_box_size_m == (size, size, size)
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
    plan, _ = as_written(description, "ptp")
    carried = np.linalg.norm(plan.prediction.reaction_momentum_orbit_nms, axis=1)
    assert 0.0 < float(np.max(carried)) <= bound
    assert float(np.max(np.abs(plan.prediction.wheel_momentum_nms))) <= 0.8 * capacity


@pytest.mark.slow
@pytest.mark.parametrize("experiment", ["ptp", "reactionless", "gjm", "coordination",
                                        "nonholonomic"])  # fmt: skip
def test_every_experiment_plans_as_written(
    scaffolded: tuple[str, Path, dict[str, Any], RobotDescription],
    experiment: str,
) -> None:
    _, _, scaffold_report, description = scaffolded
    plan, report = as_written(description, experiment)
    failing = [row for row in report.rows if row.verdict != "pass"]
    assert report.passed, failing
    # the scaffold's own check of the file as written says the same
    said = scaffold_report["experiments"][experiment]
    assert said["passed"] and said["failing"] == []
    assert said["clearance_m"] == pytest.approx(report.row("clearance").value, rel=1e-9)
    rates = (
        np.abs(np.diff(plan.command_joints_rad, axis=0)) / np.diff(plan.command_times_s)[:, None]
    )
    assert np.all(rates <= description.model.joint_rate_limit_radps * (1 + 1e-6))


@pytest.mark.slow
def test_the_nonholonomic_start_is_the_first_candidate_that_passes(
    scaffolded: tuple[str, Path, dict[str, Any], RobotDescription],
) -> None:
    """The start written is pose A plus the offsets the report names, and its plan's
    clearance is the report's; every candidate tried before it fell short of the flight
    rules' clearance, the screen's or the full check's (recomputed here for those checked
    in full)."""
    robot, _, report, description = scaffolded
    nh, tried = report["nonholonomic"], report["nonholonomic_tried"]
    assert nh["passed"] and report["failing_experiments"] == []
    n = description.model.n_joints
    labels = [label for label, _ in nonholonomic_candidates(n)]
    offsets = dict(nonholonomic_candidates(n))
    order = [labels.index(e["candidate"]) for e in tried]
    assert order == sorted(set(order))  # in the candidates' order, each once
    assert tried[-1]["candidate"] == nh["candidate"]
    defaults = description.experiment_defaults("nonholonomic")
    qa = description.pose_joints_rad("A")
    assert np.degrees(qa) == pytest.approx(defaults["phi_end_deg"], abs=1e-3)
    # A plus the offsets, or less where a joint would come near its limit
    moved = np.array(defaults["phi_init_deg"]) - np.degrees(qa)
    offset = offsets[nh["candidate"]]
    assert np.all(np.abs(moved) <= np.abs(offset) + 1e-3) and np.all(moved * offset >= -1e-6)
    assert not np.allclose(moved, 0.0)
    assert moved == pytest.approx(nh["phi_init_deg"] - np.degrees(qa), abs=1e-3)
    min_clearance = description.flight_rules.min_clearance_m
    for entry in tried[:-1]:  # those before it fall short
        if entry.get("clearance_m") is None:  # screened out
            screened = entry["screened_clearance_m"]
            assert screened is None or screened < min_clearance, entry
            continue
        assert not entry["passed"], entry
        params = parameters_from_values(
            resolve("nonholonomic")[0], {"phi_init_deg": entry["phi_init_deg"]},
            defaults=defaults,
        )  # fmt: skip
        again = description.check_plan(plan_experiment("nonholonomic", params, robot=description))
        assert not again.passed
        assert again.row("clearance").value == pytest.approx(entry["clearance_m"], rel=1e-9)
    # the chosen plan, recomputed: passes with the clearance the report gives
    plan, check = as_written(description, "nonholonomic")
    assert check.passed
    assert check.row("clearance").value == pytest.approx(nh["clearance_m"], rel=1e-9)
    assert nh["clearance_m"] >= min_clearance
    assert plan.metrics["predicted_end_attitude_error_deg"] == pytest.approx(
        nh["end_attitude_error_deg"], rel=1e-6
    )
    if robot == "ur5":  # ETS-VII's offsets as they are take wrist_2_link into the base box
        assert tried[0]["candidate"] == "ETS-VII's offsets x1"
        assert nh["candidate"] != tried[0]["candidate"]


def test_nonholonomic_candidates_start_with_ets_vii_s_offsets() -> None:
    candidates = nonholonomic_candidates(6)
    first, reversed_ = candidates[0][1], candidates[1][1]
    assert first.tolist() == [9.6, -2.0, 2.0, 0.0, -13.6, 0.0]
    assert reversed_.tolist() == [-9.6, 2.0, -2.0, 0.0, 13.6, 0.0]
    # every sign pattern of the four non-zero offsets at each scale, no repeats
    assert len(candidates) == 16 * len(NONHOLONOMIC_SCALES)
    assert len({tuple(o) for _, o in candidates}) == len(candidates)
    assert candidates[16][0] == "ETS-VII's offsets x0.5"
    assert candidates[16][1] == pytest.approx(0.5 * first)
    assert nonholonomic_candidates(7)[0][1].tolist() == [9.6, -2.0, 2.0, 0.0, -13.6, 0.0, 0.0]


@pytest.mark.slow
def test_a_nonholonomic_start_that_fails_is_said_not_written_silently(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """With only ETS-VII's offsets at 1.5 times their size, as they are and reversed, to try,
    no start keeps the UR5's non-holonomic path clear of the base: the file is written for
    the user to edit, but the exit status is 1, stderr names the experiment and the report
    gives the nearer candidate and the verdicts (in process, to narrow the candidates, and
    the experiments checked as written to the non-holonomic one: the others, planned on the
    same poses, pass in the shared scaffold's run, test_every_experiment_plans_as_written)."""
    candidates = scaffold_experiments.nonholonomic_candidates
    for module in (scaffold_experiments, scaffold_text):  # the candidates, the file's comment
        monkeypatch.setattr(module, "NONHOLONOMIC_SCALES", (1.5,))
    monkeypatch.setattr(
        scaffold_experiments, "nonholonomic_candidates", lambda n: candidates(n)[:2]
    )
    monkeypatch.setattr(scaffold_experiments, "EXPERIMENTS", ("nonholonomic",))
    out = tmp_path / "ur5.toml"
    result = CliRunner().invoke(
        app, ["robot", "init", "--urdf", str(vendor_urdf("ur5")), "--hand", "tool0",
              "--out", str(out), "--json"],
    )  # fmt: skip
    assert result.exit_code == 1, (result.stdout, result.stderr)
    report = json.loads(result.stdout)
    assert list(report["experiments"]) == report["failing_experiments"] == ["nonholonomic"]
    nh = report["nonholonomic"]
    assert not nh["passed"] and nh["candidates_tried"] == 2 and nh["fully_checked"] == 0
    tried = [e["candidate"] for e in report["nonholonomic_tried"]]
    assert tried == ["ETS-VII's offsets x1.5", "reversed x1.5"]
    screened = [e["screened_clearance_m"] for e in report["nonholonomic_tried"]]
    assert nh["screened_clearance_m"] == max(v for v in screened if v is not None) < 0.05
    row = report["experiments"]["nonholonomic"]
    assert not row["passed"] and row["clearance_m"] < 0.05
    assert any(f.startswith("clearance ") for f in row["failing"])
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("warning: "), result.stderr
    assert "[experiments.nonholonomic]" in lines[0] and nh["candidate"] in lines[0]
    assert f"clearance {row['clearance_m']:.4g} m" in lines[0]
    text = out.read_text()
    assert "NO candidate passes the flight rules" in text
    assert "nonholonomic FAILS" in text.replace("\n# ", " ")
    description = load_robot(out)
    params = parameters_from_values(
        resolve("nonholonomic")[0], {}, defaults=description.experiment_defaults("nonholonomic")
    )
    check = description.check_plan(plan_experiment("nonholonomic", params, robot=description))
    assert check.row("clearance").value == pytest.approx(row["clearance_m"], rel=1e-9)


# --- refusals: exit 2, one line naming what is wrong (in process: nothing is planned) ---------


def in_process(*args: str) -> Result:
    return CliRunner().invoke(app, list(args))


def _refused(result: Result, *needles: str) -> None:
    assert result.exit_code == 2, (result.stdout, result.stderr)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]


def test_refusals_name_what_is_wrong(tmp_path: Path) -> None:
    urdf = vendor_urdf("ur5")
    out = tmp_path / "ur5.toml"
    args = ["robot", "init", "--urdf", str(urdf), "--out", str(out)]
    _refused(in_process(*args, "--hand", "no_such_link"), "no_such_link", "ur5_robot.urdf")
    _refused(in_process(*args, "--hand", "tool0", "--base-mass", "-3"), "--base-mass", "-3")
    _refused(in_process(*args, "--hand", "tool0", "--base-size", "0"), "--base-size")
    _refused(
        in_process("robot", "init", "--urdf", str(tmp_path / "none.urdf"), "--hand", "tool0",
                   "--out", str(out)),
        "none.urdf",
    )  # fmt: skip
    out.write_text("# mine\n")
    _refused(in_process(*args, "--hand", "tool0"), str(out), "exists")
    assert out.read_text() == "# mine\n"  # left alone
    other = tmp_path / "b" / "ur5.toml"
    other.parent.mkdir()
    (other.parent / urdf.name).write_text("<robot name='else'/>")
    _refused(
        in_process("robot", "init", "--urdf", str(urdf), "--hand", "tool0", "--out", str(other)),
        "in the way",
    )
    assert not other.exists()


@pytest.mark.slow
def test_the_text_report_names_the_file_and_the_next_step(
    scaffolded: tuple[str, Path, dict[str, Any], RobotDescription],
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Without ``--json`` the command prints its report as lines (``robot_cli._print_init``,
    the branch ``--json`` replaces): the file written, where the URDF went, each pose and
    the next commands."""
    robot, out, report, _ = scaffolded
    copied = None if report["copied_urdf"] is None else Path(report["copied_urdf"])
    robot_cli._print_init(out, copied, report)
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith(f"wrote {out} ({report['n_joints']} joints")
    assert ("copied the URDF unchanged" in lines[0]) == (robot != "ur5")
    assert [line.split(":")[0] for line in lines[1:4]] == ["  pose A", "  pose B", "  pose C"]
    assert lines[-1] == f"next: hikoboshi robot check {out}; hikoboshi plan --robot {out} pass"
