"""The post-pass tests use ``demo_recording`` from tests/conftest.py (shared with the
server's report tests, so the pass is flown once per session)."""

from __future__ import annotations

import pytest

from planner.model import RobotModel
from telemetry.recording import PassRecording


@pytest.fixture(scope="session")
def noise_free_free_drift(model: RobotModel) -> PassRecording:
    """The identification tests' free-drift plan flown without sensor noise
    (tests/telemetry/test_identification.py's ``fly(model, 0.0)``), flown once for its
    tests and the gravity-gradient resimulation's (read only)."""
    from tests.support.identification import fly

    return fly(model, 0.0)
