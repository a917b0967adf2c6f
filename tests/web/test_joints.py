"""The console plots the joints the data has: a 7-joint pass's archive shows seven joint
plots and a J7 column; ETS-VII's shows six (the store takes n from the data, not a 6)."""

from __future__ import annotations

import time

from server.storage import repository as repo
from telemetry.layout import FrameLayout
from tests.server.link.harness import Ground
from tests.server.storage.factories import make_frames, make_plan
from tests.web.conftest import VIEWER_TOKEN, Console


def _stored_pass(ground: Ground, name: str, n_joints: int, n_frames: int) -> str:
    now = time.time_ns()
    with ground.sessions() as session:
        plan = repo.add_plan(session=session, plan=make_plan(n_joints=n_joints), created_at_ns=now)
        record = repo.add_pass(
            session=session,
            name=name,
            plan_id=plan.id,
            aos_time_ns=now,
            los_time_ns=now + 10**12,
            relay="TDRS-W",
            created_at_ns=now,
        )
        repo.ingest_frames(
            session=session,
            pass_id=record.id,
            frames=make_frames(range(n_frames), layout=FrameLayout(n_joints, 3)),
            reception_time_ns=now,
        )
        session.commit()
        return record.id


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
