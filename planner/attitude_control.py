"""The base attitude-control law (reaction wheels), shared by the prediction, the planners
that optimise against the closed loop and the spacecraft's onboard controller.

Modes (SPEC section 3): ``feedback`` holds a target attitude with the wheels;
``free_drift`` commands no wheel torque (the wheels keep their momentum). The **offset
destination** (experiment 3c) is feedback with a target that is not the nominal attitude.

The feedback is a PD law per base axis on the small-angle attitude error ``e`` and the base
rate ``w`` (base frame)::

    torque_on_base = -kp * e - kd * (w - w_ref),   w_ref = -w_ff   (feedforward on)
    w_ff = -H~_b^-1 H~_bm phi'_cmd                                  eq. (9)

and the wheel motors apply the opposite torque to the rotors (sign convention: the motor
torque on each rotor about its axis, base frame; the base feels its negative).

**Feedforward** is the flight's *angular-velocity-type feedforward* (paper section 2.4,
角速度型フィードフォワード: Yoshida's idea, implemented on ETS-VII by Oda): the reaction rate
``w_ff`` that eq. (9) predicts from the *commanded* arm motion is fed into the rate loop, whose
reference becomes the cancelling rate ``-w_ff``. The gyro measures the total rate, reaction
included, so during the motion the loop drives the base past still, toward ``-w_ff``, and
leans it against the reaction; when the arm decelerates, its reaction adds to that recovery.
This reproduces what the flight saw in experiment 3b (paper section 3.5, Fig. 9): a fast
first response, then a strong overshoot the other way. (An *ideal* momentum feedforward,
wheels taking up ``H~_bm phi'`` exactly, would leave the base still and beat feedback, which
the flight did not show; the paper calls the flight's method counter-productive for this
motion.) In ``free_drift`` the feedforward does nothing: there is no rate loop to feed.
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
    "attitude_error_rad",
    "default_acs_gains",
    "reaction_rate_radps",
    "wheel_torque_nm",
]

Array = NDArray[np.float64]

#: Our choice (SPEC 6), calibrated against the flight by the spacecraft's truth simulation
#: (docs/spacecraft.md): feedback bandwidth 0.04 rad/s with damping ratio 0.7, so that the
#: PTP A -> B disturbance settles (0.02 deg band) about 100 s after the motion; 0.3 N m and
#: 20 N m s per wheel (the PTP needs at most 0.16 N m and 3 N m s, so neither limit shapes
#: the calibrated responses).
DEFAULT_ACS_BANDWIDTH_RADPS = 0.04
DEFAULT_ACS_DAMPING_RATIO = 0.7
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
    reaction_rate_radps: Array | None = None,
) -> Array:
    """Wheel motor torques (base frame, N m), saturated at the torque limit.

    ``omega_base_radps`` is the (measured) base rate in the base frame;
    ``reaction_rate_radps`` the eq. (9) reaction rate of the commanded arm motion
    (:func:`reaction_rate_radps`) when feedforward is on: the rate loop then tracks its
    negative (see the module docstring). Free drift gives zero torque.
    """
    if mode is AcsMode.FREE_DRIFT:
        return np.zeros(3)
    if mode is not AcsMode.FEEDBACK:
        raise InvalidInput(f"unknown attitude-control mode {mode!r}")
    rate_error = np.asarray(omega_base_radps, dtype=np.float64)
    if reaction_rate_radps is not None:
        rate_error = rate_error + reaction_rate_radps  # w - w_ref with w_ref = -w_ff
    torque = gains.kp_nm_per_rad * attitude_error + gains.kd_nms_per_rad * rate_error
    return np.clip(torque, -gains.torque_limit_nm, gains.torque_limit_nm)


def reaction_rate_radps(
    ws: DynamicsWorkspace, joints_rad: Array, joint_rates_radps: Array
) -> Array:
    """Eq. (9) in the base frame, ``w_ff = -H~_b^-1 H~_bm phi'`` (rad/s): the base rate that
    the arm's motion at ``phi'`` causes at zero momentum. Fed the *commanded* joints and
    rates, it is the feedforward signal of :func:`wheel_torque_nm`."""
    h_b, h_bm = ws.momentum_blocks(joints_rad)
    return np.asarray(-np.linalg.solve(h_b, h_bm @ joint_rates_radps))
