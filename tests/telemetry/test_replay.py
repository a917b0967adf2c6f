"""Replay on a simulated clock: every frame once and in order, on time; seek, pause, step."""

from __future__ import annotations

import numpy as np
import pytest

from telemetry.recording import CommandRow, PassRecording
from telemetry.replay import AsFastAsPossible, Batch, RealTime, Replay, Step

MS = 1_000_000


def with_commands(demo: PassRecording, n_frames: int) -> PassRecording:
    """The demo's first frames, with commands tagged between frames, on frames, before the
    first and after the last, listed out of tag order."""
    gen = demo.frames.generation_time_ns
    tags = [int(gen[3]), int(gen[0]) - 5 * MS, int(gen[10]) + 30 * MS, int(gen[n_frames - 1]) + 7]
    commands = tuple(
        CommandRow(seq=i, kind="joints", execute_time_ns=t, payload={}, stage="executed")
        for i, t in enumerate(tags)
    )
    return PassRecording(
        "cmds", demo.plan, demo.epoch_ns, demo.frames.take(slice(0, n_frames)), commands=commands
    )


def first_at_or_after(times: np.ndarray, t_ns: int) -> int:
    """The reference answer, by a plain scan."""
    for k, t in enumerate(times.tolist()):
        if t >= t_ns:
            return k
    return len(times)


@pytest.mark.slow
def test_ten_times_real_time_delivers_every_frame_once_in_order_on_time(
    demo_recording: PassRecording,
) -> None:
    gen = demo_recording.frames.generation_time_ns
    replay = Replay(demo_recording, speed=RealTime(10.0))
    rng = np.random.default_rng(3)
    now = start = 5_000 * MS
    replay.play(now)
    delivered: list[np.ndarray] = []
    polls = 0
    while not replay.finished:
        due = replay.next_due_ns(now)
        assert due is not None and due >= now
        # A late wake-up now and then (a busy event loop): batches of several frames.
        now = due + int(rng.choice([0, 0, 0, 1, 35 * MS]))
        batch = replay.poll(now)
        polls += 1
        assert len(batch) > 0, "woken when due, yet nothing delivered"
        onboard_elapsed = (now - start) * 10
        # Nothing early: each frame delivered is due by now ...
        assert int(batch.frames.generation_time_ns[-1]) - int(gen[0]) <= onboard_elapsed + 1
        # ... and nothing held back: the next one is not due yet.
        if replay.position < len(gen):
            assert int(gen[replay.position]) - int(gen[0]) >= onboard_elapsed
        delivered.append(batch.frames.seq)
    seqs = np.concatenate(delivered)
    np.testing.assert_array_equal(seqs, demo_recording.frames.seq)
    assert polls < len(gen)  # the late wake-ups did batch frames
    # The pass took a tenth of its onboard duration on the simulated clock (within a frame).
    duration_ns = int(gen[-1] - gen[0])
    assert abs((now - start) - duration_ns / 10) <= 100 * MS


@pytest.mark.parametrize("offset_ns", [0, 1, 49 * MS, -1])
def test_seek_lands_on_the_first_frame_at_or_after(
    demo_recording: PassRecording, offset_ns: int
) -> None:
    gen = demo_recording.frames.generation_time_ns
    replay = Replay(demo_recording, speed=RealTime(1.0))
    for row in (0, 1, 4321, len(gen) - 1):
        target = int(gen[row]) + offset_ns
        replay.seek_onboard(target, now_ns=0)
        want = first_at_or_after(gen, target)
        assert replay.position == want
        replay.play(0)
        batch = replay.poll(replay.next_due_ns(0) or 0)
        if want < len(gen):
            assert batch.first_row == want
            assert int(batch.frames.seq[0]) == int(demo_recording.frames.seq[want])
        else:
            assert len(batch) == 0 and replay.finished
        replay.pause(0)


def test_seek_on_the_plan_clock(demo_recording: PassRecording) -> None:
    t_s = demo_recording.t_s()
    replay = Replay(demo_recording)
    for target_s in (-5.0, 0.0, 680.0, 745.05, float(t_s[-1]), float(t_s[-1]) + 1.0):
        replay.seek_plan(target_s, now_ns=0)
        want = first_at_or_after(
            demo_recording.frames.generation_time_ns,
            demo_recording.epoch_ns + round(target_s * 1e9),
        )
        assert replay.position == want
        step = replay.step()
        assert step.first_row == want and len(step) == (1 if want < len(t_s) else 0)
        if want < len(t_s):
            assert t_s[want] >= target_s - 1e-9


def test_pause_stops_delivery_and_resume_continues_where_it_stood(
    demo_recording: PassRecording,
) -> None:
    gen = demo_recording.frames.generation_time_ns
    replay = Replay(demo_recording, speed=RealTime(2.0))
    replay.play(0)
    first = replay.poll(1000 * MS)  # 2 s onboard: frames up to gen[0] + 2 s
    assert first.frames.seq.tolist() == demo_recording.frames.seq[:21].tolist()
    replay.pause(1020 * MS)  # playhead at gen[0] + 2.04 s
    for later in (2_000 * MS, 60_000 * MS):
        assert replay.poll(later).empty
        assert replay.next_due_ns(later) is None
    assert replay.position == 21
    replay.resume(100_000 * MS)
    # Frame 21 is 2.1 s onboard from the start: 0.06 s onboard after the pause, 30 ms later.
    assert replay.next_due_ns(100_000 * MS) == 100_030 * MS
    assert replay.poll(100_029 * MS).empty
    assert replay.poll(100_030 * MS).first_row == 21
    assert int(gen[21] - gen[0]) == 2_100 * MS


def test_step_delivers_one_frame_per_call(demo_recording: PassRecording) -> None:
    replay = Replay(demo_recording, speed=Step())
    replay.play(0)
    assert replay.poll(10**15).empty
    assert replay.next_due_ns(0) is None
    for row in range(5):
        batch = replay.step()
        assert (batch.first_row, len(batch)) == (row, 1)
        assert batch.frames.seq.tolist() == [int(demo_recording.frames.seq[row])]
    # Stepping from a paused real-time replay, then resuming: no frame twice, none skipped.
    replay.set_speed(RealTime(1.0), now_ns=0)
    replay.pause(0)
    assert replay.step().first_row == 5
    replay.resume(0)
    assert replay.poll(10**15).first_row == 6


def test_as_fast_as_possible_in_batches(demo_recording: PassRecording) -> None:
    replay = Replay(demo_recording, speed=AsFastAsPossible(batch_frames=1000))
    replay.play(0)
    batches: list[Batch] = []
    while not replay.finished:
        assert replay.next_due_ns(7) == 7
        batches.append(replay.poll(7))
    assert [len(b) for b in batches[:-1]] == [1000] * (len(batches) - 1)
    seqs = np.concatenate([b.frames.seq for b in batches])
    np.testing.assert_array_equal(seqs, demo_recording.frames.seq)


@pytest.mark.parametrize("speed", [RealTime(10.0), AsFastAsPossible(batch_frames=7), Step()])
def test_commands_go_out_once_when_the_playhead_passes_their_tag(
    demo_recording: PassRecording, speed: RealTime | AsFastAsPossible | Step
) -> None:
    recording = with_commands(demo_recording, 30)
    tags = {c.seq: c.execute_time_ns for c in recording.commands}
    replay = Replay(recording, speed=speed)
    replay.play(0)
    now, sent = 0, []
    while not replay.finished:
        batch = replay.step() if isinstance(speed, Step) else replay.poll(now)
        sent += [c.seq for c in batch.commands]
        # Out: exactly the commands tagged at or before the playhead, none twice.
        passed_ns = replay.playhead_ns(now)
        assert sorted(sent) == sorted(seq for seq, t in tags.items() if t <= passed_ns)
        due = replay.next_due_ns(now)
        now = due if due is not None else now
    assert sent == sorted(tags, key=lambda seq: tags[seq])
    assert len(sent) == len(set(sent)) == 4


def test_a_recording_with_time_running_backwards_is_refused(
    demo_recording: PassRecording,
) -> None:
    frames = demo_recording.frames.take(slice(0, 10))
    frames.generation_time_ns[6] = frames.generation_time_ns[2]
    bad = PassRecording("bad", demo_recording.plan, demo_recording.epoch_ns, frames)
    with pytest.raises(ValueError, match="frame 6: generation_time_ns runs backwards"):
        Replay(bad)


def test_take_copies_even_a_slice(demo_recording: PassRecording) -> None:
    before = demo_recording.frames.joints_rad[0, 0]
    frames = demo_recording.frames.take(slice(0, 3))
    frames.joints_rad[0, 0] = before + 1.0
    assert demo_recording.frames.joints_rad[0, 0] == before
