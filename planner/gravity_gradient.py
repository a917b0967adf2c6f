"""Gravity-gradient torque, SPEC eq. (11)-(13), and the orbit it is evaluated on.

The orbit frame is treated as inertial over a pass (SPEC section 2): its z axis points to
the Earth's centre (nadir), so the vector from the Earth's centre to the system centre of
mass is ``-R * z_orbit``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["Orbit", "gravity_gradient_torque_base_nm", "orbit_of_radius"]

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Orbit:
    """A circular orbit (SPEC section 2, our choice: ETS-VII's 550 km)."""

    altitude_m: float = 550e3
    earth_radius_m: float = 6378.137e3
    mu_m3ps2: float = 3.986004418e14

    @property
    def radius_m(self) -> float:
        return self.earth_radius_m + self.altitude_m

    @property
    def mean_motion_radps(self) -> float:
        return float(np.sqrt(self.mu_m3ps2 / self.radius_m**3))

    @property
    def gradient_coefficient_ps2(self) -> float:
        """``3 mu / R^3`` (1/s^2), the factor of eq. (13)."""
        return 3.0 * self.mu_m3ps2 / self.radius_m**3


def orbit_of_radius(radius_m: float) -> Orbit:
    """The orbit of radius ``radius_m`` (m) about the nominal Earth."""
    nominal = Orbit()
    return Orbit(
        altitude_m=radius_m - nominal.earth_radius_m,
        earth_radius_m=nominal.earth_radius_m,
        mu_m3ps2=nominal.mu_m3ps2,
    )


def gravity_gradient_torque_base_nm(
    inertia_com_base_kgm2: Array, rot_orbit_from_base: Array, orbit: Orbit
) -> Array:
    """Eq. (11): ``N = 3 mu / R^5 * r x (H_c r)``, in the base frame (N m).

    ``inertia_com_base_kgm2`` is the whole system's inertia about its centre of mass in the
    base frame (H_c); ``r`` is the Earth-centre-to-CoM vector in the base frame. When the base
    is Earth-pointing this is eq. (13), ``3 mu / R^3 * (-H_yz, H_xz, 0)``.
    """
    # Unit vector from the Earth's centre to the spacecraft, base frame: -z_orbit.
    rot = np.asarray(rot_orbit_from_base)
    r = -rot[2, :]
    h = np.asarray(inertia_com_base_kgm2) @ r
    k = orbit.gradient_coefficient_ps2
    # r x (H r), written out: np.cross costs ten times more on 3-vectors.
    return np.array(
        [
            k * (r[1] * h[2] - r[2] * h[1]),
            k * (r[2] * h[0] - r[0] * h[2]),
            k * (r[0] * h[1] - r[1] * h[0]),
        ]
    )
