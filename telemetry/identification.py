"""Base inertia identification from angular-momentum conservation (SPEC eq. 3, section 4).

With the arm's link parameters known, the system's angular momentum about its CoM in the
orbit frame (treated as inertial, SPEC 2),

    L(t) = R (H~_b w_b + H~_bm phi' + h_w),    H~_b = I_base + A(q),

changes only by the gravity-gradient torque (eq. 11): ``L(t) = L_0 + int N dt``. Both
``I_base w_b`` and ``N`` are linear in the six base parameters ``theta = (Ixx, Iyy, Izz,
Ixy, Ixz, Iyz)`` (Table 1's order and sign convention, :func:`planner.model.inertia_matrix`),
so every telemetry sample gives three linear equations in ``theta`` and the unknown
constant ``L_0`` of its segment (:mod:`telemetry._momentum` holds the terms):

    (R W(w) - int R G dt) theta - L_0 = int R N_arm dt - R (A w + H~_bm phi' + h_w).

Choices, and why:

- *Rates.* ``w_b`` is the gyro's (white noise, 0.0005 deg/s by default); differentiating the
  attitude would amplify its noise 100-fold at 10 Hz. Joint rates are central differences of
  the measured joints: their noise is large per sample but telescopes in the block means
  below, and the target rates would miss the servo lag.
- *Block means.* The per-sample equations are averaged over non-overlapping blocks of
  ``block_s`` (2 s): it is a linear operation on an exact balance, it cuts the gyro noise in
  the regressor (the errors-in-variables bias of least squares goes with the noise variance
  over the rate variance), and block residuals are close to independent, so the standard
  errors mean what they say.
- *Gravity gradient* is integrated from the telemetry (attitude and joints) by the trapezoid
  rule from each segment's start, with its dependence on ``theta`` kept in the regression.
  A constant ``L_0`` per segment (not one for the pass) keeps an error in that integral, or
  a telemetry gap, from leaking between segments.
- *Instrumental variables* (``method="iv"``, the default): the gyro noise sits in the
  regressor and pulls least squares toward zero on the least excited axis (on the demo
  pass Izz comes out 6 standard errors low with 1 s blocks). The instrument is the same
  design with each sample's gyro rate replaced by the mean of the samples one block before
  and after: as good a rate for a slow base, with noise independent of the block's own.
  ``method="ls"`` keeps plain (weighted) least squares.
- *Weights.* A first fit with unit weights; its residuals give the 3x3 residual covariance
  of a block, and a second pass weighted by its inverse gives the estimate, the standard
  errors (least squares: ``sqrt(diag((X' S^-1 X)^-1))``; IV: the sandwich
  ``(Z' S^-1 X)^-1 Z' S^-1 Z (X' S^-1 Z)^-1``, both scaled by the weighted residual variance)
  and the residual.
- *Segments* (:func:`find_motion_segments`): where the servo targets move (noise-free),
  padded after each motion so the base's settling (its rate change) is kept.

What excites the regression is a change of the base rate: under wheel control the base
rate stays small and the wheels absorb the arm's momentum, while free drift lets it swing.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.dynamics import DynamicsWorkspace
from planner.model import RobotModel, default_model
from telemetry._momentum import (
    INERTIA_PARAMETER_NAMES,
    InsufficientData,
    base_regressor,
    central_rates,
    inertia_from_parameters,
    momentum_samples,
    parameter_basis,
    rotations_from_quats,
)
from telemetry.recording import PassRecording

__all__ = [
    "INERTIA_PARAMETER_NAMES",
    "METHODS",
    "InertiaIdentification",
    "InsufficientData",
    "NotPositiveDefinite",
    "find_motion_segments",
    "identify_base_inertia",
    "split_at_gaps",
]

Array = NDArray[np.float64]
IndexArray = NDArray[np.intp]

#: ``ls``: (weighted) least squares; ``iv``: instrumental variables, the gyro of the
#: neighbouring blocks standing in for a block's own in the instrument.
METHODS = ("ls", "iv")

#: Servo-target rate (any joint) above which the arm counts as moving (0.01 deg/s).
MOTION_RATE_RADPS = np.radians(0.01)


def find_motion_segments(
    recording: PassRecording,
    *,
    rate_threshold_radps: float = float(MOTION_RATE_RADPS),
    pad_before_s: float = 2.0,
    pad_after_s: float = 30.0,
    min_duration_s: float = 5.0,
) -> tuple[tuple[float, float], ...]:
    """Plan-clock intervals ``(t_start_s, t_end_s)`` where the arm moves, from the servo
    targets' rates (noise-free), widened by the pads (the base settles after a motion),
    merged where they overlap and clipped to the recording; shorter ones are dropped."""
    t = recording.t_s()
    if len(t) < 3:
        return ()
    rates = np.abs(central_rates(t, recording.frames.joint_targets_rad)).max(axis=1)
    moving = rates > rate_threshold_radps
    intervals: list[list[float]] = []
    for k in np.flatnonzero(moving):
        lo, hi = float(t[k]) - pad_before_s, float(t[k]) + pad_after_s
        if intervals and lo <= intervals[-1][1]:
            intervals[-1][1] = max(intervals[-1][1], hi)
        else:
            intervals.append([lo, hi])
    t0, t1 = float(t[0]), float(t[-1])
    out = []
    for lo, hi in intervals:
        lo, hi = max(lo, t0), min(hi, t1)
        if hi - lo >= min_duration_s:
            out.append((lo, hi))
    return tuple(out)


def split_at_gaps(t_s: Array, rows: IndexArray, *, max_gap_factor: float = 1.5) -> list[IndexArray]:
    """``rows`` (indices into ``t_s``) split wherever the time step exceeds
    ``max_gap_factor`` times the recording's median step (a lost or dropped frame)."""
    if len(rows) == 0:
        return []
    step = float(np.median(np.diff(t_s))) if len(t_s) > 1 else 0.0
    gaps = np.flatnonzero(np.diff(t_s[rows]) > max_gap_factor * step) + 1
    return [np.asarray(part, dtype=np.intp) for part in np.split(rows, gaps)]


@dataclass(frozen=True, eq=False)
class InertiaIdentification:
    """The identified base inertia (about the base CoM, base frame, wheels locked).

    ``parameters_kgm2`` and ``standard_error_kgm2`` are in :data:`INERTIA_PARAMETER_NAMES`
    order; ``principal_moments_kgm2`` are the eigenvalues (ascending) with first-order
    standard errors. ``residual_rms_nms`` is the per-axis RMS of the weighted fit's block
    residuals (orbit frame); ``condition_number`` is that of the weighted design matrix with
    unit-norm columns (``L_0`` columns included).
    """

    parameters_kgm2: Array
    standard_error_kgm2: Array
    covariance_kgm4: Array
    principal_moments_kgm2: Array
    principal_standard_error_kgm2: Array
    initial_momentum_orbit_nms: Array  # (segments, 3): L_0 of each segment
    residual_rms_nms: Array
    segments: tuple[tuple[float, float], ...]
    n_samples: int
    n_blocks: int
    block_s: float
    condition_number: float

    @property
    def inertia_kgm2(self) -> Array:
        return inertia_from_parameters(self.parameters_kgm2)

    @property
    def moments_kgm2(self) -> Array:
        """``(Ixx, Iyy, Izz)``."""
        return np.asarray(self.parameters_kgm2[:3])

    @property
    def products_kgm2(self) -> Array:
        """``(Ixy, Ixz, Iyz)``."""
        return np.asarray(self.parameters_kgm2[3:])

    def to_dict(self) -> dict[str, Any]:
        names = INERTIA_PARAMETER_NAMES
        return {
            "parameters_kgm2": {
                n: float(v) for n, v in zip(names, self.parameters_kgm2, strict=True)
            },
            "standard_error_kgm2": {
                n: float(v) for n, v in zip(names, self.standard_error_kgm2, strict=True)
            },
            "inertia_kgm2": self.inertia_kgm2.tolist(),
            "covariance_kgm4": np.asarray(self.covariance_kgm4).tolist(),
            "principal_moments_kgm2": np.asarray(self.principal_moments_kgm2).tolist(),
            "principal_standard_error_kgm2": np.asarray(
                self.principal_standard_error_kgm2
            ).tolist(),
            "initial_momentum_orbit_nms": np.asarray(self.initial_momentum_orbit_nms).tolist(),
            "residual_rms_nms": np.asarray(self.residual_rms_nms).tolist(),
            "segments_s": [[float(a), float(b)] for a, b in self.segments],
            "n_samples": int(self.n_samples),
            "n_blocks": int(self.n_blocks),
            "block_s": float(self.block_s),
            "condition_number": float(self.condition_number),
        }


@dataclass(frozen=True, eq=False)
class _Blocks:
    design: Array  # (blocks, 3, 6)
    instrument: Array  # (blocks, 3, 6): the design with the neighbouring blocks' gyro
    response: Array  # (blocks, 3)
    n_samples: int


def _neighbour_rates(omega: Array, shift: int) -> Array:
    """Each sample's rate replaced by the mean of the samples ``shift`` before and after it
    (the one that exists at the ends): noise independent of the sample's own."""
    n = len(omega)
    idx = np.arange(n)
    before, after = idx - shift, idx + shift
    has_b, has_a = before >= 0, after < n
    out = np.zeros_like(omega)
    count = (has_b.astype(float) + has_a.astype(float))[:, None]
    out[has_b] += omega[before[has_b]]
    out[has_a] += omega[after[has_a]]
    return np.asarray(np.where(count > 0, out / np.maximum(count, 1.0), omega))


def _segment_blocks(
    ws: DynamicsWorkspace, recording: PassRecording, rows: IndexArray, block: int
) -> _Blocks | None:
    f = recording.frames
    t = recording.t_s()[rows]
    joints = f.joints_rad[rows]
    s = momentum_samples(
        ws,
        joints_rad=joints,
        joint_rates_radps=central_rates(t, joints),
        omega_base_in_base_radps=f.omega_base_in_base_radps[rows],
        wheel_momentum_nms=f.wheel_momentum_nms[rows],
        rot_orbit_from_base=rotations_from_quats(f.quat_orbit_from_base_xyzw[rows]),
    )
    dt = np.diff(t)

    def integral(rate: Array) -> Array:
        steps = 0.5 * (rate[1:] + rate[:-1]) * dt.reshape((-1,) + (1,) * (rate.ndim - 1))
        return np.concatenate([np.zeros((1, *rate.shape[1:])), np.cumsum(steps, axis=0)])

    gg = integral(s.gg_regressor)
    design = s.base_regressor - gg
    omega_iv = _neighbour_rates(f.omega_base_in_base_radps[rows], block)
    instrument = base_regressor(s.rot_orbit_from_base, omega_iv) - gg
    response = integral(s.gg_known) - s.known_momentum
    n_blocks = len(rows) // block
    if n_blocks < 1:
        return None
    used = n_blocks * block
    return _Blocks(
        design=design[:used].reshape(n_blocks, block, 3, 6).mean(axis=1),
        instrument=instrument[:used].reshape(n_blocks, block, 3, 6).mean(axis=1),
        response=response[:used].reshape(n_blocks, block, 3).mean(axis=1),
        n_samples=used,
    )


def _weighted_fit(
    x: Array, z: Array, y: Array, n_blocks: int, weight: Array
) -> tuple[Array, Array, Array, Array]:
    """Weighted instrumental-variable fit (least squares when ``z is x``) with the 3x3
    block weight. Returns the solution, its unscaled covariance, the residuals (blocks, 3)
    and the weighted design."""
    chol = np.linalg.cholesky(weight)  # weight = chol chol'

    def whiten(a: Array) -> Array:
        blocks = a.reshape(n_blocks, 3, -1)
        return np.asarray(np.einsum("ij,bjp->bip", chol.T, blocks)).reshape(3 * n_blocks, -1)

    wx, wz, wy = whiten(x), whiten(z), whiten(y).reshape(-1)
    zx_inv = np.linalg.inv(wz.T @ wx)
    sol = zx_inv @ (wz.T @ wy)
    cov = zx_inv @ (wz.T @ wz) @ zx_inv.T
    resid = (y - x @ sol).reshape(n_blocks, 3)
    return sol, cov, resid, wx


class NotPositiveDefinite(ValueError):
    """An identified inertia no rigid body can have (a principal moment <= 0, or not
    finite): refused, never reported as a result."""


def identify_base_inertia(
    recording: PassRecording,
    model: RobotModel | None = None,
    *,
    segments: Sequence[tuple[float, float]] | None = None,
    block_s: float = 2.0,
    method: str = "iv",
) -> InertiaIdentification:
    """Identify the base inertia from the recording (see the module doc).

    ``model`` gives the arm's link parameters, the base mass and the orbit (its base inertia
    is not used); ``segments`` are plan-clock intervals ``(t_start_s, t_end_s)``, by default
    :func:`find_motion_segments`. Raises :class:`InsufficientData` when fewer blocks remain
    than unknowns, :class:`NotPositiveDefinite` when the estimate is not a positive definite
    inertia.
    """
    if method not in METHODS:
        raise ValueError(f"method {method!r} is not one of {METHODS}")
    model = model or default_model()
    ws = DynamicsWorkspace(model)
    chosen = tuple(segments) if segments is not None else find_motion_segments(recording)
    t = recording.t_s()
    period = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    block = max(1, round(block_s / period)) if period > 0 else 1
    parts: list[_Blocks] = []
    used: list[tuple[float, float]] = []
    for lo, hi in chosen:
        rows = np.flatnonzero((t >= lo) & (t <= hi)).astype(np.intp)
        for piece in split_at_gaps(t, rows):
            blocks = _segment_blocks(ws, recording, piece, block) if len(piece) > 1 else None
            if blocks is not None:
                parts.append(blocks)
                used.append((float(t[piece[0]]), float(t[piece[0] + blocks.n_samples - 1])))
    n_seg = len(parts)
    n_blocks = sum(len(p.response) for p in parts)
    n_unknowns = 6 + 3 * n_seg
    if n_seg == 0 or 3 * n_blocks <= n_unknowns:
        raise InsufficientData(
            f"{n_blocks} blocks of {block_s} s in {n_seg} segments give {3 * n_blocks} "
            f"equations for {n_unknowns} unknowns (need more)"
        )
    x = np.zeros((n_blocks, 3, n_unknowns))
    z = np.zeros((n_blocks, 3, n_unknowns))
    y = np.zeros((n_blocks, 3))
    b = 0
    for s, part in enumerate(parts):
        nb = len(part.response)
        x[b : b + nb, :, :6] = part.design
        z[b : b + nb, :, :6] = part.instrument if method == "iv" else part.design
        x[b : b + nb, :, 6 + 3 * s : 9 + 3 * s] = -np.eye(3)
        z[b : b + nb, :, 6 + 3 * s : 9 + 3 * s] = -np.eye(3)
        y[b : b + nb] = part.response
        b += nb
    x2, z2 = x.reshape(3 * n_blocks, n_unknowns), z.reshape(3 * n_blocks, n_unknowns)
    y2 = y.reshape(-1)
    _, _, resid, _ = _weighted_fit(x2, z2, y2, n_blocks, np.eye(3))
    dof = 3 * n_blocks - n_unknowns
    cov_block = resid.T @ resid / (dof / 3.0)
    weight = np.asarray(np.linalg.inv(cov_block), dtype=np.float64)
    sol, normal_inv, resid, wx = _weighted_fit(x2, z2, y2, n_blocks, weight)
    # Scale by the weighted residual variance (1 if the block covariance is right).
    wr = np.linalg.solve(np.linalg.cholesky(cov_block), resid.T)
    scale = float(np.sum(wr**2)) / dof
    cov = normal_inv * scale
    theta = sol[:6]
    cov_theta = cov[:6, :6]
    col = wx / np.linalg.norm(wx, axis=0)
    eig, vec = np.linalg.eigh(inertia_from_parameters(theta))
    basis = parameter_basis()
    grad = np.array([[vec[:, i] @ basis[j] @ vec[:, i] for j in range(6)] for i in range(3)])
    principal_se = np.sqrt(np.einsum("ij,jk,ik->i", grad, cov_theta, grad))
    if not (np.all(np.isfinite(theta)) and eig[0] > 0.0):
        moments = ", ".join(f"{m:.6g} +- {e:.3g}" for m, e in zip(eig, principal_se, strict=True))
        raise NotPositiveDefinite(
            f"the identified base inertia is not positive definite: principal moments "
            f"[{moments}] kg m^2 (no body has these; the telemetry cannot support an "
            "identification)"
        )
    return InertiaIdentification(
        parameters_kgm2=theta,
        standard_error_kgm2=np.sqrt(np.diag(cov_theta)),
        covariance_kgm4=cov_theta,
        principal_moments_kgm2=eig,
        principal_standard_error_kgm2=principal_se,
        initial_momentum_orbit_nms=sol[6:].reshape(n_seg, 3),
        residual_rms_nms=np.sqrt(np.mean(resid**2, axis=0)),
        segments=tuple(used),
        n_samples=sum(p.n_samples for p in parts),
        n_blocks=n_blocks,
        block_s=block * period,
        condition_number=float(np.linalg.cond(col)),
    )
