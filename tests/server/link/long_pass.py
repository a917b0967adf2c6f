"""A long pass's plan, planned once per test run: a small PTP and a 400 s settle, for the
tests that start a pass on a live vehicle and abort it (or stop watching it) long before
it ends (tests/server/link/test_serve_logs.py, tests/web/test_live.py).

Planning it (the prediction over 1,600 samples and the flight-rules check, with the first
plan's set-up in a process) is 3 to 15 s of CPU, more on a loaded machine: each of those
tests planned its own (serve_logs one per log format), in its wall time. The plan is the
same whoever asks, so the first to ask plans it (``made_once``: across xdist's workers)
and the others read its document back.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from planner.dynamics import DynamicsWorkspace
from planner.experiments import PtpParams, plan_ptp
from planner.model import default_model
from planner.plan import Plan
from tests.server.link.harness import with_flight_rules

if TYPE_CHECKING:
    from tests.support.made_once import MadeOnce

__all__ = ["GOAL_DEG", "SETTLE_S", "long_plan"]

#: The joints moved (deg): a short motion, then the settle holds the arm.
GOAL_DEG = (5.0, 3.0, 0.0, 5.0, 0.0, 0.0)
#: Onboard s of settle after the motion: 40 s of wall at 10x, 20 s at 20x.
SETTLE_S = 400.0


def _plan_into(folder: Path) -> None:
    params = PtpParams(goal_joints_deg=GOAL_DEG, settle_s=SETTLE_S)
    plan = with_flight_rules(plan_ptp(DynamicsWorkspace(default_model()), params))
    (folder / "plan.json").write_text(plan.to_json())


def long_plan(made_once: MadeOnce) -> Plan:
    """The long plan, with its flight-rules report (as ``store_pass`` makes one); ``made_once``
    is tests/conftest.py's fixture of that name."""
    folder = made_once("long-ptp-plan", _plan_into)
    return Plan.from_json((folder / "plan.json").read_text())
