"""Replay of a recorded pass to one console (docs/console.md, "Replay of a recorded pass").

A :class:`ReplaySession` streams a stored pass (:func:`server.services.recordings.load_recording`)
to the console that opened it, paced by its own asyncio task driving a
:class:`telemetry.replay.Replay` on the monotonic clock. Its messages carry
``topic: "replay"`` and the ``replay_id``, so they never mix with live data; the telemetry
has the live message's shape (``columns``), so the same plotting code takes both.

Flow control instead of drops: a replay is not live, so when the console has
:attr:`ConsoleLimits.replay_window_bytes` of replay data unsent, its replays hold (the
playhead stops where it is) until half of that has gone out, then go on. A slow console
only slows its own replays; nothing else waits for it.

:class:`Replays` (on the hub) owns every session: ids, ownership (a console controls only
its own replays), the limits per console and in total, and the client messages.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import secrets
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, Protocol

from sqlalchemy.orm import Session, sessionmaker

from server.services._console_protocol import (
    AsFastAsPossibleSpec,
    ProtocolError,
    RealTimeSpec,
    ReplayCloseMsg,
    ReplayMsg,
    ReplayOpenMsg,
    ReplayPauseMsg,
    ReplayPlayMsg,
    ReplaySeekMsg,
    ReplaySpeedMsg,
    ReplayStepMsg,
    StepSpec,
)
from server.services._console_streams import requested_columns
from server.services.console_messages import (
    FrameColumns,
    ReplayClosedMsg,
    ReplayCommand,
    ReplayCommandsMsg,
    ReplayOpenedMsg,
    ReplaySpeed,
    ReplayStateMsg,
    ReplayTelemetryMsg,
    ServerMsg,
)
from server.services.errors import DomainError
from server.services.recordings import load_recording
from server.storage import repository as repo
from server.storage.errors import InvalidArgument, NotFound
from telemetry.recording import CommandRow, FrameArrays, PassRecording
from telemetry.replay import AsFastAsPossible, Batch, RealTime, Replay, Speed, Step

if TYPE_CHECKING:
    from server.services.console import ConsoleLimits

__all__ = ["ReplayClient", "ReplaySession", "Replays", "frame_columns"]

log = logging.getLogger("hikoboshi.ground.console.replay")

_NEVER_NS = -(2**62)


class ReplayClient(Protocol):
    """What a replay needs of its console (:class:`server.services.console.ConsoleClient`)."""

    actor: str
    replay_bytes: int

    def control(self, message: ServerMsg, *, in_order: bool = False) -> None: ...

    def queue_replay(self, text: str) -> None: ...

    async def replay_below(self, limit_bytes: int) -> None: ...


# --- frames as the console's columns -------------------------------------------------------


def frame_columns(frames: FrameArrays, names: Sequence[str]) -> dict[str, list[Any]]:
    """The frames as the console's telemetry ``columns`` (the live message's values: a
    buffer with nothing queued has ``buffer_next_execute_time_ns`` null, not -1)."""
    sources = frames.layout.sources
    out: dict[str, list[Any]] = {}
    for name in names:
        array, index = sources[name]
        values = getattr(frames, array)
        out[name] = (values if index is None else values[:, index]).tolist()
    if "buffer_next_execute_time_ns" in out:
        out["buffer_next_execute_time_ns"] = [
            None if t == -1 else t for t in out["buffer_next_execute_time_ns"]
        ]
    return out


def _command_doc(command: CommandRow) -> ReplayCommand:
    return ReplayCommand(
        seq=command.seq,
        kind=command.kind,
        execute_time_ns=command.execute_time_ns,
        stage=command.stage,
        reject_reason=command.reject_reason,
        stage_times_ns=dict(command.stage_times_ns),
        payload=dict(command.payload),
    )


def _speed_doc(speed: Speed) -> ReplaySpeed:
    if isinstance(speed, RealTime):
        return RealTimeSpec(mode="real_time", factor=speed.factor)
    if isinstance(speed, AsFastAsPossible):
        return AsFastAsPossibleSpec(mode="as_fast_as_possible", batch_frames=speed.batch_frames)
    return StepSpec(mode="step")


def _speed(spec: RealTimeSpec | AsFastAsPossibleSpec | StepSpec, limits: ConsoleLimits) -> Speed:
    if isinstance(spec, RealTimeSpec):
        if spec.factor > limits.max_replay_factor:
            raise ProtocolError(f"replay factor {spec.factor} exceeds {limits.max_replay_factor}")
        return RealTime(spec.factor)
    if isinstance(spec, AsFastAsPossibleSpec):
        if spec.batch_frames > limits.max_replay_batch_frames:
            limit = limits.max_replay_batch_frames
            raise ProtocolError(f"batch_frames {spec.batch_frames} exceeds {limit}")
        return AsFastAsPossible(spec.batch_frames)
    return Step()


# --- one replay ----------------------------------------------------------------------------


class ReplaySession:
    """One recorded pass streamed to one console (see the module doc)."""

    def __init__(
        self,
        *,
        replay_id: str,
        client: ReplayClient,
        recording: PassRecording,
        speed: Speed,
        columns: tuple[str, ...],
        playing: bool,
        limits: ConsoleLimits,
        on_end: Callable[[ReplaySession], None],
    ) -> None:
        self.replay_id = replay_id
        self.client = client
        self.recording = recording
        self.pass_id = str(recording.meta["pass_id"])
        self.engine = Replay(recording, speed=speed)
        self.columns = columns
        self.limits = limits
        self.seq = 0  # the last data message's seq
        self.playing = playing  # what the console asked for
        self.stalled = False  # held while the console catches up
        self._on_end = on_end
        self._wake = asyncio.Event()
        self._last_poll_ns = _NEVER_NS
        self._last_report_ns = _NEVER_NS
        self.task: asyncio.Task[None] | None = None
        times_ns = recording.frames.generation_time_ns
        self.first_ns, self.last_ns = int(times_ns[0]), int(times_ns[-1])

    def start(self) -> None:
        self._sync(time.monotonic_ns())
        self.task = asyncio.create_task(self._run(), name=f"console-replay-{self.replay_id}")

    def opened(self) -> ReplayOpenedMsg:
        """``replay_opened``: the state and what the recording holds."""
        recording = self.recording
        return ReplayOpenedMsg(
            **self.state("open").model_dump(exclude={"v", "type"}),
            name=recording.name,
            epoch_ns=recording.epoch_ns,
            commands=len(recording.commands),
            first_generation_time_ns=self.first_ns,
            last_generation_time_ns=self.last_ns,
            plan_duration_s=recording.plan.duration_s,
            columns=list(self.columns),
        )

    def state(self, reason: str) -> ReplayStateMsg:
        engine = self.engine
        frames = len(self.recording.frames)
        playhead_ns = min(engine.playhead_ns(time.monotonic_ns()), self.last_ns)
        position = engine.position
        times_ns = self.recording.frames.generation_time_ns
        next_ns = int(times_ns[position]) if position < frames else None
        return ReplayStateMsg(
            replay_id=self.replay_id,
            pass_id=self.pass_id,
            seq=self.seq,
            reason=reason,
            playing=self.playing,
            finished=engine.finished,
            speed=_speed_doc(engine.speed),
            position=position,
            frames=frames,
            next_generation_time_ns=next_ns,
            playhead_ns=playhead_ns,
            playhead_t_s=(playhead_ns - self.recording.epoch_ns) / 1e9,
        )

    def report(self, reason: str) -> None:
        self._last_report_ns = time.monotonic_ns()
        self.client.control(self.state(reason), in_order=True)

    # -- control (the hub's handler; the task is woken to notice) --------------------------

    def _sync(self, now_ns: int) -> None:
        run = self.playing and not self.stalled
        if run and self.engine.paused:
            self.engine.play(now_ns)
        elif not run and not self.engine.paused:
            self.engine.pause(now_ns)
        self._wake.set()

    def play(self) -> None:
        if self.engine.finished:
            raise ProtocolError(f"replay {self.replay_id!r} is at its end: seek to play again")
        self.playing = True
        self._sync(time.monotonic_ns())
        self.report("play")

    def pause(self) -> None:
        self.playing = False
        self._sync(time.monotonic_ns())
        self.report("pause")

    def step(self) -> None:
        if self.engine.finished:
            raise ProtocolError(f"replay {self.replay_id!r} is at its end: nothing to step")
        self._deliver(self.engine.step())
        if self.engine.finished:
            self.playing = False
            self._sync(time.monotonic_ns())
        self.report("step")

    def set_speed(self, speed: Speed) -> None:
        self.engine.set_speed(speed, time.monotonic_ns())
        self._wake.set()
        self.report("speed")

    def seek(self, message: ReplaySeekMsg) -> None:
        if (message.onboard_time_ns is None) == (message.plan_t_s is None):
            raise ProtocolError("replay_seek needs one of onboard_time_ns and plan_t_s")
        if message.onboard_time_ns is not None:
            time_ns = message.onboard_time_ns
        else:
            assert message.plan_t_s is not None
            time_ns = self.recording.epoch_ns + round(message.plan_t_s * 1e9)
        if not self.first_ns <= time_ns <= self.last_ns:
            raise ProtocolError(
                f"seek to onboard {time_ns} ns is outside the recording "
                f"({self.first_ns}..{self.last_ns} ns)"
            )
        self.engine.seek_onboard(time_ns, time.monotonic_ns())
        self._wake.set()
        self.report("seek")

    def cancel(self) -> None:
        if self.task is not None:
            self.task.cancel()

    # -- delivery ------------------------------------------------------------------------

    def _deliver(self, batch: Batch) -> None:
        replay_id, pass_id = self.replay_id, self.pass_id
        chunk = self.limits.max_replay_batch_frames
        for lo in range(0, len(batch.frames), chunk):
            part = batch.frames.take(slice(lo, lo + chunk))
            self.seq += 1
            message = ReplayTelemetryMsg(
                replay_id=replay_id,
                pass_id=pass_id,
                seq=self.seq,
                row=batch.first_row + lo,
                count=len(part),
                columns=FrameColumns(frame_columns(part, self.columns)),
            )
            self.client.queue_replay(message.encode())
        if batch.commands:
            self.seq += 1
            commands = [_command_doc(c) for c in batch.commands]
            self.client.queue_replay(
                ReplayCommandsMsg(
                    replay_id=replay_id, pass_id=pass_id, seq=self.seq, commands=commands
                ).encode()
            )

    async def _wait(self, delay_s: float | None) -> None:
        self._wake.clear()
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self._wake.wait(), delay_s)

    async def _run(self) -> None:
        try:
            await self._pace()
        except asyncio.CancelledError:
            raise
        except Exception as exc:
            log.exception("replay %s of pass %s failed", self.replay_id, self.pass_id)
            self._on_end(self)
            reason = f"failed: {exc!r}"[:300]
            self.client.control(
                ReplayClosedMsg(replay_id=self.replay_id, seq=self.seq, reason=reason),
                in_order=True,
            )

    async def _pace(self) -> None:
        limits = self.limits
        while True:
            now_ns = time.monotonic_ns()
            due_ns = self.engine.next_due_ns(now_ns)
            if due_ns is None:  # paused, stepping or at the end: wait for the console
                await self._wait(None)
                continue
            if self.client.replay_bytes > limits.replay_window_bytes:
                self.stalled = True
                self._sync(now_ns)
                await self.client.replay_below(limits.replay_window_bytes // 2)
                self.stalled = False
                self._sync(time.monotonic_ns())
                continue
            if isinstance(self.engine.speed, RealTime):
                # Not more often than every tick: at x1000 frames come in batches, not one
                # wake-up each.
                due_ns = max(due_ns, self._last_poll_ns + round(limits.replay_tick_s * 1e9))
            if due_ns > now_ns:
                await self._wait((due_ns - now_ns) / 1e9)
                continue
            self._last_poll_ns = now_ns
            self._deliver(self.engine.poll(now_ns))
            if self.engine.finished:
                self.playing = False
                self._sync(now_ns)
                self.report("finished")
            elif now_ns - self._last_report_ns >= limits.replay_report_s * 1e9:
                self.report("progress")
            await asyncio.sleep(0)  # the console's sender (and everyone else) gets a turn


# --- every replay of the hub ---------------------------------------------------------------


class Replays:
    """The replays of every console of one hub: opening, control, limits, ownership."""

    def __init__(self, *, sessions: sessionmaker[Session], limits: ConsoleLimits) -> None:
        self._sessions = sessions
        self.limits = limits
        self._by_id: dict[str, ReplaySession] = {}
        self._opening: list[ReplayClient] = []  # consoles loading a recording (one slot each)

    def __len__(self) -> int:
        return len(self._by_id)

    def of(self, client: ReplayClient) -> list[ReplaySession]:
        """The console's open replays."""
        return [s for s in self._by_id.values() if s.client is client]

    def _count(self, client: ReplayClient) -> int:
        return len(self.of(client)) + sum(1 for c in self._opening if c is client)

    async def handle(self, client: ReplayClient, message: ReplayMsg) -> None:
        if isinstance(message, ReplayOpenMsg):
            await self._open(client, message)
            return
        session = self._by_id.get(message.replay_id)
        if session is None or session.client is not client:
            raise ProtocolError(f"replay {message.replay_id!r} is not open on this console")
        if isinstance(message, ReplayPlayMsg):
            session.play()
        elif isinstance(message, ReplayPauseMsg):
            session.pause()
        elif isinstance(message, ReplayStepMsg):
            session.step()
        elif isinstance(message, ReplaySpeedMsg):
            session.set_speed(_speed(message.speed, self.limits))
        elif isinstance(message, ReplaySeekMsg):
            session.seek(message)
        elif isinstance(message, ReplayCloseMsg):
            self._end(session)
            client.control(
                ReplayClosedMsg(replay_id=session.replay_id, seq=session.seq, reason="requested"),
                in_order=True,
            )

    async def _open(self, client: ReplayClient, message: ReplayOpenMsg) -> None:
        limits = self.limits
        speed = _speed(message.speed or RealTimeSpec(mode="real_time"), limits)
        asked = requested_columns(message.fields)
        if self._count(client) >= limits.max_replays_per_console:
            raise ProtocolError(
                f"{limits.max_replays_per_console} replays per console at most: close one"
            )
        if len(self._by_id) + len(self._opening) >= limits.max_replays:
            raise ProtocolError(f"the server has {limits.max_replays} replays open, its limit")
        self._opening.append(client)
        try:
            recording = await asyncio.to_thread(self._load, message.pass_id)
        finally:
            self._opening.remove(client)
        replay_id = f"r-{secrets.token_hex(6)}"
        # The pass's robot's columns: a field it does not have (j7 of a 6-joint pass) is
        # left out, so a console may ask for the joints up to the archive's most.
        own = recording.frames.layout.columns
        columns = own if asked is None else tuple(name for name in asked if name in own)
        try:
            session = ReplaySession(
                replay_id=replay_id,
                client=client,
                recording=recording,
                speed=speed,
                columns=columns,
                playing=not message.paused,
                limits=limits,
                on_end=self._forget,
            )
        except ValueError as exc:  # an onboard clock that ran backwards
            raise ProtocolError(f"pass {recording.name!r} cannot be replayed: {exc}") from None
        self._by_id[replay_id] = session
        client.control(session.opened(), in_order=True)
        session.start()
        log.info("console %s replays pass %s as %s", client.actor, session.pass_id, replay_id)

    def _load(self, pass_id: str) -> PassRecording:
        try:
            with self._sessions() as session:
                record = repo.get_pass(session=session, pass_id=pass_id)
                if record.epoch_ns is None:
                    raise ProtocolError(
                        f"pass {record.name!r} is {record.state}: it has not flown, "
                        "there is nothing to replay"
                    )
                n = repo.count_frames(session=session, pass_id=record.id)
                if n == 0:
                    raise ProtocolError(f"pass {record.name!r} has no telemetry to replay")
                if n > self.limits.max_replay_frames:
                    limit = self.limits.max_replay_frames
                    raise ProtocolError(
                        f"pass {record.name!r} has {n} frames: a replay holds {limit} at most"
                    )
                return load_recording(session=session, pass_id=record.id)
        except (NotFound, InvalidArgument) as exc:
            raise ProtocolError(str(exc)) from None
        except DomainError as exc:
            raise ProtocolError(exc.message) from None

    def _forget(self, session: ReplaySession) -> None:
        if self._by_id.get(session.replay_id) is session:
            del self._by_id[session.replay_id]

    def _end(self, session: ReplaySession) -> None:
        self._forget(session)
        session.cancel()

    def close_client(self, client: ReplayClient) -> None:
        """The console went: its replays end without a word."""
        for session in self.of(client):
            self._end(session)

    async def close(self) -> None:
        sessions = list(self._by_id.values())
        for session in sessions:
            self._end(session)
        for session in sessions:
            if session.task is not None:
                with contextlib.suppress(asyncio.CancelledError):
                    await session.task
