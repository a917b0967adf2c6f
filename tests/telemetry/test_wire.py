"""The wire protocol: golden JSON, and refusal of everything that is not a message."""

from __future__ import annotations

import json
import math
from typing import Any

import pytest

from telemetry.layout import DEFAULT_LAYOUT, FrameLayout
from telemetry.wire import (
    MAX_DEPTH,
    MAX_MESSAGE_BYTES,
    AcsCommandMsg,
    AcsModeName,
    CommandAck,
    CommandQuery,
    CommandStage,
    ErrorMsg,
    Hello,
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
    escape_controls,
)
from tests.support.wire import frame as _frame
from tests.support.wire import telemetry_text as _telemetry_text

GOLDEN_JOINT_COMMAND = (
    '{"v":2,"type":"command","kind":"joints","seq":7,"execute_time_ns":1000250000000,'
    '"joints_rad":[0.1,-0.2,0.3,0.0,0.5,-0.6]}'
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
        (GOLDEN_JOINT_COMMAND.replace("[0.1,-0.2,0.3,0.0,0.5,-0.6]", "[]"), "joints_rad"),
        (GOLDEN_JOINT_COMMAND.replace("-0.6]", "-0.6" + ",0.0" * 27 + "]"), "joints_rad"),
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


def test_a_multibyte_message_is_measured_in_bytes() -> None:
    pad = "\u00e9" * (MAX_MESSAGE_BYTES // 2)
    text = json.dumps({"v": 2, "type": "ping", "pad": pad}, ensure_ascii=False)
    assert len(text) < MAX_MESSAGE_BYTES < len(text.encode())
    with pytest.raises(WireError, match="exceeds"):
        decode_ground(text)


HELLO = {
    "v": 2,
    "type": "hello",
    "vehicle": "ETS-VII",
    "onboard_time_ns": 10**18,
    "time_scale": 20.0,
    "next_telemetry_seq": 0,
}


def _nested(depth: int) -> dict[str, object]:
    """A hello ``depth`` levels deep (the message object is level 1)."""
    value: object = 1
    for _ in range(depth - 1):
        value = [value]
    return {**HELLO, "vehicle": "x", "deep": value}


@pytest.mark.parametrize("text", ["[" * 10_000, '{"a":' * 10_000, '[{"a":' * 5_000, "[" * 200_000])
@pytest.mark.parametrize("decode", [decode_ground, decode_spacecraft])
def test_nesting_beyond_the_parser_is_a_wire_error(text: str, decode: Any) -> None:
    """10 KB of brackets make json.loads raise RecursionError (a RuntimeError, which the
    link once took for a closed socket): a WireError with the reason."""
    for raw in (text, text.encode()):
        with pytest.raises(WireError, match=f"nested deeper than {MAX_DEPTH} levels"):
            decode(raw)


def test_nesting_beyond_the_bound_is_refused_before_validation() -> None:
    deepest = encode(TelemetryMsg(frames=[_frame(0)]))
    assert _depth(json.loads(deepest)) == 4  # the deepest real message
    assert decode_spacecraft(deepest).type == "telemetry"
    # At the bound the message reaches validation (and fails there: unknown field)...
    with pytest.raises(WireError, match="deep") as info:
        decode_spacecraft(json.dumps(_nested(MAX_DEPTH)))
    assert "nested" not in str(info.value)
    # ... one level more and it does not.
    with pytest.raises(WireError, match=f"nested deeper than {MAX_DEPTH}") as info:
        decode_spacecraft(json.dumps(_nested(MAX_DEPTH + 1)))
    assert info.value.ref_type == "hello"
    with pytest.raises(WireError, match="nested deeper"):
        decode_ground(json.dumps({"v": 2, "type": "ping", "x": [{"y": [[]]}] * 3 + _deep(20)}))


def _deep(depth: int) -> list[object]:
    value: list[object] = []
    for _ in range(depth):
        value = [value]
    return value


def _depth(value: object) -> int:
    if isinstance(value, dict):
        return 1 + max((_depth(v) for v in value.values()), default=0)
    if isinstance(value, list):
        return 1 + max((_depth(v) for v in value), default=0)
    return 0


@pytest.mark.parametrize(
    "char", ["\x00", "\x01", "\t", "\n", "\r", "\x1b", "\x1f", "\x7f", "\x85", "\x9f", "\ud800"]
)
def test_control_characters_in_any_string_are_refused(char: str) -> None:
    for doc in (
        {**HELLO, "vehicle": f"ETS{char}VII"},
        {**HELLO, f"vehi{char}cle": "ETS-VII"},  # in a key
    ):
        for raw in (json.dumps(doc), json.dumps(doc, ensure_ascii=False)):
            if char == "\ud800" and "\\ud800" not in raw:
                continue
            with pytest.raises(WireError, match=f"control character U\\+{ord(char):04X}") as info:
                decode_spacecraft(raw)
            assert info.value.ref_type == "hello"
            assert not _has_control(str(info.value))
            if char != "\ud800":
                with pytest.raises(WireError, match="control character"):
                    decode_spacecraft(raw.encode())
    command = json.loads(GOLDEN_JOINT_COMMAND)
    with pytest.raises(WireError, match="control character"):
        decode_ground(json.dumps({**command, "kind": f"joints{char}"}))
    detail = {"v": 2, "type": "command_ack", "seq": 1, "stage": "received", "onboard_time_ns": 1}
    with pytest.raises(WireError, match="control character"):
        decode_spacecraft(json.dumps({**detail, "detail": f"a{char}b"}))


def _has_control(text: str) -> bool:
    return any(ord(c) < 0x20 or 0x7F <= ord(c) <= 0x9F or 0xD800 <= ord(c) <= 0xDFFF for c in text)


def test_printable_unicode_is_not_a_control_character() -> None:
    hello = decode_spacecraft(json.dumps({**HELLO, "vehicle": "\u304d\u304f \u00e9\u2028 \\"}))
    assert isinstance(hello, Hello) and hello.vehicle == "\u304d\u304f \u00e9\u2028 \\"


def test_an_error_message_is_delivered_with_its_control_characters_escaped() -> None:
    raw = json.dumps(
        {"v": 2, "type": "error", "reason": "bad\x00byte\n\ud800", "ref_type": "x\x07"}
    )
    message = decode_spacecraft(raw)
    assert isinstance(message, ErrorMsg)
    assert message.reason == "bad\\x00byte\\n\\ud800" and message.ref_type == "x\\x07"
    assert escape_controls("plain \u00e9") == "plain \u00e9"
    # Not its keys, nor nesting: those are refused (and, an error, never answered).
    with pytest.raises(WireError, match="control character") as info:
        decode_spacecraft(json.dumps({"v": 2, "type": "error", "reason": "r", "k\x00": 1}))
    assert info.value.ref_type == "error"


def test_a_wire_error_names_the_type_escaped() -> None:
    with pytest.raises(WireError) as info:
        decode_ground(json.dumps({"v": 2, "type": "boom\x00" + "x" * 100}))
    assert info.value.ref_type == "boom\\x00" + "x" * 56
    assert not _has_control(str(info.value))
    with pytest.raises(WireError, match="not JSON") as info:
        decode_ground('{"v":2,"type":"ping","ping_id":1' + "1" * 5000 + "}")  # int digits limit
    assert info.value.ref_type is None


# --- n joints: lengths checked against the receiver's robot ---------------------------------


def _seven_joint_frame(seq: int) -> TelemetryFrame:
    return _frame(seq).model_copy(update={"joints_rad": [0.1] * 7, "joint_targets_rad": [0.2] * 7})


def test_a_joint_command_of_any_bounded_length_decodes_and_is_checked_against_the_robot() -> None:
    seven = GOLDEN_JOINT_COMMAND.replace("-0.6]", "-0.6,0.7]")
    decoded = decode_ground(seven)
    assert isinstance(decoded, JointCommandMsg) and len(decoded.joints_rad) == 7
    assert decode_ground(seven, FrameLayout(7, 3)) == decoded
    with pytest.raises(WireError, match="joints_rad has 7 values, this robot has 6 joints"):
        decode_ground(seven, DEFAULT_LAYOUT)
    # ETS-VII's own command passes its layout, and an ACS command has no joints to check
    assert isinstance(decode_ground(GOLDEN_JOINT_COMMAND, DEFAULT_LAYOUT), JointCommandMsg)
    acs = encode(AcsCommandMsg(seq=1, execute_time_ns=0, mode=AcsModeName.FREE_DRIFT))
    assert isinstance(decode_ground(acs, FrameLayout(7, 3)), AcsCommandMsg)


def test_telemetry_of_another_robot_is_refused_with_the_reason() -> None:
    text = encode(TelemetryMsg(frames=[_seven_joint_frame(0), _seven_joint_frame(1)]))
    message = decode_spacecraft(text)
    assert isinstance(message, TelemetryMsg) and len(message.frames[1].joint_targets_rad) == 7
    assert decode_spacecraft(text, FrameLayout(7, 3)) == message
    with pytest.raises(WireError, match=r"frame 0: joints_rad has 7 values.*\(6 joints") as info:
        decode_spacecraft(text, DEFAULT_LAYOUT)
    assert info.value.ref_type == "telemetry"
    ets7 = encode(TelemetryMsg(frames=[_frame(0)]))
    with pytest.raises(WireError, match="joints_rad has 6 values"):
        decode_spacecraft(ets7, FrameLayout(7, 3))


def test_hello_names_the_robot_optionally_and_ets7s_hello_is_unchanged() -> None:
    plain = decode_spacecraft(json.dumps(HELLO))
    assert isinstance(plain, Hello) and plain.robot is None and plain.n_joints is None
    # absent fields stay absent: the bytes of a hello without them are as before
    assert json.loads(encode(plain)).keys() == Hello.model_fields.keys() - {
        "robot",
        "robot_hash",
        "n_joints",
    }
    named = {**HELLO, "robot": "orihime", "robot_hash": "sha256:ab12", "n_joints": 7}
    hello = decode_spacecraft(json.dumps(named), FrameLayout(7, 3))
    assert isinstance(hello, Hello)
    assert (hello.robot, hello.robot_hash, hello.n_joints) == ("orihime", "sha256:ab12", 7)
    assert decode_spacecraft(encode(hello)) == hello
    with pytest.raises(WireError, match="n_joints 7, this session's robot has 6 joints"):
        decode_spacecraft(json.dumps(named), DEFAULT_LAYOUT)
    for bad in ({"n_joints": 0}, {"n_joints": 33}, {"robot": ""}, {"robot_hash": "x" * 129}):
        with pytest.raises(WireError, match="invalid hello"):
            decode_spacecraft(json.dumps({**HELLO, **bad}))


@pytest.mark.parametrize(
    ("changes", "code", "reason"),
    [
        ({"joints_rad": [0.0, 0.0, float("nan"), 0.0, 0.0, 0.0]}, "invalid", "finite number"),
        ({"omega_base_in_base_radps": [float("inf"), 0.0, 0.0]}, "invalid", "finite number"),
        ({"joints_rad": [0.0, 0.0, 1e15, 0.0, 0.0, 0.0]}, "unphysical", "joints_rad[2] = 1e+15"),
        ({"joint_targets_rad": [0.0, -13.0, 0.0, 0.0, 0.0, 0.0]}, "unphysical", "-13 rad"),
        ({"omega_base_in_base_radps": [0.0, 1e30, 0.0]}, "unphysical", "base rate 1e+30"),
        ({"quat_orbit_from_base_xyzw": [0.0, 0.0, 0.0, 2.0]}, "unphysical", "norm 2"),
        ({"wheel_speeds_radps": [1.0, 2e5, 3.0]}, "unphysical", "wheel speed 200000"),
        ({"wheel_momentum_nms": [0.0, 0.0, -3e4]}, "unphysical", "wheel momentum 30000"),
    ],
)
def test_nonsense_telemetry_is_refused_with_a_counted_code(
    changes: dict[str, Any], code: str, reason: str
) -> None:
    """A diverged simulation's frames (non-finite, or finite but beyond any real vehicle:
    telemetry.wire's MAX_* bounds) never reach the archive: the message is refused with a
    code the ground counts (server/services/malformed.py) and the frame named."""
    with pytest.raises(WireError) as info:
        decode_spacecraft(_telemetry_text(**changes))
    assert info.value.code == code
    assert info.value.ref_type == "telemetry"
    assert reason in str(info.value), str(info.value)
    if code == "unphysical":
        assert "frame 1 (seq 1)" in str(info.value)
    # the bounds leave every real frame alone: a joint at 2 pi, a base turning at 1 rad/s
    decode_spacecraft(
        _telemetry_text(
            joints_rad=[2 * math.pi, 0.0, 0.0, 0.0, 0.0, -2 * math.pi],
            omega_base_in_base_radps=[1.0, 0.0, 0.0],
        )
    )
