"""A scaffold's hardware numbers a URDF does not give (``hikoboshi robot init``,
:mod:`planner.description.scaffold`):

- **mission limits** inside the vendor's: each joint's range shrunk by
  :data:`LIMIT_MARGIN_DEG` and cut to +-:data:`MAX_MISSION_DEG` (no wrap-around), where that
  leaves a range; every joint at :data:`MISSION_RATE_DEGPS` or the vendor's rate if slower
  (a space arm's rates, not a factory arm's; :func:`mission_limits`);
- **servos** that the integrator holds: the fastest servo mode (:mod:`planner.servo_check`)
  is linear in ``lag * bandwidth^2``, so it is computed once at unit gains over the poses
  and the seeded samples and the bandwidth and lag chosen so that it stays under
  :data:`SERVO_MARGIN` of the bound, keeping the damping ratio at the reference at least
  :data:`SERVO_DAMPING` while the lag stays under :data:`MAX_SERVO_LAG_S`
  (:func:`servo_design`);
- **wheels** sized from the arm's reaction momentum: the bound
  ``max |H~_bm| |phi'_max|`` (operator norm over the sampled poses, every joint at its
  mission rate), times :data:`WHEEL_MARGIN`; the torque limit fills that capacity in
  :data:`WHEEL_FILL_S` (the shipped robots' ratio), the rotors spin at
  :data:`WHEEL_SPEED_RADPS` at capacity (:func:`wheel_sizing`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from planner.dynamics import DynamicsWorkspace
from planner.model import RobotModel
from planner.ptp import ptp_commands
from planner.servo_check import ServoModes, servo_modes
from planner.simulation import default_servo_gains
from planner.state import State

__all__ = ["Wheels", "mission_limits", "servo_design", "wheel_sizing"]

Array = NDArray[np.float64]

#: Mission limits: the vendor's range less this on each side, inside +-MAX_MISSION_DEG.
LIMIT_MARGIN_DEG = 5.0
MAX_MISSION_DEG = 175.0
#: The planners' joint rate (ETS-VII's limit, SPEC 7), or the vendor's if slower.
MISSION_RATE_DEGPS = 3.0
#: Servos: the bound's fraction the fastest mode may reach, the damping ratio kept at the
#: reference, the largest lag (tracking error = lag x rate: 1.5 deg at 3 deg/s, under the
#: default live limits' 2.25 deg watch band) and bandwidth.
SERVO_MARGIN = 0.8
SERVO_DAMPING = 0.6
MAX_SERVO_LAG_S = 0.5
MAX_SERVO_BANDWIDTH_RADPS = 4.0
#: Wheels: capacity over the reaction-momentum bound, seconds to fill it at the torque limit
#: (ETS-VII 20 N m s / 0.3 N m = 67 s, Orihime 12 / 0.2 = 60 s), rotor speed at capacity
#: (Orihime's, 2292 rpm) and radius (thin disc).
WHEEL_MARGIN = 2.5
WHEEL_FILL_S = 60.0
WHEEL_SPEED_RADPS = 240.0
WHEEL_RADIUS_M = 0.15


def mission_limits(vendor: Array, vendor_rate: Array) -> tuple[Array, Array]:
    """The mission limits (rad, ``(n, 2)``) and rates (rad/s) inside the vendor's
    ``vendor`` and ``vendor_rate`` (the module docstring)."""
    out = np.empty_like(vendor)
    margin = math.radians(LIMIT_MARGIN_DEG)
    cap = math.radians(MAX_MISSION_DEG)
    for i, (lo, hi) in enumerate(vendor):
        a, b = lo + margin, hi - margin
        if b - a < 2 * margin:  # a narrow joint: keep its middle half
            mid, half = 0.5 * (lo + hi), 0.25 * (hi - lo)
            a, b = mid - half, mid + half
        ca, cb = max(a, -cap), min(b, cap)
        out[i] = (ca, cb) if cb - ca >= 2 * margin else (a, b)
    rate = np.minimum(vendor_rate, math.radians(MISSION_RATE_DEGPS))
    return out, rate


def servo_design(
    model: RobotModel, ws: DynamicsWorkspace, poses: Mapping[str, Array]
) -> tuple[float, float, ServoModes, ServoModes]:
    """The servos' bandwidth (rad/s) and lag (s), with the modes at unit gains and at those
    (the module docstring); ``ws`` on ``model`` at its reference pose."""
    unit = default_servo_gains(model, bandwidth_radps=1.0, lag_s=1.0)
    unit_modes = servo_modes(ws, unit, poses=poses)
    allowed = SERVO_MARGIN * unit_modes.limit_per_s / unit_modes.fastest_per_s  # lag wn^2
    bandwidth = min(MAX_SERVO_BANDWIDTH_RADPS, allowed / (2.0 * SERVO_DAMPING))
    lag = 2.0 * SERVO_DAMPING / bandwidth
    if lag > MAX_SERVO_LAG_S:
        lag = MAX_SERVO_LAG_S
        bandwidth = math.sqrt(allowed / lag)
    bandwidth, lag = _round_down(bandwidth), _round_down(lag)
    modes = servo_modes(ws, default_servo_gains(model, bandwidth_radps=bandwidth, lag_s=lag),
                        poses=poses)  # fmt: skip
    return bandwidth, lag, unit_modes, modes


@dataclass(frozen=True)
class Wheels:
    """Each wheel's limits and rotor, and the PTP A -> B reaction they were checked on."""

    momentum_limit_nms: float
    torque_limit_nm: float
    spin_inertia_kgm2: float
    rotor_mass_kg: float
    ptp_peak_nms: float  # |H~_bm phi'| at its largest on the PTP
    ptp_torque_nm: float  # and its rate of change


def wheel_sizing(
    model: RobotModel, ws: DynamicsWorkspace, qa: Array, qb: Array, reaction_bound_nms: float
) -> Wheels:
    """The wheels for the bound ``reaction_bound_nms`` (N m s) on the arm's reaction
    momentum, their torque enough for the PTP from ``qa`` to ``qb`` (the module docstring)."""
    times, joints = ptp_commands(model, qa, qb, rate_fraction=0.9)
    rates_ptp = np.gradient(joints, times, axis=0)
    momentum = np.array(
        [ws.evaluate(State(joints_rad=q)).H_bm_tilde @ r for q, r in zip(joints, rates_ptp,
                                                                          strict=True)]
    )  # fmt: skip
    ptp_peak_nms = float(np.max(np.linalg.norm(momentum, axis=1)))
    ptp_torque_nm = float(np.max(np.linalg.norm(np.gradient(momentum, times, axis=0), axis=1)))
    capacity = _round_up(WHEEL_MARGIN * reaction_bound_nms)
    torque = _round_up(max(capacity / WHEEL_FILL_S, WHEEL_MARGIN * ptp_torque_nm))
    spin = _round_up(capacity / WHEEL_SPEED_RADPS)
    rotor = _round_up(2.0 * spin / WHEEL_RADIUS_M**2)
    return Wheels(
        momentum_limit_nms=capacity,
        torque_limit_nm=torque,
        spin_inertia_kgm2=spin,
        rotor_mass_kg=rotor,
        ptp_peak_nms=ptp_peak_nms,
        ptp_torque_nm=ptp_torque_nm,
    )


def _round_down(value: float) -> float:
    """Down to 3 significant digits (a gain rounded down keeps its mode under the bound)."""
    scale = 10.0 ** (math.floor(math.log10(value)) - 2)
    return float(f"{math.floor(value / scale + 1e-9) * scale:.3g}")


def _round_up(value: float) -> float:
    """Up to 2 significant digits (a limit rounded up stays a bound)."""
    if value <= 0:
        return value
    scale = 10.0 ** (math.floor(math.log10(value)) - 1)
    return float(f"{math.ceil(value / scale - 1e-9) * scale:.2g}")
