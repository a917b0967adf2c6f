"""The URDF export against the canonical model and against the MuJoCo-based dynamics.

The URDF is read back with the standard library only, and its kinematics and mass
properties are recomputed here in plain NumPy (an independent reference to
:class:`planner.dynamics.DynamicsWorkspace`, which runs MuJoCo on the MJCF).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np
import pytest
from numpy.typing import NDArray

from planner.dynamics import DynamicsWorkspace
from planner.model import RobotModel, default_model
from planner.state import State
from planner.urdf import urdf_xml

Array = NDArray[np.float64]

# Lengths are ~3 m and every step is a handful of float operations, so agreement is to
# ~1e-15; 1e-12 m / 1e-12 (rotation-matrix entries, ~rad) leaves room without hiding a bug.
KINEMATICS_TOL = 1e-12
N_RANDOM_POSES = 10

LINKS = ["base_link", "robot_base", *(f"link{i}" for i in range(1, 7)), "hand"]
JOINTS = {
    "robot_base_joint": ("fixed", "base_link", "robot_base"),
    **{
        f"joint{i}": ("revolute", "robot_base" if i == 1 else f"link{i - 1}", f"link{i}")
        for i in range(1, 7)
    },
    "hand_joint": ("fixed", "link6", "hand"),
}


# --- a tiny URDF reader and forward kinematics -----------------------------------------


def _floats(text: str | None) -> Array:
    assert text is not None
    return np.array([float(x) for x in text.split()])


def _rpy_matrix(rpy: Array) -> Array:
    """URDF's fixed-axis roll, pitch, yaw: ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    cr, sr = np.cos(rpy[0]), np.sin(rpy[0])
    cp, sp = np.cos(rpy[1]), np.sin(rpy[1])
    cy, sy = np.cos(rpy[2]), np.sin(rpy[2])
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return np.asarray(rz @ ry @ rx, dtype=np.float64)


def _axis_angle(axis: Array, angle_rad: float) -> Array:
    """Rodrigues' formula."""
    k = axis / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.asarray(
        np.eye(3) + np.sin(angle_rad) * kx + (1 - np.cos(angle_rad)) * kx @ kx, dtype=np.float64
    )


def _transform(rot: Array, pos: Array) -> Array:
    t = np.eye(4)
    t[:3, :3], t[:3, 3] = rot, pos
    return t


def _origin(elem: ET.Element) -> Array:
    """The 4x4 transform of ``elem``'s ``<origin>`` (identity if absent)."""
    origin = elem.find("origin")
    if origin is None:
        return np.eye(4)
    return _transform(
        _rpy_matrix(_floats(origin.get("rpy", "0 0 0"))), _floats(origin.get("xyz", "0 0 0"))
    )


@dataclass
class Urdf:
    root: ET.Element
    links: dict[str, ET.Element]
    joints: dict[str, ET.Element]
    joint_of_child: dict[str, ET.Element]

    @classmethod
    def parse(cls, text: str) -> Urdf:
        root = ET.fromstring(text)
        links = {e.get("name", ""): e for e in root.findall("link")}
        joints = {e.get("name", ""): e for e in root.findall("joint")}
        joint_of_child = {}
        for joint in joints.values():
            child = joint.find("child")
            assert child is not None
            joint_of_child[child.get("link", "")] = joint
        return cls(root, links, joints, joint_of_child)

    def pose(self, link: str, q: Array) -> Array:
        """``T_base_link_from_link`` at joint angles ``q`` (joint k takes ``q[k - 1]``)."""
        t = np.eye(4)
        while link in self.joint_of_child:
            joint = self.joint_of_child[link]
            step = _origin(joint)
            if joint.get("type") == "revolute":
                axis = joint.find("axis")
                assert axis is not None
                k = int(joint.get("name", "")[len("joint") :])
                step = step @ _transform(
                    _axis_angle(_floats(axis.get("xyz")), q[k - 1]), np.zeros(3)
                )
            t = step @ t
            parent = joint.find("parent")
            assert parent is not None
            link = parent.get("link", "")
        assert link == "base_link"
        return t

    def inertial(self, link: str) -> tuple[float, Array, Array]:
        """Mass, CoM in the link frame, inertia about the CoM (link axes) of ``link``."""
        inertial = self.links[link].find("inertial")
        assert inertial is not None
        mass, inertia = inertial.find("mass"), inertial.find("inertia")
        assert mass is not None and inertia is not None
        i = {k: float(inertia.get(k, "nan")) for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")}
        matrix = np.array(
            [
                [i["ixx"], i["ixy"], i["ixz"]],
                [i["ixy"], i["iyy"], i["iyz"]],
                [i["ixz"], i["iyz"], i["izz"]],
            ]
        )
        frame = _origin(inertial)
        # Inertia given in a rotated frame would need rotating; the exporter writes rpy 0.
        np.testing.assert_array_equal(frame[:3, :3], np.eye(3))
        return float(mass.get("value", "nan")), frame[:3, 3], matrix


# --- fixtures ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def model() -> RobotModel:
    return default_model()


@pytest.fixture(scope="module")
def urdf(model: RobotModel) -> Urdf:
    return Urdf.parse(urdf_xml(model))


@pytest.fixture(scope="module")
def workspace(model: RobotModel) -> DynamicsWorkspace:
    return DynamicsWorkspace(model)


def _random_poses(model: RobotModel, seed: int) -> list[Array]:
    rng = np.random.default_rng(seed)
    lo, hi = model.joint_limit_rad[:, 0], model.joint_limit_rad[:, 1]
    return [rng.uniform(lo, hi) for _ in range(N_RANDOM_POSES)]


# --- 1. structure -----------------------------------------------------------------------


def test_tree_has_the_expected_links_and_joints(urdf: Urdf) -> None:
    assert urdf.root.tag == "robot"
    assert urdf.root.get("name") == "ets7"
    assert [e.get("name") for e in urdf.root.findall("link")] == LINKS
    found = {}
    for name, joint in urdf.joints.items():
        parent, child = joint.find("parent"), joint.find("child")
        assert parent is not None and child is not None
        found[name] = (joint.get("type"), parent.get("link"), child.get("link"))
    assert found == JOINTS
    assert len(urdf.root.findall("joint")) == len(JOINTS)  # no duplicate names


def test_tree_is_one_tree_rooted_at_base_link(urdf: Urdf) -> None:
    children = [j.find("child") for j in urdf.joints.values()]
    child_links = [c.get("link") for c in children if c is not None]
    assert len(child_links) == len(set(child_links))  # each link has at most one parent
    assert set(urdf.links) - set(child_links) == {"base_link"}
    for link in urdf.links:  # every link reaches base_link (pose() asserts so)
        urdf.pose(link, np.zeros(6))


def test_name_argument_names_the_robot(model: RobotModel) -> None:
    assert ET.fromstring(urdf_xml(model, name="ets7_flight")).get("name") == "ets7_flight"


# --- 2. kinematics ----------------------------------------------------------------------


def test_zero_pose_puts_the_hand_at_spec_pose_a(urdf: Urdf) -> None:
    # SPEC 1.2 and 7: pose A in the robot frame, robot origin at (-0.785, -0.295, 1.0) in base.
    t = urdf.pose("hand", np.zeros(6))
    expected = np.array([-0.785, -0.295, 1.0]) + np.array([1.162, -0.267, 1.497])
    np.testing.assert_allclose(t[:3, 3], expected, rtol=0, atol=KINEMATICS_TOL)
    np.testing.assert_allclose(t[:3, :3], np.eye(3), rtol=0, atol=KINEMATICS_TOL)


@pytest.mark.parametrize("q_index", range(N_RANDOM_POSES))
def test_hand_pose_matches_dynamics(
    q_index: int, model: RobotModel, urdf: Urdf, workspace: DynamicsWorkspace
) -> None:
    q = _random_poses(model, seed=7)[q_index]
    t = urdf.pose("hand", q)
    hand = workspace.hand_pose(State(joints_rad=q))
    np.testing.assert_allclose(t[:3, 3], hand.pos_base_m, rtol=0, atol=KINEMATICS_TOL)
    np.testing.assert_allclose(t[:3, :3], hand.rot_base_from_hand, rtol=0, atol=KINEMATICS_TOL)


def test_link_cylinders_run_from_joint_to_next_joint(urdf: Urdf) -> None:
    ends = {f"link{i}": f"joint{i + 1}" for i in range(1, 6)} | {"link6": "hand_joint"}
    for link, next_joint in ends.items():
        visual = urdf.links[link].find("visual")
        assert visual is not None
        cylinder = visual.find("geometry/cylinder")
        assert cylinder is not None
        half = 0.5 * float(cylinder.get("length", "nan")) * _origin(visual)[:3, 2]
        centre = _origin(visual)[:3, 3]
        np.testing.assert_allclose(centre - half, np.zeros(3), rtol=0, atol=KINEMATICS_TOL)
        np.testing.assert_allclose(
            centre + half, _origin(urdf.joints[next_joint])[:3, 3], rtol=0, atol=KINEMATICS_TOL
        )


def test_base_box_is_centred_on_the_base_com(urdf: Urdf) -> None:
    visual = urdf.links["base_link"].find("visual")
    assert visual is not None
    box = visual.find("geometry/box")
    assert box is not None
    np.testing.assert_array_equal(_floats(box.get("size")), [2.4, 2.0, 2.0])
    np.testing.assert_array_equal(_origin(visual), np.eye(4))


# --- 3. mass properties -----------------------------------------------------------------


def test_masses_sum_to_the_model_total(model: RobotModel, urdf: Urdf) -> None:
    masses = [urdf.inertial(link)[0] for link in ["base_link", *(s.name for s in model.links)]]
    for link in ("robot_base", "hand"):
        assert urdf.links[link].find("inertial") is None  # massless frames
    assert sum(masses) == pytest.approx(model.total_mass_kg, rel=0, abs=1e-9)
    assert sum(masses) == pytest.approx(2690.4, rel=0, abs=1e-9)  # SPEC 1.1, Table 1


def test_inertials_equal_the_model_exactly(model: RobotModel, urdf: Urdf) -> None:
    # repr-formatted numbers round-trip, so equality is exact, not approximate.
    mass, com, inertia = urdf.inertial("base_link")
    assert mass == model.base_mass_kg
    np.testing.assert_array_equal(com, np.zeros(3))
    np.testing.assert_array_equal(inertia, model.base_inertia_kgm2)
    for spec in model.links:
        mass, com, inertia = urdf.inertial(spec.name)
        assert mass == spec.mass_kg
        np.testing.assert_array_equal(com, spec.com_robot_m - spec.joint_pos_robot_m)
        np.testing.assert_array_equal(inertia, spec.inertia_com_robot_kgm2)


def test_system_com_matches_dynamics(
    model: RobotModel, urdf: Urdf, workspace: DynamicsWorkspace
) -> None:
    bodies = ["base_link", *(s.name for s in model.links)]
    for q in _random_poses(model, seed=11):
        weighted = np.zeros(3)
        total = 0.0
        for link in bodies:
            mass, com_link, _ = urdf.inertial(link)
            t = urdf.pose(link, q)
            weighted += mass * (t[:3, :3] @ com_link + t[:3, 3])
            total += mass
        expected = workspace.evaluate(State(joints_rad=q)).com_orbit_m  # base at identity, 0
        np.testing.assert_allclose(weighted / total, expected, rtol=0, atol=KINEMATICS_TOL)


# --- 4. limits --------------------------------------------------------------------------


def test_joint_limits_and_rates_equal_the_model(model: RobotModel, urdf: Urdf) -> None:
    for i in range(model.n_joints):
        limit = urdf.joints[f"joint{i + 1}"].find("limit")
        assert limit is not None
        assert float(limit.get("lower", "nan")) == model.joint_limit_rad[i, 0]
        assert float(limit.get("upper", "nan")) == model.joint_limit_rad[i, 1]
        assert float(limit.get("velocity", "nan")) == model.joint_rate_limit_radps[i]
        assert float(limit.get("effort", "nan")) == 200.0  # documented choice in planner.urdf


def test_limits_follow_a_non_default_model() -> None:
    model = default_model(joint_limit_deg=90.0, joint_rate_limit_degps=1.5)
    urdf = Urdf.parse(urdf_xml(model))
    limit = urdf.joints["joint4"].find("limit")
    assert limit is not None
    assert float(limit.get("upper", "nan")) == np.radians(90.0)
    assert float(limit.get("velocity", "nan")) == np.radians(1.5)
