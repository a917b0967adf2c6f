"""``--robot FILE`` on ``hikoboshi model urdf|mjcf|quantities`` (issue 12's CLI contract), run
as a real subprocess, and the printed URDF read by another URDF parser (yourdfpy)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yourdfpy

from planner.description import ETS7_DESCRIPTION, EXAMPLES_DIR, load_robot
from planner.dynamics import DynamicsWorkspace
from planner.state import State

HIKOBOSHI = [sys.executable, "-m", "hikoboshi"]
ROBOTS = {"ets7": ETS7_DESCRIPTION, "orihime": EXAMPLES_DIR / "orihime" / "orihime.toml"}
KEYS = [
    "joints_deg",
    "total_mass_kg",
    "hand_position_robot_m",
    "hand_rpy_deg",
    "generalized_jacobian",
    "base_reaction_map",
    "system_inertia_com_kgm2",
    "gravity_gradient_torque_nm",
]


def run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*HIKOBOSHI, *args], capture_output=True, text=True, timeout=120)


@pytest.fixture(scope="module", params=list(ROBOTS))
def robot_path(request: pytest.FixtureRequest) -> Path:
    return ROBOTS[request.param]


@pytest.fixture(scope="module")
def printed_urdf(robot_path: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    result = run("model", "urdf", "--robot", str(robot_path))
    assert result.returncode == 0, result.stderr
    out = tmp_path_factory.mktemp("urdf") / f"{robot_path.stem}.urdf"
    out.write_text(result.stdout)
    return out


# --- model quantities ----------------------------------------------------------------------


def test_quantities_keep_today_s_keys_and_shapes(robot_path: Path) -> None:
    description = load_robot(robot_path)
    n = description.n_joints
    pose = np.degrees(description.pose_joints_rad("B"))
    joints = ",".join(repr(float(x)) for x in pose)
    result = run(
        "model", "quantities", "--robot", str(robot_path), "--joints-deg", joints, "--json"
    )
    assert result.returncode == 0, result.stderr
    doc = json.loads(result.stdout)
    assert list(doc) == KEYS
    assert np.shape(doc["generalized_jacobian"]) == (6, n)
    assert np.shape(doc["base_reaction_map"]) == (3, n)
    assert np.shape(doc["system_inertia_com_kgm2"]) == (3, 3)
    # The conventions: base at the orbit frame's nominal attitude, zero momentum.
    q = DynamicsWorkspace(description.model).evaluate(
        State(joints_rad=np.radians(pose), joint_rates_radps=np.zeros(n))
    )
    np.testing.assert_allclose(doc["generalized_jacobian"], q.J_g, rtol=0, atol=1e-12)
    np.testing.assert_allclose(doc["base_reaction_map"], q.reaction_map, rtol=0, atol=1e-12)
    np.testing.assert_allclose(
        doc["system_inertia_com_kgm2"], q.inertia_com_base_kgm2, rtol=1e-12, atol=1e-12
    )
    assert doc["total_mass_kg"] == pytest.approx(description.model.total_mass_kg, abs=1e-9)


def test_ets7_file_gives_today_s_answer() -> None:
    joints = "31.6,21.4,-8.8,77.4,0,68.6"
    built_in = run("model", "quantities", "--joints-deg", joints, "--json")
    from_file = run(
        "model", "quantities", "--robot", str(ETS7_DESCRIPTION), "--joints-deg", joints, "--json"
    )
    assert built_in.returncode == 0 and from_file.returncode == 0
    assert from_file.stdout == built_in.stdout


def test_joint_count_mismatch_is_one_line() -> None:
    result = run(
        "model", "quantities", "--robot", str(ROBOTS["orihime"]), "--joints-deg", "0,0,0,0,0,0"
    )
    assert result.returncode != 0 and result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "needs 7 comma-separated angles, got 6" in lines[0]


@pytest.mark.parametrize("command", ["urdf", "mjcf", "quantities"])
def test_bad_description_is_one_line_without_traceback(tmp_path: Path, command: str) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "bad"\nurdf = "missing.urdf"\nbase_link = "base_link"\n')
    extra = ["--joints-deg", "0,0,0,0,0,0"] if command == "quantities" else []
    result = run("model", command, "--robot", str(bad), *extra)
    assert result.returncode == 2
    assert result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert str(bad) in lines[0] and "wheels" in lines[0]
    assert "Traceback" not in result.stderr


# --- model urdf / mjcf ---------------------------------------------------------------------


def test_printed_urdf_is_rooted_at_the_base_and_has_a_hand(
    printed_urdf: Path, robot_path: Path
) -> None:
    root = ET.parse(printed_urdf).getroot()
    assert root.get("name") == load_robot(robot_path).name
    children = {j.find("child").get("link") for j in root.iter("joint")}
    links = [link.get("name") for link in root.iter("link")]
    assert [name for name in links if name not in children] == ["base_link"]
    assert "hand" in links
    # The root's frame is the base frame: its inertial sits at its origin, unrotated.
    origin = root.find("link/inertial/origin")
    assert origin is not None
    assert origin.get("xyz") == "0.0 0.0 0.0" and origin.get("rpy") == "0.0 0.0 0.0"


def test_mjcf_follows_the_robot(robot_path: Path) -> None:
    result = run("model", "mjcf", "--robot", str(robot_path))
    assert result.returncode == 0, result.stderr
    root = ET.fromstring(result.stdout)
    n = load_robot(robot_path).n_joints
    hinges = [j.get("name") for j in root.iter("joint") if j.get("type") == "hinge"]
    assert hinges[:n] == [f"joint{i}" for i in range(1, n + 1)]
    assert root.get("model") == robot_path.stem


# --- the printed URDF in yourdfpy ----------------------------------------------------------


def _mass_properties(urdf: yourdfpy.URDF) -> tuple[float, np.ndarray, np.ndarray]:
    """Total mass, CoM and inertia about the CoM, in the root link's frame."""
    bodies = []
    for link in urdf.robot.links:
        if link.inertial is None or link.inertial.mass == 0.0:
            continue
        frame = urdf.get_transform(link.name, "base_link") @ link.inertial.origin
        bodies.append((link.inertial.mass, frame[:3, 3], frame[:3, :3], link.inertial.inertia))
    mass = sum(m for m, *_ in bodies)
    com = sum(m * c for m, c, *_ in bodies) / mass
    inertia = np.zeros((3, 3))
    for m, c, rot, tensor in bodies:
        d = c - com
        inertia += rot @ tensor @ rot.T + m * (d @ d * np.eye(3) - np.outer(d, d))
    return float(mass), np.asarray(com), inertia


@pytest.mark.parametrize("pose", ["A", "B"])
def test_yourdfpy_sees_our_mass_com_and_inertia(
    printed_urdf: Path, robot_path: Path, pose: str
) -> None:
    description = load_robot(robot_path)
    n = description.n_joints
    urdf = yourdfpy.URDF.load(
        str(printed_urdf), build_scene_graph=True, load_meshes=False, load_collision_meshes=False
    )
    assert urdf.base_link == "base_link"
    assert urdf.actuated_joint_names == [f"joint{i}" for i in range(1, n + 1)]
    joints = description.pose_joints_rad(pose)
    urdf.update_cfg(joints)
    mass, com, inertia = _mass_properties(urdf)
    q = DynamicsWorkspace(description.model).evaluate(
        State(joints_rad=joints, joint_rates_radps=np.zeros(n))
    )
    assert mass == pytest.approx(q.total_mass_kg, rel=1e-12)
    # Base at the origin and unrotated: orbit-frame CoM = base-frame CoM.
    np.testing.assert_allclose(com, q.com_orbit_m, rtol=0, atol=1e-12)
    np.testing.assert_allclose(inertia, q.inertia_com_base_kgm2, rtol=1e-12, atol=1e-9)
    hand = urdf.get_transform("hand", "base_link")
    np.testing.assert_allclose(hand[:3, 3], q.hand.pos_base_m, rtol=0, atol=1e-12)
    np.testing.assert_allclose(hand[:3, :3], q.hand.rot_base_from_hand, rtol=0, atol=1e-12)
    assert pose == "A" or np.abs(joints).max() > 0.1  # B really moves the arm


# --- robot check ---------------------------------------------------------------------------


def test_robot_check_prints_what_a_vendor_urdf_became(tmp_path: Path) -> None:
    """The Panda from example-robot-data, unchanged (tests/planner/test_vendor_urdf.py)."""
    from tests.support.vendor import copy_robot

    toml = copy_robot(tmp_path, "panda")
    result = run("robot", "check", str(toml))
    assert result.returncode == 0, result.stderr
    out = result.stdout
    for line in (
        "link panda_hand into panda_link7",
        "link panda_leftfinger into panda_link7",
        "link panda_link0 into [base]",
        "joint panda_finger_joint2 (prismatic) at 0.02 m",
        "renamed: none",
        "reference pose: ready (0, -45, 0, -135, 0, 90, 45 deg)",
        "hand: link panda_hand_tcp, rpy at the all-zero pose (180, ",
        "panda_joint4 -> panda_link4: mission [-170, -10] deg, 3 deg/s (vendor [-176.001, ",
    ):
        assert line in out, out
    report = json.loads(run("robot", "check", str(toml), "--json").stdout)
    assert report["servo"]["holds_at_poses"] is True
    assert report["servo"]["limit_per_s"] == pytest.approx(250.0)
    assert [row["into"] for row in report["lumped"]] == ["[base]", *["panda_link7"] * 3]


def test_robot_check_warns_of_ets7_s_fast_corners_and_names_renames(tmp_path: Path) -> None:
    """ETS-VII loads unchanged (its flown poses' fastest mode is under the bound) and the
    check warns of the corners of its +-170 deg box where it is not; an arm link called
    'base' is renamed and said so."""
    result = run("robot", "check", str(ETS7_DESCRIPTION), "--json")
    assert result.returncode == 0, result.stderr
    servo = json.loads(result.stdout)["servo"]
    assert servo["fastest_at_poses_per_s"] < 250.0 < servo["fastest_over_range_per_s"]
    assert (
        "warning: somewhere inside the limits"
        in run("robot", "check", str(ETS7_DESCRIPTION)).stdout
    )
    target = tmp_path / "ets7"
    shutil.copytree(ETS7_DESCRIPTION.parent, target)
    for name in ("ets7.urdf", "ets7.toml"):  # the link and its allowed contacts
        path = target / name
        path.write_text(path.read_text().replace('"link2"', '"base"'))
    out = run("robot", "check", str(target / "ets7.toml")).stdout
    assert "link base is link2" in out, out


def test_robot_check_refusal_is_one_line_naming_the_element(tmp_path: Path) -> None:
    """A pose's error names the pose (the TOML table is no longer eaten as console markup)."""
    target = tmp_path / "ets7"
    shutil.copytree(ETS7_DESCRIPTION.parent, target)
    toml = target / "ets7.toml"
    text = toml.read_text()
    toml.write_text(text.replace("[1.170, 0.407, 0.490]", "[1.170, 0.407, 0.540]"))
    result = run("robot", "check", str(toml))
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1
    assert f"error: {toml}: [poses.B]: joints_deg put the hand" in result.stderr, result.stderr
