"""Loading descriptions from files: read (``files``), parse and check (``tables``,
``urdf_xml``), then build (``build``)."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

from planner.description.build import build_robot
from planner.description.collision_xml import mesh_filenames
from planner.description.files import (
    ETS7_DESCRIPTION,
    read_limited,
    read_mesh_points,
    read_toml,
    urdf_path_of,
)
from planner.description.tables import head_from, sensor_noise_from, servo_from
from planner.description.urdf_xml import Urdf
from planner.robot import RobotDescription, SensorNoiseSpec, ServoSpec

__all__ = ["VehicleTables", "default_robot", "load_robot", "load_vehicle_tables"]


def load_robot(path: str | Path) -> RobotDescription:
    """Load and validate the robot description at ``path`` (a TOML file; ``docs/robots.md``).

    Raises :class:`~planner.description.checks.InvalidRobotDescription` (an
    :class:`~planner.errors.InvalidInput`) for any fault, naming the file, the element and
    what is wrong.
    """
    toml_path = Path(path)
    c, doc = read_toml(toml_path, "description")
    head = head_from(c, doc, lambda urdf_name: urdf_path_of(c, toml_path, urdf_name))
    urdf = Urdf(head.urdf_path, read_limited(head.urdf_path, "URDF"))
    meshes = (
        {name: read_mesh_points(head.urdf_path, name) for name in mesh_filenames(urdf)}
        if doc.get("urdf_collision", True) is not False  # false: <collision> is not read
        else {}
    )
    return build_robot(c, doc, head, urdf, meshes)


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
