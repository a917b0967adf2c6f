"""The wire takes any joint count; the vehicle refuses a joint command for another robot."""

from __future__ import annotations

import numpy as np

from spacecraft.vehicle import Vehicle
from spacecraft.vehicle_config import VehicleConfig
from telemetry.layout import DEFAULT_LAYOUT
from telemetry.wire import CommandStage, JointCommandMsg, RejectReason

EPOCH = 1_700_000_000_000_000_000
SECOND = 1_000_000_000
T0 = EPOCH + 2 * SECOND


def test_a_seven_joint_command_to_ets7_is_rejected_malformed_and_never_executed() -> None:
    v = Vehicle(VehicleConfig(), epoch_ns=EPOCH, seed=3)
    v.advance_to(T0)
    ack = v.receive(JointCommandMsg(seq=0, execute_time_ns=T0 + SECOND, joints_rad=[0.1] * 7))
    assert ack.stage is CommandStage.REJECTED and ack.reason is RejectReason.MALFORMED
    assert ack.detail == "joints_rad has 7 values, this robot has 6 joints"
    ok = v.receive(JointCommandMsg(seq=1, execute_time_ns=T0 + SECOND, joints_rad=[0.0] * 6))
    assert ok.stage is CommandStage.RECEIVED
    acks, frames = v.advance_to(T0 + 3 * SECOND)
    assert [a.seq for a in acks] == [1]
    np.testing.assert_array_equal(v.joint_target_rad(), np.zeros(6))
    # its frames are ETS-VII's layout
    for frame in frames:
        DEFAULT_LAYOUT.check(frame)
