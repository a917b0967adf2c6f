"""Fault injection's grammar (spacecraft.faults): what ``--fault`` takes, what it refuses and
how it says so, on the vehicle's configuration and on the command line."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from planner.model import default_model
from spacecraft.faults import Fault, FaultSpecError, check_faults, parse_fault
from spacecraft.vehicle import Vehicle
from spacecraft.vehicle_config import VehicleConfig, VehicleError


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("joint3-stuck@120", Fault("joint-stuck", 120.0, index=3)),
        ("joint1-drift@5", Fault("joint-drift", 5.0, index=1, rate_degps=0.5)),
        ("joint6-drift@5.5,rate_degps=-2", Fault("joint-drift", 5.5, index=6, rate_degps=-2.0)),
        ("joint2-offset@5", Fault("joint-offset", 5.0, index=2, deg=1.0)),
        (
            "joint2-offset@cmd+4,deg=-1.5",
            Fault("joint-offset", 4.0, index=2, deg=-1.5, after_first_command=True),
        ),
        ("wheel2-fail@0", Fault("wheel-fail", 0.0, index=2)),
        ("attitude-bias@10", Fault("attitude-bias", 10.0, deg=3.0, axis="x")),
        ("attitude-bias@10,axis=z,deg=4", Fault("attitude-bias", 10.0, deg=4.0, axis="z")),
        ("bump@7", Fault("bump", 7.0, nms=10.0, axis="x")),
        (" bump@7, nms=30 , axis=y ", Fault("bump", 7.0, nms=30.0, axis="y")),
        ("joint3-stuck@cmd+20", Fault("joint-stuck", 20.0, index=3, after_first_command=True)),
        ("bump@cmd+0,nms=5", Fault("bump", 0.0, nms=5.0, axis="x", after_first_command=True)),
    ],
)
def test_a_fault_is_read_with_its_defaults(text: str, expected: Fault) -> None:
    fault = parse_fault(text)
    assert fault == expected
    assert parse_fault(fault.spec) == fault  # the spec written back reads the same


def test_the_spec_names_every_parameter() -> None:
    assert parse_fault("joint3-drift@12").spec == "joint3-drift@12,rate_degps=0.5"
    assert parse_fault("bump@1,axis=z").spec == "bump@1,nms=10,axis=z"
    assert parse_fault("wheel1-fail@2").name == "wheel1-fail"
    assert parse_fault("joint3-stuck@cmd+20.5").spec == "joint3-stuck@cmd+20.5"
    assert parse_fault("joint4-offset@3").spec == "joint4-offset@3,deg=1"


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("joint3-stuck", "needs NAME@T"),
        ("joint3-stuk@1", "unknown fault 'joint3-stuk'; known: jointN-stuck, jointN-drift"),
        ("wheel2-stuck@1", "a wheel can be fail, not 'stuck'"),
        ("joint2-fail@1", "a joint can be stuck or drift or offset, not 'fail'"),
        ("joint2-offset@1,deg=0", "deg = 0 is no fault"),
        ("joint2-offset@1,rate_degps=1", "joint-offset takes deg; not 'rate_degps'"),
        ("joint0-stuck@1", "joints are numbered from 1"),
        ("bump@soon", "T = 'soon' is not a number"),
        ("bump@-1", "T = -1 s must lie in [0,"),
        ("bump@cmd+-1", "T = -1 s must lie in [0, 3.15576e+07] (onboard seconds from the first"),
        ("bump@cmd+soon", "T = 'soon' is not a number"),
        ("bump@start+5", "T = 'start+5' is not a number"),
        ("bump@inf", "T = 'inf' is not finite"),
        ("bump@5,deg=3", "bump takes nms, axis; not 'deg'"),
        ("joint1-stuck@5,rate_degps=1", "joint-stuck takes no parameter; not 'rate_degps'"),
        ("bump@5,nms", "'nms' is not key=value"),
        ("bump@5,axis=w", "axis must be x, y or z, got 'w'"),
        ("bump@5,nms=0", "nms = 0 is no fault"),
        ("attitude-bias@5,deg=200", "deg = 200 must lie within +-180"),
    ],
)
def test_a_bad_fault_is_refused_naming_the_problem(text: str, reason: str) -> None:
    with pytest.raises(FaultSpecError) as info:
        parse_fault(text)
    assert reason in str(info.value)
    assert repr(text) in str(info.value)  # the message quotes what was given


def test_a_fault_on_a_joint_or_wheel_the_robot_lacks_is_refused() -> None:
    check_faults(
        [parse_fault("joint6-stuck@1"), parse_fault("wheel3-fail@1")], n_joints=6, n_wheels=3
    )
    with pytest.raises(
        FaultSpecError, match=r"the robot has 6 joints \(joint1 to joint6\), no joint9"
    ):
        check_faults([parse_fault("joint9-stuck@10")], n_joints=6, n_wheels=3)
    with pytest.raises(
        FaultSpecError, match=r"the robot has 3 wheels \(wheel1 to wheel3\), no wheel4"
    ):
        check_faults([parse_fault("wheel4-fail@10")], n_joints=6, n_wheels=3)
    # the vehicle's configuration checks them against its model
    with pytest.raises(VehicleError, match="no joint7"):
        VehicleConfig(faults=(parse_fault("joint7-drift@3"),))
    assert VehicleConfig(model=default_model(), faults=(parse_fault("joint6-drift@3"),)).faults


def test_the_command_line_refuses_a_bad_fault_in_one_line() -> None:
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "hikoboshi",
            "spacecraft",
            "--ground",
            "ws://127.0.0.1:9/link",
            "--token",
            "t",
            "--fault",
            "bump@3",
            "--fault",
            "joint9-stuck@10",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert (
        "fault 'joint9-stuck@10': the robot has 6 joints (joint1 to joint6), no joint9"
        in (lines[0])
    )


def test_an_offset_steps_the_joint_away_from_the_target_telemetry_shows() -> None:
    """joint2 offset by 1.5 deg at 2 s, then a drift of 0.1 deg/s on it at 6 s: the
    software's target (telemetry's) stays 0, the measured joint steps to the offset and
    settles there, then the drift adds to it; the truth log has both onsets."""
    faults = (parse_fault("joint2-offset@2,deg=1.5"), parse_fault("joint2-drift@6,rate_degps=0.1"))
    vehicle = Vehicle(VehicleConfig(faults=faults), epoch_ns=0, seed=5)
    _, frames = vehicle.advance_to(10 * 10**9)
    t_s = np.array([f.generation_time_ns / 1e9 for f in frames])
    joint2 = np.degrees([f.joints_rad[1] for f in frames])
    assert all(f.joint_targets_rad == [0.0] * 6 for f in frames)
    before = joint2[t_s < 2.0]
    assert np.all(np.abs(before) < 0.03)  # the encoder's noise (0.005 deg, 1 sigma) alone
    settled = joint2[(t_s >= 4.0) & (t_s < 6.0)]
    assert float(np.mean(settled)) == pytest.approx(1.5, abs=0.01)
    # the step is a step: the joint is near it within the servo's settling (lag 0.1 s)
    assert float(joint2[np.searchsorted(t_s, 3.0)]) == pytest.approx(1.5, abs=0.05)
    drifting = (t_s >= 7.0) & (t_s <= 10.0)
    slope, _ = np.polyfit(t_s[drifting], joint2[drifting], 1)
    assert slope == pytest.approx(0.1, abs=0.01)
    events = [e for e in vehicle.take_truth_events() if e["event"] == "fault"]
    assert [(e["fault"], e["onboard_s"]) for e in events] == [
        ("joint2-offset", 2.0),
        ("joint2-drift", 6.0),
    ]
    assert events[0]["deg"] == 1.5 and events[0]["joint"] == 2
    assert math.isclose(vehicle.joint_target_rad()[1], 0.0)
