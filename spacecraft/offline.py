"""Fly a plan through the vehicle with no link: every command reaches the buffer at once
(the schedule's capacity is raised to the plan's command count if it is smaller).

What the onboard computer would do with a perfect link, as fast as the simulation runs. For
tests, benchmarks and tools that need a flown pass without a ground server; the vehicle,
its servos, attitude control, sensors and gravity gradient are exactly those of the process.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from planner.model import default_model
from planner.plan import Plan
from spacecraft.vehicle import Vehicle
from spacecraft.vehicle_config import VehicleConfig, VehicleError, vehicle_config_for
from telemetry.uplink import plan_commands
from telemetry.wire import CommandAck, CommandStage, TelemetryFrame

if TYPE_CHECKING:
    from planner.robot import RobotDescription

__all__ = ["OfflineFlight", "fly_offline"]

#: The plan's t = 0 lies this far after the vehicle starts (onboard s), on the 0.25 s grid.
LEAD_S = 1.0


@dataclass(frozen=True)
class OfflineFlight:
    epoch_ns: int
    frames: list[TelemetryFrame]
    acks: list[CommandAck]

    @property
    def rejected(self) -> list[CommandAck]:
        return [a for a in self.acks if a.stage is CommandStage.REJECTED]


def fly_offline(
    plan: Plan,
    config: VehicleConfig | None = None,
    *,
    robot: RobotDescription | None = None,
    seed: int = 0,
    start_ns: int = 0,
    after_s: float = 2.0,
    progress: Callable[[float], None] | None = None,
    chunk_s: float = 10.0,
) -> OfflineFlight:
    """Start the vehicle at ``start_ns`` in the plan's initial pose, queue every command of
    ``plan`` (t = 0 at ``start_ns`` + 1 s), and run until ``after_s`` past the last tag.
    The vehicle is ``config``, or that of ``robot`` (a loaded robot description:
    :func:`spacecraft.vehicle_config.vehicle_config_for`), or ETS-VII's; a plan for another joint
    count is refused (:class:`~spacecraft.vehicle_config.VehicleError`).
    ``progress`` is called with the fraction done after each ``chunk_s`` of onboard time."""
    initial = tuple(float(v) for v in plan.initial_joints_rad)
    if config is not None and robot is not None:
        raise VehicleError("give fly_offline a vehicle config or a robot description, not both")
    model = config.model if config is not None else robot.model if robot is not None else None
    n_joints = model.n_joints if model is not None else default_model().n_joints
    if len(initial) != n_joints:
        raise VehicleError(
            f"the plan is for {len(initial)} joints, the vehicle's robot has {n_joints}"
        )
    if config is None:
        if robot is not None:
            config = vehicle_config_for(robot, initial_joints_rad=initial)
        else:
            config = VehicleConfig(initial_joints_rad=initial)
    epoch_ns = start_ns + round(LEAD_S * 1e9)
    commands = plan_commands(plan, epoch_ns=epoch_ns, first_seq=0)
    if len(commands) > config.schedule_capacity:
        # every command is loaded at once: the schedule is made to hold the whole plan
        config = replace(config, schedule_capacity=len(commands))
    vehicle = Vehicle(config, epoch_ns=start_ns, seed=seed)
    acks = [vehicle.receive(cmd) for cmd in commands]
    frames: list[TelemetryFrame] = []
    end_ns = max(c.execute_time_ns for c in commands) + round(after_s * 1e9)
    chunk_ns = round(chunk_s * 1e9)
    t = start_ns
    while t < end_ns:
        t = min(t + chunk_ns, end_ns)
        more_acks, more_frames = vehicle.advance_to(t)
        acks += more_acks
        frames += more_frames
        if progress is not None:
            progress((t - start_ns) / (end_ns - start_ns))
    return OfflineFlight(epoch_ns=epoch_ns, frames=frames, acks=acks)
