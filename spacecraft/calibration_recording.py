"""Calibrating the attitude-control law to a recorded pass (``hikoboshi calibrate --mcap``
or ``--pass``, docs/spacecraft.md).

:func:`fit_to_recording`: the plan's prediction (:func:`planner.prediction.predict`, ideal
tracking) with the law against a recorded pass's base attitude, the rotation vector of the
difference per axis over the frames flown in ``feedback`` mode, in least squares
(:func:`spacecraft.calibration.solve`). Returns the fit, its residual RMS and standard
errors from the Jacobian.

With ``servo_and_noise`` it also fits the joint servos (each joint's lag and, where
observable, bandwidth) and estimates the sensor noise (:mod:`spacecraft.servo_fit`), adding
their rows to the report; :func:`spacecraft.servo_fit.write_vehicle_config` writes them as
``[servo]`` and ``[sensor_noise]`` tables.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation, Slerp

from planner.attitude_control import AcsMode
from planner.dynamics import DynamicsWorkspace
from planner.errors import InvalidInput
from planner.mjcf import ServoGains
from planner.model import default_model
from planner.plan import Plan
from spacecraft.calibration import (
    CalibrationResult,
    Progress,
    TargetRow,
    check_parameters,
    gains_from_parameters,
    memoised,
    predict_with,
    solve,
    start_values,
)
from spacecraft.servo_fit import NoiseEstimate, ServoFit, estimate_sensor_noise, fit_servo

__all__ = ["fit_to_recording"]

Array = NDArray[np.float64]


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
    names = check_parameters(parameters)
    plan: Plan = recording.plan
    ws = ws or DynamicsWorkspace(default_model())
    t_obs, q_obs = _observed(recording)
    rot_obs = Rotation.from_quat(q_obs)
    first = start_values(names, start)

    @memoised
    def residuals(values: dict[str, float]) -> Array:
        pred = predict_with(ws, plan, gains_from_parameters(ws, values))
        slerp = Slerp(pred.t_s, Rotation.from_quat(pred.quat_orbit_from_base_xyzw))
        t = np.clip(t_obs, pred.t_s[0], pred.t_s[-1])
        diff = (slerp(t).inv() * rot_obs).as_rotvec()
        return np.asarray(np.degrees(diff).ravel(), dtype=np.float64)

    fit = solve(names, first, residuals, max_evaluations, progress)
    r = fit[3]
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
    return CalibrationResult.of_fit(
        "recording", first, fit, r0, rows, servo=servo, sensor_noise=noise
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
