"""The console plots the joints the data has: a 7-joint pass's archive shows seven joint
plots and a J7 column; ETS-VII's shows six (the store takes n from the data, not a 6)."""

from __future__ import annotations

import pytest

from tests.server.link.harness import Ground
from tests.server.storage.factories import make_plan
from tests.support.web import VIEWER_TOKEN, Console, stored_pass

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time


def _stored_pass(ground: Ground, name: str, n_joints: int, n_frames: int) -> str:
    return stored_pass(ground, name, make_plan(n_joints=n_joints), n_frames)


def _joint_plots(console: Console, pass_id: str, frames: int) -> tuple[list[int], list[str]]:
    console.sign_in(VIEWER_TOKEN, f"#/live/{pass_id}")
    console.wait(f"() => window.hikoboshiLive?.frames() === {frames}", "the archive loaded")
    console.wait(
        f"() => Math.min(...window.hikoboshiLive.pointCounts()) >= {frames}", "plots drawn"
    )
    counts: list[int] = console.page.evaluate("() => window.hikoboshiLive.pointCounts()")
    headers: list[str] = console.page.evaluate(
        "() => [...document.querySelectorAll('[data-test=values] table.vals th')]"
        ".map((th) => th.textContent)"
    )
    return counts, headers


def test_a_seven_joint_pass_gets_seven_joint_plots(console: Console, ground: Ground) -> None:
    pass_id = _stored_pass(ground, "seven", 7, 40)
    counts, headers = _joint_plots(console, pass_id, 40)
    # seven joints, then attitude, rates and wheel momentum
    assert len(counts) == 7 + 3
    assert console.page.locator("[data-test=joint-plots] > *").count() == 7
    assert "J7" in headers and "J8" not in headers
    assert min(counts) >= 40  # every plot, the seventh joint's included, has the frames


def test_ets7s_pass_keeps_six_joint_plots(console: Console, ground: Ground) -> None:
    pass_id = _stored_pass(ground, "ets7", 6, 30)
    counts, headers = _joint_plots(console, pass_id, 30)
    assert len(counts) == 6 + 3
    assert "J6" in headers and "J7" not in headers
    assert min(counts) >= 30
