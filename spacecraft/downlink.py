"""The onboard telemetry store: every frame is kept until the ground acknowledges it.

Live frames go down as soon as they are made. A frame not acknowledged within
``resend_after_s`` (longer than a round trip) is sent again, and so are frames the ground
asks for (``retransmit``); resends go oldest first, at most ``dump_rate_fps`` frames per
second (a token bucket), so that after an outage the backlog drains without starving the
live stream. The ground deduplicates by sequence number, so a frame may arrive twice but is
stored once. Times are onboard seconds.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from telemetry.wire import MAX_FRAMES_PER_MESSAGE, TelemetryFrame

__all__ = ["Downlink", "DownlinkConfig"]


@dataclass(frozen=True)
class DownlinkConfig:
    resend_after_s: float = 10.0  # > the 6 s round trip of SPEC 6 plus margin
    dump_rate_fps: float = 100.0  # ten times the default live rate
    max_frames_per_message: int = 50
    capacity_frames: int = 100_000  # > a 20-minute pass at 10 Hz (12 000 frames)

    def __post_init__(self) -> None:
        if not self.resend_after_s > 0:
            raise ValueError(f"resend_after_s = {self.resend_after_s} must be > 0")
        if not self.dump_rate_fps > 0:
            raise ValueError(f"dump_rate_fps = {self.dump_rate_fps} must be > 0")
        if not 1 <= self.max_frames_per_message <= MAX_FRAMES_PER_MESSAGE:
            raise ValueError(
                f"max_frames_per_message = {self.max_frames_per_message} must lie in "
                f"[1, {MAX_FRAMES_PER_MESSAGE}]"
            )


class Downlink:
    def __init__(self, config: DownlinkConfig | None = None) -> None:
        self.config = config or DownlinkConfig()
        self._frames: dict[int, TelemetryFrame] = {}  # unacknowledged, by seq
        #: the seqs were added in increasing order (the vehicle's frames are): the dict's
        #: order is then the seqs' and an acknowledgement need not look at every frame held
        #: (a gap flown without a link leaves tens of thousands)
        self._ordered = True
        self._last_added: int | None = None
        self._last_sent_s: dict[int, float] = {}
        self._live: list[int] = []  # made but not yet sent once
        self._requested: set[int] = set()
        self._tokens = float(self.config.max_frames_per_message)
        self._token_time_s: float | None = None
        self.frames_overflowed = 0
        self.resent = 0

    @property
    def unacked(self) -> int:
        return len(self._frames)

    def add(self, frames: Iterable[TelemetryFrame]) -> None:
        for frame in frames:
            if len(self._frames) >= self.config.capacity_frames:
                # Never silently: the oldest frame is the one given up, and it is counted.
                oldest = next(iter(self._frames)) if self._ordered else min(self._frames)
                self._frames.pop(oldest)
                self._last_sent_s.pop(oldest, None)
                self.frames_overflowed += 1
            if self._last_added is not None and frame.seq <= self._last_added:
                self._ordered = False
            self._last_added = frame.seq
            self._frames[frame.seq] = frame
            self._live.append(frame.seq)

    def _through(self, seq: int) -> list[int]:
        """The seqs held up to ``seq``."""
        if not self._ordered:
            return [s for s in self._frames if s <= seq]
        out = []
        for s in self._frames:
            if s > seq:
                break
            out.append(s)
        return out

    def _within(self, lo: int, hi: int) -> list[int]:
        """The seqs held in ``[lo, hi]``, by looking each up when the range is the smaller."""
        if hi - lo < len(self._frames):
            return [s for s in range(lo, hi + 1) if s in self._frames]
        return [s for s in self._frames if lo <= s <= hi]

    def on_ack(self, through_seq: int, ranges: Iterable[tuple[int, int]] = ()) -> None:
        for seq in self._through(through_seq):
            self._forget(seq)
        for lo, hi in ranges:
            for seq in self._within(lo, hi):
                self._forget(seq)

    def on_retransmit(self, ranges: Iterable[tuple[int, int]]) -> None:
        for lo, hi in ranges:
            self._requested.update(self._within(lo, hi))

    def _forget(self, seq: int) -> None:
        self._frames.pop(seq, None)
        self._last_sent_s.pop(seq, None)
        self._requested.discard(seq)

    def _refill(self, now_s: float) -> None:
        if self._token_time_s is not None:
            elapsed = max(0.0, now_s - self._token_time_s)
            cap = float(self.config.max_frames_per_message)
            self._tokens = min(cap, self._tokens + elapsed * self.config.dump_rate_fps)
        self._token_time_s = now_s

    def due(self, now_s: float) -> list[tuple[list[TelemetryFrame], bool]]:
        """Messages to send now: ``(frames, retransmission)``, live first."""
        out: list[tuple[list[TelemetryFrame], bool]] = []
        size = self.config.max_frames_per_message
        live = [s for s in self._live if s in self._frames]
        self._live.clear()
        for i in range(0, len(live), size):
            batch = live[i : i + size]
            for seq in batch:
                self._last_sent_s[seq] = now_s
            out.append(([self._frames[s] for s in batch], False))
        self._refill(now_s)
        stale = now_s - self.config.resend_after_s
        candidates = sorted(
            s
            for s in self._frames
            if s in self._requested or self._last_sent_s.get(s, now_s) <= stale
        )
        budget = int(self._tokens)
        resend = candidates[:budget]
        self._tokens -= len(resend)
        for i in range(0, len(resend), size):
            batch = resend[i : i + size]
            for seq in batch:
                self._last_sent_s[seq] = now_s
                self._requested.discard(seq)
            self.resent += len(batch)
            out.append(([self._frames[s] for s in batch], True))
        return out
