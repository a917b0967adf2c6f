"""What a plan predicts: the states under ideal joint tracking, at every command time.

The joints follow the commands exactly (linear between consecutive 4 Hz commands, as on
board). The base and wheels obey angular-momentum balance about the system CoM (eq. 3):

    R^T L = H~_b w_b + H~_bm phi' + h_w        (base frame)
    dL/dt = R N_gg                             (orbit frame; 0 without gravity gradient)
    dh_w/dt = wheel torque from the attitude-control law (planner.attitude_control)

so ``w_b = H~_b^-1 (R^T L - H~_bm phi' - h_w)``; with no control and zero momentum this is
eq. (9) and its integral eq. (10). The attitude quaternion, the wheel momentum and L are
integrated with RK4, ``sub_steps`` per command interval. The base translates so that the
system centre of mass stays put (eq. 2 at zero linear momentum); positions are orbit-frame
coordinates with the origin at the initial base CoM. (The rotors' own share of the base's
angular acceleration, ``I_w a . w_b'``, is left out of dh_w/dt: 0.15 kg m^2 against thousands.)

The attitude-control law runs in continuous time (:func:`planner.attitude_law.law_rates`):
its integral and rate-estimate states are appended to the ODE and restart, as on board
(:class:`planner.attitude_law.AttitudeController`), at the first command time at which
the mode becomes ``feedback``; a change of target restarts the integral only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from planner.attitude_control import AcsGains, AcsMode, attitude_error_rad
from planner.attitude_law import law_rates, wheel_torque_nm
from planner.dynamics import DynamicsWorkspace, solve_small
from planner.errors import InvalidInput
from planner.frames import (
    IDENTITY_QUAT_XYZW,
    matrix_from_quat_xyzw,
    quat_xyzw_from_matrix,
    rpy_from_matrix,
)
from planner.free_drift import quat_multiply_xyzw
from planner.gravity_gradient import Orbit, gravity_gradient_torque_base_nm
from planner.plan import AcsCommand, Prediction
from planner.state import State

__all__ = ["predict"]

Array = NDArray[np.float64]


@dataclass
class _Acs:
    mode: AcsMode
    target: Array
    feedforward: bool


def _acs_at(commands: Sequence[AcsCommand], t_s: float, default: _Acs) -> _Acs:
    current = default
    for c in commands:
        if c.t_s <= t_s + 1e-9:
            current = _Acs(c.mode, c.target_quat_orbit_from_base_xyzw, c.feedforward)
    return current


def predict(
    ws: DynamicsWorkspace,
    command_times_s: Array,
    command_joints_rad: Array,
    *,
    acs_commands: Sequence[AcsCommand] = (),
    acs_gains: AcsGains | None = None,
    initial_quat_orbit_from_base_xyzw: Array | None = None,
    initial_wheel_momentum_nms: Array | None = None,
    initial_omega_base_orbit_radps: Array | None = None,
    orbit: Orbit | None = None,
    sub_steps: int = 2,
) -> Prediction:
    """Predicted states at each command time (see the module docstring).

    ``acs_commands`` switch the attitude-control mode and target at their times (free drift
    before the first); ``acs_gains`` is needed when any command is ``feedback`` (feedforward
    acts through the feedback loop). ``orbit`` switches the gravity-gradient torque on.
    The base starts at ``initial_quat_orbit_from_base_xyzw`` turning at
    ``initial_omega_base_orbit_radps`` (orbit frame; default the orbit frame, at rest), the
    wheels holding ``initial_wheel_momentum_nms`` (base frame; default none), the arm at rest.
    """
    times = np.asarray(command_times_s, dtype=np.float64)
    joints = np.asarray(command_joints_rad, dtype=np.float64)
    n = ws.model.n_joints
    if times.ndim != 1 or times.size < 1 or joints.shape != (times.size, n):
        raise InvalidInput("command times (k,) and joints (k, n) do not match")
    if np.any(np.diff(times) <= 0.0):
        raise InvalidInput("command times must increase")
    needs_gains = any(c.mode is AcsMode.FEEDBACK for c in acs_commands)
    if needs_gains and acs_gains is None:
        raise InvalidInput("attitude-control commands need acs_gains")
    ordered = sorted(acs_commands, key=lambda c: c.t_s)
    free = _Acs(AcsMode.FREE_DRIFT, IDENTITY_QUAT_XYZW, False)

    quat = (
        IDENTITY_QUAT_XYZW.copy()
        if initial_quat_orbit_from_base_xyzw is None
        else np.asarray(initial_quat_orbit_from_base_xyzw, dtype=np.float64)
    )
    h_w = (
        np.zeros(3)
        if initial_wheel_momentum_nms is None
        else np.array(initial_wheel_momentum_nms, dtype=np.float64)
    )
    # Total angular momentum (orbit frame) of a system starting with the arm at rest: the
    # base's turning (eq. 3, H~_b w_b) and the wheels'.
    rot0 = matrix_from_quat_xyzw(quat)
    base_momentum = np.zeros(3)
    if initial_omega_base_orbit_radps is not None:
        omega0 = np.asarray(initial_omega_base_orbit_radps, dtype=np.float64)
        if omega0.shape != (3,) or not np.all(np.isfinite(omega0)):
            raise InvalidInput(f"initial base rate must be a finite 3-vector, got {omega0}")
        base_momentum = ws.momentum_blocks(joints[0])[0] @ (rot0.T @ omega0)
    momentum = rot0 @ (base_momentum + h_w)

    cache: dict[str, tuple[Array, Array, Array]] = {}

    def blocks(phi: Array) -> tuple[Array, Array]:
        # Holds evaluate the same pose many times over.
        last = cache.get("last")  # np.array_equal's test, without its wrapper
        if last is None or last[0].shape != phi.shape or not (last[0] == phi).all():
            h_b, h_bm = ws.momentum_blocks(phi)
            cache["last"] = (phi.copy(), h_b, h_bm)
            return h_b, h_bm
        return last[1], last[2]

    def rates(
        phi: Array, rate: Array, quat_now: Array, h_now: Array, l_now: Array
    ) -> tuple[Array, Array, Array, Array]:
        h_b, h_bm = blocks(phi)
        rot = matrix_from_quat_xyzw(quat_now)
        reaction = h_bm @ rate
        omega: Array = solve_small(h_b, rot.T @ l_now - reaction - h_now)
        return omega, rot, h_b, reaction

    stateful = acs_gains is not None and acs_gains.stateful

    def feedforward_rate(h_b: Array, reaction: Array, acs: _Acs) -> Array | None:
        # eq. (9) of the commanded motion: the same as reaction_rate_radps()
        if not acs.feedforward:
            return None
        return -solve_small(h_b, reaction)

    def derivative(phi: Array, rate: Array, y: Array, acs: _Acs) -> Array:
        # y[:4] / np.linalg.norm(y[:4]): the norm's own arithmetic, without its wrapper
        quat_now, h_now, l_now = y[:4] / math.sqrt(y[:4].dot(y[:4])), y[4:7], y[7:10]
        omega, rot, h_b, reaction = rates(phi, rate, quat_now, h_now, l_now)
        dquat = 0.5 * quat_multiply_xyzw(quat_now, (*omega.tolist(), 0.0))
        torque = np.zeros(3)
        d_law: Array | None = np.zeros(6) if stateful else None
        if acs.mode is AcsMode.FEEDBACK:
            assert acs_gains is not None
            error = attitude_error_rad(quat_now, acs.target)
            ff = feedforward_rate(h_b, reaction, acs)
            if stateful:
                torque, d_int, d_rate = law_rates(
                    acs_gains,
                    attitude_error=error,
                    rate_error=omega if ff is None else omega + ff,
                    integral=y[10:13],
                    rate_estimate=y[13:16],
                )
                d_law = np.concatenate([d_int, d_rate])
            else:
                torque = wheel_torque_nm(
                    acs_gains,
                    acs.mode,
                    attitude_error=error,
                    omega_base_radps=omega,
                    reaction_rate_radps=ff,
                )
            # A wheel at capacity takes no more torque in the same sense.
            full = (np.abs(h_now) >= acs_gains.momentum_limit_nms) & (torque * h_now > 0)
            torque = np.where(full, 0.0, torque)
        dl = np.zeros(3)
        if orbit is not None:
            dl = rot @ gravity_gradient_torque_base_nm(h_b, rot, orbit)  # H~_b is H_c
        if d_law is None:
            return np.concatenate([dquat, torque, dl])
        return np.concatenate([dquat, torque, dl, d_law])

    # State: attitude, wheel momentum, total momentum (and the law's integral and rate
    # estimate if it has them).
    y = np.concatenate([quat, h_w, momentum, np.zeros(6 if stateful else 0)])
    states = [y.copy()]
    omegas = []
    reactions = []
    previous: _Acs = free
    for k in range(times.size):
        # Rates at command k: the interval that starts there (the last holds still).
        rate = (
            (joints[k + 1] - joints[k]) / (times[k + 1] - times[k])
            if k + 1 < times.size
            else np.zeros(n)
        )
        omega, rot, h_b, reaction = rates(joints[k], rate, y[:4], y[4:7], y[7:10])
        omegas.append(rot @ omega)
        reactions.append(rot @ reaction)
        if k + 1 == times.size:
            break
        acs = _acs_at(ordered, float(times[k]), free)
        if stateful and acs.mode is AcsMode.FEEDBACK:
            if previous.mode is not AcsMode.FEEDBACK:
                # The law starts: integral 0, rate estimate the rate error now.
                ff = feedforward_rate(h_b, reaction, acs)
                y[10:13] = 0.0
                y[13:16] = omega if ff is None else omega + ff
            elif not np.array_equal(previous.target, acs.target):
                y[10:13] = 0.0  # a new target restarts the integral; the estimate carries on
        previous = acs
        dt = (times[k + 1] - times[k]) / sub_steps
        for j in range(sub_steps):
            tau = j * dt
            phi0 = joints[k] + rate * tau
            phi_mid = phi0 + 0.5 * dt * rate
            phi1 = phi0 + dt * rate
            k1 = derivative(phi0, rate, y, acs)
            k2 = derivative(phi_mid, rate, y + 0.5 * dt * k1, acs)
            k3 = derivative(phi_mid, rate, y + 0.5 * dt * k2, acs)
            k4 = derivative(phi1, rate, y + dt * k3, acs)
            y = y + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            y[:4] /= np.linalg.norm(y[:4])
        states.append(y.copy())
    ys = np.array(states)
    quats = np.array([q if q[3] >= 0 else -q for q in ys[:, :4]])
    hand_pos = np.zeros((times.size, 3))
    hand_quat = np.zeros((times.size, 4))
    rpy = np.zeros((times.size, 3))
    # Eq. (2) with zero linear momentum: the system CoM stays where it starts, and the base
    # moves under it as the arm moves.
    com0 = ws.com_orbit_m(State(joints_rad=joints[0], quat_orbit_from_base_xyzw=quats[0]))
    for k in range(times.size):
        offset = ws.com_orbit_m(State(joints_rad=joints[k], quat_orbit_from_base_xyzw=quats[k]))
        hand = ws.hand_pose(
            State(
                joints_rad=joints[k],
                quat_orbit_from_base_xyzw=quats[k],
                pos_base_orbit_m=com0 - offset,
            )
        )
        hand_pos[k] = hand.pos_orbit_m
        hand_quat[k] = quat_xyzw_from_matrix(hand.rot_orbit_from_hand)
        rpy[k] = rpy_from_matrix(matrix_from_quat_xyzw(quats[k]))
    return Prediction(
        t_s=times.copy(),
        joints_rad=joints.copy(),
        quat_orbit_from_base_xyzw=quats,
        rpy_base_rad=rpy,
        omega_base_orbit_radps=np.array(omegas),
        hand_pos_orbit_m=hand_pos,
        quat_orbit_from_hand_xyzw=hand_quat,
        reaction_momentum_orbit_nms=np.array(reactions),
        wheel_momentum_nms=ys[:, 4:7],
    )
