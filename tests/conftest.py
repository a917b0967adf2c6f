"""Shared fixtures."""

from __future__ import annotations

import pytest

from planner.dynamics import DynamicsWorkspace
from planner.model import RobotModel, default_model
from planner.schedule import plan_pass
from spacecraft.offline import fly_offline
from telemetry.recording import PassRecording


@pytest.fixture(scope="session")
def model() -> RobotModel:
    return default_model()


@pytest.fixture()
def workspace(model: RobotModel) -> DynamicsWorkspace:
    return DynamicsWorkspace(model)


@pytest.fixture(scope="session")
def demo_recording(model: RobotModel) -> PassRecording:
    """A flown demo pass (the whole ETS-VII schedule through the real vehicle, default
    sensor noise and gravity gradient, perfect link), shared by the post-pass tests of a
    session (telemetry and server): about 17 s to plan and fly, once."""
    plan = plan_pass(DynamicsWorkspace(model))
    flight = fly_offline(plan, seed=7)
    assert not flight.rejected, flight.rejected[:3]
    return PassRecording.from_frames(
        "demo", plan, flight.epoch_ns, flight.frames, meta={"source": "offline flight, seed 7"}
    )


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Modules with a slow test run first, each module's tests in their own order: with the
    suite spread over workers (pyproject's ``-n``), a minute-long test started last keeps one
    worker busy after the other has run out of work."""
    slow = {item.path for item in items if item.get_closest_marker("slow") is not None}
    items.sort(key=lambda item: item.path not in slow)  # stable: the order within stays
