"""The ground's downlink: telemetry frames in, stored once, acknowledged, gaps asked for.

- Every ``telemetry`` frame is stored (storage dedupes by ``(pass, seq)``) against the pass
  whose *telemetry window* contains its ``generation_time_ns``; windows are opened and
  closed by the runner through :class:`~server.services.link.GroundLink`. A frame generated
  outside every window is **not archived**: it is counted (``frames_outside_pass``) and
  still acknowledged, so the spacecraft does not resend it for ever.
- **Acknowledgement**: ``telemetry_ack`` with the frames held (cumulative from seq 0, the
  rest as ranges), and ``retransmit`` for the gaps between the frames held. A seq is asked
  for again at most once per resend window (10 s onboard, the spacecraft's own resend
  timeout); frames below the lowest one seen are left to that timeout (after a ground
  restart the ground cannot know which of them were acknowledged).
"""

from __future__ import annotations

import asyncio
import bisect
import logging
import math
from collections.abc import Awaitable, Callable
from dataclasses import dataclass

from sqlalchemy.orm import Session

from server.services.clock import Clock
from server.services.dbworker import Database, Publisher
from server.services.events import RetransmitRequested, event_job
from server.storage import repository as repo
from server.storage.models import PassRecord
from telemetry.wire import Retransmit, TelemetryAck, TelemetryFrame, TelemetryMsg, encode

__all__ = ["GroundDownlink", "SeqRanges", "TelemetryWindow"]

log = logging.getLogger("hikoboshi.ground.downlink")

#: The spacecraft resends unacknowledged frames after this long (onboard s, protocol doc).
RESEND_WINDOW_S = 10.0
#: A gap is asked for once it has stayed open this long (onboard s): the relay's jitter
#: delivers frames out of order.
GAP_GRACE_S = 1.0
#: Wall seconds added to the onboard windows for each end's own processing time.
WALL_ALLOWANCE_S = 1.0
MAX_ACK_RANGES = 1000


class SeqRanges:
    """A set of non-negative ints kept as sorted, disjoint, non-adjacent inclusive ranges."""

    def __init__(self) -> None:
        self._ranges: list[list[int]] = []
        self.count = 0

    def __contains__(self, seq: int) -> bool:
        i = bisect.bisect_right(self._ranges, seq, key=lambda r: r[0]) - 1
        return i >= 0 and self._ranges[i][1] >= seq

    def add(self, seq: int) -> bool:
        """Add ``seq``; whether it was new."""
        rs = self._ranges
        i = bisect.bisect_right(rs, seq, key=lambda r: r[0])
        prev = i - 1
        if prev >= 0 and rs[prev][1] >= seq:
            return False
        join_prev = prev >= 0 and rs[prev][1] == seq - 1
        join_next = i < len(rs) and rs[i][0] == seq + 1
        if join_prev and join_next:
            rs[prev][1] = rs[i][1]
            del rs[i]
        elif join_prev:
            rs[prev][1] = seq
        elif join_next:
            rs[i][0] = seq
        else:
            rs.insert(i, [seq, seq])
        self.count += 1
        return True

    def ranges(self) -> list[tuple[int, int]]:
        return [(lo, hi) for lo, hi in self._ranges]

    def gaps(self) -> list[tuple[int, int]]:
        """The missing ranges between the lowest and the highest member."""
        rs = self._ranges
        return [(rs[k][1] + 1, rs[k + 1][0] - 1) for k in range(len(rs) - 1)]

    def highest(self) -> int:
        return self._ranges[-1][1] if self._ranges else -1


@dataclass
class TelemetryWindow:
    """Frames generated in ``[start_ns, end_ns)`` (onboard) belong to the pass."""

    pass_id: str
    start_ns: int
    end_ns: int | None = None

    def contains(self, generation_time_ns: int) -> bool:
        return self.start_ns <= generation_time_ns and (
            self.end_ns is None or generation_time_ns < self.end_ns
        )


#: The most frames one database job stores (more only if a single message holds more): the
#: rest of a backlog goes in the next job, so that a control job slips in between.
MAX_INGEST_FRAMES = 400


@dataclass
class _Batch:
    """One telemetry message's new frames, waiting for the database."""

    fresh: list[TelemetryFrame]
    by_pass: dict[str, list[TelemetryFrame]]
    reception_ns: int
    #: a retransmission's (a ground gone may have stored its frames: looked up first)
    retransmission: bool = False
    #: of its frames, those the archive already held (set by the database job)
    known: frozenset[int] = frozenset()


class GroundDownlink:
    """The telemetry half of the link (see the module docstring). ``send`` puts a message on
    the spacecraft's socket (False: no link); ``time_scale`` is the onboard clock's scale."""

    def __init__(
        self,
        *,
        db: Database,
        publisher: Publisher,
        clock: Clock,
        send: Callable[[str], Awaitable[bool]],
        time_scale: Callable[[], float],
    ) -> None:
        self._db = db
        self._publisher = publisher
        self._clock = clock
        self._send = send
        self._time_scale = time_scale
        self.held = SeqRanges()
        #: seqs handed to the database and not yet committed
        self._storing: set[int] = set()
        #: messages read while a frame job is in flight: (fresh, by pass, reception ns)
        self._waiting: list[_Batch] = []
        self._ingesting = False
        self._ack_wanted = False
        self._acker: asyncio.Task[None] | None = None
        self._requested_at: dict[int, float] = {}
        self._gap_seen_at: dict[int, float] = {}
        self.windows: list[TelemetryWindow] = []
        self.newest: tuple[int, int] | None = None  # (seq, generation ns)
        self.oldest: tuple[int, int] | None = None
        #: The newest frame received (highest seq): what the vehicle last said it does.
        self.latest_frame: TelemetryFrame | None = None
        self.duplicates = 0
        #: pass id -> copies of its frames dropped since the service started
        self.duplicates_by_pass: dict[str, int] = {}
        self.frames_outside_pass = 0
        self.retransmit_requests = 0

    def restart_numbering(self) -> None:
        """The vehicle counts frames from 0 again (a new spacecraft process)."""
        self.held = SeqRanges()
        self._requested_at.clear()
        self._gap_seen_at.clear()
        self.newest = self.oldest = None

    # -- windows -------------------------------------------------------------------------

    def open_window(
        self, pass_id: str, start_ns: int, end_ns: int | None = None
    ) -> TelemetryWindow:
        window = TelemetryWindow(pass_id, start_ns=start_ns, end_ns=end_ns)
        self.windows.append(window)
        return window

    def close_window(self, window: TelemetryWindow, end_ns: int | None) -> None:
        window.end_ns = end_ns

    def drop_window(self, window: TelemetryWindow) -> None:
        if window in self.windows:
            self.windows.remove(window)

    def _window_of(self, frame: TelemetryFrame) -> str | None:
        for window in reversed(self.windows):  # the later pass wins an overlap
            if window.contains(frame.generation_time_ns):
                return window.pass_id
        return None

    # -- frames --------------------------------------------------------------------------

    async def on_telemetry(self, message: TelemetryMsg, received_mono: float | None = None) -> None:
        """File one telemetry message. Its frames are handed to the database worker and the
        socket is read on at once: the frames are acknowledged when they have committed
        (from the worker's completion), and the acknowledgements of everything that
        committed meanwhile go out as one. So the live path pipelines decode, storage and
        acknowledgement instead of waiting for a commit per message, and the console's
        fan-out never holds up an acknowledgement. ``received_mono``: when the message was
        read off the socket, on the ground clock (the link's one timing of its arrival; now if
        not given); the frames' reception time is that instant's."""
        clock = self._clock
        reception_ns = clock.time_ns() if received_mono is None else clock.time_ns_at(received_mono)
        by_pass: dict[str, list[TelemetryFrame]] = {}
        fresh: list[TelemetryFrame] = []
        held, storing = self.held, self._storing
        for frame in message.frames:
            seq = frame.seq
            pass_id = self._window_of(frame)
            if seq in storing or seq in held:
                self.duplicates += 1
                if pass_id is not None:
                    self.duplicates_by_pass[pass_id] = self.duplicates_by_pass.get(pass_id, 0) + 1
                continue
            storing.add(seq)
            fresh.append(frame)
            if pass_id is not None:
                by_pass.setdefault(pass_id, []).append(frame)
        if not fresh:
            # Only copies: the spacecraft missed an acknowledgement; say it again.
            self._ack_soon()
            return
        if not by_pass:
            self._committed(_Batch(fresh, by_pass, reception_ns), {})
            return
        self._waiting.append(_Batch(fresh, by_pass, reception_ns, message.retransmission))
        if not self._ingesting:
            self._ingest()

    def _ingest(self) -> None:
        """One database job for every message read since the last one was handed over: at
        most one frame job is in flight, so under load the frames of many messages share
        one transaction (and one look-up of their pass) instead of queueing a job each."""
        # At most MAX_INGEST_FRAMES frames (whole messages) per job: an operator's control
        # job waits for the job in progress, and on a loaded PostgreSQL a backlog of several
        # thousand frames in one job took seconds (an abort answered 1.5 s late).
        take, n = 0, 0
        while take < len(self._waiting) and (take == 0 or n < MAX_INGEST_FRAMES):
            n += len(self._waiting[take].fresh)
            take += 1
        batches, self._waiting = self._waiting[:take], self._waiting[take:]
        self._ingesting = True

        def job(session: Session) -> list[dict[str, int] | None]:
            # held, so that each ingest finds its pass in the session's identity map
            passes = [
                session.get(PassRecord, pass_id)
                for pass_id in {p for b in batches for p in b.by_pass}
            ]
            for batch in batches:
                if batch.retransmission:  # not published again: see _committed
                    batch.known = frozenset(
                        seq
                        for pass_id, frames in batch.by_pass.items()
                        for seq in repo.stored_among(
                            session=session, pass_id=pass_id, seqs=[f.seq for f in frames]
                        )
                    )
            if len(batches) > 1:
                # All the messages in one write per pass; if one of them is refused, each
                # is stored (or refused) alone below.
                merged: dict[str, list[tuple[list[TelemetryFrame], int]]] = {}
                for batch in batches:
                    for pass_id, frames in batch.by_pass.items():
                        merged.setdefault(pass_id, []).append((frames, batch.reception_ns))
                try:
                    with session.begin_nested():
                        together = {
                            pass_id: repo.ingest_messages(
                                session=session, pass_id=pass_id, messages=messages
                            ).duplicates
                            for pass_id, messages in merged.items()
                        }
                except Exception:
                    log.debug("telemetry of %d messages: storing them one by one", len(batches))
                else:
                    del passes
                    # the copies the archive held, counted once (with the first message)
                    return [together, *({} for _ in batches[1:])]
            out: list[dict[str, int] | None] = []
            for batch in batches:
                duplicates = {}
                try:
                    # a message that fails is rolled back alone, and not acknowledged
                    with session.begin_nested():
                        for pass_id, frames in batch.by_pass.items():
                            result = repo.ingest_frames(
                                session=session,
                                pass_id=pass_id,
                                frames=frames,
                                reception_time_ns=batch.reception_ns,
                            )
                            duplicates[pass_id] = result.duplicates
                except Exception:
                    log.exception("telemetry message of %d frames not stored", len(batch.fresh))
                    out.append(None)
                    continue
                out.append(duplicates)
            del passes
            return out

        def done(results: list[dict[str, int] | None] | None) -> None:
            for k, batch in enumerate(batches):
                outcome = None if results is None else results[k]
                self._committed(batch, outcome)
            self._ingesting = False
            if self._waiting:
                self._ingest()

        self._db.submit_then(job, done)

    def _committed(self, batch: _Batch, duplicates: dict[str, int] | None) -> None:
        fresh, by_pass = batch.fresh, batch.by_pass
        for frame in fresh:
            self._storing.discard(frame.seq)
        if duplicates is None:
            return  # not stored: not acknowledged, the spacecraft sends them again
        # Copies the archive already held (after a ground restart the in-memory set
        # starts empty): dropped by the storage's dedupe.
        for pass_id, n in duplicates.items():
            self.duplicates += n
            self.duplicates_by_pass[pass_id] = self.duplicates_by_pass.get(pass_id, 0) + n
        stored = {frame.seq for frames in by_pass.values() for frame in frames}
        for frame in fresh:
            if self.held.add(frame.seq):
                self._requested_at.pop(frame.seq, None)
                if frame.seq not in stored:
                    self.frames_outside_pass += 1
                if self.newest is None or frame.seq > self.newest[0]:
                    self.newest = (frame.seq, frame.generation_time_ns)
                    self.latest_frame = frame
                if self.oldest is None or frame.seq < self.oldest[0]:
                    self.oldest = (frame.seq, frame.generation_time_ns)
        self._ack_soon()
        # Published once: a retransmission's frames that the archive already held (stored
        # by a ground gone, or before this ground's restart) reached the consoles then, or
        # through the takeover's backfill (server/services/_console_backfill.py).
        known = batch.known
        for pass_id, frames in by_pass.items():
            new = [f for f in frames if f.seq not in known] if known else frames
            if new:
                self._publisher.publish_frames(pass_id, new, batch.reception_ns)

    def _ack_soon(self) -> None:
        """Acknowledge what is held: one acknowledgement for everything that committed while
        the previous one was being sent."""
        self._ack_wanted = True
        if self._acker is None or self._acker.done():
            self._acker = asyncio.get_running_loop().create_task(self._ack_loop())

    async def _ack_loop(self) -> None:
        while self._ack_wanted:
            self._ack_wanted = False
            try:
                await self._acknowledge()
            except Exception:
                log.exception("telemetry acknowledgement failed")

    async def settled(self) -> None:
        """Wait until every frame read so far is stored and acknowledged (tests, shutdown)."""
        while True:
            await self._db.drain()
            acker = self._acker
            if acker is not None and not acker.done():
                await acker
                continue
            if not self._storing and not self._ack_wanted:
                return
            await asyncio.sleep(0)

    async def _acknowledge(self) -> None:
        ranges = self.held.ranges()
        through = -1
        if ranges and ranges[0][0] == 0:
            through = ranges.pop(0)[1]
        await self._send(encode(TelemetryAck(through_seq=through, ranges=ranges[:MAX_ACK_RANGES])))
        now = self._clock.monotonic()
        scale = self._time_scale()
        # Onboard time scaled to wall, plus wall time for the two ends' own processing:
        # at high time scales the onboard windows shrink below what a loaded machine takes
        # to handle a message, and asking early only brings copies.
        window_s = RESEND_WINDOW_S / scale + WALL_ALLOWANCE_S
        grace_s = GAP_GRACE_S / scale + WALL_ALLOWANCE_S / 5
        due: list[tuple[int, int]] = []
        gaps = self.held.gaps()
        missing = {seq for lo, hi in gaps for seq in range(lo, hi + 1)}
        self._gap_seen_at = {
            seq: self._gap_seen_at.get(seq, now) for seq in missing
        }  # a gap is asked for once it has stayed open a while (jitter reorders frames)
        for lo, hi in gaps:
            for seq in range(lo, hi + 1):
                if now - self._gap_seen_at[seq] < grace_s:
                    continue
                if now - self._requested_at.get(seq, -math.inf) >= window_s:
                    self._requested_at[seq] = now
                    if due and due[-1][1] == seq - 1:
                        due[-1] = (due[-1][0], seq)
                    else:
                        due.append((seq, seq))
        if due:
            self.retransmit_requests += 1
            await self._send(encode(Retransmit(ranges=due[:MAX_ACK_RANGES])))
            frames = sum(hi - lo + 1 for lo, hi in due)
            asked = RetransmitRequested(actor="ground", ranges=due[:20], frames=frames)
            self._db.submit(event_job(asked, self._clock))

    def frames_behind(self, onboard_now_ns: int | None) -> int | None:
        """Frames generated onboard (estimated from the rate) that the ground does not hold."""
        if self.newest is None or self.oldest is None or onboard_now_ns is None:
            return None
        span_seq = self.newest[0] - self.oldest[0]
        if span_seq <= 0:
            return None
        period_ns = (self.newest[1] - self.oldest[1]) / span_seq
        since = max(0, onboard_now_ns - self.newest[1])
        generated = self.newest[0] + 1 + int(since // period_ns)
        return generated - (self.oldest[0] + self.held.count)
