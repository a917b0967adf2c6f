"""Loading descriptions from files: read (``files``), parse and check (``tables``,
``urdf_xml``), then build (``build``)."""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from planner.description.build import build_robot
from planner.description.checks import InvalidRobotDescription
from planner.description.collision_xml import mesh_filenames
from planner.description.files import (
    ETS7_DESCRIPTION,
    MAX_MESHES_BYTES,
    mesh_path,
    packages_from,
    read_limited,
    read_limited_size,
    read_mesh_points,
    read_toml,
    shipped_robots,
    urdf_path_of,
)
from planner.description.tables import head_from, sensor_noise_from, servo_from
from planner.description.urdf_xml import Urdf
from planner.meshes import MESH_MEDIA_TYPES, mesh_media_type
from planner.robot import RobotDescription, SensorNoiseSpec, ServoSpec

__all__ = ["VehicleTables", "default_robot", "load_robot", "load_vehicle_tables"]


def _named(path: Path) -> Path:
    """``path``, or, when it names no file and is a bare name (no folder, no suffix), the
    shipped robot of that name; a bare name that is neither is refused naming them."""
    if path.exists() or path.parent != Path(".") or path.suffix:
        return path
    shipped = shipped_robots()
    if str(path) in shipped:
        return shipped[str(path)]
    known = ", ".join(shipped) or "none here"
    raise InvalidRobotDescription(
        path, "description", f"no such file, nor a shipped robot of that name ({known})"
    )


def load_robot(path: str | Path) -> RobotDescription:
    """Load and validate the robot description at ``path`` (a TOML file; ``docs/robots.md``),
    or of the shipped robot ``path`` names (``ets7``, ``orihime``: :func:`shipped_robots`).

    Raises :class:`~planner.description.checks.InvalidRobotDescription` (an
    :class:`~planner.errors.InvalidInput`) for any fault, naming the file, the element and
    what is wrong.
    """
    toml_path = _named(Path(path))
    c, doc = read_toml(toml_path, "description")
    head = head_from(c, doc, lambda urdf_name: urdf_path_of(c, toml_path, urdf_name))
    urdf = Urdf(head.urdf_path, read_limited(head.urdf_path, "URDF"))
    packages = packages_from(c, toml_path, doc.get("packages", {}))
    collision_names = (
        mesh_filenames(urdf)
        if doc.get("urdf_collision", True) is not False  # false: <collision> is not read
        else []
    )
    visual_files = _visual_files(head.urdf_path, urdf, packages)
    sizes = {path.resolve(): path.stat().st_size for path in visual_files.values()}
    meshes = {}
    for name in collision_names:
        meshes[name] = read_mesh_points(head.urdf_path, name, packages)
        found = mesh_path(head.urdf_path, name, packages, "<collision> <mesh>")
        assert found is not None  # read_mesh_points refuses an unknown package
        sizes[found.resolve()] = found.stat().st_size
    total = sum(sizes.values())
    if total > MAX_MESHES_BYTES:
        raise InvalidRobotDescription(
            head.urdf_path,
            "<mesh>",
            f"the {len(sizes)} mesh files it names are {total} bytes together, over the "
            f"{MAX_MESHES_BYTES} byte limit of one robot's meshes",
        )
    return build_robot(c, doc, head, urdf, meshes, visual_files)


def _visual_files(urdf_path: Path, urdf: Urdf, packages: Mapping[str, Path]) -> dict[str, Path]:
    """The file of every ``<visual>`` mesh the description reaches, by filename, each
    size-limited (a ``package://`` mesh whose folder ``[packages]`` does not give is left to
    the primitives); a reachable file that is missing or too large is refused."""
    out: dict[str, Path] = {}
    for name in mesh_filenames(urdf, "visual"):
        where = f"<visual> <mesh filename={name!r}>"
        path = mesh_path(urdf_path, name, packages, where)
        if path is None:
            continue
        if mesh_media_type(name) is None:
            raise InvalidRobotDescription(
                urdf_path, where, f"not a mesh viewers draw: {sorted(MESH_MEDIA_TYPES)}"
            )
        try:
            read_limited_size(path, "mesh")
        except InvalidRobotDescription as exc:
            raise InvalidRobotDescription(urdf_path, where, exc.problem) from None
        out[name] = path
    return out


@functools.cache
def default_robot() -> RobotDescription:
    """ETS-VII's description (``ETS7_DESCRIPTION``), loaded once. The planners do not need
    it (given no robot they plan on ``planner.model.default_model()``, the same numbers);
    it is the file's description for callers that want one."""
    return load_robot(ETS7_DESCRIPTION)


@dataclass(frozen=True)
class VehicleTables:
    """A vehicle file's ``[servo]`` and ``[sensor_noise]`` (``None`` where absent)."""

    servo: ServoSpec | None
    sensor_noise: SensorNoiseSpec | None


def load_vehicle_tables(path: str | Path, n_joints: int) -> VehicleTables:
    """The ``[servo]`` and ``[sensor_noise]`` tables of a TOML file (``hikoboshi calibrate
    --vehicle-out`` writes one; ``hikoboshi spacecraft --vehicle-config`` reads it), checked
    as a robot description's for an arm of ``n_joints``; any other table is refused. Every
    fault raises one :class:`~planner.description.checks.InvalidRobotDescription`."""
    c, doc = read_toml(Path(path), "vehicle configuration")
    c.keys("document", doc, frozenset({"servo", "sensor_noise"}))
    if not doc:
        raise c.fail("document", "give a [servo] or a [sensor_noise] table")
    return VehicleTables(
        servo=servo_from(c, doc["servo"], n_joints) if "servo" in doc else None,
        sensor_noise=sensor_noise_from(c, doc["sensor_noise"]) if "sensor_noise" in doc else None,
    )
