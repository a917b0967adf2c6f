"""Robot description files (planner.description, docs/robots.md): ETS-VII's file gives the
built-in model to the last bit, the second robot is physically sensible, the hash follows
content, and every fault is one clear error naming the file and the element."""

from __future__ import annotations

import math
import re
import shutil
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from planner.attitude_control import default_acs_gains
from planner.description import (
    ETS7_DESCRIPTION,
    EXAMPLES_DIR,
    MAX_FILE_BYTES,
    InvalidRobotDescription,
    RobotDescription,
    load_robot,
)
from planner.dynamics import DynamicsWorkspace
from planner.errors import InvalidInput
from planner.mjcf import mjcf_xml
from planner.model import RobotModel, default_model
from planner.simulation import default_servo_gains
from planner.state import State
from planner.urdf import urdf_xml
from spacecraft.vehicle_config import SensorNoise
from tests import reference_dynamics as ref

ORIHIME_DESCRIPTION = EXAMPLES_DIR / "orihime" / "orihime.toml"
ROBOTS = {"ets7": ETS7_DESCRIPTION, "orihime": ORIHIME_DESCRIPTION}


@pytest.fixture(scope="module")
def ets7() -> RobotDescription:
    return load_robot(ETS7_DESCRIPTION)


@pytest.fixture(scope="module")
def orihime() -> RobotDescription:
    return load_robot(ORIHIME_DESCRIPTION)


def _physical_arrays(model: RobotModel) -> dict[str, object]:
    """Every number the physics uses (LinkSpec keeps the inertia in a frame of its choice;
    its tensor in robot axes is what every consumer reads)."""
    out: dict[str, object] = {
        "base_mass_kg": model.base_mass_kg,
        "base_inertia_kgm2": model.base_inertia_kgm2,
        "pos_base_from_robot_m": model.pos_base_from_robot_m,
        "hand_pos_robot_m": model.hand_pos_robot_m,
        "joint_limit_rad": model.joint_limit_rad,
        "joint_rate_limit_radps": model.joint_rate_limit_radps,
    }
    for link in model.links:
        out |= {
            f"{link.name}.name": link.name,
            f"{link.name}.joint_pos_robot_m": link.joint_pos_robot_m,
            f"{link.name}.joint_axis_robot": link.joint_axis_robot,
            f"{link.name}.mass_kg": link.mass_kg,
            f"{link.name}.com_robot_m": link.com_robot_m,
            f"{link.name}.inertia_com_robot_kgm2": link.inertia_com_robot_kgm2,
        }
    for wheel in model.wheels:
        out |= {
            f"{wheel.name}.axis_base": wheel.axis_base,
            f"{wheel.name}.spin_inertia_kgm2": wheel.spin_inertia_kgm2,
            f"{wheel.name}.mass_kg": wheel.mass_kg,
        }
    return out


# --- 1. ETS-VII's file is today's model --------------------------------------------------


def test_ets7_file_equals_the_built_in_model_to_the_last_bit(ets7: RobotDescription) -> None:
    loaded, built_in = _physical_arrays(ets7.model), _physical_arrays(default_model())
    assert loaded.keys() == built_in.keys()
    for key, value in built_in.items():
        assert np.array_equal(np.asarray(loaded[key]), np.asarray(value)), key
    # The same MuJoCo model, and the same URDF once the collision geometry (the flight
    # rules' data, written by hand beside the export) is taken out.
    assert mjcf_xml(ets7.model) == mjcf_xml(default_model())
    assert _without_collision_geometry(ets7.urdf_path.read_text()) == _canonical(
        urdf_xml(ets7.model, name=ets7.name)
    )


def _canonical(text: str) -> str:
    return ET.canonicalize(text, strip_text=True)


def _without_collision_geometry(text: str) -> str:
    """The URDF without its <collision> elements and its equipment: the massless links fixed
    on the base that carry only geometry, and their joints."""
    root = ET.fromstring(text)
    for link in root.findall("link"):
        for collision in link.findall("collision"):
            link.remove(collision)
    equipment = {
        link.get("name")
        for link in root.findall("link")
        if link.find("inertial") is None
        and link.find("visual") is not None
        and link.get("name") != "hand"
    }
    for joint in root.findall("joint"):
        if joint.find("child").get("link") in equipment:  # type: ignore[union-attr]
            root.remove(joint)
    for link in root.findall("link"):
        if link.get("name") in equipment:
            root.remove(link)
    return _canonical(ET.tostring(root, encoding="unicode"))


def test_ets7_urdf_read_independently_matches_the_spec_tables() -> None:
    """The reference's own URDF reader (homogeneous transforms) against its re-typed SPEC
    tables: the checked-in file carries SPEC's numbers."""
    robot = ref.robot_from_description(ETS7_DESCRIPTION)
    for name in (
        "base_inertia_kgm2",
        "pos_base_from_robot_m",
        "joint_pos_robot_m",
        "joint_axis_robot",
        "link_mass_kg",
        "link_com_robot_m",
        "link_inertia_zero_pose_robot_kgm2",
        "hand_pos_robot_m",
        "wheel_axes_base",
    ):
        np.testing.assert_allclose(
            getattr(robot, name), getattr(ref.ETS7, name), rtol=0, atol=1e-15, err_msg=name
        )
    assert robot.base_mass_kg == ref.BASE_MASS_KG


def test_ets7_parameters_are_today_s_defaults(ets7: RobotDescription) -> None:
    ws = DynamicsWorkspace(ets7.model)
    gains, today = ets7.acs_gains(ws), default_acs_gains(ws)
    for name in ("kp_nm_per_rad", "kd_nms_per_rad", "ki_nm_per_rad_s"):
        np.testing.assert_array_equal(getattr(gains, name), getattr(today, name), err_msg=name)
    for name in ("torque_limit_nm", "momentum_limit_nms", "rate_filter_tau_s", "dead_band_rad"):
        assert getattr(gains, name) == getattr(today, name), name
    servo, servo_today = ets7.servo_gains(), default_servo_gains(default_model())
    np.testing.assert_array_equal(servo.kp_nm_per_rad, servo_today.kp_nm_per_rad)
    np.testing.assert_array_equal(servo.kd_nms_per_rad, servo_today.kd_nms_per_rad)
    from dataclasses import asdict

    assert SensorNoise(**asdict(ets7.sensor_noise)) == SensorNoise()


def test_ets7_poses_are_spec_1_2(ets7: RobotDescription) -> None:
    assert sorted(ets7.poses) == ["A", "B", "C"]
    np.testing.assert_array_equal(ets7.pose_joints_rad("A"), np.zeros(6))
    np.testing.assert_allclose(
        np.degrees(ets7.pose_joints_rad("B")), [31.6, 21.4, -8.8, 77.4, 0.0, 68.6], atol=1e-12
    )
    b, c = ets7.poses["B"], ets7.poses["C"]
    assert b.hand_pos_robot_m is not None and c.hand_pos_robot_m is not None
    np.testing.assert_allclose(c.hand_pos_robot_m - b.hand_pos_robot_m, [0, 0, 0.35], atol=1e-12)
    with pytest.raises(InvalidInput, match="no pose 'D'"):
        ets7.pose_joints_rad("D")


def test_ets7_experiment_defaults_are_the_planners(ets7: RobotDescription) -> None:
    from planner.catalogue import parameters_from_values, resolve

    for name, values in ets7.experiments.items():
        params_type = resolve(name)[0]
        assert parameters_from_values(params_type, values) == params_type(), name


# --- 2. the second robot -----------------------------------------------------------------


def test_orihime_is_a_light_base_with_a_seven_joint_arm(orihime: RobotDescription) -> None:
    model = orihime.model
    assert orihime.name == "orihime" and model.n_joints == 7 and len(model.wheels) == 3
    assert 200.0 < model.base_mass_kg < 500.0
    arm_fraction = (model.total_mass_kg - model.base_mass_kg) / model.total_mass_kg
    assert arm_fraction > 0.1  # ETS-VII's is 0.05
    for link in model.links:
        moments = np.linalg.eigvalsh(link.inertia_com_robot_kgm2)
        assert moments[0] > 0.0, link.name
        assert moments[0] + moments[1] >= moments[2], link.name  # a real rigid body
    moments = np.linalg.eigvalsh(model.base_inertia_kgm2)
    assert moments[0] > 0.0 and moments[0] + moments[1] >= moments[2]
    assert np.all(model.joint_rate_limit_radps > 0.0)


def test_orihime_has_a_spherical_wrist(orihime: RobotDescription) -> None:
    """Joints 5-7's axes meet at one point at the all-zero pose."""
    links = orihime.model.links
    centre = links[5].joint_pos_robot_m
    for link in links[4:]:
        offset = centre - link.joint_pos_robot_m
        along = offset - (offset @ link.joint_axis_robot) * link.joint_axis_robot
        assert np.linalg.norm(along) < 1e-12, link.name


@pytest.mark.parametrize("pose", ["A", "B", "C"])
def test_orihime_reaction_is_large_and_its_null_space_has_four_dimensions(
    orihime: RobotDescription, ets7: RobotDescription, pose: str
) -> None:
    n = orihime.n_joints
    q = orihime.pose_joints_rad(pose)
    quantities = DynamicsWorkspace(orihime.model).evaluate(
        State(joints_rad=q, joint_rates_radps=np.zeros(n))
    )
    assert quantities.rns_basis.shape == (n, n - 3)
    assert np.linalg.matrix_rank(quantities.H_bm_tilde, tol=1e-3) == 3
    ets7_q = DynamicsWorkspace(ets7.model).evaluate(State(joints_rad=np.zeros(6)))
    # base rotation per joint rotation: several times ETS-VII's
    assert np.abs(quantities.reaction_map).max() > 5 * np.abs(ets7_q.reaction_map).max()


def test_orihime_acs_and_servos(orihime: RobotDescription) -> None:
    gains = orihime.acs_gains()
    assert gains.torque_limit_nm == 0.2 and gains.momentum_limit_nms == 12.0
    servo = orihime.servo_gains()
    assert servo.kp_nm_per_rad.shape == (7,) and np.all(servo.kp_nm_per_rad > 0)
    np.testing.assert_allclose(servo.kd_nms_per_rad, 0.3 * servo.kp_nm_per_rad, rtol=1e-15)


def test_servo_lag_and_bandwidth_are_one_number_or_one_per_joint(
    tmp_path: Path, ets7: RobotDescription
) -> None:
    """ETS-VII's file gives a lag per joint (kd / kp is the lag); a bandwidth may be per joint
    too; one number applies to every joint, and a missing key is the one-for-all default
    (0.3 s, 6 rad/s)."""
    from planner.simulation import ETS7_SERVO_BANDWIDTH_RADPS, ETS7_SERVO_LAG_S

    servo = ets7.servo_gains()
    np.testing.assert_allclose(
        servo.kd_nms_per_rad / servo.kp_nm_per_rad, ETS7_SERVO_LAG_S, rtol=1e-15
    )
    inertia = servo.kp_nm_per_rad / np.square(ETS7_SERVO_BANDWIDTH_RADPS)
    target = _copy_robot(tmp_path, "ets7")
    toml = target / "ets7.toml"
    _edit(toml, "bandwidth_radps = 6.0", "bandwidth_radps = [5.0, 5.0, 5.0, 5.0, 5.0, 4.0]")
    _edit(toml, "lag_s = [0.3, 0.1, 0.35, 0.55, 0.3, 0.3]", "lag_s = 0.25")
    mixed = load_robot(toml).servo_gains()
    np.testing.assert_allclose(
        mixed.kp_nm_per_rad, np.array([25.0, 25.0, 25.0, 25.0, 25.0, 16.0]) * inertia, rtol=1e-12
    )
    np.testing.assert_allclose(mixed.kd_nms_per_rad, 0.25 * mixed.kp_nm_per_rad, rtol=1e-15)
    _edit(toml, "bandwidth_radps = [5.0, 5.0, 5.0, 5.0, 5.0, 4.0]\nlag_s = 0.25\n", "")
    default = load_robot(toml).servo_gains()
    np.testing.assert_allclose(default.kp_nm_per_rad, 36.0 * inertia, rtol=1e-12)
    np.testing.assert_allclose(default.kd_nms_per_rad, 0.3 * default.kp_nm_per_rad, rtol=1e-15)


# --- 3. frames with rotations -------------------------------------------------------------


def _rpy_text(rot: np.ndarray) -> str:
    return " ".join(repr(float(a)) for a in Rotation.from_matrix(rot).as_euler("xyz"))


def _vec_text(v: np.ndarray) -> str:
    return " ".join(repr(float(x)) for x in v)


def test_rotated_link_frames_load_to_the_same_physics(tmp_path: Path) -> None:
    """Link 3's frame turned by Q (its joint's origin rpy), with its axis, inertial and the
    next joint's origin written in that frame: the loaded model is the same physics."""
    import xml.etree.ElementTree as ET

    q = Rotation.from_euler("xyz", [0.3, -0.5, 1.1]).as_matrix()
    target = _copy_robot(tmp_path, "ets7")
    root = ET.parse(target / "ets7.urdf").getroot()
    joints = {j.get("name"): j for j in root.iter("joint")}
    link3 = next(link for link in root.iter("link") if link.get("name") == "link3")
    joints["joint3"].find("origin").set("rpy", _rpy_text(q))
    axis = joints["joint3"].find("axis")
    axis.set("xyz", _vec_text(q.T @ np.array([float(x) for x in axis.get("xyz").split()])))
    inertial = link3.find("inertial")
    origin = inertial.find("origin")
    com = np.array([float(x) for x in origin.get("xyz").split()])
    origin.set("xyz", _vec_text(q.T @ com))
    origin.set("rpy", _rpy_text(q.T))  # inertia axes: the robot's
    nxt = joints["joint4"].find("origin")
    offset = np.array([float(x) for x in nxt.get("xyz").split()])
    nxt.set("xyz", _vec_text(q.T @ offset))
    nxt.set("rpy", _rpy_text(q.T))
    (target / "ets7.urdf").write_text(ET.tostring(root, encoding="unicode"))

    loaded = load_robot(target / "ets7.toml").model
    assert loaded.links[2].rot_robot_from_inertia is not None
    expected = _physical_arrays(default_model())
    for key, value in _physical_arrays(loaded).items():
        if key.endswith(".name"):
            assert value == expected[key]
            continue
        np.testing.assert_allclose(
            np.asarray(value, dtype=float),
            np.asarray(expected[key], dtype=float),
            rtol=0,
            atol=1e-12,
            err_msg=key,
        )


# --- 4. the content hash ------------------------------------------------------------------


def _copy_robot(tmp_path: Path, name: str) -> Path:
    target = tmp_path / name
    shutil.copytree(EXAMPLES_DIR / name, target)
    return target


def test_hash_follows_content_not_layout(tmp_path: Path, ets7: RobotDescription) -> None:
    target = _copy_robot(tmp_path, "ets7")
    toml, urdf = target / "ets7.toml", target / "ets7.urdf"
    # Comments, blank lines and the URDF's file name are not content.
    urdf.rename(target / "renamed.urdf")
    text = toml.read_text().replace('urdf = "ets7.urdf"', 'urdf = "renamed.urdf"')
    toml.write_text("# another comment\n\n" + text)
    xml = (target / "renamed.urdf").read_text()
    (target / "renamed.urdf").write_text(xml.replace("<robot", "<!-- hi -->\n<robot", 1))
    assert load_robot(toml).content_sha256 == ets7.content_sha256
    # A number is content, in either file.
    toml.write_text(text.replace("settle_s = 120.0", "settle_s = 100.0"))
    assert load_robot(toml).content_sha256 != ets7.content_sha256
    toml.write_text(text)
    (target / "renamed.urdf").write_text(xml.replace('value="35.0"', 'value="35.5"'))
    assert load_robot(toml).content_sha256 != ets7.content_sha256
    assert re.fullmatch(r"[0-9a-f]{64}", ets7.content_sha256)


def test_the_two_robots_differ(ets7: RobotDescription, orihime: RobotDescription) -> None:
    assert ets7.content_sha256 != orihime.content_sha256


# --- 5. faults: one clear error each ------------------------------------------------------


def _edit(path: Path, old: str, new: str, count: int = 1) -> None:
    text = path.read_text()
    assert old in text, old
    path.write_text(text.replace(old, new, count))


def _expect(toml: Path, *fragments: str) -> InvalidRobotDescription:
    with pytest.raises(InvalidRobotDescription) as info:
        load_robot(toml)
    message = str(info.value)
    assert "\n" not in message
    for fragment in fragments:
        assert fragment in message, message
    return info.value


URDF_FAULTS = {
    "not_parsing": ("</robot>", "<robot>", ["ets7.urdf", "document", "not well-formed XML"]),
    "missing_inertia": (
        '<inertia ixx="1.31" ixy="0.0" ixz="0.0" iyy="3.75"',
        '<inertiaX ixx="1.31" ixy="0.0" ixz="0.0" iyy="3.75"',
        ["link 'link2' <inertial>", "missing <inertia>"],
    ),
    "massless_arm_link": ('value="16.5"', 'value="0.0"', ["link 'link4' <inertial>", "missing"]),
    "not_positive_definite": (
        'ixx="1.31" ixy="0.0" ixz="0.0" iyy="3.75"',
        'ixx="1.31" ixy="5.0" ixz="0.0" iyy="3.75"',
        ["link 'link2' <inertial> <inertia>", "not positive definite"],
    ),
    "prismatic": (
        '<joint name="joint4" type="revolute">',
        '<joint name="joint4" type="prismatic">',
        ["joint 'joint4'", "type 'prismatic' cannot be flown"],
    ),
    "floating": (
        '<joint name="joint2" type="revolute">',
        '<joint name="joint2" type="floating">',
        ["joint 'joint2'", "cannot be flown"],
    ),
    "no_hand": ('"hand"', '"gripper"', ["link 'hand'", "missing"]),
    "negative_mass": ('value="35.0"', 'value="-35.0"', ["link 'link1' <inertial> <mass>"]),
    "zero_rate": (
        'velocity="0.05235987755982989"',
        'velocity="0.0"',
        ["joint 'joint1' <limit>", "velocity must be > 0"],
    ),
    "bad_number": ('xyz="-0.785 -0.295 1.0"', 'xyz="-0.785 abc 1.0"', ["<origin xyz>"]),
    "entity": (
        '<?xml version="1.0"?>',
        '<?xml version="1.0"?>\n<!DOCTYPE r [<!ENTITY a "aaaa">]>',
        ["document", "DTDs and entity declarations are refused"],
    ),
}


@pytest.mark.parametrize("fault", list(URDF_FAULTS))
def test_urdf_fault_is_one_clear_error(tmp_path: Path, fault: str) -> None:
    old, new, fragments = URDF_FAULTS[fault]
    target = _copy_robot(tmp_path, "ets7")
    _edit(target / "ets7.urdf", old, new, count=-1)  # every occurrence
    error = _expect(target / "ets7.toml", str(target / "ets7.urdf"), *fragments)
    assert error.path == str(target / "ets7.urdf")


def test_triangle_inequality_is_not_required() -> None:
    """ETS-VII's identified link 1 breaks it (0.25 + 0.25 < 1.69) and loads (docs/model.md)."""
    link1 = load_robot(ETS7_DESCRIPTION).model.links[0]
    moments = np.linalg.eigvalsh(link1.inertia_com_robot_kgm2)
    assert moments[0] + moments[1] < moments[2]


def _add_to_urdf(path: Path, xml: str) -> None:
    _edit(path, "</robot>", xml + "\n</robot>")


def test_link_with_two_parents(tmp_path: Path) -> None:
    target = _copy_robot(tmp_path, "ets7")
    _add_to_urdf(
        target / "ets7.urdf",
        '<joint name="extra" type="fixed"><parent link="link1"/><child link="link3"/></joint>',
    )
    _expect(target / "ets7.toml", "link 'link3'", "two parents", "'joint3'", "'extra'")


def test_loop(tmp_path: Path) -> None:
    target = _copy_robot(tmp_path, "ets7")
    _add_to_urdf(
        target / "ets7.urdf",
        '<joint name="back" type="fixed"><parent link="link6"/><child link="base_link"/></joint>',
    )
    _expect(target / "ets7.toml", "in a loop of joints", "base_link")


def test_disconnected_tree(tmp_path: Path) -> None:
    target = _copy_robot(tmp_path, "ets7")
    _add_to_urdf(target / "ets7.urdf", '<link name="orphan"/>')
    _expect(target / "ets7.toml", "link 'orphan'", "not connected to the base link")


def test_massive_branch_is_lumped_and_a_massless_frame_is_not(tmp_path: Path) -> None:
    """A massive link on a fixed joint joins the arm link it is fixed to (exact numbers:
    tests/planner/test_vendor_urdf.py)."""
    target = _copy_robot(tmp_path, "ets7")
    camera = (
        '<link name="camera"/><joint name="camera_joint" type="fixed">'
        '<origin xyz="0.1 0 0"/><parent link="link3"/><child link="camera"/></joint>'
    )
    _add_to_urdf(target / "ets7.urdf", camera)
    assert load_robot(target / "ets7.toml").model.n_joints == 6
    _edit(
        target / "ets7.urdf",
        '<link name="camera"/>',
        '<link name="camera"><inertial><mass value="2.0"/>'
        '<inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>',
    )
    robot = load_robot(target / "ets7.toml")
    assert robot.lumped == (("camera", "link3"),)
    assert robot.model.links[2].mass_kg == pytest.approx(21.9 + 2.0, rel=1e-15)


def test_fewer_than_four_arm_joints(tmp_path: Path) -> None:
    target = _copy_robot(tmp_path, "ets7")
    for k in (4, 5, 6):
        _edit(
            target / "ets7.urdf",
            f'<joint name="joint{k}" type="revolute">',
            f'<joint name="joint{k}" type="fixed">',
        )
    _expect(target / "ets7.toml", "3 arm joint(s)", "at least 4")


TOML_FAULTS = {
    "not_parsing": ('name = "ets7"', 'name = "ets7', ["document", "not valid TOML"]),
    "unknown_key": ('name = "ets7"', 'name = "ets7"\ncolour = "red"', ["unknown key(s) colour"]),
    "unknown_base": ('base_link = "base_link"', 'base_link = "bus"', ["link 'bus'", "not in"]),
    "base_not_root": (
        'base_link = "base_link"',
        'base_link = "link2"',
        ["must be the URDF's root"],
    ),
    "absolute_urdf": ('urdf = "ets7.urdf"', 'urdf = "/etc/ets7.urdf"', ["urdf", "relative"]),
    "urdf_outside": ('urdf = "ets7.urdf"', 'urdf = "../ets7.urdf"', ["urdf", "must stay inside"]),
    "missing_urdf": ('urdf = "ets7.urdf"', 'urdf = "none.urdf"', ["none.urdf", "no such file"]),
    "bad_name": ('name = "ets7"', 'name = "ets 7!"', ["name"]),
    "two_wheels": (
        "[[wheels]]\naxis = [0.0, 0.0, 1.0]\nspin_inertia_kgm2 = 0.15\nrotor_mass_kg = 0.001\n"
        "torque_limit_nm = 0.3\nmomentum_limit_nms = 20.0\n",
        "",
        ["[[wheels]]", "exactly 3 wheels"],
    ),
    "zero_wheel_axis": ("axis = [0.0, 1.0, 0.0]", "axis = [0.0, 0.0, 0.0]", ["[[wheels]] 2 axis"]),
    "coplanar_wheels": ("axis = [0.0, 0.0, 1.0]", "axis = [1.0, 1.0, 0.0]", ["must span space"]),
    "negative_rotor": (
        "spin_inertia_kgm2 = 0.15",
        "spin_inertia_kgm2 = -0.15",
        ["[[wheels]] 1 spin_inertia_kgm2", "must be > 0"],
    ),
    "wheel_limit_missing": (
        "torque_limit_nm = 0.3\n",
        "",
        ["[[wheels]] 1", "missing torque_limit_nm"],
    ),
    "wheel_limit_text": (
        "momentum_limit_nms = 20.0",
        'momentum_limit_nms = "lots"',
        ["momentum_limit_nms", "must be a number"],
    ),
    "rotor_heavier_than_base": (
        "rotor_mass_kg = 0.001",
        "rotor_mass_kg = 3000.0",
        ["[[wheels]]", "must fit inside the base"],
    ),
    "acs_limit": (
        "damping_ratio = 0.55",
        "damping_ratio = 0.55\ntorque_limit_nm = 1.0",
        ["[acs] torque_limit_nm", "[[wheels]]"],
    ),
    "acs_unknown": (
        "damping_ratio = 0.55",
        "damping = 0.55",
        ["[acs]", "unknown attitude-control"],
    ),
    "servo_negative": ("lag_s = [0.3, 0.1,", "lag_s = [0.3, -0.1,", ["[servo] lag_s[1]", ">= 0"]),
    "servo_negative_scalar": (
        "lag_s = [0.3, 0.1, 0.35, 0.55, 0.3, 0.3]",
        "lag_s = -0.3",
        ["[servo] lag_s", ">= 0"],
    ),
    "servo_lag_count": (
        "lag_s = [0.3, 0.1, 0.35, 0.55, 0.3, 0.3]",
        "lag_s = [0.3, 0.1, 0.35]",
        ["[servo] lag_s", "one number or a list of 6 (one per joint), got 3"],
    ),
    "servo_lag_text": (
        "lag_s = [0.3, 0.1,",
        'lag_s = [0.3, "slow",',
        ["[servo] lag_s[1]", "number"],
    ),
    "servo_bandwidth_zero": (
        "bandwidth_radps = 6.0",
        "bandwidth_radps = [6.0, 0.0, 6.0, 6.0, 6.0, 6.0]",
        ["[servo] bandwidth_radps[1]", "must be > 0"],
    ),
    "servo_bandwidth_count": (
        "bandwidth_radps = 6.0",
        "bandwidth_radps = [6.0, 6.0, 6.0, 6.0, 6.0, 6.0, 6.0]",
        ["[servo] bandwidth_radps", "list of 6 (one per joint), got 7"],
    ),
    "servo_both_forms": (
        "lag_s = [0.3, 0.1, 0.35, 0.55, 0.3, 0.3]",
        "lag_s = [0.3, 0.1, 0.35, 0.55, 0.3, 0.3]\nkp_nm_per_rad = [1.0, 1.0, 1.0, 1.0, 1.0, 1.0]",
        ["[servo]", "give either bandwidth_radps/lag_s or both"],
    ),
    "noise_negative": ("joint_deg = 0.005", "joint_deg = -1.0", ["[sensor_noise] joint_deg"]),
    "pose_count": (
        "joints_deg = [31.6, 21.4, -8.8, 77.4, 0.0, 68.6]",
        "joints_deg = [31.6, 21.4, -8.8, 77.4, 0.0]",
        ["[poses.B] joints_deg", "list of 6 numbers"],
    ),
    "pose_limit": (
        "joints_deg = [31.6, 21.4, -8.8, 77.4, 0.0, 68.6]",
        "joints_deg = [31.6, 21.4, -8.8, 177.4, 0.0, 68.6]",
        ["[poses.B] joints_deg[3]", "outside joint 4's limits"],
    ),
    "pose_disagrees": (
        "hand_pos_robot_m = [1.170, 0.407, 0.490]",
        "hand_pos_robot_m = [1.170, 0.407, 0.590]",
        ["[poses.B]", "from hand_pos_robot_m"],
    ),
    "pose_half_hand": (
        "hand_pos_robot_m = [1.170, 0.407, 0.840]\nhand_rpy_deg = [0.0, 90.0, -37.0]",
        "hand_pos_robot_m = [1.170, 0.407, 0.840]",
        ["[poses.C]", "both"],
    ),
    "unknown_experiment": ("[experiments.gjm]", "[experiments.juggling]", ["juggling", "unknown"]),
    "experiment_joint_count": (
        "start_joints_deg = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]",
        "start_joints_deg = [0.0, 0.0, 0.0]",
        ["[experiments.ptp] start_joints_deg", "needs 6 values"],
    ),
    "experiment_bad_value": (
        "distance_m = 0.35",
        'distance_m = "far"',
        ["[experiments.reactionless]", "distance_m"],
    ),
    "experiment_unknown_parameter": (
        "hand_pitch_deg = -23.0",
        "hand_pitch = -23.0",
        ["[experiments.gjm]", "hand_pitch"],
    ),
}


@pytest.mark.parametrize("fault", list(TOML_FAULTS))
def test_toml_fault_is_one_clear_error(tmp_path: Path, fault: str) -> None:
    old, new, fragments = TOML_FAULTS[fault]
    target = _copy_robot(tmp_path, "ets7")
    _edit(target / "ets7.toml", old, new)
    _expect(target / "ets7.toml", *fragments)


def test_missing_description(tmp_path: Path) -> None:
    _expect(tmp_path / "nothing.toml", "nothing.toml", "no such file")


def test_a_shipped_robot_loads_by_its_name_and_an_unknown_name_says_which_exist(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)  # no file of that name here: the name is the shipped robot's
    assert load_robot("orihime").path == (EXAMPLES_DIR / "orihime" / "orihime.toml")
    _expect(Path("ets8"), "ets8", "nor a shipped robot of that name (ets7, orihime)")
    (tmp_path / "orihime").write_text("")  # a file of that name wins, and is read
    _expect(Path("orihime"), "orihime: name: missing")


def test_a_directory_is_not_a_description(tmp_path: Path) -> None:
    _expect(tmp_path, str(tmp_path), "not a regular file")


@pytest.mark.parametrize("which", ["ets7.toml", "ets7.urdf"])
def test_a_2_gib_file_is_refused_by_its_size(tmp_path: Path, which: str) -> None:
    """A sparse file: nothing is written, and nothing of it may be read."""
    target = _copy_robot(tmp_path, "ets7")
    subprocess.run(["truncate", "-s", "2G", str(target / which)], check=True)
    assert (target / which).stat().st_size == 2 * 1024**3
    error = _expect(target / "ets7.toml", str(target / which), f"{MAX_FILE_BYTES} byte limit")
    assert "2147483648 bytes" in str(error)


def test_a_failing_load_changes_nothing(tmp_path: Path, ets7: RobotDescription) -> None:
    target = _copy_robot(tmp_path, "ets7")
    before = {p.name: p.read_bytes() for p in target.iterdir()}
    _edit(target / "ets7.urdf", 'type="revolute"', 'type="prismatic"')
    broken = (target / "ets7.urdf").read_bytes()
    _expect(target / "ets7.toml", "prismatic")
    assert (target / "ets7.urdf").read_bytes() == broken
    (target / "ets7.urdf").write_bytes(before["ets7.urdf"])
    assert {p.name: p.read_bytes() for p in target.iterdir()} == before
    again = load_robot(target / "ets7.toml")
    assert again.content_sha256 == ets7.content_sha256
    assert mjcf_xml(again.model) == mjcf_xml(ets7.model)


def test_errors_are_invalid_input() -> None:
    assert issubclass(InvalidRobotDescription, InvalidInput)
    assert math.isfinite(MAX_FILE_BYTES) and MAX_FILE_BYTES == 16 * 1024 * 1024


def test_continuous_joints_get_a_turn_each_way(tmp_path: Path) -> None:
    target = _copy_robot(tmp_path, "ets7")
    _edit(
        target / "ets7.urdf",
        '<joint name="joint6" type="revolute">',
        '<joint name="joint6" type="continuous">',
    )
    model = load_robot(target / "ets7.toml").model
    np.testing.assert_array_equal(model.joint_limit_rad[5], [-2 * np.pi, 2 * np.pi])
    np.testing.assert_array_equal(model.joint_limit_rad[:5], default_model().joint_limit_rad[:5])


def test_base_box_comes_from_the_base_link_visual(
    ets7: RobotDescription, orihime: RobotDescription
) -> None:
    assert ets7.base_box_size_m == (2.4, 2.0, 2.0)
    assert orihime.base_box_size_m == (1.2, 1.0, 1.0)
    import xml.etree.ElementTree as ET

    assert orihime.base_box_size_m is not None
    text = urdf_xml(orihime.model, name="orihime", base_box_size_m=orihime.base_box_size_m)
    box = ET.fromstring(text).find("link/visual/geometry/box")
    assert box is not None and box.get("size") == "1.2 1.0 1.0"


def test_vehicle_tables_load_as_a_description_s(tmp_path: Path) -> None:
    """``hikoboshi calibrate --vehicle-out`` writes [servo] and [sensor_noise] tables that
    load with a description's checks; anything else is one clear error."""
    from planner.description import load_vehicle_tables

    path = tmp_path / "vehicle.toml"
    path.write_text(
        "[servo]\nbandwidth_radps = 6.0\nlag_s = [0.3, 0.1, 0.35, 0.55, 0.3, 0.3]\n\n"
        "[sensor_noise]\nattitude_deg = 0.008\n"
    )
    tables = load_vehicle_tables(path, 6)
    assert tables.servo is not None and tables.sensor_noise is not None
    np.testing.assert_array_equal(tables.servo.lag_s, [0.3, 0.1, 0.35, 0.55, 0.3, 0.3])
    assert tables.sensor_noise.attitude_rad == pytest.approx(np.radians(0.008), rel=1e-15)
    assert tables.sensor_noise.joint_rad == pytest.approx(np.radians(0.005), rel=1e-15)
    with pytest.raises(InvalidRobotDescription, match=r"\[servo\] lag_s: needs one number or"):
        load_vehicle_tables(path, 7)
    path.write_text("[acs]\nbandwidth_radps = 0.03\n")
    with pytest.raises(InvalidRobotDescription, match="unknown key"):
        load_vehicle_tables(path, 6)
    path.write_text("")
    with pytest.raises(InvalidRobotDescription, match="give a"):
        load_vehicle_tables(path, 6)
