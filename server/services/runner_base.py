"""What the pass runner's parts share (:class:`server.services.runner.PassRunner`, built
of :class:`~server.services.runner_ends.PassEnds` and
:class:`~server.services.runner_handover.PassHandover`): the collaborators and the state
the runner's constructor sets, and the steps one part asks of another."""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Coroutine
from typing import Any, Protocol

from sqlalchemy.orm import Session

from server.services.clock import Clock
from server.services.dbworker import Database, Publisher
from server.services.downlink import GroundDownlink
from server.services.errors import ConflictError
from server.services.event_log import Recorded
from server.services.link import GroundLink
from server.services.pass_states import ActivePass
from server.services.schedule_delete import ScheduleDeletes
from server.services.tracker import Trackers
from server.settings import Settings
from telemetry.wire import Safing

__all__ = ["Authority", "RunnerParts", "SafingAlarms"]

#: Onboard s after the last tag before LOS.
SETTLE_S = 2.0


class SafingAlarms(Protocol):
    """What the runner tells the alarms of the vehicle's safing (server.services.alarms)."""

    def vehicle_safed(self, pass_id: str | None, report: Safing) -> None: ...

    def vehicle_nominal(self, pass_id: str | None, report: Safing) -> None: ...


class Authority(Protocol):
    """Whether this ground may command the vehicle (server.services.authority)."""

    def may_command(self) -> bool: ...

    def refusal(self) -> ConflictError | None: ...


class RunnerParts:
    """The runner's state (set by its constructor) and the steps its parts share."""

    _link: GroundLink
    _downlink: GroundDownlink
    _db: Database
    _publisher: Publisher
    _trackers: Trackers
    _clock: Clock
    _settings: Settings
    _alarms: SafingAlarms | None
    _authority: Authority | None
    _active: ActivePass | None
    _lock: asyncio.Lock
    _wake: asyncio.Event
    _closing: asyncio.Event
    _safing: asyncio.Task[None] | None
    _diverged: asyncio.Task[None] | None
    _background: set[asyncio.Task[Any]]
    #: passes aborted while a resume of theirs waited for the vehicle (it then ends)
    _aborted_unstarted: set[str]
    _deletes: ScheduleDeletes
    _settle_ns: int

    def _begin(self, active: ActivePass, body: Coroutine[Any, Any, None]) -> None:
        raise NotImplementedError

    async def _run(self, active: ActivePass) -> None:
        raise NotImplementedError

    async def _finish(self, active: ActivePass) -> None:
        raise NotImplementedError

    async def _stop_pass_task(self, active: ActivePass) -> None:
        raise NotImplementedError

    def _background_task(self, coro: Coroutine[Any, Any, None]) -> None:
        raise NotImplementedError

    def _refuse_unless_commanding(self) -> None:
        raise NotImplementedError

    async def _abort_locked(
        self, pass_id: str, actor: str, reason: str, *, safed_at_ns: int | None = None
    ) -> None:
        raise NotImplementedError

    def _ground_transition(
        self, pass_id: str, to: str, reason: str, **window_ns: int | None
    ) -> Callable[[Session], list[Recorded]]:
        raise NotImplementedError
