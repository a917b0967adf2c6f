"""The tables of a pass report, built from stored analysis documents: pure (no database,
no files), so the command line builds them from a recording file too.

:func:`build_report` gives the :class:`~server.schemas.analyses.ReportPublic` that
:mod:`server.services.reports` serves as JSON and renders as HTML; :data:`FIGURE_CAPTIONS`
orders and captions the figures. A pass's alarms (their documents, docs/alarms.md) make two
tables: the alarms, and their timeline (every change of band and every acknowledgement).
A pass's command outcome (:class:`server.services.summary.CommandOutcome`, as a mapping)
makes the ``commands`` table, after the paper's: ``nominal`` or ``degraded`` and the counts.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

from planner.plan import ETS7_ROBOT_HASH
from server.schemas import iso_from_ns
from server.schemas.analyses import ReportAnalysisPublic, ReportPublic, ReportTablePublic
from server.services.analyses import KINDS
from telemetry.analysis.paper import (
    Predicted,
    Sources,
    compare_with_flight,
    compare_with_plan,
    phase_plane_ordering,
    reaction_ordering,
)
from telemetry.identification import INERTIA_PARAMETER_NAMES

__all__ = ["FIGURE_CAPTIONS", "build_report", "predicted_of"]


def predicted_of(plan: Mapping[str, Any]) -> Predicted | None:
    """A plan document's (``Plan.to_dict``: ``robot``, ``robot_hash``, ``experiment``,
    ``metrics``) predictions when its robot is not ETS-VII; ``None`` for ETS-VII's (a
    document naming no robot is ETS-VII's, as everywhere)."""
    if plan.get("robot_hash", ETS7_ROBOT_HASH) == ETS7_ROBOT_HASH:
        return None
    metrics = plan.get("metrics")
    return Predicted(
        robot=str(plan.get("robot")),
        experiment=str(plan.get("experiment")),
        metrics=metrics if isinstance(metrics, Mapping) else {},
    )


FIGURE_CAPTIONS = {
    "predicted_vs_flown": "Predicted against flown: base attitude, attitude and joint differences.",
    "reaction": "Experiment 1 (paper Fig. 5): hand speed, the reaction momentum |H~bm phi'| "
    "and the base attitude, PTP against the fast and slow reactionless legs.",
    "joint_tracking": "Joint tracking (Fig. 6): commanded against measured joints.",
    "hand_attitude": "Experiment 2 (Fig. 8): hand attitude held while the base turns.",
    "phase_plane": "Experiment 3 (paper Fig. 9): base pitch against pitch rate, side by side: "
    "(a) feedback, (b) feedforward, (c) offset; first dip and peak marked.",
    "endpoint": "Experiment 4 (Fig. 11): non-holonomic motion and its end-point errors.",
    "alarm_timeline": "Alarms: the band each alarm was in over the pass (plan clock), "
    "coloured by severity (watch, warning, distress, critical, severe).",
}
_RPY = ("roll", "pitch", "yaw")


def _table(
    id_: str, title: str, columns: Sequence[str], rows: list[list[Any]], notes: Sequence[str] = ()
) -> ReportTablePublic:
    return ReportTablePublic(
        id=id_, title=title, columns=list(columns), rows=rows, notes=list(notes)
    )


def _records_table(
    id_: str, title: str, columns: Sequence[str], records: Iterable[Mapping[str, Any]]
) -> ReportTablePublic:
    """A table with one row per record, each cell the record's value of its column."""
    return _table(id_, title, columns, [_get(r, *columns) for r in records])


def _get(doc: Mapping[str, Any], *keys: str) -> list[Any]:
    return [doc.get(k) for k in keys]


def _vector(values: Any, n: int) -> list[Any]:
    return list(values) if isinstance(values, list) and len(values) == n else [None] * n


def _pass_tables(doc: Mapping[str, Any]) -> list[ReportTablePublic]:
    out = []
    cov = doc.get("coverage") or {}
    notes = [f"missing: {m}" for m in doc.get("missing", [])]
    notes += [f"skipped (not in the plan): {s}" for s in doc.get("skipped", [])]
    out.append(
        _table(
            "coverage",
            "Telemetry coverage (plan clock)",
            ["frames", "period_s", "first_t_s", "last_t_s", "plan_end_s", "gaps", "ends_early"],
            [
                [
                    *_get(cov, "frames", "period_s", "first_t_s", "last_t_s", "plan_end_s"),
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
            _table(
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
            _table(
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
                        *_get(s, "segment", "kind", "frames", "worst_joint"),
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
            _table(
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
            _table(
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
        _table(
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
        _table(
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
        _table(
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
        _table(
            "clearance",
            "Clearance: flown against predicted",
            ["", "min_clearance_m", "t_s", "bodies", "limit_m", "verdict"],
            rows,
            notes,
        )
    ]


_TABLES: dict[str, Callable[[Mapping[str, Any]], list[ReportTablePublic]]] = {
    "pass_analysis": _pass_tables,
    "inertia_identification": _identification_tables,
    "gravity_gradient_resim": _resim_tables,
    "flown_clearance": _clearance_tables,
}


def _t_s(time_ns: Any, epoch_ns: int | None) -> float | None:
    """An onboard time on the plan's clock (s from its ``t = 0``)."""
    if time_ns is None or epoch_ns is None:
        return None
    return (int(time_ns) - epoch_ns) / 1e9


def _alarm_tables(
    alarms: Sequence[Mapping[str, Any]], epoch_ns: int | None
) -> list[ReportTablePublic]:
    """The alarms (oldest raised first) and their timeline."""
    rows, timeline = [], []
    for k, a in enumerate(alarms, start=1):
        name = f"{k}: {a.get('quantity')}{' ' + a['channel'] if a.get('channel') else ''}"
        rows.append(
            [
                name,
                a.get("source"),
                a.get("severity"),
                a.get("state"),
                a.get("acknowledged_by"),
                a.get("comment"),
                _t_s(a.get("raised_generation_time_ns"), epoch_ns),
                a.get("raised_frame_seq"),
                _t_s(a.get("cleared_generation_time_ns"), epoch_ns),
                a.get("trigger_value"),
                a.get("worst_value"),
                a.get("limit"),
                a.get("unit"),
                a.get("count"),
            ]
        )
        for entry in a.get("timeline") or ():
            timeline.append(
                [
                    name,
                    entry.get("severity") or "within limits",
                    _t_s(entry.get("generation_time_ns"), epoch_ns),
                    entry.get("frame_seq"),
                    entry.get("value"),
                    a.get("unit"),
                    entry.get("time_ns"),
                ]
            )
        if a.get("acknowledged"):
            ack = f"acknowledged by {a.get('acknowledged_by')}"
            comment = a.get("comment")
            timeline.append(
                [name, ack + (f": {comment}" if comment else ""), None, None, None, None,
                 a.get("acknowledged_time_ns")]
            )  # fmt: skip
    by_severity = {s: sum(a.get("severity") == s for a in alarms) for s in _SEVERITIES}
    counts = ", ".join(f"{n} {s}" for s, n in by_severity.items() if n) or "none"
    return [
        _table(
            "alarms",
            "Alarms: the worst band each reached (latching: listed until acknowledged)",
            [
                "alarm",
                "source",
                "severity",
                "state",
                "acknowledged_by",
                "comment",
                "raised_t_s",
                "raised_frame_seq",
                "cleared_t_s",
                "trigger_value",
                "worst_value",
                "limit",
                "unit",
                "frames",
            ],
            rows,
            [
                f"{len(alarms)} alarms: {counts}; t_s on the plan's clock (onboard), the "
                "link's health timed on the ground has none"
            ],
        ),
        _table(
            "alarm_timeline",
            "Alarm timeline: every change of band, and the acknowledgements",
            ["alarm", "band", "t_s", "frame_seq", "value", "unit", "ground_time_ns"],
            timeline,
        ),
    ]


_SEVERITIES = ("watch", "warning", "distress", "critical", "severe")


def _flight_table(
    documents: Mapping[str, tuple[Mapping[str, Any], int | None]],
    plan: Predicted | None = None,
) -> ReportTablePublic:
    """The paper's results against this pass's (:mod:`telemetry.analysis.paper`); an
    analysis absent or failed gives "not measured" rows. For a robot other than ETS-VII
    (``plan`` given) the flight's numbers are not its own: each result's criterion, in the
    same shape, is held against the pass's own plan's prediction instead, and the table
    says so (``plan_against_ours``)."""

    def result(kind: str) -> Mapping[str, Any] | None:
        doc = documents.get(kind, ({}, None))[0]
        found = doc.get("result") if doc.get("status") == "ok" else None
        return found if isinstance(found, Mapping) else None

    sources = Sources(
        pass_analysis=result("pass_analysis"),
        identification=result("inertia_identification"),
        resim=result("gravity_gradient_resim"),
    )
    rows = compare_with_flight(sources) if plan is None else compare_with_plan(sources, plan)
    counts = {v: sum(r.verdict == v for r in rows) for v in dict.fromkeys(r.verdict for r in rows)}
    summary = ", ".join(f"{n} {v}" for v, n in counts.items())
    if plan is not None:
        return _table(
            "plan_against_ours",
            f"Plan against ours: robot {plan.robot} is not ETS-VII, so each result of the "
            "paper is held against this pass's own plan, not the flight",
            ["result", "paper", "plan", "ours", "criterion", "verdict"],
            [r.row() for r in rows],
            [
                f"The flight's numbers are ETS-VII's, not robot {plan.robot}'s: each criterion "
                "keeps the paper's shape (the same tolerance, band or ordering) with the number "
                f"the plan ({plan.experiment}) predicted in the flight's place.",
                summary,
            ],
        )
    return _table(
        "flight_against_ours",
        "Flight against ours: every result of the paper, measured on this pass",
        ["result", "paper", "flight", "ours", "criterion", "verdict"],
        [r.row() for r in rows],
        [summary],
    )


#: The command outcome's columns (CommandOutcome.document's keys).
_OUTCOME_COLUMNS = (
    "outcome",
    "total",
    "executed_at_tag",
    "late",
    "expired",
    "rejected",
    "cancelled",
    "unresolved",
)


def _commands_table(outcome: Mapping[str, Any]) -> ReportTablePublic:
    return _table(
        "commands",
        f"Commands: {outcome.get('outcome')} (nominal only when every command executed on "
        "board at its time tag)",
        _OUTCOME_COLUMNS,
        [_get(outcome, *_OUTCOME_COLUMNS)],
        [str(outcome.get("text", ""))],
    )


def build_report(
    *,
    pass_id: str | None,
    name: str,
    state: str | None,
    experiment: str,
    imported: bool,
    documents: Mapping[str, tuple[Mapping[str, Any], int | None]],
    figure_names: Sequence[str],
    alarms: Sequence[Mapping[str, Any]] = (),
    epoch_ns: int | None = None,
    commands: Mapping[str, Any] | None = None,
    plan: Predicted | None = None,
) -> ReportPublic:
    """The report of stored documents (``kind -> (document, created_at_ns)``, as
    :mod:`server.services.analyses` stores them), of the pass's ``alarms`` (oldest
    raised first; ``epoch_ns``: the plan's ``t = 0`` onboard, for their times) and of its
    ``commands``' outcome (None: not known, as for a recording file). ``plan``: the pass's
    plan's predictions when its robot is not ETS-VII (:func:`predicted_of`), whose first
    table then holds the pass against them instead of the flight."""
    statuses, tables = [], []
    for kind in KINDS:
        if kind not in documents:
            statuses.append(ReportAnalysisPublic(kind=kind, status="absent"))
            continue
        doc, created_ns = documents[kind]
        created = None if created_ns is None else iso_from_ns(created_ns)
        if doc.get("status") == "ok":
            statuses.append(ReportAnalysisPublic(kind=kind, status="ok", created_at=created))
            tables += _TABLES[kind](doc.get("result") or {})
        else:
            error = doc.get("error") or {}
            reason = f"{error.get('type', 'error')}: {error.get('message', '')}"
            statuses.append(
                ReportAnalysisPublic(kind=kind, status="failed", created_at=created, error=reason)
            )
    tables.insert(0, _flight_table(documents, plan))
    if commands is not None:
        tables.insert(1, _commands_table(commands))
    tables += _alarm_tables(alarms, epoch_ns)
    order = list(FIGURE_CAPTIONS)
    names = sorted(figure_names, key=lambda n: (order.index(n) if n in order else len(order), n))
    return ReportPublic(
        pass_id=pass_id,
        name=name,
        state=state,
        experiment=experiment,
        imported=imported,
        analyses=statuses,
        tables=tables,
        figures=names,
    )
