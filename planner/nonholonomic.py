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

**Re-timing.** Each path is re-parametrised by ``sigma``, the time it takes at every joint's
full rate limit (``d sigma = max_i |d phi_i| / rate_limit_i``), and run on the quintic
``sigma(t) = L quintic(t / T)`` (zero rate and acceleration at both ends) with
``T = 15/8 L / rate_fraction`` rounded up to whole 0.25 s periods; the arm stops at ``p``.
Commands are samples of the curves, 0.25 s apart from t = 0, after ``lead_s`` at
``phi_init`` and followed by ``tail_s`` at ``phi_end``.

**Final correction.** On board the joints move *linearly* between commands: chords, not the
curve, and the attitude is path dependent. The rotation of the command sequence is integrated
as :func:`planner.prediction.predict` does (RK4, 4 sub-steps per period) and ``x`` is
corrected by Gauss-Newton steps (same ``J``, durations kept) until it, too, ends within
``attitude_tolerance_rad``.
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
    skew,
)
from planner.model import RobotModel
from planner.plan import AcsCommand, Plan, Segment, check_plan_limits, plan_for_robot
from planner.prediction import predict
from planner.ptp import COMMAND_PERIOD_S, QUINTIC_PEAK_RATE_FACTOR, quintic

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

_FD_STEP = 1e-7  # rad, forward-difference step of J
_RETIME_SAMPLES = 2001
_PATH_SAMPLES = 401
_SUB_STEPS = 4  # as planner.prediction.predict


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


def _layout(n: int) -> tuple[slice, slice, slice]:
    """``x``'s layout for n joints: p, then forward a_1, a_2, then backward b_1, b_2."""
    return slice(0, n), slice(n, 3 * n), slice(3 * n, 5 * n)


# --- paths and their rotation -------------------------------------------------------------


def _curve(start: Array, p: Array, coeffs: Array, lam: Array) -> tuple[Array, Array]:
    """Joints (m, n) and d phi / d lam (m, n) of a path at ``lam`` (m,); ``coeffs`` (2 n,)."""
    c = coeffs.reshape(2, start.size)
    k_pi = np.pi * np.arange(1, 3)[:, None]
    shape = np.sin(k_pi * lam)  # (2, m)
    joints = start + lam[:, None] * (p - start) + shape.T @ c
    rates = (p - start) + (k_pi * np.cos(k_pi * lam)).T @ c
    return joints, rates


def _base_rates(ws: DynamicsWorkspace, joints: Array, rates: Array) -> Array:
    """Eq. (9), base frame: ``A(phi) phi'`` per row (m, 3)."""
    h_b = np.empty((joints.shape[0], 3, 3))
    h_bm_rate = np.empty((joints.shape[0], 3))
    for k, (q, r) in enumerate(zip(joints, rates, strict=True)):
        hb, hbm = ws.momentum_blocks(q)
        h_b[k], h_bm_rate[k] = hb, hbm @ r
    return np.asarray(-np.linalg.solve(h_b, h_bm_rate[:, :, None])[:, :, 0], dtype=np.float64)


def _omega_matrix(w: Array) -> Array:
    """(m, 4, 4) with ``M @ q == quat_multiply_xyzw(q, (w, 0))``, scalar-last ``q``."""
    x, y, z = w[:, 0], w[:, 1], w[:, 2]
    o = np.zeros_like(x)
    rows = [[o, z, -y, x], [-z, o, x, y], [y, -x, o, z], [-x, -y, -z, o]]
    return np.moveaxis(np.array(rows), (0, 1), (1, 2))


def _rk4_rotation(w0: Array, wm: Array, w1: Array, h: float) -> Array:
    """``G`` (3, 3) of ``G' = G [w]x`` from the identity over steps of ``h`` with body rates at
    each step's start, midpoint and end (n, 3) each; RK4 on the quaternion as in predict."""
    m0, mm, m1 = (0.5 * _omega_matrix(w) for w in (w0, wm, w1))
    q = np.array([0.0, 0.0, 0.0, 1.0])
    for a, b, c in zip(m0, mm, m1, strict=True):
        k1 = a @ q
        y = q + 0.5 * h * k1
        k2 = b @ _unit(y)
        y = q + 0.5 * h * k2
        k3 = b @ _unit(y)
        y = q + h * k3
        k4 = c @ _unit(y)
        q = _unit(q + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4))
    return matrix_from_quat_xyzw(q)


def _unit(y: Array) -> Array:
    """``y / np.linalg.norm(y)`` with the norm's own arithmetic, without its wrapper (the
    loop above runs a hundred thousand times per meeting)."""
    return y / math.sqrt(y.dot(y))


def _path_rotation(ws: DynamicsWorkspace, start: Array, p: Array, coeffs: Array, n: int) -> Array:
    lam = np.linspace(0.0, 1.0, 2 * n + 1)
    w = _base_rates(ws, *_curve(start, p, coeffs, lam))
    return _rk4_rotation(w[0:-1:2], w[1::2], w[2::2], 1.0 / n)


def _grid_rotation(ws: DynamicsWorkspace, joints: Array) -> Array:
    """Rotation of linearly interpolated 4 Hz commands (k, n), as predict integrates it."""
    n = joints.shape[1]
    step = np.diff(joints, axis=0)
    moving = np.flatnonzero(np.any(step != 0.0, axis=1))
    tau = np.linspace(0.0, 1.0, 2 * _SUB_STEPS + 1)
    pts = joints[moving][:, None, :] + tau[None, :, None] * step[moving][:, None, :]
    rates = np.broadcast_to(step[moving][:, None, :] / COMMAND_PERIOD_S, pts.shape)
    w = _base_rates(ws, pts.reshape(-1, n), rates.reshape(-1, n)).reshape((*pts.shape[:2], 3))
    h = COMMAND_PERIOD_S / _SUB_STEPS
    return _rk4_rotation(
        w[:, 0:-1:2].reshape(-1, 3), w[:, 1::2].reshape(-1, 3), w[:, 2::2].reshape(-1, 3), h
    )


# --- the meeting --------------------------------------------------------------------------


@dataclass(frozen=True)
class _Problem:
    ws: DynamicsWorkspace
    start: Array
    goal: Array
    rot_init: Array  # rot_orbit_from_base at the start
    rot_end: Array
    steps: int

    @property
    def slices(self) -> tuple[slice, slice, slice]:
        return _layout(self.start.size)

    def rotations(self, x: Array) -> tuple[Array, Array]:
        p, fwd, bwd = self.slices
        g_f = _path_rotation(self.ws, self.start, x[p], x[fwd], self.steps)
        g_b = _path_rotation(self.ws, self.goal, x[p], x[bwd], self.steps)
        return g_f, g_b

    def gap(self, g_f: Array, g_b: Array) -> Array:
        """``e = log(R_b^T R_f)`` at the meeting (rad)."""
        rot = (self.rot_end @ g_b).T @ self.rot_init @ g_f
        return np.asarray(Rotation.from_matrix(rot).as_rotvec(), dtype=np.float64)

    def jacobian(self, x: Array, g_f: Array, g_b: Array, e: Array) -> Array:
        p, fwd, bwd = self.slices
        jac = np.empty((3, x.size))
        for i in range(x.size):
            xi = x.copy()
            xi[i] += _FD_STEP
            if i < fwd.start:  # p moves both paths' ends
                gf, gb = self.rotations(xi)
            elif i < fwd.stop:
                gf, gb = _path_rotation(self.ws, self.start, xi[p], xi[fwd], self.steps), g_b
            else:
                gf, gb = g_f, _path_rotation(self.ws, self.goal, xi[p], xi[bwd], self.steps)
            jac[:, i] = (self.gap(gf, gb) - e) / _FD_STEP
        return jac

    def seed(self, mid: Array, e0: Array) -> Array:
        """One loop per path in the plane of largest curvature about ``e0``'s axis."""
        n = mid.size
        x = np.concatenate([mid, np.zeros(4 * n)])
        norm = float(np.linalg.norm(e0))
        if norm == 0.0:
            return x
        eps = 1e-5
        reaction = _reaction(self.ws, mid)
        d_reaction = np.array(  # [i] = dA / dphi_i, (n, 3, n)
            [
                _reaction(self.ws, mid + eps * d) - _reaction(self.ws, mid - eps * d)
                for d in np.eye(n)
            ]
        ) / (2.0 * eps)
        # Curvature of w = A dphi, F_ij = d_i A_j - d_j A_i + A_i x A_j, along e0's axis.
        axis = e0 / norm
        grad = np.einsum("k,ikj->ij", axis, d_reaction)
        curv = grad - grad.T - reaction.T @ skew(axis) @ reaction
        # ``curv`` is antisymmetric: it turns its top invariant plane by 90 deg and scales it
        # by the top singular value (a pair). Any orthonormal (u, v) of that plane serves; u is
        # pinned to the joint axis closest to the plane so that round-off cannot turn it.
        vecs, sing, _ = np.linalg.svd(curv)
        proj = vecs[:, :2] @ vecs[:, :2].T
        u = proj[:, int(np.argmax(np.diag(proj)))]
        u = u / np.linalg.norm(u)
        v = curv @ u / np.linalg.norm(curv @ u)
        # A loop (s u sin(pi lam), s v sin(2 pi lam)) encloses 4/3 s^2; half of e0 per path.
        s = math.sqrt(3.0 * norm / (8.0 * max(float(sing[0]), 1e-12)))
        best, best_gap = x, math.inf
        for sign in (1.0, -1.0):  # the loop's sense
            cand = np.concatenate([mid, s * u, sign * s * v, s * u, -sign * s * v])
            gap = float(np.linalg.norm(self.gap(*self.rotations(cand))))
            if gap < best_gap:
                best, best_gap = cand, gap
        return best


def _reaction(ws: DynamicsWorkspace, joints: Array) -> Array:
    h_b, h_bm = ws.momentum_blocks(joints)
    return np.asarray(-np.linalg.solve(h_b, h_bm))


def _gauss_newton_step(jac: Array, e: Array, mu: float) -> Array:
    """Damped minimum-norm step ``-J^T (J J^T + mu tr(J J^T) / 3 I)^-1 e``."""
    jjt = jac @ jac.T
    damp = mu * float(np.trace(jjt)) / 3.0
    return np.asarray(-jac.T @ np.linalg.pinv(jjt + damp * np.eye(3)) @ e)


def _problem(ws: DynamicsWorkspace, params: NonholonomicParams) -> _Problem:
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
    return _Problem(
        ws=ws,
        start=joints["phi_init_deg"],
        goal=joints["phi_end_deg"],
        rot_init=matrix_from_rpy(np.radians(params.attitude_init_deg)),
        rot_end=matrix_from_rpy(np.radians(params.attitude_end_deg)),
        steps=params.path_steps,
    )


def _solve_meeting(prob: _Problem, params: NonholonomicParams) -> tuple[Meeting, Array]:
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
    forward = _curve(prob.start, x[p_slice], x[fwd], lam)[0]
    backward = _curve(prob.goal, x[p_slice], x[bwd], lam)[0]
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


# --- re-timing and the plan ---------------------------------------------------------------


def _path_commands(
    model: RobotModel, start: Array, p: Array, coeffs: Array, rate_fraction: float, n: int | None
) -> Array:
    """Commands (n + 1, joints) along a path, 0.25 s apart, on the quintic in ``sigma``."""
    lam = np.linspace(0.0, 1.0, _RETIME_SAMPLES)
    rates = _curve(start, p, coeffs, lam)[1]
    speed = np.max(np.abs(rates) / model.joint_rate_limit_radps, axis=1)  # s per unit lam
    sigma = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(lam))])
    if n is None:
        full_s = QUINTIC_PEAK_RATE_FACTOR * sigma[-1] / rate_fraction
        n = max(1, math.ceil(full_s / COMMAND_PERIOD_S - 1e-9))
    s = sigma[-1] * quintic(np.arange(n + 1) / n)
    joints = _curve(start, p, coeffs, np.interp(s, sigma, lam))[0]
    joints[0], joints[-1] = start, p
    return joints


def _commands(
    prob: _Problem, x: Array, params: NonholonomicParams, n: tuple[int, int] | None
) -> tuple[Array, Array]:
    """(forward, reversed backward) commands; each path's period count grows until every
    joint stays within ``rate_fraction`` of its limit (sigma is sampled, not exact)."""
    model = prob.ws.model
    counts: list[int | None] = [None, None] if n is None else list(n)
    legs = []
    p, fwd, bwd = prob.slices
    for leg, (start, coeffs) in enumerate(((prob.start, x[fwd]), (prob.goal, x[bwd]))):
        for _ in range(4):
            joints = _path_commands(model, start, x[p], coeffs, params.rate_fraction, counts[leg])
            worst = np.max(
                np.abs(np.diff(joints, axis=0))
                / COMMAND_PERIOD_S
                / (params.rate_fraction * model.joint_rate_limit_radps)
            )
            if n is not None or worst <= 1.0 + 1e-12:
                break
            counts[leg] = math.ceil((joints.shape[0] - 1) * worst)
        legs.append(joints)
    return legs[0], legs[1][::-1]


def _correct_on_grid(
    prob: _Problem, params: NonholonomicParams, x: Array, jac: Array
) -> tuple[Array, Array, tuple[int, int], int]:
    """Commands from ``phi_init`` to ``phi_end`` (k, n) whose 4 Hz linear interpolation ends
    at ``R_end``, the corrected ``x``, the period count of each path and the corrections."""
    forward, backward = _commands(prob, x, params, None)
    counts = (forward.shape[0] - 1, backward.shape[0] - 1)
    e_grid = np.zeros(3)
    step = np.zeros_like(x)
    jac = jac.copy()
    for corrections in range(params.max_corrections + 1):
        if corrections:
            step = _gauss_newton_step(jac, e_grid, 0.0)
            x = x + step
            forward, backward = _commands(prob, x, params, counts)
        joints = np.vstack([forward, backward[1:]])
        # End error of the commands in e's terms: log(R_end^T R_final) = G_b e.
        rot_final = prob.rot_init @ _grid_rotation(prob.ws, joints)
        end_error = Rotation.from_matrix(prob.rot_end.T @ rot_final).as_rotvec()
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
