"""The console tests' flight; their application is tests/server/conftest.py's ``client``,
the ways to drive it the way the link does and to speak as a console are
tests/support/console.py's."""

from __future__ import annotations

import pytest

from planner.plan import Plan
from spacecraft.offline import OfflineFlight, fly_offline
from tests.server.storage.factories import make_plan


@pytest.fixture(scope="session")
def flight() -> tuple[Plan, OfflineFlight]:
    """A short plan flown offline: 61 frames at 10 Hz over 6 s onboard, 18 commands (17
    joint commands slow enough that none is rejected, one ACS command)."""
    plan = make_plan(17)
    flown = fly_offline(plan, after_s=1.0)
    assert not flown.rejected, flown.rejected[:3]
    return plan, flown
