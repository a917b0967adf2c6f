"""Wire messages the tests build by hand."""

from __future__ import annotations

import json
from typing import Any

from telemetry.wire import AcsModeName, BufferState, TelemetryFrame, TelemetryMsg, encode


def frame(seq: int) -> TelemetryFrame:
    """ETS-VII's frame ``seq`` at 10 Hz from 1000 s, the arm at zero, three queued."""
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


def telemetry_text(**changes: Any) -> str:
    """A telemetry message of frames 0 and 1, frame 1's fields ``changes`` (any JSON)."""
    doc = json.loads(encode(TelemetryMsg(frames=[frame(0), frame(1)])))
    for key, value in changes.items():
        doc["frames"][1][key] = value
    return json.dumps(doc)
