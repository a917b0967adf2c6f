"""Capacity lanes: what a request may draw on, decided in one place (docs/security.md,
*Capacity*).

The edge (:mod:`server.api.edge`) classifies every request once, after authenticating it,
by its route and its caller's role (:func:`lane_of`), puts the lane in the ASGI scope
(:func:`request_lane`) and admits it (:class:`Admission`):

- :attr:`Lane.LIVE`: liveness (``/api/health``), the link status and the websockets (the
  consoles', the spacecraft's). ``async`` routes that use no thread and no pooled database
  connection; never counted, never refused for load.
- :attr:`Lane.OPERATOR`: every request with an operator's token (control: start, abort,
  safing exit, alarm acknowledgement; and the operator's own reads). Never counted against
  the viewers' cap; its database sessions come from the operators' pool
  (``operator_pool_size``), which no viewer uses.
- :attr:`Lane.VIEWER`: every other authenticated request. At most ``viewer_requests_max``
  run at once in the whole server; past that a request waits its turn, parked on the
  event loop (no thread, no work), while fewer than ``viewer_queue`` wait and for at most
  ``viewer_queue_wait_s``; else 503 ``busy`` with ``Retry-After``. The cap is below the
  framework's thread limit (40 threads for synchronous routes and file streaming), so
  viewers never hold every thread an operator's request needs, nor enough to starve the
  event loop and the link's database worker of the interpreter; and waiting in turn
  costs nothing, where refusing at once had 200 viewers retrying every second.

Whatever the lane, a heavy read (:data:`HEAVY_ROUTES`: a recording, the report, its page
and figures, raw telemetry and its CSV and Parquet exports, a quantity across passes, an
analyses run, contact windows) is limited per token holder: past
``heavy_reads_per_token`` in flight, 429 ``too_many_requests`` with ``Retry-After``.

The counters live on the event loop (the edge admits and releases there): no locks.
"""

from __future__ import annotations

import asyncio
from collections import Counter, deque
from collections.abc import MutableMapping
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

from starlette.requests import HTTPConnection
from starlette.routing import compile_path

from server.settings import Role, Settings

__all__ = [
    "HEAVY_ROUTES",
    "LIVE_PATHS",
    "Admission",
    "Lane",
    "Refusal",
    "Ticket",
    "is_heavy",
    "lane_of",
    "request_lane",
    "set_lane",
]

#: Retry-After (s) of a refusal for the viewers' share (they wait first) and of a token's
#: heavy read past its share (its others take seconds at least).
BUSY_RETRY_AFTER_S = 1
HEAVY_RETRY_AFTER_S = 5

#: Where the edge leaves a request's lane in its ASGI scope.
_SCOPE_KEY = "hikoboshi.lane"


class Lane(StrEnum):
    LIVE = "live"
    OPERATOR = "operator"
    VIEWER = "viewer"


#: Paths of the live lane: ``async``, no thread, no pooled connection.
LIVE_PATHS = frozenset(
    {"/api/health", "/api/ready", "/api/command", "/api/link/status", "/api/console", "/api/link"}
)

#: ``(method, path template)`` of the heavy reads: each runs a worker process or streams a
#: file; limited per token holder. Matched on the request's path (no router involved), so
#: the edge decides before any route runs.
HEAVY_ROUTES = frozenset(
    {
        ("GET", "/api/passes/{pass_id}/recording.mcap"),
        ("GET", "/api/passes/{pass_id}/report"),
        ("GET", "/api/passes/{pass_id}/report.html"),
        ("GET", "/api/passes/{pass_id}/report/figures/{name}.png"),
        ("GET", "/api/passes/{pass_id}/telemetry"),
        ("GET", "/api/passes/{pass_id}/telemetry.csv"),  # the whole pass, streamed
        ("GET", "/api/passes/{pass_id}/telemetry.parquet"),  # the whole pass, built whole
        ("POST", "/api/passes/{pass_id}/analyses"),
        ("GET", "/api/windows"),  # contact windows, computed in a worker process
        ("GET", "/api/telemetry/across"),  # up to 20 passes' aggregates
    }
)
_HEAVY = tuple((method, compile_path(template)[0]) for method, template in HEAVY_ROUTES)


def is_heavy(method: str, path: str) -> bool:
    """Whether ``method path`` is a heavy read (HEAD as GET)."""
    method = "GET" if method == "HEAD" else method
    return any(m == method and regex.match(path) for m, regex in _HEAVY)


def lane_of(path: str, role: Role | None) -> Lane:
    """The lane of a request for ``path`` by a caller of ``role`` (None: no token, a public
    path)."""
    if path in LIVE_PATHS or role is None:
        return Lane.LIVE
    if role is Role.OPERATOR:
        return Lane.OPERATOR
    return Lane.VIEWER


def set_lane(scope: MutableMapping[str, Any], lane: Lane) -> None:
    scope[_SCOPE_KEY] = lane


def request_lane(connection: HTTPConnection) -> Lane:
    """The lane the edge gave this request (the viewers' when it gave none)."""
    lane: Lane = connection.scope.get(_SCOPE_KEY, Lane.VIEWER)
    return lane


@dataclass(frozen=True)
class Refusal:
    status: int
    code: str
    message: str
    retry_after_s: int


class Ticket:
    """An admitted request's share of the counters; :meth:`release` once it is answered
    (again: nothing)."""

    def __init__(self, admission: Admission, viewer: bool, holder: str | None) -> None:
        self._admission = admission
        self._viewer = viewer
        self._holder = holder
        self._released = False

    def release(self) -> None:
        if self._released:
            return
        self._released = True
        if self._viewer:
            self._admission._free()
        if self._holder is not None:
            self._admission._heavy_done(self._holder)


class Admission:
    """The server's counters of requests in flight: viewers' in all (running and waiting
    for a place), heavy reads per token holder. ``refused``: refusals so far, by code (for
    the benchmarks and the tests)."""

    def __init__(
        self,
        *,
        viewer_requests_max: int,
        heavy_reads_per_token: int,
        viewer_queue: int = 0,
        viewer_queue_wait_s: float = 0.0,
    ) -> None:
        self.viewer_requests_max = viewer_requests_max
        self.heavy_reads_per_token = heavy_reads_per_token
        self.viewer_queue = viewer_queue
        self.viewer_queue_wait_s = viewer_queue_wait_s
        self.viewers_in_flight = 0
        self.viewers_waiting = 0
        self.heavy_in_flight: Counter[str] = Counter()
        self.refused: Counter[str] = Counter()
        self._turns: deque[asyncio.Future[None]] = deque()

    @classmethod
    def of(cls, settings: Settings) -> Admission:
        return cls(
            viewer_requests_max=settings.viewer_requests_max,
            heavy_reads_per_token=settings.heavy_reads_per_token,
            viewer_queue=settings.viewer_queue,
            viewer_queue_wait_s=settings.viewer_queue_wait_s,
        )

    async def admit(self, lane: Lane, *, heavy: bool, holder: str | None) -> Ticket | Refusal:
        """A ticket for the request, or why it is refused (it holds nothing then). A viewer
        past the running cap waits for a place (no thread, no work: a parked coroutine), in
        turn, at most ``viewer_queue_wait_s``, when fewer than ``viewer_queue`` wait."""
        counted_heavy = holder if heavy and holder is not None else None
        if counted_heavy is not None and (
            self.heavy_in_flight[counted_heavy] >= self.heavy_reads_per_token
        ):
            self.refused["too_many_requests"] += 1
            return Refusal(
                429,
                "too_many_requests",
                f"{self.heavy_reads_per_token} heavy reads of this token are in flight: "
                "retry once one is done",
                HEAVY_RETRY_AFTER_S,
            )
        viewer = lane is Lane.VIEWER
        if viewer and self.viewers_in_flight >= self.viewer_requests_max:
            if counted_heavy is not None:  # its place in the token's share while it waits
                self.heavy_in_flight[counted_heavy] += 1
            try:
                placed = await self._wait_for_place()
            finally:
                if counted_heavy is not None:
                    self._heavy_done(counted_heavy)
            if not placed:
                self.refused["busy"] += 1
                return Refusal(
                    503,
                    "busy",
                    f"{self.viewer_requests_max} viewer requests are in flight and "
                    f"{self.viewers_waiting} wait: retry shortly",
                    BUSY_RETRY_AFTER_S,
                )
        elif viewer:
            self.viewers_in_flight += 1
        if counted_heavy is not None:
            self.heavy_in_flight[counted_heavy] += 1
        return Ticket(self, viewer, counted_heavy)

    async def _wait_for_place(self) -> bool:
        """Whether a place came free (handed over by :meth:`_free`, already counted)."""
        if self.viewers_waiting >= self.viewer_queue or self.viewer_queue_wait_s <= 0:
            return False
        turn: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._turns.append(turn)
        self.viewers_waiting += 1
        try:
            await asyncio.wait_for(asyncio.shield(turn), self.viewer_queue_wait_s)
            return True
        except TimeoutError:
            if turn.done():  # handed over as the wait ran out: keep it
                return True
            turn.cancel()
            return False
        except asyncio.CancelledError:
            if turn.done() and not turn.cancelled():
                self._free()  # handed over to a request that is gone: pass it on
            turn.cancel()
            raise
        finally:
            self.viewers_waiting -= 1

    def _free(self) -> None:
        """A viewer's place is free: to the next waiting request, if any, else counted
        free."""
        while self._turns:
            turn = self._turns.popleft()
            if not turn.done():
                turn.set_result(None)
                return
        self.viewers_in_flight -= 1

    def _heavy_done(self, holder: str) -> None:
        self.heavy_in_flight[holder] -= 1
        if self.heavy_in_flight[holder] <= 0:
            del self.heavy_in_flight[holder]
