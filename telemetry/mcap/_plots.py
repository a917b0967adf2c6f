"""Plot-friendly channels: flat objects of named numbers, degrees at this edge (a UI).

Derived from the recording on export and never read back. Every field is a number, so a
Foxglove Plot path is just ``/plot/base.pitch_deg``; booleans are written as 0 or 1.
Numbers carry 7 significant digits (display only; the exact values are in our channels).
``t_s`` is the plan's clock (s from its ``t = 0``); the log time is the onboard time.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from planner.plan import Plan
from telemetry.recording import FrameArrays

__all__ = [
    "PLOT_TOPICS",
    "frame_plot_messages",
    "plot_messages",
    "plot_schema",
    "prediction_plot_messages",
]

Array = NDArray[np.float64]

TOPIC_PLOT_JOINTS = "/plot/joints"
TOPIC_PLOT_BASE = "/plot/base"
TOPIC_PLOT_WHEELS = "/plot/wheels"
TOPIC_PLOT_PREDICTION = "/plot/prediction"
PLOT_TOPICS = (TOPIC_PLOT_JOINTS, TOPIC_PLOT_BASE, TOPIC_PLOT_WHEELS, TOPIC_PLOT_PREDICTION)

_SCHEMA_NAMES = {
    TOPIC_PLOT_JOINTS: "hikoboshi.plot.Joints",
    TOPIC_PLOT_BASE: "hikoboshi.plot.Base",
    TOPIC_PLOT_WHEELS: "hikoboshi.plot.Wheels",
    TOPIC_PLOT_PREDICTION: "hikoboshi.plot.Prediction",
}
_DESCRIPTIONS = {
    TOPIC_PLOT_JOINTS: "Measured and commanded joint angles and their error (target - "
    "measured), deg, per telemetry frame.",
    TOPIC_PLOT_BASE: "Base attitude roll/pitch/yaw (R = Rz(yaw) Ry(pitch) Rx(roll), orbit "
    "from base), base rate in the base frame, the ACS target attitude; per telemetry frame.",
    TOPIC_PLOT_WHEELS: "Wheel speeds relative to the base and wheel momentum (base frame), "
    "onboard command-buffer depth; per telemetry frame.",
    TOPIC_PLOT_PREDICTION: "The plan's prediction under ideal tracking, one row per "
    "prediction sample: base roll/pitch/yaw, joints, hand position (orbit frame), "
    "reaction momentum H~_bm phi' (orbit frame).",
}


def _rpy_deg(quat_xyzw: Array) -> Array:
    """(N, 3) roll, pitch, yaw in degrees, planner.frames' z-y-x convention."""
    if len(quat_xyzw) == 0:
        return np.zeros((0, 3))
    yaw_pitch_roll = Rotation.from_quat(quat_xyzw).as_euler("ZYX")
    return np.degrees(np.asarray(yaw_pitch_roll, dtype=np.float64)[:, ::-1])


def _xyz(prefix: str, unit: str, values: Array) -> dict[str, Array]:
    return {f"{prefix}_{axis}_{unit}": values[:, i] for i, axis in enumerate("xyz")}


def _columns(frames: FrameArrays, t_s: Array) -> dict[str, dict[str, Array]]:
    measured = np.degrees(frames.joints_rad)
    target = np.degrees(frames.joint_targets_rad)
    joints: dict[str, Array] = {"t_s": t_s}
    for i in range(measured.shape[1]):
        joints[f"j{i + 1}_deg"] = measured[:, i]
    for i in range(measured.shape[1]):
        joints[f"j{i + 1}_target_deg"] = target[:, i]
    for i in range(measured.shape[1]):
        joints[f"j{i + 1}_error_deg"] = target[:, i] - measured[:, i]
    rpy = _rpy_deg(frames.quat_orbit_from_base_xyzw)
    target_rpy = _rpy_deg(frames.acs_target_quat_xyzw)
    base: dict[str, Array] = {"t_s": t_s}
    base |= {f"{a}_deg": rpy[:, i] for i, a in enumerate(("roll", "pitch", "yaw"))}
    base |= _xyz("omega", "degps", np.degrees(frames.omega_base_in_base_radps))
    base |= {f"target_{a}_deg": target_rpy[:, i] for i, a in enumerate(("roll", "pitch", "yaw"))}
    base["acs_free_drift"] = (frames.acs_mode == "free_drift").astype(np.float64)
    base["acs_feedforward"] = frames.acs_feedforward.astype(np.float64)
    wheels: dict[str, Array] = {"t_s": t_s}
    wheels |= _xyz("speed", "radps", frames.wheel_speeds_radps)
    wheels |= _xyz("momentum", "nms", frames.wheel_momentum_nms)
    wheels["buffer_queued"] = frames.buffer_queued.astype(np.float64)
    return {TOPIC_PLOT_JOINTS: joints, TOPIC_PLOT_BASE: base, TOPIC_PLOT_WHEELS: wheels}


def _prediction_columns(plan: Plan) -> dict[str, Array]:
    pred = plan.prediction
    rpy = np.degrees(np.asarray(pred.rpy_base_rad, dtype=np.float64).reshape(-1, 3))
    joints = np.degrees(np.asarray(pred.joints_rad, dtype=np.float64))
    cols: dict[str, Array] = {"t_s": np.asarray(pred.t_s, dtype=np.float64)}
    cols |= {f"{a}_deg": rpy[:, i] for i, a in enumerate(("roll", "pitch", "yaw"))}
    cols |= {f"j{i + 1}_deg": joints[:, i] for i in range(joints.shape[1])}
    cols |= _xyz("hand", "m", np.asarray(pred.hand_pos_orbit_m, dtype=np.float64))
    cols |= _xyz(
        "reaction_momentum", "nms", np.asarray(pred.reaction_momentum_orbit_nms, np.float64)
    )
    return cols


def _json_rows(columns: dict[str, Array]) -> list[bytes]:
    # 7 significant digits: plenty for a plot, and a third of the bytes of repr's 17.
    template = "{" + ",".join(f'"{name}":%.7g' for name in columns) + "}"
    lists = [np.asarray(c, dtype=np.float64).tolist() for c in columns.values()]
    return [(template % row).encode() for row in zip(*lists, strict=True)]


def plot_schema(topic: str, fields: list[str]) -> dict[str, Any]:
    return {
        "title": _SCHEMA_NAMES[topic],
        "description": _DESCRIPTIONS[topic],
        "type": "object",
        "properties": {name: {"type": "number"} for name in fields},
        "required": fields,
    }


_Plot = tuple[dict[str, Any], NDArray[np.int64], list[bytes]]


def frame_plot_messages(frames: FrameArrays, t_s: Array) -> dict[str, _Plot]:
    """``/plot/joints``, ``/plot/base``, ``/plot/wheels``: topic -> (schema, log times in
    onboard ns, JSON messages), one message per frame (``t_s``: the frames' plan times)."""
    return {
        topic: (plot_schema(topic, list(cols)), frames.generation_time_ns, _json_rows(cols))
        for topic, cols in _columns(frames, t_s).items()
    }


def prediction_plot_messages(plan: Plan, epoch_ns: int) -> _Plot:
    """``/plot/prediction``: (schema, log times ``epoch_ns + t_s``, JSON messages)."""
    pred = _prediction_columns(plan)
    log_ns = epoch_ns + np.round(pred["t_s"] * 1e9).astype(np.int64)
    return plot_schema(TOPIC_PLOT_PREDICTION, list(pred)), log_ns, _json_rows(pred)


def plot_messages(frames: FrameArrays, t_s: Array, plan: Plan, epoch_ns: int) -> dict[str, _Plot]:
    """topic -> (schema, log times in onboard ns, JSON messages)."""
    out = frame_plot_messages(frames, t_s)
    out[TOPIC_PLOT_PREDICTION] = prediction_plot_messages(plan, epoch_ns)
    return out
