"""Free-floating simulation core on MuJoCo, reused by the spacecraft's truth simulation and
by planners that optimise against the closed loop.

The simulator steps the model with joint servo targets (or joint torques), reaction-wheel
torques and an external base torque, optionally with the gravity-gradient torque of eq. (11),
and reports the state in the project's conventions (:mod:`planner.state`).

Time comes from the simulator's own step counter, never from a clock.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import mujoco
import numpy as np
from numpy.typing import NDArray

from planner.errors import InvalidInput
from planner.frames import matrix_from_quat_xyzw
from planner.gravity_gradient import Orbit, gravity_gradient_torque_base_nm
from planner.mjcf import MjcfOptions, ServoGains, compile_model
from planner.model import RobotModel
from planner.mujoco_conventions import MjLayout, read_state, write_state
from planner.state import State

__all__ = [
    "DEFAULT_SERVO_BANDWIDTH_RADPS",
    "DEFAULT_SERVO_LAG_S",
    "ETS7_SERVO_BANDWIDTH_RADPS",
    "ETS7_SERVO_LAG_S",
    "FreeFloatingSimulator",
    "SimConfig",
    "Trajectory",
    "default_servo_gains",
    "follow_commands",
    "per_joint",
]

Array = NDArray[np.float64]

#: Our choice (SPEC 6, paper Fig. 6): ETS-VII's servos, one bandwidth and a lag per joint.
#: ``kd / kp`` is the lag behind a ramp. A reactionless path lies in the reaction null space,
#: and a lag common to every joint only re-times it: it stays reactionless. The flight's
#: residual, growing with the hand's speed, needs joints that lag by different times, and
#: what the base feels is the difference among the three pitch joints (2, 3, 4), the arm's
#: plane. Experiment 2 bounds it from the other side: in the GJM legs the same joints move in
#: much the same proportions, and a lag difference among them turns the hand that the flight
#: held within 0.1 deg. A stiff shoulder (joint 2, 0.1 s) against a softer elbow (0.35 s) and
#: wrist (0.55 s) leaves the fast reactionless leg 0.007 deg and the slow one 0.003 deg
#: (noise-free; docs/spacecraft.md), holds the GJM hand within 0.085 deg (0.075 with one
#: lag), and the wrist pitch (joint 4), the joint that moves most in those legs, lags its
#: command most, as in Fig. 6: 0.86 deg RMS on the fast leg, 0.43 on the slow. More residual
#: costs more joint error, about 1 deg of the wrist's per 0.008 deg. Damping ratios
#: ``lag wn / 2``: 0.3 (shoulder), 0.9, 1.05 (elbow), 1.65 (wrist). The servos' fastest mode
#: (``M^-1 Kd``, docs/robots.md) stays at most 288 1/s at random poses, 137 1/s along the
#: demo pass (one 0.3 s lag: 344 and 138).
ETS7_SERVO_LAG_S = (0.3, 0.1, 0.35, 0.55, 0.3, 0.3)
ETS7_SERVO_BANDWIDTH_RADPS = (6.0, 6.0, 6.0, 6.0, 6.0, 6.0)
#: One lag and bandwidth for every joint of an arm that brings no gains of its own (0.3 s:
#: 0.3 deg at 1 deg/s, "a few tenths of a degree at the RNS speeds"; damping ratio 0.9).
DEFAULT_SERVO_BANDWIDTH_RADPS = 6.0
DEFAULT_SERVO_LAG_S = 0.3

#: A bandwidth or lag: one value for every joint, or one per joint.
PerJoint = float | Sequence[float] | Array


def per_joint(name: str, value: PerJoint, n_joints: int) -> Array:
    """``value`` as (n_joints,) floats: a single number repeated, or n numbers as given.
    Raises :class:`~planner.errors.InvalidInput` naming ``name`` for any other shape."""
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        return np.full(n_joints, float(arr))
    if arr.shape != (n_joints,):
        raise InvalidInput(
            f"{name} needs one number or {n_joints} (one per joint), got shape {arr.shape}"
        )
    return arr.copy()


def default_servo_gains(
    model: RobotModel,
    *,
    bandwidth_radps: PerJoint | None = None,
    lag_s: PerJoint | None = None,
) -> ServoGains:
    """PD gains ``kp = I wn^2`` and ``kd = lag kp`` per joint, ``I`` the joint's own inertia
    ``H_m[i, i]`` at the reference pose (all zeros unless the model names one).
    ``bandwidth_radps`` and ``lag_s``: one value for every joint or one per joint; ``None``:
    ETS-VII's per-joint values for a 6-joint arm (the built-in robot,
    :data:`ETS7_SERVO_LAG_S`), else :data:`DEFAULT_SERVO_LAG_S` and
    :data:`DEFAULT_SERVO_BANDWIDTH_RADPS` on every joint."""
    from planner.dynamics import DynamicsWorkspace

    n = model.n_joints
    ets7 = n == len(ETS7_SERVO_LAG_S)
    if bandwidth_radps is None:
        bandwidth_radps = ETS7_SERVO_BANDWIDTH_RADPS if ets7 else DEFAULT_SERVO_BANDWIDTH_RADPS
    if lag_s is None:
        lag_s = ETS7_SERVO_LAG_S if ets7 else DEFAULT_SERVO_LAG_S
    bandwidth = per_joint("servo bandwidth_radps", bandwidth_radps, n)
    lag = per_joint("servo lag_s", lag_s, n)
    if not (np.all(np.isfinite(bandwidth)) and np.all(bandwidth > 0.0)):
        raise InvalidInput(f"servo bandwidth_radps must be > 0 on every joint, got {bandwidth}")
    if not (np.all(np.isfinite(lag)) and np.all(lag >= 0.0)):
        raise InvalidInput(f"servo lag_s must be >= 0 on every joint, got {lag}")
    zeros = np.zeros(n)
    reference = model.reference_joints
    inertia = np.diag(
        DynamicsWorkspace(model).evaluate(State(reference, joint_rates_radps=zeros)).H_m
    )
    kp = inertia * bandwidth**2
    return ServoGains(kp_nm_per_rad=kp, kd_nms_per_rad=lag * kp)


@dataclass(frozen=True, eq=False)
class SimConfig:
    """How the truth model is stepped. ``servo=None`` means the default servo gains."""

    timestep_s: float = 0.01
    integrator: str = "RK4"
    servo: ServoGains | None = None
    servo_enabled: bool = True
    wheel_torque_limit_nm: float | None = None
    wheel_momentum_limit_nms: float | None = None
    gravity_gradient: bool = False
    #: the gravity-gradient torque is held constant over this interval (it changes with the
    #: slow attitude and arm motion only; 1e-4 N m scale).
    gravity_gradient_update_s: float = 0.5
    orbit: Orbit = field(default_factory=Orbit)


class FreeFloatingSimulator:
    """The free-floating satellite, arm and wheels, stepped by MuJoCo."""

    def __init__(self, model: RobotModel, initial: State, config: SimConfig | None = None):
        self.model = model
        self.config = cfg = config or SimConfig()
        servo = None
        if cfg.servo_enabled:
            servo = cfg.servo if cfg.servo is not None else default_servo_gains(model)
        self._mjm = compile_model(
            model,
            MjcfOptions(
                timestep_s=cfg.timestep_s,
                integrator=cfg.integrator,
                servo=servo,
                wheel_torque_limit_nm=cfg.wheel_torque_limit_nm,
            ),
        )
        self._mjd = mujoco.MjData(self._mjm)
        self._layout = MjLayout.of(self._mjm, model.n_joints, len(model.wheels))
        self._n = model.n_joints
        self._servo = servo is not None
        self._wheel_ctrl = slice(self._n, self._n + 3) if self._servo else slice(0, 3)
        self._spin_inertia = np.array([w.spin_inertia_kgm2 for w in model.wheels])
        self._steps = 0
        self._gg_torque_base_nm = np.zeros(3)
        self._gg_steps = max(1, round(cfg.gravity_gradient_update_s / cfg.timestep_s))
        self._steps_until_gg = 0
        write_state(self._mjd, self._layout, initial)
        if self._servo:
            self._mjd.act[: self._n] = initial.joints_rad
        mujoco.mj_forward(self._mjm, self._mjd)

    # -- read --------------------------------------------------------------------------

    @property
    def mj_model(self) -> mujoco.MjModel:
        """The compiled model, for baselines that step it directly (bench)."""
        return self._mjm

    @property
    def time_s(self) -> float:
        return self._steps * self.config.timestep_s

    @property
    def step_count(self) -> int:
        return self._steps

    @property
    def instability_warnings(self) -> int:
        """How many times MuJoCo found the state non-finite or huge and reset it ("the
        simulation is unstable": bad qacc, qvel or qpos) since the simulator was built."""
        w = self._mjd.warning
        return int(
            w[mujoco.mjtWarning.mjWARN_BADQACC].number
            + w[mujoco.mjtWarning.mjWARN_BADQVEL].number
            + w[mujoco.mjtWarning.mjWARN_BADQPOS].number
        )

    def state(self) -> State:
        return read_state(self._mjd, self._layout)

    def joint_target_rad(self) -> Array:
        """The servo's current position target (it saturates at the joint limits)."""
        if not self._servo:
            raise InvalidInput("this simulator has no joint servos")
        return np.array(self._mjd.act[: self._n])

    def wheel_momentum_nms(self) -> Array:
        """Rotor momentum relative to the base, ``I_w * rate``, base frame (N m s)."""
        return np.asarray(self._spin_inertia * self._mjd.qvel[self._layout.wheel_qvel])

    def gravity_gradient_torque_base_nm(self) -> Array:
        """The gravity-gradient torque being applied now (zero when it is switched off)."""
        return self._gg_torque_base_nm.copy()

    # -- command -----------------------------------------------------------------------

    def set_joint_target(self, target_rad: Array, rate_radps: Array | None = None) -> None:
        """Servo target now, moving at ``rate_radps`` until the next call (linear ramp).

        Targets beyond a joint limit saturate at the limit (onboard limit enforcement).
        """
        if not self._servo:
            raise InvalidInput("this simulator has no joint servos")
        target = np.asarray(target_rad, dtype=np.float64)
        rate = np.zeros(self._n) if rate_radps is None else np.asarray(rate_radps, float)
        if target.shape != (self._n,) or rate.shape != (self._n,):
            raise InvalidInput(f"joint target and rate need shape ({self._n},)")
        lo, hi = self.model.joint_limit_rad[:, 0], self.model.joint_limit_rad[:, 1]
        self._mjd.act[: self._n] = np.clip(target, lo, hi)
        self._mjd.ctrl[: self._n] = rate

    def apply_base_impulse(self, impulse_base_nms: Array) -> None:
        """An external angular impulse on the base now (N m s, base frame), as a bump gives:
        the velocities jump by ``M^-1 J_b^T`` of it (the response of the whole free-floating
        system to an impulsive torque on the base), so the system's angular momentum changes
        by exactly the impulse and its linear momentum not at all; positions, servo targets
        and the step count are unchanged."""
        impulse = np.asarray(impulse_base_nms, dtype=np.float64)
        if impulse.shape != (3,) or not np.all(np.isfinite(impulse)):
            raise InvalidInput(f"base impulse needs 3 finite numbers, got {impulse_base_nms!r}")
        m, d = self._mjm, self._mjd
        mujoco.mj_forward(m, d)  # the mass matrix and frames at the current state
        base = self._layout.base_body
        rot_orbit_from_base = d.xmat[base].reshape(3, 3)
        generalized = np.zeros(m.nv)
        mujoco.mj_applyFT(
            m,
            d,
            np.zeros(3),
            rot_orbit_from_base @ impulse,
            d.xipos[base].copy(),
            base,
            generalized,
        )
        dqvel = np.zeros(m.nv)
        mujoco.mj_solveM(m, d, dqvel.reshape(1, -1), generalized.reshape(1, -1))
        d.qvel[:] += dqvel
        mujoco.mj_forward(m, d)

    def _steps_for(self, duration_s: float) -> int:
        steps = round(duration_s / self.config.timestep_s)
        if steps < 0 or abs(steps * self.config.timestep_s - duration_s) > 1e-9:
            raise InvalidInput(
                f"duration {duration_s!r} s is not a whole number of "
                f"{self.config.timestep_s} s steps"
            )
        return steps

    def _update_gravity_gradient(self) -> None:
        d, m = self._mjd, self._mjm
        com = d.subtree_com[self._layout.base_body]
        rot_orbit_from_base = d.xmat[self._layout.base_body].reshape(3, 3)
        # H_c about the system CoM from each body's principal inertia and position.
        inertia = np.zeros((3, 3))
        for body in range(1, m.nbody):
            rot = d.ximat[body].reshape(3, 3)
            r = d.xipos[body] - com
            inertia += (rot * m.body_inertia[body]) @ rot.T
            inertia += m.body_mass[body] * (np.dot(r, r) * np.eye(3) - np.outer(r, r))
        inertia_base = rot_orbit_from_base.T @ inertia @ rot_orbit_from_base
        self._gg_torque_base_nm = gravity_gradient_torque_base_nm(
            inertia_base, rot_orbit_from_base, self.config.orbit
        )

    def advance(
        self,
        duration_s: float,
        *,
        wheel_torque_nm: Array | None = None,
        base_torque_orbit_nm: Array | None = None,
        joint_torque_nm: Array | None = None,
    ) -> None:
        """Step for ``duration_s`` (a whole number of steps) holding the given inputs.

        ``wheel_torque_nm``: motor torque on each rotor about its axis (the base feels the
        opposite), clipped to the torque limit, and zeroed on a wheel whose momentum is at
        its capacity and would grow further. ``base_torque_orbit_nm``: an external torque on
        the base, orbit frame. ``joint_torque_nm``: added to the servo torque (or the only
        joint torque without servos). The gravity-gradient torque, when on, is added too.
        """
        steps = self._steps_for(duration_s)
        d = self._mjd
        torque = np.zeros(3) if wheel_torque_nm is None else np.asarray(wheel_torque_nm, float)
        limit = self.config.wheel_momentum_limit_nms
        if limit is not None:
            momentum = self.wheel_momentum_nms()
            torque = np.where((np.abs(momentum) >= limit) & (torque * momentum > 0), 0.0, torque)
        d.ctrl[self._wheel_ctrl] = torque
        external = (
            np.zeros(3) if base_torque_orbit_nm is None else np.asarray(base_torque_orbit_nm, float)
        )
        d.qfrc_applied[self._layout.joint_qvel] = (
            0.0 if joint_torque_nm is None else np.asarray(joint_torque_nm, float)
        )
        base = self._layout.base_body
        while steps > 0:
            chunk = steps
            if self.config.gravity_gradient:
                if self._steps_until_gg == 0:
                    self._update_gravity_gradient()
                    self._steps_until_gg = self._gg_steps
                chunk = min(steps, self._steps_until_gg)
                self._steps_until_gg -= chunk
                rot = d.xmat[base].reshape(3, 3)
                d.xfrc_applied[base, 3:6] = external + rot @ self._gg_torque_base_nm
            else:
                d.xfrc_applied[base, 3:6] = external
            mujoco.mj_step(self._mjm, d, nstep=chunk)
            steps -= chunk
            self._steps += chunk


@dataclass(frozen=True, eq=False)
class Trajectory:
    """Sampled simulator output; row k is time ``t_s[k]``."""

    t_s: Array
    joints_rad: Array
    joint_targets_rad: Array
    quat_orbit_from_base_xyzw: Array
    omega_base_orbit_radps: Array
    wheel_momentum_nms: Array


#: A controller for the wheels: called every control period with the time and the state,
#: returns the wheel motor torques (N m).
WheelController = Callable[[float, State], Array]


def follow_commands(
    sim: FreeFloatingSimulator,
    command_times_s: Array,
    command_joints_rad: Array,
    *,
    end_time_s: float,
    sample_period_s: float = 0.1,
    wheel_controller: WheelController | None = None,
    on_sample: Callable[[float], None] | None = None,
) -> Trajectory:
    """Execute time-tagged joint commands as the spacecraft does and sample the result.

    Between consecutive commands the servo target moves linearly (SPEC section 6); after
    the last one it holds. ``command_times_s`` must be increasing and not before
    ``sim.time_s``. The wheel controller, if any, runs once per sample period;
    ``on_sample(t_s)`` is called after each sample (for progress display).
    """
    times = np.asarray(command_times_s, dtype=np.float64)
    targets = np.asarray(command_joints_rad, dtype=np.float64)
    if times.ndim != 1 or targets.shape != (times.size, sim.model.n_joints):
        raise InvalidInput("command times (k,) and joints (k, n) do not match")
    if times.size and (np.any(np.diff(times) <= 0) or times[0] < sim.time_s - 1e-9):
        raise InvalidInput("command times must increase and not lie in the past")
    dt = sim.config.timestep_s
    # Event steps: every command, every sample, the end.
    sample_steps = np.arange(
        round(sim.time_s / dt), round(end_time_s / dt) + 1, round(sample_period_s / dt)
    )
    command_steps = np.round(times / dt).astype(np.int64)
    events = np.union1d(sample_steps, command_steps[command_steps <= sample_steps[-1]])
    n_samples = sample_steps.size
    nq, nv = sim._mjm.nq, sim._mjm.nv
    qpos = np.zeros((n_samples, nq))
    qvel = np.zeros((n_samples, nv))
    act = np.zeros((n_samples, sim.model.n_joints))
    k_cmd = 0
    k_sample = 0
    wheel_torque = np.zeros(3)
    d = sim._mjd
    for step in events:
        if step > sim.step_count:
            sim.advance((step - sim.step_count) * dt, wheel_torque_nm=wheel_torque)
        while k_cmd < times.size and command_steps[k_cmd] <= step:
            if k_cmd + 1 < times.size:
                rate = (targets[k_cmd + 1] - targets[k_cmd]) / (times[k_cmd + 1] - times[k_cmd])
            else:
                rate = np.zeros(sim.model.n_joints)
            sim.set_joint_target(targets[k_cmd], rate)
            k_cmd += 1
        if k_sample < n_samples and sample_steps[k_sample] == step:
            qpos[k_sample] = d.qpos
            qvel[k_sample] = d.qvel
            act[k_sample] = d.act[: sim.model.n_joints]
            if wheel_controller is not None:
                wheel_torque = np.asarray(wheel_controller(step * dt, sim.state()), float)
            k_sample += 1
            if on_sample is not None:
                on_sample(step * dt)
    layout = sim._layout
    quat_xyzw = qpos[:, [4, 5, 6, 3]]
    omega = np.einsum(
        "kij,kj->ki", np.array([matrix_from_quat_xyzw(q) for q in quat_xyzw]), qvel[:, 3:6]
    )
    return Trajectory(
        t_s=sample_steps.astype(np.float64) * dt,
        joints_rad=qpos[:, layout.joint_qpos],
        joint_targets_rad=act,
        quat_orbit_from_base_xyzw=quat_xyzw,
        omega_base_orbit_radps=omega,
        wheel_momentum_nms=qvel[:, layout.wheel_qvel] * sim._spin_inertia,
    )
