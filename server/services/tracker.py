"""The fate of a pass's commands: one :class:`CommandTracker` per pass.

The tracker holds every command's stage in memory (the rules of
:mod:`server.storage.stages`), moved by what the ground does (sent, expired, cancelled) and
by the typed link events (:class:`~server.services.link.CommandAcked`,
:class:`~server.services.link.CommandsUnknown`) that :class:`~server.services.link.GroundLink`
emits after filing the vehicle's word. The database is its record (the ground's own stage
writes go through it, in jobs of :data:`STAGE_JOB_COMMANDS`: ``released`` and ``sent``,
ground times, at a command's first transmission, the count of transmissions with them and
after retransmissions; ``expired``), never its mailbox: nothing here reads a stage back.

**Resolution after LOS** (:meth:`CommandTracker.resolve`): commands whose tag has passed
(after on-board safing: every one) without a final acknowledgement are asked about
(``command_query``, up to :data:`MAX_COMMAND_QUERIES` times: acks lost on the downlink come
again, commands lost on the uplink come back ``command_unknown`` and expire) until none is
left ``sent`` or ``received`` (or the queries are used up). It waits on its own state changing (an
acknowledgement, the link back) and on the query timer of the injected clock. A pass resumed
after a restart first asks, :data:`EXPIRED_QUERIES` times, about the commands taken as
``expired``: the vehicle's own word (``executed``) replaces the guess. Aborted instead, it
asks as many times about the commands the vehicle holds with no send on file
(``ask_about``), those still ``queued`` and those its uplink took as ``expired`` alike.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from sqlalchemy.orm import Session

from server.services.clock import Clock
from server.services.dbworker import Database
from server.services.event_log import Recorded
from server.services.link import (
    CommandAcked,
    CommandsUnknown,
    GroundLink,
    LinkEvent,
    LinkUnavailable,
    LinkUp,
)
from server.services.stage_writes import StageMove, StageWrites
from server.services.uplink import UplinkCommand
from server.storage.models import CommandRecord
from server.storage.stages import AWAITING_ACK_STAGES, acked_stage, expires_unknown, moves
from telemetry.uplink import Command

__all__ = [
    "EXPIRED_QUERIES",
    "LINK_DOWN_POLL_S",
    "MAX_COMMAND_QUERIES",
    "STAGE_JOB_COMMANDS",
    "CommandTracker",
    "Trackers",
]

#: Commands per database job of stage writes (an operator's control job waits for one).
STAGE_JOB_COMMANDS = 16
#: After LOS, ask the vehicle about unacknowledged commands at most this many times (under
#: 20 % loss each way one round is lost with p = 0.36; twenty rounds all with p < 1e-8).
MAX_COMMAND_QUERIES = 20
#: Rounds of asking about a resumed pass's ``expired`` commands (answers to expired ones
#: the vehicle never had change nothing, so there is no telling when all have come).
EXPIRED_QUERIES = 2
#: Ground s between looks while the link is down (its return wakes the waiter at once).
LINK_DOWN_POLL_S = 0.5

Job = Callable[[Session], list[Recorded]]


@dataclass
class _Fate:
    stage: str
    tag_ns: int


class CommandTracker:
    """Every command of one pass: its stage now, as the ground knows it (see the module
    docstring), made by :class:`Trackers`; :meth:`close` when the pass's commands are
    resolved."""

    def __init__(
        self,
        pass_id: str,
        fates: Iterable[tuple[int, str, int]],
        *,
        link: GroundLink,
        db: Database,
        clock: Clock,
        one_way_delay_s: float,
    ) -> None:
        self.pass_id = pass_id
        self._fates = {seq: _Fate(stage, tag_ns) for seq, stage, tag_ns in fates}
        self._link = link
        self._db = db
        self._clock = clock
        self._writes = StageWrites(clock)
        #: Onboard ns between queries: a round trip and a second to answer.
        self._period_ns = round((2 * one_way_delay_s + 1.0) * 1e9)
        self._changed = asyncio.Event()
        self._unsubscribe: Callable[[], None] | None = link.add_listener(self._on_link_event)

    def close(self) -> None:
        """Stop following the link (idempotent)."""
        if self._unsubscribe is not None:
            self._unsubscribe()
            self._unsubscribe = None

    # -- state ---------------------------------------------------------------------------

    def stage(self, seq: int) -> str | None:
        fate = self._fates.get(seq)
        return None if fate is None else fate.stage

    def outstanding(self) -> list[tuple[int, int]]:
        """(seq, tag) of the commands sent and not acknowledged final, by seq."""
        return [
            (seq, f.tag_ns)
            for seq, f in sorted(self._fates.items())
            if f.stage in AWAITING_ACK_STAGES
        ]

    def counts(self) -> dict[str, int]:
        """How many commands are in each stage now (stages with none left out)."""
        counts: dict[str, int] = {}
        for fate in self._fates.values():
            counts[fate.stage] = counts.get(fate.stage, 0) + 1
        return counts

    def in_stage(self, stage: str) -> list[int]:
        return sorted(seq for seq, f in self._fates.items() if f.stage == stage)

    def _move(self, seq: int, stage: str) -> None:
        fate = self._fates.get(seq)
        if fate is not None and moves(fate.stage, stage):
            fate.stage = stage
            self._changed.set()

    def _on_link_event(self, event: LinkEvent) -> None:
        if isinstance(event, CommandAcked):
            stage = acked_stage(event.stage, event.reason)
            if stage is not None:
                self._move(event.seq, stage)
        elif isinstance(event, CommandsUnknown):
            for seq in event.seqs:
                fate = self._fates.get(seq)
                if fate is not None and expires_unknown(
                    fate.stage, fate.tag_ns, event.onboard_time_ns
                ):
                    self._move(seq, "expired")
        elif isinstance(event, LinkUp):
            self._changed.set()  # a query can go up again

    # -- the ground's own stage moves, and their record ----------------------------------

    def record_sent(
        self, released_ns: int, first: list[tuple[int, int]], again: list[tuple[int, int]]
    ) -> None:
        """``first``: (seq, ground ns) of first transmissions (stages ``released`` at
        ``released_ns`` and ``sent``); ``again``: (seq, transmissions) of the others."""
        for seq, _ in first:
            self._move(seq, "sent")
        # In jobs of STAGE_JOB_COMMANDS: an operator's control job waits for the job in
        # progress, and the start's first batch (hundreds of commands, three statements
        # each) took 4-5 s in one job on a loaded PostgreSQL. Consecutive jobs still share
        # their statements (server.services.stage_writes).
        for lo in range(0, max(len(first), len(again)), STAGE_JOB_COMMANDS):
            hi = lo + STAGE_JOB_COMMANDS
            self._db.submit(self._sent_job(released_ns, first[lo:hi], again[lo:hi]))

    def _sent_job(
        self, released_ns: int, first: list[tuple[int, int]], counts: list[tuple[int, int]]
    ) -> Job:
        pass_id = self.pass_id
        moves = [
            StageMove(pass_id, seq, stage, at_ns, transmissions=1)
            for seq, sent_ns in first
            for stage, at_ns in (("released", released_ns), ("sent", sent_ns))
        ]
        moves += [StageMove(pass_id, seq, None, transmissions=n) for seq, n in counts]
        return self._writes.job(moves)

    def record_expired(self, expired: list[UplinkCommand], now_ns: int) -> None:
        """These could not be sent early enough to arrive before their tag."""
        seqs = [c.seq for c in expired]
        for seq in seqs:
            self._move(seq, "expired")
        for lo in range(0, len(seqs), STAGE_JOB_COMMANDS):
            self._db.submit(self._expired_job(now_ns, seqs[lo : lo + STAGE_JOB_COMMANDS]))

    def _expired_job(self, now_ns: int, seqs: list[int]) -> Job:
        detail = "could not be sent early enough to arrive before its tag"
        return self._writes.job(
            StageMove(self.pass_id, seq, "expired", now_ns, detail=detail) for seq in seqs
        )

    def cancelled(self, seqs: Iterable[int]) -> None:
        """These were cancelled (those not final), in a transaction of the caller's
        (:func:`server.services.command_stages.cancel_commands`)."""
        for seq in seqs:
            self._move(seq, "cancelled")

    # -- resolution after LOS ------------------------------------------------------------

    async def resolve(
        self,
        stop: asyncio.Event,
        *,
        ask_expired: bool = False,
        any_tag: bool = False,
        ask_about: Iterable[int] = (),
    ) -> int:
        """Ask the vehicle about the commands still ``sent`` or ``received`` once their tag
        has passed (``any_tag``: at once, whatever their tag: after on-board safing, when
        the vehicle has dropped or refused every one it did not execute), up to
        :data:`MAX_COMMAND_QUERIES` times, until none is left or ``stop`` is set; how many
        are left unresolved (see the module docstring)."""
        link, clock = self._link, self._clock
        watch = asyncio.ensure_future(stop.wait())
        watch.add_done_callback(lambda _: self._changed.set())
        try:
            if ask_expired:
                await self._ask_about(stop, lambda: self.in_stage("expired"))
            unfiled = set(ask_about)
            if unfiled:  # on board with no send on file: the vehicle's word, as acks
                await self._ask_about(stop, lambda: self._guessed(unfiled))
            queries = 0
            next_query = clock.monotonic()
            while True:
                self._changed.clear()
                left = self.outstanding()
                if not left or queries >= MAX_COMMAND_QUERIES or stop.is_set():
                    break
                wake_at = clock.monotonic() + LINK_DOWN_POLL_S
                if link.connected:
                    if clock.monotonic() >= next_query:
                        now_ns = link.onboard_now_ns()
                        due = [seq for seq, tag in left if any_tag or tag < now_ns]
                        if due and await link.query_commands(due):
                            queries += 1
                        next_query = link.mono_at_onboard(link.onboard_now_ns() + self._period_ns)
                    wake_at = next_query
                await clock.sleep_until(wake_at, self._changed)
            if left and queries and not stop.is_set():
                # the last answers are a round trip away
                with contextlib.suppress(LinkUnavailable):
                    until = link.mono_at_onboard(link.onboard_now_ns() + self._period_ns)
                    while self.outstanding() and not stop.is_set():
                        if clock.monotonic() >= until:
                            break
                        self._changed.clear()
                        await clock.sleep_until(until, self._changed)
            return len(self.outstanding())
        finally:
            watch.cancel()

    def _guessed(self, seqs: set[int]) -> list[int]:
        """Those of ``seqs`` the vehicle has not spoken of: still ``queued``, or taken as
        ``expired`` by the ground (a resumed uplink expires, with no send on file, commands
        the vehicle holds or ran: the vehicle's word replaces that guess)."""
        return sorted(s for s in seqs if self.stage(s) in ("queued", "expired"))

    async def _ask_about(self, stop: asyncio.Event, which: Callable[[], list[int]]) -> None:
        """Ask the vehicle about ``which()`` commands, again while some are left (the relay
        may lose a query or its answers), :data:`EXPIRED_QUERIES` times at most."""
        link, clock = self._link, self._clock
        for _ in range(EXPIRED_QUERIES):  # the relay may lose one
            seqs = which()
            if not seqs or stop.is_set() or not link.connected:
                return
            if await link.query_commands(seqs):
                # the answers are a round trip away (acks replace the guess)
                with contextlib.suppress(LinkUnavailable):
                    await clock.sleep_until(
                        link.mono_at_onboard(link.onboard_now_ns() + self._period_ns), stop
                    )


@dataclass(frozen=True)
class Trackers:
    """Makes the :class:`CommandTracker` of each pass (the service's composition root
    builds one and hands it to the runner)."""

    link: GroundLink
    db: Database
    clock: Clock
    one_way_delay_s: float

    def _make(self, pass_id: str, fates: Iterable[tuple[int, str, int]]) -> CommandTracker:
        return CommandTracker(
            pass_id,
            fates,
            link=self.link,
            db=self.db,
            clock=self.clock,
            one_way_delay_s=self.one_way_delay_s,
        )

    def queued(self, pass_id: str, commands: Iterable[Command]) -> CommandTracker:
        """A new pass: every command ``queued``."""
        return self._make(pass_id, ((c.seq, "queued", c.execute_time_ns) for c in commands))

    def stored(self, pass_id: str, rows: Iterable[CommandRecord]) -> CommandTracker:
        """A pass resumed after a restart: the stages as the archive holds them."""
        return self._make(pass_id, ((r.seq, r.stage, r.execute_time_ns) for r in rows))
