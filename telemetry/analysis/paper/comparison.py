"""The table "flight against ours" (:mod:`telemetry.analysis.paper`): one
:class:`Comparison` per paper result, measured on a pass's stored documents, against the
flight (:func:`compare_with_flight`) or, for a robot other than ETS-VII, against the pass's
own plan (:func:`compare_with_plan`: the flight's number replaced by the plan's prediction
where the plan gives one, the criterion's shape kept).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

from telemetry.analysis.paper.documents import (
    Sources,
    number,
    ordered,
    settling_values,
    variants_of,
)
from telemetry.analysis.paper.results import PAPER_RESULTS, Measured, PaperResult, missing

__all__ = [
    "MIN_SETTLE_TOLERANCE_S",
    "NOT_MEASURED",
    "NOT_REPRODUCED",
    "REPRODUCED",
    "Comparison",
    "Predicted",
    "compare_with_flight",
    "compare_with_plan",
    "verdict",
]

REPRODUCED = "reproduced"
NOT_REPRODUCED = "not reproduced"
NOT_MEASURED = "not measured"


@dataclass(frozen=True)
class Comparison:
    id: str
    result: str
    section: str
    flight: str
    ours: str
    criterion: str
    verdict: str

    def row(self) -> list[str]:
        return [self.result, self.section, self.flight, self.ours, self.criterion, self.verdict]


def verdict(holds: bool | None) -> str:
    if holds is None:
        return NOT_MEASURED
    return REPRODUCED if holds else NOT_REPRODUCED


def compare_with_flight(
    sources: Sources, results: Sequence[PaperResult] = PAPER_RESULTS
) -> list[Comparison]:
    """One :class:`Comparison` per paper result, measured on ``sources``."""
    out = []
    for r in results:
        try:
            measured = r.check(r, sources)
        except (KeyError, TypeError, ValueError, AttributeError) as exc:  # malformed document
            measured = missing(f"{type(exc).__name__}: {exc}")
        out.append(
            Comparison(
                r.id, r.result, r.section, r.flight, measured.ours, r.criterion,
                verdict(measured.holds),
            )
        )  # fmt: skip
    return out


# --- another robot: the pass against its own plan ---------------------------------------------

#: The coordination variants' labels in the report, by the plan's variant names.
_VARIANT_LABELS = {"feedback": "(a)", "feedforward": "(b)", "offset": "(c)"}
#: The shortest PTP settling tolerance against a plan (s): a plan that predicts settling at
#: once cannot be met within 30 % of 0 s; the reactionless criterion's 5 s instead.
MIN_SETTLE_TOLERANCE_S = 5.0


@dataclass(frozen=True)
class Predicted:
    """A plan's own predictions: its ``metrics`` (a pass plan's keyed ``experiment.key``,
    an experiment's plan by ``key``), for a robot other than ETS-VII."""

    robot: str
    experiment: str
    metrics: Mapping[str, Any]

    def get(self, experiment: str, key: str) -> float | None:
        if self.experiment == "pass":
            return number(self.metrics.get(f"{experiment}.{key}"))
        return number(self.metrics.get(key)) if self.experiment == experiment else None


def _against_plan(r: PaperResult, plan: Predicted) -> PaperResult | None:
    """``r`` with the plan's predicted number in the flight's place (the criterion's shape
    kept); ``None`` when the plan predicts no such number. Criteria that compare the pass
    with itself are kept as they are."""
    get = plan.get
    if r.id == "ptp_settling":
        p = get("ptp", "settling_time_after_motion_s")
        if p is None:
            return None
        tol = max(r.limits["relative_tolerance"] * p, MIN_SETTLE_TOLERANCE_S)
        return replace(
            r,
            flight=f"plan: {p:.1f} s to settle",
            criterion=f"settling within {p:.1f} s +- {tol:.1f} s (30 %, at least "
            f"{MIN_SETTLE_TOLERANCE_S:g} s; the plan's band)",
            limits={"flight_s": p, "relative_tolerance": 0.3, "tolerance_s": tol},
        )
    if r.id == "gjm_base_pitch":
        p = get("gjm", "base_pitch_change_deg")
        if p is None:
            return None
        tol = r.limits["tolerance_deg"]
        return replace(
            r,
            flight=f"plan: {p:+.3f} deg",
            criterion=f"largest base pitch change {p:+.3f} +- {tol:g} deg",
            limits={"flight_deg": p, "tolerance_deg": tol},
        )
    if r.id == "gjm_hand_hold":
        p = get("gjm", "hand_orientation_max_deviation_deg")
        if p is None:
            return None
        return replace(
            r,
            flight=f"plan: within {p:.3g} deg",
            criterion=f"largest hand attitude change per leg at most {p + 0.15:.3g} deg "
            "(the plan's + 0.15)",
            limits={"max_deg": p + 0.15},
        )
    if r.id == "coordination_feedback_range":
        lo = get("coordination", "predicted_feedback_pitch_min_deg")
        hi = get("coordination", "predicted_feedback_pitch_max_deg")
        if lo is None or hi is None:
            return None
        tol = r.limits["tolerance_deg"]
        return replace(
            r,
            flight=f"plan: {lo:+.2f} to {hi:+.2f} deg",
            criterion=f"min {lo:+.2f} +- {tol:g} deg and max {hi:+.2f} +- {tol:g} deg",
            limits={"min_deg": lo, "max_deg": hi, "tolerance_deg": tol},
        )
    if r.id in ("coordination_feedforward", "coordination_offset_range",
                "coordination_offset_settling"):  # fmt: skip
        key, largest = {
            "coordination_feedforward": ("pitch_max_deg", True),
            "coordination_offset_range": ("pitch_range_deg", False),
            "coordination_offset_settling": ("settling_time_s", False),
        }[r.id]
        values = {
            label: get("coordination", f"predicted_{name}_{key}")
            for name, label in _VARIANT_LABELS.items()
        }
        known = {k: v for k, v in values.items() if v is not None}
        if len(known) < len(values):
            return None
        pick = (max if largest else min)(known, key=lambda k: known[k])
        what = {"pitch_max_deg": "largest pitch peak", "pitch_range_deg": "smallest pitch range",
                "settling_time_s": "fastest settling"}[key]  # fmt: skip
        return replace(
            r,
            flight=f"plan: {what} {pick} ({ordered(values, 's' if 'time' in key else 'deg')})",
            criterion=f"{pick}'s {what.split(' ', 1)[1]} the {what.split(' ')[0]} of (a), (b), "
            "(c), as the plan predicts",
            limits={"largest": float(largest)},
            check=_variant_extreme(pick, key, largest),
        )
    if r.id == "nonholonomic_endpoint":
        p = get("nonholonomic", "predicted_end_attitude_error_deg")
        if p is None:
            return None
        joint = r.limits["joint_deg"]
        return replace(
            r,
            flight=f"plan: attitude error {p:.3g} deg",
            criterion=f"final attitude error at most {p + 0.1:.3g} deg (the plan's + 0.1) and "
            f"joints within {joint:g} deg",
            limits={"attitude_deg": p + 0.1, "joint_deg": joint},
        )
    if r.id == "inertia_identification":
        return replace(r, flight="the robot's own model (its description)",
                       criterion="every parameter within 3 standard errors of the robot's "
                       "model")  # fmt: skip
    return replace(r, flight="(a criterion of the pass against itself)")


def _variant_extreme(
    pick: str, key: str, largest: bool
) -> Callable[[PaperResult, Sources], Measured]:
    def check(r: PaperResult, src: Sources) -> Measured:
        if key == "settling_time_s":
            values: dict[str, float | None] = dict(settling_values(variants_of(src)))
        else:
            values = {k: number(x.get(key)) for k, x in variants_of(src).items()}
        if set(values) < {"(a)", "(b)", "(c)"} or None in values.values():
            return missing("variants (a), (b), (c) not all analysed")
        mine = float(values[pick] or 0.0)
        others = [float(v or 0.0) for k, v in values.items() if k != pick]
        holds = all(mine > o for o in others) if largest else all(mine < o for o in others)
        unit = "s" if key == "settling_time_s" else "deg"
        return Measured(f"{key.replace('_', ' ')} {ordered(values, unit)}", holds)

    return check


def compare_with_plan(
    sources: Sources, plan: Predicted, results: Sequence[PaperResult] = PAPER_RESULTS
) -> list[Comparison]:
    """For a robot other than ETS-VII: one :class:`Comparison` per paper result whose
    shape the plan gives a number for, the flight's number replaced by the plan's own
    prediction (``flight`` then reads ``plan: ...``); results the plan predicts nothing for
    are ``not measured``."""
    out = []
    for r in results:
        mine = _against_plan(r, plan)
        if mine is None:
            out.append(
                Comparison(
                    r.id, r.result, r.section, "plan: no prediction",
                    f"not measured: the plan of {plan.experiment!r} predicts no number for it",
                    r.criterion, NOT_MEASURED,
                )
            )  # fmt: skip
            continue
        out.extend(compare_with_flight(sources, (mine,)))
    return out
