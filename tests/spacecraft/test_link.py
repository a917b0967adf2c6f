"""The relay-link emulator: delay statistics, loss, outages, bandwidth, order, determinism and
its configuration (SPEC 6). Times are onboard seconds throughout."""

from __future__ import annotations

import itertools
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spacecraft.link import (
    LinkConfig,
    LinkEmulator,
    LinkStats,
    Outage,
    load_link_config,
    parse_outage,
)

EXACT = 1e-9  # s; sums of a few decimal fractions of a second, nothing statistical


def _send_all(link: LinkEmulator, times_s: np.ndarray, size_bytes: int = 100) -> list[float | None]:
    return [link.send(float(t), size_bytes) for t in times_s]


def _delivered(results: list[float | None]) -> list[float]:
    return [r for r in results if r is not None]


class _FixedDraws:
    """Stands in for the emulator's generator to pin the jitter draw (the clip is otherwise
    reached once in 1.7 million messages, too rarely to test by sampling)."""

    def __init__(self, z: float) -> None:
        self.z = z

    def random(self) -> float:
        return 0.5

    def standard_normal(self) -> float:
        return self.z


# --- delay and jitter -----------------------------------------------------------------------


def test_delay_mean_and_std_match_the_config() -> None:
    n = 20_000
    cfg = LinkConfig(delay_s=3.0, jitter_s=0.05, preserve_order=False, seed=11)
    times_s = np.arange(n) * 0.25  # 4 Hz, SPEC 6
    delays_s = np.array(_send_all(LinkEmulator(cfg), times_s), dtype=float) - times_s

    # Standard error of the mean is sigma/sqrt(n) = 0.35 ms and of the sample standard
    # deviation about sigma/sqrt(2 n) = 0.25 ms (Gaussian). Five standard errors: a correct
    # emulator fails with probability below 1e-6 for an arbitrary seed, while a bias of 2 ms
    # or a std off by 2.5 % is caught. The 5-sigma clip changes the std by under 1e-5 relative.
    assert abs(delays_s.mean() - 3.0) <= 5 * 0.05 / math.sqrt(n)
    assert abs(delays_s.std(ddof=1) - 0.05) <= 5 * 0.05 / math.sqrt(2 * n)
    assert delays_s.min() >= 3.0 - 5 * 0.05 - EXACT
    assert delays_s.max() <= 3.0 + 5 * 0.05 + EXACT


def test_no_jitter_gives_exactly_the_delay() -> None:
    link = LinkEmulator(LinkConfig(delay_s=3.0, jitter_s=0.0))
    assert link.send(10.0, 100) == pytest.approx(13.0, abs=EXACT)
    assert link.send(10.25, 100) == pytest.approx(13.25, abs=EXACT)


@pytest.mark.parametrize(
    ("z", "expected_delay_s"),
    [(10.0, 3.0 + 5 * 0.05), (-10.0, 3.0 - 5 * 0.05), (1.0, 3.05), (-1.0, 2.95)],
)
def test_jitter_is_clipped_at_five_sigma(z: float, expected_delay_s: float) -> None:
    link = LinkEmulator(LinkConfig(delay_s=3.0, jitter_s=0.05))
    link._rng = _FixedDraws(z)  # type: ignore[assignment]
    assert link.send(0.0, 100) == pytest.approx(expected_delay_s, abs=EXACT)


def test_delay_never_goes_below_zero() -> None:
    link = LinkEmulator(LinkConfig(delay_s=0.1, jitter_s=1.0))
    link._rng = _FixedDraws(-3.0)  # type: ignore[assignment]
    assert link.send(5.0, 100) == pytest.approx(5.0, abs=EXACT)  # not 5.0 + 0.1 - 3.0

    # Sampled: a large jitter against a short delay clips about P(z < -0.1) = 46 % to zero.
    n = 4000
    times_s = np.arange(n) * 10.0
    cfg = LinkConfig(delay_s=0.1, jitter_s=1.0, preserve_order=False, seed=3)
    delays_s = np.array(_send_all(LinkEmulator(cfg), times_s), dtype=float) - times_s
    assert delays_s.min() >= 0.0
    # binomial standard error sqrt(0.46 * 0.54 / 4000) = 0.8 %; five of them
    assert abs(np.mean(delays_s == 0.0) - 0.4602) <= 0.04


# --- random loss ----------------------------------------------------------------------------


@pytest.mark.parametrize("loss", [0.01, 0.1, 0.5])
def test_loss_rate_matches_the_config(loss: float) -> None:
    n = 10_000
    link = LinkEmulator(LinkConfig(loss=loss, seed=5))
    results = _send_all(link, np.arange(n) * 0.25)
    n_lost = sum(r is None for r in results)
    rate = n_lost / n
    # Binomial: standard error sqrt(p (1 - p) / n), at most 0.5 % here; four of them keep a
    # correct emulator inside for any seed with probability 0.99994, and a rate off by a
    # fifth of p (at p = 0.1) or more is caught.
    assert abs(rate - loss) <= 4 * math.sqrt(loss * (1 - loss) / n)
    assert link.stats == LinkStats(
        sent=n, delivered=n - n_lost, dropped_loss=n_lost, dropped_outage=0, max_queue_delay_s=0.0
    )


def test_no_loss_delivers_everything() -> None:
    link = LinkEmulator(LinkConfig(loss=0.0, seed=5))
    results = _send_all(link, np.arange(5000) * 0.25)
    assert all(r is not None for r in results)
    assert link.stats.delivered == 5000


# --- outages --------------------------------------------------------------------------------


def test_is_up_at_the_outage_boundaries() -> None:
    link = LinkEmulator(LinkConfig(outages=(Outage(10.0, 20.0), Outage(50.0, 80.0))))
    assert link.is_up(9.999)
    assert not link.is_up(10.0)  # down from start_s ...
    assert not link.is_up(19.999)
    assert link.is_up(20.0)  # ... up again at end_s
    assert not link.is_up(65.0)
    assert link.is_up(80.0)


@pytest.mark.parametrize(
    ("send_s", "expected"),
    [
        (6.9, 9.9),  # arrives just before LOS
        (7.0, None),  # arrives as LOS begins
        (8.5, None),  # in flight when LOS begins
        (15.0, None),  # sent during LOS
        (19.99, None),  # sent just before AOS
        (20.0, 23.0),  # sent as the link returns
    ],
)
def test_outage_rule_at_the_boundaries(send_s: float, expected: float | None) -> None:
    link = LinkEmulator(LinkConfig(delay_s=3.0, jitter_s=0.0, outages=(Outage(10.0, 20.0),)))
    got = link.send(send_s, 100)
    if expected is None:
        assert got is None
        assert link.stats.dropped_outage == 1
    else:
        assert got == pytest.approx(expected, abs=EXACT)
        assert link.stats.delivered == 1


def test_a_short_outage_during_the_flight_loses_the_message() -> None:
    # 1 s of LOS entirely inside a 3 s flight: the message was in flight when LOS began.
    link = LinkEmulator(LinkConfig(delay_s=3.0, jitter_s=0.0, outages=(Outage(11.0, 12.0),)))
    assert link.send(7.9, 100) == pytest.approx(10.9, abs=EXACT)
    assert link.send(10.0, 100) is None
    assert link.send(12.0, 100) == pytest.approx(15.0, abs=EXACT)


def test_an_outage_added_at_run_time_acts_as_one_configured_from_the_start() -> None:
    cfg = LinkConfig(delay_s=3.0, jitter_s=0.05, loss=0.2, seed=5)
    configured = LinkEmulator(replace(cfg, outages=(Outage(40.0, 70.0),)))
    added = LinkEmulator(cfg)
    times_s = np.arange(0.0, 120.0, 0.25)
    early = times_s[times_s < 20.0]
    assert _send_all(added, early) == _send_all(configured, early)
    added.add_outage(Outage(40.0, 70.0))
    assert not added.is_up(50.0) and added.is_up(70.0)
    late = times_s[times_s >= 20.0]
    got = _send_all(added, late)
    assert got == _send_all(configured, late)
    assert any(a is None for a in got) and any(a is not None for a in got)


def test_an_outage_cannot_be_added_before_the_last_message_sent() -> None:
    link = LinkEmulator(LinkConfig())
    link.send(10.0, 100)
    with pytest.raises(ValueError, match=r"before the last message sent at 10\.0 s"):
        link.add_outage(Outage(9.0, 30.0))
    link.add_outage(Outage(10.0, 30.0))  # from now on is fine
    assert not link.is_up(10.0)


def test_outages_drop_exactly_the_messages_that_touch_them() -> None:
    outages = (Outage(100.0, 130.0), Outage(200.5, 201.0), Outage(400.0, 460.0))
    clear_cfg = LinkConfig(delay_s=3.0, jitter_s=0.05, preserve_order=False, seed=21)
    times_s = np.arange(0.0, 600.0, 0.25)
    with_los = _send_all(LinkEmulator(replace(clear_cfg, outages=outages)), times_s)
    # Same seed, no outages: the same draws, so the arrival each message would have had.
    clear = _send_all(LinkEmulator(clear_cfg), times_s)

    for t_s, got, arrival_s in zip(times_s, with_los, clear, strict=True):
        assert arrival_s is not None
        touched = any(o.start_s <= arrival_s and o.end_s > t_s for o in outages)
        assert (got is None) == touched, (t_s, arrival_s)
        if got is not None:
            assert got == arrival_s
    # Independent of the overlap formula: the link is up at send, at arrival and at every
    # outage start in between for each delivered message.
    probe = LinkEmulator(LinkConfig(outages=outages))
    for t_s, got in zip(times_s, with_los, strict=True):
        if got is not None:
            assert probe.is_up(t_s)
            assert probe.is_up(got)
            assert not any(t_s <= o.start_s <= got for o in outages)
    n_dropped = sum(r is None for r in with_los)
    # about 30 s + 0.5 s + 60 s of sends plus 3 s of flight before each LOS, at 4 Hz
    assert 4 * (90.5 + 3 * 3) - 6 <= n_dropped <= 4 * (90.5 + 3 * 3) + 6


# --- bandwidth ------------------------------------------------------------------------------


def test_back_to_back_messages_are_spaced_by_size_over_bandwidth() -> None:
    link = LinkEmulator(LinkConfig(delay_s=3.0, jitter_s=0.0, bandwidth_bps=1000.0))
    got = [float(link.send(0.0, 500) or math.nan) for _ in range(5)]
    # each takes 500 B / 1000 B/s = 0.5 s to serialise, one after another
    np.testing.assert_allclose(got, [3.5, 4.0, 4.5, 5.0, 5.5], rtol=0, atol=EXACT)
    assert link.stats.max_queue_delay_s == pytest.approx(2.0, abs=EXACT)
    # the spacing is set by the size of the later message; it waited 2.5 s behind the five
    assert link.send(0.0, 100) == pytest.approx(5.6, abs=EXACT)
    assert link.stats.max_queue_delay_s == pytest.approx(2.5, abs=EXACT)
    # once the transmitter is idle, no queueing: only this message's own serialisation
    assert link.send(10.0, 2000) == pytest.approx(15.0, abs=EXACT)
    # sent while the previous one is still being serialised (until 12.0): waits 1.5 s
    assert link.send(10.5, 250) == pytest.approx(12.0 + 0.25 + 3.0, abs=EXACT)
    assert link.stats.max_queue_delay_s == pytest.approx(2.5, abs=EXACT)  # 1.5 s < 2.5 s


def test_queueing_delay_grows_when_sending_faster_than_the_link() -> None:
    # 4 Hz of 500 B over 1000 B/s: each message needs 0.5 s, one arrives every 0.25 s, so the
    # k-th waits 0.25 k s behind the others.
    n = 40
    link = LinkEmulator(LinkConfig(delay_s=3.0, jitter_s=0.0, bandwidth_bps=1000.0))
    times_s = np.arange(n) * 0.25
    got = np.array(_send_all(link, times_s, size_bytes=500), dtype=float)
    queue_s = got - times_s - 0.5 - 3.0
    np.testing.assert_allclose(queue_s, 0.25 * np.arange(n), rtol=0, atol=EXACT)
    assert link.stats.max_queue_delay_s == pytest.approx(0.25 * (n - 1), abs=EXACT)


def test_unlimited_bandwidth_ignores_size() -> None:
    link = LinkEmulator(LinkConfig(delay_s=3.0, jitter_s=0.0))
    assert link.send(0.0, 10**9) == pytest.approx(3.0, abs=EXACT)
    assert link.send(0.0, 10**9) == pytest.approx(3.0, abs=EXACT)
    assert link.stats.max_queue_delay_s == 0.0


def test_lost_messages_still_occupy_the_transmitter() -> None:
    link = LinkEmulator(LinkConfig(delay_s=3.0, jitter_s=0.0, loss=0.5, bandwidth_bps=1000.0))
    got = [link.send(0.0, 500) for _ in range(200)]
    assert 0 < link.stats.dropped_loss < 200
    for k, r in enumerate(got):
        if r is not None:
            assert r == pytest.approx(3.0 + 0.5 * (k + 1), abs=1e-6)  # 200 sums of 0.5 s


# --- order ----------------------------------------------------------------------------------


def test_order_is_preserved_and_jitter_only_delays() -> None:
    # jitter of 1 s against 0.1 s between sends: without the rule, messages overtake
    ordered_cfg = LinkConfig(delay_s=3.0, jitter_s=1.0, loss=0.2, preserve_order=True, seed=8)
    times_s = np.arange(2000) * 0.1
    ordered = _send_all(LinkEmulator(ordered_cfg), times_s)
    raw = _send_all(LinkEmulator(replace(ordered_cfg, preserve_order=False)), times_s)

    raw_delivered = np.array(_delivered(raw))
    assert np.any(np.diff(raw_delivered) < 0)  # the test would see a violation
    assert np.all(np.diff(_delivered(ordered)) >= 0)

    # each delivered message arrives at max(its own arrival, the last delivered one)
    floor_s = -math.inf
    for o, r in zip(ordered, raw, strict=True):
        assert (o is None) == (r is None)  # same loss draws
        if r is not None:
            assert o == max(r, floor_s)
            floor_s = max(r, floor_s)


# --- determinism ----------------------------------------------------------------------------


def _busy_run(seed: int) -> tuple[list[float | None], LinkStats]:
    cfg = LinkConfig(
        jitter_s=0.3,
        loss=0.1,
        outages=(Outage(50.0, 80.0),),
        bandwidth_bps=2000.0,
        seed=seed,
    )
    link = LinkEmulator(cfg)
    sizes = [100, 700, 40, 1500, 320]
    results = [link.send(0.25 * k, sizes[k % 5]) for k in range(1000)]
    return results, link.stats


def test_same_seed_same_results() -> None:
    a, stats_a = _busy_run(seed=42)
    b, stats_b = _busy_run(seed=42)
    assert a == b  # exactly, not approximately
    assert stats_a == stats_b


def test_different_seeds_differ() -> None:
    a, _ = _busy_run(seed=42)
    b, _ = _busy_run(seed=43)
    assert a != b
    assert [r is None for r in a] != [r is None for r in b]


# --- properties -----------------------------------------------------------------------------


@settings(max_examples=200, deadline=None)
@given(
    gaps_s=st.lists(st.floats(0.0, 5.0), min_size=1, max_size=60),
    sizes=st.lists(st.integers(0, 5000), min_size=60, max_size=60),
    jitter_s=st.floats(0.0, 2.0),
    loss=st.floats(0.0, 0.9),
    bandwidth_bps=st.none() | st.floats(100.0, 1e6),
    outage=st.tuples(st.floats(0.0, 100.0), st.floats(0.01, 40.0)),
    seed=st.integers(0, 2**32),
)
def test_invariants_hold_for_any_traffic(
    gaps_s: list[float],
    sizes: list[int],
    jitter_s: float,
    loss: float,
    bandwidth_bps: float | None,
    outage: tuple[float, float],
    seed: int,
) -> None:
    los = Outage(outage[0], outage[0] + outage[1])
    cfg = LinkConfig(
        jitter_s=jitter_s, loss=loss, outages=(los,), bandwidth_bps=bandwidth_bps, seed=seed
    )
    link = LinkEmulator(cfg)
    times_s = list(itertools.accumulate(gaps_s))
    delivered = []
    for t_s, size in zip(times_s, sizes, strict=False):
        got = link.send(t_s, size)
        if got is not None:
            assert got >= t_s
            assert not los.overlaps(t_s, got)
            delivered.append(got)
    assert delivered == sorted(delivered)
    s = link.stats
    assert s.sent == len(times_s) == s.delivered + s.dropped_loss + s.dropped_outage
    assert s.delivered == len(delivered)
    assert s.max_queue_delay_s >= 0.0


# --- arguments and configuration ------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        ({"delay_s": -1.0}, ["delay_s", "-1.0", "[0, inf) s"]),
        ({"delay_s": math.nan}, ["delay_s", "nan"]),
        ({"jitter_s": -0.01}, ["jitter_s", "-0.01", "[0, inf) s"]),
        ({"loss": 1.0}, ["loss", "1.0", "[0, 1)"]),
        ({"loss": -0.1}, ["loss", "-0.1", "[0, 1)"]),
        ({"bandwidth_bps": 0.0}, ["bandwidth_bps", "0.0", "(0, inf) bytes/s"]),
        ({"seed": -1}, ["seed", "-1", ">= 0"]),
        ({"delay_s": "3"}, ["delay_s", "'3'"]),
        ({"preserve_order": 1}, ["preserve_order", "1"]),
    ],
)
def test_config_validation_names_field_value_and_range(
    kwargs: dict[str, object], words: list[str]
) -> None:
    with pytest.raises(ValueError) as info:
        LinkConfig(**kwargs)  # type: ignore[arg-type]
    for word in words:
        assert word in str(info.value)


@pytest.mark.parametrize(("start_s", "end_s"), [(20.0, 10.0), (10.0, 10.0)])
def test_outage_must_end_after_it_starts(start_s: float, end_s: float) -> None:
    with pytest.raises(ValueError, match=r"end_s = 10.0 must be greater than start_s"):
        Outage(start_s, end_s)


def test_send_rejects_bad_arguments() -> None:
    link = LinkEmulator(LinkConfig())
    link.send(10.0, 100)
    with pytest.raises(ValueError, match=r"now_s = 9.0 s is earlier than the previous send"):
        link.send(9.0, 100)
    with pytest.raises(ValueError, match=r"size_bytes = -1"):
        link.send(11.0, -1)
    with pytest.raises(ValueError, match=r"now_s = nan"):
        link.send(math.nan, 100)
    assert link.stats.sent == 1  # rejected calls send nothing
    assert link.send(10.0, 100) is not None  # the same instant is allowed


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "link.toml"
    path.write_text(text)
    return path


def test_toml_directions_inherit_the_shared_table(tmp_path: Path) -> None:
    path = _write(
        tmp_path,
        """
        [link]
        delay_s = 2.5
        jitter_s = 0.1
        seed = 7
        outages = [{start_s = 100, end_s = 130}]

        [uplink]
        loss = 0.05

        [downlink]
        jitter_s = 0.02
        bandwidth_bps = 8000
        preserve_order = false
        outages = [{start_s = 100, end_s = 130}, {start_s = 400.5, end_s = 431}]
        """,
    )
    up, down = load_link_config(path)
    assert up == LinkConfig(
        delay_s=2.5, jitter_s=0.1, loss=0.05, outages=(Outage(100, 130),), seed=7
    )
    assert down == LinkConfig(
        delay_s=2.5,
        jitter_s=0.02,
        bandwidth_bps=8000,
        preserve_order=False,
        outages=(Outage(100, 130), Outage(400.5, 431)),
        seed=8,  # the shared seed + 1
    )


def test_toml_seeds(tmp_path: Path) -> None:
    up, down = load_link_config(_write(tmp_path, ""))
    assert (up, down) == (LinkConfig(seed=0), LinkConfig(seed=1))
    up, down = load_link_config(_write(tmp_path, "[link]\nseed = 3\n[downlink]\nseed = 99\n"))
    assert (up.seed, down.seed) == (3, 99)
    up, down = load_link_config(_write(tmp_path, "[uplink]\nseed = 5\n"))
    assert (up.seed, down.seed) == (5, 1)


@pytest.mark.parametrize(
    ("text", "pattern"),
    [
        (
            "[uplink]\ndelai_s = 3.0\n",
            r"\[uplink\] has unknown key\(s\) delai_s; allowed: .*delay_s",
        ),
        ("[sidelink]\ndelay_s = 3.0\n", r"unknown table\(s\) sidelink; allowed: link, uplink"),
        ("[downlink]\ndelay_s = -1.0\n", r"\[downlink\] delay_s = -1.0 is outside .*\[0, inf\)"),
        ("[link]\ndelay_s = -1.0\n", r"\[link\] delay_s = -1.0 is outside"),
        ("[uplink]\nloss = 1.0\n", r"\[uplink\] loss = 1.0 is outside the allowed range \[0, 1\)"),
        ("[uplink]\nloss = 1.5\n", r"\[uplink\] loss = 1.5 is outside the allowed range \[0, 1\)"),
        (
            "[link]\noutages = [{start_s = 130, end_s = 100}]\n",
            r"\[link\] outages\[0\]: outage end_s = 100 must be greater than start_s = 130",
        ),
        (
            "[uplink]\noutages = [{start_s = 1, end_s = 2}, {start_s = 5, end_s = 5}]\n",
            r"\[uplink\] outages\[1\]: outage end_s = 5 must be greater than start_s = 5",
        ),
        (
            "[uplink]\noutages = [{start_s = 1, end = 2}]\n",
            r"outages\[0\] = .* must be a table with exactly start_s and end_s",
        ),
        ("[uplink]\noutages = 5\n", r"outages must be an array"),
        ("[uplink]\ndelay_s = '3'\n", r"delay_s = '3' is outside"),
        ("link = 3\n", r"\[link\] must be a table"),
        ("[uplink\n", r"not valid TOML"),
    ],
)
def test_toml_errors_are_clear(tmp_path: Path, text: str, pattern: str) -> None:
    path = _write(tmp_path, text)
    with pytest.raises(ValueError, match=pattern) as info:
        load_link_config(path)
    assert str(path) in str(info.value)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("100:130", Outage(100.0, 130.0)),
        ("0.5:1.25", Outage(0.5, 1.25)),
        (" 100 : 130 ", Outage(100.0, 130.0)),
        ("-5:1e2", Outage(-5.0, 100.0)),
    ],
)
def test_parse_outage(text: str, expected: Outage) -> None:
    assert parse_outage(text) == expected


@pytest.mark.parametrize(
    ("text", "pattern"),
    [
        ("100", r"not START:END"),
        ("100-130", r"not START:END"),
        ("1:2:3", r"not START:END"),
        ("a:b", r"not START:END"),
        ("", r"not START:END"),
        (":130", r"not START:END"),
        ("130:100", r"end_s = 100.0 must be greater than start_s = 130.0"),
        ("100:100", r"must be greater than"),
        ("nan:5", r"start_s = nan is outside"),
        ("0:inf", r"end_s = inf is outside"),
    ],
)
def test_parse_outage_rejects(text: str, pattern: str) -> None:
    with pytest.raises(ValueError, match=pattern) as info:
        parse_outage(text)
    assert repr(text) in str(info.value)
