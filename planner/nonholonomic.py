"""Non-holonomic end-point control by the bi-directional approach (SPEC section 3, item 4;
Nakamura and Mukherjee 1991).

**Problem.** In free drift at zero angular momentum the base turns at eq. (9),
``w_b = -H~_b^-1 H~_bm phi' = A(phi) phi'`` (base frame, rad/s; in the base frame ``A``, the
3 x n reaction map, depends on the joints only), and ``R' = R [w_b]x`` with
``R = rot_orbit_from_base``. Eq. (10) does not integrate: the attitude a joint path leaves
depends on the path. Wanted: a path from ``(phi_init, R_init)`` to ``(phi_end, R_end)``, i.e. the
joints go where they must *and* the attitude is steered to its target with no wheel.

**Bi-directional approach.** A *forward* path leaves the start, a *backward* path leaves the
goal; both converge to a common intermediate point ``p`` (SPEC: "converge to a common
intermediate point"). Each is a smooth curve in joint space (rad), ``lam`` in [0, 1]::

    phi_f(lam) = phi_init + lam (p - phi_init) + sum_k a_k sin(k pi lam)      k = 1, 2
    phi_b(lam) = phi_end  + lam (p - phi_end)  + sum_k b_k sin(k pi lam)

so both end at ``p`` exactly (joint gap zero by construction); a ``sin(pi lam)``,
``sin(2 pi lam)`` pair lets a path enclose a loop, the only way a path whose joints return can
turn the base. Along each path eq. (9) is integrated in ``lam`` (RK4): ``R_f(1) = R_init G_f``,
``R_b(1) = R_end G_b``. The backward path is a motion that, run from ``p`` back to
``phi_end``, ends at ``R_end``: eq. (9) is driftless, so reversing a path reverses its rotation.

**Meeting.** The paths meet when their attitudes agree too: ``e(x) = log(R_b(1)^T R_f(1)) = 0``
(rotation vector, base frame, rad), with ``x = (p, a_1, a_2, b_1, b_2)`` (5 n numbers: 30 for
ETS-VII's 6 joints).
``V(x) = |e|^2 / 2`` is the Lyapunov function: every iteration moves *both* paths at once by the
damped minimum-norm Gauss-Newton step ``dx = -J^T (J J^T + mu I)^-1 e`` (``J = de/dx``, finite
differences) and is kept only if ``V`` decreases (``mu`` grows otherwise), until
``|e| < attitude_tolerance_rad``. Start: ``p`` midway, and on each path one loop in the joint
plane where the curvature of the connection ``A`` about the needed rotation axis is largest,
sized to cancel the straight path's rotation.

*Why not a point-wise law.* The textbook gradient law (joint rates of both path tips chosen to
decrease ``|phi_f - phi_b|^2 + w |e|^2`` through ``A``) stalls here: near the meeting the
attitude rows of its 9 x 12 system are ``A(phi_f) - A(phi_b) -> 0``, so only loops as thin
as the remaining gap steer the attitude (no smooth state feedback can do it, as the paper
recalls). Tried on this model with several weights and dampings it stalled at 1e-4 to 3e-4
rad of attitude gap with joints driven past 180 deg. Moving whole paths uses loops as large
as the paths and converges quadratically (4 iterations for the flight case).

**Re-timing.** Each path is run at the joints' rate limits on a quintic, rounded up to whole
0.25 s periods (:mod:`planner.nonholonomic_paths`); the arm stops at ``p``. Commands are
samples of the curves, 0.25 s apart from t = 0, after ``lead_s`` at ``phi_init`` and
followed by ``tail_s`` at ``phi_end``.

**Final correction.** On board the joints move *linearly* between commands: chords, not the
curve, and the attitude is path dependent. The rotation of the command sequence is integrated
as :func:`planner.prediction.predict` does (RK4, 4 sub-steps per period) and ``x`` is
corrected by Gauss-Newton steps (same ``J``, durations kept) until it, too, ends within
``attitude_tolerance_rad``.

The paths themselves (their shape and rotation, the gap ``e``, its Jacobian and the seed,
the re-timing) are :mod:`planner.nonholonomic_paths`'s; the solving and the plan are here.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from planner.attitude_control import AcsMode
from planner.dynamics import DynamicsWorkspace
from planner.errors import DidNotConverge, InvalidInput, JointLimitExceeded
from planner.frames import (
    matrix_from_quat_xyzw,
    matrix_from_rpy,
    quat_xyzw_from_matrix,
    rotvec_from_matrix,
)
from planner.model import RobotModel
from planner.nonholonomic_paths import MeetingProblem, commands, curve, grid_rotation
from planner.plan import AcsCommand, Plan, Segment, check_plan_limits, plan_for_robot
from planner.prediction import predict
from planner.ptp import COMMAND_PERIOD_S

if TYPE_CHECKING:
    from planner.robot import RobotDescription

__all__ = [
    "PAPER_PHI_MID_DEG",
    "Meeting",
    "NonholonomicParams",
    "find_meeting",
    "plan_nonholonomic",
]

Array = NDArray[np.float64]

#: The flight plan's intermediate turning point (paper section 3.6), deg. For comparison only.
PAPER_PHI_MID_DEG = (-36.4, 28.5, -20.3, -19.8, 54.3, 7.2)

_PATH_SAMPLES = 401


@dataclass(frozen=True)
class NonholonomicParams:
    """Experiment 4 (SPEC section 3). Angles in deg (roll, pitch, yaw: z-y-x), times in s."""

    phi_init_deg: tuple[float, ...] = (9.6, -2.0, 2.0, 0.0, -13.6, 0.0)
    attitude_init_deg: tuple[float, ...] = (0.0, 0.0, 0.0)
    phi_end_deg: tuple[float, ...] = (0.0,) * 6  # ETS-VII's; a robot's own in its description
    attitude_end_deg: tuple[float, ...] = (0.0, 0.0, 0.0)
    #: paths meet when their attitudes agree within this (rad); also the 4 Hz end target.
    attitude_tolerance_rad: float = 1e-7
    max_iterations: int = 40
    max_corrections: int = 5
    #: initial Levenberg-Marquardt damping, relative to the mean eigenvalue of J J^T.
    damping: float = 1e-3
    path_steps: int = 48  # RK4 steps along each path
    rate_fraction: float = 0.9  # of the joint rate limit, at the quintic's peak
    lead_s: float = 5.0
    tail_s: float = 10.0

    def __post_init__(self) -> None:
        # The joint count is the robot's (the planner checks it against the model); here both
        # joint lists must have phi_end_deg's length.
        n = len(self.phi_end_deg) if isinstance(self.phi_end_deg, tuple | list) else 0
        if n < 1:
            raise InvalidInput(
                f"phi_end_deg must be one number per joint, got {self.phi_end_deg!r}"
            )
        sizes = {"phi_init_deg": n, "attitude_init_deg": 3, "phi_end_deg": n}
        for name, size in {**sizes, "attitude_end_deg": 3}.items():
            try:
                value = np.asarray(getattr(self, name), dtype=np.float64)
            except (TypeError, ValueError) as exc:
                raise InvalidInput(f"{name} must be {size} numbers: {exc}") from exc
            if value.shape != (size,):
                what = "values (as many as phi_end_deg)" if name == "phi_init_deg" else "values"
                raise InvalidInput(f"{name} needs {size} {what}, got shape {value.shape}")
            if not np.all(np.isfinite(value)):
                raise InvalidInput(f"{name} must be finite, got {value.tolist()}")
            if size == 3 and np.max(np.abs(value)) > 180.0:
                raise InvalidInput(f"{name} {value.tolist()} exceeds limit 180 deg")
            object.__setattr__(self, name, tuple(float(v) for v in value))  # JSON-able
        _check_range("attitude_tolerance_rad", self.attitude_tolerance_rad, 1e-12, 1e-3)
        _check_range("damping", self.damping, 0.0, 1e3)
        _check_range("rate_fraction", self.rate_fraction, 1e-3, 1.0)
        for name, lowest in (("max_iterations", 1), ("max_corrections", 0), ("path_steps", 4)):
            value = getattr(self, name)
            if not isinstance(value, int) or not lowest <= value <= 10_000:
                raise InvalidInput(f"{name} {value!r} must be an integer in [{lowest}, 10000]")
        for name in ("lead_s", "tail_s"):
            value = getattr(self, name)
            _check_range(name, value, 0.0, 3600.0)
            if abs(value / COMMAND_PERIOD_S - round(value / COMMAND_PERIOD_S)) > 1e-9:
                raise InvalidInput(f"{name} {value} s is not a multiple of {COMMAND_PERIOD_S} s")


def _check_range(name: str, value: float, lo: float, hi: float) -> None:
    if not (isinstance(value, int | float) and math.isfinite(value) and lo <= value <= hi):
        raise InvalidInput(f"{name} {value!r} outside [{lo:g}, {hi:g}]")


@dataclass(frozen=True, eq=False)
class Meeting:
    """Where the forward and backward paths met (rad, base frame)."""

    joints_rad: Array  # p, (n,)
    quat_orbit_from_base_xyzw: Array  # attitude of both paths at p
    forward_joints_rad: Array  # (401, n), phi_init -> p, uniform in lam
    backward_joints_rad: Array  # (401, n), phi_end -> p
    joint_gap_rad: float  # |phi_f(1) - phi_b(1)|
    attitude_gap_rad: float  # |e|
    iterations: int
    straight_path_error_rad: float  # |e| of straight paths (no loops): what is steered away
    path_parameters: Array  # x, (5 n,)

    @property
    def paper_distance_deg(self) -> float:
        """Euclidean distance over the joints to the paper's ``phi_mid`` (deg); NaN for a
        robot of another joint count (the paper's is ETS-VII's)."""
        if self.joints_rad.shape != (len(PAPER_PHI_MID_DEG),):
            return math.nan
        return float(np.linalg.norm(np.degrees(self.joints_rad) - PAPER_PHI_MID_DEG))


# --- the meeting --------------------------------------------------------------------------


def _gauss_newton_step(jac: Array, e: Array, mu: float) -> Array:
    """Damped minimum-norm step ``-J^T (J J^T + mu tr(J J^T) / 3 I)^-1 e``."""
    jjt = jac @ jac.T
    damp = mu * float(np.trace(jjt)) / 3.0
    return np.asarray(-jac.T @ np.linalg.pinv(jjt + damp * np.eye(3)) @ e)


def _problem(ws: DynamicsWorkspace, params: NonholonomicParams) -> MeetingProblem:
    model = ws.model
    joints = {}
    for name in ("phi_init_deg", "phi_end_deg"):
        given = len(getattr(params, name))
        if given != model.n_joints:
            raise InvalidInput(f"{name} has {given} angles; this robot has {model.n_joints} joints")
        try:
            joints[name] = model.check_joints(np.radians(getattr(params, name)))
        except JointLimitExceeded as exc:
            raise JointLimitExceeded(
                exc.joint, exc.value, exc.limit, exc.unit, what=f"in {name} at"
            ) from exc
    return MeetingProblem(
        ws=ws,
        start=joints["phi_init_deg"],
        goal=joints["phi_end_deg"],
        rot_init=matrix_from_rpy(np.radians(params.attitude_init_deg)),
        rot_end=matrix_from_rpy(np.radians(params.attitude_end_deg)),
        steps=params.path_steps,
    )


def _solve_meeting(prob: MeetingProblem, params: NonholonomicParams) -> tuple[Meeting, Array]:
    mid = 0.5 * (prob.start + prob.goal)
    p_slice, fwd, bwd = prob.slices
    straight = prob.gap(*prob.rotations(np.concatenate([mid, np.zeros(4 * mid.size)])))
    x = prob.seed(mid, straight)
    g_f, g_b = prob.rotations(x)
    e = prob.gap(g_f, g_b)
    jac = np.zeros((3, x.size))
    mu = params.damping
    iterations = 0
    while float(np.linalg.norm(e)) >= params.attitude_tolerance_rad:
        if iterations == params.max_iterations:
            raise DidNotConverge(
                f"nonholonomic: at the paths' meeting (before timing) forward and backward "
                f"paths did not meet in {iterations} iterations: attitude gap "
                f"{np.linalg.norm(e):.3g} rad exceeds tolerance "
                f"{params.attitude_tolerance_rad:.3g} rad: raise max_iterations or move "
                "phi_init_deg nearer phi_end_deg"
            )
        jac = prob.jacobian(x, g_f, g_b, e)
        for _ in range(12):  # Lyapunov descent: keep a step only if V = |e|^2 / 2 decreases
            trial = x + _gauss_newton_step(jac, e, mu)
            gf, gb = prob.rotations(trial)
            e_trial = prob.gap(gf, gb)
            if np.linalg.norm(e_trial) < np.linalg.norm(e):
                x, g_f, g_b, e = trial, gf, gb, e_trial
                mu = max(mu / 10.0, 1e-12)
                break
            mu *= 10.0
        else:
            raise DidNotConverge(
                f"nonholonomic: at the paths' meeting (before timing) the meeting stalled at "
                f"an attitude gap of {np.linalg.norm(e):.3g} rad (tolerance "
                f"{params.attitude_tolerance_rad:.3g} rad): change damping or path_steps, or "
                "move phi_init_deg nearer phi_end_deg"
            )
        iterations += 1
    if not jac.any():
        jac = prob.jacobian(x, g_f, g_b, e)
    lam = np.linspace(0.0, 1.0, _PATH_SAMPLES)
    forward = curve(prob.start, x[p_slice], x[fwd], lam)[0]
    backward = curve(prob.goal, x[p_slice], x[bwd], lam)[0]
    _check_path_limits(prob.ws.model, np.vstack([forward, backward]))
    meeting = Meeting(
        joints_rad=x[p_slice].copy(),
        quat_orbit_from_base_xyzw=quat_xyzw_from_matrix(prob.rot_init @ g_f),
        forward_joints_rad=forward,
        backward_joints_rad=backward,
        joint_gap_rad=float(np.linalg.norm(forward[-1] - backward[-1])),
        attitude_gap_rad=float(np.linalg.norm(e)),
        iterations=iterations,
        straight_path_error_rad=float(np.linalg.norm(straight)),
        path_parameters=x,
    )
    return meeting, jac


def _check_path_limits(model: RobotModel, joints: Array) -> None:
    lo, hi = model.joint_limit_rad[:, 0], model.joint_limit_rad[:, 1]
    bad = np.argwhere((joints < lo) | (joints > hi))
    if bad.size:
        k, i = bad[0]
        limit = hi[i] if joints[k, i] > hi[i] else lo[i]
        raise DidNotConverge(
            f"nonholonomic: the {'forward' if k < joints.shape[0] // 2 else 'backward'} path "
            f"(before timing) met the other only beyond the joint limits: joint {i + 1} "
            f"reaches {np.degrees(joints[k, i]):.1f} deg, limit {np.degrees(limit):.1f} deg: "
            "move phi_init_deg or phi_end_deg away from that limit"
        )


def find_meeting(ws: DynamicsWorkspace, params: NonholonomicParams | None = None) -> Meeting:
    """Run the bi-directional approach (module docstring) and return where the paths met."""
    params = params or NonholonomicParams()
    return _solve_meeting(_problem(ws, params), params)[0]


# --- the final correction and the plan ----------------------------------------------------


def _correct_on_grid(
    prob: MeetingProblem, params: NonholonomicParams, x: Array, jac: Array
) -> tuple[Array, Array, tuple[int, int], int]:
    """Commands from ``phi_init`` to ``phi_end`` (k, n) whose 4 Hz linear interpolation ends
    at ``R_end``, the corrected ``x``, the period count of each path and the corrections."""
    forward, backward = commands(prob, x, params.rate_fraction, None)
    counts = (forward.shape[0] - 1, backward.shape[0] - 1)
    e_grid = np.zeros(3)
    step = np.zeros_like(x)
    jac = jac.copy()
    for corrections in range(params.max_corrections + 1):
        if corrections:
            step = _gauss_newton_step(jac, e_grid, 0.0)
            x = x + step
            forward, backward = commands(prob, x, params.rate_fraction, counts)
        joints = np.vstack([forward, backward[1:]])
        # End error of the commands in e's terms: log(R_end^T R_final) = G_b e.
        rot_final = prob.rot_init @ grid_rotation(prob.ws, joints)
        end_error = rotvec_from_matrix(prob.rot_end.T @ rot_final)
        e_prev, e_grid = e_grid, np.asarray(prob.rotations(x)[1].T @ end_error, dtype=np.float64)
        if np.linalg.norm(e_grid) < params.attitude_tolerance_rad:
            return joints, x, counts, corrections
        if corrections:
            # Broyden's update: the meeting's J is the smooth paths'; the chords' differs by
            # the discretisation, which each step measures (a vendor arm's fast joints
            # leave few commands per path, and plain Gauss-Newton on J stalled at 1e-5 rad).
            jac += np.outer(e_grid - e_prev - jac @ step, step) / float(step @ step)
    duration_s = (counts[0] + counts[1]) * COMMAND_PERIOD_S
    raise DidNotConverge(
        f"nonholonomic: at t = {params.lead_s + duration_s:.2f} s (the motion's end) the 4 Hz "
        f"commands end {np.linalg.norm(e_grid):.3g} rad from the target attitude after "
        f"{params.max_corrections} corrections (tolerance "
        f"{params.attitude_tolerance_rad:.3g} rad): raise max_corrections (at most 20), lower "
        "rate_fraction (more commands per path) or move phi_init_deg nearer phi_end_deg"
    )


def plan_nonholonomic(
    ws: DynamicsWorkspace,
    params: NonholonomicParams | None = None,
    *,
    robot: RobotDescription | None = None,
) -> Plan:
    """The experiment-4 plan: free drift, forward path to the meeting, backward path reversed.

    Raises :class:`DidNotConverge` when no meeting (or no corrected 4 Hz plan) is found,
    :class:`JointLimitExceeded` for start or goal joints outside their limits and
    :class:`InvalidInput` for joint lists of another length than the robot's joints (the
    joints are the parameters': a robot's own are its description's ``[experiments.
    nonholonomic]`` table, which :mod:`planner.catalogue` reads).
    """
    params = params or NonholonomicParams()
    if robot is not None and robot.model.n_joints != ws.model.n_joints:
        raise InvalidInput(
            f"the workspace's model has {ws.model.n_joints} joints, robot {robot.name!r} "
            f"{robot.model.n_joints}"
        )
    prob = _problem(ws, params)
    meeting, jac = _solve_meeting(prob, params)
    motion, x, counts, corrections = _correct_on_grid(prob, params, meeting.path_parameters, jac)
    period = COMMAND_PERIOD_S
    n_lead, n_tail = round(params.lead_s / period), round(params.tail_s / period)
    joints = np.vstack([np.tile(prob.start, (n_lead, 1)), motion, np.tile(prob.goal, (n_tail, 1))])
    times = np.arange(joints.shape[0], dtype=np.float64) * period
    t_meet = (n_lead + counts[0]) * period
    t_goal = t_meet + counts[1] * period
    acs = (AcsCommand(0.0, AcsMode.FREE_DRIFT),)
    quat_init = quat_xyzw_from_matrix(prob.rot_init)
    prediction = predict(
        ws, times, joints, acs_commands=acs, initial_quat_orbit_from_base_xyzw=quat_init
    )
    rot_pred = [matrix_from_quat_xyzw(q) for q in prediction.quat_orbit_from_base_xyzw]
    meeting_deg = np.degrees(meeting.joints_rad)
    metrics = {
        **{f"meeting_joint{i + 1}_deg": float(v) for i, v in enumerate(meeting_deg)},
        # the flight's meeting point is ETS-VII's: no distance for another joint count
        **(
            {"paper_meeting_distance_deg": meeting.paper_distance_deg}
            if math.isfinite(meeting.paper_distance_deg)
            else {}
        ),
        "meeting_joint_gap_rad": meeting.joint_gap_rad,
        "meeting_attitude_gap_rad": meeting.attitude_gap_rad,
        "straight_path_attitude_error_deg": math.degrees(meeting.straight_path_error_rad),
        "predicted_end_attitude_error_deg": _angle_deg(prob.rot_end.T @ rot_pred[-1]),
        "predicted_end_joint_error_deg": float(
            np.degrees(np.max(np.abs(prediction.joints_rad[-1] - prob.goal)))
        ),
        "peak_attitude_change_deg": max(_angle_deg(prob.rot_init.T @ r) for r in rot_pred),
        "max_joint_excursion_deg": float(np.degrees(np.max(np.abs(joints)))),
        "max_joint_rate_degps": float(np.degrees(np.max(np.abs(np.diff(joints, axis=0)))) / period),
        "duration_s": float(times[-1]),
        "iterations": float(meeting.iterations),
        "corrections": float(corrections),
        "correction_rad": float(np.max(np.abs(x - meeting.path_parameters))),
    }
    plan = Plan(
        experiment="nonholonomic",
        parameters={k: list(v) if isinstance(v, tuple) else v for k, v in asdict(params).items()},
        initial_joints_rad=prob.start.copy(),
        command_times_s=times,
        command_joints_rad=joints,
        segments=(
            Segment("lead", "hold", 0.0, float(params.lead_s)),
            Segment("forward", "nonholonomic", float(params.lead_s), t_meet),
            Segment("backward", "nonholonomic", t_meet, t_goal),
            Segment("tail", "hold", t_goal, float(times[-1])),
        ),
        prediction=prediction,
        metrics=metrics,
        acs_commands=acs,
        initial_quat_orbit_from_base_xyzw=quat_init,
    )
    check_plan_limits(ws.model, plan)
    return plan_for_robot(plan, robot)


def _angle_deg(rot: Array) -> float:
    return math.degrees(float(np.linalg.norm(Rotation.from_matrix(rot).as_rotvec())))
