"""Analyses of incomplete passes: telemetry gaps, a pass aborted half-way, a plan without
some experiments. Each reports what it can and says what is missing."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from planner.dynamics import DynamicsWorkspace
from telemetry.analysis import analyse_pass
from telemetry.recording import PassRecording


def _keep(recording: PassRecording, mask: np.ndarray) -> PassRecording:
    return dataclasses.replace(recording, frames=recording.frames.take(mask))


def test_gap_in_a_reactionless_leg(
    demo_recording: PassRecording, workspace: DynamicsWorkspace
) -> None:
    t = demo_recording.t_s()
    # 30 s outage across the end of B->C and the pause at C.
    gapped = _keep(demo_recording, ~((t > 170.0) & (t < 200.0)))
    result = analyse_pass(gapped, workspace)
    # The gap runs from the last frame before it to the first after (10 Hz frames).
    assert len(result.coverage.gaps_s) == 1
    assert result.coverage.gaps_s[0] == pytest.approx((170.0, 200.0), abs=0.11)
    assert any("gap" in m for m in result.missing)
    assert result.reaction is not None
    fast = result.reaction.motion("reactionless")[0]
    assert fast.note is not None and "covers only" in fast.note
    # What remains is still analysed: the leg before the gap, the PTP untouched.
    assert fast.peak_excursion_deg is not None
    (ptp,) = result.reaction.motion("ptp")
    assert ptp.settling_time_s is not None and ptp.settling_time_s > 50.0
    json.dumps(result.to_dict(), allow_nan=False)


def test_aborted_pass_reports_what_it_can(
    demo_recording: PassRecording, workspace: DynamicsWorkspace
) -> None:
    t = demo_recording.t_s()
    settle = demo_recording.plan.segment("coordination: (a) settle")
    cut = 0.5 * (settle.t_start_s + settle.t_end_s)
    aborted = _keep(demo_recording, t < cut)  # during coordination variant (a)'s settle
    result = analyse_pass(aborted, workspace)
    assert result.coverage.ends_early
    assert any("ends at" in m for m in result.missing)
    assert result.reaction is not None and result.hand_attitude is not None
    plane = result.phase_plane
    assert plane is not None
    feedback, feedforward, offset = plane.variants
    assert feedback.pitch_range_deg is not None and feedback.note is not None
    assert feedforward.frames == 0 and feedforward.pitch_range_deg is None
    assert offset.frames == 0
    end = result.endpoint
    assert end is not None and end.joint_error_deg is None
    assert any("nonholonomic" in m for m in end.missing)
    comparison = result.predicted_vs_flown
    assert comparison is not None
    assert comparison.segment("nonholonomic: forward").attitude_peak_deg is None
    json.dumps(result.to_dict(), allow_nan=False)


def test_no_frames_at_all(demo_recording: PassRecording, workspace: DynamicsWorkspace) -> None:
    empty = _keep(demo_recording, np.zeros(len(demo_recording.frames), dtype=bool))
    result = analyse_pass(empty, workspace)
    assert result.coverage.frames == 0 and result.missing[0] == "no telemetry frames at all"
    assert result.reaction is None and result.predicted_vs_flown is None
    json.dumps(result.to_dict(), allow_nan=False)


def test_experiment_missing_from_the_plan_is_skipped(
    demo_recording: PassRecording, workspace: DynamicsWorkspace
) -> None:
    plan = demo_recording.plan
    without = dataclasses.replace(
        plan,
        segments=tuple(
            s for s in plan.segments if not s.name.startswith(("coordination:", "gjm:"))
        ),
    )
    result = analyse_pass(dataclasses.replace(demo_recording, plan=without), workspace)
    assert result.phase_plane is None and result.hand_attitude is None
    assert set(result.skipped) == {"phase_plane", "hand_attitude"}
    assert "coordination" not in result.experiments and "gjm" not in result.experiments
    assert result.endpoint is not None and result.reaction is not None
