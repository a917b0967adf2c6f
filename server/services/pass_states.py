"""A pass's transactions, as database jobs for the runner (:mod:`server.services.runner`):
its state transitions, the start (``aos`` then ``running``, the commands queued) and the
abort (commands cancelled, ``aborted``).

Every transition is a compare-and-set on the pass's version (``update_pass_state``) and an
event ``pass_state`` (actor, from, to, reason) in the same transaction.

**Start** (needs a connected spacecraft with a known clock, flying the robot the plan was
made for): ``aos`` then ``running`` in one transaction. A plan made for another robot (its
description's hash, or its joint count, differs from what the vehicle's ``hello`` announced;
a ``hello`` naming no robot is ETS-VII's) is refused 409 ``robot_mismatch`` with both robots
named, and the refusal is audited (``pass_start_refused``); the pass stays ``scheduled``.
The plan's ``t = 0`` is put at ``epoch_ns``, on the 0.25 s grid at most the start lead
after onboard now (:func:`server.operations.windows.start_lead_s`: ``uplink_start_lead_s``,
at least one-way delay + margin + three first retransmission timeouts, and the onboard time
of 1 s wall for the start transaction and the grid step), so that even the first command
can be sent again before its tag if the relay loses it. The plan's joint and ACS commands
are queued with ``seq`` from one past the highest the vehicle or the archive has seen, in
tag order. The pass's telemetry window opens at onboard now.

**Abort**: the uplink stops. With something sent, a ``schedule_delete`` (PUS 11) from the
next 0.25 s grid tag ``T`` at least (delay + margin) ahead, for the pass's seqs, goes up
at once three times and then on the retransmission timer until the vehicle's
``verification`` arrives (:mod:`server.services.schedule_delete`); the arm holds at the last
target before ``T``. On the ground the pass's commands tagged at or after ``T`` and
those never sent become ``cancelled`` with the reason, in one ``commands_cancelled``
event; the vehicle's own word on a command (it executed after all, the delete arriving
late) overrules that. The telemetry window closes ``SETTLE_S`` (the runner) after ``T``. The link
down at the abort: ``T`` is chosen when it is back. Then ``aborted``; the stages of the
commands before ``T`` are resolved in the background as their tags pass.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from planner.plan import Plan
from server.services.clock import Clock
from server.services.command_stages import cancel_commands
from server.services.events import PassStartRefused, PassState, Recorded
from server.services.events import record as record_event
from server.services.link import GroundLink, RobotIdentity, TelemetryWindow, robot_mismatch
from server.services.tracker import CommandTracker
from server.services.uplink import Uplink
from server.settings import Settings
from server.storage import repository as repo
from server.storage.errors import Conflict
from server.storage.models import CommandRecord
from telemetry.uplink import GRID_NS, Command, plan_commands
from telemetry.wire import AcsCommandMsg, JointCommandMsg

__all__ = [
    "MAX_REFUSED_IN_A_ROW",
    "REFUSALS",
    "TRANSITIONS",
    "ActivePass",
    "RefusalStreak",
    "Started",
    "abort_job",
    "command_from_record",
    "new_uplink",
    "plan_robot",
    "start_job",
    "transition",
    "uplink_timing",
]

Job = Callable[[Session], list[Recorded]]

#: Allowed transitions: to -> the states it may come from.
TRANSITIONS = {
    "aos": {"scheduled"},
    "running": {"aos"},
    "los": {"running"},
    "complete": {"los"},
    "aborted": {"scheduled", "aos", "running", "los"},
    "safed": {"aos", "running", "los"},
}
#: Refusals that mean the arm no longer follows the plan, and how many in a row stop it
#: (2 s of joint commands).
REFUSALS = ("out_of_limits", "late")
MAX_REFUSED_IN_A_ROW = 8


def transition(
    session: Session,
    clock: Clock,
    pass_id: str,
    to: str,
    actor: str,
    reason: str,
    time_ns: int,
    epoch_ns: int | None = None,
    **window_ns: int | None,
) -> Recorded:
    record = repo.get_pass(session=session, pass_id=pass_id, refresh=True)
    if record.state not in TRANSITIONS[to]:
        raise Conflict(f"pass {record.name!r} is {record.state}; it cannot go {to}")
    previous = record.state
    record = repo.update_pass_state(
        session=session,
        pass_id=pass_id,
        expected_version=record.version,
        state=to,
        updated_at_ns=time_ns,
        reason=reason,
        epoch_ns=epoch_ns,
        telemetry_start_ns=window_ns.get("telemetry_start_ns"),
        telemetry_end_ns=window_ns.get("telemetry_end_ns"),
    )
    event = PassState(
        actor=actor,
        pass_id=record.id,
        from_state=previous,
        to=to,
        reason=reason,
        version=record.version,
        epoch_ns=epoch_ns,
    )
    return record_event(session, event, clock.time_ns())


def plan_robot(plan: Plan) -> RobotIdentity:
    """The robot ``plan`` was made for."""
    return RobotIdentity(plan.robot, plan.robot_hash, len(plan.initial_joints_rad))


def command_from_record(record: CommandRecord) -> Command:
    """The wire message a stored command was (or will be) sent as."""
    fields = {"seq": record.seq, "execute_time_ns": record.execute_time_ns, **record.payload}
    if record.kind == "joints":
        return JointCommandMsg.model_validate(fields)
    return AcsCommandMsg.model_validate(fields)


def uplink_timing(settings: Settings, link: GroundLink) -> dict[str, Any]:
    """An uplink's keywords besides its commands: the ground's delay, margin and lead
    window, the connected vehicle's schedule capacity and time scale."""
    return {
        "one_way_delay_s": settings.link_one_way_delay_s,
        "margin_s": settings.uplink_margin_s,
        "lead_window_s": settings.uplink_lead_window_s,
        "capacity": link.schedule_capacity,
        "time_scale": link.time_scale,
    }


def new_uplink(commands: list[Command], settings: Settings, link: GroundLink) -> Uplink:
    """The windowed uplink of a pass's ``commands`` to the vehicle now connected."""
    return Uplink(commands, **uplink_timing(settings, link))


@dataclass(frozen=True)
class Started:
    """A pass the start transaction made ``running``."""

    pass_id: str
    name: str
    commands: list[Command]
    robot: RobotIdentity


def _refusal(
    actor: str,
    pass_id: str,
    plan_id: str,
    robot: RobotIdentity,
    vehicle: RobotIdentity | None,
    message: str,
) -> PassStartRefused:
    """The audit event of a start refused for the robot."""
    return PassStartRefused(
        actor=actor,
        pass_id=pass_id,
        reason="robot_mismatch",
        message=message,
        plan_id=plan_id,
        plan_robot=robot.name,
        plan_robot_hash=robot.hash,
        plan_n_joints=robot.n_joints,
        vehicle_robot=None if vehicle is None else vehicle.name,
        vehicle_robot_hash=None if vehicle is None else vehicle.hash,
        vehicle_n_joints=None if vehicle is None else vehicle.n_joints,
    )


def start_job(
    *,
    pass_id: str,
    actor: str,
    link: GroundLink,
    clock: Clock,
    lead_s: float,
    telemetry_start_ns: int,
) -> Callable[[Session], tuple[list[Recorded], Started | None, str | None]]:
    """The start transaction: (events, the pass started or None, why it was refused). The
    plan's ``t = 0`` is put on the 0.25 s grid at most ``lead_s`` after onboard now (the
    start lead, :func:`server.operations.windows.start_lead_s`: it holds the onboard time
    of 1 s wall for this transaction and the grid step); its
    commands are queued with ``seq`` from one past the highest the vehicle or the archive
    has seen."""

    def job(session: Session) -> tuple[list[Recorded], Started | None, str | None]:
        record = repo.get_pass(session=session, pass_id=pass_id, refresh=True)
        plan = Plan.from_json(repo.get_plan(session=session, plan_id=record.plan_id).document)
        robot = plan_robot(plan)
        vehicle_robot = link.robot
        refusal = (
            "no hello from the spacecraft yet"
            if vehicle_robot is None
            else robot_mismatch(robot, vehicle_robot)
        )
        if refusal is not None:
            event = _refusal(actor, record.id, record.plan_id, robot, vehicle_robot, refusal)
            return [record_event(session, event, clock.time_ns())], None, refusal
        vehicle = link.vehicle or "spacecraft"
        now_wall = clock.time_ns()
        connected = f"{vehicle} connected"
        events = [transition(session, clock, record.id, "aos", actor, connected, now_wall)]
        now_ns = link.onboard_now_ns()
        epoch_ns = (now_ns + round(lead_s * 1e9)) // GRID_NS * GRID_NS
        used = session.scalar(select(func.max(CommandRecord.seq)))
        first_seq = max(-1 if used is None else used, link.last_command_seq) + 1
        commands = plan_commands(plan, epoch_ns=epoch_ns, first_seq=first_seq)
        repo.add_commands(
            session=session, pass_id=record.id, commands=commands, queued_at_ns=now_wall
        )
        reason = f"started: {len(commands)} commands from seq {first_seq}"
        events.append(
            transition(
                session,
                clock,
                record.id,
                "running",
                actor,
                reason,
                now_wall,
                epoch_ns,
                telemetry_start_ns=telemetry_start_ns,
            )
        )
        return events, Started(record.id, record.name, commands, robot), None

    return job


def abort_job(
    *,
    pass_id: str,
    actor: str,
    reason: str,
    clock: Clock,
    cancel: list[int] | None,
    from_ns: int | None,
    end_ns: int | None,
    to: str = "aborted",
) -> Job:
    """The abort transaction: ``cancel`` (None: a pass not running here, after a restart:
    every command not sent) becomes ``cancelled`` (one ``commands_cancelled`` event), then
    ``to`` (``aborted``, or ``safed`` when the vehicle safed itself; the telemetry window
    ending at ``end_ns``)."""
    why = reason if from_ns is None else f"{reason} (deleted from the schedule)"

    def job(session: Session) -> list[Recorded]:
        key = repo.get_pass(session=session, pass_id=pass_id, refresh=True).id
        now = clock.time_ns()
        events: list[Recorded] = []
        if cancel is None:
            rows = repo.list_commands(session=session, pass_id=key, stages=("queued",))
            seqs = [r.seq for r in rows]
        else:
            seqs = cancel
        if seqs:
            events += cancel_commands(
                session,
                clock=clock,
                pass_id=key,
                seqs=seqs,
                time_ns=now,
                actor=actor,
                reason=why,
                from_time_ns=from_ns,
            )
        events.append(
            transition(session, clock, key, to, actor, reason, now, telemetry_end_ns=end_ns)
        )
        return events

    return job


@dataclass
class RefusalStreak:
    """Joint commands the vehicle refused in a row (``out_of_limits`` or ``late``): at
    :data:`MAX_REFUSED_IN_A_ROW` the arm no longer follows the plan.

    A ``late`` refusal of a command first sent before the onboard clock was confirmed after
    a (re)connection (:attr:`~server.services.link.GroundLink.clock_confirmed`) is not
    counted: it says the hello was read late, which the refusal's own stamp corrects, not
    that the vehicle no longer follows the plan. It does not end a streak either."""

    count: int = 0
    #: seqs first sent on an unconfirmed onboard clock
    unconfirmed: set[int] = field(default_factory=set)
    #: ``late`` refusals not counted for that reason
    excused: int = 0

    def sent_unconfirmed(self, seq: int) -> None:
        self.unconfirmed.add(seq)

    def observe(self, stage: str, reason: str | None, seq: int) -> str | None:
        """One acknowledgement of a joint command; why the pass must stop, or None."""
        if stage == "rejected" and reason == "late" and seq in self.unconfirmed:
            self.excused += 1
            return None
        if stage == "executed":
            self.count = 0
        elif stage == "rejected" and reason in REFUSALS:
            self.count += 1
            if self.count >= MAX_REFUSED_IN_A_ROW:
                return (
                    f"the vehicle refused {self.count} commands in a row "
                    f"(last: {reason}, seq {seq}): the arm no longer follows the plan"
                )
        return None


@dataclass
class ActivePass:
    """A pass running here: its uplink, telemetry window and command tracker."""

    pass_id: str
    name: str
    uplink: Uplink
    window: TelemetryWindow
    tracker: CommandTracker
    last_tag_ns: int
    #: The highest seq of the pass (a ``schedule_delete`` covers up to it).
    max_seq: int
    #: The robot the pass's plan was made for.
    robot: RobotIdentity
    #: The first command's tag (the plan's t = 0 on board).
    first_tag_ns: int | None = None
    stop: asyncio.Event = field(default_factory=asyncio.Event)
    task: asyncio.Task[None] | None = None
    refusals: RefusalStreak = field(default_factory=RefusalStreak)
    #: Resumed after a restart: the previous process may have sent commands it had not yet
    #: recorded as sent, which this one then took as never sent (and expired).
    resumed: bool = False

    @classmethod
    def of(
        cls,
        pass_id: str,
        name: str,
        uplink: Uplink,
        window: TelemetryWindow,
        tracker: CommandTracker,
        tags: dict[int, int],
        robot: RobotIdentity,
        *,
        resumed: bool = False,
    ) -> ActivePass:
        """The pass's running state (``tags``: seq -> tag of all its commands)."""
        last_tag_ns, max_seq = max(tags.values()), max(tags)
        return cls(
            pass_id, name, uplink, window, tracker, last_tag_ns, max_seq, robot,
            first_tag_ns=min(tags.values()), resumed=resumed,
        )  # fmt: skip
