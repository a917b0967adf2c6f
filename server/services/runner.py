"""Passes: the state machine and the windowed uplink of their commands.

    scheduled -> aos -> running -> los -> complete
    scheduled | aos | running | los -> aborted

Every transition is a compare-and-set on the pass's version (``update_pass_state``) and an
event ``pass_state`` (actor, from, to, reason) in the same transaction. All timing reads
the injected :class:`~server.services.clock.Clock` (``SystemClock`` in the service, a
``ManualClock`` in the unit tests), so the rules below are tested in simulated time.

**Start** (needs a connected spacecraft with a known clock, flying the robot the plan was
made for): ``aos`` then ``running`` in one transaction. A plan made for another robot (its
description's hash, or its joint count, differs from what the vehicle's ``hello`` announced;
a ``hello`` naming no robot is ETS-VII's) is refused 409 ``robot_mismatch`` with both robots
named, and the refusal is audited (``pass_start_refused``); the pass stays ``scheduled``.
The plan's ``t = 0`` is put at ``epoch_ns`` = onboard now + the start lead
(``uplink_start_lead_s``, at least one-way delay + margin) + the onboard time of 1 s wall
for the start transaction, rounded up to the 0.25 s grid, so that even the first command
can be sent again before its tag if the relay loses it. The plan's joint and ACS commands
are queued with ``seq`` from one past the highest the vehicle or the archive has seen, in
tag order. The pass's telemetry window opens at onboard now.

**Uplink** (:mod:`server.services.uplink`): the onboard schedule is kept loaded
``uplink_lead_window_s`` ahead of the onboard clock, within the vehicle's schedule
capacity; every command is sent again on its retransmission timer until the vehicle
acknowledges it, as long as it can still arrive (one-way delay + half the margin before its
tag); a command never sent that can no longer arrive is ``expired``. Stages ``released``
and ``sent`` (ground times) are written at the first transmission, the count of
transmissions with them and after retransmissions. The runner wakes at the next timer,
the next command entering the window, or any typed link event (acknowledgement, link up).

**Completion**: at the last tag + :data:`SETTLE_S` onboard the pass goes ``los`` (the
telemetry window closes there); commands whose tag has passed without a final
acknowledgement are asked about (``command_query``, up to :data:`MAX_COMMAND_QUERIES`
times: acks lost on the downlink come again, commands lost on the uplink come back
``command_unknown`` and expire); once no command is left ``sent`` or ``received`` (or
the queries are used up) it is ``complete``.

**Abort**: the uplink stops. With something sent, a ``schedule_delete`` (PUS 11) from the
next 0.25 s grid tag ``T`` at least (delay + margin) ahead, for the pass's seqs, goes up
at once three times and then on the retransmission timer until the vehicle's
``verification`` arrives; the arm holds at the last target before ``T`` (the vehicle
ramps to it and stops). On the ground the pass's commands tagged at or after ``T`` and
those never sent become ``cancelled`` with the reason, in one ``commands_cancelled``
event; the vehicle's own word on a command (it executed after all, the delete arriving
late) overrules that. The telemetry window closes :data:`SETTLE_S` after ``T``. The link
down at the abort: ``T`` is chosen when it is back. Then ``aborted``; the stages of the
commands before ``T`` are resolved in the background as their tags pass.

**Another robot mid-pass**: when the vehicle greets again (a new ``hello``) naming another
robot than the running pass's plan, the uplink stops at once (no command of the plan goes to
it) and the pass is aborted with that reason. A pass resumed after a restart is checked the
same way before its uplink starts.

**Restart**: :meth:`PassRunner.recover` reopens the telemetry windows stored on the
passes and resumes a pass left ``running`` or ``los`` by a process that did not shut
down (a graceful stop aborts the running pass instead). Its commands not final are loaded
into a new uplink: those the earlier process sent and the vehicle did not acknowledge are
sent again at once (the vehicle answers a copy of a command it holds with its stored
acknowledgement), the rest as the window admits them.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TypeVar

from sqlalchemy import func, select, update
from sqlalchemy.orm import Session

from planner.plan import ETS7_ROBOT_HASH, ETS7_ROBOT_NAME, Plan
from server.services.clock import Clock
from server.services.command_stages import cancel_commands, set_command_stage, write_event
from server.services.dbworker import done_unless
from server.services.errors import ConflictError
from server.services.link import (
    CommandAcked,
    GroundLink,
    LinkEvent,
    LinkUnavailable,
    LinkUp,
    RequestVerified,
    RobotIdentity,
    TelemetryWindow,
    robot_mismatch,
)
from server.services.uplink import RttEstimator, Uplink, UplinkCommand
from server.settings import Settings
from server.storage import repository as repo
from server.storage._common import canonical_id
from server.storage.errors import Conflict
from server.storage.models import CommandRecord, PassRecord
from telemetry.uplink import GRID_NS, Command, plan_commands
from telemetry.wire import AcsCommandMsg, JointCommandMsg, ScheduleDelete, Verification

__all__ = ["TRANSITIONS", "PassRunner", "plan_commands"]

T = TypeVar("T")

log = logging.getLogger("hikoboshi.ground.runner")

#: Allowed transitions: to -> the states it may come from.
TRANSITIONS = {
    "aos": {"scheduled"},
    "running": {"aos"},
    "los": {"running"},
    "complete": {"los"},
    "aborted": {"scheduled", "aos", "running", "los"},
}
#: Wall s allowed for the start transaction itself (its first use of a fresh PostgreSQL
#: connection can take a few hundred ms: at 20x that is seconds onboard).
START_SLACK_WALL_S = 1.0
SETTLE_S = 2.0  # onboard s after the last tag before LOS
#: Commands per database job of stage writes (an operator's control job waits for one).
STAGE_JOB_COMMANDS = 16
#: Refusals that mean the arm no longer follows the plan, and how many in a row stop it
#: (2 s of joint commands).
REFUSALS = ("out_of_limits", "late")
MAX_REFUSED_IN_A_ROW = 8
#: After LOS, ask the vehicle about unacknowledged commands at most this many times (under
#: 20 % loss each way one round is lost with p = 0.36; twenty rounds all with p < 1e-8).
MAX_COMMAND_QUERIES = 20
#: Rounds of asking about a resumed pass's ``expired`` commands (answers to expired ones
#: the vehicle never had change nothing, so there is no telling when all have come).
EXPIRED_QUERIES = 2
#: A pass starts late enough for its first command to go up this many times (the first
#: timeout, before any round-trip sample) before its last chance.
START_TRANSMISSIONS = 3
#: Telemetry windows of this many recent passes are reopened after a restart.
RECOVERED_WINDOWS = 50
#: Copies of a ``schedule_delete`` sent at once (then one per retransmission timeout).
DELETE_COPIES = 3
#: Ground s between looks while the link is down.
LINK_DOWN_POLL_S = 0.5


def _transition(
    session: Session,
    pass_id: str,
    to: str,
    actor: str,
    reason: str,
    time_ns: int,
    epoch_ns: int | None = None,
    **window_ns: int | None,
) -> dict[str, Any]:
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
    detail: dict[str, Any] = {"from": previous, "to": to, "reason": reason}
    detail["version"] = record.version
    if epoch_ns is not None:
        detail["epoch_ns"] = epoch_ns
    return write_event(session, "pass_state", actor, detail, record.id)


def plan_robot(plan: Plan) -> RobotIdentity:
    """The robot ``plan`` was made for."""
    return RobotIdentity(plan.robot, plan.robot_hash, len(plan.initial_joints_rad))


def _document_robot(document: str) -> RobotIdentity:
    """The robot of a stored plan document, without building the plan (a document without
    robot fields predates them: ETS-VII's)."""
    doc = json.loads(document)
    return RobotIdentity(
        str(doc.get("robot", ETS7_ROBOT_NAME)),
        str(doc.get("robot_hash", ETS7_ROBOT_HASH)),
        len(doc["initial_joints_rad"]),
    )


def command_from_record(record: CommandRecord) -> Command:
    """The wire message a stored command was (or will be) sent as."""
    fields = {"seq": record.seq, "execute_time_ns": record.execute_time_ns, **record.payload}
    if record.kind == "joints":
        return JointCommandMsg.model_validate(fields)
    return AcsCommandMsg.model_validate(fields)


def _event_job(
    kind: str, detail: dict[str, Any], pass_id: str
) -> Callable[[Session], list[dict[str, Any]]]:
    return lambda session: [write_event(session, kind, "ground", detail, pass_id)]


@dataclass
class _Active:
    pass_id: str
    name: str
    uplink: Uplink
    window: TelemetryWindow
    last_tag_ns: int
    #: The lowest and highest seq of the pass (a ``schedule_delete`` covers up to it).
    min_seq: int
    max_seq: int
    #: The robot the pass's plan was made for.
    robot: RobotIdentity
    stop: asyncio.Event = field(default_factory=asyncio.Event)
    task: asyncio.Task[None] | None = None
    refused_in_a_row: int = 0
    #: Resumed after a restart: the previous process may have sent commands it had not yet
    #: recorded as sent, which this one then took as never sent (and expired).
    resumed: bool = False


@dataclass
class _Delete:
    """A ``schedule_delete`` on its way: retransmitted until verified."""

    pass_id: str
    request: ScheduleDelete | None  # None: the link was down, T not chosen yet
    min_seq: int
    max_seq: int
    reason: str
    actor: str
    rtt: RttEstimator
    verified: asyncio.Event = field(default_factory=asyncio.Event)
    report: Verification | None = None
    sends: int = 0


class PassRunner:
    def __init__(self, *, link: GroundLink, settings: Settings, clock: Clock | None = None):
        self._link = link
        self._clock: Clock = clock or link.clock
        self._settings = settings
        self._delay_s = settings.link_one_way_delay_s
        self._margin_s = settings.uplink_margin_s
        self._lead_ns = round((settings.link_one_way_delay_s + settings.uplink_margin_s) * 1e9)
        self._active: _Active | None = None
        self._lock = asyncio.Lock()
        self._wake = asyncio.Event()
        self._diverged: asyncio.Task[None] | None = None
        self._background: set[asyncio.Task[Any]] = set()
        self._deletes: dict[int, _Delete] = {}  # request id -> delete
        self._closing = asyncio.Event()
        #: onboard s between each command's ``received`` and its tag, of the last pass
        self.fill_margins_s: list[float] = []
        link.add_listener(self._on_link_event)
        link.set_uplink_status(self.uplink_status)

    # -- link events ---------------------------------------------------------------------

    def _on_link_event(self, event: LinkEvent) -> None:
        active = self._active
        if isinstance(event, CommandAcked):
            if active is None:
                return
            first = active.uplink.on_ack(
                event.seq, event.reason, event.onboard_time_ns, event.read_mono
            )
            if event.stage == "executed" or (event.stage == "rejected" and first):
                self._watch(active, event)
            if first or event.reason == "schedule_full":
                self._wake.set()
        elif isinstance(event, RequestVerified):
            delete = self._deletes.get(event.report.request_id)
            if delete is not None and delete.report is None:
                delete.report = event.report
                delete.verified.set()
        elif isinstance(event, LinkUp):
            if active is not None and not active.stop.is_set():
                refusal = robot_mismatch(active.robot, RobotIdentity.of_hello(event.hello))
                if refusal is not None:
                    self._foreign_vehicle(active, refusal)
            self._wake.set()

    def _watch(self, active: _Active, ack: CommandAcked) -> None:
        """Stop a pass the vehicle no longer follows: :data:`MAX_REFUSED_IN_A_ROW` joint
        commands refused in a row (``out_of_limits`` or ``late``). The plan cannot continue
        from there; the pass is aborted (the schedule deleted, the arm held)."""
        cmd = active.uplink.by_seq.get(ack.seq)
        if cmd is None or not isinstance(cmd.command, JointCommandMsg):
            return
        if ack.stage == "executed":
            active.refused_in_a_row = 0
        elif ack.stage == "rejected" and ack.reason in REFUSALS:
            active.refused_in_a_row += 1
            if active.refused_in_a_row >= MAX_REFUSED_IN_A_ROW and self._diverged is None:
                reason = (
                    f"the vehicle refused {active.refused_in_a_row} commands in a row "
                    f"(last: {ack.reason}, seq {ack.seq}): the arm no longer follows the plan"
                )
                self._diverged = asyncio.get_running_loop().create_task(
                    self._abort_diverged(active, reason)
                )

    def _foreign_vehicle(self, active: _Active, refusal: str) -> None:
        """The vehicle now connected flies another robot: nothing more of the plan goes up
        (the uplink stops before the runner can wake), and the pass is aborted."""
        active.uplink.stop()
        log.warning("pass %s: %s", active.pass_id, refusal)
        if self._diverged is None:
            self._diverged = asyncio.get_running_loop().create_task(
                self._abort_diverged(active, f"another robot connected mid-pass: {refusal}")
            )

    async def _abort_diverged(self, active: _Active, reason: str) -> None:
        try:
            await self.abort(active.pass_id, "ground", reason)
        except Exception:
            log.exception("pass %s: abort after divergence failed", active.pass_id)
        finally:
            self._diverged = None

    @property
    def resolving(self) -> bool:
        """Whether the stages of an aborted pass's last commands are still being resolved."""
        return bool(self._background)

    @property
    def active_pass_id(self) -> str | None:
        return None if self._active is None else self._active.pass_id

    def uplink_status(self) -> dict[str, Any] | None:
        active = self._active
        if active is None:
            return None
        onboard = self._link.onboard_now_ns() if self._link.connected else None
        return {"pass_id": active.pass_id, **active.uplink.status(onboard)}

    def _new_uplink(self, commands: list[Command]) -> Uplink:
        link = self._link
        return Uplink(
            commands,
            one_way_delay_s=self._delay_s,
            margin_s=self._margin_s,
            lead_window_s=self._settings.uplink_lead_window_s,
            capacity=link.schedule_capacity,
            time_scale=link.time_scale,
        )

    # -- start ---------------------------------------------------------------------------

    async def start(self, pass_id: str, actor: str) -> None:
        async with self._lock:
            if self._active is not None:
                raise Conflict(f"pass {self._active.name!r} is running; one pass at a time")
            link = self._link
            if not link.connected:
                raise LinkUnavailable("no spacecraft is connected: a pass needs the link")
            clock = self._clock
            # The window opens before the start transaction: storing thousands of commands
            # takes longer than the relay delay at high time scales, and the frames
            # generated meanwhile must already find their pass.
            window = link.open_window(canonical_id(pass_id, what="pass"), link.onboard_now_ns())
            # onboard s: the first command's last chance, then its first copies before it
            first_rto_s = RttEstimator(2 * self._delay_s / link.time_scale).rto_s
            lead_s = max(
                self._settings.uplink_start_lead_s,
                self._lead_ns / 1e9 + START_TRANSMISSIONS * first_rto_s * link.time_scale,
            )

            def job(
                session: Session,
            ) -> tuple[list[dict[str, Any]], list[Command], _Active | None, str | None]:
                record = repo.get_pass(session=session, pass_id=pass_id, refresh=True)
                plan = Plan.from_json(
                    repo.get_plan(session=session, plan_id=record.plan_id).document
                )
                robot = plan_robot(plan)
                vehicle_robot = link.robot
                refusal = (
                    "no hello from the spacecraft yet"
                    if vehicle_robot is None
                    else robot_mismatch(robot, vehicle_robot)
                )
                if refusal is not None:
                    detail = {
                        "reason": "robot_mismatch",
                        "message": refusal,
                        "plan_id": record.plan_id,
                        "plan_robot": robot.name,
                        "plan_robot_hash": robot.hash,
                        "plan_n_joints": robot.n_joints,
                        "vehicle_robot": None if vehicle_robot is None else vehicle_robot.name,
                        "vehicle_robot_hash": None if vehicle_robot is None else vehicle_robot.hash,
                        "vehicle_n_joints": (
                            None if vehicle_robot is None else vehicle_robot.n_joints
                        ),
                    }
                    event = write_event(session, "pass_start_refused", actor, detail, record.id)
                    return [event], [], None, refusal
                vehicle = link.vehicle or "spacecraft"
                now_wall = clock.time_ns()
                events = [
                    _transition(session, record.id, "aos", actor, f"{vehicle} connected", now_wall)
                ]
                now_ns = link.onboard_now_ns()
                slack_s = lead_s + START_SLACK_WALL_S * link.time_scale
                epoch_ns = math.ceil((now_ns + round(slack_s * 1e9)) / GRID_NS) * GRID_NS
                used = session.scalar(select(func.max(CommandRecord.seq)))
                first_seq = max(-1 if used is None else used, link.last_command_seq) + 1
                commands = plan_commands(plan, epoch_ns=epoch_ns, first_seq=first_seq)
                repo.add_commands(
                    session=session, pass_id=record.id, commands=commands, queued_at_ns=now_wall
                )
                reason = f"started: {len(commands)} commands from seq {first_seq}"
                events.append(
                    _transition(
                        session,
                        record.id,
                        "running",
                        actor,
                        reason,
                        now_wall,
                        epoch_ns,
                        telemetry_start_ns=window.start_ns,
                    )
                )
                seqs = [c.seq for c in commands]
                active = _Active(
                    record.id,
                    record.name,
                    self._new_uplink(commands),
                    window,
                    last_tag_ns=max(c.execute_time_ns for c in commands),
                    min_seq=min(seqs),
                    max_seq=max(seqs),
                    robot=robot,
                )
                return events, commands, active, None

            try:
                events, commands, started, refusal = await link.db.run(job)
            except BaseException:
                link.drop_window(window)
                raise
            link.publisher.publish(events)
            if started is None:
                link.drop_window(window)
                raise ConflictError(
                    "robot_mismatch", refusal or "robot mismatch", events[0].get("detail")
                )
            active = started
            link.expect_commands(active.pass_id, [c.seq for c in commands])
            self._begin(active, self._run(active))

    def _begin(self, active: _Active, body: Any) -> None:
        self._active = active
        self.fill_margins_s = []
        active.task = asyncio.create_task(body, name=f"pass-{active.pass_id}")

    # -- the uplink loop -----------------------------------------------------------------

    async def _run(self, active: _Active) -> None:
        link = self._link
        try:
            los_ns = active.last_tag_ns + round(SETTLE_S * 1e9)
            while not active.stop.is_set():
                self._wake.clear()
                wake_at = await self._uplink_step(active)
                if link.connected and link.onboard_now_ns() >= los_ns:
                    break
                if link.connected:
                    wake_at = min(wake_at, link.mono_at_onboard(los_ns))
                await self._clock.sleep_until(wake_at, self._wake)
            if active.stop.is_set():
                return
            # The stage writes queued so far, unless an abort comes meanwhile: on a loaded
            # database they take seconds, and the abort waits for this task.
            await link.db.barrier(until=active.stop)
            # No lock from here: abort() holds it while it waits for this task. Between
            # the stop check and the write there is no await, and abort() transitions
            # only after this task has ended, from whatever state it left.
            if active.stop.is_set():
                return
            self.fill_margins_s = active.uplink.fill_margins_s()
            end = link.onboard_now_ns()
            link.close_window(active.window, end)
            reason = f"last command's tag + {SETTLE_S} s passed"
            now_wall = self._clock.time_ns()
            await link.db.write(
                lambda s: [
                    _transition(
                        s, active.pass_id, "los", "ground", reason, now_wall, telemetry_end_ns=end
                    )
                ]
            )
            await self._finish(active)
        except Exception:
            log.exception("pass %s: the runner failed", active.pass_id)
            with contextlib.suppress(Exception):
                await self._abort_locked(active.pass_id, "ground", "runner failure")
            raise

    async def _uplink_step(self, active: _Active) -> float:
        """Expire, send what is due; the ground monotonic instant to look again."""
        link, clock, up = self._link, self._clock, active.uplink
        if not link.connected:
            # The onboard clock is still known from the last hello: what can no longer
            # arrive expires; the rest waits for the link.
            with contextlib.suppress(LinkUnavailable):
                self._record_expired(active, up.expire(link.onboard_now_ns()))
            return clock.monotonic() + LINK_DOWN_POLL_S
        onboard = link.onboard_now_ns()
        self._record_expired(active, up.expire(onboard))
        batch = up.due(clock.monotonic(), onboard)
        first: list[tuple[UplinkCommand, int]] = []
        again: list[UplinkCommand] = []
        released_ns = clock.time_ns()
        for i, cmd in enumerate(batch):
            # an abort stops a long batch (retransmissions after a stall) between sends
            if active.stop.is_set() or not await link.send_command(cmd.command):
                for rest in reversed(batch[i:]):
                    up.unsent(rest)
                break
            if up.sent(cmd, clock.monotonic(), link.onboard_now_ns()):
                again.append(cmd)
            else:
                first.append((cmd, clock.time_ns()))
        if first or again:
            self._record_sent(active, released_ns, first, again)
        return up.next_wake(link.mono_at_onboard)

    def _record_sent(
        self,
        active: _Active,
        released_ns: int,
        first: list[tuple[UplinkCommand, int]],
        again: list[UplinkCommand],
    ) -> None:
        pass_id = active.pass_id
        counts = [(c.seq, c.transmissions) for c in again]
        # In jobs of STAGE_JOB_COMMANDS: an operator's control job waits for the job in
        # progress, and the start's first batch (hundreds of commands, three statements
        # each) took 4-5 s in one job on a loaded PostgreSQL.
        for lo in range(0, max(len(first), len(counts)), STAGE_JOB_COMMANDS):
            hi = lo + STAGE_JOB_COMMANDS
            self._link.db.submit(self._sent_job(pass_id, released_ns, first[lo:hi], counts[lo:hi]))

    @staticmethod
    def _sent_job(
        pass_id: str,
        released_ns: int,
        first: list[tuple[UplinkCommand, int]],
        counts: list[tuple[int, int]],
    ) -> Callable[[Session], list[dict[str, Any]]]:
        def job(session: Session) -> list[dict[str, Any]]:
            events: list[dict[str, Any]] = []
            for cmd, sent_ns in first:
                for stage, at_ns in (("released", released_ns), ("sent", sent_ns)):
                    events += set_command_stage(
                        session,
                        pass_id=pass_id,
                        seq=cmd.seq,
                        stage=stage,
                        time_ns=at_ns,
                        actor="ground",
                        transmissions=1,
                    )
            for seq, n in counts:
                session.execute(
                    update(CommandRecord)
                    .where(
                        CommandRecord.pass_id == pass_id,
                        CommandRecord.seq == seq,
                        CommandRecord.transmissions < n,
                    )
                    .values(transmissions=n)
                )
            return events

        return job

    def _record_expired(self, active: _Active, expired: list[UplinkCommand]) -> None:
        if not expired:
            return
        pass_id = active.pass_id
        now_ns = self._clock.time_ns()
        for lo in range(0, len(expired), STAGE_JOB_COMMANDS):
            seqs = [c.seq for c in expired[lo : lo + STAGE_JOB_COMMANDS]]
            self._link.db.submit(self._expired_job(pass_id, now_ns, seqs))

    @staticmethod
    def _expired_job(
        pass_id: str, now_ns: int, seqs: list[int]
    ) -> Callable[[Session], list[dict[str, Any]]]:
        def job(session: Session) -> list[dict[str, Any]]:
            events: list[dict[str, Any]] = []
            for seq in seqs:
                events += set_command_stage(
                    session,
                    pass_id=pass_id,
                    seq=seq,
                    stage="expired",
                    time_ns=now_ns,
                    actor="ground",
                    detail="could not be sent early enough to arrive before its tag",
                )
            return events

        return job

    async def _finish(self, active: _Active) -> None:
        """After LOS: wait for the last acknowledgements, asking the vehicle about commands
        whose tag has passed without one, then ``complete``."""
        left = await self._resolve_outstanding(
            active.pass_id, active.stop, ask_expired=active.resumed
        )
        if active.stop.is_set():
            return
        reason = "every command acknowledged" if not left else f"{left} unacknowledged"
        now_wall = self._clock.time_ns()
        await self._link.db.write(
            lambda s: [_transition(s, active.pass_id, "complete", "ground", reason, now_wall)]
        )
        if self._active is active:
            self._active = None

    async def _read_unless(self, job: Callable[[Session], T], stop: asyncio.Event) -> T | None:
        """Run the read-only ``job`` on the link's database worker, unless ``stop`` is set
        first (None): behind a backlog of stage writes it can wait seconds, and an abort
        waits for the pass's task. The job itself may still run; it writes nothing."""
        if stop.is_set():
            return None
        read = asyncio.ensure_future(self._link.db.run(job))
        if await done_unless(read, stop):
            return read.result()
        read.cancel()
        return None

    async def _resolve_outstanding(
        self, pass_id: str, stop: asyncio.Event, *, ask_expired: bool = False
    ) -> int:
        """Ask the vehicle (``command_query``: acks lost on the downlink, commands lost on
        the uplink) about the pass's commands still ``sent`` or ``received`` once their tag
        has passed, up to :data:`MAX_COMMAND_QUERIES` times; how many are left unresolved.

        ``ask_expired`` (a pass resumed after a restart): also ask, once, about the commands
        taken as ``expired``: the vehicle's own word (``executed``) replaces the guess."""
        link, clock = self._link, self._clock
        if ask_expired:
            await self._ask_about_expired(pass_id, stop)
        # Onboard s between queries: a round trip and a second to answer.
        period_ns = round((2 * self._delay_s + 1.0) * 1e9)
        poll_s = 0.05

        def outstanding(session: Session) -> list[tuple[int, int]]:
            rows = repo.list_commands(
                session=session, pass_id=pass_id, stages=("released", "sent", "received")
            )
            return [(r.seq, r.execute_time_ns) for r in rows]

        left = await self._read_unless(outstanding, stop) or []
        queries = 0
        next_query = clock.monotonic()
        while left and queries < MAX_COMMAND_QUERIES and not stop.is_set():
            if clock.monotonic() >= next_query:
                if link.connected:
                    due = [seq for seq, tag in left if tag < link.onboard_now_ns()]
                    if due and await link.query_commands(due):
                        queries += 1
                    next_query = link.mono_at_onboard(link.onboard_now_ns() + period_ns)
                else:
                    next_query = clock.monotonic() + poll_s
            await clock.sleep_until(clock.monotonic() + poll_s, stop)
            left = await self._read_unless(outstanding, stop) or []
        if left and not stop.is_set() and queries:
            # the last answers are a round trip away
            with contextlib.suppress(LinkUnavailable):
                await clock.sleep_until(
                    link.mono_at_onboard(link.onboard_now_ns() + period_ns), stop
                )
            left = await self._read_unless(outstanding, stop) or []
        return len(left)

    async def _ask_about_expired(self, pass_id: str, stop: asyncio.Event) -> None:
        link, clock = self._link, self._clock

        def expired(session: Session) -> list[int]:
            rows = repo.list_commands(session=session, pass_id=pass_id, stages=("expired",))
            return [r.seq for r in rows]

        period_ns = round((2 * self._delay_s + 1.0) * 1e9)
        for _ in range(EXPIRED_QUERIES):  # the relay may lose one
            seqs = await link.db.run(expired)
            if not seqs or stop.is_set() or not link.connected:
                return
            if await link.query_commands(seqs):
                # the answers are a round trip away (acks replace the guess)
                with contextlib.suppress(LinkUnavailable):
                    await clock.sleep_until(
                        link.mono_at_onboard(link.onboard_now_ns() + period_ns), stop
                    )
                await link.db.barrier(until=stop)

    def _background_task(self, coro: Any) -> None:
        task = asyncio.get_running_loop().create_task(coro)
        self._background.add(task)
        task.add_done_callback(self._background.discard)

    # -- recovery after a restart --------------------------------------------------------

    async def recover(self) -> None:
        """After the service (re)starts: reopen the telemetry windows of recent passes (late
        and resent frames still reach their pass), and resume a pass the previous process
        left ``running`` or ``los`` (it stopped without shutting down: killed, crashed), once
        the spacecraft is back (see the module docstring). No spacecraft before the pass's
        scheduled LOS: the pass is aborted with that reason."""
        link = self._link

        def job(session: Session) -> tuple[list[TelemetryWindow], list[dict[str, Any]]]:
            recent = session.scalars(
                select(PassRecord)
                .where(PassRecord.telemetry_start_ns.is_not(None))
                .order_by(PassRecord.telemetry_start_ns.desc())
                .limit(RECOVERED_WINDOWS)
            ).all()
            windows = [
                TelemetryWindow(r.id, start_ns=r.telemetry_start_ns or 0, end_ns=r.telemetry_end_ns)
                for r in reversed(recent)
            ]
            unfinished = session.scalars(
                select(PassRecord).where(PassRecord.state.in_(("aos", "running", "los")))
            ).all()
            found = []
            for record in unfinished:
                rows = repo.list_commands(session=session, pass_id=record.id)
                document = repo.get_plan(session=session, plan_id=record.plan_id).document
                found.append(
                    {
                        "id": record.id,
                        "name": record.name,
                        "state": record.state,
                        "los_time_ns": record.los_time_ns,
                        "start_ns": record.telemetry_start_ns,
                        "commands": rows,
                        "robot": _document_robot(document),
                    }
                )
            return windows, found

        windows, unfinished = await link.db.run(job)
        opened = {w.pass_id: link.open_window(w.pass_id, w.start_ns, w.end_ns) for w in windows}
        for info in unfinished:
            if self._active is not None or info["state"] == "aos" or not info["commands"]:
                reason = "ground service restarted before the pass was running"
                if self._active is not None:
                    reason = "ground service restarted with another pass to resume"
                await self._abort_locked(info["id"], "ground", reason)
                continue
            rows: list[CommandRecord] = info["commands"]
            link.expect_commands(info["id"], [r.seq for r in rows])
            window = opened.get(info["id"])
            if window is None:
                window = link.open_window(info["id"], info["start_ns"] or 0)
            pending = [
                r for r in rows if r.stage not in ("executed", "rejected", "expired", "cancelled")
            ]
            detail = {"state": info["state"], "pending": len(pending), "commands": len(rows)}
            await link.db.write(_event_job("pass_resumed", detail, info["id"]))
            self._background_task(self._resume(info, rows, pending, window))

    async def _resume(
        self,
        info: dict[str, Any],
        rows: list[CommandRecord],
        pending: list[CommandRecord],
        window: TelemetryWindow,
    ) -> None:
        link, clock = self._link, self._clock
        pass_id = info["id"]
        while not link.connected:
            if self._closing.is_set():
                return
            if clock.time_ns() > info["los_time_ns"]:
                reason = "ground service restarted mid-pass; no spacecraft before LOS"
                await self.abort(pass_id, "ground", reason)
                return
            self._wake.clear()
            await clock.sleep_until(clock.monotonic() + LINK_DOWN_POLL_S, self._wake)
        async with self._lock:
            if self._active is not None:
                await self._abort_locked(pass_id, "ground", "another pass started first")
                return
            refusal = None if link.robot is None else robot_mismatch(info["robot"], link.robot)
            if refusal is not None:
                reason = f"ground service restarted mid-pass; {refusal}"
                await self._abort_locked(pass_id, "ground", reason)
                return
            uplink = self._new_uplink([command_from_record(r) for r in pending])
            uplink.restore(
                {
                    r.seq: (r.transmissions, r.stage == "received")
                    for r in pending
                    if r.stage in ("released", "sent", "received")
                }
            )
            seqs = [r.seq for r in rows]
            active = _Active(
                pass_id,
                info["name"],
                uplink,
                window,
                last_tag_ns=max(r.execute_time_ns for r in rows),
                min_seq=min(seqs),
                max_seq=max(seqs),
                robot=info["robot"],
                resumed=True,
            )
            if info["state"] == "los":
                uplink.stop()
                self._begin(active, self._finish(active))
            else:
                self._begin(active, self._run(active))

    # -- abort ---------------------------------------------------------------------------

    async def abort(self, pass_id: str, actor: str, reason: str) -> None:
        async with self._lock:
            await self._abort_locked(pass_id, actor, reason)

    def _delete_from_ns(self) -> int:
        earliest = self._link.onboard_now_ns() + self._lead_ns
        return math.ceil(earliest / GRID_NS) * GRID_NS

    async def _abort_locked(self, pass_id: str, actor: str, reason: str) -> None:
        link, clock = self._link, self._clock
        active = self._active if self._active and self._active.pass_id == pass_id else None
        if active is not None:
            active.stop.set()
            active.uplink.stop()
            self._wake.set()
            if active.task is not None and active.task is not asyncio.current_task():
                with contextlib.suppress(Exception, asyncio.CancelledError):
                    await active.task
        delete: _Delete | None = None
        from_ns: int | None = None
        if active is not None and active.uplink.sent_commands():
            # The delete goes first, before any database work: its tag is (delay + margin)
            # ahead of now, and a backlog of writes must not make it late.
            delete = _Delete(
                pass_id,
                None,
                active.min_seq,
                active.max_seq,
                reason,
                actor,
                active.uplink.rtt,
            )
            if link.connected:
                from_ns = self._delete_from_ns()
                delete.request = ScheduleDelete(
                    request_id=active.max_seq, from_time_ns=from_ns, max_seq=active.max_seq
                )
                self._deletes[active.max_seq] = delete
                for _ in range(DELETE_COPIES):
                    if await link.send_schedule_delete(delete.request):
                        delete.sends += 1
        end: int | None = None  # the onboard time unknown: leave the window open
        if from_ns is not None:
            end = from_ns + round(SETTLE_S * 1e9)
        elif active is not None and delete is None and link.connected:
            end = link.onboard_now_ns()
        if active is not None:
            link.close_window(active.window, end)
        # Cancelled on the ground: never sent, and (the delete's T known) tagged from T on.
        cancel: list[int] = []
        if active is not None:
            cancel = [c.seq for c in active.uplink.commands if c.transmissions == 0]
            if from_ns is not None:
                cancel += [
                    c.seq for c in active.uplink.commands if c.transmissions and c.tag_ns >= from_ns
                ]
        why = reason if from_ns is None else f"{reason} (deleted from the schedule)"

        def job(session: Session) -> list[dict[str, Any]]:
            key = repo.get_pass(session=session, pass_id=pass_id, refresh=True).id
            now = clock.time_ns()
            events: list[dict[str, Any]] = []
            if active is None:
                # a pass not running here (restart): everything not final and not sent
                rows = repo.list_commands(session=session, pass_id=key, stages=("queued",))
                seqs = [r.seq for r in rows]
            else:
                seqs = cancel
            if seqs:
                events += cancel_commands(
                    session,
                    pass_id=key,
                    seqs=seqs,
                    time_ns=now,
                    actor=actor,
                    reason=why,
                    from_time_ns=from_ns,
                )
            events.append(
                _transition(session, key, "aborted", actor, reason, now, telemetry_end_ns=end)
            )
            return events

        # Ahead of the stage writes still queued: the operator waits for this answer, and
        # none of them can undo it (``cancelled`` is final; the vehicle's own ``executed``
        # still overrules it, as it should).
        link.publisher.publish(await link.db.run(job, control=True))
        if active is not None and self._active is active:
            self._active = None
        if delete is not None:
            self._background_task(self._complete_delete(delete, active))
        elif active is not None and link.connected:
            self._background_task(self._resolve_outstanding(pass_id, self._closing))

    async def _complete_delete(self, delete: _Delete, active: _Active | None) -> None:
        """Retransmit the ``schedule_delete`` until its verification arrives (choosing ``T``
        once the link is back, if it was down at the abort), then file the vehicle's report
        and resolve the stages of the commands before ``T``."""
        link, clock = self._link, self._clock
        last_tag = None if active is None else active.last_tag_ns
        while not self._closing.is_set() and not delete.verified.is_set():
            if not link.connected:
                self._wake.clear()
                await clock.sleep_until(clock.monotonic() + LINK_DOWN_POLL_S, self._wake)
                continue
            if last_tag is not None and link.onboard_now_ns() > last_tag:
                break  # every command's tag has passed: nothing left to delete
            if delete.request is None:
                from_ns = self._delete_from_ns()
                delete.request = ScheduleDelete(
                    request_id=delete.max_seq, from_time_ns=from_ns, max_seq=delete.max_seq
                )
                self._deletes[delete.max_seq] = delete
                if active is not None:
                    link.close_window(active.window, from_ns + round(SETTLE_S * 1e9))
                copies = DELETE_COPIES
            else:
                copies = 1
            for _ in range(copies):
                if await link.send_schedule_delete(delete.request):
                    delete.sends += 1
            timeout = delete.rtt.rto_s  # fixed, as the commands' own timer
            await clock.sleep_until(clock.monotonic() + timeout, delete.verified)
        report = delete.report
        request = delete.request
        if request is not None:
            self._deletes.pop(request.request_id, None)
        pass_id = delete.pass_id
        if report is not None and request is not None:
            seqs = [s for lo, hi in report.deleted_ranges for s in range(lo, hi + 1)]
            if active is not None:
                seqs += [c.seq for c in active.uplink.commands if c.tag_ns >= request.from_time_ns]
            detail = {
                "request_id": report.request_id,
                "from_time_ns": request.from_time_ns,
                "deleted": report.deleted,
                "executed_after_from": report.executed_after_from,
                "copies_sent": delete.sends,
            }
            now = clock.time_ns()

            def job(session: Session) -> list[dict[str, Any]]:
                events = [write_event(session, "schedule_deleted", "ground", detail, pass_id)]
                if seqs:
                    events += cancel_commands(
                        session,
                        pass_id=pass_id,
                        seqs=seqs,
                        time_ns=now,
                        actor=delete.actor,
                        reason=f"{delete.reason} (deleted from the schedule)",
                        from_time_ns=request.from_time_ns,
                    )
                return events

            await link.db.write(job)
        elif not self._closing.is_set():
            info = {"request_id": None if request is None else request.request_id}
            await link.db.write(_event_job("schedule_delete_unverified", info, pass_id))
        await self._resolve_outstanding(pass_id, self._closing)

    async def shutdown(self) -> None:
        """The service stops: a running pass is aborted (its schedule deleted)."""
        active = self._active
        if active is not None:
            with contextlib.suppress(Exception):
                await self.abort(active.pass_id, "ground", "ground service stopped")
        self._closing.set()
        for task in list(self._background):
            with contextlib.suppress(Exception, asyncio.CancelledError):
                await task
        await self._link.db.drain()
