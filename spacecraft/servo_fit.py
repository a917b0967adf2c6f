"""The joint servos and the sensor noise of a recorded pass (``hikoboshi calibrate --mcap``,
``--pass``; docs/spacecraft.md).

**Servos** (:func:`fit_servo`). Each joint's servo is the PD law of
:func:`planner.simulation.default_servo_gains`, ``kp = I wn^2``, ``kd = lag kp`` with ``I``
the joint's own inertia ``H_m[i, i]`` at the all-zero pose. Per joint, the model is that law
on the joint's free-floating inertia ``M = H*[i, i]`` (``H* = H_m - H_bm^T H_b^-1 H_bm``,
averaged over the frames in which the joint is commanded to move), alone:

    M q'' = kp (r - q) - kd q'

driven by the commanded target ``r``: the plan's 4 Hz commands, linear in between, as on
board. It is simulated on a 0.05 s grid (the 4 Hz commands and the 10 Hz frames fall on it;
:func:`scipy.signal.lsim`, first-order hold: exact for the piecewise-linear target) from rest
at the first command, and :func:`scipy.optimize.least_squares` fits ``log lag`` and
``log wn`` so that it flies the recorded (measured) angles. ``lag = kd / kp`` is the lag
behind a ramp and does not depend on ``M``; ``wn`` shows only where the commanded rate
changes (a ramp's start and stop) and through ``M``, so it is weakly observable: its standard
error says how well. The other joints' coupling through ``H*`` is left out (it is what the
joint's own inertia average misses). A joint commanded at under 0.05 deg/s throughout says
nothing of its servo and keeps its start value (``note``).

**Sensor noise** (:func:`estimate_sensor_noise`). Where the arm holds still (plan segments of
kind ``hold`` or ``settle``, from 5 s after each starts: the servos have caught up), the
joints are still and the base turns slowly and smoothly: the second difference of three
consecutive samples, ``x[k+1] - 2 x[k] + x[k-1]``, is then ``6 sigma^2`` of white noise and a
negligible part of the motion (at 10 Hz the base's own second difference is under 1e-5 deg).
The 1-sigma values are pooled over the axes (attitude: the rotation vector of each sample
against the run's first, base frame; rate: the gyro's base-frame rate; joints: every joint),
the quantities of :class:`spacecraft.SensorNoise`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.signal import lsim
from scipy.spatial.transform import Rotation

from planner.dynamics import DynamicsWorkspace
from planner.errors import InvalidInput
from planner.mjcf import ServoGains
from planner.plan import Plan
from planner.simulation import default_servo_gains
from planner.state import State

__all__ = [
    "HOLD_SKIP_S",
    "MIN_SERVO_RATE_DEGPS",
    "JointServoFit",
    "NoiseEstimate",
    "ServoFit",
    "estimate_sensor_noise",
    "fit_servo",
    "write_vehicle_config",
]

Array = NDArray[np.float64]

#: A joint commanded at no more than this (deg/s) throughout says nothing of its servo.
MIN_SERVO_RATE_DEGPS = 0.05
#: The servo model's grid (s): the 4 Hz commands and the 10 Hz frames both fall on it.
SERVO_GRID_S = 0.05
#: Hold frames this soon after a hold starts are left out of the noise estimate.
HOLD_SKIP_S = 5.0
#: Bounds of the fit (lag in s, the model's own bandwidth sqrt(kp / M) in rad/s).
_LAG_BOUNDS_S = (0.005, 20.0)
_WN_BOUNDS_RADPS = (0.2, 100.0)
#: A bandwidth whose standard error is under this fraction of it counts as observed.
BANDWIDTH_OBSERVABLE = 0.1
#: Consecutive samples closer than this to the recording's period count as equally spaced.
_SPACING_TOLERANCE_S = 1e-6


@dataclass(frozen=True)
class JointServoFit:
    """One joint's servo: start and fit (``None`` where the joint was not observable), the
    standard errors from the Jacobian (noise only), the RMS of measured minus modelled
    angle at the start and at the fit, and the frames used."""

    joint: int  # 1-based
    start_lag_s: float
    start_bandwidth_radps: float
    lag_s: float | None
    bandwidth_radps: float | None
    lag_standard_error_s: float | None
    bandwidth_standard_error_radps: float | None
    rms_start_deg: float | None
    rms_fit_deg: float | None
    frames: int
    note: str = ""

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass(frozen=True)
class ServoFit:
    joints: tuple[JointServoFit, ...]
    evaluations: int

    @property
    def lag_s(self) -> tuple[float, ...]:
        """Per joint: the fit, or the start where the joint was not observable."""
        return tuple(j.start_lag_s if j.lag_s is None else j.lag_s for j in self.joints)

    @property
    def bandwidth_radps(self) -> tuple[float, ...]:
        return tuple(
            j.start_bandwidth_radps if j.bandwidth_radps is None else j.bandwidth_radps
            for j in self.joints
        )

    def gains(self, ws: DynamicsWorkspace) -> ServoGains:
        """The fitted servos as PD gains (the design of ``default_servo_gains``)."""
        return default_servo_gains(ws.model, bandwidth_radps=self.bandwidth_radps, lag_s=self.lag_s)

    def to_dict(self) -> dict[str, Any]:
        return {
            "lag_s": list(self.lag_s),
            "bandwidth_radps": list(self.bandwidth_radps),
            "evaluations": self.evaluations,
            "joints": [j.to_dict() for j in self.joints],
        }


@dataclass(frozen=True)
class NoiseEstimate:
    """1-sigma sensor noise (deg, deg/s) and the second differences each rests on."""

    attitude_deg: float | None
    rate_degps: float | None
    joint_deg: float | None
    samples: dict[str, int]

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


# --- servos ---------------------------------------------------------------------------------


def _servo_design(ws: DynamicsWorkspace, gains: ServoGains) -> tuple[Array, Array, Array]:
    """``I = H_m[i, i]`` at the all-zero pose, and the design's lag and bandwidth."""
    inertia = default_servo_gains(ws.model, bandwidth_radps=1.0, lag_s=1.0).kp_nm_per_rad
    kp = np.asarray(gains.kp_nm_per_rad, dtype=np.float64)
    kd = np.asarray(gains.kd_nms_per_rad, dtype=np.float64)
    return inertia, kd / kp, np.sqrt(kp / inertia)


def _free_inertia(ws: DynamicsWorkspace, joints_rad: Array) -> Array:
    """The diagonal of ``H*`` at each row of joint angles."""
    out = np.zeros_like(joints_rad)
    n = joints_rad.shape[1]
    for k, q in enumerate(joints_rad):
        quantities = ws.evaluate(State(joints_rad=q, joint_rates_radps=np.zeros(n)))
        h_star = quantities.H_m - quantities.H_bm.T @ np.linalg.solve(
            quantities.H_b, quantities.H_bm
        )
        out[k] = np.diag(h_star)
    return out


def _simulate(lag_s: float, wn_radps: float, grid_s: Array, target: Array) -> Array:
    """``q'' = wn^2 (r - q) - lag wn^2 q'`` from rest at ``target[0]``, on ``grid_s``."""
    a = wn_radps * wn_radps
    system = (
        np.array([[0.0, 1.0], [-a, -lag_s * a]]),
        np.array([[0.0], [a]]),
        np.array([[1.0, 0.0]]),
        np.array([[0.0]]),
    )
    _, y, _ = lsim(system, target, grid_s, X0=[target[0], 0.0], interp=True)
    return np.asarray(y, dtype=np.float64)


def fit_servo(
    recording: Any,
    ws: DynamicsWorkspace,
    *,
    start: ServoGains | None = None,
    max_evaluations: int = 20,
    progress: Callable[[int], None] | None = None,
) -> ServoFit:
    """Each joint's ``lag`` and ``wn`` from the recording's commanded and measured angles
    (the module doc says how). ``start``: the servos the fit starts from and reports
    against (default: ``default_servo_gains`` of ``ws.model``). ``max_evaluations`` bounds
    the optimiser's steps on the whole arm (each with its finite-difference Jacobian, two
    simulations per fitted parameter); ``progress(simulations so far)`` is called after
    each simulation of the arm."""
    plan: Plan = recording.plan
    n = ws.model.n_joints
    if plan.command_joints_rad.shape[1] != n:
        raise InvalidInput(
            f"the recording's plan has {plan.command_joints_rad.shape[1]} joints, the model {n}"
        )
    inertia, lag0, wn0 = _servo_design(ws, start or default_servo_gains(ws.model))
    times = plan.command_times_s
    t_all = recording.t_s()
    measured_all = np.asarray(recording.frames.joints_rad, dtype=np.float64)
    keep = (t_all >= times[0]) & (t_all <= times[-1]) & np.all(np.isfinite(measured_all), axis=1)
    if np.count_nonzero(keep) < 10:
        raise InvalidInput("the recording has fewer than 10 frames within its plan to fit servos")
    t_obs, measured = t_all[keep], measured_all[keep]
    rate = np.abs(np.diff(plan.command_joints_rad, axis=0)) / np.diff(times)[:, None]
    moving_cmd = np.concatenate([rate, np.zeros((1, n))]) > math.radians(MIN_SERVO_RATE_DEGPS)
    interval = np.clip(np.searchsorted(times, t_obs, side="right") - 1, 0, times.size - 1)
    moving_obs = moving_cmd[interval]
    observable = np.any(moving_obs, axis=0)
    # Stage 1, joint by joint (decoupled, fast): the lag, the start of stage 2.
    lag1 = lag0.copy()
    grid = times[0] + SERVO_GRID_S * np.arange(
        math.floor((t_obs[-1] - times[0]) / SERVO_GRID_S + 1e-9) + 2
    )
    for i in np.flatnonzero(observable):
        target = np.interp(grid, times, plan.command_joints_rad[:, i])
        y = np.degrees(measured[:, i])

        def one(x: Array, target: Array = target, y: Array = y) -> Array:
            q = _simulate(math.exp(x[0]), math.exp(x[1]), grid, target)
            return np.asarray(np.degrees(np.interp(t_obs, grid, q)) - y)

        lower = np.log([_LAG_BOUNDS_S[0], _WN_BOUNDS_RADPS[0]])
        upper = np.log([_LAG_BOUNDS_S[1], _WN_BOUNDS_RADPS[1]])
        x0 = np.clip(np.log([lag0[i], wn0[i]]), lower + 1e-9, upper - 1e-9)
        lag1[i] = math.exp(float(least_squares(one, x0, bounds=(lower, upper)).x[0]))
    # Stage 2, the whole arm in the free-floating simulator: lags and bandwidths together.
    return _fit_arm(
        ws, plan, t_obs, measured, inertia, lag0, wn0, lag1, observable, moving_obs,
        max_evaluations, progress,
    )  # fmt: skip


#: The arm's fit simulates at this step (s): half the vehicle's, so that a candidate with
#: stiffer damping than the vehicle's stays inside RK4's stable interval.
ARM_FIT_TIMESTEP_S = 0.005
#: The fastest servo mode a candidate may have, ``kd / M`` with ``M`` the smallest free
#: inertia met (1/s): RK4 at 5 ms is stable up to 556 1/s.
_MAX_SERVO_MODE_PER_S = 300.0


def _fit_arm(
    ws: DynamicsWorkspace,
    plan: Plan,
    t_obs: Array,
    measured: Array,
    inertia: Array,
    lag0: Array,
    wn0: Array,
    lag1: Array,
    observable: NDArray[np.bool_],
    moving_obs: NDArray[np.bool_],
    max_evaluations: int,
    progress: Callable[[int], None] | None,
) -> ServoFit:
    from planner.simulation import FreeFloatingSimulator, SimConfig, follow_commands

    n = ws.model.n_joints
    times = plan.command_times_s - plan.command_times_s[0]
    t_rel = t_obs - plan.command_times_s[0]
    joints = np.flatnonzero(observable)
    k = joints.size
    commanded = np.column_stack(
        [np.interp(t_rel, times, plan.command_joints_rad[:, i]) for i in range(n)]
    )
    rows = np.flatnonzero(np.any(moving_obs, axis=1))
    sample = rows[:: max(1, rows.size // 200)] if rows.size else np.arange(1)
    m_min = np.min(_free_inertia(ws, commanded[sample]), axis=0)
    lag_lo, lag_hi = lag1[joints] / 2.0, lag1[joints] * 2.0
    wn_lo = wn0[joints] / 4.0
    wn_hi = np.minimum(
        wn0[joints] * 4.0,
        np.sqrt(_MAX_SERVO_MODE_PER_S * m_min[joints] / (inertia[joints] * lag_hi)),
    )
    wn_start = np.clip(wn0[joints], wn_lo * 1.01, wn_hi * 0.99)
    lower = np.log(np.concatenate([lag_lo, wn_lo]))
    upper = np.log(np.concatenate([lag_hi, wn_hi]))
    x0 = np.log(np.concatenate([lag1[joints], wn_start]))
    count = {"n": 0}

    def values(x: Array) -> tuple[Array, Array]:
        lag, wn = lag0.copy(), wn0.copy()
        lag[joints], wn[joints] = np.exp(x[:k]), np.exp(x[k:])
        return lag, wn

    def simulate(lag: Array, wn: Array) -> Array:
        sim = FreeFloatingSimulator(
            ws.model,
            State(joints_rad=plan.command_joints_rad[0]),
            SimConfig(
                timestep_s=ARM_FIT_TIMESTEP_S,
                servo=default_servo_gains(ws.model, bandwidth_radps=wn, lag_s=lag),
            ),
        )
        flown = follow_commands(
            sim, times, plan.command_joints_rad, end_time_s=float(t_rel[-1]) + SERVO_GRID_S,
            sample_period_s=SERVO_GRID_S,
        )  # fmt: skip
        q = np.column_stack([np.interp(t_rel, flown.t_s, flown.joints_rad[:, i]) for i in joints])
        count["n"] += 1
        if progress is not None:
            progress(count["n"])
        return np.asarray(np.degrees(q - measured[:, joints]).ravel(order="F"))

    def residuals(x: Array) -> Array:
        return simulate(*values(x))

    r0 = simulate(lag0, wn0)  # the start's tracking, for the report
    result = least_squares(
        residuals, x0, bounds=(lower, upper), method="trf", diff_step=1e-3,
        max_nfev=max(1, max_evaluations),
    )  # fmt: skip
    lag, wn = values(result.x)
    r = np.asarray(result.fun, dtype=np.float64)
    m = t_obs.size
    se = np.full(2 * k, math.nan)
    if r.size > 2 * k:
        jac = np.asarray(result.jac, dtype=np.float64)
        try:
            cov = np.linalg.inv(jac.T @ jac) * float(r @ r) / (r.size - 2 * k)
            se = np.exp(result.x) * np.sqrt(np.maximum(np.diag(cov), 0.0))
        except np.linalg.LinAlgError:
            pass
    out: list[JointServoFit] = []
    for i in range(n):
        if not observable[i]:
            out.append(
                JointServoFit(
                    i + 1, float(lag0[i]), float(wn0[i]), None, None, None, None, None, None, 0,
                    note=f"commanded at under {MIN_SERVO_RATE_DEGPS} deg/s throughout",
                )
            )  # fmt: skip
            continue
        j = int(np.flatnonzero(joints == i)[0])
        part, part0 = r[j * m : (j + 1) * m], r0[j * m : (j + 1) * m]
        wn_se = float(se[k + j])
        observed = math.isfinite(wn_se) and wn_se < BANDWIDTH_OBSERVABLE * float(wn[i])
        out.append(
            JointServoFit(
                joint=i + 1,
                start_lag_s=float(lag0[i]),
                start_bandwidth_radps=float(wn0[i]),
                lag_s=float(lag[i]),
                bandwidth_radps=float(wn[i]) if observed else None,
                lag_standard_error_s=float(se[j]) if math.isfinite(se[j]) else None,
                bandwidth_standard_error_radps=wn_se if math.isfinite(wn_se) else None,
                rms_start_deg=float(np.sqrt(np.mean(part0**2))),
                rms_fit_deg=float(np.sqrt(np.mean(part**2))),
                frames=int(m),
                note=""
                if observed
                else f"bandwidth not observable (fit {float(wn[i]):.3g} rad/s, standard error "
                f"{wn_se:.3g}): the start's kept",
            )
        )
    return ServoFit(joints=tuple(out), evaluations=count["n"])


# --- sensor noise ---------------------------------------------------------------------------


def _hold_runs(recording: Any) -> list[NDArray[np.intp]]:
    """Row indices of the frames in each hold (``HOLD_SKIP_S`` after its start), split at
    gaps: runs of equally spaced frames."""
    plan: Plan = recording.plan
    t = recording.t_s()
    runs: list[NDArray[np.intp]] = []
    if t.size < 3:
        return runs
    period = float(np.median(np.diff(t)))
    for seg in plan.segments:
        if seg.kind not in ("hold", "settle"):
            continue
        rows = np.flatnonzero((t >= seg.t_start_s + HOLD_SKIP_S) & (t <= seg.t_end_s))
        if rows.size < 3:
            continue
        breaks = np.flatnonzero(np.abs(np.diff(t[rows]) - period) > _SPACING_TOLERANCE_S) + 1
        runs.extend(part for part in np.split(rows, breaks) if part.size >= 3)
    return runs


def _second_difference_sigma(blocks: Sequence[Array]) -> tuple[float | None, int]:
    diffs = [b[2:] - 2.0 * b[1:-1] + b[:-2] for b in blocks if len(b) >= 3]
    values = np.concatenate([d.ravel() for d in diffs]) if diffs else np.zeros(0)
    values = values[np.isfinite(values)]
    if values.size < 10:
        return None, int(values.size)
    return math.sqrt(float(np.mean(values**2)) / 6.0), int(values.size)


def estimate_sensor_noise(recording: Any) -> NoiseEstimate:
    """1-sigma attitude, rate and joint noise from the recording's holds (module doc)."""
    frames = recording.frames
    runs = _hold_runs(recording)
    quats = np.asarray(frames.quat_orbit_from_base_xyzw, dtype=np.float64)
    attitude_blocks = []
    for rows in runs:
        q = quats[rows]
        if not np.all(np.isfinite(q)):
            continue
        rot = Rotation.from_quat(q)
        attitude_blocks.append(np.degrees((rot[0].inv() * rot).as_rotvec()))
    attitude, n_att = _second_difference_sigma(attitude_blocks)
    omega = np.degrees(np.asarray(frames.omega_base_in_base_radps, dtype=np.float64))
    rate, n_rate = _second_difference_sigma([omega[rows] for rows in runs])
    joints = np.degrees(np.asarray(frames.joints_rad, dtype=np.float64))
    joint, n_joint = _second_difference_sigma([joints[rows] for rows in runs])
    return NoiseEstimate(
        attitude_deg=attitude,
        rate_degps=rate,
        joint_deg=joint,
        samples={"attitude": n_att, "rate": n_rate, "joint": n_joint},
    )


# --- the file ---------------------------------------------------------------------------


def write_vehicle_config(path: Any, servo: ServoFit | None, noise: NoiseEstimate | None) -> None:
    """``[servo]`` (``bandwidth_radps``, ``lag_s``, one per joint) and ``[sensor_noise]``
    (``attitude_deg``, ``rate_degps``, ``joint_deg``) tables: the keys and units of a robot
    description's tables (docs/robots.md), which ``hikoboshi spacecraft --vehicle-config``
    reads. A noise the recording could not estimate is left out (the default stays)."""
    from pathlib import Path

    lines: list[str] = []
    if servo is not None:
        lines += [
            "[servo]",
            "bandwidth_radps = [" + ", ".join(repr(float(v)) for v in servo.bandwidth_radps) + "]",
            "lag_s = [" + ", ".join(repr(float(v)) for v in servo.lag_s) + "]",
        ]
    if noise is not None:
        values = {
            "attitude_deg": noise.attitude_deg,
            "rate_degps": noise.rate_degps,
            "joint_deg": noise.joint_deg,
        }
        if lines:
            lines.append("")
        lines.append("[sensor_noise]")
        lines += [f"{k} = {float(v)!r}" for k, v in values.items() if v is not None]
    Path(path).write_text("\n".join(lines) + "\n")
