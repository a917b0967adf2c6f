"""The per-instant state of the free-flying robot (pinocchio's model/state split).

Velocity convention, stated once (SPEC section 2, eq. (1)-(2)):
``x_b' = (v_b, w_b)`` is the base centre-of-mass linear velocity and the base angular
velocity, **both in the orbit frame**; ``phi'`` are the joint rates; wheel rates are each
rotor's spin rate *relative to the base*. Twists and Jacobian rows are ordered linear first,
angular second.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from planner.errors import InvalidInput
from planner.frames import IDENTITY_QUAT_XYZW, matrix_from_quat_xyzw

__all__ = ["State"]

Array = NDArray[np.float64]


def _zeros(n: int) -> Array:
    return np.zeros(n)


#: The default of ``State.joint_rates_radps``: replaced by zeros of the joints' shape.
_UNSET_RATES: Array = np.zeros(0)


@dataclass(frozen=True, eq=False)
class State:
    """Positions and velocities of base, joints and wheels (SI units)."""

    joints_rad: Array
    quat_orbit_from_base_xyzw: Array = field(default_factory=lambda: IDENTITY_QUAT_XYZW.copy())
    pos_base_orbit_m: Array = field(default_factory=lambda: _zeros(3))
    vel_base_orbit_mps: Array = field(default_factory=lambda: _zeros(3))
    omega_base_orbit_radps: Array = field(default_factory=lambda: _zeros(3))
    #: defaults to zeros of ``joints_rad``'s shape (any joint count)
    joint_rates_radps: Array = field(default_factory=lambda: _UNSET_RATES)
    wheel_rates_radps: Array = field(default_factory=lambda: _zeros(3))

    def __post_init__(self) -> None:
        shapes = {
            "joints_rad": None,
            "quat_orbit_from_base_xyzw": (4,),
            "pos_base_orbit_m": (3,),
            "vel_base_orbit_mps": (3,),
            "omega_base_orbit_radps": (3,),
            "wheel_rates_radps": (3,),
        }
        for name, shape in shapes.items():
            value = np.asarray(getattr(self, name), dtype=np.float64)
            if shape is not None and value.shape != shape:
                raise InvalidInput(f"{name} must have shape {shape}, got {value.shape}")
            if not np.all(np.isfinite(value)):
                raise InvalidInput(f"{name} must be finite, got {value.tolist()}")
            object.__setattr__(self, name, value)
        rates = np.asarray(self.joint_rates_radps, dtype=np.float64)
        if self.joint_rates_radps is _UNSET_RATES:
            rates = np.zeros_like(self.joints_rad)
        if rates.shape != self.joints_rad.shape:
            raise InvalidInput(
                f"joint_rates_radps has shape {rates.shape}, joints_rad {self.joints_rad.shape}"
            )
        object.__setattr__(self, "joint_rates_radps", rates)
        norm = float(np.linalg.norm(self.quat_orbit_from_base_xyzw))
        if not 0.5 < norm < 2.0:
            raise InvalidInput(f"quat_orbit_from_base_xyzw is not a rotation (norm {norm:.3g})")
        object.__setattr__(self, "quat_orbit_from_base_xyzw", self.quat_orbit_from_base_xyzw / norm)

    @property
    def rot_orbit_from_base(self) -> Array:
        return matrix_from_quat_xyzw(self.quat_orbit_from_base_xyzw)

    @property
    def base_twist_orbit(self) -> Array:
        """``x_b' = (v_b, w_b)``, orbit frame, shape (6,)."""
        return np.concatenate([self.vel_base_orbit_mps, self.omega_base_orbit_radps])
