"""The vendor arms' planning quantities against Pinocchio (``pin``, a dev dependency) built
from the vendor's URDF file unchanged, to 1e-9 relative (docs/robots.md, "A vendor's URDF").

The Pinocchio model is built independently of our loader:

- ``pin.buildModelFromUrdf(file, JointModelFreeFlyer())`` on the example-robot-data file as
  shipped: the free-flyer's body is the URDF's root link with every link fixed to it (Pinocchio
  lumps fixed joints itself);
- the description's ``[base]`` cube (its mass, a uniform box inertia from its size) is appended
  to that body at the cube's centre, placed from ``mount_xyz_m`` / ``mount_rpy_deg`` read from
  the TOML (the root's origin and axes on the cube);
- the tool joints off the base-to-hand chain (the Panda's fingers) are locked with
  ``pin.buildReducedModel``, at the TOML's ``[locked_joints]`` position or, for a joint with
  ``<mimic>``, the mimicked position times its multiplier plus its offset (read from the URDF
  here), which lumps them into the last arm link as our loader does.

Conventions, and the map between them. Ours (planner/state.py, planner/dynamics.py): the base
frame has the cube's axes and its origin at the base body's centre of mass (cube plus the
links fixed to the root); the generalised velocity is ``(v_c, w, phi')`` with ``v_c`` the base
CoM velocity and ``w`` the base angular velocity, both in the orbit (world) frame, linear
before angular; the base quaternion is scalar-last (x, y, z, w). Pinocchio's free-flyer:
``q = (p_O, quat_xyzw, phi)`` (also scalar-last) with ``O`` the URDF root's origin, and
``v = (v_O, w)`` both in the root's *local* axes, linear before angular. With ``R`` the orbit
from root rotation and ``l`` the base CoM in root coordinates (Pinocchio's own
``inertias[1].lever``): ``p_O = p_c - R l`` and

    v_pin = T v_ours,  T = [[R^T, R^T [R l]x, 0], [0, R^T, 0], [0, 0, P]]

(``P`` puts our joint order into Pinocchio's, by joint name), so a matrix acting on velocities
compares as ``M_ours = T^T M_pin T`` and a Jacobian as ``J_ours = J_pin T``. The hand Jacobian
is ``pin.computeFrameJacobian`` of the hand frame in ``LOCAL_WORLD_ALIGNED`` (the hand point's
velocity and the angular velocity in world axes: our ``(J_b | J_m)``); the momentum maps are
rows of ``pin.ccrba``'s centroidal momentum matrix (linear, then angular about the system CoM,
world axes): its angular rows times ``T`` are ``(0, H~_b, H~_bm)`` of eq. (3); ``pin.crba``
(upper triangle, mirrored) gives H_b, H_bm, H_m of eq. (1); J_g = J_m - J_b H_b^-1 H_bm is
formed from Pinocchio's blocks. Our wheels' rotors sit inside the base's mass and inertia
(the locked base), so they add nothing here.

Each comparison is ``max|ours - pin| / max|pin|`` over the quantity (a matrix's largest
entry as its scale), asserted below 1e-9 at several random joint poses inside the mission
limits and random base attitudes and positions.
``.venv/bin/python -m tests.planner.test_vendor_pinocchio`` prints the largest of each.
"""

from __future__ import annotations

import json
import tomllib
import xml.etree.ElementTree as ET
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")

from planner.description import load_robot  # noqa: E402
from planner.dynamics import DynamicsWorkspace  # noqa: E402
from planner.frames import matrix_from_quat_xyzw  # noqa: E402
from planner.robot import RobotDescription  # noqa: E402
from planner.state import State  # noqa: E402

if TYPE_CHECKING:
    from tests.support.made_once import MadeOnce

TOLERANCE = 1e-9
POSES = 6
ROBOTS = ("ur5", "panda", "panda_turned", "ur5_init", "panda_init")
#: The scaffolded ones: ``hikoboshi robot init`` on the vendor file, as tests/
#: test_cli_robot_init.py runs it once per test run (the UR5 on the default 300 kg cube, the
#: Panda on a 500 kg cube of 1.2 m: another mass and size than the descriptions'
#: tests/planner/vendor/*.toml)
INIT = {"ur5_init": "ur5", "panda_init": "panda"}


def _skew(a: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def _rpy(rpy: np.ndarray) -> np.ndarray:
    """URDF's fixed-axis roll, pitch, yaw: Rz(yaw) Ry(pitch) Rx(roll)."""
    return np.asarray(pin.rpy.rpyToMatrix(*rpy))


def _copy(tmp: Path, robot: str, made_once: MadeOnce) -> Path:
    from tests.support.vendor import copy_robot

    if robot in INIT:  # read only: the scaffold is shared
        from tests.support.scaffold import scaffold_once

        done = scaffold_once(made_once, INIT[robot])
        assert done.returncode == 0, done.stderr
        return done.out
    if robot != "panda_turned":
        return copy_robot(tmp, robot)
    # The Panda's root off the cube's centre and turned on it: the mount's rotation and
    # offset must enter the base frame as the description says.
    toml = copy_robot(tmp, "panda")
    text = toml.read_text().replace(
        "mount_xyz_m = [0.0, 0.0, 0.5]",
        "mount_xyz_m = [0.2, -0.1, 0.5]\nmount_rpy_deg = [5.0, -8.0, 30.0]",
    )
    assert "mount_rpy_deg" in text
    toml.write_text(text)
    return toml


@dataclass
class Reference:
    """Pinocchio's model of a description's vendor URDF, base and locked tools."""

    description: RobotDescription
    model: Any  # pinocchio.Model
    data: Any
    hand_frame: int
    joint1: int
    v_index: np.ndarray  # Pinocchio's velocity index of our joint k
    q_index: np.ndarray
    lever_m: np.ndarray  # base CoM in the root's coordinates
    rot_base_from_root: np.ndarray


def reference(toml: Path) -> Reference:
    description = load_robot(toml)
    doc = tomllib.loads(toml.read_text())
    urdf = toml.parent / doc["urdf"]
    full = pin.buildModelFromUrdf(str(urdf), pin.JointModelFreeFlyer())
    base = doc["base"]
    rot_br = _rpy(np.radians(base.get("mount_rpy_deg", [0.0, 0.0, 0.0])))
    pos_br = np.array(base["mount_xyz_m"], dtype=float)
    size = np.array(base["size_m"], dtype=float)
    mass = float(base["mass_kg"])
    box = (mass / 12.0) * np.diag(
        [size[1] ** 2 + size[2] ** 2, size[0] ** 2 + size[2] ** 2, size[0] ** 2 + size[1] ** 2]
    )
    # the cube's centre and axes in the root's frame
    rot_rb = rot_br.T
    centre = -rot_rb @ pos_br
    full.appendBodyToJoint(1, pin.Inertia(mass, np.zeros(3), box), pin.SE3(rot_rb, centre))

    # Tool joints off the chain, locked where the TOML and the URDF's <mimic> put them.
    xml = ET.parse(urdf).getroot()
    joints = {j.get("name"): j for j in xml.findall("joint")}
    explicit = {
        name: float(t["position_m"]) if "position_m" in t else np.radians(t["position_deg"])
        for name, t in doc.get("locked_joints", {}).items()
    }

    def position(name: str) -> float:
        if name in explicit:
            return explicit[name]
        mimic = joints[name].find("mimic")
        if mimic is not None:
            return float(mimic.get("multiplier", 1.0)) * position(mimic.get("joint", "")) + float(
                mimic.get("offset", 0.0)
            )
        return 0.0

    arm = set(description.joint_names)
    lock = [jid for jid in range(2, full.njoints) if full.names[jid] not in arm]
    q_ref = pin.neutral(full)
    locked = []
    for jid in lock:
        name = full.names[jid]
        q_ref[full.joints[jid].idx_q] = position(name)
        locked.append((name, joints[name].get("type"), position(name)))
    # our loader locked the same joints at the same positions
    assert sorted(locked) == sorted(description.locked)
    model = pin.buildReducedModel(full, lock, q_ref) if lock else full
    assert model.nv == 6 + description.n_joints
    v_index = np.array([model.joints[model.getJointId(n)].idx_v for n in description.joint_names])
    q_index = np.array([model.joints[model.getJointId(n)].idx_q for n in description.joint_names])
    return Reference(
        description=description,
        model=model,
        data=model.createData(),
        hand_frame=model.getFrameId(description.hand_link),
        joint1=model.getJointId(description.joint_names[0]),
        v_index=v_index,
        q_index=q_index,
        lever_m=np.array(model.inertias[1].lever),
        rot_base_from_root=rot_br,
    )


def _rel(ours: np.ndarray | float, ref: np.ndarray | float) -> float:
    ours, ref = np.asarray(ours, dtype=float), np.asarray(ref, dtype=float)
    assert ours.shape == ref.shape
    return float(np.max(np.abs(ours - ref)) / np.max(np.abs(ref)))


def pinocchio_quantities(
    ref: Reference, joints: np.ndarray, quat_xyzw: np.ndarray, pos_c: np.ndarray
) -> dict[str, np.ndarray]:
    """Pinocchio's numbers at one state of ours, in our conventions (the module's ``T``)."""
    n = ref.description.n_joints
    model, data = ref.model, ref.data
    rot_ob = matrix_from_quat_xyzw(quat_xyzw)
    rot = rot_ob @ ref.rot_base_from_root  # orbit from root
    q = pin.neutral(model)
    q[:3] = pos_c - rot @ ref.lever_m
    q[3:7] = pin.Quaternion(rot).coeffs()  # (x, y, z, w)
    q[ref.q_index] = joints
    nv = model.nv
    t = np.zeros((nv, nv))
    t[:3, :3] = rot.T
    t[:3, 3:6] = rot.T @ _skew(rot @ ref.lever_m)
    t[3:6, 3:6] = rot.T
    t[ref.v_index, 6 + np.arange(n)] = 1.0

    com = pin.centerOfMass(model, data, q)
    upper = pin.crba(model, data, q)
    big_m = t.T @ (np.triu(upper) + np.triu(upper, 1).T) @ t
    ag = pin.ccrba(model, data, q, np.zeros(nv)) @ t
    pin.framesForwardKinematics(model, data, q)
    hand = data.oMf[ref.hand_frame]
    jac = (
        pin.computeFrameJacobian(
            model, data, q, ref.hand_frame, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
        )
        @ t
    )
    h_b, h_bm = big_m[:6, :6], big_m[:6, 6:]
    j_b, j_m = jac[:, :6], jac[:, 6:]
    h_b_tilde, h_bm_tilde = ag[3:, 3:6], ag[3:, 6:]
    return {
        "total mass": np.array(pin.computeTotalMass(model)),
        "CoM": np.array(com),
        "H_b": h_b,
        "H_bm": h_bm,
        "H_m": big_m[6:, 6:],
        "linear momentum rows": ag[:3],
        # about the system CoM a translation of the whole system carries no momentum
        "angular momentum of v_c": ag[3:, :3],
        "H~_b (ccrba)": h_b_tilde,
        "H~_bm (ccrba)": h_bm_tilde,
        "system inertia about CoM (Ig)": np.array(data.Ig.inertia),
        "reaction map": -np.linalg.solve(h_b_tilde, h_bm_tilde),
        "hand position": np.array(hand.translation),
        "hand position, robot frame": rot_ob.T
        @ (hand.translation - data.oMi[ref.joint1].translation),
        "hand rotation": np.array(hand.rotation),
        "J_b": j_b,
        "J_m": j_m,
        "J_g": j_m - j_b @ np.linalg.solve(h_b, h_bm),
    }


def differences(
    ref: Reference, joints: np.ndarray, quat_xyzw: np.ndarray, pos_c: np.ndarray
) -> dict[str, float]:
    """``max|ours - pin| / max|pin|`` of every quantity at one state (the Python API that
    ``hikoboshi model quantities`` calls)."""
    theirs = pinocchio_quantities(ref, joints, quat_xyzw, pos_c)
    q = DynamicsWorkspace(ref.description.model).evaluate(
        State(
            joints_rad=joints,
            quat_orbit_from_base_xyzw=quat_xyzw,
            pos_base_orbit_m=pos_c,
            joint_rates_radps=np.zeros(ref.description.n_joints),
        )
    )
    zero = theirs.pop("angular momentum of v_c")
    assert float(np.max(np.abs(zero))) <= TOLERANCE * float(np.max(np.abs(theirs["H~_b (ccrba)"])))
    ours: dict[str, Any] = {
        "total mass": q.total_mass_kg,
        "CoM": q.com_orbit_m,
        "H_b": q.H_b,
        "H_bm": q.H_bm,
        "H_m": q.H_m,
        "linear momentum rows": np.hstack([q.H_b[:3], q.H_bm[:3]]),
        "H~_b (ccrba)": q.H_b_tilde,
        "H~_bm (ccrba)": q.H_bm_tilde,
        "system inertia about CoM (Ig)": q.inertia_com_orbit_kgm2,
        "reaction map": q.reaction_map,
        "hand position": q.hand.pos_orbit_m,
        "hand position, robot frame": q.hand.pos_robot_m,
        "hand rotation": q.hand.rot_orbit_from_hand,
        "J_b": q.J_b,
        "J_m": q.J_m,
        "J_g": q.J_g,
    }
    return {key: _rel(ours[key], value) for key, value in theirs.items()}


def states(ref: Reference, seed: int) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Random joint poses inside the mission limits, random base attitudes and positions;
    the first at the reference pose and the identity attitude."""
    rng = np.random.default_rng(seed)
    limits = np.asarray(ref.description.model.joint_limit_rad)
    yield ref.description.model.reference_joints, np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3)
    for _ in range(POSES - 1):
        quat = rng.normal(size=4)
        yield (
            rng.uniform(limits[:, 0], limits[:, 1]),
            quat / np.linalg.norm(quat),
            rng.uniform(-2.0, 2.0, size=3),
        )


def max_differences(ref: Reference, seed: int = 0) -> dict[str, float]:
    worst: dict[str, float] = {}
    for joints, quat, pos in states(ref, seed):
        for key, value in differences(ref, joints, quat, pos).items():
            worst[key] = max(worst.get(key, 0.0), value)
    return worst


@pytest.fixture(
    scope="module",
    params=[pytest.param(r, marks=pytest.mark.slow) if r in INIT else r for r in ROBOTS],
)
def ref(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory, made_once: MadeOnce
) -> Reference:
    return reference(_copy(tmp_path_factory.mktemp(request.param), request.param, made_once))


def test_quantities_agree_with_pinocchio(ref: Reference) -> None:
    worst = max_differences(ref, seed=sum(map(ord, str(ref.description.path))) % 1000)
    bad = {k: v for k, v in worst.items() if not v <= TOLERANCE}
    assert not bad, f"{ref.description.name}: beyond {TOLERANCE:g} relative: {bad}"


def test_the_command_line_s_quantities_agree_with_pinocchio(ref: Reference) -> None:
    """``hikoboshi model quantities --robot FILE --json`` (the base at the identity attitude)
    at a pose near the reference pose against the same Pinocchio numbers: the printed JSON
    round-trips every float."""
    from typer.testing import CliRunner

    from hikoboshi.cli import app

    d = ref.description
    joints_deg = np.degrees(d.model.reference_joints) + 7.0 * np.cos(np.arange(d.n_joints))
    joints_deg = np.clip(joints_deg, *np.degrees(np.asarray(d.model.joint_limit_rad)).T)
    text = ",".join(repr(float(v)) for v in joints_deg)
    result = CliRunner().invoke(
        app, ["model", "quantities", "--robot", str(d.path), "--joints-deg", text, "--json"]
    )
    assert result.exit_code == 0, result.output
    doc = json.loads(result.output)
    assert doc["joints_deg"] == joints_deg.tolist()
    theirs = pinocchio_quantities(
        ref, np.radians(joints_deg), np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3)
    )
    pairs = {
        "total_mass_kg": "total mass",
        "hand_position_robot_m": "hand position, robot frame",
        "generalized_jacobian": "J_g",
        "base_reaction_map": "reaction map",
        "system_inertia_com_kgm2": "system inertia about CoM (Ig)",
    }
    worst = {key: _rel(np.asarray(doc[key]), theirs[name]) for key, name in pairs.items()}
    bad = {key: value for key, value in worst.items() if not value <= TOLERANCE}
    assert not bad, f"{d.name}: beyond {TOLERANCE:g} relative: {bad}"


if __name__ == "__main__":  # the numbers docs/robots.md quotes
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:

        def made_here(name: str, make: Callable[[Path], None]) -> Path:
            folder = Path(tmp) / name
            if not folder.exists():
                folder.mkdir()
                make(folder)
            return folder

        for robot in ROBOTS:
            (Path(tmp) / robot).mkdir()
            r = reference(_copy(Path(tmp) / robot, robot, made_here))
            for key, value in max_differences(r, seed=sum(map(ord, robot))).items():
                print(f"{robot:13s} {key:32s} {value:.2e}")
