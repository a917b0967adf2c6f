"""Passes: the state machine and the 4 Hz uplink emitter.

    scheduled -> aos -> running -> los -> complete
    scheduled | aos | running | los -> aborted

Every transition is a compare-and-set on the pass's version (``update_pass_state``) and an
event ``pass_state`` (actor, from, to, reason) in the same transaction.

**Start** (needs a connected spacecraft with a known clock): ``aos`` then ``running`` in one
transaction. The plan's ``t = 0`` is put at ``epoch_ns`` = onboard now + (one-way delay +
uplink margin + 1 s + the onboard time of 1 s wall for the start transaction), rounded up
to the 0.25 s grid; the plan's joint and ACS commands are
queued with ``seq`` from one past the highest the vehicle has seen (the stored commands and
``hello.last_command_seq``), in tag order. The pass's telemetry window opens at onboard now.

**Emitter**: command ``k`` is released when the onboard clock reads ``tag - (delay +
margin)``. The deadline is an absolute ``time.monotonic`` instant computed from the
``hello`` clock mapping (onboard seconds divided by the time scale), never an accumulated
sleep, so the cadence is isochronous and does not drift. Stages ``released`` then ``sent``
(ground times) are written without the emitter waiting for the commit. With the link down
the command waits; a command that could no longer be sent with (one-way delay + half the
margin) before its tag is marked ``expired`` instead: SPEC 6 asks for delay + margin, and
half the margin is kept as the release's own tolerance (an event loop a few ms late must
not expire a command; a link back after an outage must not send one that jitter could
make late). ``emission_lags_s`` keeps how late each release was after its deadline (wall s).

**Completion**: at the last tag + :data:`SETTLE_S` onboard the pass goes ``los`` (the
telemetry window closes there); commands whose tag has passed without a final
acknowledgement are asked about (``command_query``, up to :data:`MAX_COMMAND_QUERIES`
times: acks lost on the downlink come again, commands lost on the uplink come back
``command_unknown`` and expire); once no command is left ``sent`` or ``received`` (or
the queries are used up) it is ``complete``.

**Restart**: :meth:`PassRunner.recover` reopens the telemetry windows stored on the
passes and resumes a pass left ``running`` or ``los`` by a process that did not shut
down (a graceful stop aborts the running pass instead, holding the arm).

**Abort**: the emitter stops; commands not yet sent are ``expired``; a hold is sent: one
joint command at the next 0.25 s grid tag at least (delay + margin) ahead, holding the
**last joint target sent** (the commands already sent will still execute on board, and
the hold keeps the arm where they leave it). Nothing was sent: no hold (the arm was never
moved by this pass). The telemetry window closes :data:`SETTLE_S` after the hold's tag so
the hold is seen in the pass's telemetry. Then ``aborted``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from planner.plan import Plan
from server.services.link import (
    GroundLink,
    LinkUnavailable,
    TelemetryWindow,
    set_command_stage,
    write_event,
)
from server.settings import Settings
from server.storage import repository as repo
from server.storage._common import canonical_id
from server.storage.errors import Conflict
from server.storage.models import CommandRecord, PassRecord
from telemetry.uplink import GRID_NS, Command, plan_commands
from telemetry.wire import AcsCommandMsg, JointCommandMsg, encode

__all__ = ["TRANSITIONS", "PassRunner", "plan_commands"]

log = logging.getLogger("hikoboshi.ground.runner")

#: Allowed transitions: to -> the states it may come from.
TRANSITIONS = {
    "aos": {"scheduled"},
    "running": {"aos"},
    "los": {"running"},
    "complete": {"los"},
    "aborted": {"scheduled", "aos", "running", "los"},
}
START_SLACK_S = 1.0  # onboard s beyond delay + margin, for the first command
#: Wall s allowed for the start transaction itself (its first use of a fresh PostgreSQL
#: connection can take a few hundred ms: at 20x that is seconds onboard).
START_SLACK_WALL_S = 1.0
SETTLE_S = 2.0  # onboard s after the last tag before LOS
UNSENT = ("queued", "released")
#: Refusals that mean the arm no longer follows the plan, and how many in a row stop it
#: (2 s of joint commands).
REFUSALS = ("out_of_limits", "late")
MAX_REFUSED_IN_A_ROW = 8
#: After LOS, ask the vehicle about unacknowledged commands at most this many times.
MAX_COMMAND_QUERIES = 5
#: Telemetry windows of this many recent passes are reopened after a restart.
RECOVERED_WINDOWS = 50


def _transition(
    session: Session,
    pass_id: str,
    to: str,
    actor: str,
    reason: str,
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
        updated_at_ns=time.time_ns(),
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


def command_from_record(record: CommandRecord) -> Command:
    """The wire message a stored command was (or will be) sent as."""
    fields = {"seq": record.seq, "execute_time_ns": record.execute_time_ns, **record.payload}
    if record.kind == "joints":
        return JointCommandMsg.model_validate(fields)
    return AcsCommandMsg.model_validate(fields)


def _hold_job(
    pass_id: str, hold: JointCommandMsg, actor: str
) -> Callable[[Session], list[dict[str, Any]]]:
    def job(session: Session) -> list[dict[str, Any]]:
        key = repo.get_pass(session=session, pass_id=pass_id).id
        repo.add_commands(
            session=session, pass_id=key, commands=[hold], queued_at_ns=time.time_ns()
        )
        detail = {"seq": hold.seq, "execute_time_ns": hold.execute_time_ns}
        return [write_event(session, "hold_queued", actor, detail, key)]

    return job


def _event_job(
    kind: str, detail: dict[str, Any], pass_id: str
) -> Callable[[Session], list[dict[str, Any]]]:
    return lambda session: [write_event(session, kind, "ground", detail, pass_id)]


@dataclass
class _Active:
    pass_id: str
    name: str
    #: The commands still to send, in tag order.
    commands: list[Command]
    window: TelemetryWindow
    last_tag_ns: int
    #: The highest seq of the pass (a hold takes the next one).
    max_seq: int
    stop: asyncio.Event = field(default_factory=asyncio.Event)
    task: asyncio.Task[None] | None = None
    last_sent_joints: list[float] | None = None
    last_sent_tag_ns: int = -1
    #: Where to hold on abort instead of the last target sent (the vehicle's own target
    #: when it stopped following the plan).
    hold_joints: list[float] | None = None


class PassRunner:
    def __init__(self, *, link: GroundLink, settings: Settings) -> None:
        self._link = link
        self._delay_s = settings.link_one_way_delay_s
        self._margin_s = settings.uplink_margin_s
        self._lead_ns = round((settings.link_one_way_delay_s + settings.uplink_margin_s) * 1e9)
        self._active: _Active | None = None
        self._lock = asyncio.Lock()
        self.emission_lags_s: list[float] = []
        self._refused_in_a_row = 0
        self._diverged: asyncio.Task[None] | None = None
        self._background: set[asyncio.Task[int]] = set()
        self._closing = asyncio.Event()
        link.publisher.subscribe(self._watch)

    def _watch(self, event: dict[str, Any]) -> None:
        """Stop a pass the vehicle no longer follows: :data:`MAX_REFUSED_IN_A_ROW` joint
        commands refused in a row (``out_of_limits`` or ``late``: after lost commands each
        next one is a jump from where the arm stopped, and every later one is too). The
        plan cannot continue from there; the pass is aborted and the arm held where the
        vehicle's own target is."""
        active = self._active
        if active is None or event.get("kind") != "command_stage":
            return
        if event.get("pass_id") != active.pass_id:
            return
        detail = event.get("detail", {})
        if detail.get("stage") == "executed":
            self._refused_in_a_row = 0
        elif detail.get("stage") == "rejected" and detail.get("reason") in REFUSALS:
            self._refused_in_a_row += 1
            if self._refused_in_a_row >= MAX_REFUSED_IN_A_ROW and self._diverged is None:
                reason = (
                    f"the vehicle refused {self._refused_in_a_row} commands in a row "
                    f"(last: {detail.get('reason')}, seq {detail.get('seq')}): the arm no "
                    "longer follows the plan"
                )
                self._diverged = asyncio.get_running_loop().create_task(
                    self._abort_diverged(active, reason)
                )

    async def _abort_diverged(self, active: _Active, reason: str) -> None:
        try:
            frame = self._link.latest_frame
            if frame is not None:
                active.hold_joints = list(frame.joint_targets_rad)
            await self.abort(active.pass_id, "ground", reason)
        except Exception:
            log.exception("pass %s: abort after divergence failed", active.pass_id)
        finally:
            self._diverged = None
            self._refused_in_a_row = 0

    @property
    def resolving(self) -> bool:
        """Whether the stages of an aborted pass's last commands are still being resolved."""
        return bool(self._background)

    @property
    def active_pass_id(self) -> str | None:
        return None if self._active is None else self._active.pass_id

    # -- start ---------------------------------------------------------------------------

    async def start(self, pass_id: str, actor: str) -> None:
        async with self._lock:
            if self._active is not None:
                raise Conflict(f"pass {self._active.name!r} is running; one pass at a time")
            link = self._link
            if not link.connected:
                raise LinkUnavailable("no spacecraft is connected: a pass needs the link")
            # The window opens before the start transaction: storing thousands of commands
            # takes longer than the relay delay at high time scales, and the frames
            # generated meanwhile must already find their pass.
            window = TelemetryWindow(
                canonical_id(pass_id, what="pass"), start_ns=link.onboard_now_ns()
            )

            def job(session: Session) -> tuple[list[dict[str, Any]], _Active]:
                record = repo.get_pass(session=session, pass_id=pass_id, refresh=True)
                plan = Plan.from_json(
                    repo.get_plan(session=session, plan_id=record.plan_id).document
                )
                vehicle = link.vehicle or "spacecraft"
                events = [_transition(session, record.id, "aos", actor, f"{vehicle} connected")]
                now_ns = link.onboard_now_ns()
                slack_s = START_SLACK_S + START_SLACK_WALL_S * link.time_scale
                earliest = now_ns + self._lead_ns + round(slack_s * 1e9)
                epoch_ns = math.ceil(earliest / GRID_NS) * GRID_NS
                used = session.scalar(select(func.max(CommandRecord.seq)))
                first_seq = max(-1 if used is None else used, link.last_command_seq) + 1
                commands = plan_commands(plan, epoch_ns=epoch_ns, first_seq=first_seq)
                repo.add_commands(
                    session=session,
                    pass_id=record.id,
                    commands=commands,
                    queued_at_ns=time.time_ns(),
                )
                reason = f"started: {len(commands)} commands from seq {first_seq}"
                events.append(
                    _transition(
                        session,
                        record.id,
                        "running",
                        actor,
                        reason,
                        epoch_ns,
                        telemetry_start_ns=window.start_ns,
                    )
                )
                last_tag = commands[-1].execute_time_ns
                max_seq = max(c.seq for c in commands)
                active = _Active(record.id, record.name, commands, window, last_tag, max_seq)
                return events, active

            link.windows.append(window)
            self._refused_in_a_row = 0
            try:
                events, active = await link.db.run(job)
            except BaseException:
                link.windows.remove(window)
                raise
            link.publisher.publish(events)
            for command in active.commands:
                link.command_pass[command.seq] = active.pass_id
            self._active = active
            active.task = asyncio.create_task(self._run(active), name=f"pass-{active.pass_id}")

    # -- the emitter ---------------------------------------------------------------------

    async def _wait(self, deadline_mono: float, stop: asyncio.Event) -> bool:
        """Sleep until ``deadline_mono``; False if ``stop`` was set first."""
        remaining = deadline_mono - time.monotonic()
        if remaining > 0:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), remaining)
        return not stop.is_set()

    async def _emit(self, active: _Active, command: Command) -> bool:
        """Release and send one command at its deadline; False if stopped."""
        link = self._link
        if not await self._wait(
            link.mono_at_onboard(command.execute_time_ns - self._lead_ns), active.stop
        ):
            return False
        self.emission_lags_s.append(
            time.monotonic() - link.mono_at_onboard(command.execute_time_ns - self._lead_ns)
        )
        released_ns = time.time_ns()
        while True:
            left_s = (command.execute_time_ns - link.onboard_now_ns()) / 1e9
            if left_s < self._delay_s + self._margin_s / 2:
                self._record(active, command.seq, [("expired", time.time_ns())])
                return True
            if link.connected and await link.send(encode(command)):
                stages = [("released", released_ns), ("sent", time.time_ns())]
                self._record(active, command.seq, stages)
                if isinstance(command, JointCommandMsg):
                    active.last_sent_joints = list(command.joints_rad)
                    active.last_sent_tag_ns = command.execute_time_ns
                return True
            if not await self._wait(time.monotonic() + 0.01, active.stop):
                return False

    def _record(self, active: _Active, seq: int, stages: list[tuple[str, int]]) -> None:
        def job(session: Session) -> list[dict[str, Any]]:
            events: list[dict[str, Any]] = []
            for stage, time_ns in stages:
                events += set_command_stage(
                    session,
                    pass_id=active.pass_id,
                    seq=seq,
                    stage=stage,
                    time_ns=time_ns,
                    actor="ground",
                )
            return events

        self._link.db.submit(job)

    async def _run(self, active: _Active) -> None:
        link = self._link
        try:
            for command in active.commands:
                if not await self._emit(active, command):
                    return  # aborted: abort() finishes the pass
            los_ns = active.last_tag_ns + round(SETTLE_S * 1e9)
            if not await self._wait(link.mono_at_onboard(los_ns), active.stop):
                return
            await link.db.drain()
            # No lock from here: abort() holds it while it waits for this task. Between
            # the stop check and the write there is no await, and abort() transitions
            # only after this task has ended, from whatever state it left.
            if active.stop.is_set():
                return
            end = link.onboard_now_ns()
            active.window.end_ns = end
            reason = f"last command's tag + {SETTLE_S} s passed"
            await link.db.write(
                lambda s: [
                    _transition(s, active.pass_id, "los", "ground", reason, telemetry_end_ns=end)
                ]
            )
            await self._finish(active)
        except Exception:
            log.exception("pass %s: the runner failed", active.pass_id)
            with contextlib.suppress(Exception):
                await self._abort_locked(active.pass_id, "ground", "runner failure")
            raise

    async def _finish(self, active: _Active) -> None:
        """After LOS: wait for the last acknowledgements, asking the vehicle about commands
        whose tag has passed without one, then ``complete``."""
        left = await self._resolve_outstanding(active.pass_id, active.stop)
        if active.stop.is_set():
            return
        reason = "every command acknowledged" if not left else f"{left} unacknowledged"
        await self._link.db.write(
            lambda s: [_transition(s, active.pass_id, "complete", "ground", reason)]
        )
        if self._active is active:
            self._active = None

    async def _resolve_outstanding(self, pass_id: str, stop: asyncio.Event) -> int:
        """Ask the vehicle (``command_query``: acks lost on the downlink, commands lost on
        the uplink) about the pass's commands still ``sent`` or ``received`` once their tag
        has passed, up to :data:`MAX_COMMAND_QUERIES` times; how many are left unresolved."""
        link = self._link
        # Onboard s between queries: a round trip and a second to answer.
        period_s = 2 * self._delay_s + 1.0

        def outstanding(session: Session) -> list[tuple[int, int]]:
            rows = repo.list_commands(session=session, pass_id=pass_id, stages=("sent", "received"))
            return [(r.seq, r.execute_time_ns) for r in rows]

        left = await link.db.run(outstanding)
        queries = 0
        next_query = time.monotonic()
        while left and queries < MAX_COMMAND_QUERIES and not stop.is_set():
            if time.monotonic() >= next_query:
                if link.connected:
                    due = [seq for seq, tag in left if tag < link.onboard_now_ns()]
                    if due and await link.query_commands(due):
                        queries += 1
                    next_query = link.mono_at_onboard(link.onboard_now_ns() + round(period_s * 1e9))
                else:
                    next_query = time.monotonic() + 0.05
            await self._wait(time.monotonic() + 0.05, stop)
            left = await link.db.run(outstanding)
        if left and not stop.is_set() and queries:
            # the last answers are a round trip away
            await self._wait(
                link.mono_at_onboard(link.onboard_now_ns() + round(period_s * 1e9)), stop
            )
            left = await link.db.run(outstanding)
        return len(left)

    def _resolve_later(self, pass_id: str) -> None:
        """After an abort: the commands already sent still run on board; resolve their
        stages in the background as their tags pass."""
        task = asyncio.get_running_loop().create_task(
            self._resolve_outstanding(pass_id, self._closing)
        )
        self._background.add(task)
        task.add_done_callback(self._background.discard)

    # -- recovery after a restart --------------------------------------------------------

    async def recover(self) -> None:
        """After the service (re)starts: reopen the telemetry windows of recent passes (late
        and resent frames still reach their pass), and resume a pass the previous process
        left ``running`` or ``los`` (it stopped without shutting down: killed, crashed).
        The emitter picks up at the first command never sent, once the spacecraft is back;
        commands whose tag comes too close meanwhile expire. No spacecraft before the pass's
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
                found.append(
                    {
                        "id": record.id,
                        "name": record.name,
                        "state": record.state,
                        "los_time_ns": record.los_time_ns,
                        "start_ns": record.telemetry_start_ns,
                        "commands": rows,
                    }
                )
            return windows, found

        windows, unfinished = await link.db.run(job)
        link.windows.extend(windows)
        for info in unfinished:
            if self._active is not None or info["state"] == "aos" or not info["commands"]:
                reason = "ground service restarted before the pass was running"
                if self._active is not None:
                    reason = "ground service restarted with another pass to resume"
                await self._abort_locked(info["id"], "ground", reason)
                continue
            rows: list[CommandRecord] = info["commands"]
            for row in rows:
                link.command_pass[row.seq] = info["id"]
            unsent = [command_from_record(r) for r in rows if r.stage in UNSENT]
            unsent.sort(key=lambda c: (c.execute_time_ns, c.seq))
            window = next((w for w in windows if w.pass_id == info["id"]), None)
            if window is None:
                window = TelemetryWindow(info["id"], start_ns=info["start_ns"] or 0)
                link.windows.append(window)
            active = _Active(
                info["id"],
                info["name"],
                unsent,
                window,
                last_tag_ns=max(r.execute_time_ns for r in rows),
                max_seq=max(r.seq for r in rows),
            )
            sent_joints = [r for r in rows if r.kind == "joints" and r.sent_at_ns is not None]
            if sent_joints:
                last = max(sent_joints, key=lambda r: r.seq)
                active.last_sent_joints = list(last.payload["joints_rad"])
                active.last_sent_tag_ns = last.execute_time_ns
            detail = {"state": info["state"], "unsent": len(unsent), "commands": len(rows)}
            await link.db.write(_event_job("pass_resumed", detail, info["id"]))
            self._active = active
            active.task = asyncio.create_task(
                self._resume(active, info["state"], info["los_time_ns"]),
                name=f"pass-{active.pass_id}",
            )

    async def _resume(self, active: _Active, state: str, los_time_ns: int) -> None:
        while not self._link.connected:
            if active.stop.is_set():
                return
            if time.time_ns() > los_time_ns:
                reason = "ground service restarted mid-pass; no spacecraft before LOS"
                await self.abort(active.pass_id, "ground", reason)
                return
            await asyncio.sleep(0.05)
        # The stage writes are not awaited by the emitter, so the killed process may have
        # sent commands whose ``sent`` never committed. The vehicle's hello names the
        # highest seq it has received, and seqs go out in order: those are not sent again
        # (the vehicle would refuse a duplicate), but asked about.
        link = self._link
        seen = link.last_command_seq
        found = [c.seq for c in active.commands if c.seq <= seen]
        if found:
            active.commands = [c for c in active.commands if c.seq > seen]

            def job(session: Session) -> list[dict[str, Any]]:
                events: list[dict[str, Any]] = []
                now = time.time_ns()
                for seq in found:
                    events += set_command_stage(
                        session,
                        pass_id=active.pass_id,
                        seq=seq,
                        stage="sent",
                        time_ns=now,
                        actor="ground",
                        detail="sent before the ground restarted (the vehicle has seen it)",
                    )
                return events

            await link.db.write(job)
            await link.query_commands(found)
        if state == "los":
            await self._finish(active)
        else:
            await self._run(active)

    # -- abort ---------------------------------------------------------------------------

    async def abort(self, pass_id: str, actor: str, reason: str) -> None:
        async with self._lock:
            await self._abort_locked(pass_id, actor, reason)

    async def _abort_locked(self, pass_id: str, actor: str, reason: str) -> None:
        link = self._link
        active = self._active if self._active and self._active.pass_id == pass_id else None
        if active is not None:
            active.stop.set()
            if active.task is not None and active.task is not asyncio.current_task():
                with contextlib.suppress(Exception, asyncio.CancelledError):
                    await active.task
        # The hold goes first, before any database work: its tag is (delay + margin) ahead
        # of now, and a backlog of writes must not make it late.
        hold: JointCommandMsg | None = None
        hold_joints = None if active is None else active.hold_joints or active.last_sent_joints
        if active is not None and hold_joints is not None and link.connected:
            earliest = link.onboard_now_ns() + self._lead_ns
            tag = max(math.ceil(earliest / GRID_NS) * GRID_NS, active.last_sent_tag_ns + GRID_NS)
            seq = max(active.max_seq, link.last_command_seq) + 1
            hold = JointCommandMsg(seq=seq, execute_time_ns=tag, joints_rad=hold_joints)
            link.command_pass[seq] = pass_id
            # Queued (not awaited) before it is sent: the writes run in order, so the row
            # exists before the hold's acknowledgement is filed.
            link.db.submit(_hold_job(pass_id, hold, actor))
            released = time.time_ns()
            if await link.send(encode(hold)):
                self._record(active, seq, [("released", released), ("sent", time.time_ns())])
        end: int | None = None  # the clock unknown: leave the window open
        if hold is not None:
            end = hold.execute_time_ns + round(SETTLE_S * 1e9)
        elif link.connected:
            end = link.onboard_now_ns()
        if active is not None:
            active.window.end_ns = end
        await link.db.drain()

        def job(session: Session) -> list[dict[str, Any]]:
            key = repo.get_pass(session=session, pass_id=pass_id, refresh=True).id
            events: list[dict[str, Any]] = []
            now = time.time_ns()
            for record in repo.list_commands(session=session, pass_id=key, stages=UNSENT):
                events += set_command_stage(
                    session, pass_id=key, seq=record.seq, stage="expired", time_ns=now, actor=actor
                )
            events.append(_transition(session, key, "aborted", actor, reason, telemetry_end_ns=end))
            return events

        link.publisher.publish(await link.db.run(job))
        if active is not None and self._active is active:
            self._active = None
        if active is not None and link.connected:
            self._resolve_later(pass_id)

    async def shutdown(self) -> None:
        """The service stops: a running pass is aborted (its remaining commands expire)."""
        active = self._active
        if active is not None:
            with contextlib.suppress(Exception):
                await self.abort(active.pass_id, "ground", "ground service stopped")
        self._closing.set()
        for task in list(self._background):
            with contextlib.suppress(Exception, asyncio.CancelledError):
                await task
        await self._link.db.drain()
