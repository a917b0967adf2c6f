"""What the ground's link does with a message it cannot read (docs/protocol.md, "Malformed
messages: a noisy link"): :class:`LinkNoise` acts on what
:class:`~server.services.malformed.MalformedGuard` decides.

- It answers a malformed message with ``error`` when the guard's rate allows (never an
  ``error`` of the vehicle's, readable or not), and closes the connection (1008, audited as
  ``link_closed_malformed``) only when the guard finds its stream unusable: nothing
  readable on it for a whole interval under a run of malformed messages. A flood beside
  valid frames is dropped and counted.
- It writes one audit row per kind per interval: the message that ends an interval audits
  it, and an auditor task waits on the injected clock for the end of the one it opens (a
  quiet link opens none).

Nothing here waits for the database (its rows are queued), and the event loop is let go
after each malformed message, so the uplink's sends and the acknowledgements between the
noise go first.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable

from server.services.clock import Clock
from server.services.dbworker import Database
from server.services.events import LinkClosedMalformed, event_job, record
from server.services.link_connection import Connection
from server.services.malformed import MalformedGuard, MalformedPolicy, tally_events
from telemetry.wire import ErrorMsg, WireError, encode

__all__ = ["LinkNoise"]

log = logging.getLogger("hikoboshi.ground.link")


class LinkNoise:
    def __init__(
        self,
        *,
        db: Database,
        clock: Clock,
        policy: MalformedPolicy,
        send: Callable[[str], Awaitable[bool]],
        current: Callable[[], Connection | None],
    ) -> None:
        self._db = db
        self._clock = clock
        self._send = send
        #: the link's current connection (a reply goes only there)
        self._current = current
        #: the counts and the decisions (the link status reads them)
        self.guard = MalformedGuard(policy)
        #: ``error`` messages from the vehicle, readable or not
        self.errors_received = 0
        self._auditor: asyncio.Task[None] | None = None
        self._actor = "spacecraft"

    def error_received(self, conn: Connection, message: ErrorMsg, received: float) -> None:
        """A well-formed ``error`` from the vehicle: tallied, never answered (its text
        arrives escaped)."""
        self.errors_received += 1
        self._noisy(conn, received)
        self.guard.error_received(message.reason, message.ref_type, received)

    async def refuse(self, conn: Connection, exc: WireError, received: float) -> None:
        """A message of ``conn`` that did not decode, read at ``received``: counted,
        audited with its kind once per interval, answered with ``error`` (naming the
        reason; the wire's reasons hold no control character) at a bounded rate, the
        connection closed when its stream is unusable. A broken ``error`` from the vehicle
        is counted, never answered."""
        reason = str(exc)[:500]
        if exc.ref_type == "error":
            self.errors_received += 1
            reason = f"unreadable error message: {reason}"[:500]
        self._noisy(conn, received)
        verdict = self.guard.refused(conn.id, exc, reason, received)
        if verdict.reply is not None and conn is self._current():
            await self._send(encode(ErrorMsg(reason=verdict.reply, ref_type=exc.ref_type)))
        if verdict.close is not None:
            log.warning("closing the spacecraft's link: %s", verdict.close)
            closed = LinkClosedMalformed(
                actor=conn.actor,
                connection=conn.id,
                reason=verdict.close,
                count=verdict.run_count,
                interval_s=self.guard.policy.interval_s,
                unreadable_s=round(verdict.run_s, 3),
            )
            self._db.submit(event_job(closed, self._clock))
            with contextlib.suppress(Exception):
                await conn.close(1008, verdict.close)
        await asyncio.sleep(0)

    def _noisy(self, conn: Connection, now: float) -> None:
        """Before tallying a message of ``conn`` at ``now``: the interval it ends is
        audited, and an auditor waits for the end of the one it opens."""
        self._actor = conn.actor
        end = self.guard.interval_end()
        if end is not None and now >= end:
            self._audit_interval()
        if self._auditor is None or self._auditor.done():
            self._auditor = asyncio.create_task(self._audit_intervals(), name="link-noise")

    async def _audit_intervals(self) -> None:
        await asyncio.sleep(0)  # the message that started it is tallied first
        while (end := self.guard.interval_end()) is not None:
            await self._clock.sleep_until(end)
            if self.guard.interval_end() == end:
                self._audit_interval()

    def _audit_interval(self) -> None:
        """One audit row per kind of the open interval (queued, not waited for)."""
        events = tally_events(self.guard.take_interval(), self._actor, self._clock)
        if events:
            self._db.submit(lambda s: [record(s, e, self._clock.time_ns()) for e in events])

    def close(self) -> None:
        """The ground is stopping: what the open interval counted so far is audited."""
        if self._auditor is not None:
            self._auditor.cancel()
        self._audit_interval()
