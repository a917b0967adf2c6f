"""A 20-minute pass on the simulation core, against a raw MuJoCo loop of the same model.

The pass: PTP A -> B, hold, B -> A, hold, ... for 1200 s of simulated time, as 4 Hz joint
commands that the lagging servos follow (targets interpolated linearly between commands),
sampled at 10 Hz like the telemetry. Baselines, same model and same number of steps:
``mj_step(m, d, nstep=N)`` in one call (MuJoCo alone) and one ``mj_step`` per Python call.

Targets (foundation issue): >= 500x real time and >= 0.7 of the raw loop's speed.
"""

from __future__ import annotations

import mujoco
import numpy as np
from _common import best_of, emit

from planner.model import default_model
from planner.ptp import ptp_commands
from planner.simulation import FreeFloatingSimulator, follow_commands
from planner.state import State

PASS_S = 1200.0
JOINTS_B_RAD = np.radians([31.6, 21.4, -8.8, 77.4, 0.0, 68.6])


def pass_commands() -> tuple[np.ndarray, np.ndarray]:
    model = default_model()
    t_go, q_go = ptp_commands(model, np.zeros(6), JOINTS_B_RAD)
    t_back, q_back = ptp_commands(model, JOINTS_B_RAD, np.zeros(6))
    times, joints, t0 = [], [], 0.0
    while t0 < PASS_S:
        for t, q in ((t_go, q_go), (t_back, q_back)):
            times.append(t0 + t)
            joints.append(q)
            t0 += float(t[-1]) + 30.0  # 30 s hold after each move
    all_t = np.concatenate(times)
    keep = all_t <= PASS_S
    return all_t[keep], np.concatenate(joints)[keep]


def main() -> None:
    model = default_model()
    times, joints = pass_commands()

    def run_core() -> None:
        sim = FreeFloatingSimulator(model, State(joints_rad=np.zeros(6)))
        follow_commands(sim, times, joints, end_time_s=PASS_S, sample_period_s=0.1)

    sim = FreeFloatingSimulator(model, State(joints_rad=np.zeros(6)))
    mjm = sim.mj_model
    n_steps = round(PASS_S / sim.config.timestep_s)

    def run_raw_nstep() -> None:
        d = mujoco.MjData(mjm)
        mujoco.mj_step(mjm, d, nstep=n_steps)

    def run_raw_loop() -> None:
        d = mujoco.MjData(mjm)
        step = mujoco.mj_step
        for _ in range(n_steps):
            step(mjm, d)

    core_s = best_of(run_core, repeat=3)
    raw_nstep_s = best_of(run_raw_nstep, repeat=3)
    raw_loop_s = best_of(run_raw_loop, repeat=3)
    raw_best_s = min(raw_nstep_s, raw_loop_s)
    figures = {
        "simulated_s": PASS_S,
        "steps": n_steps,
        "timestep_s": sim.config.timestep_s,
        "commands": int(times.size),
        "samples": int(PASS_S / 0.1) + 1,
        "core_wall_s": core_s,
        "core_real_time_factor": PASS_S / core_s,
        "raw_mj_step_nstep_wall_s": raw_nstep_s,
        "raw_mj_step_python_loop_wall_s": raw_loop_s,
        "raw_real_time_factor": PASS_S / raw_best_s,
        "speed_ratio_core_over_raw": raw_best_s / core_s,
        "us_per_step_core": core_s / n_steps * 1e6,
        "us_per_step_raw": raw_best_s / n_steps * 1e6,
    }
    emit(
        "simulation_core_20min_pass",
        figures,
        {
            "real_time_factor_ge_500": figures["core_real_time_factor"] >= 500.0,
            "speed_ratio_ge_0.7": figures["speed_ratio_core_over_raw"] >= 0.7,
        },
    )


if __name__ == "__main__":
    main()
