"""The ground's clocks: an injected wall/monotonic clock, and its estimate of the onboard one.

:class:`Clock` is what the runner and the link read time from and sleep on. The service uses
:class:`SystemClock`; tests use :class:`ManualClock`, which only moves when the test moves it,
so the uplink's rules (window filling, retransmission, expiry, abort, LOS, restart) are
tested in simulated time without sleeping on the wall clock.

:class:`OnboardClock` maps the ground's monotonic clock to the onboard clock. ``hello`` is
the session handshake, not delayed by the relay, so it gives the mapping at the instant it
is read off the socket. A ground that reads it late (a process still starting, a stalled
event loop) would believe the onboard clock is *behind* where it is, and every later
message read late errs the same way, never ahead. So the mapping is refined from every
later onboard time stamp the ground receives (``pong``, ``command_ack``, telemetry frames):
the stamp plus the relay's nominal one-way delay is a lower bound of the onboard time at
reading, less the jitter. A sample that puts the onboard clock further ahead than the
current mapping by more than the jitter allowance moves the mapping forward to it (less
the allowance); nothing moves it back but a new ``hello``.
"""

from __future__ import annotations

import asyncio
import contextlib
import heapq
import itertools
import time
from typing import Any, Protocol

__all__ = ["Clock", "ManualClock", "OnboardClock", "SystemClock"]


class Clock(Protocol):
    def monotonic(self) -> float:
        """Seconds, monotonic (the ground's own time base)."""
        ...

    def time_ns(self) -> int:
        """Wall-clock nanoseconds (UTC), for the ground times the archive keeps."""
        ...

    def time_ns_at(self, mono: float) -> int:
        """The wall-clock nanoseconds of the earlier monotonic instant ``mono`` (an arrival
        timed once, when it was read off the socket)."""
        ...

    async def sleep_until(self, deadline: float, wake: asyncio.Event | None = None) -> None:
        """Return at ``deadline`` (monotonic s), or as soon as ``wake`` is set."""
        ...


class SystemClock:
    def monotonic(self) -> float:
        return time.monotonic()

    def time_ns(self) -> int:
        return time.time_ns()

    def time_ns_at(self, mono: float) -> int:
        return time.time_ns() - round((time.monotonic() - mono) * 1e9)

    async def sleep_until(self, deadline: float, wake: asyncio.Event | None = None) -> None:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            await asyncio.sleep(0)
            return
        if wake is None:
            await asyncio.sleep(remaining)
            return
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(wake.wait(), remaining)


class ManualClock:
    """Simulated time: :meth:`advance` moves it and wakes the sleepers whose deadline has
    come, in deadline order, letting each run before the next is woken."""

    def __init__(self, start: float = 1000.0, wall_ns: int = 1_800_000_000 * 10**9) -> None:
        self._now = start
        self._wall0 = wall_ns - round(start * 1e9)
        self._sleepers: list[tuple[float, int, asyncio.Future[None]]] = []
        self._ids = itertools.count()

    def monotonic(self) -> float:
        return self._now

    def time_ns(self) -> int:
        return self._wall0 + round(self._now * 1e9)

    def time_ns_at(self, mono: float) -> int:
        return self._wall0 + round(mono * 1e9)

    async def sleep_until(self, deadline: float, wake: asyncio.Event | None = None) -> None:
        if deadline <= self._now or (wake is not None and wake.is_set()):
            await asyncio.sleep(0)
            return
        future: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        heapq.heappush(self._sleepers, (deadline, next(self._ids), future))
        waiter = None if wake is None else asyncio.ensure_future(wake.wait())
        try:
            waits: list[asyncio.Future[Any]] = [future] if waiter is None else [future, waiter]
            await asyncio.wait(waits, return_when=asyncio.FIRST_COMPLETED)
        finally:
            if waiter is not None:
                waiter.cancel()
            if not future.done():
                future.cancel()

    def jump(self, seconds: float) -> None:
        """Move time forward without waking anyone: a stalled process, whose sleepers find
        their deadlines long past when it runs again."""
        self._now += seconds

    async def settle(self, rounds: int = 20) -> None:
        """Let every task that can run, run (a few loop turns)."""
        for _ in range(rounds):
            await asyncio.sleep(0)

    async def advance(self, seconds: float, step: float | None = None) -> None:
        """Move time forward by ``seconds`` (in steps of at most ``step``), waking sleepers
        at their deadlines and letting the loop run after each."""
        end = self._now + seconds
        await self.settle()  # what is runnable now runs at this instant, before time moves
        while True:
            self._sleepers = [s for s in self._sleepers if not s[2].done()]
            heapq.heapify(self._sleepers)
            nxt = self._sleepers[0][0] if self._sleepers else end
            target = min(end, nxt) if step is None else min(end, nxt, self._now + step)
            self._now = max(self._now, target)
            while self._sleepers and self._sleepers[0][0] <= self._now:
                _, _, future = heapq.heappop(self._sleepers)
                if not future.done():
                    future.set_result(None)
            await self.settle()
            if self._now >= end:
                return


class OnboardClock:
    """The onboard clock as the ground knows it (see the module docstring)."""

    def __init__(
        self, clock: Clock, onboard_ns: int, mono: float, scale: float, jitter_allowance_s: float
    ) -> None:
        self._clock = clock
        self.scale = scale
        self._ref_ns = onboard_ns
        self._ref_mono = mono
        self._allowance_ns = round(jitter_allowance_s * 1e9)
        #: onboard ns the mapping has been moved forward by since the hello
        self.corrected_ns = 0
        self.corrections = 0

    def now_ns(self, mono: float | None = None) -> int:
        at = self._clock.monotonic() if mono is None else mono
        return self._ref_ns + round((at - self._ref_mono) * self.scale * 1e9)

    def mono_at(self, onboard_ns: int) -> float:
        """The monotonic instant at which the onboard clock reads ``onboard_ns``."""
        return self._ref_mono + (onboard_ns - self._ref_ns) / 1e9 / self.scale

    def observe(self, stamp_ns: int, transit_s: float, read_mono: float) -> bool:
        """A message stamped ``stamp_ns`` onboard, ``transit_s`` onboard seconds on its way
        (nominal), read at ``read_mono``: move the mapping forward if it shows the onboard
        clock further ahead than the jitter allows. Whether it moved."""
        ahead = stamp_ns + round(transit_s * 1e9) - self.now_ns(read_mono) - self._allowance_ns
        if ahead <= 0:
            return False
        self._ref_ns += ahead
        self.corrected_ns += ahead
        self.corrections += 1
        return True
