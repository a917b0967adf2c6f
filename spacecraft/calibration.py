"""Calibrating the attitude-control law (``hikoboshi calibrate``, docs/spacecraft.md): what
both fits share.

Two fits of the law's design parameters (:func:`planner.attitude_control.default_acs_gains`:
``bandwidth_radps``, ``damping_ratio``, ``rate_filter_tau_s``, ``integral_time_s``, the
torque limit and the dead band), to a recorded pass
(:func:`spacecraft.calibration_recording.fit_to_recording`) and to the paper's targets
(:func:`spacecraft.calibration_paper.fit_to_paper`). Both go through :func:`solve`:
:func:`scipy.optimize.least_squares` (trust-region reflective, bounds) in a well-scaled
space (:data:`PARAMETERS`: logarithms of the bandwidth and damping ratio, ``log(1 + tau)``,
the integral rate ``100 s / Ti`` with 0 = no integral term), at most a budget of
evaluations, the best point seen kept.

Every report row (:class:`TargetRow`) holds the target, its tolerance, the value at the
start and at the fit and whether the criterion holds there: a target the fit cannot meet
says so. :func:`write_acs_config` writes the fit as an ``[acs]`` table.
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

from planner.attitude_control import (
    DEFAULT_ACS_BANDWIDTH_RADPS,
    DEFAULT_ACS_DAMPING_RATIO,
    DEFAULT_DEAD_BAND_DEG,
    DEFAULT_RATE_FILTER_TAU_S,
    DEFAULT_WHEEL_TORQUE_LIMIT_NM,
    AcsGains,
    default_acs_gains,
)
from planner.dynamics import DynamicsWorkspace
from planner.errors import InvalidInput
from planner.plan import Plan, Prediction
from planner.prediction import predict
from spacecraft.servo_fit import NoiseEstimate, ServoFit

__all__ = [
    "PARAMETERS",
    "CalibrationResult",
    "Progress",
    "TargetRow",
    "check_parameters",
    "gains_from_parameters",
    "memoised",
    "predict_with",
    "solve",
    "start_values",
    "write_acs_config",
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


def check_parameters(parameters: Sequence[str]) -> tuple[str, ...]:
    """The names to fit, each of :data:`PARAMETERS` once (:class:`InvalidInput` otherwise)."""
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


def start_values(names: Sequence[str], start: Mapping[str, float] | None) -> dict[str, float]:
    """A fit's start: each of ``names`` at its default, or at ``start``'s value where given
    (``start``'s other names left out)."""
    first = {n: PARAMETERS[n].default for n in names}
    first.update({k: float(v) for k, v in (start or {}).items() if k in names})
    return first


def predict_with(ws: DynamicsWorkspace, plan: Plan, gains: AcsGains) -> Prediction:
    """``plan``'s prediction (ideal tracking) under the law of ``gains``, from the plan's
    initial attitude."""
    return predict(
        ws,
        plan.command_times_s,
        plan.command_joints_rad,
        acs_commands=plan.acs_commands,
        acs_gains=gains,
        initial_quat_orbit_from_base_xyzw=plan.initial_quat_orbit_from_base_xyzw,
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

    @classmethod
    def of_fit(
        cls,
        kind: str,
        start: dict[str, float],
        fit: tuple[_Objective, dict[str, float], dict[str, float] | None, Array, str],
        r_start: Array,
        targets: list[TargetRow],
        **more: Any,
    ) -> CalibrationResult:
        """The result of ``fit`` (what :func:`solve` returned) from ``start``, whose
        residuals were ``r_start``."""
        objective, values, stderr, r, message = fit
        return cls(
            kind=kind,
            parameters=values,
            start=dict(start),
            standard_error=stderr,
            cost_start=0.5 * float(r_start @ r_start),
            cost=0.5 * float(r @ r),
            residual_rms=float(np.sqrt(np.mean(r**2))),
            evaluations=objective.evaluations,
            targets=targets,
            message=message,
            **more,
        )

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


def memoised(fn: Callable[[dict[str, float]], _T]) -> Callable[[dict[str, float]], _T]:
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


def solve(
    names: tuple[str, ...],
    start: Mapping[str, float],
    residuals: Callable[[dict[str, float]], Array],
    max_evaluations: int,
    progress: Progress | None,
) -> tuple[_Objective, dict[str, float], dict[str, float] | None, Array, str]:
    """Fit ``names`` from ``start`` so that ``residuals`` of the values are least squares,
    in at most ``max_evaluations``: the objective (its evaluations and costs), the values
    at the fit, their standard errors from the Jacobian (None where it cannot tell), the
    residuals there and the optimiser's message."""
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
