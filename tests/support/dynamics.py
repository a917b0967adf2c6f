"""The comparison of the project's dynamics with the independent reference
(tests/reference_dynamics.py): the quantities compared, their tolerances, and the random
states they are compared at."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from operator import attrgetter

import numpy as np
from numpy.typing import NDArray

from planner.dynamics import Quantities
from planner.state import State
from tests import reference_dynamics as ref

Array = NDArray[np.float64]


# Project vs reference: both are float64 and agree to ~1e-14; 1e-9 leaves room for another
# BLAS or MuJoCo build while still catching any modelling slip (those show at >= 1e-4).
RTOL_REFERENCE = 1e-9


# The two reference methods (CRB vs sum over bodies) share only the kinematics.
RTOL_REFERENCE_METHODS = 1e-12


def relative_error(actual: Array, expected: Array) -> float:
    """Largest entry-wise error over the largest entry of ``expected``."""
    actual, expected = np.asarray(actual, dtype=np.float64), np.asarray(expected)
    assert actual.shape == expected.shape, f"shape {actual.shape} != {expected.shape}"
    scale = float(np.max(np.abs(expected)))
    assert scale > 0.0, "expected quantity is all zero; a relative comparison means nothing"
    return float(np.max(np.abs(actual - expected))) / scale


def random_unit_quat_xyzw(rng: np.random.Generator) -> Array:
    """Uniform on the rotation group: a normalised 4-D Gaussian."""
    quat = rng.normal(size=4)
    return quat / np.linalg.norm(quat)


Getter = Callable[[Quantities], Array]


RefGetter = Callable[[ref.Reference], Array]


COMPARED: dict[str, tuple[Getter, RefGetter]] = {
    "hand.pos_robot_m": (lambda q: q.hand.pos_robot_m, lambda r: r.kinematics.hand_pos_robot_m),
    "hand.rot_robot_from_hand": (
        lambda q: q.hand.rot_robot_from_hand,
        lambda r: r.kinematics.rot_robot_from_hand,
    ),
    "hand.pos_base_m": (lambda q: q.hand.pos_base_m, lambda r: r.kinematics.hand_pos_base_m),
    "hand.rot_base_from_hand": (
        lambda q: q.hand.rot_base_from_hand,
        lambda r: r.kinematics.rot_base_from_hand,
    ),
    "hand.pos_orbit_m": (lambda q: q.hand.pos_orbit_m, lambda r: r.kinematics.hand_pos_orbit_m),
    "hand.rot_orbit_from_hand": (
        lambda q: q.hand.rot_orbit_from_hand,
        lambda r: r.kinematics.rot_orbit_from_hand,
    ),
    "total_mass_kg": (lambda q: np.array(q.total_mass_kg), lambda r: np.array(r.total_mass_kg)),
    "com_orbit_m": (lambda q: q.com_orbit_m, lambda r: r.com_orbit_m),
    **{
        name: (attrgetter(name), attrgetter(name))  # the same name on both sides
        for name in (
            "J_b",
            "J_m",
            "H_b",
            "H_bm",
            "H_m",
            "linear_momentum_nms",
            "angular_momentum_nms",
            "H_b_tilde",
            "H_bm_tilde",
            "reaction_map",
            "J_g",
            "rns_projector",
            "inertia_com_base_kgm2",
            "gravity_gradient_torque_base_nm",
        )
    },
}


FD_STEP = 1e-6  # rad or m


# Central differences: truncation ~ h^2 |x'''| / 6 ~ 1e-12; round-off ~ eps |x| / h ~ 1e-9
# for hand positions of a few metres. 1e-7 sits well above both.
FD_ATOL = 1e-7


def random_state(rng: np.random.Generator, joints_rad: Array) -> State:
    """A random state at ``joints_rad`` (drawn first, from ``rng``): attitude, base position
    and every rate random, at the scales of a pass (wheels at about 100 rad/s)."""
    n = len(joints_rad)
    return State(
        joints_rad=joints_rad,
        quat_orbit_from_base_xyzw=random_unit_quat_xyzw(rng),
        pos_base_orbit_m=rng.uniform(-5.0, 5.0, 3),
        vel_base_orbit_mps=rng.normal(scale=0.05, size=3),
        omega_base_orbit_radps=rng.normal(scale=0.01, size=3),
        joint_rates_radps=rng.normal(scale=0.05, size=n),
        wheel_rates_radps=rng.normal(scale=100.0, size=3),
    )


def reference_at(
    state: State, wheel_spin_inertia_kgm2: Array, robot: ref.RobotData = ref.ETS7
) -> ref.Reference:
    """The reference's quantities of ``robot`` at ``state``, with the wheels' spin inertia
    given (the reference leaves the rotors to the model)."""
    # the state's fields are the reference's arguments of the same names
    values = {f.name: getattr(state, f.name) for f in dataclasses.fields(state)}
    return ref.evaluate(**values, wheel_spin_inertia_kgm2=wheel_spin_inertia_kgm2, robot=robot)
