"""The wire protocol: golden JSON, and refusal of everything that is not a message."""

from __future__ import annotations

import json

import pytest

from telemetry.wire import (
    MAX_MESSAGE_BYTES,
    AcsCommandMsg,
    AcsModeName,
    BufferState,
    CommandAck,
    CommandQuery,
    CommandStage,
    JointCommandMsg,
    RejectReason,
    ScheduleDelete,
    TelemetryAck,
    TelemetryFrame,
    TelemetryMsg,
    Verification,
    WireError,
    decode_ground,
    decode_spacecraft,
    encode,
)

GOLDEN_JOINT_COMMAND = (
    '{"v":2,"type":"command","kind":"joints","seq":7,"execute_time_ns":1000250000000,'
    '"joints_rad":[0.1,-0.2,0.3,0.0,0.5,-0.6]}'
)


def _frame(seq: int) -> TelemetryFrame:
    return TelemetryFrame(
        seq=seq,
        generation_time_ns=10**12 + seq * 10**8,
        joints_rad=[0.0] * 6,
        joint_targets_rad=[0.0] * 6,
        quat_orbit_from_base_xyzw=[0.0, 0.0, 0.0, 1.0],
        omega_base_in_base_radps=[0.0, 1e-5, 0.0],
        wheel_speeds_radps=[1.0, 2.0, 3.0],
        wheel_momentum_nms=[0.15, 0.3, 0.45],
        acs_mode=AcsModeName.FEEDBACK,
        acs_target_quat_xyzw=[0.0, 0.0, 0.0, 1.0],
        acs_feedforward=False,
        buffer=BufferState(queued=3, next_execute_time_ns=10**12, last_executed_seq=6),
    )


def test_golden_joint_command() -> None:
    msg = JointCommandMsg(
        seq=7, execute_time_ns=1_000_250_000_000, joints_rad=[0.1, -0.2, 0.3, 0.0, 0.5, -0.6]
    )
    assert encode(msg) == GOLDEN_JOINT_COMMAND
    assert decode_ground(GOLDEN_JOINT_COMMAND) == msg


def test_round_trips_of_every_message() -> None:
    for msg in (
        AcsCommandMsg(seq=1, execute_time_ns=5, mode=AcsModeName.FREE_DRIFT, feedforward=True),
        TelemetryAck(through_seq=10, ranges=[(12, 15)]),
        ScheduleDelete(request_id=4, from_time_ns=10**12, max_seq=99),
        CommandQuery(seqs=[3, 4]),
    ):
        assert decode_ground(encode(msg)) == msg
    for sc in (
        TelemetryMsg(frames=[_frame(0), _frame(1)]),
        CommandAck(seq=3, stage=CommandStage.REJECTED, reason=RejectReason.LATE, onboard_time_ns=9),
        CommandAck(
            seq=4, stage=CommandStage.REJECTED, reason=RejectReason.SCHEDULE_FULL, onboard_time_ns=9
        ),
        Verification(
            request_id=4,
            stage="completed",
            deleted=3,
            deleted_ranges=[(5, 7)],
            executed_after_from=1,
            onboard_time_ns=10**12,
        ),
    ):
        assert decode_spacecraft(encode(sc)) == sc


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("{", "not JSON"),
        ("[1, 2]", "must be a JSON object"),
        ('{"v": 1, "type": "ping"}', "protocol version 1 is not served: this end speaks 2"),
        ('{"v": 3, "type": "ping"}', "protocol version 3 is not served"),
        ('{"v": 2}', "string 'type'"),
        ('{"v": 2, "type": "self_destruct"}', "unknown message type"),
        (GOLDEN_JOINT_COMMAND.replace('"seq":7', '"seq":-7'), "seq"),
        (GOLDEN_JOINT_COMMAND.replace("0.5", '"x"'), "joints_rad"),
        (GOLDEN_JOINT_COMMAND.replace("0.5", "NaN"), "finite"),
        (GOLDEN_JOINT_COMMAND.replace("-0.6]", "-0.6, 1.0]"), "joints_rad"),
        (GOLDEN_JOINT_COMMAND.replace('"seq":7', '"seq":7,"extra":1'), "extra"),
        ('{"v":2,"type":"retransmit","ranges":[]}', "ranges"),
        ('{"v":2,"type":"schedule_delete","request_id":1,"from_time_ns":-1,"max_seq":3}', "time"),
    ],
)
def test_bad_messages_are_refused_with_a_reason(text: str, reason: str) -> None:
    with pytest.raises(WireError) as info:
        decode_ground(text)
    assert reason.lower() in str(info.value).lower()


def test_huge_messages_are_refused_unread() -> None:
    huge = json.dumps({"v": 2, "type": "ping", "pad": "x" * MAX_MESSAGE_BYTES})
    with pytest.raises(WireError, match="exceeds"):
        decode_ground(huge)
