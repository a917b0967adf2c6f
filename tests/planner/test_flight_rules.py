"""Flight rules: coal's distances against answers worked out by hand, the kinematics against
MuJoCo's, the fine grid's exact per-sample minimum against brute force, and the rules on
the issue's plans (into the base: refused; 0.15 m from it: accepted; Orihime folding its
wrist onto itself: refused). Every shipped pass keeping every rule: test_schedule.py (ETS-VII)
and test_robot_planners.py (Orihime), which plan the passes already."""

from __future__ import annotations

import math
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from planner.catalogue import parameters_from_values, plan_experiment, resolve
from planner.clearance_sampling import joint_paths, sample_step_s, sampled_clearance
from planner.collision import (
    CollisionBody,
    CollisionModel,
    CollisionShape,
    ShapeSet,
    body_poses,
    reach_bounds,
)
from planner.description import (
    EXAMPLES_DIR,
    InvalidRobotDescription,
    RobotDescription,
    default_robot,
    load_robot,
)
from planner.dynamics import DynamicsWorkspace
from planner.errors import InvalidInput
from planner.frames import matrix_from_rpy
from planner.ik import solve_ik
from planner.plan import Plan
from planner.ptp import COMMAND_PERIOD_S
from planner.servo_response import servo_response
from planner.state import State

ORIHIME = EXAMPLES_DIR / "orihime" / "orihime.toml"
I3 = np.eye(3)
O3 = np.zeros(3)


def _shape(kind: str, dims: tuple[float, ...], pos: tuple[float, ...], rot: np.ndarray = I3):
    return CollisionShape(kind, dims, np.asarray(rot, float), np.asarray(pos, float))


def _distance(a: CollisionShape, b: CollisionShape) -> tuple[float, tuple, tuple]:
    model = CollisionModel((CollisionBody("a", 0, (a,)), CollisionBody("b", 1, (b,))))
    found = ShapeSet(model).distance(0, 1, I3, O3, I3, O3)
    return found.distance_m, found.point_a_robot_m, found.point_b_robot_m


# --- coal's numbers against the hand's ------------------------------------------------------


def test_box_capsule_distance_is_exact() -> None:
    """ETS-VII's base box (half sizes 1.2, 1.0, 1.0) and a 0.06 m capsule along x from
    (1.5, 1.3, 1.4) to (2.37, 1.3, 1.4): the nearest points are the box's corner (1.2, 1, 1)
    and the segment's end, sqrt(0.3^2 + 0.3^2 + 0.4^2) = sqrt(0.34) apart, less the radius."""
    box = _shape("box", (2.4, 2.0, 2.0), (0.0, 0.0, 0.0))
    along_x = matrix_from_rpy(np.array([0.0, math.pi / 2, 0.0]))  # the capsule's z onto x
    capsule = _shape("capsule", (0.06, 0.87), (1.5 + 0.435, 1.3, 1.4), along_x)
    d, on_box, _ = _distance(box, capsule)
    assert d == pytest.approx(math.sqrt(0.34) - 0.06, abs=1e-9)
    assert on_box == pytest.approx((1.2, 1.0, 1.0), abs=1e-9)
    # Straight above the top face: the gap is the height less the radius.
    upright = _shape("capsule", (0.06, 0.87), (0.3, -0.2, 1.0 + 0.25 + 0.435))
    assert _distance(box, upright)[0] == pytest.approx(0.25 - 0.06, abs=1e-9)


def test_capsule_capsule_distance_is_exact() -> None:
    """Two capsules on crossing segments: x axis from -1 to 1 (radius 0.1), and along y at
    x = 0.3, z = 0.5 (radius 0.05): the segments are 0.5 apart, the capsules 0.35. Moved to
    x = 1.5, z = 0.2, the nearest point is the first segment's end (1, 0, 0):
    sqrt(0.5^2 + 0.2^2) - 0.15."""
    along_x = matrix_from_rpy(np.array([0.0, math.pi / 2, 0.0]))
    along_y = matrix_from_rpy(np.array([-math.pi / 2, 0.0, 0.0]))
    first = _shape("capsule", (0.1, 2.0), (0.0, 0.0, 0.0), along_x)
    crossing = _shape("capsule", (0.05, 2.0), (0.3, 0.0, 0.5), along_y)
    assert _distance(first, crossing)[0] == pytest.approx(0.35, abs=1e-9)
    beyond = _shape("capsule", (0.05, 2.0), (1.5, 0.0, 0.2), along_y)
    d, on_first, _ = _distance(first, beyond)
    assert d == pytest.approx(math.hypot(0.5, 0.2) - 0.15, abs=1e-9)
    assert on_first[0] > 1.0  # on the first capsule's rounded end, toward the other


def test_penetration_is_a_negative_distance() -> None:
    """A 0.08 m sphere whose centre is 0.3 m inside a box's face: -0.38 m."""
    box = _shape("box", (2.4, 2.0, 2.0), (0.0, 0.0, 0.0))
    sphere = _shape("sphere", (0.08,), (0.0, -0.7, 0.2))
    assert _distance(box, sphere)[0] == pytest.approx(-0.38, abs=1e-6)


# --- the kinematics and the grid ------------------------------------------------------------


@pytest.fixture(scope="module")
def ets7() -> RobotDescription:
    return default_robot()


@pytest.fixture(scope="module")
def orihime() -> RobotDescription:
    return load_robot(ORIHIME)


@pytest.mark.parametrize("robot_name", ["ets7", "orihime"])
def test_body_poses_put_the_hand_where_mujoco_does(
    robot_name: str, ets7: RobotDescription, orihime: RobotDescription
) -> None:
    robot = ets7 if robot_name == "ets7" else orihime
    rng = np.random.default_rng(3)
    lo, hi = robot.model.joint_limit_rad[:, 0], robot.model.joint_limit_rad[:, 1]
    joints = rng.uniform(lo, hi, size=(5, robot.n_joints))
    R, t = body_poses(robot.model, joints)
    ws = DynamicsWorkspace(robot.model)
    for s, q in enumerate(joints):
        hand = ws.hand_pose(State(q))
        ours = R[s, -1] @ robot.model.hand_pos_robot_m + t[s, -1]
        np.testing.assert_allclose(ours, hand.pos_robot_m, atol=1e-9)
        np.testing.assert_allclose(R[s, -1], hand.rot_robot_from_hand, atol=1e-9)


def test_the_step_keeps_every_point_within_half_the_clearance(ets7: RobotDescription) -> None:
    """At the rate limits no point of the arm moves more than min_clearance / 2 per step."""
    assert ets7.collision is not None
    limit = ets7.flight_rules.min_clearance_m
    step = sample_step_s(ets7.model, ets7.collision, limit)
    reach = reach_bounds(ets7.model, ets7.collision).max(axis=1)
    speed = float(np.sum(ets7.model.joint_rate_limit_radps * reach))
    assert step * speed <= limit / 2
    assert COMMAND_PERIOD_S / step == round(COMMAND_PERIOD_S / step)
    # and no finer than needed: one sample fewer per period would break the bound
    per_period = round(COMMAND_PERIOD_S / step)
    assert per_period == 1 or COMMAND_PERIOD_S / (per_period - 1) * speed > limit / 2


def _ptp(robot: RobotDescription | None, goal_deg: tuple[float, ...]) -> Plan:
    params_type, _ = resolve("ptp")
    defaults = {} if robot is None else dict(robot.experiment_defaults("ptp"))
    params = parameters_from_values(params_type, {**defaults, "goal_joints_deg": goal_deg})
    return plan_experiment("ptp", params, robot=robot)


def test_each_samples_minimum_is_exact_against_brute_force(ets7: RobotDescription) -> None:
    """The bounds only skip pairs that cannot be the nearest: every sample's minimum equals
    the minimum over every pair asked of coal directly (every 5th sample of a plan that drives
    the hand through the base)."""
    assert ets7.collision is not None
    plan = _ptp(None, (90.0, 120.0, 60.0, 0.0, 0.0, 0.0))
    step = sample_step_s(ets7.model, ets7.collision, ets7.flight_rules.min_clearance_m)
    count = (plan.command_times_s.size - 1) * round(COMMAND_PERIOD_S / step) + 1
    times = np.arange(count) * step
    joints, rates = servo_response(
        ets7.servo_model(), plan.command_times_s, plan.command_joints_rad,
        plan.initial_joints_rad, times,
    )  # fmt: skip
    R, t = body_poses(ets7.model, joints)
    pairs = list(ets7.collision.pairs)
    found = sampled_clearance(
        ets7.collision, pairs, R, t, joint_paths(ets7.servo_model(), plan, step, joints, rates),
        ets7.model,
    )  # fmt: skip
    shapes = ShapeSet(ets7.collision)
    frame = [b.joint for b in ets7.collision.bodies]
    for s in range(0, count, 5):
        brute = min(
            shapes.distance(
                a, b, R[s, frame[a]], t[s, frame[a]], R[s, frame[b]], t[s, frame[b]]
            ).distance_m
            for a, b in pairs
        )
        assert found.per_sample_m[s] == pytest.approx(brute, abs=1e-9), s
    assert found.queries < len(pairs) * count / 4  # and it asked far fewer questions


def test_servo_response_lags_a_ramp_by_its_lag(ets7: RobotDescription) -> None:
    """A PD servo with kd = lag kp follows a steady ramp ``lag`` seconds behind."""
    servo = ets7.servo_model()
    n = ets7.n_joints
    rate = 0.02
    command_times = np.arange(0.0, 60.0 + 1e-9, COMMAND_PERIOD_S)
    commands = np.outer(command_times * rate, np.ones(n))
    joints, rates = servo_response(servo, command_times, commands, np.zeros(n), command_times)
    lag = np.array([0.3, 0.1, 0.35, 0.55, 0.3, 0.3])  # ets7.toml [servo] lag_s
    np.testing.assert_allclose(commands[-1] - joints[-1], rate * lag, rtol=1e-3)
    np.testing.assert_allclose(rates[-1], rate, rtol=1e-6)


# --- the rules on plans ---------------------------------------------------------------------


def test_the_issues_plan_into_the_base_is_refused(ets7: RobotDescription) -> None:
    plan = _ptp(None, (90.0, 120.0, 60.0, 0.0, 0.0, 0.0))
    report = ets7.check_plan(plan)
    assert not report.passed
    row = report.row("clearance")
    assert not row.passed and row.value < 0.0
    assert set(row.bodies or ()) == {"base_link", "hand"}
    assert [r.rule for r in report.failing] == ["clearance"]
    # the goal pose itself: the hand centre 0.30 m inside the base's -y face and 0.36 m
    # below its +z face (base frame, hand at about (-0.52, -0.70, 0.64))
    hand = DynamicsWorkspace(ets7.model).hand_pose(State(plan.command_joints_rad[-1]))
    np.testing.assert_allclose(hand.pos_base_m, [-0.52, -0.70, 0.64], atol=0.01)


def test_a_plan_015_m_from_the_base_passes_with_its_clearance_exact(
    ets7: RobotDescription,
) -> None:
    """The hand lowered, pointing down, to 0.23 m above the base's +z face (robot z = 0)
    beside the docked target: the nearest pair is the hand's 0.08 m sphere and the base,
    0.23 - 0.08 = 0.15 m apart, and the report says so to within 1 mm."""
    ws = DynamicsWorkspace(ets7.model)
    goal = solve_ik(ws, np.array([0.2, 0.9, 0.23]), matrix_from_rpy(np.radians([0, 90, -37])))
    plan = _ptp(None, tuple(np.degrees(goal[0].joints_rad)))
    report = ets7.check_plan(plan)
    assert report.passed, [r.describe() for r in report.failing]
    row = report.row("clearance")
    assert set(row.bodies or ()) == {"base_link", "hand"}
    assert row.value == pytest.approx(0.15, abs=1e-3)
    # the nearest points: on the base's top face and the bottom of the hand's sphere
    assert row.bodies is not None and row.points_robot_m is not None
    points = dict(zip(row.bodies, row.points_robot_m, strict=True))
    on_base, on_hand = points["base_link"], points["hand"]
    assert on_base[2] == pytest.approx(0.0, abs=1e-6)
    assert on_hand[2] == pytest.approx(row.value, abs=1e-6)
    assert min(report.clearance.min_m) == pytest.approx(
        min(row.value, report.row("self_clearance").value), abs=1e-12
    )


def test_orihime_folding_its_wrist_onto_itself_is_refused(orihime: RobotDescription) -> None:
    plan = _ptp(orihime, (0.0, 0.0, 0.0, 0.0, 0.0, 120.0, 0.0))
    report = orihime.check_plan(plan)
    row = report.row("self_clearance")
    assert not row.passed and row.value < 0.0
    assert set(row.bodies or ()) == {"link5", "hand"}
    assert report.row("clearance").passed


def test_a_plan_for_another_robot_is_refused(
    ets7: RobotDescription, orihime: RobotDescription
) -> None:
    plan = _ptp(None, (10.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    with pytest.raises(InvalidInput, match="not 'orihime'"):
        orihime.check_plan(plan)


def _copy_orihime(tmp_path: Path) -> Path:
    folder = tmp_path / "orihime"
    shutil.copytree(ORIHIME.parent, folder)
    return folder


def test_a_description_without_collision_shapes_cannot_be_shown_safe(tmp_path: Path) -> None:
    folder = _copy_orihime(tmp_path)
    urdf = folder / "orihime.urdf"
    urdf.write_text(re.sub(r"<collision.*?</collision>", "", urdf.read_text(), flags=re.S))
    toml = folder / "orihime.toml"
    text = re.sub(
        r"\[\[flight_rules\.allowed_contact\]\].*?(?=\n\[|\Z)", "", toml.read_text(), flags=re.S
    )
    toml.write_text(text)
    robot = load_robot(toml)
    assert robot.collision is None
    plan = _ptp(robot, (10.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    with pytest.raises(InvalidInput, match="no <collision> shapes"):
        robot.check_plan(plan)


def test_an_allowed_contact_must_name_collision_bodies(tmp_path: Path) -> None:
    folder = _copy_orihime(tmp_path)
    toml = folder / "orihime.toml"
    toml.write_text(
        toml.read_text()
        + '\n[[flight_rules.allowed_contact]]\nbodies = ["link2", "wing"]\nreason = "typo"\n'
    )
    with pytest.raises(InvalidRobotDescription, match="no collision body 'wing'"):
        load_robot(toml)


def test_a_mesh_is_taken_as_its_convex_hull(tmp_path: Path) -> None:
    """Orihime's star tracker as a mesh file (a unit cube scaled to its box, plus a point
    inside the hull) instead of a box: the same body, the same distances."""
    folder = _copy_orihime(tmp_path)
    corners = [(x, y, z) for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)]
    faces = [  # the cube's 12 triangles, 1-based OBJ indices
        (1, 2, 4), (1, 4, 3), (5, 7, 8), (5, 8, 6), (1, 5, 6), (1, 6, 2),
        (3, 4, 8), (3, 8, 7), (1, 3, 7), (1, 7, 5), (2, 6, 8), (2, 8, 4),
    ]  # fmt: skip
    lines = [f"v {x} {y} {z}" for x, y, z in corners] + ["v 0.1 0.1 0.1"]
    lines += [f"f {a} {b} {c}" for a, b, c in faces]
    (folder / "tracker.obj").write_text("\n".join(lines) + "\n")
    urdf = folder / "orihime.urdf"
    box = '<geometry><box size="0.15 0.15 0.2"/></geometry>\n    </collision>'
    text = urdf.read_text()
    assert text.count(box) == 1
    urdf.write_text(
        text.replace(
            box,
            '<geometry><mesh filename="tracker.obj" scale="0.15 0.15 0.2"/></geometry>\n'
            "    </collision>",
        )
    )
    meshed, boxed = load_robot(folder / "orihime.toml"), load_robot(ORIHIME)
    assert meshed.collision is not None and boxed.collision is not None
    [shape] = meshed.collision.body("star_tracker").shapes
    assert shape.kind == "convex"
    rng = np.random.default_rng(5)
    joints = rng.uniform(-0.5, 0.5, size=(6, 7))
    R, t = body_poses(boxed.model, joints)
    names = [b.name for b in boxed.collision.bodies]
    a, b = names.index("star_tracker"), names.index("hand")
    for s in range(len(joints)):
        ja, jb = 0, boxed.collision.bodies[b].joint
        want = ShapeSet(boxed.collision).distance(a, b, R[s, ja], t[s, ja], R[s, jb], t[s, jb])
        got = ShapeSet(meshed.collision).distance(a, b, R[s, ja], t[s, ja], R[s, jb], t[s, jb])
        assert got.distance_m == pytest.approx(want.distance_m, abs=1e-6)


def test_a_mesh_outside_a_ros_workspace_is_refused_with_the_reason(tmp_path: Path) -> None:
    folder = _copy_orihime(tmp_path)
    urdf = folder / "orihime.urdf"
    urdf.write_text(
        urdf.read_text().replace(
            '<geometry><box size="0.15 0.15 0.2"/></geometry>\n    </collision>',
            '<geometry><mesh filename="package://tracker/tracker.stl"/></geometry>\n'
            "    </collision>",
        )
    )
    with pytest.raises(InvalidRobotDescription, match="package:// needs a ROS workspace"):
        load_robot(folder / "orihime.toml")
