"""The tables of each stored post-pass analysis (server.services.analyses's ``KINDS``) in a
pass report, built from its document: pure (no database, no files).

:data:`TABLES` maps an analysis's kind to the function that turns its result (the
analysis's ``to_dict()``) into report tables: the pass analysis (coverage, predicted
against flown and experiments 1 to 4), the inertia identification, the gravity-gradient
re-simulation and the flown clearance. :func:`table` and :func:`cells` build a table and a
row's cells; :mod:`server.services.report_tables` assembles the report around them.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

from server.schemas.analyses import ReportTablePublic
from telemetry.analysis.paper import phase_plane_ordering, reaction_ordering
from telemetry.identification import INERTIA_PARAMETER_NAMES

__all__ = ["TABLES", "cells", "table"]

_RPY = ("roll", "pitch", "yaw")


def table(
    id_: str, title: str, columns: Sequence[str], rows: list[list[Any]], notes: Sequence[str] = ()
) -> ReportTablePublic:
    """A report table: ``rows`` of cells in ``columns`` order, with its ``notes``."""
    return ReportTablePublic(
        id=id_, title=title, columns=list(columns), rows=rows, notes=list(notes)
    )


def _records_table(
    id_: str, title: str, columns: Sequence[str], records: Iterable[Mapping[str, Any]]
) -> ReportTablePublic:
    """A table with one row per record, each cell the record's value of its column."""
    return table(id_, title, columns, [cells(r, *columns) for r in records])


def cells(doc: Mapping[str, Any], *keys: str) -> list[Any]:
    """The document's values of ``keys``, in order (None where one is missing)."""
    return [doc.get(k) for k in keys]


def _vector(values: Any, n: int) -> list[Any]:
    return list(values) if isinstance(values, list) and len(values) == n else [None] * n


def _pass_tables(doc: Mapping[str, Any]) -> list[ReportTablePublic]:
    out = []
    cov = doc.get("coverage") or {}
    notes = [f"missing: {m}" for m in doc.get("missing", [])]
    notes += [f"skipped (not in the plan): {s}" for s in doc.get("skipped", [])]
    out.append(
        table(
            "coverage",
            "Telemetry coverage (plan clock)",
            ["frames", "period_s", "first_t_s", "last_t_s", "plan_end_s", "gaps", "ends_early"],
            [
                [
                    *cells(cov, "frames", "period_s", "first_t_s", "last_t_s", "plan_end_s"),
                    len(cov.get("gaps_s", [])),
                    cov.get("ends_early"),
                ]
            ],
            notes,
        )
    )
    pvf = doc.get("predicted_vs_flown")
    if pvf:
        out.append(
            _records_table(
                "predicted_vs_flown",
                "Predicted against flown, per plan segment (flown minus the plan's prediction)",
                [
                    "segment",
                    "kind",
                    "frames",
                    "attitude_rms_deg",
                    "attitude_peak_deg",
                    "joint_peak_max_deg",
                ],
                pvf.get("segments", []),
            )
        )
    reaction = doc.get("reaction")
    if reaction:
        out.append(
            _records_table(
                "reaction",
                f"Experiment 1: settling after each motion (band {reaction.get('settle_band_deg')}"
                " deg)",
                [
                    "segment",
                    "kind",
                    "settling_time_s",
                    "peak_excursion_deg",
                    "peak_hand_speed_mps",
                    "rms_reaction_momentum_nms",
                    "peak_residual_deg",
                    "note",
                ],
                reaction.get("motions", []),
            )
        )
        rows, notes = reaction_ordering(reaction)
        out.append(
            table(
                "reaction_ordering",
                "Experiment 1 (Fig. 5): the reaction on the reaction momentum |H~bm phi'| "
                "beside the attitude; flight: the faster leg, the larger reaction",
                ["measure", "unit", "ptp", "fast_leg", "slow_leg", "fast_leg_larger"],
                rows,
                notes,
            )
        )
    tracking = doc.get("joint_tracking")
    if tracking:
        out.append(
            table(
                "joint_tracking",
                "Joint tracking: RMS of measured minus commanded "
                f"({tracking.get('commanded_source')})",
                [
                    "segment",
                    "kind",
                    "frames",
                    "worst_joint",
                    *(f"j{j}_rms_error_deg" for j in range(1, 7)),
                ],
                [
                    [
                        *cells(s, "segment", "kind", "frames", "worst_joint"),
                        *_vector(s.get("rms_error_deg"), 6),
                    ]
                    for s in tracking.get("segments", [])
                ],
            )
        )
    hand = doc.get("hand_attitude")
    if hand:
        out.append(
            _records_table(
                "hand_attitude",
                "Experiment 2: hand attitude held in the orbit frame while the base turns",
                [
                    "span",
                    "t_start_s",
                    "t_end_s",
                    "hand_change_max_deg",
                    "base_change_max_deg",
                    "hold_ratio",
                ],
                hand.get("holds", []),
            )
        )
    plane = doc.get("phase_plane")
    if plane:
        out.append(
            _records_table(
                "phase_plane",
                "Experiment 3: base pitch per attitude-control variant",
                [
                    "variant",
                    "label",
                    "start_pitch_deg",
                    "pitch_min_deg",
                    "pitch_max_deg",
                    "pitch_range_deg",
                    "first_dip_deg",
                    "first_dip_t_s",
                    "peak_deg",
                    "peak_t_s",
                    "settling_time_s",
                    "settled",
                    "note",
                ],
                plane.get("variants", []),
            )
        )
        out.append(
            table(
                "phase_plane_ordering",
                "Experiment 3 (Fig. 9): the variants' ordering, ours against the flight's",
                ["quantity", "ours", "flight", "same_as_flight"],
                [r.row() for r in phase_plane_ordering(plane)],
                [
                    "first dip: the lowest pitch during the forward leg; peak: the highest "
                    "over the variant's window; settling after the back leg, back within "
                    f"{plane.get('settle_band_deg')} deg of the attitude target (the origin) "
                    f"and inside over the last {plane.get('final_s')} s of its window"
                ],
            )
        )
    end = doc.get("endpoint")
    if end:
        rows = [
            [
                "attitude error (final against target)",
                *_vector(end.get("attitude_error_deg"), 3),
                end.get("attitude_error_angle_deg"),
            ],
            [
                "attitude change error (flown against predicted change)",
                *_vector(end.get("attitude_change_error_deg"), 3),
                None,
            ],
            [
                "attitude error against nominal",
                *_vector(end.get("attitude_error_nominal_deg"), 3),
                None,
            ],
            ["largest joint error", None, None, None, end.get("max_joint_error_deg")],
        ]
        out.append(
            table(
                "endpoint",
                "Experiment 4: non-holonomic end-point errors",
                ["quantity", "roll_deg", "pitch_deg", "yaw_deg", "angle_deg"],
                rows,
            )
        )
    return out


def _identification_tables(doc: Mapping[str, Any]) -> list[ReportTablePublic]:
    estimate = doc.get("parameters_kgm2", {})
    error = doc.get("standard_error_kgm2", {})
    reference = (doc.get("reference") or {}).get("parameters_kgm2", {})
    rows = []
    for name in INERTIA_PARAMETER_NAMES:
        value, sigma, truth = estimate.get(name), error.get(name), reference.get(name)
        diff = None if value is None or truth is None else value - truth
        ratio = None if diff is None or not sigma else diff / sigma
        rows.append([name, value, sigma, truth, diff, ratio])
    segments = doc.get("segments_s", [])
    notes = [
        f"{doc.get('n_blocks')} blocks of {doc.get('block_s')} s ({doc.get('n_samples')} "
        f"samples) in {len(segments)} motion segments; condition number "
        f"{doc.get('condition_number')}",
        f"residual RMS per axis (orbit frame, N m s): {doc.get('residual_rms_nms')}",
        f"reference: {(doc.get('reference') or {}).get('source', 'none')}",
    ]
    principal = [
        [i + 1, value, sigma]
        for i, (value, sigma) in enumerate(
            zip(
                doc.get("principal_moments_kgm2", []),
                doc.get("principal_standard_error_kgm2", []),
                strict=False,
            )
        )
    ]
    return [
        table(
            "inertia_identification",
            "Base inertia identified from momentum conservation (base frame, about the base CoM)",
            [
                "parameter",
                "identified_kgm2",
                "standard_error_kgm2",
                "reference_kgm2",
                "difference_kgm2",
                "difference_sigma",
            ],
            rows,
            notes,
        ),
        table(
            "inertia_principal",
            "Principal moments of the identified inertia",
            ["moment", "identified_kgm2", "standard_error_kgm2"],
            principal,
        ),
    ]


def _resim_tables(doc: Mapping[str, Any]) -> list[ReportTablePublic]:
    rows = []
    for seg in doc.get("segments", []):
        for key, label in (("with_gg", "with eq. (11)"), ("without_gg", "without")):
            run = seg.get(key) or {}
            rows.append(
                [
                    seg.get("t_start_s"),
                    seg.get("t_end_s"),
                    label,
                    *_vector(run.get("rms_residual_deg"), 3),
                    run.get("rms_residual_angle_deg"),
                    *_vector(run.get("final_residual_deg"), 3),
                ]
            )
    return [
        table(
            "gravity_gradient_resim",
            "Free drift re-simulated with and without the gravity-gradient torque: residual "
            "against the recorded attitude (base frame)",
            [
                "t_start_s",
                "t_end_s",
                "run",
                *(f"rms_{a}_deg" for a in _RPY),
                "rms_angle_deg",
                *(f"final_{a}_deg" for a in _RPY),
            ],
            rows,
            [
                f"initial momentum and attitude from the first {doc.get('initial_window_s')} s of "
                "each segment"
            ],
        )
    ]


def _bodies(value: Any) -> str | None:
    return " / ".join(str(b) for b in value) if isinstance(value, list) else None


def _clearance_tables(doc: Mapping[str, Any]) -> list[ReportTablePublic]:
    """The clearance flown (measured joints) beside the plan's predicted one."""
    flown = doc.get("flown") or {}
    predicted = doc.get("predicted")
    limit = doc.get("limit_m")
    rows = [
        [
            "flown (measured joints)",
            flown.get("value_m"),
            flown.get("t_s"),
            _bodies(flown.get("bodies")),
            limit,
            flown.get("verdict"),
        ]
    ]
    if isinstance(predicted, Mapping):
        value = predicted.get("value_m")
        verdict = None if value is None or limit is None else ("pass" if value >= limit else "fail")
        rows.append(
            [
                "predicted (the plan's flight rules)",
                value,
                predicted.get("t_s"),
                _bodies(predicted.get("bodies")),
                limit,
                verdict,
            ]
        )
    notes = [
        f"{doc.get('n_frames')} of {doc.get('n_frames_total')} telemetry frames, "
        f"{doc.get('n_pairs')} pairs of bodies, {doc.get('n_queries')} distance queries"
    ]
    if not isinstance(predicted, Mapping):
        notes.append("the plan carries no flight-rules report: nothing predicted to compare")
    return [
        table(
            "clearance",
            "Clearance: flown against predicted",
            ["", "min_clearance_m", "t_s", "bodies", "limit_m", "verdict"],
            rows,
            notes,
        )
    ]


#: An analysis's kind -> its result's tables.
TABLES: dict[str, Callable[[Mapping[str, Any]], list[ReportTablePublic]]] = {
    "pass_analysis": _pass_tables,
    "inertia_identification": _identification_tables,
    "gravity_gradient_resim": _resim_tables,
    "flown_clearance": _clearance_tables,
}
