"""A vendor URDF's meshes (docs/robots.md, "Meshes"): the UR5 and Panda of example-robot-data
(a dev dependency) with their ``package://`` meshes found through ``[packages]``.

The collision meshes become convex hulls (coal's, from the points coal's loader reads); a
hull's distance is checked against an independent computation: the mesh read by trimesh,
its hull by scipy (qhull), and the distance from a point to that hull by brute force over
its triangles. A plan driving the UR5's wrist into the base is refused, one to its pose B
passes. A description naming a mesh over the size limit, or a package with no folder, is
refused with the reason; the shipped robots name no mesh at all.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial import ConvexHull

from planner.catalogue import parameters_from_values, plan_experiment, resolve
from planner.collision import CollisionBody, CollisionModel, CollisionShape, ShapeSet
from planner.description import EXAMPLES_DIR, InvalidRobotDescription, load_robot
from planner.description.files import MAX_FILE_BYTES
from planner.plan import Plan
from planner.robot import RobotDescription
from tests.support.vendor import meshed_robot, package_root


@pytest.fixture(scope="module")
def ur5(tmp_path_factory: pytest.TempPathFactory) -> RobotDescription:
    return load_robot(meshed_robot(tmp_path_factory.mktemp("ur5"), "ur5"))


def _brute_distance(point: np.ndarray, vertices: np.ndarray) -> float:
    """The signed distance from ``point`` to the convex hull of ``vertices`` (scipy's qhull):
    outside, the least distance to any hull triangle (its plane inside the triangle, else its
    edges); inside, minus the least distance to a facet's plane."""
    hull = ConvexHull(vertices)
    normals, offsets = hull.equations[:, :3], hull.equations[:, 3]
    plane = normals @ point + offsets
    if np.all(plane <= 0.0):
        return float(np.max(plane))
    a, b, c = (vertices[hull.simplices[:, k]] for k in range(3))
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1)[:, None]
    height = np.einsum("ij,ij->i", point - a, n)
    foot = point - height[:, None] * n
    inside = np.ones(len(a), dtype=bool)
    for p, q in ((a, b), (b, c), (c, a)):
        side = np.einsum("ij,ij->i", np.cross(q - p, foot - p), n)
        inside &= side >= -1e-15
    best = np.where(inside, np.abs(height), np.inf)
    for p, q in ((a, b), (b, c), (c, a)):
        d = q - p
        t = np.clip(np.einsum("ij,ij->i", point - p, d) / np.einsum("ij,ij->i", d, d), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(point - (p + t[:, None] * d), axis=1))
    return float(np.min(best))


@pytest.mark.parametrize("link", ["upper_arm_link", "wrist_1_link"])
def test_a_hull_s_distance_agrees_with_an_independent_computation(
    ur5: RobotDescription, link: str
) -> None:
    assert ur5.collision is not None
    [shape] = ur5.collision.body(link).shapes
    assert shape.kind == "convex" and shape.vertices_m is not None
    name = {"upper_arm_link": "upperarm", "wrist_1_link": "wrist1"}[link]
    mesh = trimesh.load(
        package_root("ur5") / f"robots/ur_description/meshes/ur5/collision/{name}.stl",
        force="mesh",
    )
    # the same points, read by another library (coal's assimp vs trimesh's own STL reader)
    ours = {tuple(p) for p in np.round(shape.vertices_m, 6)}
    theirs = {tuple(p) for p in np.round(np.asarray(mesh.vertices), 6)}
    assert ours == theirs
    robot_points = np.asarray(mesh.vertices) @ shape.rot_robot_from_shape.T + shape.pos_robot_m
    centre = robot_points.mean(axis=0)
    rng = np.random.default_rng(28)
    radius = 0.01
    checked = 0
    for k in range(12):
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        point = centre + direction * (0.02 + 0.05 * k)  # from inside the hull to well outside
        probe = CollisionShape("sphere", (radius,), np.eye(3), point)
        model = CollisionModel(
            (CollisionBody("hull", 0, (shape,)), CollisionBody("p", 1, (probe,)))
        )
        got = ShapeSet(model).distance(0, 1, np.eye(3), np.zeros(3), np.eye(3), np.zeros(3))
        want = _brute_distance(point, robot_points) - radius
        assert got.distance_m == pytest.approx(want, abs=2e-6), (k, point)
        checked += want < 0.0
    assert 0 < checked < 12  # both penetration and separation were compared


def _ptp(robot: RobotDescription, goal_deg: tuple[float, ...]) -> Plan:
    params_type, _ = resolve("ptp")
    start = [float(v) for v in np.degrees(robot.model.reference_joints)]
    params = parameters_from_values(
        params_type, {"start_joints_deg": start, "goal_joints_deg": goal_deg}
    )
    return plan_experiment("ptp", params, robot=robot)


def test_a_plan_driving_the_ur5_s_wrist_into_the_base_is_refused(ur5: RobotDescription) -> None:
    """From home (upper arm up, forearm level) the shoulder lowered to level: the forearm
    hangs down and the wrist's mesh goes into the 1 m cube it is mounted on."""
    report = ur5.check_plan(_ptp(ur5, (0.0, 0.0, 90.0, -90.0, -90.0, 0.0)))
    row = report.row("clearance")
    assert not row.passed and row.value < -0.1
    bodies = set(row.bodies or ())
    assert "world" in bodies  # the cube of [base], on the base link's body
    assert bodies & {"wrist_1_link", "wrist_2_link", "wrist_3_link", "ee_link"}
    assert [r.rule for r in report.failing] == ["clearance"]


def test_a_plan_to_the_ur5_s_pose_b_keeps_clear_of_its_meshes(ur5: RobotDescription) -> None:
    report = ur5.check_plan(_ptp(ur5, (20.0, -70.0, 100.0, -110.0, -90.0, 10.0)))
    assert report.passed, [r.describe() for r in report.failing]
    # a mesh pair is what is nearest (not only the capsules' stand-ins)
    assert report.row("self_clearance").bodies is not None
    assert report.row("clearance").value < 0.5


def test_the_panda_s_meshes_and_generated_contacts(tmp_path: Path) -> None:
    panda = load_robot(meshed_robot(tmp_path, "panda"))
    assert panda.collision is not None
    kinds = {b.name: [s.kind for s in b.shapes] for b in panda.collision.bodies}
    assert kinds["panda_link0"] == ["convex", "box"]  # its mesh, and the cube of [base]
    assert kinds["panda_link4"] == ["convex"]
    allowed = {frozenset(a.bodies) for a in panda.collision.allowed}
    assert frozenset({"panda_link0", "panda_link1"}) in allowed  # a joint's two sides
    assert frozenset({"panda_link0", "panda_link4"}) not in allowed
    # every visual mesh is reached, each body's on the joint that moves it
    by_link = {v.link: v for v in panda.visual_meshes}
    assert by_link["panda_leftfinger"].joint == 7 and by_link["panda_link3"].joint == 3
    assert set(panda.mesh_files) == {v.key for v in panda.visual_meshes}


def test_a_package_without_a_folder_is_refused_with_the_fix(tmp_path: Path) -> None:
    toml = meshed_robot(tmp_path, "ur5")
    toml.write_text(re.sub(r"\[packages\]\n.*\n", "", toml.read_text()))
    with pytest.raises(InvalidRobotDescription) as caught:
        load_robot(toml)
    message = str(caught.value)
    assert "package:// needs a ROS workspace" in message
    assert "'example-robot-data'" in message and "[packages]" in message
    assert "ur5/collision/base.stl" in message  # the element names the mesh


def test_a_mesh_over_the_size_limit_is_refused(tmp_path: Path) -> None:
    """A copy of the package's UR5 folder whose forearm visual is a sparse file one byte over
    the limit: refused by its size before anything is read."""
    root = tmp_path / "pkg"
    source = package_root("ur5") / "robots/ur_description"
    shutil.copytree(source / "meshes/ur5", root / "robots/ur_description/meshes/ur5")
    huge = root / "robots/ur_description/meshes/ur5/visual/forearm.dae"
    with huge.open("r+b") as f:
        f.truncate(MAX_FILE_BYTES + 1)
    toml = meshed_robot(tmp_path, "ur5", packages=str(root))
    with pytest.raises(InvalidRobotDescription) as caught:
        load_robot(toml)
    message = str(caught.value)
    assert "forearm.dae" in message
    assert f"{MAX_FILE_BYTES + 1} bytes, over the {MAX_FILE_BYTES} byte limit" in message


def test_a_package_path_may_not_leave_its_folder(tmp_path: Path) -> None:
    toml = meshed_robot(tmp_path, "ur5")
    urdf = toml.parent / "ur5_robot.urdf"
    urdf.write_text(
        urdf.read_text().replace(
            "package://example-robot-data/robots/ur_description/meshes/ur5/visual/base.dae",
            "package://example-robot-data/../../../../etc/passwd",
        )
    )
    with pytest.raises(InvalidRobotDescription, match="leaves the folder of package"):
        load_robot(toml)


def test_the_shipped_robots_name_no_mesh() -> None:
    """The wheel carries the shipped descriptions without any mesh file: none is needed."""
    for urdf in sorted(EXAMPLES_DIR.glob("*/*.urdf")):
        assert "<mesh" not in urdf.read_text(), urdf
    for toml in sorted(EXAMPLES_DIR.glob("*/*.toml")):
        robot = load_robot(toml)
        assert robot.visual_meshes == () and dict(robot.mesh_files) == {}
