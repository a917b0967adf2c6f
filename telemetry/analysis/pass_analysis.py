"""Every post-pass analysis that applies to a pass (SPEC section 4), in one result.

An experiment the plan does not contain is skipped (its field is ``None`` and it is named in
``skipped``); an experiment whose telemetry is partly or wholly missing (gaps, a pass aborted
half-way) reports what it can and says what is missing in ``missing``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from planner.coordination import REPORT_SETTLE_BAND_DEG
from planner.dynamics import DynamicsWorkspace
from planner.model import default_model
from telemetry.analysis._common import MOTION_KINDS, experiment_segments
from telemetry.analysis.coverage import Coverage, coverage
from telemetry.analysis.endpoint import EndpointAnalysis, analyse_endpoint
from telemetry.analysis.hand_attitude import HandAttitudeAnalysis, analyse_hand_attitude
from telemetry.analysis.phase_plane import PhasePlaneAnalysis, analyse_phase_plane
from telemetry.analysis.predicted_vs_flown import PredictedVsFlown, analyse_predicted_vs_flown
from telemetry.analysis.reaction import ReactionAnalysis, analyse_reaction
from telemetry.analysis.tracking import JointTrackingAnalysis, analyse_joint_tracking
from telemetry.recording import PassRecording

__all__ = ["ANALYSIS_FORMAT_VERSION", "PassAnalysis", "analyse_pass"]

ANALYSIS_FORMAT_VERSION = 1

_ANALYSES = ("reaction", "joint_tracking", "hand_attitude", "phase_plane", "endpoint")


@dataclass(frozen=True, eq=False)
class PassAnalysis:
    name: str
    experiments: tuple[str, ...]
    settle_band_deg: float
    coverage: Coverage
    reaction: ReactionAnalysis | None
    joint_tracking: JointTrackingAnalysis | None
    hand_attitude: HandAttitudeAnalysis | None
    phase_plane: PhasePlaneAnalysis | None
    endpoint: EndpointAnalysis | None
    predicted_vs_flown: PredictedVsFlown | None
    skipped: tuple[str, ...]
    missing: tuple[str, ...]

    def to_dict(self) -> dict[str, Any]:
        def part(value: Any) -> Any:
            return None if value is None else value.to_dict()

        return {
            "format_version": ANALYSIS_FORMAT_VERSION,
            "name": self.name,
            "experiments": list(self.experiments),
            "settle_band_deg": self.settle_band_deg,
            "coverage": self.coverage.to_dict(),
            "reaction": part(self.reaction),
            "joint_tracking": part(self.joint_tracking),
            "hand_attitude": part(self.hand_attitude),
            "phase_plane": part(self.phase_plane),
            "endpoint": part(self.endpoint),
            "predicted_vs_flown": part(self.predicted_vs_flown),
            "skipped": list(self.skipped),
            "missing": list(self.missing),
        }


def _experiments(recording: PassRecording) -> tuple[str, ...]:
    found = []
    for name in ("ptp", "reactionless", "gjm", "coordination", "nonholonomic"):
        if any(s.kind in MOTION_KINDS for s in experiment_segments(recording.plan, name)):
            found.append(name)
    return tuple(found)


def analyse_pass(
    recording: PassRecording,
    workspace: DynamicsWorkspace | None = None,
    *,
    settle_band_deg: float = REPORT_SETTLE_BAND_DEG,
) -> PassAnalysis:
    """All analyses that apply to ``recording`` (see the module docstring).

    ``workspace`` evaluates the dynamics (default: one of :func:`planner.model.default_model`);
    ``settle_band_deg`` is the settling band of experiments 1 and 3.
    """
    ws = workspace or DynamicsWorkspace(default_model())
    cov = coverage(recording)
    missing: list[str] = []
    if cov.frames == 0:
        missing.append("no telemetry frames at all")
    elif cov.ends_early:
        missing.append(
            f"telemetry ends at {cov.last_t_s:.1f} s, before the plan's end at "
            f"{cov.plan_end_s:.1f} s"
        )
    missing += [f"telemetry gap {a:.1f}-{b:.1f} s" for a, b in cov.gaps_s]
    results: dict[str, Any] = {}
    if cov.frames:
        results = {
            "reaction": analyse_reaction(recording, ws, settle_band_deg=settle_band_deg),
            "joint_tracking": analyse_joint_tracking(recording),
            "hand_attitude": analyse_hand_attitude(recording, ws),
            "phase_plane": analyse_phase_plane(recording, settle_band_deg=settle_band_deg),
            "endpoint": analyse_endpoint(recording),
        }
    skipped = [name for name in _ANALYSES if results.get(name) is None]
    for value in results.values():
        if value is not None:
            missing.extend(value.missing)
    return PassAnalysis(
        name=recording.name,
        experiments=_experiments(recording),
        settle_band_deg=settle_band_deg,
        coverage=cov,
        reaction=results.get("reaction"),
        joint_tracking=results.get("joint_tracking"),
        hand_attitude=results.get("hand_attitude"),
        phase_plane=results.get("phase_plane"),
        endpoint=results.get("endpoint"),
        predicted_vs_flown=analyse_predicted_vs_flown(recording) if cov.frames else None,
        skipped=tuple(skipped),
        missing=tuple(missing),
    )
