"""The truth simulation under the onboard computer: the free-floating simulator
(:class:`planner.simulation.FreeFloatingSimulator`) with the faults injected into it
(:mod:`spacecraft.faults`), the noisy sensors that measure it, and the signs that it has
diverged (SPEC section 6, docs/spacecraft.md, docs/robots.md "Servo stability").

:class:`spacecraft.vehicle.Vehicle` drives one: it steps it on the onboard clock's grid with
the wheel torque its attitude control commands, hands it the servo target, and reads the
sensor sample of each instant. What the faults change (the servos' hardware, the wheel
torques, the attitude sensor, the base's momentum) and the divergence are the truth log's
records (:meth:`TruthSimulation.take_log`), never sent down.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.attitude_control import AcsGains
from planner.simulation import FreeFloatingSimulator
from planner.state import State
from spacecraft._sensors import Measurement, measure
from spacecraft.faults import FaultInjector
from spacecraft.vehicle_config import VehicleConfig
from telemetry.wire import (
    MAX_BASE_RATE_RADPS,
    MAX_JOINT_ABS_RAD,
    MAX_WHEEL_SPEED_RADPS,
    SafingTrigger,
)

__all__ = ["TruthSimulation"]

Array = NDArray[np.float64]


class TruthSimulation:
    """The truth of a vehicle of ``config`` whose wheels obey ``gains``' limits, its clock
    starting at onboard ``epoch_ns``, its sensor noise drawn from ``seed``."""

    def __init__(self, config: VehicleConfig, gains: AcsGains, *, epoch_ns: int, seed: int) -> None:
        q0 = np.array(config.initial_joints_rad, dtype=np.float64)
        self.sim = FreeFloatingSimulator(
            config.model,
            State(
                joints_rad=q0,
                quat_orbit_from_base_xyzw=np.array(config.initial_quat_orbit_from_base_xyzw),
                joint_rates_radps=np.zeros_like(q0),
            ),
            replace(
                config.sim,
                wheel_torque_limit_nm=gains.torque_limit_nm,
                wheel_momentum_limit_nms=gains.momentum_limit_nms,
            ),
        )
        self._epoch_ns = epoch_ns
        self._step_ns = config.step_ns
        self._timestep_s = config.sim.timestep_s
        self._noise = config.noise
        self._rng = np.random.default_rng(seed)
        self._faults = FaultInjector(config.faults, epoch_ns=epoch_ns, step_ns=self._step_ns)
        self._sample: tuple[int, State, Measurement] | None = None
        #: the truth state at a step count (the divergence check, control and telemetry at
        #: one instant read it once); cleared where the state changes without a step
        self._state_at: tuple[int, State] | None = None
        self._log: list[dict[str, Any]] = []
        #: onboard ns of the divergence of the truth simulation (None: it holds)
        self.diverged_ns: int | None = None

    @property
    def time_ns(self) -> int:
        """Onboard time: the epoch and the steps taken."""
        return self._epoch_ns + self.sim.step_count * self._step_ns

    def step_to(self, t: int, wheel_torque_nm: Array) -> None:
        """Step to onboard ``t`` (on the grid) with the commanded wheel torque (through the
        wheel faults)."""
        steps = (t - self.time_ns) // self._step_ns
        if steps > 0:
            torque = self._faults.wheel_torque(wheel_torque_nm)
            self.sim.advance(steps * self._timestep_s, wheel_torque_nm=torque)

    def servo(self, target: Array, rate: Array, now: int) -> None:
        """The software's servo target (moving at ``rate``) through the joint faults to the
        servos."""
        target, rate = self._faults.servo(target, rate, now)
        self.sim.set_joint_target(target, rate)

    @property
    def next_fault_ns(self) -> int | None:
        """The onset of the next fault (None: none left)."""
        return self._faults.next_onset_ns

    def command_executed(self, t: int) -> None:
        """A time-tagged command executed at ``t`` (the ``@cmd+T`` faults count from the
        first)."""
        self._faults.first_command(t)

    def begin_faults(self, t: int) -> None:
        """The faults due at ``t`` begin (the truth changes first: what is measured at ``t``
        shows it); the servos must be given their target again."""
        self._log += self._faults.begin(t, self.sim)
        self._state_at = None  # a bump changed the velocities

    def state(self) -> State:
        """The truth state now, read once per step count (shared, read only)."""
        steps = self.sim.step_count
        if self._state_at is None or self._state_at[0] != steps:
            self._state_at = (steps, self.sim.state())
        return self._state_at[1]

    def measure(self, t: int) -> tuple[State, Measurement]:
        """The sensor sample at ``t`` (one per instant: control and telemetry share it)."""
        if self._sample is None or self._sample[0] != t:
            state = self.state()
            sample = self._faults.sense(measure(state, self._noise, self._rng))
            self._sample = (t, state, sample)
        return self._sample[1], self._sample[2]

    def divergence(self, t: int) -> SafingTrigger | None:
        """The sign that the truth simulation has diverged by ``t``, or None: MuJoCo's
        instability warnings (it found the state non-finite or huge and reset it), or the
        state beyond the wire's bounds (``telemetry.wire``'s ``MAX_*``)."""
        warnings = self.sim.instability_warnings
        if warnings:
            return SafingTrigger(
                quantity="simulation_diverged",
                channel="",
                value=float(warnings),
                limit=0.0,
                detail=f"the truth simulation diverged by onboard {t}: MuJoCo reset its "
                f"non-finite or huge state {warnings} time(s) (servos faster than the "
                "integrator holds?)",
            )
        state = self.state()
        checks = (
            ("joints", np.abs(state.joints_rad), MAX_JOINT_ABS_RAD, "rad"),
            ("base rate", np.abs(state.omega_base_orbit_radps), MAX_BASE_RATE_RADPS, "rad/s"),
            ("wheel speed", np.abs(state.wheel_rates_radps), MAX_WHEEL_SPEED_RADPS, "rad/s"),
        )
        for name, values, bound, unit in checks:
            if values.size == 0 or values.max() <= bound:  # finite and within (NaN: false)
                continue
            bad = ~np.isfinite(values) | (np.nan_to_num(values, nan=np.inf) > bound)
            if np.any(bad):
                worst = float(values[int(np.argmax(bad))])
                return SafingTrigger(
                    quantity="simulation_diverged",
                    channel=name.replace(" ", "_"),
                    value=worst if math.isfinite(worst) else 1e308,
                    limit=bound,
                    detail=f"the truth simulation diverged by onboard {t}: {name} {worst:.6g} "
                    f"{unit} (beyond {bound:g} {unit} or not finite)",
                )
        return None

    def diverged(self, t: int, trigger: SafingTrigger) -> None:
        """The truth diverged at ``t`` (``trigger``, of :meth:`divergence`): logged."""
        self.diverged_ns = t
        self._log.append(
            {
                "event": "simulation_diverged",
                "onboard_time_ns": t,
                "onboard_s": (t - self._epoch_ns) / 1e9,
                **trigger.model_dump(),
            }
        )

    def take_log(self) -> list[dict[str, Any]]:
        """The truth log's records since the last call: each fault's onset, the divergence."""
        out, self._log = self._log, []
        return out
