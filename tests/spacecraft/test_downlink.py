"""The onboard telemetry store: nothing is given up until the ground holds it."""

from __future__ import annotations

from spacecraft.downlink import Downlink, DownlinkConfig
from tests.support.wire import frame as _frame


def _sent(messages: list) -> list[int]:  # type: ignore[type-arg]
    return [f.seq for frames, _ in messages for f in frames]


def test_live_frames_go_at_once_and_acked_ones_are_forgotten() -> None:
    store = Downlink(DownlinkConfig(resend_after_s=10.0))
    store.add(_frame(i) for i in range(5))
    assert _sent(store.due(0.0)) == [0, 1, 2, 3, 4]
    assert store.unacked == 5
    store.on_ack(2, [(4, 4)])
    assert store.unacked == 1
    assert store.due(5.0) == []  # not stale yet
    messages = store.due(10.0)
    assert _sent(messages) == [3] and messages[0][1] is True  # a retransmission


def test_a_backlog_drains_oldest_first_at_the_dump_rate() -> None:
    store = Downlink(DownlinkConfig(resend_after_s=10.0, dump_rate_fps=100.0))
    store.add(_frame(i) for i in range(1000))
    store.due(0.0)  # all sent once, into an outage: none acknowledged
    resent: list[int] = []
    t = 10.0
    while len(resent) < 1000:
        resent += _sent(store.due(t))
        t += 0.1
        assert t < 30.0
    assert resent == list(range(1000))  # oldest first, each once
    # 1000 frames at 100 frames/s (plus one bucket of 50): about 9.5 s
    assert 9.0 <= t - 10.0 <= 10.5


def test_retransmit_requests_jump_the_timeout() -> None:
    store = Downlink()
    store.add(_frame(i) for i in range(10))
    store.due(0.0)
    store.on_ack(3, [(7, 9)])
    store.on_retransmit([(4, 6)])
    assert _sent(store.due(0.5)) == [4, 5, 6]
    assert store.resent == 3


def test_overflow_is_counted_not_silent() -> None:
    store = Downlink(DownlinkConfig(capacity_frames=10))
    store.add(_frame(i) for i in range(12))
    assert store.unacked == 10 and store.frames_overflowed == 2


def test_acks_and_requests_forget_and_resend_the_same_frames_in_any_order_of_adding() -> None:
    """An acknowledgement reads only the seqs it covers when the frames came in seq order
    (the vehicle's); frames added out of order, ranges wider than the store and empty ranges
    give what a look at every frame held gives."""
    for order in (list(range(20)), [5, 3, 9, 0, 1, 2, 4, 6, 7, 8, *range(10, 20)]):
        store = Downlink(DownlinkConfig(capacity_frames=18))
        store.add(_frame(i) for i in order)  # the two oldest (0 and 1) are given up
        held = set(range(2, 20))
        store.due(0.0)
        store.on_ack(4, [(8, 8), (12, 10), (15, 10**9)])
        held -= {s for s in held if s <= 4 or s == 8 or s >= 15}
        assert store.unacked == len(held)
        store.on_retransmit([(0, 6), (9, 11), (-(10**9), 7)])
        assert _sent(store.due(0.5)) == sorted(held & {5, 6, 7, 9, 10, 11})
