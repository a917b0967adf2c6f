"""The joint servos' fastest mode, against what the simulator's integrator can hold.

The vehicle's servos are PD laws on each joint (``planner.mjcf``: a position actuator ``kp``
and joint damping ``kd``), stepped explicitly by RK4. Near rest each joint mode decays at the
rate of an eigenvalue of ``M^-1 K_d``, ``M`` the free-floating joint inertia
``H_m - H_bm^T H_b^-1 H_bm`` (the base free, the wheels locked in it), ``K_d = diag(kd)``. RK4
at step ``h`` holds a decaying mode only while ``rate h`` stays below about 2.785 (its
stability bound on the negative real axis); past it the simulation diverges within seconds
(MuJoCo warns "simulation is unstable" and resets). :data:`MAX_SERVO_RATE_STEP` is the
bound measured on the simulator itself (``scripts/servo_threshold.py``, docs/robots.md,
"Servo stability"), less a margin.

:func:`servo_modes` evaluates ``M^-1 K_d`` at the reference pose, every named pose and poses
drawn uniformly inside the limits (a fixed seed: the same answer every time), and gives the
fastest; :func:`proposed_lag_s` scales the damping down until it fits.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from planner.dynamics import DynamicsWorkspace
from planner.mjcf import ServoGains
from planner.state import State

__all__ = [
    "MAX_SERVO_RATE_STEP",
    "SERVO_SAMPLES",
    "ServoModes",
    "fastest_mode_at",
    "servo_modes",
]

Array = NDArray[np.float64]

#: The largest ``rate * timestep`` a servo mode may reach: the simulator held 2.77 (Orihime)
#: and 2.82 (ETS-VII) and diverged just above (scripts/servo_threshold.py, RK4 at 10 ms;
#: RK4's bound on the real axis is 2.785), less about a tenth for the poses between those
#: checked.
MAX_SERVO_RATE_STEP = 2.5
#: Random poses drawn inside the limits, besides the reference and the named poses.
SERVO_SAMPLES = 64
_SEED = 20260


@dataclass(frozen=True)
class ServoModes:
    """The servos' fastest mode over the sampled poses."""

    fastest_per_s: float  # largest eigenvalue of M^-1 K_d (1/s)
    at_joints_rad: Array  # where
    at: str  # "reference", a pose's name, or "sample k"
    limit_per_s: float  # MAX_SERVO_RATE_STEP / timestep
    timestep_s: float
    samples: int

    @property
    def stable(self) -> bool:
        return self.fastest_per_s <= self.limit_per_s

    def describe(self) -> str:
        return (
            f"fastest servo mode {self.fastest_per_s:.4g} 1/s (largest eigenvalue of M^-1 Kd "
            f"over {self.samples} poses, at {self.at}); the integrator holds "
            f"{self.limit_per_s:.4g} 1/s at a {self.timestep_s * 1e3:.4g} ms step"
        )


def fastest_mode_at(ws: DynamicsWorkspace, gains: ServoGains, joints_rad: Array) -> float:
    """The largest eigenvalue of ``M^-1 K_d`` at these joints (1/s)."""
    q = ws.evaluate(State(np.asarray(joints_rad, dtype=np.float64)))
    inertia = q.H_m - q.H_bm.T @ np.linalg.solve(q.H_b, q.H_bm)
    inertia = 0.5 * (inertia + inertia.T)
    kd = np.diag(np.asarray(gains.kd_nms_per_rad, dtype=np.float64))
    return float(scipy.linalg.eigh(kd, inertia, eigvals_only=True)[-1])


def servo_modes(
    ws: DynamicsWorkspace,
    gains: ServoGains,
    *,
    poses: Mapping[str, Array] | None = None,
    timestep_s: float = 0.01,
    samples: int = SERVO_SAMPLES,
) -> ServoModes:
    """The fastest servo mode at the reference pose, ``poses`` and ``samples`` seeded
    uniform draws inside the joint limits."""
    model = ws.model
    candidates: list[tuple[str, Array]] = [("reference", model.reference_joints)]
    candidates += [(f"pose {name}", np.asarray(q)) for name, q in (poses or {}).items()]
    rng = np.random.default_rng(_SEED)
    lo, hi = model.joint_limit_rad[:, 0], model.joint_limit_rad[:, 1]
    for k in range(samples):
        candidates.append((f"sample {k + 1}", rng.uniform(lo, hi)))
    best = ("reference", model.reference_joints, -np.inf)
    for name, q in candidates:
        rate = fastest_mode_at(ws, gains, q)
        if rate > best[2]:
            best = (name, q, rate)
    return ServoModes(
        fastest_per_s=float(best[2]),
        at_joints_rad=np.asarray(best[1]),
        at=best[0],
        limit_per_s=MAX_SERVO_RATE_STEP / timestep_s,
        timestep_s=timestep_s,
        samples=len(candidates),
    )
