"""Recovery after a restart: what the archive says, and what to do about it.

:func:`load` reads (in a database job) the telemetry windows of the
:data:`RECOVERED_WINDOWS` most recent passes (late and resent frames still reach their pass)
and the passes a previous process left ``aos``, ``running`` or ``los``. :func:`decide` turns
them into decisions, frozen values the runner carries out: a pass left ``running`` or ``los``
(by a process killed, crashed, or stopped gracefully: a graceful stop hands the pass to the
vehicle and leaves it in its state, :meth:`server.services.runner.PassRunner.shutdown`) with
commands is resumed once the spacecraft is back; any other is aborted.
:func:`resume_refusal` says, when the link is up, why a resumable pass must be aborted after
all (another pass started first, another robot connected); a pass whose scheduled LOS comes
before any spacecraft is aborted too (:data:`NO_SPACECRAFT`).

A resumed pass's commands not final are loaded into a new uplink: those the earlier process
sent and the vehicle did not acknowledge are sent again at once (the vehicle answers a copy of
a command it holds with its stored acknowledgement), the rest as the window admits them,
unless the vehicle's schedule ran dry in mid-motion: then the rest is held
(:mod:`server.services.continuity`).

**Unresolved commands of ended passes** (:class:`UnresolvedPass`): a recent pass that ended
(``complete``, ``aborted``, ``safed``) with commands still ``sent`` or ``received`` (the
queries ran out, the service stopped while it was asking, or a pass aborted because no
spacecraft came before its LOS) has them asked about again once the vehicle is back: every
command's final stage is the vehicle's word, none stays ``sent`` or ``received`` for good.

A ``safed`` pass is final, as ``complete`` and ``aborted`` are: it is never resumed (only its
telemetry window is reopened). The vehicle's last on-board safing episode
(:class:`SafingEpisode`, from the last ``vehicle_safed`` or ``vehicle_safe_exited`` event)
is handed back to the link, so that a vehicle still safe continues that episode (and its
alarm) instead of beginning another; a pass left ``running`` whose vehicle safed itself
before the ground could file it is resumed and made ``safed`` by the vehicle's report
after its ``hello``.
"""

from __future__ import annotations

import asyncio
import json
from dataclasses import dataclass

from pydantic import ValidationError
from sqlalchemy import select
from sqlalchemy.orm import Session

from planner.plan import ETS7_ROBOT_HASH, ETS7_ROBOT_NAME
from server.services.clock import Clock
from server.services.link import (
    GroundLink,
    LinkEvent,
    LinkUp,
    RobotIdentity,
    TelemetryWindow,
    robot_mismatch,
)
from server.services.summary import ENDED_STATES
from server.services.tracker import LINK_DOWN_POLL_S
from server.storage import repository as repo
from server.storage.models import CommandRecord, EventRecord, PassRecord
from server.storage.stages import AWAITING_ACK_STAGES, is_final
from telemetry.wire import Safing

__all__ = [
    "NO_SPACECRAFT",
    "RECOVERED_WINDOWS",
    "AbortPass",
    "Decision",
    "Recovered",
    "ResumePass",
    "SafingEpisode",
    "UnfinishedPass",
    "UnresolvedPass",
    "decide",
    "document_robot",
    "last_safing",
    "load",
    "resume_refusal",
    "spacecraft_back",
]

#: Telemetry windows of this many recent passes are reopened after a restart.
RECOVERED_WINDOWS = 50
#: The audit log's events of the vehicle's safing episodes (server.services.events).
SAFING_EVENTS = ("vehicle_safed", "vehicle_safe_exited")
NO_SPACECRAFT = "ground service restarted mid-pass; no spacecraft before LOS"


def document_robot(document: str) -> RobotIdentity:
    """The robot of a stored plan document, without building the plan (a document without
    robot fields predates them: ETS-VII's)."""
    doc = json.loads(document)
    return RobotIdentity(
        str(doc.get("robot", ETS7_ROBOT_NAME)),
        str(doc.get("robot_hash", ETS7_ROBOT_HASH)),
        len(doc["initial_joints_rad"]),
    )


@dataclass(frozen=True)
class UnfinishedPass:
    """A pass the previous process left ``aos``, ``running`` or ``los``."""

    id: str
    name: str
    state: str
    los_time_ns: int
    start_ns: int | None
    commands: tuple[CommandRecord, ...]
    robot: RobotIdentity

    @property
    def pending(self) -> tuple[CommandRecord, ...]:
        """Its commands not final."""
        return tuple(r for r in self.commands if not is_final(r.stage))

    @property
    def transmitted(self) -> dict[int, tuple[int, bool]]:
        """seq -> (transmissions, received) of the commands sent and not final."""
        return {
            r.seq: (r.transmissions, r.stage == "received")
            for r in self.commands
            if r.stage in AWAITING_ACK_STAGES
        }


@dataclass(frozen=True)
class UnresolvedPass:
    """A pass that ended with commands whose fate the ground does not know (``commands``:
    every one of the pass's, the tracker's starting point)."""

    id: str
    state: str
    commands: tuple[CommandRecord, ...]

    @property
    def unresolved(self) -> int:
        return sum(1 for r in self.commands if r.stage in AWAITING_ACK_STAGES)


@dataclass(frozen=True)
class SafingEpisode:
    """The vehicle's last safing episode as the audit log has it: its entry (``report``
    ``safe``) or the exit that ended it (``nominal``), and the pass it stopped."""

    report: Safing
    pass_id: str | None


@dataclass(frozen=True)
class Recovered:
    windows: tuple[TelemetryWindow, ...]
    unfinished: tuple[UnfinishedPass, ...]
    safing: SafingEpisode | None = None
    unresolved: tuple[UnresolvedPass, ...] = ()


@dataclass(frozen=True)
class ResumePass:
    unfinished: UnfinishedPass


@dataclass(frozen=True)
class AbortPass:
    pass_id: str
    reason: str


Decision = ResumePass | AbortPass


def load(session: Session) -> Recovered:
    """The database job: recent windows and unfinished passes."""
    recent = session.scalars(
        select(PassRecord)
        .where(PassRecord.telemetry_start_ns.is_not(None))
        .order_by(PassRecord.telemetry_start_ns.desc())
        .limit(RECOVERED_WINDOWS)
    ).all()
    windows = tuple(
        TelemetryWindow(r.id, start_ns=r.telemetry_start_ns or 0, end_ns=r.telemetry_end_ns)
        for r in reversed(recent)
    )
    records = session.scalars(
        select(PassRecord).where(PassRecord.state.in_(("aos", "running", "los")))
    ).all()
    unfinished = tuple(
        UnfinishedPass(
            id=record.id,
            name=record.name,
            state=record.state,
            los_time_ns=record.los_time_ns,
            start_ns=record.telemetry_start_ns,
            commands=tuple(repo.list_commands(session=session, pass_id=record.id)),
            robot=document_robot(repo.get_plan(session=session, plan_id=record.plan_id).document),
        )
        for record in records
    )
    ended = [r for r in recent if r.state in ENDED_STATES]
    waiting = set(
        session.scalars(
            select(CommandRecord.pass_id)
            .where(
                CommandRecord.pass_id.in_([r.id for r in ended]),
                CommandRecord.stage.in_(AWAITING_ACK_STAGES),
            )
            .distinct()
        ).all()
    )
    unresolved = tuple(
        UnresolvedPass(r.id, r.state, tuple(repo.list_commands(session=session, pass_id=r.id)))
        for r in ended
        if r.id in waiting
    )
    return Recovered(windows, unfinished, last_safing(session), unresolved)


def last_safing(session: Session) -> SafingEpisode | None:
    """The last ``vehicle_safed`` or ``vehicle_safe_exited`` event as a report (None: no
    episode, or one whose detail no longer reads as a report)."""
    row = session.scalars(
        select(EventRecord)
        .where(EventRecord.kind.in_(SAFING_EVENTS))
        .order_by(EventRecord.time_ns.desc(), EventRecord.id.desc())
        .limit(1)
    ).first()
    if row is None:
        return None
    detail = row.detail
    since = detail.get("since_time_ns")
    try:
        if row.kind == "vehicle_safed":
            report = Safing(
                state="safe",
                since_time_ns=since,
                trigger=detail.get("trigger"),
                cancelled=detail.get("cancelled", 0),
                onboard_time_ns=detail.get("onboard_time_ns") or since or 0,
            )
        else:
            report = Safing(
                state="nominal",
                since_time_ns=since,
                exit_request_id=detail.get("request_id"),
                onboard_time_ns=detail.get("onboard_time_ns") or 0,
            )
    except ValidationError:
        return None
    return SafingEpisode(report, row.pass_id)


def decide(unfinished: tuple[UnfinishedPass, ...], *, running: bool) -> tuple[Decision, ...]:
    """Resume or abort each unfinished pass (``running``: a pass already runs here)."""
    decisions: list[Decision] = []
    for p in unfinished:
        if running or p.state == "aos" or not p.commands:
            reason = "ground service restarted before the pass was running"
            if running:
                reason = "ground service restarted with another pass to resume"
            decisions.append(AbortPass(p.id, reason))
        else:
            decisions.append(ResumePass(p))
    return tuple(decisions)


def resume_refusal(
    p: UnfinishedPass, *, running: bool, vehicle: RobotIdentity | None
) -> str | None:
    """Why ``p`` must not resume now that the spacecraft is back, or None."""
    if running:
        return "another pass started first"
    refusal = None if vehicle is None else robot_mismatch(p.robot, vehicle)
    return None if refusal is None else f"ground service restarted mid-pass; {refusal}"


async def spacecraft_back(
    p: UnfinishedPass, *, link: GroundLink, clock: Clock, closing: asyncio.Event
) -> str | None:
    """Wait for the spacecraft (or ``closing``); why ``p`` must be aborted instead
    (:data:`NO_SPACECRAFT`: its scheduled LOS came first), or None."""
    back = asyncio.Event()

    def on_event(event: LinkEvent) -> None:
        if isinstance(event, LinkUp):
            back.set()

    unsubscribe = link.add_listener(on_event)
    try:
        while not link.connected and not closing.is_set():
            if clock.time_ns() > p.los_time_ns:
                return NO_SPACECRAFT
            back.clear()
            await clock.sleep_until(clock.monotonic() + LINK_DOWN_POLL_S, back)
        return None
    finally:
        unsubscribe()
