"""Malformed messages for rehearsing a noisy link (``hikoboshi spacecraft --garbage``).

A relay that corrupts, or a vehicle whose software misbehaves, puts messages on the link the
ground cannot read. :class:`GarbageMaker` makes them, deterministically from a seed, in a
fixed rotation of four kinds that each take a different path through the ground's decoder
(``telemetry/wire.py``):

- ``invalid_json``: a telemetry message cut short (the JSON parser refuses it);
- ``unknown_type``: a well-formed version-2 message of a type the protocol does not have;
- ``wrong_version``: a telemetry message of version 1 or 3 (refused after the JSON parse and
  the tree check, before any field is validated);
- ``malformed_telemetry``: a version-2 telemetry message of five frames, one of whose fields
  is wrong (a vector of the wrong length, a negative seq, a missing field, NaN): refused by
  the field validation, the most expensive path.

None of them is an ``error`` message (the ground never answers those, and counts them
apart). The frames look like the vehicle's (six joints, three wheels), about 2.4 KB a
message. The process sends them (:mod:`spacecraft.process`) at the ground end of the relay,
straight onto the socket, at the rate ``--garbage START:END:RATE`` asks.
"""

from __future__ import annotations

import itertools
import json
import random
from typing import Any

__all__ = ["KINDS", "GarbageMaker"]

#: The kinds, in the order they rotate.
KINDS = ("invalid_json", "unknown_type", "wrong_version", "malformed_telemetry")
_FRAMES = 5
_UNKNOWN_TYPES = ("housekeeping", "beacon", "telemetry_v3", "status")


class GarbageMaker:
    """Malformed spacecraft -> ground messages, one kind after the other (:data:`KINDS`)."""

    def __init__(self, seed: int = 0, *, epoch_ns: int = 1_900_000_000 * 10**9) -> None:
        self._rng = random.Random(seed)
        self._n = itertools.count()
        self._epoch_ns = epoch_ns
        self.made: dict[str, int] = dict.fromkeys(KINDS, 0)

    def _frame(self, seq: int) -> dict[str, Any]:
        r = self._rng
        return {
            "seq": seq,
            "generation_time_ns": self._epoch_ns + seq * 100_000_000,
            "joints_rad": [round(r.uniform(-1, 1), 6) for _ in range(6)],
            "joint_targets_rad": [round(r.uniform(-1, 1), 6) for _ in range(6)],
            "quat_orbit_from_base_xyzw": [0.0, 0.0, 0.0, 1.0],
            "omega_base_in_base_radps": [round(r.gauss(0, 1e-4), 8) for _ in range(3)],
            "wheel_speeds_radps": [round(r.uniform(-50, 50), 4) for _ in range(3)],
            "wheel_momentum_nms": [round(r.uniform(-1, 1), 6) for _ in range(3)],
            "acs_mode": "feedback",
            "acs_target_quat_xyzw": [0.0, 0.0, 0.0, 1.0],
            "acs_feedforward": False,
            "buffer": {"queued": r.randrange(0, 500), "last_executed_seq": r.randrange(0, 5000)},
        }

    def _telemetry(self, v: int = 2) -> dict[str, Any]:
        first = self._rng.randrange(0, 10**6)
        frames = [self._frame(first + i) for i in range(_FRAMES)]
        return {"v": v, "type": "telemetry", "frames": frames, "retransmission": False}

    def next(self) -> str:
        """The next malformed message (text)."""
        kind = KINDS[next(self._n) % len(KINDS)]
        self.made[kind] += 1
        r = self._rng
        if kind == "invalid_json":
            text = json.dumps(self._telemetry())
            return text[: r.randrange(1, len(text) - 1)]
        if kind == "unknown_type":
            doc = self._telemetry()
            doc["type"] = r.choice(_UNKNOWN_TYPES)
            return json.dumps(doc)
        if kind == "wrong_version":
            return json.dumps(self._telemetry(v=r.choice((1, 3))))
        doc = self._telemetry()
        frame = doc["frames"][r.randrange(_FRAMES)]
        fault = r.randrange(4)
        if fault == 0:
            frame["joints_rad"] = frame["joints_rad"] + [0.0] * 40  # over the 32 a vector holds
        elif fault == 1:
            frame["seq"] = -1
        elif fault == 2:
            del frame["buffer"]
        else:
            frame["wheel_momentum_nms"][0] = float("nan")
        return json.dumps(doc)
