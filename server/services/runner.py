"""Passes: the state machine and the 4 Hz uplink emitter.

    scheduled -> aos -> running -> los -> complete
    scheduled | aos | running | los -> aborted

Every transition is a compare-and-set on the pass's version (``update_pass_state``) and an
event ``pass_state`` (actor, from, to, reason) in the same transaction.

**Start** (needs a connected spacecraft with a known clock): ``aos`` then ``running`` in one
transaction. The plan's ``t = 0`` is put at ``epoch_ns`` = onboard now + (one-way delay +
uplink margin + 1 s + the onboard time of 0.5 s wall for the start transaction), rounded up
to the 0.25 s grid; the plan's joint and ACS commands are
queued with ``seq`` from one past the highest the vehicle has seen (the stored commands and
``hello.last_command_seq``), in tag order. The pass's telemetry window opens at onboard now.

**Emitter**: command ``k`` is released when the onboard clock reads ``tag - (delay +
margin)``. The deadline is an absolute ``time.monotonic`` instant computed from the
``hello`` clock mapping (onboard seconds divided by the time scale), never an accumulated
sleep, so the cadence is isochronous and does not drift. Stages ``released`` then ``sent``
(ground times) are written without the emitter waiting for the commit. With the link down
the command waits; a command that can no longer reach the vehicle before its tag (less
than the one-way delay left) is marked ``expired`` instead. ``emission_lags_s`` keeps how
late each release was after its deadline (wall s).

**Completion**: at the last tag + :data:`SETTLE_S` onboard the pass goes ``los`` (the
telemetry window closes there); once no command is left ``sent`` or ``received`` (or
after two one-way delays + margin more) it is ``complete``.

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
from server.storage.errors import Conflict
from server.storage.models import CommandRecord
from telemetry.uplink import GRID_NS, Command, plan_commands
from telemetry.wire import JointCommandMsg, encode

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
START_SLACK_WALL_S = 0.5
SETTLE_S = 2.0  # onboard s after the last tag before LOS
UNSENT = ("queued", "released")


def _transition(
    session: Session, pass_id: str, to: str, actor: str, reason: str, epoch_ns: int | None = None
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
    )
    detail: dict[str, Any] = {"from": previous, "to": to, "reason": reason}
    detail["version"] = record.version
    if epoch_ns is not None:
        detail["epoch_ns"] = epoch_ns
    return write_event(session, "pass_state", actor, detail, record.id)


@dataclass
class _Active:
    pass_id: str
    name: str
    commands: list[Command]
    window: TelemetryWindow
    stop: asyncio.Event = field(default_factory=asyncio.Event)
    task: asyncio.Task[None] | None = None
    last_sent_joints: list[float] | None = None


class PassRunner:
    def __init__(self, *, link: GroundLink, settings: Settings) -> None:
        self._link = link
        self._delay_s = settings.link_one_way_delay_s
        self._lead_ns = round((settings.link_one_way_delay_s + settings.uplink_margin_s) * 1e9)
        self._active: _Active | None = None
        self._lock = asyncio.Lock()
        self.emission_lags_s: list[float] = []

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
                events.append(_transition(session, record.id, "running", actor, reason, epoch_ns))
                window = TelemetryWindow(record.id, start_ns=now_ns)
                return events, _Active(record.id, record.name, commands, window)

            events, active = await link.db.run(job)
            link.publisher.publish(events)
            link.windows.append(active.window)
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
            if left_s < self._delay_s:
                self._record(active, command.seq, [("expired", time.time_ns())])
                return True
            if link.connected and await link.send(encode(command)):
                stages = [("released", released_ns), ("sent", time.time_ns())]
                self._record(active, command.seq, stages)
                if isinstance(command, JointCommandMsg):
                    active.last_sent_joints = list(command.joints_rad)
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
            last_tag = active.commands[-1].execute_time_ns
            los_ns = last_tag + round(SETTLE_S * 1e9)
            if not await self._wait(link.mono_at_onboard(los_ns), active.stop):
                return
            await link.db.drain()
            # No lock from here: abort() holds it while it waits for this task. Between
            # the stop check and the write there is no await, and abort() transitions
            # only after this task has ended, from whatever state it left.
            if active.stop.is_set():
                return
            active.window.end_ns = link.onboard_now_ns()
            reason = f"last command's tag + {SETTLE_S} s passed"
            await link.db.write(lambda s: [_transition(s, active.pass_id, "los", "ground", reason)])
            wait_ns = round((2 * self._delay_s + 2.0) * 1e9)
            give_up = link.mono_at_onboard(link.onboard_now_ns() + wait_ns)

            def outstanding(session: Session) -> int:
                rows = repo.list_commands(
                    session=session, pass_id=active.pass_id, stages=("sent", "received")
                )
                return len(rows)

            left = await link.db.run(outstanding)
            while left and time.monotonic() < give_up and not active.stop.is_set():
                await self._wait(time.monotonic() + 0.05, active.stop)
                left = await link.db.run(outstanding)
            if active.stop.is_set():
                return
            reason = "every command acknowledged" if not left else f"{left} unacknowledged"
            await link.db.write(
                lambda s: [_transition(s, active.pass_id, "complete", "ground", reason)]
            )
            if self._active is active:
                self._active = None
        except Exception:
            log.exception("pass %s: the runner failed", active.pass_id)
            with contextlib.suppress(Exception):
                await self._abort_locked(active.pass_id, "ground", "runner failure")
            raise

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
        await link.db.drain()
        hold: JointCommandMsg | None = None
        if active is not None and active.last_sent_joints is not None and link.connected:
            earliest = link.onboard_now_ns() + self._lead_ns
            tag = math.ceil(earliest / GRID_NS) * GRID_NS
            hold = JointCommandMsg(seq=0, execute_time_ns=tag, joints_rad=active.last_sent_joints)

        def job(session: Session) -> tuple[list[dict[str, Any]], JointCommandMsg | None]:
            key = repo.get_pass(session=session, pass_id=pass_id, refresh=True).id
            events: list[dict[str, Any]] = []
            now = time.time_ns()
            for record in repo.list_commands(session=session, pass_id=key, stages=UNSENT):
                events += set_command_stage(
                    session, pass_id=key, seq=record.seq, stage="expired", time_ns=now, actor=actor
                )
            held = None
            if hold is not None:
                used = session.scalar(select(func.max(CommandRecord.seq))) or 0
                held = hold.model_copy(update={"seq": max(used, link.last_command_seq) + 1})
                repo.add_commands(session=session, pass_id=key, commands=[held], queued_at_ns=now)
                detail = {"seq": held.seq, "execute_time_ns": held.execute_time_ns}
                events.append(write_event(session, "hold_queued", actor, detail, key))
            events.append(_transition(session, key, "aborted", actor, reason))
            return events, held

        events, held = await link.db.run(job)
        link.publisher.publish(events)
        if active is not None:
            end: int | None = None  # the clock unknown: leave the window open
            with contextlib.suppress(LinkUnavailable):
                end = link.onboard_now_ns()
            if held is not None:
                link.command_pass[held.seq] = pass_id
                end = held.execute_time_ns + round(SETTLE_S * 1e9)
                released = time.time_ns()
                if await link.send(encode(held)):
                    self._record(
                        active, held.seq, [("released", released), ("sent", time.time_ns())]
                    )
            active.window.end_ns = end
            if self._active is active:
                self._active = None

    async def shutdown(self) -> None:
        """The service stops: a running pass is aborted (its remaining commands expire)."""
        active = self._active
        if active is not None:
            with contextlib.suppress(Exception):
                await self.abort(active.pass_id, "ground", "ground service stopped")
        await self._link.db.drain()
