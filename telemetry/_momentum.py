"""Angular momentum of the system from telemetry, with the base inertia kept apart (eq. 3).

Shared by :mod:`telemetry.identification` and :mod:`telemetry.resim`. Conventions:

- ``L = R (H~_b w + H~_bm phi' + h_w)`` about the system CoM, orbit frame (N m s), with
  ``R = rot_orbit_from_base``, ``w`` the gyro's base rate in the base frame, ``h_w`` the wheel
  rotors' momentum relative to the base (base frame) and ``H~_b``, ``H~_bm`` in the base frame
  (:meth:`planner.dynamics.DynamicsWorkspace.momentum_blocks`; they depend on the joints only).
- ``H~_b = I_base + A(q)``: the locked base's inertia (Table 1) enters ``H~_b`` additively,
  the parallel-axis terms depend on masses only, so ``A(q) = H~_b(q) - model.base_inertia``
  is the arm's share whatever base inertia the model carries.
- The six base-inertia parameters are ``theta = (Ixx, Iyy, Izz, Ixy, Ixz, Iyz)`` (Table 1's
  order); ``I_base = sum_j theta_j E_j`` with ``E_j = inertia_matrix(unit j)``, so the
  product sign convention stays in :func:`planner.model.inertia_matrix`.
- Gravity gradient (eq. 11) is linear in ``H_c = H~_b``, hence in ``theta`` too.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from planner.dynamics import DynamicsWorkspace
from planner.frames import matrix_from_quat_xyzw
from planner.gravity_gradient import gravity_gradient_torque_base_nm
from planner.model import inertia_matrix

__all__ = [
    "INERTIA_PARAMETER_NAMES",
    "InsufficientData",
    "MomentumSamples",
    "base_regressor",
    "central_rates",
    "inertia_from_parameters",
    "momentum_samples",
    "parameter_basis",
    "rotations_from_quats",
]

Array = NDArray[np.float64]

#: Table 1's order of the base inertia parameters.
INERTIA_PARAMETER_NAMES = ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")


class InsufficientData(ValueError):
    """A recording (or the part of it asked for) cannot support the analysis; the message
    names what is missing and the limit."""


def parameter_basis() -> Array:
    """``E_j`` (6, 3, 3): the inertia matrix of each unit parameter, Table 1's convention."""
    return np.array([inertia_matrix(*np.eye(6)[j]) for j in range(6)])


def inertia_from_parameters(theta_kgm2: Array) -> Array:
    """3x3 inertia (kg m^2) from ``(Ixx, Iyy, Izz, Ixy, Ixz, Iyz)``."""
    return np.asarray(inertia_matrix(*(float(v) for v in theta_kgm2)))


def rotations_from_quats(quats_xyzw: Array) -> Array:
    """``rot_orbit_from_base`` (k, 3, 3) of scalar-last quaternions (k, 4)."""
    return np.array([matrix_from_quat_xyzw(q) for q in np.asarray(quats_xyzw)]).reshape(-1, 3, 3)


def base_regressor(rot_orbit_from_base: Array, omega_base_in_base_radps: Array) -> Array:
    """``R W(w)`` (k, 3, 6): ``R I_base w`` is ``base_regressor @ theta``."""
    per_axis = np.einsum("jab,kb->kaj", parameter_basis(), omega_base_in_base_radps)
    return np.asarray(np.einsum("kab,kbj->kaj", rot_orbit_from_base, per_axis))


def central_rates(t_s: Array, values: Array) -> Array:
    """Rates of ``values`` (k, m) by central differences on the (possibly uneven) grid ``t_s``,
    one-sided at the ends. Block means of these telescope, so encoder noise does not pile up."""
    return np.asarray(np.gradient(values, t_s, axis=0, edge_order=1))


@dataclass(frozen=True, eq=False)
class MomentumSamples:
    """Per-sample terms of the momentum balance (orbit frame, row k at telemetry sample k).

    ``L_k = base_regressor[k] @ theta + known_momentum[k]`` and
    ``dL/dt = gg_regressor[k] @ theta + gg_known[k]`` (eq. 11 split the same way).
    """

    rot_orbit_from_base: Array  # (k, 3, 3)
    #: ``R W(w)``, (k, 3, 6): the base's ``I_base w`` per unit parameter, orbit frame (s^-1).
    base_regressor: Array
    #: ``R (A w + H~_bm phi' + h_w)``, (k, 3), N m s.
    known_momentum: Array
    #: gravity-gradient torque per unit parameter, orbit frame, (k, 3, 6), N m per kg m^2.
    gg_regressor: Array
    #: gravity-gradient torque of the arm's share ``A(q)``, orbit frame, (k, 3), N m.
    gg_known: Array


def momentum_samples(
    ws: DynamicsWorkspace,
    *,
    joints_rad: Array,
    joint_rates_radps: Array,
    omega_base_in_base_radps: Array,
    wheel_momentum_nms: Array,
    rot_orbit_from_base: Array,
) -> MomentumSamples:
    """The momentum-balance terms at each sample (see :class:`MomentumSamples`)."""
    n = len(joints_rad)
    basis = parameter_basis()
    base_inertia = np.asarray(ws.model.base_inertia_kgm2)
    known = np.zeros((n, 3))
    gg_reg = np.zeros((n, 3, 6))
    gg_known = np.zeros((n, 3))
    for k in range(n):
        rot = rot_orbit_from_base[k]
        h_b, h_bm = ws.momentum_blocks(joints_rad[k])
        arm = h_b - base_inertia
        w = omega_base_in_base_radps[k]
        known[k] = rot @ (arm @ w + h_bm @ joint_rates_radps[k] + wheel_momentum_nms[k])
        gg_known[k] = rot @ gravity_gradient_torque_base_nm(arm, rot, ws.orbit)
        for j in range(6):
            gg_reg[k, :, j] = rot @ gravity_gradient_torque_base_nm(basis[j], rot, ws.orbit)
    base_reg = base_regressor(rot_orbit_from_base, omega_base_in_base_radps)
    return MomentumSamples(rot_orbit_from_base, base_reg, known, gg_reg, gg_known)
