"""Never analyse nonsense as a pass (issue 28): a recording with frames no vehicle can have
sent (a diverged simulation's, arriving by an import rather than the link, which refuses
them) fails every analysis with the reason, and an identification that comes out not
positive definite is a failed analysis, not a result."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from planner.model import RobotModel
from server.services.analyses import compute_analyses
from telemetry.recording import PassRecording
from tests.telemetry.test_identification import fly


@pytest.fixture(scope="module")
def flown(model: RobotModel) -> PassRecording:
    return fly(model, 1.0)


def test_a_diverged_recording_fails_every_analysis_with_the_reason(
    flown: PassRecording, model: RobotModel
) -> None:
    joints = np.array(flown.frames.joints_rad)
    joints[200:, 3] = 1e15  # the arm gone, 20 s in
    diverged = replace(flown, frames=replace(flown.frames, joints_rad=joints))
    run = compute_analyses(diverged, model)
    assert set(run.documents) == {
        "pass_analysis",
        "inertia_identification",
        "gravity_gradient_resim",
        "flown_clearance",
    }
    for kind, doc in run.documents.items():
        assert doc["status"] == "failed", kind
        assert doc["error"]["type"] == "UnphysicalTelemetry", (kind, doc)
        message = doc["error"]["message"]
        assert f"{len(joints) - 200} of {len(joints)} frames are not physical" in message
        assert f"seq {int(flown.frames.seq[200])}: joints_rad 1e+15 rad" in message
    assert run.figures == {}


def test_a_negative_identified_inertia_is_a_failed_analysis(
    flown: PassRecording, model: RobotModel
) -> None:
    wrong = replace(
        model,
        links=tuple(replace(link, com_robot_m=link.com_robot_m * 3.0) for link in model.links),
    )
    doc = compute_analyses(flown, wrong).documents["inertia_identification"]
    assert doc["status"] == "failed"
    assert doc["error"]["type"] == "NotPositiveDefinite"
    assert "principal moments [-" in doc["error"]["message"]
    # the same recording with the model flown: ok
    assert compute_analyses(flown, model).documents["inertia_identification"]["status"] == "ok"
