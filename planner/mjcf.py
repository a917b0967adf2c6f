"""MuJoCo model generated from the canonical :class:`~planner.model.RobotModel`.

Free base, zero gravity, RK4, contacts off (collisions are checked before uplink, by
planner.flight_rules on the description's shapes, not by the engine). Body frames follow
:mod:`planner.model`: each link body has its origin on its joint and is parallel to the
robot frame at the all-zero pose.

Joint servos, when asked for, are MuJoCo ``intvelocity`` actuators plus joint damping: the
actuator's activation is the position target, its control the target's rate, so a target
that moves linearly between 4 Hz commands is integrated inside MuJoCo and many steps run in
one ``mj_step(nstep=...)`` call. The servo is a PD law ``kp (target - q) - kd q'``; without
rate feed-forward the measured angle lags a ramp by ``kd / kp * rate`` (SPEC section 6).
The actuator's activation range is the joint range, so targets beyond a limit saturate.

Table 1's inertias of links 1-3 break the triangle inequality (link 1: 0.25 + 0.25 < 1.69
kg m^2), which MuJoCo's compiler refuses. They are the identified flight values and the
dynamics stay well defined (the matrices are positive definite), so :func:`compile_model`
compiles with ``balanceinertia`` and then writes the exact principal inertias back into the
compiled model. The document from :func:`mjcf_xml` carries the exact numbers and the
``balanceinertia`` flag, so other MuJoCo tools load it with those three links adjusted.
"""

from __future__ import annotations

from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

import mujoco
import numpy as np
from numpy.typing import NDArray

from planner.frames import quat_xyzw_from_matrix
from planner.model import RobotModel, base_body_inertial
from planner.mujoco_conventions import quat_wxyz_from_xyzw

__all__ = ["MjcfOptions", "ServoGains", "compile_model", "mjcf_xml"]

Array = NDArray[np.float64]

_MIN_SEGMENT_M = 1e-6  # MuJoCo refuses a capsule whose ends are closer


@dataclass(frozen=True, eq=False)
class ServoGains:
    """PD gains per joint: ``kp`` in N m/rad, ``kd`` in N m s/rad."""

    kp_nm_per_rad: Array
    kd_nms_per_rad: Array


@dataclass(frozen=True, eq=False)
class MjcfOptions:
    timestep_s: float = 0.01
    integrator: str = "RK4"
    servo: ServoGains | None = None
    wheel_torque_limit_nm: float | None = None


def _vec(a: Array) -> str:
    return " ".join(repr(float(x)) for x in a)


def _full_inertia(inertia: Array) -> str:
    i = inertia
    return _vec(np.array([i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2]]))


def _link_geom(indent: str, segment_m: Array) -> str:
    """A capsule from the joint to the next joint; a sphere where they coincide (a wrist)."""
    if float(np.linalg.norm(segment_m)) < _MIN_SEGMENT_M:
        return f'{indent}<geom type="sphere" size="0.06"/>'
    return f'{indent}<geom type="capsule" size="0.06" fromto="0 0 0 {_vec(segment_m)}"/>'


def mjcf_xml(model: RobotModel, options: MjcfOptions | None = None, *, name: str = "ets7") -> str:
    """The MJCF document of ``model``, named ``name``."""
    opt = options or MjcfOptions()
    base_mass, base_inertia = base_body_inertial(model)
    lines = [
        f"<mujoco model={quoteattr(name)}>",
        '  <compiler angle="radian" autolimits="true" balanceinertia="true"/>',
        f'  <option gravity="0 0 0" integrator={quoteattr(opt.integrator)}'
        f' timestep="{opt.timestep_s:.12g}">',
        '    <flag contact="disable"/>',
        "  </option>",
        '  <default><geom contype="0" conaffinity="0" rgba="0.8 0.8 0.85 1"/></default>',
        "  <worldbody>",
        '    <body name="base" pos="0 0 0">',
        '      <freejoint name="base_free"/>',
        f'      <inertial pos="0 0 0" mass="{base_mass:.12g}"'
        f' fullinertia="{_full_inertia(base_inertia)}"/>',
        '      <geom name="base_box" type="box" size="1.2 1.0 1.0" rgba="0.85 0.7 0.3 1"/>',
        f'      <site name="robot_origin" pos="{_vec(model.pos_base_from_robot_m)}"/>',
    ]
    parent_pos = -model.pos_base_from_robot_m  # so that link1's pos = robot origin + joint 1
    indent = "      "
    for i, link in enumerate(model.links):
        lo, hi = model.joint_limit_rad[i]
        damping = 0.0 if opt.servo is None else float(opt.servo.kd_nms_per_rad[i])
        end = (
            model.links[i + 1].joint_pos_robot_m
            if i + 1 < model.n_joints
            else (model.hand_pos_robot_m)
        )
        lines += [
            f'{indent}<body name="{link.name}" pos="{_vec(link.joint_pos_robot_m - parent_pos)}">',
            f'{indent}  <joint name="joint{i + 1}" type="hinge"'
            f' axis="{_vec(link.joint_axis_robot)}" range="{lo:.12g} {hi:.12g}"'
            f' damping="{damping:.12g}"/>',
            f'{indent}  <inertial pos="{_vec(link.com_robot_m - link.joint_pos_robot_m)}"'
            f' mass="{link.mass_kg!r}"'
            f' fullinertia="{_full_inertia(link.inertia_com_robot_kgm2)}"/>',
            _link_geom(indent + "  ", end - link.joint_pos_robot_m),
        ]
        parent_pos = link.joint_pos_robot_m
        indent += "  "
    hand_pos = _vec(model.hand_pos_robot_m - parent_pos)
    if model.rot_robot_from_hand is None:
        lines.append(f'{indent}<site name="hand" pos="{hand_pos}"/>')
    else:
        quat = quat_wxyz_from_xyzw(quat_xyzw_from_matrix(model.rot_robot_from_hand))
        lines.append(f'{indent}<site name="hand" pos="{hand_pos}" quat="{_vec(quat)}"/>')
    for _ in model.links:
        indent = indent[:-2]
        lines.append(f"{indent}</body>")
    # Wheels after the arm, so qvel is (base, joints, wheels) as in planner.state.
    for wheel in model.wheels:
        lines += [
            f'      <body name="{wheel.name}" pos="0 0 0">',
            f'        <joint name="{wheel.name}" type="hinge" axis="{_vec(wheel.axis_base)}"/>',
            f'        <inertial pos="0 0 0" mass="{wheel.mass_kg:.12g}"'
            f' fullinertia="{_full_inertia(wheel.rigid_inertia_base_kgm2)}"/>',
            "      </body>",
        ]
    lines += ["    </body>", "  </worldbody>", "  <actuator>"]
    if opt.servo is not None:
        for i in range(model.n_joints):
            lo, hi = model.joint_limit_rad[i]
            lines.append(
                f'    <intvelocity name="servo{i + 1}" joint="joint{i + 1}"'
                f' kp="{float(opt.servo.kp_nm_per_rad[i]):.12g}" actrange="{lo:.12g} {hi:.12g}"/>'
            )
    for wheel in model.wheels:
        limit = (
            ""
            if opt.wheel_torque_limit_nm is None
            else f' ctrlrange="{-opt.wheel_torque_limit_nm:.12g} {opt.wheel_torque_limit_nm:.12g}"'
        )
        lines.append(f'    <motor name="{wheel.name}" joint="{wheel.name}"{limit}/>')
    lines += ["  </actuator>", "</mujoco>"]
    return "\n".join(lines) + "\n"


def _principal(inertia: Array) -> tuple[Array, Array]:
    """Principal moments and the scalar-first quaternion of body-from-principal axes."""
    moments, axes = np.linalg.eigh(inertia)
    if np.linalg.det(axes) < 0.0:
        axes[:, 0] = -axes[:, 0]
    quat_wxyz = np.zeros(4)
    mujoco.mju_mat2Quat(quat_wxyz, np.ascontiguousarray(axes).ravel())
    return moments, quat_wxyz


def compile_model(model: RobotModel, options: MjcfOptions | None = None) -> mujoco.MjModel:
    """Compile ``model`` into a MuJoCo model with Table 1's inertias exactly."""
    mjm = mujoco.MjModel.from_xml_string(mjcf_xml(model, options))
    exact = [(link.name, link.inertia_com_robot_kgm2) for link in model.links]
    exact.append(("base", base_body_inertial(model)[1]))
    for name, inertia in exact:
        body = mujoco.mj_name2id(mjm, mujoco.mjtObj.mjOBJ_BODY, name)
        mjm.body_inertia[body], mjm.body_iquat[body] = _principal(inertia)
    mujoco.mj_setConst(mjm, mujoco.MjData(mjm))
    return mjm
