"""The bi-directional approach's paths (:mod:`planner.nonholonomic`, which describes the
method): their shape, the rotation they leave, the meeting's gap with its Jacobian and its
seed, and their re-timing into 4 Hz commands.

A path runs from ``start`` to the meeting point ``p`` (:func:`curve`)::

    phi(lam) = start + lam (p - start) + sum_k c_k sin(k pi lam)      k = 1, 2, lam in [0, 1]

and the rotation it leaves is eq. (9) integrated in ``lam`` by RK4 on the quaternion;
:func:`grid_rotation` integrates the 4 Hz chords of commands the way
:func:`planner.prediction.predict` does. :class:`MeetingProblem` holds the start, the goal
and their attitudes, and gives, for the path parameters ``x = (p, a_1, a_2, b_1, b_2)``, the
gap ``e(x) = log(R_b(1)^T R_f(1))``, its Jacobian (forward differences) and the seed (one
loop per path in the joint plane of largest curvature).

**Re-timing.** Each path is re-parametrised by ``sigma``, the time it takes at every joint's
full rate limit (``d sigma = max_i |d phi_i| / rate_limit_i``), and run on the quintic
``sigma(t) = L quintic(t / T)`` (zero rate and acceleration at both ends) with
``T = 15/8 L / rate_fraction`` rounded up to whole 0.25 s periods; the arm stops at ``p``.
Commands are samples of the curves, 0.25 s apart (:func:`commands`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from planner.dynamics import DynamicsWorkspace
from planner.frames import matrix_from_quat_xyzw, rotvec_from_matrix, skew
from planner.model import RobotModel
from planner.ptp import COMMAND_PERIOD_S, QUINTIC_PEAK_RATE_FACTOR, quintic

__all__ = ["MeetingProblem", "commands", "curve", "grid_rotation"]

Array = NDArray[np.float64]

_FD_STEP = 1e-7  # rad, forward-difference step of J
_RETIME_SAMPLES = 2001
_SUB_STEPS = 4  # as planner.prediction.predict


def _layout(n: int) -> tuple[slice, slice, slice]:
    """``x``'s layout for n joints: p, then forward a_1, a_2, then backward b_1, b_2."""
    return slice(0, n), slice(n, 3 * n), slice(3 * n, 5 * n)


# --- paths and their rotation -------------------------------------------------------------


def curve(start: Array, p: Array, coeffs: Array, lam: Array) -> tuple[Array, Array]:
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
    w = _base_rates(ws, *curve(start, p, coeffs, lam))
    return _rk4_rotation(w[0:-1:2], w[1::2], w[2::2], 1.0 / n)


def grid_rotation(ws: DynamicsWorkspace, joints: Array) -> Array:
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


# --- the meeting's problem ----------------------------------------------------------------


@dataclass(frozen=True)
class MeetingProblem:
    """Paths from ``start`` (at ``rot_init``) and from ``goal`` (at ``rot_end``) to meet
    between, each integrated in ``steps`` RK4 steps; ``x`` is laid out p, a_1, a_2, b_1, b_2."""

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
        return rotvec_from_matrix(rot)

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


# --- re-timing -----------------------------------------------------------------------------


def _path_commands(
    model: RobotModel, start: Array, p: Array, coeffs: Array, rate_fraction: float, n: int | None
) -> Array:
    """Commands (n + 1, joints) along a path, 0.25 s apart, on the quintic in ``sigma``."""
    lam = np.linspace(0.0, 1.0, _RETIME_SAMPLES)
    rates = curve(start, p, coeffs, lam)[1]
    speed = np.max(np.abs(rates) / model.joint_rate_limit_radps, axis=1)  # s per unit lam
    sigma = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(lam))])
    if n is None:
        full_s = QUINTIC_PEAK_RATE_FACTOR * sigma[-1] / rate_fraction
        n = max(1, math.ceil(full_s / COMMAND_PERIOD_S - 1e-9))
    s = sigma[-1] * quintic(np.arange(n + 1) / n)
    joints = curve(start, p, coeffs, np.interp(s, sigma, lam))[0]
    joints[0], joints[-1] = start, p
    return joints


def commands(
    prob: MeetingProblem, x: Array, rate_fraction: float, n: tuple[int, int] | None
) -> tuple[Array, Array]:
    """(forward, reversed backward) commands; each path's period count grows until every
    joint stays within ``rate_fraction`` of its limit (sigma is sampled, not exact)."""
    model = prob.ws.model
    counts: list[int | None] = [None, None] if n is None else list(n)
    legs = []
    p, fwd, bwd = prob.slices
    for leg, (start, coeffs) in enumerate(((prob.start, x[fwd]), (prob.goal, x[bwd]))):
        for _ in range(4):
            joints = _path_commands(model, start, x[p], coeffs, rate_fraction, counts[leg])
            worst = np.max(
                np.abs(np.diff(joints, axis=0))
                / COMMAND_PERIOD_S
                / (rate_fraction * model.joint_rate_limit_radps)
            )
            if n is not None or worst <= 1.0 + 1e-12:
                break
            counts[leg] = math.ceil((joints.shape[0] - 1) * worst)
        legs.append(joints)
    return legs[0], legs[1][::-1]
