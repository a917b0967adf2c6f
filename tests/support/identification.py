"""A pass in free drift through the real vehicle: what the inertia identification and the
re-simulation are tested on."""

from __future__ import annotations

import numpy as np

from planner.attitude_control import AcsMode
from planner.model import RobotModel
from planner.plan import AcsCommand, Plan, Prediction, Segment
from planner.ptp import COMMAND_PERIOD_S, ptp_commands
from spacecraft._sensors import SensorNoise
from spacecraft.offline import fly_offline
from spacecraft.vehicle_config import VehicleConfig
from telemetry.recording import PassRecording

#: Two PTP moves and back, every joint moving (joint 1 excites yaw), in free drift.
WAYPOINTS_DEG = ((30.0, 20.0, -30.0, 20.0, 30.0, 20.0), (-20.0, 40.0, -60.0, -10.0, -20.0, 40.0))


def free_drift_plan(model: RobotModel, hold_s: float = 10.0) -> Plan:
    """PTP moves through WAYPOINTS_DEG and back to zero, ``hold_s`` after each, in free
    drift from t = 0 (127.5 s). No prediction: the vehicle does not need one."""
    times, joints = [np.zeros(1)], [np.zeros((1, model.n_joints))]
    q, t = np.zeros(model.n_joints), 0.0
    for waypoint in (*WAYPOINTS_DEG, (0.0,) * model.n_joints):
        goal = np.radians(waypoint)
        move_t, move_q = ptp_commands(model, q, goal)
        times.append(t + move_t[1:])
        joints.append(move_q[1:])
        t, q = t + float(move_t[-1]), goal
        n_hold = round(hold_s / COMMAND_PERIOD_S)
        times.append(t + COMMAND_PERIOD_S * np.arange(1, n_hold + 1))
        joints.append(np.tile(q, (n_hold, 1)))
        t += hold_s
    all_t = np.concatenate(times)
    none3, none4 = np.zeros((0, 3)), np.zeros((0, 4))
    prediction = Prediction(
        np.zeros(0), np.zeros((0, 6)), none4, none3, none3, none3, none4, none3, none3
    )
    return Plan(
        experiment="identification test",
        parameters={},
        initial_joints_rad=np.zeros(model.n_joints),
        command_times_s=all_t,
        command_joints_rad=np.concatenate(joints),
        segments=(Segment("moves", "ptp", 0.0, float(all_t[-1])),),
        prediction=prediction,
        metrics={},
        acs_commands=(AcsCommand(0.0, AcsMode.FREE_DRIFT),),
    )


def fly(model: RobotModel, noise_scale: float, seed: int = 3) -> PassRecording:
    """The free-drift plan through the real vehicle with the default sensor noise scaled.
    In free drift the noise does not feed back, so every scale flies the same truth, and
    with one seed the noise samples are the same numbers scaled."""
    plan = free_drift_plan(model)
    base = SensorNoise()
    noise = SensorNoise(
        attitude_rad=base.attitude_rad * noise_scale,
        rate_radps=base.rate_radps * noise_scale,
        joint_rad=base.joint_rad * noise_scale,
    )
    flight = fly_offline(plan, VehicleConfig(model=model, noise=noise), seed=seed)
    assert not flight.rejected, flight.rejected[:3]
    return PassRecording.from_frames(
        f"noise x{noise_scale:g}", plan, flight.epoch_ns, flight.frames
    )
