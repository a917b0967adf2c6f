"""A plan's prediction made again from its commands: what a plan from outside must agree with.

    repredict(plan, ws, acs_gains=, servo_gains=)      -> Prediction   the planner's own
    prediction_difference(document, ground, tolerance=) -> Difference | None   the first one

:func:`repredict` runs :func:`planner.prediction.predict` on what the plan flies and what it
states about its start, never on what it predicts:

- the joints: the commands; or, for a plan pre-shaped for the servos' lag
  (:func:`planner.servo_compensation.compensate_servo_lag`), the path its prediction's
  joints give, but only when pre-shaping that path gives the commands again (to
  :data:`JOINT_TOLERANCE_RAD`): the planners predict such a plan along the path the servos
  are shaped to follow;
- the attitude-control commands, with the robot's gains (``acs_gains``);
- the start: the plan's initial attitude, and the wheels' momentum and the base's rate of its
  prediction's first row (the state the plan says it starts from; the base rate there is
  the start's rate less what the arm's first motion adds, which the ground computes);
- the gravity-gradient torque where the plan's parameters switch it on (``gjm``:
  ``gravity_gradient``, ``pass``: ``gravity_gradient_radius_m``), as the planners do.

:func:`prediction_difference` compares two predictions column by column, each to
``tolerance`` in its own unit (rad, rad/s, m, N m s; quaternions by component, either sign),
and names the first row and column that disagree.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from planner.attitude_control import AcsGains, AcsMode
from planner.dynamics import DynamicsWorkspace, solve_small
from planner.errors import InvalidInput
from planner.frames import matrix_from_quat_xyzw
from planner.gravity_gradient import Orbit, orbit_of_radius
from planner.mjcf import ServoGains
from planner.plan import Plan, Prediction
from planner.prediction import predict
from planner.servo_compensation import compensate_servo_lag

__all__ = [
    "JOINT_TOLERANCE_RAD",
    "PREDICTION_TOLERANCE",
    "Difference",
    "prediction_difference",
    "repredict",
]

Array = NDArray[np.float64]

#: How far a pre-shaped plan's commands may lie from its path pre-shaped again (rad).
JOINT_TOLERANCE_RAD = 1e-9
#: How far a plan's prediction may lie from the ground's, in each column's unit (rad, rad/s,
#: m, N m s; quaternion components): a millionth, far below any flight rule's resolution
#: (degrees, tenths of a wheel's capacity, centimetres) and far above the last-bit
#: differences of another machine's arithmetic.
PREDICTION_TOLERANCE = 1e-6

_COLUMNS = (
    ("joints_rad", "rad"),
    ("quat_orbit_from_base_xyzw", ""),
    ("rpy_base_rad", "rad"),
    ("omega_base_orbit_radps", "rad/s"),
    ("hand_pos_orbit_m", "m"),
    ("quat_orbit_from_hand_xyzw", ""),
    ("reaction_momentum_orbit_nms", "N m s"),
    ("wheel_momentum_nms", "N m s"),
)


@dataclass(frozen=True)
class Difference:
    """Where two predictions first disagree: a column, its component, the row's time, both
    values (NaN when the shapes differ) and the tolerance."""

    quantity: str
    component: int
    t_s: float
    document: float
    ground: float
    unit: str
    tolerance: float

    def __str__(self) -> str:
        unit = f" {self.unit}" if self.unit else ""
        return (
            f"{self.quantity}[{self.component}] at t = {self.t_s:.2f} s is {self.document!r}"
            f"{unit}, the ground predicts {self.ground!r}{unit} (tolerance {self.tolerance:g})"
        )

    def to_dict(self) -> dict[str, object]:
        return {
            "quantity": self.quantity,
            "component": self.component,
            "t_s": self.t_s,
            "document": self.document if math.isfinite(self.document) else None,
            "ground": self.ground if math.isfinite(self.ground) else None,
            "unit": self.unit,
            "tolerance": self.tolerance,
        }


def _orbit(plan: Plan) -> Orbit | None:
    if plan.experiment == "gjm" and plan.parameters.get("gravity_gradient") is True:
        return Orbit()
    if plan.experiment == "pass":
        radius = plan.parameters.get("gravity_gradient_radius_m", 0.0)
        if isinstance(radius, (int, float)) and not isinstance(radius, bool) and radius > 0.0:
            return orbit_of_radius(float(radius))
    return None


def _joints(plan: Plan, ws: DynamicsWorkspace, servo_gains: ServoGains) -> Array:
    """The joints the planners predict along: the commands, or the path they pre-shape."""
    commands = plan.command_joints_rad
    path = np.asarray(plan.prediction.joints_rad, dtype=np.float64)
    if path.shape != commands.shape or np.array_equal(path, commands):
        return commands
    shaped = compensate_servo_lag(ws, servo_gains, plan.command_times_s, path)
    gap = np.abs(shaped - commands)
    if float(np.max(gap)) > JOINT_TOLERANCE_RAD:
        k, j = np.unravel_index(int(np.argmax(gap)), gap.shape)
        raise InvalidInput(
            f"the prediction's joints are neither the commands nor the path they are "
            f"pre-shaped for: at t = {float(plan.command_times_s[k]):.2f} s joint {j + 1} is "
            f"commanded {float(commands[k, j])!r} rad, the path pre-shaped gives "
            f"{float(shaped[k, j])!r} rad"
        )
    return path


def repredict(
    plan: Plan,
    ws: DynamicsWorkspace,
    *,
    acs_gains: AcsGains,
    servo_gains: ServoGains,
) -> Prediction:
    """``plan``'s prediction made again from its commands and stated start (module
    docstring), on ``ws`` (its robot's model). The plan must have passed
    :meth:`Plan.check_consistent`."""
    joints = _joints(plan, ws, servo_gains)
    times = plan.command_times_s
    first = plan.prediction
    rot0 = matrix_from_quat_xyzw(plan.initial_quat_orbit_from_base_xyzw)
    h_b, h_bm = ws.momentum_blocks(joints[0])
    rate0 = (joints[1] - joints[0]) / (times[1] - times[0]) if times.size > 1 else 0 * joints[0]
    # row 0's base rate is the start's less the arm's share, -H_b^-1 H_bm phi' (eq. 9)
    start_rate = np.asarray(first.omega_base_orbit_radps[0], dtype=np.float64) + rot0 @ (
        solve_small(h_b, h_bm @ rate0)
    )
    feedback = any(c.mode is AcsMode.FEEDBACK for c in plan.acs_commands)
    return predict(
        ws,
        times,
        joints,
        acs_commands=plan.acs_commands,
        acs_gains=acs_gains if feedback else None,
        initial_quat_orbit_from_base_xyzw=plan.initial_quat_orbit_from_base_xyzw,
        initial_wheel_momentum_nms=np.asarray(first.wheel_momentum_nms[0], dtype=np.float64),
        initial_omega_base_orbit_radps=start_rate,
        orbit=_orbit(plan),
    )


def _gap(name: str, document: Array, ground: Array) -> Array:
    if name.startswith("quat"):  # q and -q are one rotation
        return np.asarray(np.minimum(np.abs(document - ground), np.abs(document + ground)))
    return np.asarray(np.abs(document - ground))


def prediction_difference(
    document: Prediction, ground: Prediction, *, tolerance: float = PREDICTION_TOLERANCE
) -> Difference | None:
    """The first (earliest row, then column) value of ``document`` farther than
    ``tolerance`` from ``ground``'s; None when every value is within it."""
    worst: Difference | None = None
    for name, unit in _COLUMNS:
        a = np.asarray(getattr(document, name), dtype=np.float64)
        b = np.asarray(getattr(ground, name), dtype=np.float64)
        if a.shape != b.shape:
            return Difference(name, 0, 0.0, math.nan, math.nan, unit, tolerance)
        over = np.argwhere(~(_gap(name, a, b) <= tolerance))  # NaN too
        if over.size == 0:
            continue
        k, j = (int(v) for v in over[0])
        if worst is None or ground.t_s[k] < worst.t_s:
            worst = Difference(
                name, j, float(ground.t_s[k]), float(a[k, j]), float(b[k, j]), unit, tolerance
            )
    return worst
