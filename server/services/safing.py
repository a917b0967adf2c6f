"""The vehicle's on-board safing as the ground sees it, and the telecommand that ends it.

The vehicle protects itself (docs/protocol.md, "On-board safing"): at a red limit it holds
the arm, drops its schedule and reports ``safing`` (state ``safe``) at once and every second
while it stays safe; only the ground's ``safe_exit`` takes it out, answered by a ``safing``
report with state ``nominal`` and that request's id. The relay can lose any of them.

- :class:`VehicleSafingState` (held by the link) turns the stream of reports into the
  vehicle's mode and its episodes: the first report of an episode *enters* it (the repeats
  do not: an episode is known by its ``since_time_ns``), a ``nominal`` report after a safe
  one *exits* it. A new ``hello`` resets the mode to nominal: a safe vehicle sends its
  report right after its hello, a nominal one sends nothing.
- :class:`SafeExitSender` sends ``safe_exit`` and sends the same request again, on the
  injected clock, until the vehicle's ``nominal`` report naming it arrives or
  :data:`MAX_TRANSMISSIONS` copies went unanswered (a ``vehicle_safe_exit_unverified``
  event). Request ids are the ground's clock in milliseconds, so that a restarted ground
  never reuses one the vehicle remembers (it answers a known id with its first report).
- :func:`exit_confirmation`: the operator's typed confirmation, ``EXIT SAFE <vehicle>``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any, Literal

from server.services.clock import Clock
from server.services.dbworker import Database
from server.services.events import VehicleSafeExitUnverified, event_job
from telemetry.wire import SafeExit, Safing, encode

__all__ = [
    "MAX_TRANSMISSIONS",
    "RESEND_MARGIN_S",
    "SafeExitRefused",
    "SafeExitSender",
    "VehicleSafingState",
    "check_exit_request",
    "exit_confirmation",
]

log = logging.getLogger("hikoboshi.ground.safing")

#: Copies of one ``safe_exit`` before the ground gives up waiting for its report (about four
#: minutes at the nominal relay: under heavy loss both the copy and its answer can be lost).
MAX_TRANSMISSIONS = 30
#: Onboard s added to the round trip before a copy is sent again (the vehicle's reply
#: waits for its next onboard step; the relay's jitter).
RESEND_MARGIN_S = 2.0


def exit_confirmation(vehicle: str | None) -> str:
    """The text an operator types to take the vehicle out of SAFE."""
    return f"EXIT SAFE {vehicle or 'spacecraft'}"


class SafeExitRefused(Exception):
    """A ``safe_exit`` the ground will not send: ``code`` says why (``vehicle_not_safe``,
    ``confirmation_mismatch``)."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code


def check_exit_request(vehicle: str | None, mode: str, confirm: str) -> None:
    """Refuse (:class:`SafeExitRefused`) a ``safe_exit`` for ``vehicle`` in ``mode`` unless
    the vehicle is in SAFE and ``confirm`` is exactly :func:`exit_confirmation`'s text."""
    expected = exit_confirmation(vehicle)
    if confirm != expected:
        raise SafeExitRefused(
            "confirmation_mismatch", f"confirm must be exactly {expected!r}, got {confirm!r}"
        )
    if mode != "safe":
        raise SafeExitRefused("vehicle_not_safe", f"the vehicle {vehicle!r} is not in SAFE")


@dataclass
class VehicleSafingState:
    """The vehicle's mode from its ``safing`` reports (see the module docstring)."""

    mode: Literal["nominal", "safe"] = "nominal"
    #: the last report of the episode in progress, or the one that ended the last episode
    last: Safing | None = None
    #: the pass that was running when the episode began (None: none)
    pass_id: str | None = None
    #: onboard ns of the newest report of this connection: an older one is stale
    newest_ns: int | None = None

    @property
    def episode_open(self) -> bool:
        """An episode has begun and no report has ended it (whatever the mode since the last
        ``hello``)."""
        return self.last is not None and self.last.state == "safe"

    def on_report(self, report: Safing) -> tuple[bool, bool] | None:
        """File one report: (it enters an episode, it exits one); None for a stale report
        (older onboard than one already read on this connection: the relay's jitter can
        deliver a 1 s repeat after the exit's answer), which changes nothing."""
        if self.newest_ns is not None and report.onboard_time_ns < self.newest_ns:
            return None
        self.newest_ns = report.onboard_time_ns
        previous = self.last
        if report.state == "safe":
            # an episode is known by its since_time_ns: its repeats, and its report right
            # after a new hello, continue it
            entered = not (
                self.episode_open
                and previous is not None
                and previous.since_time_ns == report.since_time_ns
            )
            if not entered and previous is not None:
                # keep the entry's cancelled count (a repeat may say 0)
                report = report.model_copy(
                    update={"cancelled": max(previous.cancelled, report.cancelled)}
                )
            self.mode, self.last = "safe", report
            return entered, False
        exited = self.episode_open
        if exited:
            self.last = report.model_copy(
                update={"since_time_ns": report.since_time_ns or _since(previous)}
            )
        self.mode = "nominal"
        return False, exited

    def on_hello(self) -> None:
        """A new connection: nominal until the vehicle says otherwise (a safe vehicle sends
        its report right after its hello; a nominal one sends nothing). The episode stays
        known, so that report continues it instead of beginning another."""
        self.mode = "nominal"
        self.newest_ns = None

    def restore(self, last: Safing | None, pass_id: str | None) -> None:
        """After a restart: the last episode as the audit log has it (its entry, or the
        exit that ended it), so that the reports of a vehicle still safe continue it."""
        self.last, self.pass_id = last, pass_id

    def status(self) -> dict[str, Any] | None:
        """The last report as the link status shows it (None before any)."""
        if self.last is None:
            return None
        return {
            **self.last.model_dump(mode="json", exclude={"v", "type"}),
            "pass_id": self.pass_id,
        }


def _since(report: Safing | None) -> int | None:
    return None if report is None else report.since_time_ns


@dataclass
class SafeExitSender:
    """The ``safe_exit`` telecommand until the vehicle reports it left SAFE."""

    clock: Clock
    db: Database
    send: Callable[[str], Awaitable[bool]]  # the link's send
    #: wall s to wait for the answer to one copy (a round trip and a margin), read per copy
    answer_wait_s: Callable[[], float]
    pending: dict[int, asyncio.Task[None]] = field(default_factory=dict)
    done: dict[int, asyncio.Event] = field(default_factory=dict)

    def new_request_id(self) -> int:
        request_id = self.clock.time_ns() // 1_000_000
        while request_id in self.done:
            request_id += 1
        return request_id

    def start(self, request_id: int) -> None:
        self.done[request_id] = asyncio.Event()
        self.pending[request_id] = asyncio.get_running_loop().create_task(
            self._run(request_id), name=f"safe-exit-{request_id}"
        )

    def answered(self, request_id: int | None) -> None:
        """The vehicle's ``nominal`` report naming ``request_id`` arrived."""
        if request_id is not None and request_id in self.done:
            self.done[request_id].set()

    async def _run(self, request_id: int) -> None:
        clock, done = self.clock, self.done[request_id]
        sent = 0
        try:
            while sent < MAX_TRANSMISSIONS and not done.is_set():
                if await self.send(encode(SafeExit(request_id=request_id))):
                    sent += 1
                await clock.sleep_until(clock.monotonic() + self.answer_wait_s(), done)
            if not done.is_set():
                event = VehicleSafeExitUnverified(
                    actor="ground", request_id=request_id, transmissions=sent
                )
                await self.db.write(event_job(event, clock))
        except Exception:
            log.exception("safe_exit %d failed", request_id)
        finally:
            self.pending.pop(request_id, None)

    async def close(self) -> None:
        for task in list(self.pending.values()):
            task.cancel()
            with contextlib.suppress(BaseException):
                await task
