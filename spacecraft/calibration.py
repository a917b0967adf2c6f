"""Calibrating the attitude-control law (``hikoboshi calibrate``, docs/spacecraft.md).

Two fits of the law's design parameters (:func:`planner.attitude_control.default_acs_gains`:
``bandwidth_radps``, ``damping_ratio``, ``rate_filter_tau_s``, ``integral_time_s``), both by
:func:`scipy.optimize.least_squares` (trust-region reflective, bounds) in a well-scaled
space (logarithms of the bandwidth and damping ratio, ``log(1 + tau)``, the integral rate
``100 s / Ti`` with 0 = no integral term):

- :func:`fit_to_recording`: the plan's prediction (:func:`planner.prediction.predict`, ideal
  tracking) with the law against a recorded pass's base attitude, the rotation vector of
  the difference per axis over the frames flown in ``feedback`` mode, in least squares.
  Returns the fit, its residual RMS and standard errors from the Jacobian;
- :func:`fit_to_paper`: the law against the paper's targets of experiments 1 and 3 that the
  law shapes (PTP settling, the feedback-only pitch range, the feedforward's shape, the
  offset destination's smallest range and fastest settling), each residual scaled by its
  tolerance, the orderings as hinges (zero when they hold), measured as the report measures
  them (the 0.05 deg band around the window's final value; experiment 3 as the demo pass
  schedules it; the PTP with a 360 s wait, so that its final value is the attitude the loop
  holds). Evaluated on the prediction;
  optionally the start and the fit are flown through the vehicle
  (:func:`spacecraft._calibration.fly_plan`, the same plans) and reported beside it. The targets
  the law does not shape (GJM flies in free drift; the reactionless reaction comes from
  joint-servo lag) are reported, not fitted.

With ``servo_and_noise``, :func:`fit_to_recording` also fits the joint servos (each joint's
lag and, where observable, bandwidth) and estimates the sensor noise
(:mod:`spacecraft.servo_fit`), adding their rows to the report; :func:`write_vehicle_config`
writes them as ``[servo]`` and ``[sensor_noise]`` tables.

Every report row holds the target, its tolerance, the value at the start and at the fit and
whether the criterion holds there: a target the fit cannot meet says so.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation, Slerp

from planner.attitude_control import (
    DEFAULT_ACS_BANDWIDTH_RADPS,
    DEFAULT_ACS_DAMPING_RATIO,
    DEFAULT_DEAD_BAND_DEG,
    DEFAULT_RATE_FILTER_TAU_S,
    DEFAULT_WHEEL_TORQUE_LIMIT_NM,
    AcsGains,
    AcsMode,
    default_acs_gains,
)
from planner.dynamics import DynamicsWorkspace
from planner.errors import InvalidInput
from planner.mjcf import ServoGains
from planner.model import default_model
from planner.plan import Plan
from planner.prediction import predict
from spacecraft._calibration import (
    SETTLE_BAND_DEG,
    Flight,
    calibration_plans,
    coordination_metrics,
    ptp_settling_s,
)
from spacecraft.servo_fit import (
    NoiseEstimate,
    ServoFit,
    estimate_sensor_noise,
    fit_servo,
    write_vehicle_config,
)

__all__ = [
    "PARAMETERS",
    "CalibrationResult",
    "Progress",
    "TargetRow",
    "fit_to_paper",
    "fit_to_recording",
    "gains_from_parameters",
    "write_acs_config",
    "write_vehicle_config",
]

Array = NDArray[np.float64]

#: Called after each evaluation: (evaluations so far, the budget, the current best cost).
Progress = Callable[[int, int, float], None]


#: A rate filter shorter than this is no filter in the fit (the prediction's fixed-step
#: integrator cannot follow a much faster filter, and the law's time scales are tens of
#: seconds).
MIN_RATE_FILTER_TAU_S = 0.5


def _tau_from_x(x: float) -> float:
    tau = math.expm1(max(x, 0.0))
    return tau if tau >= MIN_RATE_FILTER_TAU_S else 0.0


@dataclass(frozen=True)
class _Parameter:
    default: float
    lower: float  # in the fit's space
    upper: float
    to_x: Callable[[float], float]
    from_x: Callable[[float], float]
    #: where the optimiser starts when the start is the parameter's "off" value (on the
    #: bound, where a finite difference sees nothing): a small, active value
    active_start: float | None = None
    #: which bound is "off": the lower (no filter, no integral term, no dead band) or the
    #: upper (a torque limit that does not bind)
    off_at_upper: bool = False


#: The largest dead band the fit tries (deg): a wider one would leave the attitude the loop
#: holds further off than the settling band the report judges by.
MAX_FIT_DEAD_BAND_DEG = 0.5

#: The law's fittable parameters; ``integral_time_s`` = ``inf`` means no integral term;
#: ``torque_limit_nm`` is the law's saturation, at most the wheels' rating (the default: it
#: does not bind in the calibration flights) and only seen where the loop saturates;
#: ``dead_band_deg`` 0 means none.
PARAMETERS: Mapping[str, _Parameter] = {
    "bandwidth_radps": _Parameter(
        DEFAULT_ACS_BANDWIDTH_RADPS, math.log(1e-3), math.log(1.0), math.log, math.exp
    ),
    "damping_ratio": _Parameter(
        DEFAULT_ACS_DAMPING_RATIO, math.log(0.05), math.log(5.0), math.log, math.exp
    ),
    "rate_filter_tau_s": _Parameter(
        DEFAULT_RATE_FILTER_TAU_S,
        0.0,
        math.log1p(200.0),
        math.log1p,
        _tau_from_x,
        active_start=2.0,
    ),
    "integral_time_s": _Parameter(
        math.inf,
        0.0,
        10.0,  # Ti >= 10 s
        lambda ti: 100.0 / ti,
        lambda x: math.inf if x <= 0.0 else 100.0 / x,
        active_start=1000.0,
    ),
    "torque_limit_nm": _Parameter(
        DEFAULT_WHEEL_TORQUE_LIMIT_NM,
        math.log(0.005),
        math.log(DEFAULT_WHEEL_TORQUE_LIMIT_NM),
        math.log,
        math.exp,
        active_start=0.1,
        off_at_upper=True,
    ),
    "dead_band_deg": _Parameter(
        DEFAULT_DEAD_BAND_DEG,
        0.0,
        MAX_FIT_DEAD_BAND_DEG,
        float,
        float,
        active_start=0.01,
    ),
}


def _check_parameters(parameters: Sequence[str]) -> tuple[str, ...]:
    names = tuple(parameters)
    unknown = sorted(set(names) - set(PARAMETERS))
    if unknown or not names or len(set(names)) != len(names):
        raise InvalidInput(
            f"parameters {list(names)}: give distinct names among {', '.join(PARAMETERS)}"
        )
    return names


def gains_from_parameters(ws: DynamicsWorkspace, values: Mapping[str, float]) -> AcsGains:
    """The law of :func:`default_acs_gains` with these design parameters (others default)."""
    ti = float(values.get("integral_time_s", math.inf))
    return default_acs_gains(
        ws,
        bandwidth_radps=float(values.get("bandwidth_radps", DEFAULT_ACS_BANDWIDTH_RADPS)),
        damping_ratio=float(values.get("damping_ratio", DEFAULT_ACS_DAMPING_RATIO)),
        rate_filter_tau_s=float(values.get("rate_filter_tau_s", DEFAULT_RATE_FILTER_TAU_S)),
        integral_time_s=None if math.isinf(ti) else ti,
        torque_limit_nm=float(values.get("torque_limit_nm", DEFAULT_WHEEL_TORQUE_LIMIT_NM)),
        dead_band_rad=math.radians(float(values.get("dead_band_deg", DEFAULT_DEAD_BAND_DEG))),
    )


def write_acs_config(path: str | Path, values: Mapping[str, float]) -> None:
    """An ``[acs]`` TOML table (:func:`planner.description.load_acs_config` reads it);
    an infinite ``integral_time_s`` (no integral term) is left out."""
    lines = ["[acs]"]
    for name, value in values.items():
        if name == "integral_time_s" and math.isinf(value):
            continue
        lines.append(f"{name} = {float(value)!r}")
    Path(path).write_text("\n".join(lines) + "\n")


@dataclass(frozen=True)
class TargetRow:
    """One target against the fit; ``holds`` is ``None`` when not checked (not measurable
    where it was evaluated)."""

    id: str
    target: str
    tolerance: str
    start: float | None
    fit: float | None
    holds_start: bool | None
    holds: bool | None
    source: str  # "prediction", "vehicle" or "recording"
    note: str = ""


@dataclass(frozen=True)
class CalibrationResult:
    kind: str  # "paper" or "recording"
    parameters: dict[str, float]
    start: dict[str, float]
    standard_error: dict[str, float] | None
    cost_start: float
    cost: float
    residual_rms: float
    evaluations: int
    targets: list[TargetRow] = field(default_factory=list)
    message: str = ""
    #: a recording's joint servos and sensor noise (``fit_to_recording(servo_and_noise=True)``)
    servo: ServoFit | None = None
    sensor_noise: NoiseEstimate | None = None

    def to_dict(self) -> dict[str, Any]:
        def clean(value: Any) -> Any:
            if isinstance(value, float) and not math.isfinite(value):
                return None
            if isinstance(value, dict):
                return {k: clean(v) for k, v in value.items()}
            return value

        return {
            "kind": self.kind,
            "parameters": clean(self.parameters),
            "start": clean(self.start),
            "standard_error": None if self.standard_error is None else clean(self.standard_error),
            "cost_start": self.cost_start,
            "cost": self.cost,
            "residual_rms": self.residual_rms,
            "evaluations": self.evaluations,
            "message": self.message,
            "targets": [clean(dict(row.__dict__)) for row in self.targets],
            "servo": None if self.servo is None else clean(self.servo.to_dict()),
            "sensor_noise": None if self.sensor_noise is None else self.sensor_noise.to_dict(),
        }


class _BudgetSpent(Exception):
    pass


_T = TypeVar("_T")


def _memoised(fn: Callable[[dict[str, float]], _T]) -> Callable[[dict[str, float]], _T]:
    """``fn`` of a law's values (a prediction or a seeded flight: deterministic), computed
    once per distinct values; the result is shared, read only."""
    cache: dict[tuple[tuple[str, float], ...], _T] = {}

    def call(values: dict[str, float]) -> _T:
        key = tuple(sorted(values.items()))
        if key not in cache:
            cache[key] = fn(values)
        return cache[key]

    return call


@dataclass
class _Objective:
    """Counts evaluations, remembers the best point, stops at the budget."""

    names: tuple[str, ...]
    residuals: Callable[[dict[str, float]], Array]
    budget: int
    progress: Progress | None
    evaluations: int = 0
    best_cost: float = math.inf
    best_x: Array | None = None
    first_cost: float = math.nan
    #: the start in the fit's space and as given: at that point the values are the start's
    #: own (``from_x(to_x(v))`` can differ from ``v`` in the last bit)
    start_x: Array | None = None
    start: Mapping[str, float] | None = None

    def values(self, x: Array) -> dict[str, float]:
        if self.start is not None and self.start_x is not None and np.array_equal(x, self.start_x):
            return dict(self.start)
        return {n: PARAMETERS[n].from_x(float(v)) for n, v in zip(self.names, x, strict=True)}

    def __call__(self, x: Array) -> Array:
        if self.evaluations >= self.budget:
            raise _BudgetSpent
        r = self.residuals(self.values(x))
        self.evaluations += 1
        cost = 0.5 * float(r @ r)
        if self.evaluations == 1:
            self.first_cost = cost
        if cost < self.best_cost:
            self.best_cost, self.best_x = cost, np.array(x, dtype=np.float64)
        if self.progress is not None:
            self.progress(self.evaluations, self.budget, self.best_cost)
        return np.array(r, dtype=np.float64)  # the optimiser's own copy


def _solve(
    names: tuple[str, ...],
    start: Mapping[str, float],
    residuals: Callable[[dict[str, float]], Array],
    max_evaluations: int,
    progress: Progress | None,
) -> tuple[_Objective, dict[str, float], dict[str, float] | None, Array, str]:
    if max_evaluations < 1:
        raise InvalidInput(f"max_evaluations = {max_evaluations} must be >= 1")
    lower = np.array([PARAMETERS[n].lower for n in names])
    upper = np.array([PARAMETERS[n].upper for n in names])
    x0 = np.array([PARAMETERS[n].to_x(float(start[n])) for n in names])
    as_given = x0.copy()
    for i, n in enumerate(names):
        p = PARAMETERS[n]
        off = x0[i] >= upper[i] if p.off_at_upper else x0[i] <= lower[i]
        if p.active_start is not None and off:
            x0[i] = p.to_x(p.active_start)
    x0 = np.clip(x0, lower, upper)
    objective = _Objective(names, residuals, max_evaluations, progress)
    if np.array_equal(x0, as_given):
        objective.start_x, objective.start = x0, start
    jac: Array | None = None
    try:
        result = least_squares(
            objective,
            x0,
            bounds=(lower, upper),
            method="trf",
            diff_step=1e-3,
            x_scale=1.0,
            max_nfev=max_evaluations,
        )
        x, jac, message = result.x, result.jac, str(result.message)
        if objective.best_x is not None and objective.best_cost < 0.5 * float(
            result.fun @ result.fun
        ):
            x = objective.best_x
    except _BudgetSpent:
        x = objective.best_x if objective.best_x is not None else x0
        message = f"stopped at the evaluation budget ({max_evaluations})"
    values = objective.values(x)
    r = residuals(values)
    stderr = None
    if jac is not None and r.size > len(names):
        jac = np.asarray(jac, dtype=np.float64)
        s2 = float(r @ r) / (r.size - len(names))
        try:
            cov = np.linalg.inv(jac.T @ jac) * s2
        except np.linalg.LinAlgError:
            cov = None
        if cov is not None:
            stderr = {}
            for i, n in enumerate(names):
                sx = math.sqrt(max(float(cov[i, i]), 0.0))
                p = PARAMETERS[n]
                step = 1e-6
                dp = (p.from_x(float(x[i]) + step) - p.from_x(float(x[i]) - step)) / (2 * step)
                stderr[n] = abs(dp) * sx
    return objective, values, stderr, r, message


# --- fitting a recorded pass ---------------------------------------------------------------


def _observed(recording: Any) -> tuple[Array, Array]:
    """Frame times (plan clock) and base attitudes over the plan's feedback frames."""
    plan: Plan = recording.plan
    t = recording.t_s()
    quat = np.asarray(recording.frames.quat_orbit_from_base_xyzw, dtype=np.float64)
    modes = np.asarray(recording.frames.acs_mode).astype(str)
    keep = (t >= 0.0) & (t <= plan.duration_s) & (modes == AcsMode.FEEDBACK.value)
    keep &= np.all(np.isfinite(quat), axis=1)
    if np.count_nonzero(keep) < 10:
        raise InvalidInput("the recording has fewer than 10 frames in feedback mode to fit")
    return t[keep], quat[keep]


def fit_to_recording(
    recording: Any,
    parameters: Sequence[str] = ("bandwidth_radps", "damping_ratio"),
    *,
    ws: DynamicsWorkspace | None = None,
    start: Mapping[str, float] | None = None,
    max_evaluations: int = 60,
    progress: Progress | None = None,
    servo_and_noise: bool = False,
    servo_start: ServoGains | None = None,
    servo_max_evaluations: int = 20,
    servo_progress: Callable[[int], None] | None = None,
) -> CalibrationResult:
    """Fit the law so that the recording's plan, predicted with it (ideal tracking), flies
    the recorded base attitude: residuals are the rotation vector (deg) from the prediction
    to each frame flown in feedback mode during the plan. ``start`` defaults to the
    defaults; the standard errors come from the Jacobian at the fit. With
    ``servo_and_noise`` also the joint servos (from ``servo_start``, default the model's
    :func:`planner.simulation.default_servo_gains`; :func:`spacecraft.servo_fit.fit_servo`)
    and the sensor noise (:func:`spacecraft.servo_fit.estimate_sensor_noise`), with their
    report rows."""
    names = _check_parameters(parameters)
    plan: Plan = recording.plan
    ws = ws or DynamicsWorkspace(default_model())
    t_obs, q_obs = _observed(recording)
    rot_obs = Rotation.from_quat(q_obs)
    first = {n: PARAMETERS[n].default for n in names}
    first.update({k: float(v) for k, v in (start or {}).items() if k in names})

    @_memoised
    def residuals(values: dict[str, float]) -> Array:
        gains = gains_from_parameters(ws, values)
        pred = predict(
            ws,
            plan.command_times_s,
            plan.command_joints_rad,
            acs_commands=plan.acs_commands,
            acs_gains=gains,
            initial_quat_orbit_from_base_xyzw=plan.initial_quat_orbit_from_base_xyzw,
        )
        slerp = Slerp(pred.t_s, Rotation.from_quat(pred.quat_orbit_from_base_xyzw))
        t = np.clip(t_obs, pred.t_s[0], pred.t_s[-1])
        diff = (slerp(t).inv() * rot_obs).as_rotvec()
        return np.asarray(np.degrees(diff).ravel(), dtype=np.float64)

    objective, values, stderr, r, message = _solve(
        names, first, residuals, max_evaluations, progress
    )
    r0 = residuals(dict(first))
    rows = [
        TargetRow(
            id=f"rms_residual_{axis}_deg",
            target=f"base attitude {axis} against the recording (RMS)",
            tolerance="no worse than the start",
            start=float(np.sqrt(np.mean(r0[k::3] ** 2))),
            fit=float(np.sqrt(np.mean(r[k::3] ** 2))),
            holds_start=True,
            holds=bool(np.mean(r[k::3] ** 2) <= np.mean(r0[k::3] ** 2) + 1e-15),
            source="recording",
        )
        for k, axis in enumerate(("x", "y", "z"))
    ]
    servo = noise = None
    if servo_and_noise:
        servo = fit_servo(
            recording,
            ws,
            start=servo_start,
            max_evaluations=servo_max_evaluations,
            progress=servo_progress,
        )
        noise = estimate_sensor_noise(recording)
        rows += _servo_rows(servo) + _noise_rows(noise)
    return CalibrationResult(
        kind="recording",
        parameters=values,
        start=dict(first),
        standard_error=stderr,
        cost_start=0.5 * float(r0 @ r0),
        cost=0.5 * float(r @ r),
        residual_rms=float(np.sqrt(np.mean(r**2))),
        evaluations=objective.evaluations,
        targets=rows,
        message=message,
        servo=servo,
        sensor_noise=noise,
    )


def _servo_rows(servo: ServoFit) -> list[TargetRow]:
    rows: list[TargetRow] = []
    for j in servo.joints:
        se_lag = "-" if j.lag_standard_error_s is None else f"{j.lag_standard_error_s:.2g} s"
        se_wn = (
            "-"
            if j.bandwidth_standard_error_radps is None
            else f"{j.bandwidth_standard_error_radps:.2g} rad/s"
        )
        rows += [
            TargetRow(
                id=f"servo_lag_j{j.joint}_s",
                target=f"joint {j.joint} servo lag kd/kp (s)",
                tolerance=f"standard error {se_lag}",
                start=j.start_lag_s,
                fit=j.lag_s,
                holds_start=None,
                holds=None,
                source="recording",
                note=j.note if j.lag_s is None else "",
            ),
            TargetRow(
                id=f"servo_bandwidth_j{j.joint}_radps",
                target=f"joint {j.joint} servo bandwidth (rad/s)",
                tolerance=f"standard error {se_wn}",
                start=j.start_bandwidth_radps,
                fit=j.bandwidth_radps,
                holds_start=None,
                holds=None,
                source="recording",
                note=j.note,
            ),
            TargetRow(
                id=f"servo_tracking_rms_j{j.joint}_deg",
                target=f"joint {j.joint} measured against the servo model (RMS, deg)",
                tolerance="no worse than the start",
                start=j.rms_start_deg,
                fit=j.rms_fit_deg,
                holds_start=None if j.rms_fit_deg is None else True,
                holds=None
                if j.rms_fit_deg is None or j.rms_start_deg is None
                else j.rms_fit_deg <= j.rms_start_deg + 1e-12,
                source="recording",
                note=j.note if j.rms_fit_deg is None else "",
            ),
        ]
    return rows


def _noise_rows(noise: NoiseEstimate) -> list[TargetRow]:
    from spacecraft.vehicle_config import SensorNoise

    default = SensorNoise()
    rows = []
    for key, label, value, configured in (
        ("attitude", "attitude (deg)", noise.attitude_deg, math.degrees(default.attitude_rad)),
        ("rate", "base rate (deg/s)", noise.rate_degps, math.degrees(default.rate_radps)),
        ("joint", "joint angles (deg)", noise.joint_deg, math.degrees(default.joint_rad)),
    ):
        count = noise.samples.get(key, 0)
        rows.append(
            TargetRow(
                id=f"sensor_noise_{key}",
                target=f"sensor noise 1-sigma, {label}",
                tolerance=f"from {count} second differences in holds",
                start=configured,
                fit=value,
                holds_start=None,
                holds=None,
                source="recording",
                note="" if value is not None else "too few hold frames",
            )
        )
    return rows


# --- fitting the paper's targets -----------------------------------------------------------


@dataclass(frozen=True)
class _PaperTarget:
    id: str
    target: str
    tolerance: str
    #: the measured value shown in the report, from the metrics
    value: Callable[[Mapping[str, Mapping[str, float]]], float]
    #: the criterion (paper's), from the metrics
    holds: Callable[[Mapping[str, Mapping[str, float]]], bool]
    #: residuals scaled by the tolerance (hinges for orderings)
    residuals: Callable[[Mapping[str, Mapping[str, float]]], list[float]]


#: The hinges ask for the orderings to hold by this much (a tie does not hold).
_MARGIN_DEG = 0.01
_MARGIN_S = 2.0


def _paper_limits() -> dict[str, Mapping[str, float]]:
    from telemetry.analysis.paper import PAPER_RESULTS

    return {r.id: r.limits for r in PAPER_RESULTS}


def _others(m: Mapping[str, Mapping[str, float]], key: str, but: str) -> float:
    names = ("coordination_feedback", "coordination_feedforward", "coordination_offset")
    return min(m[n][key] for n in names if n != but)


def _paper_targets() -> list[_PaperTarget]:
    lim = _paper_limits()
    ptp = lim["ptp_settling"]
    lo_s = ptp["flight_s"] * (1 - ptp["relative_tolerance"])
    hi_s = ptp["flight_s"] * (1 + ptp["relative_tolerance"])
    fb = lim["coordination_feedback_range"]
    ff = lim["coordination_feedforward"]
    fbk, ffw, off = "coordination_feedback", "coordination_feedforward", "coordination_offset"

    def ff_peak_margin(m: Mapping[str, Mapping[str, float]]) -> float:
        others = max(m[fbk]["pitch_max_deg"], m[off]["pitch_max_deg"])
        return m[ffw]["pitch_max_deg"] - others

    start = lim["coordination_start"]

    def worst_start(m: Mapping[str, Mapping[str, float]]) -> float:
        return max(abs(m[n]["start_pitch_deg"]) for n in (fbk, ffw, off))

    return [
        _PaperTarget(
            "ptp_settling",
            f"PTP A->B back within {SETTLE_BAND_DEG} deg of the attitude the loop holds "
            f"about {ptp['flight_s']:.0f} s after the motion",
            f"{lo_s:.0f} to {hi_s:.0f} s",
            lambda m: m["ptp"]["settling_time_s"],
            lambda m: lo_s <= m["ptp"]["settling_time_s"] <= hi_s,
            lambda m: [
                (m["ptp"]["settling_time_s"] - ptp["flight_s"])
                / (ptp["flight_s"] * ptp["relative_tolerance"])
            ],
        ),
        _PaperTarget(
            "coordination_start",
            "every variant of experiment 3 starts at the phase plane's origin (value: the "
            "largest pitch at a forward leg's start)",
            f"at most {start['max_deg']} deg, hinge",
            worst_start,
            lambda m: worst_start(m) <= start["max_deg"],
            lambda m: [max(0.0, worst_start(m) + _MARGIN_DEG - start["max_deg"]) / 0.02],
        ),
        _PaperTarget(
            "coordination_feedback_min",
            f"(a) feedback only: pitch minimum {fb['min_deg']:+.2f} deg",
            f"+-{fb['tolerance_deg']} deg",
            lambda m: m[fbk]["pitch_min_deg"],
            lambda m: abs(m[fbk]["pitch_min_deg"] - fb["min_deg"]) <= fb["tolerance_deg"],
            lambda m: [(m[fbk]["pitch_min_deg"] - fb["min_deg"]) / fb["tolerance_deg"]],
        ),
        _PaperTarget(
            "coordination_feedback_max",
            f"(a) feedback only: pitch maximum {fb['max_deg']:+.2f} deg",
            f"+-{fb['tolerance_deg']} deg",
            lambda m: m[fbk]["pitch_max_deg"],
            lambda m: abs(m[fbk]["pitch_max_deg"] - fb["max_deg"]) <= fb["tolerance_deg"],
            lambda m: [(m[fbk]["pitch_max_deg"] - fb["max_deg"]) / fb["tolerance_deg"]],
        ),
        _PaperTarget(
            "coordination_feedforward_dip",
            f"(b) feedforward: first dip at least {ff['first_dip_deg']:+.2f} deg",
            "hinge, 0.1 deg scale",
            lambda m: m[ffw]["first_dip_deg"],
            lambda m: m[ffw]["first_dip_deg"] >= ff["first_dip_deg"],
            lambda m: [max(0.0, ff["first_dip_deg"] + _MARGIN_DEG - m[ffw]["first_dip_deg"]) / 0.1],
        ),
        _PaperTarget(
            "coordination_feedforward_overshoot",
            f"(b) feedforward: peak over {ff['peak_margin_deg']} deg above (a)'s and (c)'s"
            " (value: the margin)",
            f"hinge, {ff['peak_margin_deg']} deg scale",
            ff_peak_margin,
            lambda m: ff_peak_margin(m) > ff["peak_margin_deg"],
            lambda m: [
                max(0.0, ff["peak_margin_deg"] + _MARGIN_DEG - ff_peak_margin(m))
                / ff["peak_margin_deg"]
            ],
        ),
        _PaperTarget(
            "coordination_offset_range",
            "(c) offset: the smallest pitch range of (a), (b), (c) (value: (c)'s minus the "
            "next smallest)",
            "hinge, 0.05 deg scale",
            lambda m: m[off]["pitch_range_deg"] - _others(m, "pitch_range_deg", off),
            lambda m: m[off]["pitch_range_deg"] < _others(m, "pitch_range_deg", off),
            lambda m: [
                max(
                    0.0,
                    m[off]["pitch_range_deg"] + _MARGIN_DEG - _others(m, "pitch_range_deg", off),
                )
                / 0.05
            ],
        ),
        _PaperTarget(
            "coordination_offset_settling",
            "(c) offset: the fastest settling of (a), (b), (c) (value: (c)'s minus the next "
            "fastest, s)",
            "hinge, 10 s scale",
            lambda m: m[off]["settling_time_s"] - _others(m, "settling_time_s", off),
            lambda m: m[off]["settling_time_s"] < _others(m, "settling_time_s", off),
            lambda m: [
                max(0.0, m[off]["settling_time_s"] + _MARGIN_S - _others(m, "settling_time_s", off))
                / 10.0
            ],
        ),
    ]


def _flight_of(plan: Plan, gains: AcsGains, ws: DynamicsWorkspace) -> Flight:
    pred = predict(
        ws,
        plan.command_times_s,
        plan.command_joints_rad,
        acs_commands=plan.acs_commands,
        acs_gains=gains,
        initial_quat_orbit_from_base_xyzw=plan.initial_quat_orbit_from_base_xyzw,
    )
    return Flight(
        t_s=pred.t_s,
        quat_orbit_from_base_xyzw=pred.quat_orbit_from_base_xyzw,
        joints_rad=pred.joints_rad,
        joint_targets_rad=pred.joints_rad,
        wheel_momentum_nms=pred.wheel_momentum_nms,
        rejected=0,
    )


def _predicted_metrics(
    ws: DynamicsWorkspace, plans: Mapping[str, Plan], gains: AcsGains
) -> dict[str, dict[str, float]]:
    ptp = plans["ptp"]
    flight = _flight_of(ptp, gains, ws)
    out = {
        "ptp": {
            "peak_attitude_deg": float(np.max(flight.attitude_deg)),
            "settling_time_s": ptp_settling_s(flight, ptp),
        }
    }
    coordination = plans["coordination"]
    flight = _flight_of(coordination, gains, ws)
    for label, name in (("(a)", "feedback"), ("(b)", "feedforward"), ("(c)", "offset")):
        out[f"coordination_{name}"] = coordination_metrics(flight, coordination, label)
    return out


def _unfitted_rows(ws: DynamicsWorkspace) -> list[TargetRow]:
    """The paper's targets the law does not shape, reported for completeness."""
    from planner.gjm import plan_gjm

    lim = _paper_limits()["gjm_base_pitch"]
    value = float(plan_gjm(ws).metrics["base_pitch_change_deg"])
    holds = abs(value - lim["flight_deg"]) <= lim["tolerance_deg"]
    return [
        TargetRow(
            "gjm_base_pitch",
            f"GJM base pitch change {lim['flight_deg']:+.2f} deg",
            f"+-{lim['tolerance_deg']} deg",
            value,
            value,
            holds,
            holds,
            "prediction",
            "not fitted: GJM flies in free drift, the law does not act",
        ),
        TargetRow(
            "reactionless_grows_with_speed",
            "reactionless reaction grows with speed",
            "fast leg over 1.2x the slow leg",
            None,
            None,
            None,
            None,
            "prediction",
            "not fitted: the reaction comes from joint-servo lag (servo gains), not the law",
        ),
    ]


def _vehicle_metrics(
    values: Mapping[str, float], ws: DynamicsWorkspace, plans: Mapping[str, Plan]
) -> dict[str, dict[str, float]]:
    """The fit's metrics flown through the vehicle (truth simulation), on the same plans as
    the prediction's (the PTP with its long settling wait)."""
    from spacecraft._calibration import fly_plan
    from spacecraft.vehicle_config import VehicleConfig

    config = VehicleConfig(acs_gains=gains_from_parameters(ws, values))
    ptp = plans["ptp"]
    flight = fly_plan(ptp, config)
    out = {
        "ptp": {
            "peak_attitude_deg": float(np.max(flight.attitude_deg)),
            "settling_time_s": ptp_settling_s(flight, ptp),
        }
    }
    coordination = plans["coordination"]
    flight = fly_plan(coordination, config)
    for label, name in (("(a)", "feedback"), ("(b)", "feedforward"), ("(c)", "offset")):
        out[f"coordination_{name}"] = coordination_metrics(flight, coordination, label)
    return out


def _faithful_note(
    target: _PaperTarget,
    predicted: Mapping[str, Mapping[str, float]],
    flown: Mapping[str, Mapping[str, float]],
) -> str:
    """Where the prediction's verdict at the fit is not the vehicle's, say so."""
    if target.holds(predicted) == target.holds(flown):
        return ""
    return (
        f"the prediction gave {target.value(predicted):.4g} "
        f"({'holds' if target.holds(predicted) else 'does not hold'}): not faithful here"
    )


def fit_to_paper(
    parameters: Sequence[str] = ("bandwidth_radps", "damping_ratio"),
    *,
    ws: DynamicsWorkspace | None = None,
    start: Mapping[str, float] | None = None,
    max_evaluations: int = 40,
    progress: Progress | None = None,
    check_vehicle: bool = False,
) -> CalibrationResult:
    """Fit the law to the paper's targets that it shapes, on the prediction (about 2 s per
    evaluation); with ``check_vehicle`` the start and the fit are also flown through the
    vehicle (:func:`spacecraft._calibration.fly_plan`, the same plans, about 5 s each) and their
    rows added with source ``vehicle``."""
    names = _check_parameters(parameters)
    ws = ws or DynamicsWorkspace(default_model())
    # the PTP with a settling wait long enough to measure a slow law's settling, experiment
    # 3 as the demo pass flies it (spacecraft._calibration.calibration_plans)
    plans = calibration_plans(ws)
    targets = _paper_targets()
    first = {n: PARAMETERS[n].default for n in names}
    first.update({k: float(v) for k, v in (start or {}).items() if k in names})

    @_memoised
    def metrics(values: dict[str, float]) -> dict[str, dict[str, float]]:
        return _predicted_metrics(ws, plans, gains_from_parameters(ws, values))

    def residuals(values: dict[str, float]) -> Array:
        m = metrics(values)
        return np.array([x for t in targets for x in t.residuals(m)], dtype=np.float64)

    objective, values, _, r, message = _solve(names, first, residuals, max_evaluations, progress)
    m0, m1 = metrics(first), metrics(values)
    r0 = np.array([x for t in targets for x in t.residuals(m0)])
    rows = [
        TargetRow(
            t.id,
            t.target,
            t.tolerance,
            float(t.value(m0)),
            float(t.value(m1)),
            bool(t.holds(m0)),
            bool(t.holds(m1)),
            "prediction",
        )
        for t in targets
    ]
    rows += _unfitted_rows(ws)
    if check_vehicle:
        flown = _memoised(lambda v: _vehicle_metrics(v, ws, plans))
        v0, v1 = flown(first), flown(values)
        for t in targets:
            rows.append(
                TargetRow(
                    t.id,
                    t.target,
                    t.tolerance,
                    float(t.value(v0)),
                    float(t.value(v1)),
                    bool(t.holds(v0)),
                    bool(t.holds(v1)),
                    "vehicle",
                    _faithful_note(t, m1, v1),
                )
            )
    return CalibrationResult(
        kind="paper",
        parameters=values,
        start=dict(first),
        standard_error=None,
        cost_start=0.5 * float(r0 @ r0),
        cost=0.5 * float(r @ r),
        residual_rms=float(np.sqrt(np.mean(r**2))),
        evaluations=objective.evaluations,
        targets=rows,
        message=message,
    )
