"""The foundation's main job: PTP A -> B in free drift, simulated and predicted.

Runs the conventional PTP motion from pose A to pose B (SPEC 1.2) on the free-floating
MuJoCo model with lagging joint servos and no attitude control, compares the simulated base
attitude with the ideal-tracking prediction of eq. (10), and writes the series and a summary.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from planner.dynamics import DynamicsWorkspace
from planner.frames import matrix_from_rpy, rpy_from_matrix
from planner.free_drift import predict_base_attitude
from planner.ik import solve_ik
from planner.model import default_model
from planner.ptp import ptp_commands
from planner.simulation import FreeFloatingSimulator, follow_commands
from planner.state import State

POSE_B_POS_ROBOT_M = np.array([1.170, 0.407, 0.490])
POSE_B_RPY_DEG = np.array([0.0, 90.0, -37.0])


def _rpy_deg(quats_xyzw: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    matrices = Rotation.from_quat(quats_xyzw).as_matrix()
    return np.array([np.degrees(rpy_from_matrix(m)) for m in matrices])


def run(
    out_dir: Path,
    *,
    hold_s: float = 60.0,
    on_progress: Callable[[float, float], None] | None = None,
) -> dict[str, Any]:
    model = default_model()
    ws = DynamicsWorkspace(model)
    solutions = solve_ik(ws, POSE_B_POS_ROBOT_M, matrix_from_rpy(np.radians(POSE_B_RPY_DEG)))
    joints_b = solutions[0].joints_rad
    t_cmd, q_cmd = ptp_commands(model, np.zeros(model.n_joints), joints_b)
    end_s = float(t_cmd[-1] + hold_s)

    initial = State(joints_rad=np.zeros(model.n_joints))
    sim = FreeFloatingSimulator(model, initial)
    momentum_before = ws.evaluate(initial).angular_momentum_nms
    trajectory = follow_commands(
        sim,
        t_cmd,
        q_cmd,
        end_time_s=end_s,
        on_sample=None if on_progress is None else (lambda t: on_progress(t, end_s)),
    )
    final = sim.state()
    momentum_after = ws.evaluate(final).angular_momentum_nms
    predicted_quat, _ = predict_base_attitude(ws, t_cmd, q_cmd)

    rpy_sim_deg = _rpy_deg(trajectory.quat_orbit_from_base_xyzw)
    rpy_pred_deg = _rpy_deg(predicted_quat)
    lag_deg = np.degrees(trajectory.joint_targets_rad - trajectory.joints_rad)

    out_dir.mkdir(parents=True, exist_ok=True)
    series_path = out_dir / "ptp_attitude.csv"
    with series_path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(
            ["t_s", "roll_deg", "pitch_deg", "yaw_deg"]
            + [f"joint{i + 1}_deg" for i in range(model.n_joints)]
            + [f"joint{i + 1}_target_deg" for i in range(model.n_joints)]
        )
        for k, t in enumerate(trajectory.t_s):
            writer.writerow(
                [f"{t:.2f}", *(f"{v:.6f}" for v in rpy_sim_deg[k])]
                + [f"{v:.6f}" for v in np.degrees(trajectory.joints_rad[k])]
                + [f"{v:.6f}" for v in np.degrees(trajectory.joint_targets_rad[k])]
            )
    summary: dict[str, Any] = {
        "experiment": "ptp A->B, free drift (no attitude control yet)",
        "joints_b_deg": np.round(np.degrees(joints_b), 3).tolist(),
        "ik_solutions_found": len(solutions),
        "motion_duration_s": float(t_cmd[-1]),
        "commands": int(t_cmd.size),
        "simulated_final_rpy_deg": np.round(rpy_sim_deg[-1], 4).tolist(),
        "predicted_final_rpy_deg": np.round(rpy_pred_deg[-1], 4).tolist(),
        "prediction_error_deg": float(np.max(np.abs(rpy_sim_deg[-1] - rpy_pred_deg[-1]))),
        "peak_rpy_deg": np.round(np.max(np.abs(rpy_sim_deg), axis=0), 4).tolist(),
        "max_servo_lag_deg": np.round(np.max(np.abs(lag_deg), axis=0), 3).tolist(),
        "angular_momentum_drift_nms": float(np.linalg.norm(momentum_after - momentum_before)),
        "series_csv": str(series_path),
    }
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    summary["summary_json"] = str(out_dir / "summary.json")
    return summary
