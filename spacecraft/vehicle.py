"""The flight segment: onboard computer and truth simulation, driven by onboard time.

Deterministic and free of I/O: the spacecraft process (``spacecraft.process``) owns the
sockets and the clock and calls :meth:`Vehicle.receive` with each uplinked command,
:meth:`Vehicle.delete_schedule` with each ``schedule_delete``,
:meth:`Vehicle.heard_from_ground` on every message the uplink delivers, and
:meth:`Vehicle.advance_to` with the onboard time it has reached. Onboard rules (SPEC section
6, docs/spacecraft.md):

- **Time.** The onboard clock starts at ``epoch_ns`` and moves on the truth simulation's
  step grid (10 ms); :meth:`~Vehicle.advance_to` stops on the last grid point at or before the
  time it is given and never goes back.
- **Commands** (:meth:`~Vehicle.receive`, :meth:`~Vehicle.delete_schedule`): retransmitted
  copies, acceptance and ``schedule_delete`` follow the rules of :mod:`spacecraft.schedule`,
  which keeps the onboard schedule; the vehicle executes what it queues.
- **Execution.** The truth simulation (:mod:`spacecraft.truth_sim`) is stepped exactly to
  each tag and the command executes there. A joint command sets the servo target to its
  joints, from where it ramps to the next queued joint command and never steps
  (:mod:`spacecraft.servo_target`). An attitude-control command switches mode, target and
  feedforward at its tag.
- **Attitude control** (:mod:`spacecraft.onboard_acs`) runs every ``control_period_s`` (and
  at each attitude command's tag) on the *measured* (noisy) attitude and rate.
- **Telemetry**: a frame every ``telemetry_period_s`` on the epoch grid, seq from 0, with the
  schedule's summary (queued count, first and last tag, capacity, last executed seq).
- **Loss of signal** (``los_policy``): with ``continue`` (the default) silence from the
  ground changes nothing: the loaded schedule executes. With ``hold``, once nothing has
  arrived from the ground for ``los_hold_after_s`` (the first grid point at or after that),
  every queued joint command is refused (``link_lost``, acks returned by ``advance_to``) and
  the arm holds the target it has reached; attitude control carries on in its mode (queued
  attitude commands still execute at their tags). :meth:`~Vehicle.link_lost` does the same
  at once.
- **On-board safing** (:mod:`spacecraft.safing`; ``safing=False`` flies without it): at each
  control tick, before the commands due then, the red limits of the safing quantities are
  checked on the measured sample. On one the vehicle is SAFE at that tick: the frame of that
  sample goes down as it stood (the ground sees the value), every queued command is dropped
  and acknowledged ``rejected`` ``safing`` (acks returned by ``advance_to``), the servo
  targets hold the measured joints, attitude control holds the measured attitude in feedback
  without feedforward, and a ``safing`` report is queued (:meth:`~Vehicle.take_safing_reports`;
  again every onboard second while safe). Commands are refused ``safing`` until
  :meth:`~Vehicle.safe_exit`.
- **Faults** (:mod:`spacecraft.faults`) change the truth simulation at their onset: what the
  servos' hardware applies (the software's target, in telemetry, is unchanged), the wheel
  torques, the attitude sensor, the base's momentum. Their onsets and SAFE's entries and exits
  are the truth log's records (:meth:`~Vehicle.take_truth_events`), never sent down.
- **A diverged simulation** (servos the integrator cannot hold, docs/robots.md "Servo
  stability"): checked after every step of the truth
  (:meth:`~spacecraft.truth_sim.TruthSimulation.divergence`: MuJoCo's instability warnings,
  the state against the wire's bounds). On the first sign the vehicle is SAFE with the trigger
  ``simulation_diverged`` (even when it flies without safing), the schedule dropped as
  above, and from then on it generates **no telemetry frame**: nonsense is never streamed.
  The truth log records the divergence.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.attitude_control import AcsGains, default_acs_gains
from planner.dynamics import DynamicsWorkspace
from planner.state import State
from spacecraft.onboard_acs import OnboardAcs
from spacecraft.safing import OnboardSafing, monitor_for
from spacecraft.schedule import OnboardSchedule
from spacecraft.servo_target import ServoTarget
from spacecraft.truth_sim import TruthSimulation
from spacecraft.vehicle_config import VehicleConfig, VehicleError, grid_ns
from telemetry.wire import (
    AcsCommandMsg,
    AcsModeName,
    CommandAck,
    JointCommandMsg,
    RejectReason,
    SafeExit,
    Safing,
    SafingTrigger,
    ScheduleDelete,
    TelemetryFrame,
    Verification,
)

__all__ = ["Vehicle"]

Array = NDArray[np.float64]


class Vehicle:
    """The spacecraft's onboard computer around its truth simulation (see the module doc)."""

    def __init__(self, config: VehicleConfig, *, epoch_ns: int, seed: int) -> None:
        if epoch_ns < 0:
            raise VehicleError(f"epoch_ns = {epoch_ns} must not be negative")
        self.config = config
        model = config.model
        self._ws = DynamicsWorkspace(model, config.sim.orbit)
        self._gains = config.acs_gains or default_acs_gains(self._ws)
        q0 = np.array(config.initial_joints_rad, dtype=np.float64)
        self._truth = TruthSimulation(config, self._gains, epoch_ns=epoch_ns, seed=seed)
        self._epoch_ns = epoch_ns
        self._step_ns = config.step_ns
        self._telemetry_ns = grid_ns("telemetry_period_s", config.telemetry_period_s, 1)
        self._control_ns = grid_ns("control_period_s", config.control_period_s, 1)
        self._spin_inertia = np.array([w.spin_inertia_kgm2 for w in model.wheels])

        self._schedule = OnboardSchedule(
            model, epoch_ns=epoch_ns, step_ns=self._step_ns, capacity=config.schedule_capacity
        )
        # LOS policy: the onboard time of the last message from the ground, and how long
        # the silence may last before the arm holds (None: policy "continue").
        self._last_heard_ns = epoch_ns
        self._los_hold_ns = (
            round(config.los_hold_after_s * 1e9)
            if config.los_policy == "hold" and config.los_hold_after_s is not None
            else None
        )
        self._next_frame_seq = 0
        self._next_frame_ns = epoch_ns
        self._next_control_ns = epoch_ns

        self._acs = OnboardAcs(self._gains, self._ws, config.initial_acs_mode, epoch_ns=epoch_ns)
        # The onboard software's servo target; the joint servos' hardware applies it
        # through the faults.
        self._target = ServoTarget(q0, model.joint_limit_rad, epoch_ns)
        self._safing = OnboardSafing(epoch_ns=epoch_ns)
        self._monitor = (
            monitor_for(
                config.model,
                limits=config.limits,
                collision=config.collision,
                builtin=config.robot is None,
                momentum_limit_nms=self._gains.momentum_limit_nms,
            )
            if config.safing
            else None
        )

    # -- clock and counters -------------------------------------------------------------

    @property
    def epoch_ns(self) -> int:
        return self._epoch_ns

    @property
    def onboard_time_ns(self) -> int:
        return self._truth.time_ns

    @property
    def next_telemetry_seq(self) -> int:
        """The seq the next telemetry frame will carry (= frames generated so far)."""
        return self._next_frame_seq

    @property
    def last_command_seq(self) -> int:
        """The highest command seq received, accepted or not (-1 before the first)."""
        return self._schedule.last_command_seq

    # -- state for tests and tools ------------------------------------------------------

    @property
    def gains(self) -> AcsGains:
        return self._gains

    @property
    def acs_mode(self) -> AcsModeName:
        return AcsModeName(self._acs.mode.value)

    @property
    def acs_target_quat_xyzw(self) -> Array:
        return self._acs.target.copy()

    @property
    def acs_feedforward(self) -> bool:
        return self._acs.feedforward

    @property
    def queued(self) -> int:
        return len(self._schedule.buffer)

    @property
    def last_heard_ns(self) -> int:
        """The onboard time of the last message from the ground (the epoch before any)."""
        return self._last_heard_ns

    def true_state(self) -> State:
        return self._truth.sim.state()

    def joint_target_rad(self) -> Array:
        """The onboard software's servo target now (the commanded joints exactly at each
        command's tag; a joint fault changes what the hardware applies, not this)."""
        return self._target.at(self.onboard_time_ns)

    # -- on-board safing and faults ------------------------------------------------------

    @property
    def safe(self) -> bool:
        """The vehicle is in SAFE (on-board safing) until a ``safe_exit``."""
        return self._safing.safe

    @property
    def onboard_safing(self) -> OnboardSafing:
        """The SAFE state (when, why, how many commands it dropped), for tests and tools."""
        return self._safing

    def safe_exit(self, req: SafeExit) -> Safing:
        """Leave SAFE (the arm keeps holding, attitude control keeps its feedback hold,
        commands are accepted again): the ``safing`` report ``nominal`` with this
        ``request_id``. Idempotent by ``request_id``; answered ``nominal`` when not safe."""
        self.heard_from_ground()
        report, _ = self._safing.exit(req.request_id, self.onboard_time_ns)
        return report

    def safing_report(self) -> Safing | None:
        """The ``safing`` report of the SAFE state now (None when not safe): what a safe
        vehicle sends right after ``hello``."""
        return self._safing.report(self.onboard_time_ns) if self._safing.safe else None

    def take_safing_reports(self) -> list[Safing]:
        """The ``safing`` reports made since the last call (entry, then every onboard
        second while safe), for the downlink."""
        return self._safing.take_reports()

    def take_truth_events(self) -> list[dict[str, Any]]:
        """The truth log's records since the last call, in time order: each fault's onset,
        each entry into SAFE and exit from it (never sent to the ground)."""
        records = self._truth.take_log() + self._safing.take_truth()
        return sorted(records, key=lambda r: r["onboard_time_ns"])

    def wheel_momentum_nms(self) -> Array:
        """Rotor momentum relative to the base, ``I_w * speed`` (N m s, base frame)."""
        return self._truth.sim.wheel_momentum_nms()

    def wheel_torque_command_nm(self) -> Array:
        """The wheel motor torque the attitude controller commands (clipped at the torque
        limit; the simulator also stops a wheel at its momentum capacity)."""
        return self._acs.wheel_torque_nm.copy()

    # -- uplink ---------------------------------------------------------------------------

    def heard_from_ground(self) -> None:
        """A message from the ground arrived now (any message: the LOS policy's clock)."""
        self._last_heard_ns = max(self._last_heard_ns, self.onboard_time_ns)

    def receive(self, cmd: JointCommandMsg | AcsCommandMsg) -> CommandAck:
        """Check a command against the onboard rules and queue it (:mod:`spacecraft.schedule`):
        ``received``, or ``rejected`` with the reason and a detail that names the value and
        the limit. A copy of a command received before is answered with its latest
        acknowledgement."""
        self.heard_from_ground()
        now = self.onboard_time_ns
        ack, queued = self._schedule.receive(
            cmd, now, refusal=self._safing_refusal(), target_at=self._target.at
        )
        if (
            queued
            and isinstance(cmd, JointCommandMsg)
            and (self._target.ramp_to_ns is None or cmd.execute_time_ns < self._target.ramp_to_ns)
        ):
            self._ramp_to_next(now)  # it is the next one now: head for it from here
        return ack

    def outcome(self, seq: int) -> CommandAck | None:
        """The latest acknowledgement of command ``seq`` (None: never received)."""
        return self._schedule.outcome(seq)

    def _safing_refusal(self) -> str | None:
        """Why no command is accepted now (the vehicle is safe), or None."""
        if not self._safing.safe:
            return None
        trigger = self._safing.trigger
        why = f" ({trigger.quantity} {trigger.channel})" if trigger is not None else ""
        return (
            f"the vehicle is safe since {self._safing.since_ns}{why}: no command is "
            "accepted until safe_exit"
        )

    def link_lost(self) -> list[CommandAck]:
        """SPEC 6 safe state now (what the ``hold`` LOS policy does after its silence):
        refuse every queued joint command (``link_lost``) and hold the servo target where it
        stands; attitude control carries on in its mode."""
        return self._hold_arm(self.onboard_time_ns, "link lost: the arm holds its target")

    def _hold_arm(self, now: int, detail: str) -> list[CommandAck]:
        acks = self._schedule.drop_joints(now, RejectReason.LINK_LOST, detail)
        self._ramp_to_next(now)  # nothing queued: hold
        return acks

    def _los_deadline_ns(self) -> int | None:
        """When the ``hold`` LOS policy holds the arm (the first grid point at or after
        the allowed silence), if it has joint commands to refuse."""
        if self._los_hold_ns is None or not self._schedule.buffer.joints_queued:
            return None
        t = self._last_heard_ns + self._los_hold_ns
        steps = -((self._epoch_ns - t) // self._step_ns)  # ceil
        return self._epoch_ns + steps * self._step_ns

    def delete_schedule(self, req: ScheduleDelete) -> Verification:
        """PUS 11 delete by time range (:meth:`spacecraft.schedule.OnboardSchedule.delete`):
        the report; the servo target then heads for the first joint command left, or holds.
        Idempotent by ``request_id``."""
        self.heard_from_ground()
        now = self.onboard_time_ns
        report, carried_out = self._schedule.delete(req, now)
        if carried_out:
            nxt = self._schedule.buffer.first_joint()
            if (nxt.execute_time_ns if nxt is not None else None) != self._target.ramp_to_ns:
                self._ramp_to_next(now)  # the command ramped to is gone: the next one, or hold
        return report

    # -- time ---------------------------------------------------------------------------

    def advance_to(self, time_ns: int) -> tuple[list[CommandAck], list[TelemetryFrame]]:
        """Run the vehicle to ``time_ns`` (onboard clock; down to the step grid). Returns the
        ``executed`` acks and the telemetry frames generated on the way, in time order."""
        acks: list[CommandAck] = []
        frames: list[TelemetryFrame] = []
        if time_ns < self.onboard_time_ns:
            return acks, frames
        end = self._epoch_ns + (time_ns - self._epoch_ns) // self._step_ns * self._step_ns
        while True:
            tag = self._schedule.buffer.next_tag_ns()
            los = self._los_deadline_ns()
            fault = self._truth.next_fault_ns
            report = self._safing.next_report_ns
            t = min(
                x
                for x in (self._next_control_ns, self._next_frame_ns, tag, los, fault, report)
                if x is not None
            )
            if t > end:
                break
            self._truth.step_to(t, self._acs.wheel_torque_nm)
            if self._truth.diverged_ns is None:
                diverged = self._truth.divergence(t)
                if diverged is not None:
                    acks += self._enter_diverged(t, diverged)
            if fault == t:  # the truth changes first: what is measured at t shows it
                self._truth.begin_faults(t)
                self._apply_servo(t)
            trigger = self._check_safing(t) if t == self._next_control_ns else None
            if trigger is not None:  # before the commands due at t: none executes
                # the frame of the sample that tripped, as it stood (the ground sees the
                # value), then SAFE: the regular frame at t, if any, is this one
                if self._truth.diverged_ns is None:
                    frames.append(self._frame(t))
                if t == self._next_frame_ns:
                    self._next_frame_ns += self._telemetry_ns
                acks += self._enter_safe(t, trigger)
            if los == t:  # the silence lasted: no joint command executes from now on
                silent_s = (t - self._last_heard_ns) / 1e9
                acks += self._hold_arm(
                    t,
                    f"nothing from the ground for {silent_s:.3f} s (LOS policy hold after "
                    f"{self.config.los_hold_after_s:g} s): the arm holds its target",
                )
            if tag == t:  # commands first: control and telemetry at t see their effect
                acks += self._execute(t)
            if t == self._next_control_ns:
                self._acs.control(t, self._truth.measure, self._target)
                self._next_control_ns += self._control_ns
            if report == t:
                self._safing.tick(t)
            if t == self._next_frame_ns:
                if self._truth.diverged_ns is None:  # a diverged truth is never streamed
                    frames.append(self._frame(t))
                self._next_frame_ns += self._telemetry_ns
        self._truth.step_to(end, self._acs.wheel_torque_nm)
        if self._truth.diverged_ns is None:
            diverged = self._truth.divergence(end)
            if diverged is not None:
                acks += self._enter_diverged(end, diverged)
        return acks, frames

    @property
    def diverged_ns(self) -> int | None:
        """When the truth simulation diverged (onboard ns), None while it holds."""
        return self._truth.diverged_ns

    def _enter_diverged(self, t: int, trigger: SafingTrigger) -> list[CommandAck]:
        """The truth has diverged at ``t``: SAFE with that trigger (already SAFE: the
        divergence is logged), and no frame from now on."""
        self._truth.diverged(t, trigger)
        if self._safing.safe:
            return []
        return self._enter_safe(t, trigger)

    def _execute(self, t: int) -> list[CommandAck]:
        acks = []
        for cmd in self._schedule.buffer.pop_due(t):
            if isinstance(cmd, JointCommandMsg):
                self._set_target(np.array(cmd.joints_rad, dtype=np.float64), None, t)
                self._ramp_to_next(t)
            else:
                self._acs.command(cmd)
                # the switch takes effect at the tag, not at the next tick
                self._acs.control(t, self._truth.measure, self._target)
            acks.append(self._schedule.executed(cmd.seq, t))
            self._truth.command_executed(t)
        return acks

    def _ramp_to_next(self, now: int) -> None:
        """Move the servo target from where it stands now to the earliest queued joint
        command, reaching it at its tag; hold if there is none."""
        self._target.ramp(self._schedule.buffer.first_joint(), now)
        self._apply_servo(now)

    def _set_target(self, target: Array, rate: Array | None, now: int) -> None:
        """The software's servo target from ``now`` (moving at ``rate``; None: holding),
        applied by the servos' hardware."""
        self._target.set(target, rate, now)
        self._apply_servo(now)

    def _apply_servo(self, now: int) -> None:
        """The software's target through the joint faults to the servos."""
        self._truth.servo(self._target.at(now), self._target.rate, now)

    def _check_safing(self, t: int) -> SafingTrigger | None:
        """The red limit crossed by the measured sample at ``t`` (None: none, or the vehicle
        is safe already, or flies without safing)."""
        if self._monitor is None or self._safing.safe:
            return None
        state, m = self._truth.measure(t)
        return self._monitor.check(
            joint_targets_rad=self._target.at(t),
            joints_rad=m.joints_rad,
            quat_orbit_from_base_xyzw=m.quat_orbit_from_base_xyzw,
            acs_target_quat_xyzw=self._acs.target,
            wheel_speeds_radps=state.wheel_rates_radps,
        )

    def _enter_safe(self, t: int, trigger: SafingTrigger) -> list[CommandAck]:
        """SAFE at ``t``: every queued command dropped (acknowledged ``rejected``
        ``safing``), the arm held where it is measured, attitude control to feedback on the
        measured attitude, the entry report queued."""
        _, m = self._truth.measure(t)
        channel = f" {trigger.channel}" if trigger.channel else ""
        detail = (
            f"on-board safing at {t}: {trigger.quantity}{channel} {trigger.value:.4g} "
            f"beyond its red limit {trigger.limit:g}"
        )
        acks = self._schedule.drop_all(t, RejectReason.SAFING, detail)
        # hold the arm where it is measured, and the attitude where it is measured
        self._target.hold(m.joints_rad, t)
        self._apply_servo(t)
        self._acs.hold(m.quat_orbit_from_base_xyzw)
        self._safing.enter(t, trigger, len(acks))
        return acks

    # -- telemetry ------------------------------------------------------------------------

    def _frame(self, t: int) -> TelemetryFrame:
        state, m = self._truth.measure(t)
        frame = TelemetryFrame(
            seq=self._next_frame_seq,
            generation_time_ns=t,
            joints_rad=m.joints_rad.tolist(),
            joint_targets_rad=self._target.at(t).tolist(),
            quat_orbit_from_base_xyzw=m.quat_orbit_from_base_xyzw.tolist(),
            omega_base_in_base_radps=m.omega_base_in_base_radps.tolist(),
            wheel_speeds_radps=state.wheel_rates_radps.tolist(),
            wheel_momentum_nms=(self._spin_inertia * state.wheel_rates_radps).tolist(),
            acs_mode=self.acs_mode,
            acs_target_quat_xyzw=self._acs.target.tolist(),
            acs_feedforward=self._acs.feedforward,
            buffer=self._schedule.state(),
        )
        self._next_frame_seq += 1
        return frame
