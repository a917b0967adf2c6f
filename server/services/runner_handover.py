"""A pass across a change of ground (:class:`server.services.runner.PassRunner`'s part).

**Graceful stop** (:meth:`PassHandover.shutdown`, SIGTERM): a handover, not an abort. The
uplink and the pass's task stop, the stage writes already made are flushed, a
``ground_stopped`` event says what the vehicle holds, and the pass stays ``running`` (or
``los``) with its telemetry window open: nothing is cancelled, the vehicle flies what it
holds under its LOS policy, and the next process resumes the pass exactly as after a crash.

**Restart** (and a standby taking the command lease over): :meth:`PassHandover.recover`
reopens the telemetry windows stored on the passes and carries out the decisions of
:mod:`server.services.recovery` (resume a pass left ``running`` or ``los``, abort the
others; a ``safed`` pass is final and stays so), hands the link the vehicle's last safing
episode, and asks the vehicle, once it is back, about the commands of ended passes still
``sent`` or ``received`` (and of a pass it aborts after all). A resumed pass's uplink holds
after a gap past the lead window (:mod:`server.services.continuity`).

**Stand-down** (:meth:`PassHandover.stand_down`): another ground took the command lease
(server/services/authority.py); this one stops commanding at once and writes nothing.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging

from sqlalchemy.orm import Session

from server.services.continuity import ResumedUplink
from server.services.events import GroundStopped, PassResumed, Recorded, event_job, record
from server.services.link import LinkUnavailable, TelemetryWindow
from server.services.pass_reasons import handover_reason
from server.services.pass_states import ActivePass
from server.services.recovery import (
    AbortPass,
    UnfinishedPass,
    decide,
    resume_refusal,
    spacecraft_back,
)
from server.services.recovery import load as load_recovery
from server.services.runner_base import RunnerParts
from server.services.tracker import CommandTracker
from server.storage import repository as repo

__all__ = ["PassHandover"]

log = logging.getLogger("hikoboshi.ground.runner")


class PassHandover(RunnerParts):
    """Recovery, graceful stop and stand-down (see the module docstring)."""

    async def recover(self) -> None:
        """After the service (re)starts: reopen the telemetry windows of recent passes (late
        and resent frames still reach their pass), and carry out the decisions of
        :mod:`server.services.recovery` on the passes the previous process left unfinished:
        abort, or resume once the spacecraft is back (see the module docstring)."""
        link = self._link
        found = await self._db.run(load_recovery)
        if found.safing is not None and link.safing.last is None:
            link.safing.restore(found.safing.report, found.safing.pass_id)
        opened = {
            w.pass_id: self._downlink.open_window(w.pass_id, w.start_ns, w.end_ns)
            for w in found.windows
        }
        for ended in found.unresolved:
            log.info("pass %s: %d commands to ask about", ended.id, ended.unresolved)
            self._background_task(self._resolve(self._trackers.stored(ended.id, ended.commands)))
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
            if self._closing.is_set():
                tracker.close()
                return
            if p.id in self._aborted_unstarted:  # an operator aborted it meanwhile
                self._aborted_unstarted.discard(p.id)
                refusal = None
            elif refusal is None:
                self._begin_resumed(p, window, tracker)
                return
            else:
                await self._abort_locked(p.id, "ground", refusal)
        # what the vehicle did with the commands sent before the restart
        await self._resolve(tracker)

    def _begin_resumed(
        self, p: UnfinishedPass, window: TelemetryWindow, tracker: CommandTracker
    ) -> None:
        link = self._link  # the uplink holds after a gap past the lead window (continuity)
        uplink = ResumedUplink(p, link, self._settings, self._db, self._clock, tracker)
        tags = {r.seq: r.execute_time_ns for r in p.commands}
        active = ActivePass.of(p.id, p.name, uplink, window, tracker, tags, p.robot, resumed=True)
        if p.state == "los":
            uplink.stop()
            self._begin(active, self._finish(active))
        else:
            self._begin(active, self._run(active))

    async def _resolve(self, tracker: CommandTracker) -> None:
        """The fates of a pass's commands left ``sent`` or ``received`` when it ended (or
        was aborted after a restart): asked about once the vehicle is back and their tags
        have passed (:meth:`CommandTracker.resolve`), until the service stops."""
        try:
            await tracker.resolve(self._closing)
        finally:
            tracker.close()

    async def shutdown(self) -> None:
        """The service stops (a graceful stop): an abort or a safing in progress ends first;
        a pass in flight is handed to the vehicle, not aborted (:meth:`_hand_over`); the
        background resolutions stop where they are; the stage writes made are flushed."""
        for pending in (self._safing, self._diverged):
            if pending is not None:
                with contextlib.suppress(Exception, asyncio.CancelledError):
                    await pending
        async with self._lock:  # no start, abort or resume from here
            self._closing.set()
            active = self._active
            if active is not None:
                try:
                    await self._hand_over(active)
                except Exception:
                    log.exception("pass %s: the handover failed", active.pass_id)
        for task in list(self._background):
            with contextlib.suppress(Exception, asyncio.CancelledError):
                await task
        await self._db.drain()

    async def stand_down(self) -> None:
        """Another ground took the command lease: stop commanding at once and write nothing
        (the database refuses this ground's writes now). The pass's uplink and task stop,
        the background resolutions end; the pass stays as the record has it, for the ground
        in command to resume. This ground may take the lease again later
        (:meth:`recover` then runs again)."""
        async with self._lock:
            self._closing.set()
            active = self._active
            if active is not None:
                await self._stop_pass_task(active)
                active.tracker.close()
                if self._active is active:
                    self._active = None
                log.warning("pass %s: handed to the ground in command", active.pass_id)
            for task in list(self._background):
                task.cancel()
                with contextlib.suppress(Exception, asyncio.CancelledError):
                    await task
            self._closing = asyncio.Event()

    async def _hand_over(self, active: ActivePass) -> None:
        """The graceful stop of a pass in flight: the uplink and the pass's task stop, the
        stage writes already made are flushed, and a ``ground_stopped`` event says what the
        vehicle holds. The pass stays in its state (``running`` or ``los``), its telemetry
        window open, no command cancelled: the vehicle flies what it holds under its LOS
        policy, and the next process resumes the pass as after a crash
        (:mod:`server.services.recovery`)."""
        await self._stop_pass_task(active)
        onboard: int | None = None
        with contextlib.suppress(LinkUnavailable):
            onboard = self._link.onboard_now_ns()  # the clock outlives the socket
        tracker = active.tracker
        loaded, unsent = len(tracker.outstanding()), len(tracker.in_stage("queued"))
        policy = self._link.los_policy
        reason = handover_reason(onboard, active.first_tag_ns, loaded, unsent, policy)
        pass_id, clock = active.pass_id, self._clock

        def job(session: Session) -> list[Recorded]:
            state = repo.get_pass(session=session, pass_id=pass_id, refresh=True).state
            stopped = GroundStopped(
                actor="ground", pass_id=pass_id, state=state, reason=reason,
                onboard_time_ns=onboard, loaded=loaded, unsent=unsent, los_policy=policy,
            )  # fmt: skip
            return [record(session, stopped, clock.time_ns())]

        # Ahead of the stage writes still queued (a control job: a backlog of thousands on a
        # loaded PostgreSQL held it 20 s): the record says at once what the vehicle holds,
        # and those writes follow (or, past the stop's budget, the next ground asks the
        # vehicle for them: server/stopping.py).
        await self._db.write(job, control=True)
        tracker.close()
        if self._active is active:
            self._active = None
        log.info("pass %s: %s", pass_id, reason)
