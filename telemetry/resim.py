"""Gravity-gradient re-simulation of free-drift segments (SPEC section 4, paper Fig. 12).

In free drift the wheels apply no torque, so the system's angular momentum about its CoM in
the orbit frame (treated as inertial) changes only by the gravity-gradient torque, eq. (11):

    dL/dt = R N(H~_b(q), R)    (or 0 without it),
    w_b   = H~_b(q)^-1 (R' L - H~_bm(q) phi' - h_w),    dR/dt = R [w_b]x.

The recorded joint motion drives this model kinematically: the measured joint angles,
linear between telemetry samples (so the joint rates over an interval are the difference of
its ends over its length: encoder noise telescopes instead of piling up in the attitude),
and the recorded wheel momentum, linear between samples. No servo model enters. The
attitude and momentum are integrated by RK4 with ``substeps`` steps per telemetry interval.

Initial conditions, from the first ``initial_window_s`` of the segment (a single sample's
gyro noise, 0.0005 deg/s, would make a drift of 0.05 deg over 100 s on its own):

- momentum: the mean of ``L_k`` (eq. 3 with the model's inertia, gyro rate, central-difference
  joint rates) over the window, each sample's known gravity-gradient impulse since the start
  taken off for the run with it;
- attitude: the first recorded sample, then corrected by the mean residual over the window
  and the run repeated.

Residuals are the rotation vector of ``rot_orbit_from_base_recorded^T @ rot_sim``, base frame
components (about roll x, pitch y, yaw z), in rad inside and deg in :meth:`to_dict`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from planner.dynamics import DynamicsWorkspace
from planner.free_drift import quat_multiply_xyzw
from planner.gravity_gradient import gravity_gradient_torque_base_nm
from planner.model import RobotModel, default_model
from telemetry._momentum import InsufficientData, rotations_from_quats
from telemetry.identification import split_at_gaps
from telemetry.recording import PassRecording

__all__ = [
    "FREE_DRIFT_MODE",
    "GravityGradientResim",
    "InsufficientData",
    "ResimRun",
    "SegmentResim",
    "find_free_drift_segments",
    "resimulate_free_drift",
]

Array = NDArray[np.float64]

#: ``acs_mode`` of a telemetry frame in free drift (telemetry.wire.AcsModeName).
FREE_DRIFT_MODE = "free_drift"


def find_free_drift_segments(
    recording: PassRecording, *, min_duration_s: float = 10.0
) -> tuple[tuple[float, float], ...]:
    """Plan-clock intervals of consecutive free-drift frames (split at telemetry gaps),
    at least ``min_duration_s`` long."""
    t = recording.t_s()
    free = np.flatnonzero(recording.frames.acs_mode == FREE_DRIFT_MODE).astype(np.intp)
    runs = np.split(free, np.flatnonzero(np.diff(free) > 1) + 1) if len(free) else []
    out = []
    for run in runs:
        for piece in split_at_gaps(t, run):
            if len(piece) > 1 and t[piece[-1]] - t[piece[0]] >= min_duration_s:
                out.append((float(t[piece[0]]), float(t[piece[-1]])))
    return tuple(out)


@dataclass(frozen=True, eq=False)
class ResimRun:
    """One re-simulation of a segment, with or without the gravity-gradient torque."""

    gravity_gradient: bool
    quat_orbit_from_base_xyzw: Array  # (k, 4), at the segment's telemetry times
    residual_base_rad: Array  # (k, 3), rotvec of R_rec' R_sim, base frame

    @property
    def rms_residual_rad(self) -> Array:
        return np.asarray(np.sqrt(np.mean(self.residual_base_rad**2, axis=0)))

    @property
    def final_residual_rad(self) -> Array:
        return np.asarray(self.residual_base_rad[-1])

    @property
    def rms_residual_angle_rad(self) -> float:
        """RMS of the residual rotation's angle (all axes)."""
        return float(np.sqrt(np.mean(np.sum(self.residual_base_rad**2, axis=1))))

    def to_dict(self) -> dict[str, Any]:
        return {
            "gravity_gradient": self.gravity_gradient,
            "rms_residual_deg": np.degrees(self.rms_residual_rad).tolist(),
            "final_residual_deg": np.degrees(self.final_residual_rad).tolist(),
            "rms_residual_angle_deg": float(np.degrees(self.rms_residual_angle_rad)),
            "quat_orbit_from_base_xyzw": np.asarray(self.quat_orbit_from_base_xyzw).tolist(),
        }


@dataclass(frozen=True, eq=False)
class SegmentResim:
    """Both runs of one free-drift segment. ``gg_impulse_orbit_nms`` is the gravity-gradient
    torque's integral over the segment along the recorded motion (orbit frame)."""

    t_start_s: float
    t_end_s: float
    t_s: Array
    with_gg: ResimRun
    without_gg: ResimRun
    gg_impulse_orbit_nms: Array

    def to_dict(self) -> dict[str, Any]:
        return {
            "t_start_s": float(self.t_start_s),
            "t_end_s": float(self.t_end_s),
            "n_samples": len(self.t_s),
            "gg_impulse_orbit_nms": np.asarray(self.gg_impulse_orbit_nms).tolist(),
            "t_s": np.asarray(self.t_s).tolist(),
            "with_gg": self.with_gg.to_dict(),
            "without_gg": self.without_gg.to_dict(),
        }


@dataclass(frozen=True, eq=False)
class GravityGradientResim:
    """The re-simulation of every free-drift segment asked for."""

    segments: tuple[SegmentResim, ...]
    initial_window_s: float
    substeps: int

    def to_dict(self) -> dict[str, Any]:
        return {
            "initial_window_s": float(self.initial_window_s),
            "substeps": int(self.substeps),
            "segments": [s.to_dict() for s in self.segments],
        }


def _rot(quat_xyzw: Array) -> Array:
    x, y, z, w = quat_xyzw / np.linalg.norm(quat_xyzw)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


class _FreeDrift:
    """Right-hand side of the free-drift attitude and momentum equations along the
    recorded joints and wheel momentum (piecewise linear in time)."""

    def __init__(
        self, ws: DynamicsWorkspace, t_s: Array, joints_rad: Array, wheel_nms: Array, gg: bool
    ) -> None:
        self.ws, self.t, self.q, self.h, self.gg = ws, t_s, joints_rad, wheel_nms, gg
        #: (k, fraction of interval k) -> momentum blocks along the joint path: RK4 with one
        #: substep asks at the nodes and midpoints only, and every run of a segment follows
        #: the same path, so each configuration is evaluated once.
        #: Per configuration also ``H~_b^-1``; per (interval, fraction) ``H~_b^-1 H~_bm phi'``
        #: with that interval's joint rate.
        self._config: dict[tuple[int, float], tuple[Array, Array, Array]] = {}
        self._blocks: dict[tuple[int, float], tuple[Array, Array, Array]] = {}

    def _configuration(self, k: int, a: float) -> tuple[Array, Array, Array]:
        key = (k + 1, 0.0) if a == 1.0 else (k, a)
        found = self._config.get(key)
        if found is None:
            q = (1 - a) * self.q[k] + a * self.q[k + 1]
            h_b, h_bm = self.ws.momentum_blocks(q)
            inverse = np.asarray(np.linalg.inv(h_b), dtype=np.float64)
            found = (h_b.copy(), inverse, h_bm.copy())
            self._config[key] = found
        return found

    def blocks(self, k: int, a: float) -> tuple[Array, Array, Array]:
        """``H~_b``, ``H~_b^-1`` and ``H~_b^-1 H~_bm phi'`` at fraction ``a`` of interval k
        (the joint rate is that interval's)."""
        found = self._blocks.get((k, a))
        if found is None:
            h_b, inverse, h_bm = self._configuration(k, a)
            rate = (self.q[k + 1] - self.q[k]) / (self.t[k + 1] - self.t[k])
            arm: Array = inverse @ (h_bm @ rate)
            found = self._blocks[(k, a)] = (h_b, inverse, arm)
        return found

    def with_gg(self, gg: bool) -> _FreeDrift:
        """The same path (and its cached blocks), with or without gravity gradient."""
        other = _FreeDrift.__new__(_FreeDrift)
        other.__dict__.update(self.__dict__)
        other.gg = gg
        return other

    def __call__(self, k: int, tau: float, y: Array) -> Array:
        """``d(quat, L)/dt`` at ``t[k] + tau`` within interval k."""
        dt = self.t[k + 1] - self.t[k]
        a = tau / dt
        h_w = (1 - a) * self.h[k] + a * self.h[k + 1]
        quat, momentum = y[:4], y[4:]
        rot = _rot(quat)
        h_b, inverse, arm = self.blocks(k, a)
        omega = inverse @ (rot.T @ momentum - h_w) - arm
        dquat = 0.5 * quat_multiply_xyzw(quat, np.array([*omega, 0.0]))
        dmom = (
            rot @ gravity_gradient_torque_base_nm(h_b, rot, self.ws.orbit)
            if self.gg
            else np.zeros(3)
        )
        return np.concatenate([dquat, dmom])


def _integrate(rhs: _FreeDrift, quat0: Array, momentum0: Array, substeps: int) -> Array:
    """Quaternions (k, 4) at the telemetry times by RK4."""
    t = rhs.t
    out = np.zeros((len(t), 4))
    y = np.concatenate([quat0 / np.linalg.norm(quat0), momentum0])
    out[0] = y[:4]
    for k in range(len(t) - 1):
        h = (t[k + 1] - t[k]) / substeps
        for s in range(substeps):
            tau = s * h
            k1 = rhs(k, tau, y)
            k2 = rhs(k, tau + h / 2, y + h / 2 * k1)
            k3 = rhs(k, tau + h / 2, y + h / 2 * k2)
            k4 = rhs(k, tau + h, y + h * k3)
            y = y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            y[:4] /= np.linalg.norm(y[:4])
        out[k + 1] = y[:4] if y[3] >= 0 else -y[:4]
    return out


def _residual_rad(rec_quats: Array, sim_quats: Array) -> Array:
    rel = Rotation.from_quat(rec_quats).inv() * Rotation.from_quat(sim_quats)
    return np.asarray(rel.as_rotvec())


def _interval_momentum(
    ws: DynamicsWorkspace, t: Array, q: Array, h_w: Array, omega: Array, rots: Array
) -> tuple[Array, Array, Array]:
    """Mean momentum (eq. 3, model inertia, orbit frame) over each telemetry interval and
    the gravity-gradient impulse since the first sample at each interval's middle; and the
    whole impulse.

    The arm's term is taken along the same piecewise-linear joint path as the integrator,
    ``R H~_bm(q_mid) (q_k+1 - q_k) / dt``: second-order accurate where central differences
    of the servo-driven joints are off by up to 0.004 deg/s, and encoder noise telescopes.
    """
    n = len(t)
    body = np.zeros((n, 3))
    torque = np.zeros((n, 3))
    for k in range(n):
        h_b, _ = ws.momentum_blocks(q[k])
        body[k] = rots[k] @ (h_b @ omega[k] + h_w[k])
        torque[k] = rots[k] @ gravity_gradient_torque_base_nm(h_b, rots[k], ws.orbit)
    dt = np.diff(t)
    arm = np.zeros((n - 1, 3))
    for k in range(n - 1):
        _, h_bm = ws.momentum_blocks(0.5 * (q[k] + q[k + 1]))
        arm[k] = 0.5 * (rots[k] + rots[k + 1]) @ h_bm @ ((q[k + 1] - q[k]) / dt[k])
    steps = 0.5 * (torque[1:] + torque[:-1]) * dt[:, None]
    impulse = np.concatenate([np.zeros((1, 3)), np.cumsum(steps, axis=0)])
    mid_impulse = 0.5 * (impulse[1:] + impulse[:-1])
    return 0.5 * (body[1:] + body[:-1]) + arm, mid_impulse, impulse[-1]


def _segment(
    ws: DynamicsWorkspace,
    recording: PassRecording,
    rows: NDArray[np.intp],
    initial_window_s: float,
    substeps: int,
) -> SegmentResim:
    f = recording.frames
    t = recording.t_s()[rows]
    q = f.joints_rad[rows]
    h_w = f.wheel_momentum_nms[rows]
    quats = f.quat_orbit_from_base_xyzw[rows]
    rots = rotations_from_quats(quats)
    omega = f.omega_base_in_base_radps[rows]
    momentum, impulse, total_impulse = _interval_momentum(ws, t, q, h_w, omega, rots)
    ends = t[1:] - t[0]
    window = np.flatnonzero(ends <= max(initial_window_s, float(ends[0])))
    weights = np.diff(t)[window]
    runs = []
    path = _FreeDrift(ws, t, q, h_w, True)
    for gg in (True, False):
        known = momentum[window] - (impulse[window] if gg else 0.0)
        momentum0 = np.average(known, axis=0, weights=weights)
        rhs = path.with_gg(gg)
        sim = _integrate(rhs, quats[0], momentum0, substeps)
        # Take the first sample's attitude noise off: shift by the window's mean residual.
        first = np.flatnonzero(t - t[0] <= initial_window_s)
        shift = Rotation.from_rotvec(-np.mean(_residual_rad(quats[first], sim[first]), axis=0))
        sim = _integrate(rhs, (Rotation.from_quat(quats[0]) * shift).as_quat(), momentum0, substeps)
        runs.append(ResimRun(gg, sim, _residual_rad(quats, sim)))
    return SegmentResim(
        t_start_s=float(t[0]),
        t_end_s=float(t[-1]),
        t_s=t,
        with_gg=runs[0],
        without_gg=runs[1],
        gg_impulse_orbit_nms=total_impulse,
    )


def resimulate_free_drift(
    recording: PassRecording,
    model: RobotModel | None = None,
    *,
    segments: Sequence[tuple[float, float]] | None = None,
    initial_window_s: float = 5.0,
    substeps: int = 1,
) -> GravityGradientResim:
    """Re-simulate each free-drift segment with and without eq. (11) (see the module doc).

    ``segments`` are plan-clock intervals, by default :func:`find_free_drift_segments`; the
    frames inside each (split at telemetry gaps) are used whatever their ACS mode, so pass
    free-drift intervals only. Raises :class:`InsufficientData` when none has two samples.
    """
    model = model or default_model()
    ws = DynamicsWorkspace(model)
    chosen = tuple(segments) if segments is not None else find_free_drift_segments(recording)
    t = recording.t_s()
    out = []
    for lo, hi in chosen:
        rows = np.flatnonzero((t >= lo) & (t <= hi)).astype(np.intp)
        for piece in split_at_gaps(t, rows):
            if len(piece) > 2:
                out.append(_segment(ws, recording, piece, initial_window_s, substeps))
    if not out:
        raise InsufficientData(f"no free-drift segment of 3 samples or more in {list(chosen)}")
    return GravityGradientResim(tuple(out), initial_window_s, substeps)
