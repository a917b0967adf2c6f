"""Passes: the state machine and the windowed uplink of their commands.

    scheduled -> aos -> running -> los -> complete
    scheduled | aos | running | los -> aborted
    aos | running | los -> safed

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
command is left ``sent`` or ``received`` (or the queries are used up) it is ``complete``,
its reason the outcome (:func:`~server.services.summary.command_outcome`: "complete,
nominal: all 400 commands executed at their tags", or "complete, degraded: 393 of 6190
commands expired").

**Abort**: the uplink stops. With something sent, a ``schedule_delete`` from the next grid
tag ``T`` at least (delay + margin) ahead goes up (:mod:`server.services.schedule_delete`);
the pass's commands never sent, and those tagged from ``T`` on, become ``cancelled`` in one
``commands_cancelled`` event (:func:`~server.services.pass_states.abort_job`); the
telemetry window closes :data:`SETTLE_S` after ``T``. Then ``aborted``; the stages of the
commands before ``T`` are resolved in the background as their tags pass.

**Another robot mid-pass** (a new ``hello`` naming another robot than the plan's): the
uplink stops at once and the pass is aborted with that reason; a resumed pass is checked too.

**The vehicle safes itself** (its ``safing`` report, state ``safe``: docs/alarms.md): the
uplink stops at once, the vehicle's own protection having already emptied its schedule and
holding the arm; no ``schedule_delete`` goes up (the vehicle refuses every command while
safe, each ``rejected`` ``safing``, filed ``cancelled``). The commands never sent are
``cancelled`` on the ground, the telemetry window stays open :data:`SAFED_TAIL_S` onboard
past the safing (the report shows the hold), and the pass goes ``safed`` with the trigger as
its reason. The alarms raise the ``critical`` ``vehicle_safing`` alarm; the tracker
resolves the fates of the commands sent. No pass starts while the vehicle is safe (409
``vehicle_safe``); an operator's ``safe_exit`` ends it (:mod:`server.services.safing`).

**Graceful stop, restart, stand-down**: :mod:`server.services.runner_handover`. The abort,
the safing and a diverged vehicle's end are :mod:`server.services.runner_ends`; the state
the parts share, :mod:`server.services.runner_base`.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable, Coroutine
from typing import Any

from sqlalchemy.orm import Session

from server.logs import current_pass
from server.services.clock import Clock
from server.services.dbworker import Database, Publisher
from server.services.downlink import GroundDownlink
from server.services.errors import ConflictError
from server.services.events import (
    Recorded,
    SafingReported,
)
from server.services.link import (
    CommandAcked,
    GroundLink,
    LinkEvent,
    LinkUnavailable,
    LinkUp,
    RobotIdentity,
    robot_mismatch,
)
from server.services.pass_reasons import handover_reason, safed_reason
from server.services.pass_states import (
    TRANSITIONS,
    ActivePass,
    new_uplink,
    start_job,
    transition,
)
from server.services.runner_base import SETTLE_S, Authority, SafingAlarms
from server.services.runner_ends import SAFED_TAIL_S, PassEnds
from server.services.runner_handover import PassHandover
from server.services.schedule_delete import ScheduleDeletes
from server.services.summary import command_outcome
from server.services.tracker import LINK_DOWN_POLL_S, Trackers
from server.services.uplink import UplinkCommand
from server.settings import Settings
from server.storage._common import canonical_id
from server.storage.errors import Conflict
from telemetry.uplink import plan_commands
from telemetry.wire import JointCommandMsg

__all__ = [
    "SAFED_TAIL_S",
    "TRANSITIONS",
    "PassRunner",
    "SafingAlarms",
    "handover_reason",
    "plan_commands",
    "safed_reason",
]

log = logging.getLogger("hikoboshi.ground.runner")


class PassRunner(PassEnds, PassHandover):
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
        start_lead: Callable[[float], float],
        alarms: SafingAlarms | None = None,
        authority: Authority | None = None,
    ):
        self._link = link
        #: None: this ground always commands (one ground, the simulated-time tests)
        self._authority = authority
        self._alarms = alarms
        self._downlink = downlink
        self._db = db
        self._publisher = publisher
        self._trackers = trackers
        self._clock = clock
        self._settings = settings
        #: onboard s from a start to its plan's t = 0 at a time scale (the composition root
        #: hands it: server.operations.windows.start_lead_s)
        self._start_lead = start_lead
        self._lead_ns = round((settings.link_one_way_delay_s + settings.uplink_margin_s) * 1e9)
        self._settle_ns = round(SETTLE_S * 1e9)
        self._active: ActivePass | None = None
        self._lock = asyncio.Lock()
        self._wake = asyncio.Event()
        self._diverged: asyncio.Task[None] | None = None
        self._safing: asyncio.Task[None] | None = None
        self._background: set[asyncio.Task[Any]] = set()
        self._aborted_unstarted: set[str] = set()
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
        elif isinstance(event, SafingReported):
            self._on_safing(event)
        elif isinstance(event, LinkUp):
            if active is not None and not active.stop.is_set():
                refusal = robot_mismatch(active.robot, RobotIdentity.of_hello(event.hello))
                if refusal is not None:
                    self._foreign_vehicle(active, refusal)
            self._wake.set()

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

    def command_stages(self) -> dict[str, int]:
        """The running pass's commands by stage now (none without a pass): for /metrics."""
        active = self._active
        return {} if active is None else active.tracker.counts()

    def uplink_leads_s(self) -> list[float]:
        """The running pass's uplink leads so far: onboard s between each acknowledged
        command's arrival on board and its tag (:meth:`Uplink.fill_margins_s`): for
        /metrics."""
        active = self._active
        return [] if active is None else active.uplink.fill_margins_s()

    # -- start ---------------------------------------------------------------------------

    def _refuse_unless_commanding(self) -> None:
        """A standby (or a holder whose lease is lapsing) starts and aborts nothing."""
        refusal = None if self._authority is None else self._authority.refusal()
        if refusal is not None:
            raise refusal

    async def start(self, pass_id: str, actor: str) -> None:
        async with self._lock:
            self._refuse_unless_commanding()
            if self._active is not None:
                raise Conflict(f"pass {self._active.name!r} is running; one pass at a time")
            link = self._link
            if not link.connected:
                raise LinkUnavailable("no spacecraft is connected: a pass needs the link")
            if link.safing.mode == "safe":
                raise ConflictError(
                    "vehicle_safe",
                    f"the vehicle {link.vehicle!r} is in SAFE (on-board safing): an operator's "
                    "safe exit must end it before a pass can start",
                    link.safing.status(),
                )
            # The window opens before the start transaction: storing thousands of commands
            # takes longer than the relay delay at high time scales, and the frames
            # generated meanwhile must already find their pass.
            window = self._downlink.open_window(
                canonical_id(pass_id, what="pass"), link.onboard_now_ns()
            )
            lead_s = self._start_lead(link.time_scale)
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
            if started is None:
                self._downlink.drop_window(window)
                raise ConflictError(
                    "robot_mismatch", refusal or "robot mismatch", events[0].event.detail()
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
            log.info(
                "pass %s started by %s: %d commands",
                started.name,
                actor,
                len(commands),
                extra={
                    "pass_id": started.pass_id,
                    "fields": {"event": "pass_started", "actor": actor, "commands": len(commands)},
                },
            )

    def _begin(self, active: ActivePass, body: Coroutine[Any, Any, None]) -> None:
        self._active = active
        self.fill_margins_s = []
        # The task copies the context: whatever it logs names its pass (server/logs.py).
        named = current_pass.set(active.pass_id)
        try:
            active.task = asyncio.create_task(body, name=f"pass-{active.pass_id}")
        finally:
            current_pass.reset(named)

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
        if self._authority is not None and not self._authority.may_command():
            # the lease lapsing (the database does not answer): nothing goes up, the vehicle
            # flies what it holds; what can no longer arrive expires (a 20 s outage across
            # the pass's LOS left 40 commands queued for good)
            with contextlib.suppress(LinkUnavailable):
                active.tracker.record_expired(up.expire(link.onboard_now_ns()), clock.time_ns())
            return clock.monotonic() + LINK_DOWN_POLL_S
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
                if not link.clock_confirmed:
                    active.refusals.sent_unconfirmed(cmd.seq)
        if first or again:
            counts = [(c.seq, c.transmissions) for c in again]
            active.tracker.record_sent(released_ns, first, counts)
        return up.next_wake(link.mono_at_onboard)

    async def _finish(self, active: ActivePass) -> None:
        """After LOS: the tracker resolves the last acknowledgements, then ``complete``."""
        left = await active.tracker.resolve(active.stop, ask_expired=active.resumed)
        if active.stop.is_set():
            return  # the abort has the tracker now
        if left:
            log.warning("pass %s: %d commands still unacknowledged", active.pass_id, left)
        # The reason says the outcome (server.services.summary), counted in the transition's
        # own transaction, after the stage writes queued before it.
        now_ns, clock, pass_id = self._clock.time_ns(), self._clock, active.pass_id

        def complete(session: Session) -> list[Recorded]:
            reason = f"complete, {command_outcome(session, pass_id).sentence()}"
            return [transition(session, clock, pass_id, "complete", "ground", reason, now_ns)]

        await self._db.write(complete)
        active.tracker.close()
        if self._active is active:
            self._active = None

    def _ground_transition(
        self, pass_id: str, to: str, reason: str, **window_ns: int | None
    ) -> Callable[[Session], list[Recorded]]:
        """The ground's own transition of the pass to ``to``, timed now."""
        now_ns, clock = self._clock.time_ns(), self._clock
        return lambda s: [transition(s, clock, pass_id, to, "ground", reason, now_ns, **window_ns)]

    def _background_task(self, coro: Coroutine[Any, Any, None]) -> None:
        task = asyncio.get_running_loop().create_task(coro)
        self._background.add(task)
        task.add_done_callback(self._background.discard)

    # -- shared by the abort and the handover ---------------------------------------------

    async def _stop_pass_task(self, active: ActivePass) -> None:
        """Stop the pass's uplink and wait for its task (an abort or a handover; not the
        task itself, when it is the one stopping)."""
        active.stop.set()
        active.uplink.stop()
        self._wake.set()
        if active.task is not None and active.task is not asyncio.current_task():
            with contextlib.suppress(Exception, asyncio.CancelledError):
                await active.task
