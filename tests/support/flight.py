"""The spacecraft process flown in the test's own event loop, stopped (drained) on the way
out, however the test leaves."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Awaitable, Callable
from contextlib import asynccontextmanager

from spacecraft.process import SpacecraftProcess


@asynccontextmanager
async def flying(
    process: SpacecraftProcess, drain_s: float = 40.0
) -> AsyncIterator[Callable[[], Awaitable[None]]]:
    """``process`` running; what it yields stops it and waits (at most ``drain_s``, a hang
    guard) for it to drain: for a test that lands it early, before looking at what it left.
    Landed again on the way out (a no-op when landed)."""
    stop = asyncio.Event()
    task = asyncio.create_task(process.run(stop))

    async def land() -> None:
        stop.set()
        await asyncio.wait_for(task, drain_s)

    try:
        yield land
    finally:
        await land()
