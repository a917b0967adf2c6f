"""What the ground knows of the vehicle at the other end of the link: the robot it flies
(:class:`RobotIdentity`, announced in its ``hello``; a ``hello`` without one is ETS-VII's, 6
joints), whether a plan may fly on it (:func:`robot_mismatch`), and the link's status as the
API and the consoles show it (:class:`LinkStatus`, :class:`ScheduleStatus`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

from planner.plan import ETS7_ROBOT_HASH, ETS7_ROBOT_NAME
from telemetry.wire import Hello, TelemetryFrame

__all__ = ["ETS7_ROBOT", "LinkStatus", "RobotIdentity", "ScheduleStatus", "robot_mismatch"]


@dataclass(frozen=True)
class ScheduleStatus:
    """The onboard schedule as the newest telemetry frame reports it (PUS 11 summary)."""

    queued: int
    capacity: int
    free: int
    first_tag_ns: int | None
    last_tag_ns: int | None
    #: onboard s from the frame's time to the last tag loaded: how far ahead the arm's
    #: motion is already on board
    lead_s: float | None
    as_of_ns: int  # the frame's onboard time

    @classmethod
    def of(cls, frame: TelemetryFrame | None, capacity: int) -> ScheduleStatus | None:
        """The schedule the newest ``frame`` reports (``capacity``: the hello's, when the
        frame names none); None before any frame."""
        if frame is None:
            return None
        buffer = frame.buffer
        capacity = buffer.capacity or capacity
        last = buffer.last_queued_time_ns
        return cls(
            queued=buffer.queued,
            capacity=capacity,
            free=max(0, capacity - buffer.queued),
            first_tag_ns=buffer.next_execute_time_ns,
            last_tag_ns=last,
            lead_s=None if last is None else (last - frame.generation_time_ns) / 1e9,
            as_of_ns=frame.generation_time_ns,
        )


@dataclass(frozen=True)
class LinkStatus:
    connected: bool
    actor: str | None
    vehicle: str | None
    time_scale: float | None
    onboard_time_ns: int | None
    round_trip_s: float | None  # onboard s, last pong
    frames_received: int  # distinct frames held since the ground started
    duplicates: int
    frames_outside_pass: int
    highest_seq: int
    frames_behind: int | None  # estimated generated onboard minus held
    open_gaps: list[tuple[int, int]]
    frames_missing: int
    retransmit_requests: int
    errors_replied: int
    errors_received: int
    schedule: ScheduleStatus | None = None
    #: the uplink of the running pass (:meth:`server.services.uplink.Uplink.status`)
    uplink: dict[str, Any] | None = None
    #: onboard s the clock mapping was moved forward by later stamps since the hello
    clock_corrected_s: float = 0.0
    #: the robot the vehicle announced in its hello (ETS-VII's when it named none)
    robot: str | None = None
    robot_hash: str | None = None
    n_joints: int | None = None
    #: on-board safing: ``safe`` from the vehicle's ``safing`` report until it reports
    #: ``nominal`` (server.services.safing); the last report, with the pass it stopped
    vehicle_mode: Literal["nominal", "safe"] = "nominal"
    safing: dict[str, Any] | None = None
    #: messages that did not decode (an unreadable ``error`` included), by kind
    #: (``type:code``, server/services/malformed.py); those left unanswered by the bound on
    #: ``error`` replies; connections closed for too many of them
    malformed_received: int = 0
    malformed_by_kind: dict[str, int] = field(default_factory=dict)
    errors_unanswered: int = 0
    malformed_closes: int = 0
    #: this ground: whether it commands the vehicle (``command``: ``holder`` or
    #: ``standby``, the lease's holder and token) and whether its database answers
    #: (``database``: reachable, the journal of writes waiting, the last outage);
    #: server/services/ground_status.py
    ground: dict[str, Any] | None = None


@dataclass(frozen=True)
class RobotIdentity:
    """Which robot: its description's name, ``content_sha256`` and joint count (None: not
    announced)."""

    name: str | None
    hash: str | None
    n_joints: int | None

    @classmethod
    def of_hello(cls, hello: Hello) -> RobotIdentity:
        """The robot a ``hello`` announces: ETS-VII when it names none (a vehicle that
        predates robot descriptions, or the built-in ETS-VII)."""
        if hello.robot is None and hello.robot_hash is None and hello.n_joints is None:
            return ETS7_ROBOT
        return cls(hello.robot, hello.robot_hash, hello.n_joints)

    def __str__(self) -> str:
        joints = "? joints" if self.n_joints is None else f"{self.n_joints} joints"
        digest = "no description hash" if self.hash is None else f"description {self.hash[:12]}"
        return f"{self.name or 'unnamed'!r} ({joints}, {digest})"


ETS7_ROBOT = RobotIdentity(ETS7_ROBOT_NAME, ETS7_ROBOT_HASH, 6)


def robot_mismatch(plan: RobotIdentity, vehicle: RobotIdentity) -> str | None:
    """Why a plan made for ``plan`` must not be flown by ``vehicle``, or None when it is the
    same robot: the same description hash, and the same joint count where announced."""
    if (
        vehicle.hash is not None
        and vehicle.hash == plan.hash
        and vehicle.n_joints in (None, plan.n_joints)
    ):
        return None
    return (
        f"the plan was made for robot {plan} but the connected vehicle flies {vehicle}: "
        "plan the pass for the vehicle's robot, or connect the vehicle of the plan's robot"
    )
