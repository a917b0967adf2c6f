"""The plan's prediction between its 4 Hz samples: joints linear (as on board), attitude by
spherical linear interpolation. Outside the prediction's span the end values hold."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from planner.plan import Prediction
from telemetry.analysis._common import Array

__all__ = ["predicted_at"]


def predicted_at(prediction: Prediction, t_s: Array) -> tuple[Array, Array]:
    """Predicted joints (n, joints) and ``quat_orbit_from_base_xyzw`` (n, 4) at ``t_s``."""
    times = prediction.t_s
    t = np.clip(np.asarray(t_s, dtype=np.float64), times[0], times[-1])
    joints = np.column_stack(
        [
            np.interp(t, times, prediction.joints_rad[:, j])
            for j in range(prediction.joints_rad.shape[1])
        ]
    )
    if times.size == 1:
        return joints, np.tile(prediction.quat_orbit_from_base_xyzw[0], (t.size, 1))
    slerp = Slerp(times, Rotation.from_quat(prediction.quat_orbit_from_base_xyzw))
    quats = np.asarray(slerp(t).as_quat(), dtype=np.float64).reshape(-1, 4)
    quats[quats[:, 3] < 0.0] *= -1.0
    return joints, quats
