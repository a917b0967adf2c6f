"""How a pass ends other than ``complete`` (:class:`server.services.runner.PassRunner`'s
part): an operator's or the ground's **abort** (the ``schedule_delete`` from the next grid
tag, the commands never sent or tagged after it ``cancelled``, the telemetry window closed
after it), the vehicle's **safing** (``safed``: no delete, the window kept
:data:`SAFED_TAIL_S` past it), and a vehicle that **diverged** from the plan (refusals in a
row, another robot connected mid-pass). The rules are in :mod:`server.services.runner`'s
docstring."""

from __future__ import annotations

import asyncio
import logging

from server.services.events import SafingReported, VehicleSafed, VehicleSafeExited, event_job
from server.services.pass_reasons import safed_reason
from server.services.pass_states import ActivePass, abort_job
from server.services.runner_base import RunnerParts
from server.services.schedule_delete import Deletion
from telemetry.wire import Safing

__all__ = ["SAFED_TAIL_S", "PassEnds"]

log = logging.getLogger("hikoboshi.ground.runner")

#: Onboard s of telemetry a safed pass keeps after the vehicle safed itself.
SAFED_TAIL_S = 60.0


class PassEnds(RunnerParts):
    """Abort, safing and divergence (see the module docstring)."""

    def _on_safing(self, event: SafingReported) -> None:
        """The vehicle's ``safing`` report. Any ``safe`` report stops a running pass's
        uplink at once and makes the pass ``safed`` (the first of an episode, or one that
        reaches a pass started or resumed meanwhile); the first of an episode is audited
        (``vehicle_safed``), and every one goes to the alarms (the 1 s repeats update the
        alarm). The report ending an episode is audited and clears the alarm."""
        report, state = event.report, self._link.safing
        actor = self._link.vehicle or "spacecraft"
        if report.state == "safe":
            active = self._active
            running = active is not None and not active.stop.is_set()
            if event.entered or running:
                state.pass_id = None if active is None else active.pass_id
            if active is not None and running:
                active.uplink.stop()  # before the runner can wake: nothing more goes up
                if self._safing is None:
                    self._safing = asyncio.get_running_loop().create_task(
                        self._safe_pass(active, report)
                    )
            if event.entered:
                safed = VehicleSafed(
                    actor=actor,
                    pass_id=state.pass_id,
                    since_time_ns=report.since_time_ns,
                    trigger=None if report.trigger is None else report.trigger.model_dump(),
                    cancelled=report.cancelled,
                    onboard_time_ns=report.onboard_time_ns,
                )
                self._db.submit(event_job(safed, self._clock))
            if self._alarms is not None:
                self._alarms.vehicle_safed(state.pass_id, report)
        elif event.exited:
            exited = VehicleSafeExited(
                actor=actor,
                pass_id=state.pass_id,
                request_id=report.exit_request_id,
                since_time_ns=report.since_time_ns,
                onboard_time_ns=report.onboard_time_ns,
            )
            self._db.submit(event_job(exited, self._clock))
            if self._alarms is not None:
                self._alarms.vehicle_nominal(state.pass_id, report)

    async def _safe_pass(self, active: ActivePass, report: Safing) -> None:
        try:
            async with self._lock:
                if self._active is not active or active.stop.is_set():
                    return  # aborted meanwhile: it stays so
                since = report.since_time_ns or report.onboard_time_ns
                await self._abort_locked(
                    active.pass_id,
                    self._link.vehicle or "spacecraft",
                    safed_reason(report, active.first_tag_ns),
                    safed_at_ns=since,
                )
        except Exception:
            log.exception("pass %s: marking it safed failed", active.pass_id)
        finally:
            self._safing = None

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

    async def abort(self, pass_id: str, actor: str, reason: str) -> None:
        async with self._lock:
            self._refuse_unless_commanding()
            await self._abort_locked(pass_id, actor, reason)
        log.info(
            "pass aborted by %s: %s",
            actor,
            reason,
            extra={
                "pass_id": pass_id,
                "fields": {"event": "pass_aborted", "actor": actor, "reason": reason},
            },
        )

    async def _abort_locked(
        self, pass_id: str, actor: str, reason: str, *, safed_at_ns: int | None = None
    ) -> None:
        """Abort ``pass_id``, or, with ``safed_at_ns`` (the onboard time the vehicle safed
        itself), make it ``safed``: no ``schedule_delete`` then (the vehicle emptied its
        schedule), the window kept :data:`SAFED_TAIL_S` past the safing."""
        link = self._link
        active = self._active if self._active and self._active.pass_id == pass_id else None
        if active is None:  # a pass not running here (restart): every command not sent
            await self._abort_write(pass_id, actor, reason, None, None, None)
            self._aborted_unstarted.add(pass_id)  # a resume waiting for the vehicle ends
            return
        await self._stop_pass_task(active)
        up = active.uplink
        # Commands the vehicle holds that this ground never sent (a pass resumed after a
        # ground that was killed before it filed their sends): on board all the same.
        on_board = link.last_command_seq if active.resumed else -1
        sent = {c.seq for c in up.commands if c.transmissions or c.seq <= on_board}
        deletion: Deletion | None = None
        if safed_at_ns is None and sent:
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
        if safed_at_ns is not None:
            end = safed_at_ns + round(SAFED_TAIL_S * 1e9)
        self._downlink.close_window(active.window, end)
        # Cancelled on the ground: never sent, and (the delete's T known) tagged from T on.
        cancel = [c.seq for c in up.commands if c.seq not in sent]
        if from_ns is not None:
            cancel += [c.seq for c in up.commands if c.seq in sent and c.tag_ns >= from_ns]
        to = "aborted" if safed_at_ns is None else "safed"
        await self._abort_write(pass_id, actor, reason, cancel, from_ns, end, to)
        active.tracker.cancelled(cancel)
        if self._active is active:
            self._active = None
        if deletion is not None or link.connected:
            # asked about first, queued or taken as expired (their tags passed unheard)
            unfiled = sorted(sent - {c.seq for c in up.commands if c.transmissions} - set(cancel))
            self._background_task(
                self._deletes.after_abort(
                    active.tracker,
                    deletion,
                    self._closing,
                    safed=safed_at_ns is not None,
                    ask_about=unfiled,
                )
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
        to: str = "aborted",
    ) -> None:
        """The abort's transaction, ahead of the stage writes still queued: the operator waits
        for it, and none of them can undo it (the vehicle's own word still overrules)."""
        job = abort_job(
            pass_id=pass_id, actor=actor, reason=reason, clock=self._clock, cancel=cancel,
            from_ns=from_ns, end_ns=end_ns, to=to,
        )  # fmt: skip
        await self._db.run(job, control=True)
