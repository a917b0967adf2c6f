"""The tables of a pass report, built from stored analysis documents: pure (no database,
no files), so the command line builds them from a recording file too.

Each analysis's own tables come from :mod:`server.services.analysis_tables`; this module
adds the paper's results against the pass's (or its plan's) and assembles the report.
:func:`build_report` gives the :class:`~server.schemas.analyses.ReportPublic` that
:mod:`server.services.reports` serves as JSON and renders as HTML; :data:`FIGURE_CAPTIONS`
orders and captions the figures. A pass's alarms (their documents, docs/alarms.md) make two
tables: the alarms, and their timeline (every change of band and every acknowledgement).
A pass's command outcome (:class:`server.services.summary.CommandOutcome`, as a mapping)
makes the ``commands`` table, after the paper's: ``nominal`` or ``degraded`` and the counts.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from planner.limits import SEVERITIES
from planner.plan import ETS7_ROBOT_HASH
from server.schemas import iso_from_ns
from server.schemas.analyses import ReportAnalysisPublic, ReportPublic, ReportTablePublic
from server.services.analyses import KINDS
from server.services.analysis_tables import TABLES, cells, table
from telemetry.alarm import AlarmPublic
from telemetry.analysis.paper import Predicted, Sources, compare_with_flight, compare_with_plan

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


def _t_s(time_ns: Any, epoch_ns: int | None) -> float | None:
    """An onboard time on the plan's clock (s from its ``t = 0``)."""
    if time_ns is None or epoch_ns is None:
        return None
    return (int(time_ns) - epoch_ns) / 1e9


def _alarm_tables(alarms: Sequence[AlarmPublic], epoch_ns: int | None) -> list[ReportTablePublic]:
    """The alarms (oldest raised first) and their timeline."""
    rows, timeline = [], []
    for k, a in enumerate(alarms, start=1):
        name = f"{k}: {a.quantity}{' ' + a.channel if a.channel else ''}"
        rows.append(
            [
                name,
                a.source,
                a.severity.value,
                a.state,
                a.acknowledged_by,
                a.comment,
                _t_s(a.raised_generation_time_ns, epoch_ns),
                a.raised_frame_seq,
                _t_s(a.cleared_generation_time_ns, epoch_ns),
                a.trigger_value,
                a.worst_value,
                a.limit,
                a.unit,
                a.count,
            ]
        )
        for entry in a.timeline:
            band = "within limits" if entry.severity is None else entry.severity.value
            timeline.append(
                [
                    name,
                    band,
                    _t_s(entry.generation_time_ns, epoch_ns),
                    entry.frame_seq,
                    entry.value,
                    a.unit,
                    entry.time_ns,
                ]
            )
        if a.acknowledged:
            ack = f"acknowledged by {a.acknowledged_by}"
            comment = a.comment
            timeline.append(
                [name, ack + (f": {comment}" if comment else ""), None, None, None, None,
                 a.acknowledged_time_ns]
            )  # fmt: skip
    by_severity = {s: sum(a.severity is s for a in alarms) for s in SEVERITIES}
    counts = ", ".join(f"{n} {s}" for s, n in by_severity.items() if n) or "none"
    return [
        table(
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
        table(
            "alarm_timeline",
            "Alarm timeline: every change of band, and the acknowledgements",
            ["alarm", "band", "t_s", "frame_seq", "value", "unit", "ground_time_ns"],
            timeline,
        ),
    ]


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
        return table(
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
    return table(
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
    return table(
        "commands",
        f"Commands: {outcome.get('outcome')} (nominal only when every command executed on "
        "board at its time tag)",
        _OUTCOME_COLUMNS,
        [cells(outcome, *_OUTCOME_COLUMNS)],
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
    alarms: Sequence[AlarmPublic] = (),
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
            tables += TABLES[kind](doc.get("result") or {})
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
