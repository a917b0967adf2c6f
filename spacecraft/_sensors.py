"""Onboard sensors: the truth state as the onboard computer sees it, with seeded noise.

Noise is white and Gaussian, independent per axis and per sample (1-sigma values in
:class:`SensorNoise`). The attitude error is a small rotation in the base frame,
``rot_orbit_from_base_measured = rot_orbit_from_base * exp(delta)``; the gyro and the joint
encoders add their noise to the true base rate (base frame) and joint angles. The wheel
tachometers are taken as exact.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from planner.frames import quat_xyzw_turned_by_rotvec
from planner.state import State

__all__ = ["Measurement", "SensorNoise", "measure"]

Array = NDArray[np.float64]


@dataclass(frozen=True)
class SensorNoise:
    """1-sigma sensor noise (our choice, SPEC 6 "small noise"; docs/spacecraft.md).

    - attitude 0.005 deg per axis: a star-tracker-class attitude solution;
    - base rate 0.0005 deg/s per axis (about 9e-6 rad/s): a fibre-optic gyro;
    - joint angles 0.005 deg: encoder and quantisation noise.

    Through the calibrated wheel law they jitter the base by a few 1e-4 deg (1-sigma; the
    loop is slow and the base heavy), far below the 0.05 deg settling band.
    """

    attitude_rad: float = math.radians(0.005)
    rate_radps: float = math.radians(0.0005)
    joint_rad: float = math.radians(0.005)

    def __post_init__(self) -> None:
        for name in ("attitude_rad", "rate_radps", "joint_rad"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"sensor noise {name} = {value!r} must be finite and >= 0")


@dataclass(frozen=True, eq=False)
class Measurement:
    """One sensor sample (SI units)."""

    quat_orbit_from_base_xyzw: Array
    omega_base_in_base_radps: Array
    joints_rad: Array


def measure(state: State, noise: SensorNoise, rng: np.random.Generator) -> Measurement:
    """A noisy sample of ``state``; draws 3 + 3 + n normal numbers from ``rng`` in that order."""
    delta = rng.normal(0.0, noise.attitude_rad, 3)
    gyro = rng.normal(0.0, noise.rate_radps, 3)
    encoders = rng.normal(0.0, noise.joint_rad, state.joints_rad.shape)
    quat = quat_xyzw_turned_by_rotvec(state.quat_orbit_from_base_xyzw, delta)
    omega_base = state.rot_orbit_from_base.T @ state.omega_base_orbit_radps
    return Measurement(
        quat_orbit_from_base_xyzw=np.asarray(quat, dtype=np.float64),
        omega_base_in_base_radps=np.asarray(omega_base + gyro),
        joints_rad=np.asarray(state.joints_rad + encoders),
    )
