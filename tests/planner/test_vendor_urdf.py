"""Vendor URDFs loaded unchanged (docs/robots.md, "A vendor's URDF"): the Franka Panda and the
UR5 as the PyPI package example-robot-data ships them (a dev dependency; nothing is
downloaded at run time), each copied byte for byte beside a description in
tests/planner/vendor/ that mounts it on a 300 kg cube.

The lumping is checked against MuJoCo's own URDF compiler on the same file (every link a
body, ``fusestatic`` off): the masses, centres of mass and inertias of the URDF links that
make each of our bodies, summed in the test by the parallel-axis theorem, agree with our
model's body to round-off; the hand frame (any orientation) agrees at a pose away from zero.
"""

from __future__ import annotations

import itertools
import re
from pathlib import Path

import mujoco
import numpy as np
import pytest

from planner.description import InvalidRobotDescription, load_robot
from planner.dynamics import DynamicsWorkspace
from planner.robot import RobotDescription
from planner.state import State
from tests.support.vendor import URDFS, copy_robot, vendor_urdf

CUBE_KG, CUBE_M, MOUNT_Z_M = 300.0, 1.0, 0.5


@pytest.fixture(scope="module", params=list(URDFS))
def loaded(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> tuple[str, Path, RobotDescription]:
    robot = request.param
    toml = copy_robot(tmp_path_factory.mktemp(robot), robot)
    return robot, toml, load_robot(toml)


def mujoco_of(urdf: Path) -> mujoco.MjModel:
    """MuJoCo's compiler on the vendor's URDF: every link a body (fusestatic off), the
    geometry dropped (its package:// meshes are not on disk here), inertias as written."""
    text = urdf.read_text()
    text = re.sub(r"<visual>.*?</visual>", "", text, flags=re.S)
    text = re.sub(r"<collision>.*?</collision>", "", text, flags=re.S)
    compiler = (
        '<mujoco><compiler fusestatic="false" discardvisual="true" '
        'balanceinertia="false"/></mujoco></robot>'
    )
    return mujoco.MjModel.from_xml_string(text.replace("</robot>", compiler))


def composite(
    parts: list[tuple[float, np.ndarray, np.ndarray]],
) -> tuple[float, np.ndarray, np.ndarray]:
    """Mass, CoM and inertia about it of bodies given in one frame (the parallel-axis sum)."""
    mass = sum(m for m, _, _ in parts)
    com = sum(m * c for m, c, _ in parts) / mass
    inertia = sum(
        tensor + m * ((c - com) @ (c - com) * np.eye(3) - np.outer(c - com, c - com))
        for m, c, tensor in parts
    )
    return mass, com, inertia


def test_the_vendor_file_is_loaded_as_shipped(
    loaded: tuple[str, Path, RobotDescription],
) -> None:
    robot, toml, description = loaded
    copied = toml.parent / Path(URDFS[robot]).name
    assert copied.read_bytes() == vendor_urdf(robot).read_bytes()
    assert description.n_joints == {"panda": 7, "ur5": 6}[robot]


def test_panda_lumps_its_hand_and_fingers_and_locks_the_fingers(tmp_path: Path) -> None:
    description = load_robot(copy_robot(tmp_path, "panda"))
    assert description.lumped == (
        ("panda_link0", "[base]"),
        ("panda_hand", "panda_link7"),
        ("panda_leftfinger", "panda_link7"),
        ("panda_rightfinger", "panda_link7"),
    )
    # finger 1 as the description sets it, finger 2 by its <mimic>
    assert description.locked == (
        ("panda_finger_joint1", "prismatic", 0.02),
        ("panda_finger_joint2", "prismatic", 0.02),
    )
    assert description.joint_names == tuple(f"panda_joint{k}" for k in range(1, 8))
    assert description.hand_link == "panda_hand_tcp"


def test_lumped_bodies_agree_with_mujoco_s_compiler(
    loaded: tuple[str, Path, RobotDescription],
) -> None:
    """Each of our arm bodies against the URDF links MuJoCo compiles for it, summed here,
    at the all-zero pose with the fingers where the description locks them; the base against
    the cube plus the links fixed to the root."""
    robot, _, description = loaded
    mj = mujoco_of(vendor_urdf(robot))
    data = mujoco.MjData(mj)
    for name, _, position in description.locked:
        data.qpos[mj.jnt_qposadr[mj.joint(name).id]] = position
    mujoco.mj_kinematics(mj, data)
    model = description.model
    joint_bodies = [mj.joint(name).bodyid[0] for name in description.joint_names]
    owner = {}
    for b in range(1, mj.nbody):
        up = b
        while up != 0 and up not in joint_bodies:
            up = mj.body_parentid[up]
        owner[b] = 0 if up == 0 else joint_bodies.index(up) + 1
    # root frame = MuJoCo's world; our robot frame: base axes (the cube's, parallel to the
    # root's here), origin on joint 1
    pos_j1 = data.xpos[joint_bodies[0]].copy()

    def parts(k: int) -> list[tuple[float, np.ndarray, np.ndarray]]:
        out = []
        for b, o in owner.items():
            if o != k or mj.body_mass[b] == 0.0:
                continue
            rot = data.ximat[b].reshape(3, 3)
            out.append(
                (
                    float(mj.body_mass[b]),
                    data.xipos[b].copy(),
                    rot @ np.diag(mj.body_inertia[b]) @ rot.T,
                )
            )
        return out

    for k, link in enumerate(model.links, start=1):
        mass, com, inertia = composite(parts(k))
        assert link.mass_kg == pytest.approx(mass, rel=1e-14)
        np.testing.assert_allclose(link.com_robot_m, com - pos_j1, rtol=0, atol=1e-14)
        np.testing.assert_allclose(link.inertia_com_robot_kgm2, inertia, rtol=0, atol=1e-14)
        np.testing.assert_allclose(
            link.joint_pos_robot_m, data.xpos[joint_bodies[k - 1]] - pos_j1, atol=1e-14
        )
        axis = (
            data.xmat[joint_bodies[k - 1]].reshape(3, 3)
            @ mj.jnt_axis[mj.joint(description.joint_names[k - 1]).id]
        )
        np.testing.assert_allclose(link.joint_axis_robot, axis, atol=1e-14)

    cube_inertia = np.eye(3) * CUBE_KG * (2 * CUBE_M**2) / 12.0
    mount = np.array([0.0, 0.0, MOUNT_Z_M])  # the root in the cube's frame
    root_parts = [(m, c + mount, tensor) for m, c, tensor in parts(0)]
    mass, com, inertia = composite([(CUBE_KG, np.zeros(3), cube_inertia), *root_parts])
    assert model.base_mass_kg == pytest.approx(mass, rel=1e-15)
    np.testing.assert_allclose(model.pos_base_from_robot_m, pos_j1 + mount - com, atol=1e-14)
    np.testing.assert_allclose(model.base_inertia_kgm2, inertia, rtol=1e-14, atol=1e-13)
    total = CUBE_KG + float(np.sum(mj.body_mass))
    assert model.total_mass_kg == pytest.approx(total, rel=1e-14)


def test_whole_system_at_the_reference_pose_agrees_with_mujoco(
    loaded: tuple[str, Path, RobotDescription],
) -> None:
    """Total mass, CoM and inertia about it of the whole robot at its reference pose: our
    dynamics (lumped bodies on MuJoCo's model of ours) against every URDF link MuJoCo
    compiles from the vendor's file, fingers locked, plus the cube, summed here."""
    _, _, description = loaded
    model = description.model
    mj = mujoco_of(vendor_urdf(description.name))
    data = mujoco.MjData(mj)
    for name, _, position in description.locked:
        data.qpos[mj.jnt_qposadr[mj.joint(name).id]] = position
    for name, q in zip(description.joint_names, model.reference_joints, strict=True):
        data.qpos[mj.jnt_qposadr[mj.joint(name).id]] = q
    mujoco.mj_kinematics(mj, data)
    mount = np.array([0.0, 0.0, MOUNT_Z_M])
    parts = [(CUBE_KG, np.zeros(3), np.eye(3) * CUBE_KG * (2 * CUBE_M**2) / 12.0)]
    for b in range(1, mj.nbody):
        if mj.body_mass[b] > 0.0:
            rot = data.ximat[b].reshape(3, 3)
            inertia = rot @ np.diag(mj.body_inertia[b]) @ rot.T
            parts.append((float(mj.body_mass[b]), data.xipos[b] + mount, inertia))
    mass, com, inertia = composite(parts)
    q = DynamicsWorkspace(model).evaluate(State(model.reference_joints))
    assert q.total_mass_kg == pytest.approx(mass, rel=1e-14)
    # ours: base at the orbit origin (its CoM), cube axes; theirs: from the cube's centre
    base_com = data.xpos[mj.joint(description.joint_names[0]).bodyid[0]] + mount
    base_com = base_com - model.pos_base_from_robot_m
    np.testing.assert_allclose(q.com_orbit_m, com - base_com, rtol=0, atol=1e-13)
    np.testing.assert_allclose(q.inertia_com_base_kgm2, inertia, rtol=1e-13, atol=1e-12)


def test_hand_frame_of_any_orientation_agrees_with_mujoco(
    loaded: tuple[str, Path, RobotDescription],
) -> None:
    """The hand is the named frame (Panda: panda_hand_tcp, turned 45 deg about z and pointing
    along the flange; UR5: tool0), at pose B: position and axes to round-off."""
    robot, _, description = loaded
    mj = mujoco_of(vendor_urdf(robot))
    data = mujoco.MjData(mj)
    joints = description.pose_joints_rad("B")
    for name, q in zip(description.joint_names, joints, strict=True):
        data.qpos[mj.jnt_qposadr[mj.joint(name).id]] = q
    mujoco.mj_kinematics(mj, data)
    j1 = mj.joint(description.joint_names[0]).bodyid[0]
    hand = mj.body(description.hand_link).id
    # the robot frame's axes are the root's here (the mount has no rotation)
    ours = DynamicsWorkspace(description.model).hand_pose(State(joints))
    np.testing.assert_allclose(ours.pos_robot_m, data.xpos[hand] - data.xpos[j1], atol=1e-12)
    np.testing.assert_allclose(ours.rot_robot_from_hand, data.xmat[hand].reshape(3, 3), atol=1e-12)
    assert description.model.rot_robot_from_hand is not None  # neither hand is parallel


def test_the_export_carries_the_turned_hand_to_another_parser(
    loaded: tuple[str, Path, RobotDescription], tmp_path: Path
) -> None:
    """``hikoboshi model urdf`` of the loaded arm (planner.urdf) read by yourdfpy: mass and
    the hand's pose (its turned axes included) at pose B as our dynamics give them."""
    import yourdfpy

    from planner.urdf import urdf_xml

    _, _, description = loaded
    path = tmp_path / "export.urdf"
    path.write_text(urdf_xml(description.model, name=description.name))
    urdf = yourdfpy.URDF.load(
        str(path), build_scene_graph=True, load_meshes=False, load_collision_meshes=False
    )
    joints = description.pose_joints_rad("B")
    urdf.update_cfg(joints)
    q = DynamicsWorkspace(description.model).evaluate(State(joints))
    hand = urdf.get_transform("hand", "base_link")
    np.testing.assert_allclose(hand[:3, 3], q.hand.pos_base_m, rtol=0, atol=1e-12)
    np.testing.assert_allclose(hand[:3, :3], q.hand.rot_base_from_hand, rtol=0, atol=1e-12)
    total = sum(link.inertial.mass for link in urdf.robot.links if link.inertial is not None)
    assert total == pytest.approx(q.total_mass_kg, rel=1e-12)


def test_reference_pose_inside_limits_that_exclude_zero(
    loaded: tuple[str, Path, RobotDescription],
) -> None:
    """The Panda's joint 4 ([-176, -4] deg) excludes 0: the planners' reference is the named
    pose; the servos are designed there."""
    robot, _, description = loaded
    model = description.model
    np.testing.assert_allclose(
        model.reference_joints, description.pose_joints_rad(description.reference_pose or "")
    )
    model.check_joints(model.reference_joints)
    if robot == "panda":
        hi = np.degrees(description.vendor_joint_limit_rad[3][1])  # type: ignore[index]
        assert hi < 0.0
        assert np.degrees(model.joint_limit_rad[3]).tolist() == pytest.approx([-170.0, -10.0])


def test_mission_rates_apart_from_the_vendor_s(
    loaded: tuple[str, Path, RobotDescription],
) -> None:
    _, _, description = loaded
    assert np.degrees(description.model.joint_rate_limit_radps) == pytest.approx(3.0)
    assert description.vendor_joint_rate_limit_radps is not None
    assert np.all(np.degrees(description.vendor_joint_rate_limit_radps) > 120.0)  # 2.2 rad/s+


# --- refusals, each naming its element -------------------------------------------------


def _edit_toml(toml: Path, old: str, new: str) -> None:
    text = toml.read_text()
    assert old in text
    toml.write_text(text.replace(old, new))


def _refused(toml: Path, *fragments: str) -> str:
    with pytest.raises(InvalidRobotDescription) as info:
        load_robot(toml)
    message = str(info.value)
    for fragment in fragments:
        assert fragment in message, message
    return message


@pytest.mark.parametrize(
    ("old", "new", "fragments"),
    [
        pytest.param(
            "angle_deg = { panda_joint4 = [-170.0, -10.0] }",
            "angle_deg = { panda_joint4 = [-180.0, -10.0] }",
            ["[mission_limits] angle_deg.panda_joint4", "vendor limits [-176", "inside them"],
            id="mission_angle_outside_vendor",
        ),
        pytest.param(
            "rate_degps = 3.0",
            "rate_degps = 200.0",
            ["[mission_limits] rate_degps", "exceeds joint 'panda_joint1'", "124.6"],
            id="mission_rate_above_vendor",
        ),
        pytest.param(
            "angle_deg = { panda_joint4 = [-170.0, -10.0] }",
            "angle_deg = { elbow = [-170.0, -10.0] }",
            ["[mission_limits] angle_deg.elbow", "not an arm joint"],
            id="mission_unknown_joint",
        ),
        pytest.param(
            'reference_pose = "ready"\n',
            "",
            ["joint 'panda_joint4' <limit>", "excludes 0", "reference_pose"],
            id="no_reference_pose",
        ),
        pytest.param(
            "position_m = 0.02",
            "position_m = 0.05",
            ["[locked_joints.panda_finger_joint1]", "outside the joint's limits"],
            id="finger_beyond_its_limit",
        ),
        pytest.param(
            'hand = "panda_hand_tcp"',
            'hand = "flange"',
            ["link 'flange'", "missing: the hand frame"],
            id="unknown_hand",
        ),
        pytest.param(
            "joints_deg = [20.0, -20.0, 10.0, -110.0, 10.0, 100.0, 30.0]",
            "joints_deg = [20.0, -20.0, 10.0, -3.0, 10.0, 100.0, 30.0]",
            ["[poses.B] joints_deg[3]", "outside joint 4's limits"],
            id="pose_outside_mission_limits",
        ),
    ],
)
def test_panda_refusals_name_the_element(
    tmp_path: Path, old: str, new: str, fragments: list[str]
) -> None:
    toml = copy_robot(tmp_path, "panda")
    _edit_toml(toml, old, new)
    message = _refused(toml, *fragments)
    # one line naming the element, not a traceback or a list of unrelated complaints
    assert "\n" not in message.strip() and all(f in message for f in fragments), message


def test_unstable_servos_are_refused_with_numbers_and_a_proposal(tmp_path: Path) -> None:
    """Servos made unstable on purpose (a 3 s lag at 6 rad/s: kd ten times the shipped
    descriptions'): the fastest mode at pose B is past what RK4 at 10 ms holds
    (planner.servo_check); the lag the refusal proposes loads."""
    toml = copy_robot(tmp_path, "panda")
    _edit_toml(toml, "bandwidth_radps = 4.0\nlag_s = 0.05", "bandwidth_radps = 6.0\nlag_s = 3.0")
    message = _refused(toml, "[servo]", "fastest servo mode", "at pose B", "lag_s = ")
    rate = re.search(r"fastest servo mode ([0-9.]+) 1/s", message)
    assert rate is not None and float(rate.group(1)) > 250.0
    assert "holds 250 1/s at a 10 ms step" in message
    proposed = re.search(r"lag_s = ([0-9.]+)", message)
    assert proposed is not None and float(proposed.group(1)) < 3.0
    _edit_toml(toml, "lag_s = 3.0", f"lag_s = {proposed.group(1)}")
    load_robot(toml)


def test_generated_collision_bodies_stand_in_for_the_vendor_s_meshes(
    loaded: tuple[str, Path, RobotDescription],
) -> None:
    """``[generated_collision]``: the cube, a capsule per link, the hand sphere; each
    joint's two bodies may touch, and so may the pairs the design joins at the reference
    pose (nearer than the clearance rule there); every other pair is checked."""
    _, _, description = loaded
    collision = description.collision
    assert collision is not None
    names = [b.name for b in collision.bodies]
    links = [link.name for link in description.model.links]
    assert names == [description.base_link, *links, "hand"]
    reasons = {frozenset(a.bodies): a.reason for a in collision.allowed}
    for a, b in itertools.pairwise(names):
        assert reasons[frozenset((a, b))] == "generated: the two bodies of one joint"
    assert collision.pairs  # not everything allowed
    from planner.collision import ShapeSet, body_poses

    shapes = ShapeSet(collision)
    rots, trans = body_poses(description.model, description.model.reference_joints)
    for i, j in collision.pairs:  # the checked pairs are clear at the reference pose
        a, b = collision.bodies[i].joint, collision.bodies[j].joint
        d = shapes.distance(i, j, rots[0, a], trans[0, a], rots[0, b], trans[0, b])
        assert d.distance_m >= description.flight_rules.min_clearance_m


def test_the_ur5_reaches_the_planners_and_its_coordination_plan_passes_the_rules(
    tmp_path: Path,
) -> None:
    """From the vendor's file unchanged to a plan the flight rules pass: the coordination
    experiment flown from the UR5's reference pose (issue 28, part 3 does the rest)."""
    from planner.schedule import plan_coordination_for

    description = load_robot(copy_robot(tmp_path, "ur5"))
    ws = DynamicsWorkspace(description.model)
    plan = plan_coordination_for(ws, robot=description)
    np.testing.assert_allclose(plan.initial_joints_rad, description.model.reference_joints)
    report = description.check_plan(plan, ws=ws)
    assert report.passed, [row.rule for row in report.failing]


def test_the_vehicle_holds_a_vendor_arm_at_its_reference_pose(
    loaded: tuple[str, Path, RobotDescription],
) -> None:
    """The vehicle of the description starts at the reference pose (the Panda's all-zero
    pose is outside its limits) and, with the description's servos, holds it: no sign of
    divergence in 30 s, every measured joint within 0.05 deg of its target."""
    from spacecraft.vehicle import Vehicle
    from spacecraft.vehicle_config import vehicle_config_for

    _, _, description = loaded
    config = vehicle_config_for(description)
    np.testing.assert_allclose(config.initial_joints_rad, description.model.reference_joints)
    vehicle = Vehicle(config, epoch_ns=10**18, seed=1)
    _, frames = vehicle.advance_to(10**18 + 30 * 10**9)
    assert vehicle.diverged_ns is None and not vehicle.safe
    assert len(frames) == 301
    last = frames[-1]
    error = np.abs(np.array(last.joints_rad) - np.array(last.joint_targets_rad))
    assert np.degrees(error).max() < 0.05  # the sensors' noise is 0.005 deg (1 sigma)
