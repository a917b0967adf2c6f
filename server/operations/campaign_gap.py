"""Between two passes of a campaign: what the gap does to the vehicle (docs/missions.md,
Campaigns; SPEC eq. 3, 11 and 14).

    gravity_gradient_momentum_nms(mission, start, end, inertia, quat) -> (3,) N m s
    gap_transition(ws, mission, end_state, held_quat, start, end) -> (VehicleState, loaded)

The arm rests and attitude control holds the base at its target in the Earth-pointing orbit
frame, so the wheels take up eq. (11)'s torque (:func:`planner.gravity_gradient.
gravity_gradient_torque_base_nm`), integrated by eq. (14) over the mission's SGP4 radius
(:func:`mission.campaign.inverse_cube_radius_s_per_m3`): both packages' arithmetic, met here,
where both may be imported.
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime

import numpy as np
from numpy.typing import NDArray

from mission.campaign import inverse_cube_radius_s_per_m3
from mission.errors import MissionError
from mission.file import Mission
from planner.dynamics import DynamicsWorkspace
from planner.frames import matrix_from_quat_xyzw
from planner.gravity_gradient import Orbit, gravity_gradient_torque_base_nm
from planner.state import VehicleState

__all__ = ["GRAVITY_MU_M3PS2", "gap_transition", "gravity_gradient_momentum_nms"]

Array = NDArray[np.float64]

#: SPEC section 2: the gravitational parameter of eq. (11)-(13), m^3/s^2 (the planner's).
GRAVITY_MU_M3PS2 = Orbit().mu_m3ps2


def gravity_gradient_momentum_nms(
    mission: Mission,
    start_utc: datetime,
    end_utc: datetime,
    inertia_com_base_kgm2: Array,
    quat_orbit_from_base_xyzw: Array | Sequence[float] = (0.0, 0.0, 0.0, 1.0),
) -> Array:
    """The angular momentum (N m s, base frame) the wheels take up from ``start_utc`` to
    ``end_utc`` while attitude control holds the base at ``quat_orbit_from_base_xyzw`` and
    the arm rests (``inertia_com_base_kgm2``: the whole system's inertia about its centre of
    mass, base frame, H_c of eq. 11): eq. (11)'s torque on the circular orbit whose
    ``R^-3`` is the gap's mean ``|r|^-3``, times the gap."""
    inertia = np.asarray(inertia_com_base_kgm2, dtype=np.float64)
    if inertia.shape != (3, 3) or not np.all(np.isfinite(inertia)):
        raise MissionError(f"the inertia must be a finite 3x3 matrix, got shape {inertia.shape}")
    integral = inverse_cube_radius_s_per_m3(mission, start_utc, end_utc)
    if integral == 0.0:
        return np.zeros(3)
    span_s = (end_utc - start_utc).total_seconds()
    quat = np.asarray(quat_orbit_from_base_xyzw, dtype=np.float64)
    orbit = Orbit(altitude_m=(span_s / integral) ** (1.0 / 3.0) - Orbit().earth_radius_m)
    torque = gravity_gradient_torque_base_nm(
        inertia, matrix_from_quat_xyzw(quat / np.linalg.norm(quat)), orbit
    )
    return np.asarray(torque * span_s, dtype=np.float64)


def gap_transition(
    ws: DynamicsWorkspace,
    mission: Mission,
    end_state: VehicleState,
    held_quat_orbit_from_base_xyzw: Array,
    start_utc: datetime,
    end_utc: datetime,
) -> tuple[VehicleState, Array]:
    """The vehicle at ``end_utc`` after a gap from ``start_utc`` in which the arm rests at
    ``end_state``'s joints and attitude control holds the base at
    ``held_quat_orbit_from_base_xyzw``; and the gravity-gradient share of its wheel momentum.

    Settling: the total angular momentum ``R (H~_b w_b + h_w)`` (orbit frame, arm at rest,
    eq. 3) is kept while the base comes to rest at the held attitude, so the wheels then hold
    ``R_held^T R_end (H~_b w_b + h_w)``. Loading: :func:`gravity_gradient_momentum_nms`."""
    joints = end_state.joints_rad
    inertia_base = ws.momentum_blocks(joints)[0]  # H~_b at rest is H_c (eq. 11), base frame
    rot_end = matrix_from_quat_xyzw(end_state.quat_orbit_from_base_xyzw)
    rot_held = matrix_from_quat_xyzw(np.asarray(held_quat_orbit_from_base_xyzw, dtype=float))
    omega_base = rot_end.T @ end_state.omega_base_orbit_radps
    momentum_orbit = rot_end @ (inertia_base @ omega_base + end_state.wheel_momentum_nms)
    settled = rot_held.T @ momentum_orbit
    loaded = gravity_gradient_momentum_nms(
        mission, start_utc, end_utc, inertia_base, held_quat_orbit_from_base_xyzw
    )
    start = VehicleState(
        joints_rad=joints.copy(),
        quat_orbit_from_base_xyzw=np.asarray(held_quat_orbit_from_base_xyzw, dtype=float),
        omega_base_orbit_radps=np.zeros(3),
        wheel_momentum_nms=settled + loaded,
    )
    return start, loaded
