"""The vehicle flies a robot description (issue 12): ``hikoboshi spacecraft --robot FILE``.

Its model, servos, attitude-control law, wheel limits and sensor noise are the description's,
and ``hello`` names the robot, its description's hash and its joint count; without a
description the vehicle is ETS-VII as before and ``hello`` says nothing of the robot.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from planner.description import EXAMPLES_DIR, RobotDescription, load_robot
from planner.plan import Plan, Segment
from spacecraft.link import LinkConfig
from spacecraft.offline import fly_offline
from spacecraft.process import ProcessConfig, SpacecraftProcess
from spacecraft.vehicle import Vehicle
from spacecraft.vehicle_config import SensorNoise, VehicleConfig, VehicleError, vehicle_config_for
from telemetry.layout import FrameLayout
from telemetry.wire import CommandStage, Hello, JointCommandMsg, RejectReason, encode
from tests.server.storage.factories import still_prediction
from tests.spacecraft.ground_stub import TOKEN, GroundStub

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time

ORIHIME = EXAMPLES_DIR / "orihime" / "orihime.toml"
EPOCH = 1_700_000_000_000_000_000
SECOND = 1_000_000_000


@cache
def orihime() -> RobotDescription:
    return load_robot(ORIHIME)


def test_the_vehicle_of_a_description_is_that_robot() -> None:
    d = orihime()
    config = vehicle_config_for(d, telemetry_period_s=0.25)
    assert config.model is d.model and config.model.n_joints == 7
    assert (config.robot, config.robot_hash) == ("orihime", d.content_sha256)
    assert config.vehicle_name == "orihime" and config.telemetry_period_s == 0.25
    assert config.initial_joints_rad == (0.0,) * 7
    servo = d.servo_gains()
    assert config.sim.servo is not None and config.sim.gravity_gradient
    np.testing.assert_array_equal(config.sim.servo.kp_nm_per_rad, servo.kp_nm_per_rad)
    np.testing.assert_array_equal(config.sim.servo.kd_nms_per_rad, servo.kd_nms_per_rad)
    assert config.noise == SensorNoise(
        attitude_rad=d.sensor_noise.attitude_rad,
        rate_radps=d.sensor_noise.rate_radps,
        joint_rad=d.sensor_noise.joint_rad,
    )
    vehicle = Vehicle(config, epoch_ns=EPOCH, seed=1)
    law = d.acs_gains(vehicle._ws)
    np.testing.assert_allclose(vehicle.gains.kp_nm_per_rad, law.kp_nm_per_rad, rtol=1e-12)
    np.testing.assert_allclose(vehicle.gains.kd_nms_per_rad, law.kd_nms_per_rad, rtol=1e-12)
    # the wheels' limits (Orihime's 0.2 N m, 12 N m s, not ETS-VII's 0.3 and 20) bound the
    # law and the truth simulation's wheels
    assert (vehicle.gains.torque_limit_nm, vehicle.gains.momentum_limit_nms) == (0.2, 12.0)
    assert vehicle._truth.sim.config.wheel_torque_limit_nm == 0.2
    assert vehicle._truth.sim.config.wheel_momentum_limit_nms == 12.0
    # an --acs-config table replaces the description's keys, the rest stays
    tuned = vehicle_config_for(d, acs_overrides={"torque_limit_nm": 0.1})
    assert tuned.acs_gains is not None and tuned.acs_gains.torque_limit_nm == 0.1
    assert tuned.acs_gains.momentum_limit_nms == 12.0
    with pytest.raises(VehicleError, match="attitude control"):
        vehicle_config_for(d, acs_overrides={"no_such_key": 1.0})


def test_a_seven_joint_vehicle_executes_seven_joint_commands_and_refuses_six() -> None:
    vehicle = Vehicle(vehicle_config_for(orihime()), epoch_ns=EPOCH, seed=2)
    t0 = EPOCH + 2 * SECOND
    vehicle.advance_to(t0)
    target = [0.001 * (i + 1) for i in range(7)]
    six = vehicle.receive(JointCommandMsg(seq=0, execute_time_ns=t0 + SECOND, joints_rad=[0.0] * 6))
    assert six.stage is CommandStage.REJECTED and six.reason is RejectReason.MALFORMED
    assert six.detail == "joints_rad has 6 values, this robot has 7 joints"
    ok = vehicle.receive(JointCommandMsg(seq=1, execute_time_ns=t0 + SECOND, joints_rad=target))
    assert ok.stage is CommandStage.RECEIVED
    acks, frames = vehicle.advance_to(t0 + 3 * SECOND)
    assert [(a.seq, a.stage) for a in acks] == [(1, CommandStage.EXECUTED)]
    np.testing.assert_allclose(vehicle.joint_target_rad(), target)
    layout = FrameLayout(n_joints=7)
    assert frames
    for frame in frames:
        layout.check(frame)
        assert len(frame.joints_rad) == 7 and len(frame.joint_targets_rad) == 7


def test_a_robot_config_is_announced_whole_or_not_at_all() -> None:
    assert VehicleConfig().robot is None and VehicleConfig().robot_hash is None
    with pytest.raises(VehicleError, match="together"):
        VehicleConfig(robot="orihime")


def _plan(n_joints: int, n_commands: int = 40) -> Plan:
    """A slow ramp of every joint (0.5 deg/s) from the all-zero pose, free drift."""
    times = np.arange(n_commands) * 0.25
    joints = np.radians(0.5) * times[:, None] * np.ones(n_joints)
    prediction = still_prediction(float(times[-1]), n_joints, 3)
    return Plan(
        experiment="ptp",
        parameters={},
        initial_joints_rad=np.zeros(n_joints),
        command_times_s=times,
        command_joints_rad=joints,
        segments=(Segment("ramp", "ptp", 0.0, float(times[-1])),),
        prediction=prediction,
        metrics={},
    )


def test_a_seven_joint_plan_flies_offline_on_its_robot() -> None:
    plan = _plan(7)
    flight = fly_offline(plan, robot=orihime(), seed=4, after_s=1.0)
    assert flight.rejected == []
    executed = [a for a in flight.acks if a.stage is CommandStage.EXECUTED]
    assert len(executed) == 40
    last = flight.frames[-1]
    assert len(last.joints_rad) == 7
    # the arm followed the ramp (9.75 s at 0.5 deg/s, the servo lag a fraction of a degree)
    np.testing.assert_allclose(np.degrees(last.joints_rad), 4.875, atol=0.3)
    with pytest.raises(VehicleError, match="the plan is for 6 joints, the vehicle's robot has 7"):
        fly_offline(_plan(6), robot=orihime())
    with pytest.raises(VehicleError, match="the plan is for 7 joints, the vehicle's robot has 6"):
        fly_offline(plan)


def _hello(config: VehicleConfig) -> Hello:
    async def main() -> Hello:
        stub = GroundStub()
        await stub.start()
        process = SpacecraftProcess(
            ProcessConfig(
                ground_url=stub.url,
                token=TOKEN,
                time_scale=20.0,
                vehicle=config,
                uplink=LinkConfig(seed=1),
                downlink=LinkConfig(seed=2),
                drain_timeout_s=10.0,
            )
        )
        stop = asyncio.Event()
        task = asyncio.create_task(process.run(stop))
        try:
            await stub.wait_for(lambda: stub.hellos, timeout_s=20.0)
        finally:
            stop.set()
            await asyncio.wait_for(task, timeout=30.0)
            await stub.stop()
        return stub.hellos[0]

    return asyncio.run(main())


def test_hello_names_the_robot_its_hash_and_joint_count() -> None:
    d = orihime()
    hello = _hello(vehicle_config_for(d))
    assert (hello.vehicle, hello.robot, hello.robot_hash, hello.n_joints) == (
        "orihime",
        "orihime",
        d.content_sha256,
        7,
    )


def test_ets7_as_built_in_says_nothing_of_the_robot_in_hello() -> None:
    hello = _hello(VehicleConfig())
    assert (hello.vehicle, hello.robot, hello.robot_hash, hello.n_joints) == (
        "ETS-VII",
        None,
        None,
        None,
    )
    assert not {"robot", "robot_hash", "n_joints"} & set(json.loads(encode(hello)))


def _cli(*args: str) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [sys.executable, "-m", "hikoboshi", "spacecraft", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )


def test_the_cli_flies_the_robot_it_is_given() -> None:
    async def main() -> tuple[Hello, int, bytes]:
        stub = GroundStub()
        await stub.start()
        proc = _cli(
            "--ground", stub.url, "--token", TOKEN, "--time-scale", "20", "--robot", str(ORIHIME)
        )
        try:
            await stub.wait_for(lambda: stub.hellos and stub.frames, timeout_s=60.0)
        finally:
            proc.send_signal(signal.SIGTERM)
            _, err = await asyncio.to_thread(proc.communicate)
            await stub.stop()
        assert all(len(f.joints_rad) == 7 for f in stub.frames.values())
        return stub.hellos[0], proc.returncode or 0, err

    hello, code, err = asyncio.run(main())
    assert code == 0, err.decode()
    assert (hello.vehicle, hello.robot, hello.n_joints) == ("orihime", "orihime", 7)
    assert hello.robot_hash == orihime().content_sha256


def test_the_cli_refuses_a_bad_description_in_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\n')
    proc = _cli("--ground", "ws://127.0.0.1:9/api/link", "--token", "t", "--robot", str(bad))
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 2
    lines = err.decode().strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {bad}: "), lines
