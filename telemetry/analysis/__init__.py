"""Post-pass analyses (SPEC section 4): pure functions from a
:class:`telemetry.recording.PassRecording` to frozen results with a JSON-ready ``to_dict``.

One module per analysis:

- :mod:`.reaction`: experiment 1, PTP against reactionless (Fig. 5), settling per motion;
- :mod:`.tracking`: commanded against measured joints (Fig. 6);
- :mod:`.hand_attitude`: experiment 2, the hand's inertial attitude and pointing (Fig. 8);
- :mod:`.phase_plane`: experiment 3, pitch phase plane per attitude-control variant (Fig. 9);
- :mod:`.endpoint`: experiment 4, non-holonomic end-point errors (Fig. 11);
- :mod:`.predicted_vs_flown`: the plan's prediction against the telemetry, per segment;
- :mod:`.pass_analysis`: :func:`analyse_pass`, all that apply;
- :mod:`.paper`: the paper's flight results, and the stored numbers held against them.

Shared conventions (time base, attitude deviations, JSON numbers) are in ``_common``; joint
rates (how they are obtained) in :mod:`.rates`; the arm's reaction momentum in :mod:`.momentum`.
"""

from telemetry.analysis.coverage import Coverage, SegmentCoverage, coverage, segment_coverage
from telemetry.analysis.endpoint import EndpointAnalysis, analyse_endpoint
from telemetry.analysis.hand_attitude import (
    HandAttitudeAnalysis,
    HandHold,
    analyse_hand_attitude,
    hand_quats_orbit_xyzw,
)
from telemetry.analysis.momentum import ArmReaction, arm_reaction
from telemetry.analysis.paper import PAPER_RESULTS, Comparison, Sources, compare_with_flight
from telemetry.analysis.pass_analysis import ANALYSIS_FORMAT_VERSION, PassAnalysis, analyse_pass
from telemetry.analysis.phase_plane import (
    PhasePlaneAnalysis,
    VariantPhasePlane,
    analyse_phase_plane,
)
from telemetry.analysis.predicted_vs_flown import (
    PredictedVsFlown,
    SegmentDifference,
    analyse_predicted_vs_flown,
)
from telemetry.analysis.rates import RATE_METHOD, joint_rates_radps
from telemetry.analysis.reaction import MotionSettling, ReactionAnalysis, analyse_reaction
from telemetry.analysis.tracking import (
    JointTrackingAnalysis,
    SegmentTracking,
    analyse_joint_tracking,
)

__all__ = [
    "ANALYSIS_FORMAT_VERSION",
    "PAPER_RESULTS",
    "RATE_METHOD",
    "ArmReaction",
    "Comparison",
    "Coverage",
    "EndpointAnalysis",
    "HandAttitudeAnalysis",
    "HandHold",
    "JointTrackingAnalysis",
    "MotionSettling",
    "PassAnalysis",
    "PhasePlaneAnalysis",
    "PredictedVsFlown",
    "ReactionAnalysis",
    "SegmentCoverage",
    "SegmentDifference",
    "SegmentTracking",
    "Sources",
    "VariantPhasePlane",
    "analyse_endpoint",
    "analyse_hand_attitude",
    "analyse_joint_tracking",
    "analyse_pass",
    "analyse_phase_plane",
    "analyse_predicted_vs_flown",
    "analyse_reaction",
    "arm_reaction",
    "compare_with_flight",
    "coverage",
    "hand_quats_orbit_xyzw",
    "joint_rates_radps",
    "segment_coverage",
]
