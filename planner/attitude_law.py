"""The base attitude-control law evaluated (:mod:`planner.attitude_control` defines it: the
modes, the feedback and feedforward, the law family's parameters :class:`~planner.
attitude_control.AcsGains`).

**One law, two clocks.** The law is defined in continuous time. :class:`AttitudeController`
is its sampled form, used by the truth simulation (:func:`planner.closed_loop.fly`) and the
vehicle at their control period: it advances its state by the time between calls, taking
each sample to hold over the interval that ends at it, with the exact discretisation of the
filter (``x <- a x + (1 - a) u``, ``a = exp(-dt/tau)``: a step of the rate reaches
``1 - exp(-t/tau)`` at every sample time, whatever the period) and the rectangle rule for the
integrator. The prediction (:func:`planner.prediction.predict`) integrates the same law in
continuous time, its two states appended to its ODE (:func:`law_rates`) and reset at the
same events; both share :func:`_torque` for the torque itself. This is how the PD law has
always been shared (continuous in the prediction, sampled at 10 Hz on board); the laws'
time scales (tens of seconds) are far above the 0.1 s sample period. A law without states
(no integral term, no rate filter) is also a plain function of the measurements
(:func:`wheel_torque_nm`).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from planner.attitude_control import AcsGains, AcsMode, attitude_error_rad
from planner.errors import InvalidInput

__all__ = ["AttitudeController", "law_rates", "wheel_torque_nm"]

Array = NDArray[np.float64]


def _dead_band(gains: AcsGains, error: Array) -> Array:
    band = gains.dead_band_rad
    if band == 0.0:
        return error
    return np.asarray(np.sign(error) * np.maximum(np.abs(error) - band, 0.0), dtype=np.float64)


def _torque(
    gains: AcsGains, error_db: Array, rate_error: Array, integral: Array | None
) -> tuple[Array, Array]:
    """The law's torque before and after the torque limit: P on the dead-banded error, D on
    the (estimated) rate error, I on the integral if any. Shared by every caller."""
    raw = gains.kp_nm_per_rad * error_db + gains.kd_nms_per_rad * rate_error
    if integral is not None:
        raw = raw + gains.ki_nm_per_rad_s * integral
    return raw, np.clip(raw, -gains.torque_limit_nm, gains.torque_limit_nm)


def _rate_error(omega_base_radps: Array, reaction_rate_radps: Array | None) -> Array:
    rate_error = np.asarray(omega_base_radps, dtype=np.float64)
    if reaction_rate_radps is not None:
        rate_error = rate_error + reaction_rate_radps  # w - w_ref with w_ref = -w_ff
    return rate_error


def wheel_torque_nm(
    gains: AcsGains,
    mode: AcsMode,
    *,
    attitude_error: Array,
    omega_base_radps: Array,
    reaction_rate_radps: Array | None = None,
) -> Array:
    """Wheel motor torques (base frame, N m) of a *memoryless* law (no integral term, no
    rate filter; a dead band is allowed), saturated at the torque limit.

    ``omega_base_radps`` is the (measured) base rate in the base frame;
    ``reaction_rate_radps`` the eq. (9) reaction rate of the commanded arm motion
    (:func:`planner.attitude_control.reaction_rate_radps`) when feedforward is on: the rate
    loop then tracks its negative (:mod:`planner.attitude_control`'s docstring). Free drift
    gives zero torque. A law with states needs :class:`AttitudeController` (sampled) or
    :func:`law_rates` (continuous).
    """
    if mode is AcsMode.FREE_DRIFT:
        return np.zeros(3)
    if mode is not AcsMode.FEEDBACK:
        raise InvalidInput(f"unknown attitude-control mode {mode!r}")
    if gains.stateful:
        raise InvalidInput(
            "a law with an integral term or a rate filter has states: use AttitudeController"
        )
    rate_error = _rate_error(omega_base_radps, reaction_rate_radps)
    return _torque(gains, _dead_band(gains, attitude_error), rate_error, None)[1]


def law_rates(
    gains: AcsGains,
    *,
    attitude_error: Array,
    rate_error: Array,
    integral: Array,
    rate_estimate: Array,
) -> tuple[Array, Array, Array]:
    """The law in continuous time (feedback mode), for an ODE integration: the wheel torque
    and the time derivatives of the integral state and the rate estimate.

    ``rate_error`` is the measured ``w - w_ref`` (:func:`_rate_error`); ``integral`` and
    ``rate_estimate`` the states (start them at 0 and at the rate error when the law
    (re)starts). Unused states have zero derivatives.
    """
    error = _dead_band(gains, attitude_error)
    tau = gains.rate_filter_tau_s
    if tau > 0.0:
        rate_used = rate_estimate
        d_rate = (rate_error - rate_estimate) / tau
    else:
        rate_used, d_rate = rate_error, np.zeros(3)
    if gains.has_integral:
        raw, torque = _torque(gains, error, rate_used, integral)
        d_integral = np.where(np.abs(raw) > gains.torque_limit_nm, 0.0, error)
    else:
        torque = _torque(gains, error, rate_used, None)[1]
        d_integral = np.zeros(3)
    return torque, d_integral, d_rate


class AttitudeController:
    """The law sampled at the callers' control period (see the module docstring): state is
    the integral, the rate estimate, the time of the last call and the target in force."""

    def __init__(self, gains: AcsGains) -> None:
        self.gains = gains
        self._integral = np.zeros(3)
        self._rate: Array | None = None
        self._last_t_s: float | None = None
        self._target: Array | None = None
        self._integral_restarts = False

    def reset(self) -> None:
        """Forget the state: the next call (re)starts the law (integral 0, rate estimate
        primed with the rate error then)."""
        self._integral = np.zeros(3)
        self._rate = None
        self._last_t_s = None
        self._target = None
        self._integral_restarts = False

    @property
    def integral_rad_s(self) -> Array:
        return self._integral.copy()

    @property
    def rate_estimate_radps(self) -> Array | None:
        return None if self._rate is None else self._rate.copy()

    def torque(
        self,
        t_s: float,
        mode: AcsMode,
        *,
        target_quat_xyzw: Array | None = None,
        quat_orbit_from_base_xyzw: Array | None = None,
        omega_base_radps: Array | None = None,
        reaction_rate_radps: Array | None = None,
    ) -> Array:
        """Wheel motor torques (base frame, N m) at ``t_s`` in ``mode``: free drift resets
        the law and gives zero; in feedback a new target restarts the integral (the rate
        estimate carries on). The attitude and rate are the measured ones (not needed in
        free drift)."""
        if mode is AcsMode.FREE_DRIFT:
            self.reset()
            return np.zeros(3)
        if mode is not AcsMode.FEEDBACK:
            raise InvalidInput(f"unknown attitude-control mode {mode!r}")
        if (
            target_quat_xyzw is None
            or quat_orbit_from_base_xyzw is None
            or omega_base_radps is None
        ):
            raise InvalidInput("feedback needs the target, the attitude and the rate")
        if self._target is None:
            self.reset()  # the law starts: integral 0, the rate estimate primed below
            self._target = np.array(target_quat_xyzw, dtype=np.float64)
        elif not np.array_equal(self._target, target_quat_xyzw):
            # A new target restarts the integral only: the rate estimate is a measurement
            # and does not depend on the target (re-priming it with the raw rate would make
            # every target switch a kick of its own, whatever the offset's size).
            self._integral = np.zeros(3)
            self._integral_restarts = True
            self._target = np.array(target_quat_xyzw, dtype=np.float64)
        return self.feedback_torque(
            t_s,
            attitude_error_rad(quat_orbit_from_base_xyzw, self._target),
            omega_base_radps,
            reaction_rate_radps,
        )

    def feedback_torque(
        self,
        t_s: float,
        attitude_error: Array,
        omega_base_radps: Array,
        reaction_rate_radps: Array | None = None,
    ) -> Array:
        """The feedback law at ``t_s`` on the attitude error and the measured rate (and the
        feedforward's reaction rate, if on), advancing the state from the last call."""
        gains = self.gains
        dt = 0.0 if self._last_t_s is None else t_s - self._last_t_s
        if not dt >= 0.0:
            raise InvalidInput(
                f"the controller cannot go back in time ({t_s!r} s after {self._last_t_s!r} s)"
            )
        self._last_t_s = t_s
        rate_error = _rate_error(omega_base_radps, reaction_rate_radps)
        error = _dead_band(gains, attitude_error)
        if gains.rate_filter_tau_s > 0.0:
            if self._rate is None:
                self._rate = rate_error.copy()
            else:
                a = math.exp(-dt / gains.rate_filter_tau_s)
                self._rate = a * self._rate + (1.0 - a) * rate_error
            rate_error = self._rate
        if self._integral_restarts:  # a new target: the integral starts now, at 0
            self._integral_restarts, dt = False, 0.0
        if not gains.has_integral:
            return _torque(gains, error, rate_error, None)[1]
        candidate = self._integral + error * dt
        raw, _ = _torque(gains, error, rate_error, candidate)
        self._integral = np.where(np.abs(raw) > gains.torque_limit_nm, self._integral, candidate)
        return _torque(gains, error, rate_error, self._integral)[1]
