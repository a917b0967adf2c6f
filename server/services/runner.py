"""Passes: the state machine and the windowed uplink of their commands.

    scheduled -> aos -> running -> los -> complete
    scheduled | aos | running | los -> aborted

All timing reads the injected :class:`~server.services.clock.Clock` (``SystemClock`` in the
service, a ``ManualClock`` in the unit tests), so the rules below are tested in simulated
time. The runner is the pass's state machine; it delegates the transactions (every
transition a compare-and-set with its ``pass_state`` event) to
:mod:`server.services.pass_states`, the fate of the commands to the pass's
:class:`~server.services.tracker.CommandTracker`, the ``schedule_delete`` of an abort to
:mod:`server.services.schedule_delete` and the decisions after a restart to
:mod:`server.services.recovery`.

**Start** (needs a connected spacecraft with a known clock, flying the robot the plan was
made for): ``aos`` then ``running`` in one transaction (:func:`~server.services.pass_states.
start_job`: the plan's epoch, the commands' seqs, a refusal for another robot, 409
``robot_mismatch``). The pass's telemetry window opens at onboard now, before it.

**Uplink** (its rules: :mod:`server.services.uplink`): the onboard schedule is kept loaded
``uplink_lead_window_s`` ahead of the onboard clock, every command sent again on its timer
until acknowledged while it can still arrive, one never sent that can no longer arrive
``expired`` (the tracker records the stages). The runner wakes at the next timer, the next
command entering the window, or any typed link event (acknowledgement, link up).

**Completion**: at the last tag + :data:`SETTLE_S` onboard the pass goes ``los`` (the
telemetry window closes there); the tracker resolves the commands whose tag has passed
without a final acknowledgement (``command_query``, up to
:data:`~server.services.tracker.MAX_COMMAND_QUERIES` times: acks lost on the downlink come
again, commands lost on the uplink come back ``command_unknown`` and expire); once no
command is left ``sent`` or ``received`` (or the queries are used up) it is ``complete``.

**Abort**: the uplink stops. With something sent, a ``schedule_delete`` from the next grid
tag ``T`` at least (delay + margin) ahead goes up (:mod:`server.services.schedule_delete`);
the pass's commands never sent, and those tagged from ``T`` on, become ``cancelled`` in one
``commands_cancelled`` event (:func:`~server.services.pass_states.abort_job`); the
telemetry window closes :data:`SETTLE_S` after ``T``. Then ``aborted``; the stages of the
commands before ``T`` are resolved in the background as their tags pass.

**Another robot mid-pass** (a new ``hello`` naming another robot than the plan's): the
uplink stops at once and the pass is aborted with that reason; a resumed pass is checked too.

**Restart**: :meth:`PassRunner.recover` reopens the telemetry windows stored on the passes
and carries out the decisions of :mod:`server.services.recovery` (resume a pass left
``running`` or ``los`` by a process that did not shut down, abort the others).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable, Coroutine
from typing import Any

from sqlalchemy.orm import Session

from server.services.clock import Clock
from server.services.dbworker import Database, Publisher
from server.services.downlink import GroundDownlink
from server.services.errors import ConflictError
from server.services.events import PassResumed, event_job
from server.services.link import (
    CommandAcked,
    GroundLink,
    LinkEvent,
    LinkUnavailable,
    LinkUp,
    RobotIdentity,
    TelemetryWindow,
    robot_mismatch,
)
from server.services.pass_states import (
    TRANSITIONS,
    ActivePass,
    abort_job,
    command_from_record,
    new_uplink,
    start_job,
    transition,
)
from server.services.recovery import (
    AbortPass,
    UnfinishedPass,
    decide,
    resume_refusal,
    spacecraft_back,
)
from server.services.recovery import load as load_recovery
from server.services.schedule_delete import Deletion, ScheduleDeletes
from server.services.tracker import LINK_DOWN_POLL_S, Trackers
from server.services.uplink import RttEstimator, UplinkCommand
from server.settings import Settings
from server.storage._common import canonical_id
from server.storage.errors import Conflict
from telemetry.uplink import plan_commands
from telemetry.wire import JointCommandMsg

__all__ = ["TRANSITIONS", "PassRunner", "plan_commands"]

log = logging.getLogger("hikoboshi.ground.runner")

SETTLE_S = 2.0  # onboard s after the last tag before LOS
#: A pass starts late enough for its first command to go up this many times (the first
#: timeout, before any round-trip sample) before its last chance.
START_TRANSMISSIONS = 3


class PassRunner:
    def __init__(
        self,
        *,
        link: GroundLink,
        downlink: GroundDownlink,
        db: Database,
        publisher: Publisher,
        trackers: Trackers,
        settings: Settings,
        clock: Clock,
    ):
        self._link = link
        self._downlink = downlink
        self._db = db
        self._publisher = publisher
        self._trackers = trackers
        self._clock = clock
        self._settings = settings
        self._delay_s = settings.link_one_way_delay_s
        self._lead_ns = round((settings.link_one_way_delay_s + settings.uplink_margin_s) * 1e9)
        self._settle_ns = round(SETTLE_S * 1e9)
        self._active: ActivePass | None = None
        self._lock = asyncio.Lock()
        self._wake = asyncio.Event()
        self._diverged: asyncio.Task[None] | None = None
        self._background: set[asyncio.Task[Any]] = set()
        self._deletes = ScheduleDeletes(
            link=link,
            downlink=downlink,
            db=self._db,
            clock=self._clock,
            lead_ns=self._lead_ns,
            settle_ns=self._settle_ns,
        )
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
            cmd = active.uplink.by_seq.get(event.seq)
            joint = cmd is not None and isinstance(cmd.command, JointCommandMsg)
            if joint and (event.stage == "executed" or (event.stage == "rejected" and first)):
                # the vehicle no longer follows the plan: the pass is aborted (the schedule
                # deleted, the arm held)
                reason = active.refusals.observe(event.stage, event.reason, event.seq)
                if reason is not None:
                    self._abort_soon(active, reason)
            if first or event.reason == "schedule_full":
                self._wake.set()
        elif isinstance(event, LinkUp):
            if active is not None and not active.stop.is_set():
                refusal = robot_mismatch(active.robot, RobotIdentity.of_hello(event.hello))
                if refusal is not None:
                    self._foreign_vehicle(active, refusal)
            self._wake.set()

    def _foreign_vehicle(self, active: ActivePass, refusal: str) -> None:
        """The vehicle now connected flies another robot: nothing more of the plan goes up
        (the uplink stops before the runner can wake), and the pass is aborted."""
        active.uplink.stop()
        log.warning("pass %s: %s", active.pass_id, refusal)
        self._abort_soon(active, f"another robot connected mid-pass: {refusal}")

    def _abort_soon(self, active: ActivePass, reason: str) -> None:
        if self._diverged is None:
            self._diverged = asyncio.get_running_loop().create_task(
                self._abort_diverged(active, reason)
            )

    async def _abort_diverged(self, active: ActivePass, reason: str) -> None:
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
            window = self._downlink.open_window(
                canonical_id(pass_id, what="pass"), link.onboard_now_ns()
            )
            # onboard s: the first command's last chance, then its first copies before it
            first_rto_s = RttEstimator(2 * self._delay_s / link.time_scale).rto_s
            lead_s = max(
                self._settings.uplink_start_lead_s,
                self._lead_ns / 1e9 + START_TRANSMISSIONS * first_rto_s * link.time_scale,
            )

            job = start_job(
                pass_id=pass_id,
                actor=actor,
                link=link,
                clock=self._clock,
                lead_s=lead_s,
                telemetry_start_ns=window.start_ns,
            )
            try:
                events, started, refusal = await self._db.run(job)
            except BaseException:
                self._downlink.drop_window(window)
                raise
            self._publisher.publish(events)
            if started is None:
                self._downlink.drop_window(window)
                raise ConflictError(
                    "robot_mismatch", refusal or "robot mismatch", events[0].get("detail")
                )
            commands = started.commands
            tracker = self._trackers.queued(started.pass_id, commands)
            link.expect_commands(started.pass_id, [c.seq for c in commands])
            active = ActivePass.of(
                started.pass_id,
                started.name,
                new_uplink(commands, self._settings, link),
                window,
                tracker,
                {c.seq: c.execute_time_ns for c in commands},
                started.robot,
            )
            self._begin(active, self._run(active))

    def _begin(self, active: ActivePass, body: Coroutine[Any, Any, None]) -> None:
        self._active = active
        self.fill_margins_s = []
        active.task = asyncio.create_task(body, name=f"pass-{active.pass_id}")

    # -- the uplink loop -----------------------------------------------------------------

    async def _run(self, active: ActivePass) -> None:
        link = self._link
        try:
            los_ns = active.last_tag_ns + self._settle_ns
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
            await self._db.barrier(until=active.stop)
            # No lock from here: abort() holds it while it waits for this task. Between
            # the stop check and the write there is no await, and abort() transitions
            # only after this task has ended, from whatever state it left.
            if active.stop.is_set():
                return
            self.fill_margins_s = active.uplink.fill_margins_s()
            end = link.onboard_now_ns()
            self._downlink.close_window(active.window, end)
            reason = f"last command's tag + {SETTLE_S} s passed"
            await self._db.write(
                self._ground_transition(active.pass_id, "los", reason, telemetry_end_ns=end)
            )
            await self._finish(active)
        except Exception:
            log.exception("pass %s: the runner failed", active.pass_id)
            with contextlib.suppress(Exception):
                await self._abort_locked(active.pass_id, "ground", "runner failure")
            raise

    async def _uplink_step(self, active: ActivePass) -> float:
        """Expire, send what is due; the ground monotonic instant to look again."""
        link, clock, up = self._link, self._clock, active.uplink
        if not link.connected:
            # The onboard clock is still known from the last hello: what can no longer
            # arrive expires; the rest waits for the link.
            with contextlib.suppress(LinkUnavailable):
                active.tracker.record_expired(up.expire(link.onboard_now_ns()), clock.time_ns())
            return clock.monotonic() + LINK_DOWN_POLL_S
        onboard = link.onboard_now_ns()
        active.tracker.record_expired(up.expire(onboard), clock.time_ns())
        batch = up.due(clock.monotonic(), onboard)
        first: list[tuple[int, int]] = []
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
                first.append((cmd.seq, clock.time_ns()))
        if first or again:
            counts = [(c.seq, c.transmissions) for c in again]
            active.tracker.record_sent(released_ns, first, counts)
        return up.next_wake(link.mono_at_onboard)

    async def _finish(self, active: ActivePass) -> None:
        """After LOS: the tracker resolves the last acknowledgements, then ``complete``."""
        left = await active.tracker.resolve(active.stop, ask_expired=active.resumed)
        if active.stop.is_set():
            return  # the abort has the tracker now
        reason = "every command acknowledged" if not left else f"{left} unacknowledged"
        await self._db.write(self._ground_transition(active.pass_id, "complete", reason))
        active.tracker.close()
        if self._active is active:
            self._active = None

    def _ground_transition(
        self, pass_id: str, to: str, reason: str, **window_ns: int | None
    ) -> Callable[[Session], list[dict[str, Any]]]:
        """The ground's own transition of the pass to ``to``, timed now."""
        now_ns, clock = self._clock.time_ns(), self._clock
        return lambda s: [transition(s, clock, pass_id, to, "ground", reason, now_ns, **window_ns)]

    def _background_task(self, coro: Coroutine[Any, Any, None]) -> None:
        task = asyncio.get_running_loop().create_task(coro)
        self._background.add(task)
        task.add_done_callback(self._background.discard)

    # -- recovery after a restart --------------------------------------------------------

    async def recover(self) -> None:
        """After the service (re)starts: reopen the telemetry windows of recent passes (late
        and resent frames still reach their pass), and carry out the decisions of
        :mod:`server.services.recovery` on the passes the previous process left unfinished:
        abort, or resume once the spacecraft is back (see the module docstring)."""
        link = self._link
        found = await self._db.run(load_recovery)
        opened = {
            w.pass_id: self._downlink.open_window(w.pass_id, w.start_ns, w.end_ns)
            for w in found.windows
        }
        for decision in decide(found.unfinished, running=self._active is not None):
            if isinstance(decision, AbortPass):
                await self._abort_locked(decision.pass_id, "ground", decision.reason)
                continue
            p = decision.unfinished
            window = opened.get(p.id) or self._downlink.open_window(p.id, p.start_ns or 0)
            link.expect_commands(p.id, [r.seq for r in p.commands])
            resumed = PassResumed(
                actor="ground",
                pass_id=p.id,
                state=p.state,
                pending=len(p.pending),
                commands=len(p.commands),
            )
            await self._db.write(event_job(resumed, self._clock))
            self._background_task(self._resume(p, window))

    async def _resume(self, p: UnfinishedPass, window: TelemetryWindow) -> None:
        link = self._link
        tracker = self._trackers.stored(p.id, p.commands)  # follows the link from now on
        late = await spacecraft_back(p, link=link, clock=self._clock, closing=self._closing)
        async with self._lock:
            running = self._active is not None
            refusal = late or resume_refusal(p, running=running, vehicle=link.robot)
            if self._closing.is_set() or refusal is not None:
                tracker.close()
                if refusal is not None and not self._closing.is_set():
                    await self._abort_locked(p.id, "ground", refusal)
                return
            uplink = new_uplink([command_from_record(r) for r in p.pending], self._settings, link)
            uplink.restore(p.transmitted)
            tags = {r.seq: r.execute_time_ns for r in p.commands}
            active = ActivePass.of(
                p.id, p.name, uplink, window, tracker, tags, p.robot, resumed=True
            )
            if p.state == "los":
                uplink.stop()
                self._begin(active, self._finish(active))
            else:
                self._begin(active, self._run(active))

    # -- abort ---------------------------------------------------------------------------

    async def abort(self, pass_id: str, actor: str, reason: str) -> None:
        async with self._lock:
            await self._abort_locked(pass_id, actor, reason)

    async def _abort_locked(self, pass_id: str, actor: str, reason: str) -> None:
        link = self._link
        active = self._active if self._active and self._active.pass_id == pass_id else None
        if active is None:  # a pass not running here (restart): every command not sent
            await self._abort_write(pass_id, actor, reason, None, None, None)
            return
        active.stop.set()
        active.uplink.stop()
        self._wake.set()
        if active.task is not None and active.task is not asyncio.current_task():
            with contextlib.suppress(Exception, asyncio.CancelledError):
                await active.task
        up = active.uplink
        deletion: Deletion | None = None
        if up.sent_commands():
            commands = tuple((c.seq, c.tag_ns) for c in up.commands)
            deletion = Deletion(
                active.tracker, active.window, active.last_tag_ns, commands, active.max_seq,
                reason, actor, up.rtt,
            )  # fmt: skip
            await self._deletes.begin(deletion)  # first, before any database work
        from_ns = None if deletion is None else deletion.from_ns
        end: int | None = None  # the onboard time unknown: leave the window open
        if from_ns is not None:
            end = from_ns + self._settle_ns
        elif deletion is None and link.connected:
            end = link.onboard_now_ns()
        self._downlink.close_window(active.window, end)
        # Cancelled on the ground: never sent, and (the delete's T known) tagged from T on.
        cancel = [c.seq for c in up.commands if c.transmissions == 0]
        if from_ns is not None:
            cancel += [c.seq for c in up.commands if c.transmissions and c.tag_ns >= from_ns]
        await self._abort_write(pass_id, actor, reason, cancel, from_ns, end)
        active.tracker.cancelled(cancel)
        if self._active is active:
            self._active = None
        if deletion is not None or link.connected:
            self._background_task(
                self._deletes.after_abort(active.tracker, deletion, self._closing)
            )
        else:
            active.tracker.close()

    async def _abort_write(
        self,
        pass_id: str,
        actor: str,
        reason: str,
        cancel: list[int] | None,
        from_ns: int | None,
        end_ns: int | None,
    ) -> None:
        """The abort's transaction, ahead of the stage writes still queued: the operator waits
        for it, and none of them can undo it (the vehicle's own word still overrules)."""
        job = abort_job(
            pass_id=pass_id, actor=actor, reason=reason, clock=self._clock, cancel=cancel,
            from_ns=from_ns, end_ns=end_ns,
        )  # fmt: skip
        self._publisher.publish(await self._db.run(job, control=True))

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
        await self._db.drain()
