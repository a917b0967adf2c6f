"""Replay of a recorded pass, paced by a clock the caller owns (pure: no asyncio, no sleep).

A :class:`Replay` walks a :class:`~telemetry.recording.PassRecording` along its onboard
timeline: the frames in row order (their ``generation_time_ns`` must not decrease) and the
commands at their time tags (``execute_time_ns``, onboard too). Audit events are on the
ground clock and are not replayed. Every call that depends on time takes the caller's
monotonic time ``now_ns`` (e.g. ``time.monotonic_ns()``, or a simulated one in tests).

The *playhead* is an onboard time: everything at or before it has been delivered, the rest
has not. Speeds (:data:`Speed`):

- :class:`RealTime` ``(factor)``: the playhead advances ``factor`` onboard ns per monotonic
  ns while playing; :meth:`Replay.poll` returns what it has passed since the last call.
- :class:`AsFastAsPossible` ``(batch_frames)``: each poll delivers the next batch at once.
- :class:`Step`: poll delivers nothing; :meth:`Replay.step` delivers exactly one frame (it
  does so in any mode, e.g. while paused).

A websocket server paces it like this::

    replay = Replay(recording, speed=RealTime(10.0))
    replay.play(now_ns=time.monotonic_ns())
    while not replay.finished:
        due_ns = replay.next_due_ns(time.monotonic_ns())
        if due_ns is None:  # paused or stepping: wait for the operator
            await operator_input()
            continue
        await asyncio.sleep(max(0, due_ns - time.monotonic_ns()) / 1e9)
        batch = replay.poll(time.monotonic_ns())
        await send(batch)

:meth:`Replay.seek_onboard` / :meth:`Replay.seek_plan` put the playhead on the first frame at
or after the given time (onboard ns, or s on the plan's clock); that frame is delivered next.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from telemetry.recording import CommandRow, FrameArrays, PassRecording

__all__ = ["AsFastAsPossible", "Batch", "RealTime", "Replay", "Speed", "Step"]


@dataclass(frozen=True)
class RealTime:
    """Onboard time runs ``factor`` times as fast as the caller's monotonic clock."""

    factor: float = 1.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.factor) and self.factor > 0.0):
            raise ValueError(f"replay factor {self.factor!r} must be finite and > 0")


@dataclass(frozen=True)
class AsFastAsPossible:
    """Each poll delivers the next ``batch_frames`` frames, whatever the time."""

    batch_frames: int = 500

    def __post_init__(self) -> None:
        if self.batch_frames < 1:
            raise ValueError(f"batch_frames {self.batch_frames} must be >= 1")


@dataclass(frozen=True)
class Step:
    """Nothing moves by itself; :meth:`Replay.step` delivers one frame per call."""


Speed = RealTime | AsFastAsPossible | Step

_END_NS = 2**63 - 1


@dataclass(frozen=True, eq=False)
class Batch:
    """What one call delivered: frames (rows ``first_row`` to ``first_row + len - 1`` of the
    recording) and the commands whose tags the playhead passed, in tag order."""

    first_row: int
    frames: FrameArrays
    commands: tuple[CommandRow, ...]

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def empty(self) -> bool:
        return len(self.frames) == 0 and not self.commands


class Replay:
    """Streams one recording (see the module doc). Starts paused at the first frame."""

    def __init__(self, recording: PassRecording, *, speed: Speed | None = None) -> None:
        times = recording.frames.generation_time_ns
        if len(times) > 1 and not bool(np.all(np.diff(times) >= 0)):
            row = int(np.argmax(np.diff(times) < 0)) + 1
            raise ValueError(f"frame {row}: generation_time_ns runs backwards; cannot replay")
        self.recording = recording
        self._times_ns = times
        self._commands = tuple(sorted(recording.commands, key=lambda c: c.execute_time_ns))
        self._command_times_ns = np.array(
            [c.execute_time_ns for c in self._commands], dtype=np.int64
        )
        self._speed: Speed = speed or RealTime()
        self._paused = True
        self._row = 0  # next frame to deliver
        self._command = 0  # next command to deliver
        # The playhead at the last anchor, and the caller's clock then (RealTime only).
        # It starts on the first frame, so that frame is due as soon as play() is called.
        self._anchor_playhead_ns = int(times[0]) if len(times) else 0
        self._anchor_now_ns = 0

    # -- state ---------------------------------------------------------------------------

    @property
    def speed(self) -> Speed:
        return self._speed

    @property
    def paused(self) -> bool:
        return self._paused

    @property
    def position(self) -> int:
        """The row of the next frame to deliver (``len(frames)`` at the end)."""
        return self._row

    @property
    def finished(self) -> bool:
        return self._row >= len(self._times_ns) and self._command >= len(self._commands)

    def playhead_ns(self, now_ns: int) -> int:
        """Onboard time up to which everything is (or, at ``now_ns``, is due to be) delivered."""
        if self._paused or not isinstance(self._speed, RealTime):
            return self._anchor_playhead_ns
        elapsed_ns = max(0, now_ns - self._anchor_now_ns)
        return self._anchor_playhead_ns + math.floor(elapsed_ns * self._speed.factor)

    # -- control -------------------------------------------------------------------------

    def play(self, now_ns: int) -> None:
        """Start or resume at ``now_ns`` from where the playhead stands."""
        self._anchor_now_ns = now_ns
        self._paused = False

    def pause(self, now_ns: int) -> None:
        """Stop delivering; the playhead stays where it is at ``now_ns``."""
        if not self._paused:
            self._anchor_playhead_ns = self.playhead_ns(now_ns)
            self._anchor_now_ns = now_ns
        self._paused = True

    resume = play

    def set_speed(self, speed: Speed, now_ns: int) -> None:
        """Change speed at ``now_ns`` without moving the playhead."""
        self._anchor_playhead_ns = self.playhead_ns(now_ns)
        self._anchor_now_ns = now_ns
        self._speed = speed

    def seek_onboard(self, time_ns: int, now_ns: int) -> None:
        """Land on the first frame at or after onboard ``time_ns``: it is due at once and
        delivered next, with the commands tagged from ``time_ns`` on as their tags come.
        Past the last frame only later commands remain."""
        n = len(self._times_ns)
        self._row = int(np.searchsorted(self._times_ns, time_ns, side="left"))
        self._command = int(np.searchsorted(self._command_times_ns, time_ns, side="left"))
        landing_ns = int(self._times_ns[self._row]) if self._row < n else time_ns
        self._anchor_playhead_ns = landing_ns
        self._anchor_now_ns = now_ns

    def seek_plan(self, t_s: float, now_ns: int) -> None:
        """Land on the first frame at or after ``t_s`` on the plan's clock (s from t = 0)."""
        self.seek_onboard(self.recording.epoch_ns + round(t_s * 1e9), now_ns)

    # -- delivery ------------------------------------------------------------------------

    def _deliver(self, end_row: int, until_ns: int) -> Batch:
        """Frames ``[position, end_row)`` and the commands tagged at or before ``until_ns``."""
        first = self._row
        end_row = max(first, min(end_row, len(self._times_ns)))
        end_cmd = int(np.searchsorted(self._command_times_ns, until_ns, side="right"))
        end_cmd = max(end_cmd, self._command)
        batch = Batch(
            first_row=first,
            frames=self.recording.frames.take(slice(first, end_row)),
            commands=self._commands[self._command : end_cmd],
        )
        self._row = end_row
        self._command = end_cmd
        if self._paused or not isinstance(self._speed, RealTime):
            # Delivered by hand (step) or in a batch: the playhead moves with what went out.
            last_ns = [int(self._times_ns[end_row - 1])] if end_row > first else []
            last_ns += [c.execute_time_ns for c in batch.commands[-1:]]
            self._anchor_playhead_ns = max([self._anchor_playhead_ns, *last_ns])
        return batch

    def _through_row_ns(self, end_row: int) -> int:
        """Commands go out with the frames up to ``end_row``: up to the last one's time, or
        all that remain when no frame remains after them."""
        if end_row >= len(self._times_ns):
            return _END_NS
        return int(self._times_ns[end_row - 1]) if end_row > 0 else self._anchor_playhead_ns

    def poll(self, now_ns: int) -> Batch:
        """What is due at ``now_ns``, removed from what remains. Empty while paused or in
        :class:`Step` mode."""
        if self._paused or isinstance(self._speed, Step):
            return self._deliver(self._row, -1)
        if isinstance(self._speed, AsFastAsPossible):
            end_row = self._row + self._speed.batch_frames
            return self._deliver(end_row, self._through_row_ns(end_row))
        playhead = self.playhead_ns(now_ns)
        end_row = int(np.searchsorted(self._times_ns, playhead, side="right"))
        return self._deliver(end_row, playhead)

    def step(self) -> Batch:
        """Deliver exactly the next frame with the commands up to its time, in any mode
        (with the last frame, every command that remains)."""
        end_row = self._row + 1
        return self._deliver(end_row, self._through_row_ns(end_row))

    def next_due_ns(self, now_ns: int) -> int | None:
        """The caller's monotonic time at which the next frame or command falls due:
        ``now_ns`` when something is due already or the speed is :class:`AsFastAsPossible`;
        ``None`` when paused, stepping or finished (nothing will fall due by itself)."""
        if self.finished or self._paused or isinstance(self._speed, Step):
            return None
        if isinstance(self._speed, AsFastAsPossible):
            return now_ns
        candidates = []
        if self._row < len(self._times_ns):
            candidates.append(int(self._times_ns[self._row]))
        if self._command < len(self._commands):
            candidates.append(int(self._command_times_ns[self._command]))
        next_ns = min(candidates)
        if self.playhead_ns(now_ns) >= next_ns:
            return now_ns
        factor = self._speed.factor
        due = self._anchor_now_ns + math.ceil((next_ns - self._anchor_playhead_ns) / factor)
        # Float rounding may leave it one ns short of what playhead_ns() needs.
        while self.playhead_ns(due) < next_ns:
            due += 1
        return max(due, now_ns)
