"""The per-instant state of the free-flying robot (pinocchio's model/state split).

Velocity convention, stated once (SPEC section 2, eq. (1)-(2)):
``x_b' = (v_b, w_b)`` is the base centre-of-mass linear velocity and the base angular
velocity, **both in the orbit frame**; ``phi'`` are the joint rates; wheel rates are each
rotor's spin rate *relative to the base*. Twists and Jacobian rows are ordered linear first,
angular second.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.errors import InvalidInput
from planner.frames import IDENTITY_QUAT_XYZW, matrix_from_quat_xyzw

__all__ = ["State", "VehicleState"]

Array = NDArray[np.float64]


def _zeros(n: int) -> Array:
    return np.zeros(n)


#: The default of ``State.joint_rates_radps``: replaced by zeros of the joints' shape.
_UNSET_RATES: Array = np.zeros(0)


#: The arrays a :class:`State` checks and their shapes (None: any, the joints').
_STATE_SHAPES: tuple[tuple[str, tuple[int] | None], ...] = (
    ("joints_rad", None),
    ("quat_orbit_from_base_xyzw", (4,)),
    ("pos_base_orbit_m", (3,)),
    ("vel_base_orbit_mps", (3,)),
    ("omega_base_orbit_radps", (3,)),
    ("wheel_rates_radps", (3,)),
)


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
        # The planners make one per evaluation (tens of thousands per plan): the checks use
        # the arrays' own methods, not numpy's slower function wrappers, and all the arrays'
        # finiteness is one check (field by field, to name the culprit, only when it fails).
        values = [np.asarray(getattr(self, name), dtype=np.float64) for name, _ in _STATE_SHAPES]
        shapes_ok = all(
            s is None or v.shape == s for (_, s), v in zip(_STATE_SHAPES, values, strict=True)
        )
        if not (shapes_ok and np.isfinite(np.concatenate([v.ravel() for v in values])).all()):
            for (name, shape), value in zip(_STATE_SHAPES, values, strict=True):
                if shape is not None and value.shape != shape:
                    raise InvalidInput(f"{name} must have shape {shape}, got {value.shape}")
                if not np.isfinite(value).all():
                    raise InvalidInput(f"{name} must be finite, got {value.tolist()}")
        for (name, _), value in zip(_STATE_SHAPES, values, strict=True):
            object.__setattr__(self, name, value)
        rates = np.asarray(self.joint_rates_radps, dtype=np.float64)
        if self.joint_rates_radps is _UNSET_RATES:
            rates = np.zeros_like(self.joints_rad)
        if rates.shape != self.joints_rad.shape:
            raise InvalidInput(
                f"joint_rates_radps has shape {rates.shape}, joints_rad {self.joints_rad.shape}"
            )
        object.__setattr__(self, "joint_rates_radps", rates)
        quat = self.quat_orbit_from_base_xyzw
        norm = math.sqrt(quat.dot(quat))  # np.linalg.norm's own arithmetic
        if not 0.5 < norm < 2.0:
            raise InvalidInput(f"quat_orbit_from_base_xyzw is not a rotation (norm {norm:.3g})")
        object.__setattr__(self, "quat_orbit_from_base_xyzw", quat / norm)

    @property
    def rot_orbit_from_base(self) -> Array:
        return matrix_from_quat_xyzw(self.quat_orbit_from_base_xyzw)

    @property
    def base_twist_orbit(self) -> Array:
        """``x_b' = (v_b, w_b)``, orbit frame, shape (6,)."""
        return np.concatenate([self.vel_base_orbit_mps, self.omega_base_orbit_radps])


@dataclass(frozen=True, eq=False)
class VehicleState:
    """Where a plan starts or ends: the arm at rest at ``joints_rad``, the base attitude and
    angular rate (orbit frame) and the wheels' momentum (base frame). The default is the
    nominal start: attitude the orbit frame's, at rest, wheels empty.

    A plan is predicted from one of these (``planner.schedule.plan_pass(initial_state=)``) and
    read back at its end (:meth:`at_end_of`), so that one pass can start where another left
    the vehicle (docs/planning.md, Campaigns)."""

    joints_rad: Array
    quat_orbit_from_base_xyzw: Array = field(default_factory=lambda: IDENTITY_QUAT_XYZW.copy())
    omega_base_orbit_radps: Array = field(default_factory=lambda: _zeros(3))
    wheel_momentum_nms: Array = field(default_factory=lambda: _zeros(3))

    def __post_init__(self) -> None:
        joints = np.array(self.joints_rad, dtype=np.float64)
        if joints.ndim != 1 or joints.size == 0:
            raise InvalidInput(f"joints_rad must be a vector, got shape {joints.shape}")
        object.__setattr__(self, "joints_rad", joints)
        for name, shape in (
            ("quat_orbit_from_base_xyzw", (4,)),
            ("omega_base_orbit_radps", (3,)),
            ("wheel_momentum_nms", (3,)),
        ):
            value = np.array(getattr(self, name), dtype=np.float64)
            if value.shape != shape:
                raise InvalidInput(f"{name} must have shape {shape}, got {value.shape}")
            object.__setattr__(self, name, value)
        for name in (
            "joints_rad",
            "quat_orbit_from_base_xyzw",
            "omega_base_orbit_radps",
            "wheel_momentum_nms",
        ):
            if not np.all(np.isfinite(getattr(self, name))):
                raise InvalidInput(f"{name} must be finite, got {getattr(self, name).tolist()}")
        norm = float(np.linalg.norm(self.quat_orbit_from_base_xyzw))
        if not 0.5 < norm < 2.0:
            raise InvalidInput(f"quat_orbit_from_base_xyzw is not a rotation (norm {norm:.3g})")
        quat = self.quat_orbit_from_base_xyzw / norm
        object.__setattr__(self, "quat_orbit_from_base_xyzw", quat if quat[3] >= 0 else -quat)

    @classmethod
    def at_end_of(cls, prediction: Any) -> VehicleState:
        """The last row of a plan's prediction (``planner.plan.Prediction``): a plan's last
        command holds still, so the arm is at rest there."""
        return cls(
            joints_rad=prediction.joints_rad[-1],
            quat_orbit_from_base_xyzw=prediction.quat_orbit_from_base_xyzw[-1],
            omega_base_orbit_radps=prediction.omega_base_orbit_radps[-1],
            wheel_momentum_nms=prediction.wheel_momentum_nms[-1],
        )

    @classmethod
    def at_start_of(cls, prediction: Any) -> VehicleState:
        """The first row of a plan's prediction."""
        return cls(
            joints_rad=prediction.joints_rad[0],
            quat_orbit_from_base_xyzw=prediction.quat_orbit_from_base_xyzw[0],
            omega_base_orbit_radps=prediction.omega_base_orbit_radps[0],
            wheel_momentum_nms=prediction.wheel_momentum_nms[0],
        )

    def to_dict(self) -> dict[str, list[float]]:
        return {
            "joints_rad": [float(v) for v in self.joints_rad],
            "quat_orbit_from_base_xyzw": [float(v) for v in self.quat_orbit_from_base_xyzw],
            "omega_base_orbit_radps": [float(v) for v in self.omega_base_orbit_radps],
            "wheel_momentum_nms": [float(v) for v in self.wheel_momentum_nms],
        }

    @classmethod
    def from_dict(cls, doc: Mapping[str, Any]) -> VehicleState:
        try:
            return cls(
                joints_rad=np.array(doc["joints_rad"], dtype=np.float64),
                quat_orbit_from_base_xyzw=np.array(
                    doc["quat_orbit_from_base_xyzw"], dtype=np.float64
                ),
                omega_base_orbit_radps=np.array(doc["omega_base_orbit_radps"], dtype=np.float64),
                wheel_momentum_nms=np.array(doc["wheel_momentum_nms"], dtype=np.float64),
            )
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, InvalidInput):
                raise
            raise InvalidInput(f"malformed vehicle state: {exc!r}") from exc
