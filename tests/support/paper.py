"""The analyses' documents as the flight reported them (telemetry.analysis.paper's
sources), for the comparison with the paper and the plan's predictions."""

from __future__ import annotations

from typing import Any

from telemetry.analysis.paper import Sources


def motion(kind: str, segment: str, **values: Any) -> dict[str, Any]:
    """One motion's reaction document."""
    return {"kind": kind, "segment": segment, "frames": 100, **values}


def variant(label: str, lo: float, hi: float, dip: float, settle: float | None) -> dict[str, Any]:
    """One coordination variant's phase-plane document."""
    return {
        "label": label,
        "pitch_min_deg": lo,
        "pitch_max_deg": hi,
        "pitch_range_deg": hi - lo,
        "first_dip_deg": dip,
        "peak_deg": hi,
        "settling_time_s": settle,
        "start_pitch_deg": 0.0,
    }


def flight_like() -> Sources:
    """Documents as the flight reported them: every row holds."""
    pass_doc = {
        "reaction": {
            "settle_band_deg": 0.05,
            "motions": [
                motion(
                    "ptp", "ptp: A->B", settling_time_s=100.0, peak_excursion_deg=0.6,
                    peak_hand_speed_mps=0.05, rms_reaction_momentum_nms=3.0,
                ),
                motion(
                    "reactionless", "reactionless: B->C", settling_time_s=0.0,
                    peak_excursion_deg=0.03, peak_hand_speed_mps=0.015,
                    rms_reaction_momentum_nms=0.02, peak_residual_deg=0.01,
                ),
                motion(
                    "reactionless", "reactionless: C->B", settling_time_s=0.0,
                    peak_excursion_deg=0.01, peak_hand_speed_mps=0.0075,
                    rms_reaction_momentum_nms=0.01, peak_residual_deg=0.005,
                ),
            ],
        },
        "hand_attitude": {
            "holds": [
                {"span": "approach", "hand_change_max_deg": 0.08},
                {"span": "retreat", "hand_change_max_deg": 0.09},
                {"span": "legs", "hand_change_max_deg": 0.3,
                 "base_pitch_change_range_deg": [-0.6, 0.2]},
            ]
        },
        "phase_plane": {
            "settle_band_deg": 0.05,
            "variants": [
                variant("(a)", -0.5, 0.4, -0.5, 90.0),
                variant("(b)", -0.35, 0.6, -0.25, 100.0),
                variant("(c)", -0.35, 0.3, -0.35, 50.0),
            ],
        },
        "endpoint": {
            "attitude_error_angle_deg": 0.2,
            "attitude_error_deg": [0.2, 0.0, 0.0],
            "max_joint_error_deg": 0.01,
        },
    }  # fmt: skip
    ident = {
        "parameters_kgm2": {"Izz": 7080.0, "Ixx": 6200.0},
        "standard_error_kgm2": {"Izz": 30.0, "Ixx": 6.0},
        "reference": {"parameters_kgm2": {"Izz": 7090.0, "Ixx": 6190.0}},
    }
    resim = {
        "segments": [
            {
                "t_start_s": 400.0,
                "with_gg": {"rms_residual_angle_deg": 0.01},
                "without_gg": {"rms_residual_angle_deg": 0.03},
            }
        ]
    }
    return Sources(pass_doc, ident, resim)
