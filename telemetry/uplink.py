"""A plan's commands as they cross the link: wire messages at onboard time tags.

The ground's emitter (server) uplinks exactly these; an offline flight through the vehicle
(tests, re-simulation) receives the same list, so both fly one command stream.
"""

from __future__ import annotations

from typing import Any

from planner.plan import Plan
from telemetry.wire import AcsCommandMsg, AcsModeName, JointCommandMsg

__all__ = ["ACS_GRID_NS", "GRID_NS", "Command", "plan_commands"]

GRID_NS = 250_000_000  # the 4 Hz command grid
ACS_GRID_NS = 10_000_000  # the onboard 10 ms tag grid

Command = JointCommandMsg | AcsCommandMsg


def plan_commands(plan: Plan, *, epoch_ns: int, first_seq: int) -> list[Command]:
    """The plan's commands at onboard tags (plan ``t = 0`` at ``epoch_ns``), seq in tag order
    (an ACS command before a joint command of the same tag)."""
    items: list[tuple[int, int, Any]] = []
    for t_s, q in zip(plan.command_times_s, plan.command_joints_rad, strict=True):
        items.append((epoch_ns + round(float(t_s) * 1e9), 1, [float(v) for v in q]))
    for acs in plan.acs_commands:
        tag = epoch_ns + round(acs.t_s * 1e9 / ACS_GRID_NS) * ACS_GRID_NS
        items.append((tag, 0, acs))
    items.sort(key=lambda item: (item[0], item[1]))
    out: list[Command] = []
    for seq, (tag, order, what) in enumerate(items, start=first_seq):
        if order == 1:
            out.append(JointCommandMsg(seq=seq, execute_time_ns=tag, joints_rad=what))
        else:
            out.append(
                AcsCommandMsg(
                    seq=seq,
                    execute_time_ns=tag,
                    mode=AcsModeName(what.mode.value),
                    target_quat_orbit_from_base_xyzw=[
                        float(v) for v in what.target_quat_orbit_from_base_xyzw
                    ],
                    feedforward=what.feedforward,
                )
            )
    return out
