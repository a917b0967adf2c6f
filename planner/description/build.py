"""The pure build: a parsed, checked URDF and the wheels into a RobotModel, and a parsed
description (TOML document and URDF) into a RobotDescription. No file is read here.

The URDF is read into :class:`~planner.model.RobotModel`'s frames (``planner/model.py``):

- the *base frame* has the base link's axes and its origin at the base link's centre of mass
  (the ``<inertial>`` origin); the base inertia is turned into those axes;
- the *robot frame* has the base frame's axes and its origin on the first arm joint;
- everything else (joint points and axes, link CoMs and inertias, the hand point) is expressed
  in the robot frame at the all-zero pose, whatever rotations the URDF's origins carry;
- the hand frame must be parallel to the base frame at the all-zero pose (the planners and
  the MuJoCo model take it so).

Where the URDF's origins carry no rotation (ETS-VII's file) the numbers pass through without
a single rounding: sums of the origins' offsets only, so the model loaded from
``examples/robots/ets7`` equals :func:`planner.model.default_model` to the last bit.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.collision import AllowedContact, CollisionModel
from planner.collision_segments import generated_contacts, segment_collision_model
from planner.description.checks import Checker, InvalidRobotDescription, frozen
from planner.description.collision_xml import (
    collision_model_from,
    flight_rules_from,
    visual_meshes_from,
)
from planner.description.hashing import content_sha256
from planner.description.reduce import CONTINUOUS_LIMIT_RAD, Mount, Reduction, reduce_tree
from planner.description.tables import (
    Header,
    experiments_from,
    limits_from,
    poses_from,
    sensor_noise_from,
    servo_from,
)
from planner.description.urdf_xml import Frame, Urdf
from planner.description.vendor import locked_from, mission_limits_from, mount_from
from planner.dynamics import DynamicsWorkspace
from planner.errors import InvalidInput
from planner.flight_rules import FlightRules
from planner.meshes import mesh_key
from planner.model import LinkSpec, RobotModel, WheelSpec, base_body_inertial
from planner.robot import NamedPose, RobotDescription, ServoSpec, servo_gains_of
from planner.servo_check import servo_modes

__all__ = [
    "CONTINUOUS_LIMIT_RAD",
    "HAND",
    "MIN_ARM_JOINTS",
    "build_robot",
    "model_from_urdf",
]

#: A reaction null space (n - 3 dimensions) needs at least 4 arm joints.
MIN_ARM_JOINTS = 4
#: The hand frame's link where a description names none.
HAND = "hand"

Array = NDArray[np.float64]


def model_from_urdf(
    urdf: Urdf,
    base_link: str,
    wheels: tuple[WheelSpec, ...],
    *,
    hand: str = HAND,
    locked: Mapping[str, float] | None = None,
    mount: Mount | None = None,
) -> tuple[RobotModel, Reduction]:
    """The model of the checked tree (:func:`planner.description.reduce.reduce_tree`) with the
    vendor's joint limits, and the reduction it came from."""
    c = urdf.c
    red = reduce_tree(urdf, base_link, hand, locked or {}, mount)
    if len(red.arm) < MIN_ARM_JOINTS:
        raise c.fail(
            f"link {hand!r}",
            f"the chain from {base_link!r} has {len(red.arm)} arm joint(s); at least "
            f"{MIN_ARM_JOINTS} are needed for a reaction null space (n - 3 > 0)",
        )
    base = red.base
    base_inertia = Frame(base.rot, np.zeros(3)).rotate_tensor(base.inertia_kgm2)
    links = []
    for k, arm_body in enumerate(red.arm):
        links.append(
            LinkSpec(
                name=red.link_names[k],
                joint_pos_robot_m=frozen(red.joint_pos_robot_m[k]),
                joint_axis_robot=frozen(red.joint_axis_robot[k]),
                mass_kg=arm_body.mass_kg,
                com_robot_m=frozen(arm_body.com_m),
                inertia_com_inertia_frame_kgm2=frozen(arm_body.inertia_kgm2),
                rot_robot_from_inertia=frozen(np.eye(3) if arm_body.rot is None else arm_body.rot),
            )
        )
    model = RobotModel(
        base_mass_kg=base.mass_kg,
        base_inertia_kgm2=frozen(base_inertia),
        pos_base_from_robot_m=frozen(red.pos_j1_m - base.com_m),
        links=tuple(links),
        hand_pos_robot_m=frozen(red.hand_pos_robot_m),
        wheels=wheels,
        joint_limit_rad=frozen(red.vendor_limit_rad),
        joint_rate_limit_radps=frozen(red.vendor_rate_radps),
        rot_robot_from_hand=(
            None if red.rot_robot_from_hand is None else frozen(red.rot_robot_from_hand)
        ),
    )
    return model, red


def build_robot(
    c: Checker,
    doc: Mapping[str, Any],
    head: Header,
    urdf: Urdf,
    meshes: Mapping[str, Array] | None = None,
    visual_files: Mapping[str, Path] | None = None,
) -> RobotDescription:
    """The description from its parsed TOML document (``head`` already checked) and its
    parsed URDF (``meshes``: the points of every mesh its ``<collision>`` names, read;
    ``visual_files``: the files of the ``<visual>`` meshes that were found, by filename); ``c``
    names the TOML file and ``head.urdf_path`` the URDF in messages. Reads no file:
    :func:`planner.description.load_robot` has read them."""
    urdf_path = head.urdf_path
    urdf.check_tree(head.base_link)
    hand = c.text("hand", doc.get("hand", HAND))
    model, red = model_from_urdf(
        urdf,
        head.base_link,
        head.wheels,
        hand=hand,
        locked=locked_from(c, doc.get("locked_joints", {}), urdf),
        mount=(mount := mount_from(c, doc.get("base"))),
    )
    mission_limit, mission_rate = mission_limits_from(
        c,
        doc.get("mission_limits", {}),
        red.joint_names,
        red.vendor_limit_rad,
        red.vendor_rate_radps,
    )
    model = replace(
        model, joint_limit_rad=frozen(mission_limit), joint_rate_limit_radps=frozen(mission_rate)
    )
    rules, allowed = flight_rules_from(c, doc.get("flight_rules", {}))
    urdf_collision = doc.get("urdf_collision", True)
    if not isinstance(urdf_collision, bool):
        raise c.fail("urdf_collision", f"must be true or false, got {urdf_collision!r}")
    collision = (
        collision_model_from(
            urdf,
            head.base_link,
            list(red.joint_names),
            urdf.link_ref(urdf.joints[red.joint_names[0]], "child"),
            allowed,
            meshes or {},
            c,
            # the tree's own frames unless loading moved something (a mount, a locked
            # tool): ETS-VII's shapes keep their numbers to the last bit
            frames=red.frames if mount is not None or red.locked else None,
            mount_box=None if mount is None else (mount.size_m, -red.pos_j1_m),
        )
        if urdf_collision
        else None
    )
    first_link = urdf.link_ref(urdf.joints[red.joint_names[0]], "child")
    keys = {name: mesh_key(k, name) for k, name in enumerate(visual_files or {})}
    visuals = visual_meshes_from(
        urdf,
        head.base_link,
        list(red.joint_names),
        first_link,
        keys,
        frames=red.frames if mount is not None or red.locked else None,
    )

    rotor_mass, rotor_free_inertia = base_body_inertial(model)
    if rotor_mass <= 0.0 or float(np.linalg.eigvalsh(rotor_free_inertia)[0]) <= 0.0:
        raise c.fail(
            "[[wheels]]",
            "the rotors (mass, thin-disc inertia) must fit inside the base link's mass and "
            "inertia: the base less its rotors is not a positive mass with positive definite "
            "inertia",
        )
    try:
        ws = DynamicsWorkspace(model)
    except (ValueError, RuntimeError) as exc:  # MuJoCo's compiler refuses it
        raise InvalidRobotDescription(urdf_path, "model", f"MuJoCo refuses it: {exc}") from None

    acs = c.table("[acs]", doc.get("acs", {}))
    for key in ("torque_limit_nm", "momentum_limit_nms"):
        if key in acs:
            raise c.fail(f"[acs] {key}", "set the wheels' limits on each [[wheels]] entry")
    poses = poses_from(c, doc.get("poses", {}), ws)
    model = _with_reference(c, doc, model, red, poses)
    ws = DynamicsWorkspace(model)
    box = mount.size_m if mount is not None else urdf.box_size(head.base_link)
    generate = c.table("[flight_rules]", doc.get("flight_rules", {})).get(
        "generated_allowed_contact", False
    )
    if not isinstance(generate, bool):
        raise c.fail(
            "[flight_rules] generated_allowed_contact", f"must be true or false, got {generate!r}"
        )
    if generate:
        if collision is None:
            raise c.fail(
                "[flight_rules] generated_allowed_contact",
                "the URDF's <collision> shapes are not read (urdf_collision = false, or none)",
            )
        try:
            collision = generated_contacts(model, collision, rules.min_clearance_m)
        except InvalidInput as exc:
            raise c.fail("[flight_rules] generated_allowed_contact", str(exc)) from None
    if "generated_collision" in doc:
        if urdf_collision:
            raise c.fail(
                "[generated_collision]",
                "generates the collision bodies in place of the URDF's: set urdf_collision = "
                "false with it",
            )
        collision = _generated_collision(
            c, doc["generated_collision"], model, head.base_link, box, red, rules, allowed
        )
    servo = servo_from(c, doc.get("servo", {}), model.n_joints)
    _check_servos(c, ws, servo, poses)
    description = RobotDescription(
        name=head.name,
        description=c.text("description", doc.get("description", "")),
        path=c.path,
        urdf_path=urdf_path,
        content_sha256=content_sha256(doc, urdf.root),
        base_link=head.base_link,
        model=model,
        wheel_limits=head.wheel_limits,
        acs_config=MappingProxyType(dict(acs)),
        servo=servo,
        sensor_noise=sensor_noise_from(c, doc.get("sensor_noise", {})),
        poses=MappingProxyType(poses),
        experiments=MappingProxyType(
            experiments_from(c, doc.get("experiments", {}), model.n_joints)
        ),
        base_box_size_m=box,
        collision=collision,
        flight_rules=rules,
        limits=limits_from(c, doc.get("limits", {})),
        vendor_joint_limit_rad=frozen(red.vendor_limit_rad),
        vendor_joint_rate_limit_radps=frozen(red.vendor_rate_radps),
        joint_names=red.joint_names,
        hand_link=hand,
        reference_pose=doc.get("reference_pose"),
        lumped=red.lumped,
        locked=red.locked,
        renamed=red.renamed,
        visual_meshes=visuals,
        mesh_files=MappingProxyType(
            {keys[name]: path for name, path in (visual_files or {}).items()}
        ),
    )
    try:
        description.acs_gains(ws)
    except InvalidInput as exc:
        raise c.fail("[acs]", str(exc)) from None
    return description


def _with_reference(
    c: Checker,
    doc: Mapping[str, Any],
    model: RobotModel,
    red: Reduction,
    poses: Mapping[str, NamedPose],
) -> RobotModel:
    """The model with its reference pose: the description's ``reference_pose`` (a named pose
    with joints inside the limits), or all zeros, which every joint's limits must then hold."""
    if "reference_pose" not in doc:
        for i, (lo, hi) in enumerate(model.joint_limit_rad):
            if not lo <= 0.0 <= hi:
                raise c.fail(
                    f"joint {red.joint_names[i]!r} <limit>",
                    f"[{math.degrees(lo):.6g}, {math.degrees(hi):.6g}] deg excludes 0: name a "
                    "pose inside every joint's limits as the description's reference_pose "
                    "(the planners' reference, all zeros otherwise)",
                )
        return model
    name = c.text("reference_pose", doc["reference_pose"])
    pose = poses.get(name)
    if pose is None or pose.joints_rad is None:
        raise c.fail(
            "reference_pose",
            f"{name!r} must be a pose of [poses] with joints_deg (poses: {sorted(poses)})",
        )
    return replace(model, reference_joints_rad=frozen(pose.joints_rad))


def _check_servos(
    c: Checker, ws: DynamicsWorkspace, servo: ServoSpec, poses: Mapping[str, NamedPose]
) -> None:
    """Refuse servos whose fastest mode at the reference or a named pose the simulator's
    integrator cannot hold (:mod:`planner.servo_check`), proposing the damping that fits."""
    try:
        gains = servo_gains_of(servo, ws.model)
    except InvalidInput as exc:
        raise c.fail("[servo]", str(exc)) from None
    flown = {name: p.joints_rad for name, p in poses.items() if p.joints_rad is not None}
    modes = servo_modes(ws, gains, poses=flown, samples=0)
    if modes.stable:
        return
    scale = 0.9 * modes.limit_per_s / modes.fastest_per_s  # kd scales every mode linearly
    if servo.kd_nms_per_rad is not None:
        kd = np.asarray(servo.kd_nms_per_rad) * scale
        proposal = "kd_nms_per_rad = [" + ", ".join(f"{v:.4g}" for v in kd) + "]"
    else:
        lag = np.atleast_1d(np.asarray(servo.lag_s, dtype=np.float64)) * scale
        proposal = (
            f"lag_s = {lag[0]:.3g}"
            if lag.size == 1
            else "lag_s = [" + ", ".join(f"{v:.3g}" for v in lag) + "]"
        )
    raise c.fail(
        "[servo]",
        f"{modes.describe()}: the simulation would diverge; lower the damping, e.g. "
        f"{proposal} (a smaller bandwidth_radps lowers kp and kd together)",
    )


def _generated_collision(
    c: Checker,
    value: object,
    model: RobotModel,
    base_link: str,
    box: tuple[float, float, float] | None,
    red: Reduction,
    rules: FlightRules,
    allowed: tuple[AllowedContact, ...],
) -> CollisionModel:
    """``[generated_collision]``: capsules along the links, a hand sphere and the base box
    (:mod:`planner.collision_segments`)."""
    table = c.table("[generated_collision]", value)
    c.keys("[generated_collision]", table, frozenset({"radius_m", "hand_radius_m"}))
    radius = c.number("[generated_collision] radius_m", table.get("radius_m", 0.06), positive=True)
    hand = c.number(
        "[generated_collision] hand_radius_m", table.get("hand_radius_m", 0.08), positive=True
    )
    try:
        return segment_collision_model(
            model,
            base_name=base_link,
            radius_m=radius,
            hand_radius_m=hand,
            clearance_m=rules.min_clearance_m,
            base_box_size_m=box,
            base_box_centre_robot_m=None if box is None else -red.pos_j1_m,
            allowed=allowed,
        )
    except InvalidInput as exc:
        raise c.fail("[[flight_rules.allowed_contact]]", str(exc)) from None
