"""A request's write run as a job in a worker process (:mod:`server.services.workers`), on
the job's own database connection: planning, a plan document's check, the post-pass
analyses. One way for every route that does it (:data:`JobsDep`): the operation is called
``op(session=..., actor=..., now_ns=..., **kwargs)`` in the job, commits there, and what it
wrote is published here once the job is back (``WorkerPool.run_written``)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Annotated, Any, TypeVar

from fastapi import Depends, Request

from server.api.deps import ClockDep, SettingsDep, WorkersDep
from server.services.clock import Clock
from server.services.events import with_written
from server.services.jobs import session_job
from server.services.workers import WorkerPool
from server.settings import Settings

T = TypeVar("T")

__all__ = ["Jobs", "JobsDep"]


@dataclass(frozen=True)
class Jobs:
    """The worker pool as one request uses it: its client (watched for a disconnect), the
    database it writes to and the clock its writes are timed on."""

    http: Request
    settings: Settings
    workers: WorkerPool
    clock: Clock

    @property
    def robot_files(self) -> tuple[str, ...]:
        """The robot descriptions the server was given (as text: a job's arguments are
        pickled), for an operation that finds a plan's robot by its hash."""
        return tuple(str(p) for p in self.settings.robot_files)

    async def written(
        self, op: Callable[..., T], /, *, actor: str, what: str, deadline_s: float, **kwargs: Any
    ) -> T:
        """``op(session=..., actor=actor, now_ns=now, **kwargs)`` in a job that commits on its
        own connection; its result. ``what`` names the work in the pool's messages (503
        ``busy``, 504 past ``deadline_s``)."""
        result: T = await self.workers.run_written(
            session_job,
            self.settings.resolved_database_url(),
            partial(with_written, op),
            actor=actor,
            now_ns=self.clock.time_ns(),
            deadline_s=deadline_s,
            what=what,
            client=self.http,
            **kwargs,
        )
        return result


async def _jobs(http: Request, settings: SettingsDep, workers: WorkersDep, clock: ClockDep) -> Jobs:
    return Jobs(http, settings, workers, clock)


JobsDep = Annotated[Jobs, Depends(_jobs)]
