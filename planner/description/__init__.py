"""Robot description files, read at the planner's edge: any free-floating robot, with
ETS-VII as one example.

A description is a TOML file (format: ``docs/robots.md``) that names a URDF beside it for the
base and the arm, and adds what a URDF cannot say: which link is the free-floating base, the
reaction wheels, the attitude-control law's parameters, the joint servos, the sensor noise,
named poses and the experiments' default parameters.

    load_robot(path) -> RobotDescription      read, parse, check, build
    load_vehicle_tables(path, n)               a vehicle file's [servo] and [sensor_noise]
    load_acs_config(ws, path)                  an [acs] file's attitude-control law
    default_robot()                            ETS-VII's file, loaded once

The package is the only part of the planner that reads files, and the planner's core
imports nothing of it (an import contract in pyproject.toml says so). In order:

    files      size-limited bytes and the TOML document; where the URDF is
    tables     the TOML's tables checked into planner.robot's values
    urdf_xml   the URDF's XML parsed and checked as a tree
    reduce     the tree reduced to the model's bodies: fixed links and tool branches
               lumped, tool joints locked, reserved arm link names renamed, a mount
    vendor     a vendor URDF's keys: hand, [base], [locked_joints], [mission_limits]
    build      the pure build: parsed URDF -> RobotModel, everything -> RobotDescription
    hashing    the content hash (canonical TOML and URDF)
    checks     InvalidRobotDescription and the small validators every module uses

The loaded value, :class:`planner.robot.RobotDescription`, and what follows from it by
computation (the law, the servos, poses by IK) are the core's (``planner/robot.py``).

Every fault raises one :class:`InvalidRobotDescription` whose message names the file, the
element and what is wrong; nothing is cached or changed by a failing (or a passing) load.
"""

from planner.description.acs_file import load_acs_config
from planner.description.build import MIN_ARM_JOINTS
from planner.description.checks import InvalidRobotDescription
from planner.description.files import (
    ETS7_DESCRIPTION,
    EXAMPLES_DIR,
    MAX_FILE_BYTES,
    shipped_robots,
)
from planner.description.load import (
    VehicleTables,
    default_robot,
    load_robot,
    load_vehicle_tables,
)
from planner.robot import (
    NamedPose,
    RobotDescription,
    SensorNoiseSpec,
    ServoSpec,
    WheelLimits,
    servo_gains_of,
)

__all__ = [
    "ETS7_DESCRIPTION",
    "EXAMPLES_DIR",
    "MAX_FILE_BYTES",
    "MIN_ARM_JOINTS",
    "InvalidRobotDescription",
    "NamedPose",
    "RobotDescription",
    "SensorNoiseSpec",
    "ServoSpec",
    "VehicleTables",
    "WheelLimits",
    "default_robot",
    "load_acs_config",
    "load_robot",
    "load_vehicle_tables",
    "servo_gains_of",
    "shipped_robots",
]
