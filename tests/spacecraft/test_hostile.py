"""Hostile frames from the ground, against the spacecraft process over a real websocket:
nesting beyond the parser and control characters get ``error`` replies (a command with a
readable seq: ``rejected`` ``malformed``), the ground's ``error`` is never answered, and the
link stays up: the next good message is answered."""

from __future__ import annotations

import json

import pytest

from spacecraft.process import SpacecraftProcess
from telemetry.wire import MAX_DEPTH, CommandStage, Ping, Pong, RejectReason
from tests.spacecraft.ground_stub import GroundStub, run_session

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time


def test_hostile_ground_messages_get_error_replies_and_the_link_stays_up() -> None:
    async def scenario(stub: GroundStub, process: SpacecraftProcess) -> None:
        for text in (
            "[" * 10_000,
            '{"v":2,"type":"ping","ping_id":1,"ground_time_ns":0,"x":' + "[" * 20 + "]" * 20 + "}",
            json.dumps({"v": 2, "type": "ping", "ping_id\x00": 1, "ground_time_ns": 0}),
            json.dumps(
                {
                    "v": 2,
                    "type": "command",
                    "kind": "joints\x00",
                    "seq": 77,
                    "execute_time_ns": 0,
                    "joints_rad": [0.0] * 6,
                }
            ),
            # The ground's errors are never answered, however broken.
            json.dumps({"v": 2, "type": "error", "reason": "nul\x00here"}),
            json.dumps({"v": 2, "type": "error", "reason": "r", "x\x00": [[[[]]]]}),
        ):
            await stub.send(text)
        await stub.wait_for(lambda: len(stub.errors) >= 3 and stub.acks, 10.0)
        await stub.send(Ping(ping_id=5, ground_time_ns=123))
        await stub.wait_for(lambda: any(isinstance(m, Pong) for m in stub.other), 10.0)
        frames_before = max(stub.frames)
        await stub.wait_for(lambda: max(stub.frames) > frames_before + 10, 10.0)

    stub, process = run_session(scenario)
    reasons = [e.reason for e in stub.errors]
    assert len(reasons) == 3, reasons
    assert f"nested deeper than {MAX_DEPTH} levels" in reasons[0]
    assert f"nested deeper than {MAX_DEPTH} levels" in reasons[1]
    assert stub.errors[1].ref_type == "ping"
    assert "control character U+0000" in reasons[2] and stub.errors[2].ref_type == "ping"
    [ack] = [a for a in stub.acks if a.seq == 77]
    assert ack.stage is CommandStage.REJECTED and ack.reason is RejectReason.MALFORMED
    assert ack.detail is not None and "control character U+0000" in ack.detail
    assert not any(e.ref_type == "error" for e in stub.errors)
    [pong] = [m for m in stub.other if isinstance(m, Pong)]
    assert pong.ping_id == 5
    assert process.connections == 1  # never dropped
