"""The link follows the geometry: a contact plan from the mission's windows gives the link's
loss and acquisition of signal and its one-way delay (spacecraft/contact.py, link.py)."""

from __future__ import annotations

from datetime import timedelta
from functools import cache

import numpy as np
import pytest

from mission import MISSIONS_DIR, Window, compute_windows, light_times, load_mission, parse_utc
from spacecraft.contact import ContactPlan, ContactWindow, contact_plan
from spacecraft.link import LinkConfig, LinkEmulator, Outage

START = parse_utc("1999-09-30T00:00:00Z")


@cache
def _mission_windows() -> tuple[object, tuple[Window, ...]]:
    mission = load_mission(MISSIONS_DIR / "ets7-1999.toml")
    windows = compute_windows(mission, START, 6.0)
    return mission, tuple(windows)


def _one_relay() -> tuple[object, tuple[Window, ...]]:
    """TDRS-West's windows only: they never overlap, gaps of about 40 minutes."""
    mission, windows = _mission_windows()
    return mission, tuple(w for w in windows if w.relay == "TDRS-West")


def test_the_delay_is_the_processing_delay_plus_the_paths_light_time() -> None:
    mission, windows = _one_relay()
    plan = contact_plan(mission, START, windows[:1])
    window = windows[0]
    (cw,) = plan.windows
    assert cw.start_s == (window.aos_utc - START).total_seconds()
    assert cw.end_s == pytest.approx(cw.start_s + window.duration_s)
    processing = mission.ground.processing_delay_s  # type: ignore[attr-defined]
    # at points between the plan's samples, against the geometry sampled there directly
    offsets, light = light_times(mission, window, step_s=3.7)  # type: ignore[arg-type]
    offsets, light = offsets[:-1], light[:-1]  # at LOS the link is down
    for offset, lt in zip(offsets, light, strict=True):
        assert plan.delay_at(cw.start_s + offset) == pytest.approx(processing + lt, abs=1e-6)
    delays = [plan.delay_at(cw.start_s + o) for o in offsets]
    assert min(delays) == pytest.approx(processing + window.light_time_min_s, abs=1e-4)
    assert max(delays) == pytest.approx(processing + window.light_time_max_s, abs=1e-4)
    assert max(delays) - min(delays) > 0.02  # it varies along the window (~8000 km of range)
    assert plan.delay_at(cw.start_s - 1.0) is None
    assert plan.delay_at(cw.end_s) is None


def test_overlapping_windows_hand_over_at_the_first_ones_loss() -> None:
    def window(relay: str, a: float, b: float, d: float) -> ContactWindow:
        return ContactWindow(relay, a, b, (a, b), (d, d))

    plan = ContactPlan([window("B", 50.0, 200.0, 2.0), window("A", 0.0, 100.0, 1.0)])
    assert plan.window_at(-1.0) is None
    assert plan.window_at(0.0).relay == "A"  # type: ignore[union-attr]
    assert plan.window_at(99.9).relay == "A"  # type: ignore[union-attr]
    assert plan.window_at(100.0).relay == "B"  # type: ignore[union-attr]
    assert plan.window_at(200.0) is None
    assert plan.next_start_s(-5.0) == 0.0
    assert plan.next_start_s(10.0) is None
    assert plan.end_of_contact_s(10.0) == 200.0
    assert plan.end_of_contact_s(250.0) is None
    # a message in flight across the handover is lost with the first relay
    link = LinkEmulator(LinkConfig(jitter_s=0.0, contact=plan))
    assert link.send(98.5, 10) == pytest.approx(99.5)  # A's delay, arrives before A's LOS
    assert link.send(99.1, 10) is None
    assert link.send(99.9, 10) is None
    assert link.send(100.5, 10) == pytest.approx(102.5)  # now on B, B's delay
    assert link.send(199.5, 10) is None


def test_no_message_crosses_the_link_outside_a_window() -> None:
    """A message handed over at random instants over six hours (windows and gaps) is
    delivered only if sent inside a window and arriving before its loss of signal; every
    message sent well inside a window arrives, at the plan's delay."""
    mission, windows = _one_relay()
    plan = contact_plan(mission, START, windows)
    assert len(plan.windows) >= 3
    link = LinkEmulator(LinkConfig(jitter_s=0.0, contact=plan, seed=3))
    rng = np.random.default_rng(7)
    times = np.sort(rng.uniform(-600.0, 6 * 3600.0, 4000))
    # and a few at each window's edges
    edges = [t for w in plan.windows for t in (w.start_s - 0.1, w.end_s - 3.1, w.end_s - 2.0)]
    outside = inside = delivered_inside = 0
    for t in sorted([*times.tolist(), *edges]):
        arrival = link.send(float(t), 100)
        window = plan.window_at(float(t))
        if arrival is not None:
            assert window is not None, f"sent at {t} s outside every window, delivered"
            assert window.start_s <= t and arrival < window.end_s
            assert arrival - t == pytest.approx(window.delay_at(float(t)), abs=1e-9)
        if window is None:
            outside += 1
        elif t < window.end_s - 3.5:
            inside += 1
            delivered_inside += arrival is not None
    assert outside > 500 and inside > 500
    assert delivered_inside == inside
    stats = link.stats
    assert stats.sent == stats.delivered + stats.dropped_outage
    assert stats.dropped_outage >= outside


def test_hand_given_outages_still_apply_with_a_contact_plan() -> None:
    mission, windows = _one_relay()
    plan = contact_plan(mission, START, windows[:1])
    (cw,) = plan.windows
    mid = cw.start_s + 600.0
    link = LinkEmulator(LinkConfig(jitter_s=0.0, contact=plan, outages=(Outage(mid, mid + 30),)))
    assert not link.is_up(mid + 1.0)
    assert link.is_up(mid + 31.0)
    assert not link.is_up(cw.end_s + 1.0)
    assert link.send(mid - 1.0, 10) is None  # in flight when the outage begins
    assert link.send(mid + 40.0, 10) is not None


def test_windows_read_back_from_their_json() -> None:
    _, windows = _one_relay()
    for window in windows:
        again = Window.from_dict(window.to_dict())
        assert again.relay == window.relay
        assert abs(again.aos_utc - window.aos_utc) < timedelta(milliseconds=1)
        assert again.aos_margin_s == pytest.approx(window.aos_margin_s, abs=1e-3)
        assert again.net_s == pytest.approx(window.net_s, abs=2e-3)
