"""The base attitude-control law (reaction wheels), shared by the prediction, the planners
that optimise against the closed loop and the spacecraft's onboard controller.

Modes (SPEC section 3): ``feedback`` holds a target attitude with the wheels;
``free_drift`` commands no wheel torque (the wheels keep their momentum). Either can carry
**momentum feedforward** (eq. 9, experiment 3b): the wheels take up the arm's commanded
reaction momentum ``h_arm = H~_bm phi'_cmd`` as it changes, so that an ideally tracking arm
leaves the base still. The **offset destination** (experiment 3c) is feedback with a target
that is not the nominal attitude.

The feedback is a PD law per base axis on the small-angle attitude error:
``torque_on_base = -kp * error - kd * omega_base``; the wheel motors apply the opposite
torque to the rotors. Sign convention of wheel torque: the motor torque on the rotor about its
axis (base frame); the base feels its negative.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from numpy.typing import NDArray

from planner.dynamics import DynamicsWorkspace
from planner.errors import InvalidInput

__all__ = [
    "AcsGains",
    "AcsMode",
    "arm_reaction_momentum_base_nms",
    "attitude_error_rad",
    "default_acs_gains",
    "momentum_feedforward_torque_nm",
    "wheel_torque_nm",
]

Array = NDArray[np.float64]

#: Our choice (SPEC 6): feedback bandwidth 0.05 rad/s, critically damped, so that a PTP
#: disturbance of about a degree settles in about 100 s; 0.3 N m torque and 20 N m s per
#: wheel. Calibrated against the flight results by the spacecraft's truth simulation.
DEFAULT_ACS_BANDWIDTH_RADPS = 0.05
DEFAULT_ACS_DAMPING_RATIO = 1.0
DEFAULT_WHEEL_TORQUE_LIMIT_NM = 0.3
DEFAULT_WHEEL_MOMENTUM_LIMIT_NMS = 20.0


class AcsMode(StrEnum):
    FEEDBACK = "feedback"
    FREE_DRIFT = "free_drift"


@dataclass(frozen=True, eq=False)
class AcsGains:
    kp_nm_per_rad: Array  # (3,), per base axis
    kd_nms_per_rad: Array  # (3,)
    torque_limit_nm: float
    momentum_limit_nms: float


def default_acs_gains(
    ws: DynamicsWorkspace,
    *,
    bandwidth_radps: float = DEFAULT_ACS_BANDWIDTH_RADPS,
    damping_ratio: float = DEFAULT_ACS_DAMPING_RATIO,
    torque_limit_nm: float = DEFAULT_WHEEL_TORQUE_LIMIT_NM,
    momentum_limit_nms: float = DEFAULT_WHEEL_MOMENTUM_LIMIT_NMS,
) -> AcsGains:
    """``kp = I wn^2``, ``kd = 2 zeta I wn`` with ``I`` the system's principal-axis
    inertia about its CoM (diagonal of H_c, base frame) at the reference pose."""
    inertia = np.diag(ws.momentum_blocks(np.zeros(ws.model.n_joints))[0])
    return AcsGains(
        kp_nm_per_rad=inertia * bandwidth_radps**2,
        kd_nms_per_rad=2.0 * damping_ratio * inertia * bandwidth_radps,
        torque_limit_nm=torque_limit_nm,
        momentum_limit_nms=momentum_limit_nms,
    )


def attitude_error_rad(quat_orbit_from_base_xyzw: Array, target_quat_xyzw: Array) -> Array:
    """Rotation vector of ``rot_target_from_base`` (rad; ~ the base-frame error).

    From the error quaternion ``conj(target) * q``, taking the short way round.
    """
    tx, ty, tz, tw = target_quat_xyzw
    x, y, z, w = quat_orbit_from_base_xyzw
    # conj(t) * q (Hamilton product, scalar last)
    ex = tw * x - tx * w - ty * z + tz * y
    ey = tw * y + tx * z - ty * w - tz * x
    ez = tw * z - tx * y + ty * x - tz * w
    ew = tw * w + tx * x + ty * y + tz * z
    if ew < 0.0:
        ex, ey, ez, ew = -ex, -ey, -ez, -ew
    s = math.sqrt(ex * ex + ey * ey + ez * ez)
    if s < 1e-12:
        return np.array([2.0 * ex, 2.0 * ey, 2.0 * ez])
    angle = 2.0 * math.atan2(s, ew)
    return np.array([ex, ey, ez]) * (angle / s)


def wheel_torque_nm(
    gains: AcsGains,
    mode: AcsMode,
    *,
    attitude_error: Array,
    omega_base_radps: Array,
    feedforward_nm: Array | None = None,
) -> Array:
    """Wheel motor torques (base frame, N m), saturated at the torque limit.

    ``omega_base_radps`` is the base rate in the base frame; ``feedforward_nm`` a wheel torque
    added in either mode (momentum feedforward).
    """
    torque = np.zeros(3)
    if mode is AcsMode.FEEDBACK:
        torque = gains.kp_nm_per_rad * attitude_error + gains.kd_nms_per_rad * omega_base_radps
    elif mode is not AcsMode.FREE_DRIFT:
        raise InvalidInput(f"unknown attitude-control mode {mode!r}")
    if feedforward_nm is not None:
        torque = torque + feedforward_nm
    return np.clip(torque, -gains.torque_limit_nm, gains.torque_limit_nm)


def arm_reaction_momentum_base_nms(
    ws: DynamicsWorkspace, joints_rad: Array, joint_rates_radps: Array
) -> Array:
    """``H~_bm phi'`` in the base frame (N m s): the momentum the arm's motion carries."""
    _, h_bm = ws.momentum_blocks(joints_rad)
    return np.asarray(h_bm @ joint_rates_radps)


def momentum_feedforward_torque_nm(
    ws: DynamicsWorkspace, command_times_s: Array, command_joints_rad: Array
) -> Array:
    """Wheel torque per command interval (k - 1, 3) that takes up the change of the arm's
    commanded reaction momentum (eq. 9), so that ``h_wheels = -h_arm``.

    Joint rates at the commands are central differences of the targets (one-sided at the
    ends); the torque on interval k is ``-(h_arm[k+1] - h_arm[k]) / dt``.
    """
    times = np.asarray(command_times_s, dtype=np.float64)
    joints = np.asarray(command_joints_rad, dtype=np.float64)
    if times.size < 2:
        return np.zeros((0, 3))
    rates = np.gradient(joints, times, axis=0)
    h_arm = np.array(
        [arm_reaction_momentum_base_nms(ws, q, r) for q, r in zip(joints, rates, strict=True)]
    )
    return np.asarray(-np.diff(h_arm, axis=0) / np.diff(times)[:, None])
