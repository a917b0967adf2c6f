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
from tests.support.identification import fly


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


def test_a_pass_whose_vehicle_reported_divergence_is_not_analysed(
    flown: PassRecording, model: RobotModel
) -> None:
    """The vehicle safes with ``simulation_diverged`` (tests/spacecraft/test_safing.py) and
    the ground records it as ``vehicle_safed``: whatever frames came before, no analysis of
    the pass is ``ok``."""
    from telemetry.recording import EventRow

    safed = EventRow(
        time_ns=1,
        kind="vehicle_safed",
        actor="ets7",
        detail={
            "since_time_ns": 200_000_000,
            "trigger": {
                "quantity": "simulation_diverged",
                "value": 1.0,
                "limit": 0.0,
                "detail": "MuJoCo reset its non-finite or huge state 1 time(s)",
            },
            "cancelled": 3,
        },
    )
    run = compute_analyses(replace(flown, events=(safed,)), model)
    for kind, doc in run.documents.items():
        assert doc["status"] == "failed", kind
        assert "the vehicle reported its simulation diverged" in doc["error"]["message"]


def test_a_pass_with_no_frames_fails_every_analysis_with_the_reason(
    flown: PassRecording, model: RobotModel
) -> None:
    """A pass that stored no frame (a window lost whole) is no result: each analysis fails
    saying so, none is ``ok`` on nothing, and nothing raises (the ground answered 500)."""
    empty = PassRecording.from_frames("empty", flown.plan, flown.epoch_ns, [])
    run = compute_analyses(empty, model)
    for kind, doc in run.documents.items():
        assert doc["status"] == "failed", (kind, doc)
        assert "no telemetry frames" in doc["error"]["message"] or (
            "0 telemetry frames" in doc["error"]["message"]
        ), (kind, doc)
    assert run.figures == {}
