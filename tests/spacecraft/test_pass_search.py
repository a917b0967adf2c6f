"""The demo-pass search's score (spacecraft._pass_search): the margins of the paper's rows the
attitude law shapes, on the demo pass flown with the default law."""

from __future__ import annotations

import math

import pytest

from spacecraft._pass_search import BOUNDS, NAMES, cost, margins, values_of
from telemetry.analysis import analyse_pass
from telemetry.recording import PassRecording


def test_the_default_law_holds_every_row_on_the_demo_pass(demo_recording: PassRecording) -> None:
    m = margins(analyse_pass(demo_recording))
    assert set(m) == {
        "ptp_settling",
        "leg_peak",
        "leg_settling",
        "feedback_min",
        "feedback_max",
        "feedforward_dip",
        "feedforward_overshoot",
        "offset_range",
        "offset_settling",
        "start_(a)",
        "start_(b)",
        "start_(c)",
    }
    # Measured (seed 7), in units of 10 s, 0.05 deg, 0.02 deg (starts), 0.01 deg and 1 s
    # (legs): PTP 2.0, (a)'s dip 0.18 (0.009 deg inside -0.35), (b)'s dip 0.82, (c)'s range
    # 6.0 and settling 1.2 (12 s ahead), starts 0.67 at the least, the fast leg 0.89.
    assert all(v > 0.0 for v in m.values()), m
    assert m["offset_settling"] > 1.0 and m["offset_range"] > 1.0
    total, worst = cost([m, m])
    assert worst == m and 0.0 < total < 2.0


def test_cost_takes_each_row_s_worst_seed_and_counts_only_shortfalls() -> None:
    total, worst = cost([{"a": 2.0, "b": 0.5}, {"a": -1.0, "b": 3.0}])
    assert worst == {"a": -1.0, "b": 0.5}
    assert total == pytest.approx(2.0**2 + 0.5**2)
    assert cost([{"a": 1.0, "b": 5.0}])[0] == 0.0


def test_search_space_maps_to_the_law_s_parameters() -> None:
    assert len(NAMES) == len(BOUNDS) == 5
    v = values_of([0.03, 0.55, 11.0, math.log(0.3), 0.035])
    assert v == pytest.approx(
        {
            "bandwidth_radps": 0.03,
            "damping_ratio": 0.55,
            "rate_filter_tau_s": 11.0,
            "torque_limit_nm": 0.3,
            "dead_band_deg": 0.035,
        }
    )
    # the defaults are inside the searched box
    for (lo, hi), x in zip(BOUNDS, (0.03, 0.55, 11.0, math.log(0.3), 0.035), strict=True):
        assert lo <= x <= hi
