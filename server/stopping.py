"""How ``hikoboshi serve`` stops (SIGTERM, Ctrl-C): docs/operations.md "A graceful stop is a
handover" and "Stopping with requests in flight".

:class:`GroundServer` is uvicorn's server with :func:`begin_shutdown` first: the worker pool
stops (every request it holds answered 503), the spacecraft's link closes, and, beside a
standby, the pass is handed to the vehicle and the command lease released before uvicorn
waits for its requests, so the standby takes over within its next renewal. The lifespan's
shutdown (:func:`server.app.create_app`) does the rest.
"""

from __future__ import annotations

import asyncio
import logging
import socket
import time

import uvicorn
from fastapi import FastAPI

from server.services._console_jetstream import AcrossGrounds
from server.services.alarms import AlarmService
from server.services.authority import CommandAuthority
from server.services.dbworker import Database
from server.services.link import GroundLink
from server.services.runner import PassRunner
from server.services.workers import WorkerPool

__all__ = ["STOP_DATABASE_WAIT_S", "GroundServer", "begin_shutdown"]

log = logging.getLogger("hikoboshi.ground")

#: Wall s a stopping ground waits for a database that does not answer before the writes it
#: still holds fail (each logged): the next ground recovers them from the vehicle.
STOP_DATABASE_WAIT_S = 10.0


async def begin_shutdown(app: FastAPI) -> None:
    """The server is stopping (SIGTERM): before the HTTP server waits for the requests in
    flight, stop the worker pool, so that every request waiting for a worker or running in
    one is answered 503 ``shutting_down`` at once and no job process is left running
    (docs/operations.md "Stopping"); stop commanding (the vehicle's link is refused from
    here, so it goes to another ground); close the spacecraft's link (1001), which its
    handler records, rather than leave it to be cancelled; and, beside a standby, hand the
    pass over and release the lease (:func:`_give_up_command`). The lifespan's shutdown does
    the rest."""
    db: Database | None = getattr(app.state, "db", None)
    if db is not None:  # a database away at the stop: its journal fails, loudly, not hangs
        db.give_up(STOP_DATABASE_WAIT_S)
    workers: WorkerPool | None = getattr(app.state, "workers", None)
    if workers is not None:
        await workers.close()
    authority: CommandAuthority | None = getattr(app.state, "authority", None)
    if authority is not None:  # before the link closes: the vehicle does not come back here
        authority.stop_commanding()
    link: GroundLink | None = getattr(app.state, "link", None)
    if link is not None:
        await link.going_away()
    await _give_up_command(app)


async def _give_up_command(app: FastAPI) -> None:
    """A graceful stop beside a standby: the pass in flight is handed to the vehicle, the
    command path's last writes are flushed, and the lease is released at once, before the
    HTTP server waits for its requests and the consoles close, so the standby takes over
    within its next renewal rather than after the whole stop (docs/operations.md "One ground
    in command"). On SQLite the file's lock is the lease: nothing to hand to anyone."""
    authority: CommandAuthority | None = getattr(app.state, "authority", None)
    if authority is None or authority.policy.exclusive or not authority.holder:
        return
    runner: PassRunner | None = getattr(app.state, "runner", None)
    alarms: AlarmService | None = getattr(app.state, "alarms", None)
    db: Database | None = getattr(app.state, "db", None)
    steps: dict[str, float] = {}
    began = time.monotonic()

    def step(name: str) -> None:
        nonlocal began
        now = time.monotonic()
        steps[name] = round(now - began, 2)
        began = now

    async def flush() -> None:
        if runner is not None:
            await runner.shutdown()
            step("pass handed over")
        if alarms is not None:
            await alarms.close()
            step("alarms written")
        if db is not None:
            await db.drain()
            step("writes flushed")
        across: AcrossGrounds | None = getattr(app.state, "across", None)
        if across is not None:  # the consoles' last frames, before the next ground's
            await across.bus.flush(STOP_DATABASE_WAIT_S)
            step("live messages published")

    # A graceful stop hands over no later than a crash would: past the lease's time to
    # live, the writes still queued are left (refused once the next ground holds the
    # lease); that ground recovers the stages from the vehicle, as after a kill.
    budget = authority.policy.ttl_s
    flushing = asyncio.ensure_future(flush())
    # still running past the budget, it ends in the lifespan's shutdown (its error logged)
    flushing.add_done_callback(_log_failure)
    try:
        await asyncio.wait_for(asyncio.shield(flushing), budget)
    except TimeoutError:
        log.warning(
            "stopping: the command path's writes not flushed within %g s (the lease's time "
            "to live): the lease is released, the ground in command next asks the vehicle",
            budget,
            extra={"fields": {"event": "handover_unflushed", "journal": db.journal if db else 0}},
        )
    except Exception:
        log.exception("the handover's flush failed: the lease is left to expire")
        return
    await authority.close()
    step("lease released")
    log.info(
        "stopping: %s",
        ", ".join(f"{name} in {s:g} s" for name, s in steps.items()),
        extra={
            "fields": {
                "event": "handover_steps",
                **{k.replace(" ", "_"): v for k, v in steps.items()},
            }
        },
    )


def _log_failure(done: asyncio.Future[None]) -> None:
    if not done.cancelled() and (error := done.exception()) is not None:
        log.error("stopping: the handover's flush failed: %r", error)


class GroundServer(uvicorn.Server):
    """uvicorn's server for ``hikoboshi serve``: on SIGTERM (or Ctrl-C) it calls
    :func:`begin_shutdown` before its own shutdown, which waits a few seconds for the
    requests in flight and cancels the rest (those answer JSON too:
    :mod:`server.api.stopping`)."""

    def __init__(self, config: uvicorn.Config, app: FastAPI) -> None:
        super().__init__(config)
        self.ground = app

    async def shutdown(self, sockets: list[socket.socket] | None = None) -> None:
        try:
            await begin_shutdown(self.ground)
        except Exception:
            log.exception("stopping the worker pool failed")
        await super().shutdown(sockets)
