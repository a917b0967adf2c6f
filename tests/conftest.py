"""Shared fixtures."""

from __future__ import annotations

import pytest

from planner.dynamics import DynamicsWorkspace
from planner.model import RobotModel, default_model


@pytest.fixture(scope="session")
def model() -> RobotModel:
    return default_model()


@pytest.fixture()
def workspace(model: RobotModel) -> DynamicsWorkspace:
    return DynamicsWorkspace(model)
