"""Measure the fastest servo mode the simulator's integrator holds (docs/robots.md, "Servo
stability").

For each shipped robot: the servos' damping ``kd`` is scaled (``kp`` kept), the arm flown at
rest for 20 s from its reference pose towards a target 0.01 rad away on every joint, and the
run called diverged when a joint leaves its target by more than 1 rad or a state goes
non-finite (MuJoCo's own instability check resets the data: the joints then jump). A
bisection on the scale gives the largest fastest-mode rate ``max eig(M^-1 Kd)`` at the pose
that still holds, times the step: RK4's bound on the negative real axis is 2.785.

    .venv/bin/python scripts/servo_threshold.py [--step 0.01]

Prints one JSON line per robot: the held and diverged rates (1/s) and ``rate * step``.
"""

from __future__ import annotations

import argparse
import json
import warnings

import numpy as np

from planner.description import EXAMPLES_DIR, load_robot
from planner.dynamics import DynamicsWorkspace
from planner.mjcf import ServoGains
from planner.servo_check import fastest_mode_at
from planner.simulation import FreeFloatingSimulator, SimConfig
from planner.state import State


def holds(robot, gains: ServoGains, step_s: float) -> bool:
    start = robot.model.reference_joints
    sim = FreeFloatingSimulator(
        robot.model, State(start.copy()), SimConfig(timestep_s=step_s, servo=gains)
    )
    target = start + 0.01
    sim.set_joint_target(target)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for _ in range(200):
            sim.advance(0.1)
            q = sim.state().joints_rad
            if not np.all(np.isfinite(q)) or np.max(np.abs(q - target)) > 1.0:
                return False
    return bool(np.max(np.abs(sim.state().joints_rad - target)) < 0.01)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--step", type=float, default=0.01)
    args = parser.parse_args()
    for name in ("ets7", "orihime"):
        robot = load_robot(EXAMPLES_DIR / name / f"{name}.toml")
        ws = DynamicsWorkspace(robot.model)
        base = robot.servo_gains()
        rate0 = fastest_mode_at(ws, base, robot.model.reference_joints)

        def gains(scale: float, base: ServoGains = base) -> ServoGains:
            return ServoGains(base.kp_nm_per_rad, np.asarray(base.kd_nms_per_rad) * scale)

        lo, hi = 1.0, 6.0 / (rate0 * args.step)  # rate*step from ~0 to 6: holds, diverges
        assert holds(robot, gains(lo), args.step) and not holds(robot, gains(hi), args.step)
        for _ in range(14):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if holds(robot, gains(mid), args.step) else (lo, mid)
        print(
            json.dumps(
                {
                    "robot": name,
                    "step_s": args.step,
                    "held_per_s": round(rate0 * lo, 2),
                    "diverged_per_s": round(rate0 * hi, 2),
                    "held_rate_x_step": round(rate0 * lo * args.step, 4),
                }
            )
        )


if __name__ == "__main__":
    main()
