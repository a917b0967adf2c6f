"""Calibrating the attitude-control law to the paper's targets (``hikoboshi calibrate``
without a pass, docs/spacecraft.md).

:func:`fit_to_paper`: the law against the paper's targets of experiments 1 and 3 that the
law shapes (PTP settling, the feedback-only pitch range, the feedforward's shape, the
offset destination's smallest range and fastest settling), each residual scaled by its
tolerance, the orderings as hinges (zero when they hold), measured as the report measures
them (the 0.05 deg band around the window's final value; experiment 3 as the demo pass
schedules it; the PTP with a 360 s wait, so that its final value is the attitude the loop
holds). Evaluated on the prediction, in least squares (:func:`spacecraft.calibration.solve`);
optionally the start and the fit are flown through the vehicle
(:func:`spacecraft._calibration.fly_plan`, the same plans) and reported beside it. The
targets the law does not shape (GJM flies in free drift; the reactionless reaction comes
from joint-servo lag) are reported, not fitted.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from planner.attitude_control import AcsGains
from planner.dynamics import DynamicsWorkspace
from planner.model import default_model
from planner.plan import Plan
from spacecraft._calibration import (
    SETTLE_BAND_DEG,
    Flight,
    calibration_plans,
    coordination_metrics,
    ptp_settling_s,
)
from spacecraft.calibration import (
    CalibrationResult,
    Progress,
    TargetRow,
    check_parameters,
    gains_from_parameters,
    memoised,
    predict_with,
    solve,
    start_values,
)

__all__ = ["fit_to_paper"]

Array = NDArray[np.float64]


@dataclass(frozen=True)
class _PaperTarget:
    id: str
    target: str
    tolerance: str
    #: the measured value shown in the report, from the metrics
    value: Callable[[Mapping[str, Mapping[str, float]]], float]
    #: the criterion (paper's), from the metrics
    holds: Callable[[Mapping[str, Mapping[str, float]]], bool]
    #: residuals scaled by the tolerance (hinges for orderings)
    residuals: Callable[[Mapping[str, Mapping[str, float]]], list[float]]


#: The hinges ask for the orderings to hold by this much (a tie does not hold).
_MARGIN_DEG = 0.01
_MARGIN_S = 2.0


def _paper_limits() -> dict[str, Mapping[str, float]]:
    from telemetry.analysis.paper import PAPER_RESULTS

    return {r.id: r.limits for r in PAPER_RESULTS}


def _others(m: Mapping[str, Mapping[str, float]], key: str, but: str) -> float:
    names = ("coordination_feedback", "coordination_feedforward", "coordination_offset")
    return min(m[n][key] for n in names if n != but)


def _feedback_pitch(
    extreme: str, word: str, paper_deg: float, tolerance_deg: float
) -> _PaperTarget:
    """Experiment 3's feedback-only pitch ``extreme`` ("min" or "max") within the paper's
    tolerance of the paper's value."""
    key = f"pitch_{extreme}_deg"

    def value(m: Mapping[str, Mapping[str, float]]) -> float:
        return m["coordination_feedback"][key]

    return _PaperTarget(
        f"coordination_feedback_{extreme}",
        f"(a) feedback only: pitch {word} {paper_deg:+.2f} deg",
        f"+-{tolerance_deg} deg",
        value,
        lambda m: abs(value(m) - paper_deg) <= tolerance_deg,
        lambda m: [(value(m) - paper_deg) / tolerance_deg],
    )


def _paper_targets() -> list[_PaperTarget]:
    lim = _paper_limits()
    ptp = lim["ptp_settling"]
    lo_s = ptp["flight_s"] * (1 - ptp["relative_tolerance"])
    hi_s = ptp["flight_s"] * (1 + ptp["relative_tolerance"])
    fb = lim["coordination_feedback_range"]
    ff = lim["coordination_feedforward"]
    fbk, ffw, off = "coordination_feedback", "coordination_feedforward", "coordination_offset"

    def ff_peak_margin(m: Mapping[str, Mapping[str, float]]) -> float:
        others = max(m[fbk]["pitch_max_deg"], m[off]["pitch_max_deg"])
        return m[ffw]["pitch_max_deg"] - others

    start = lim["coordination_start"]

    def worst_start(m: Mapping[str, Mapping[str, float]]) -> float:
        return max(abs(m[n]["start_pitch_deg"]) for n in (fbk, ffw, off))

    return [
        _PaperTarget(
            "ptp_settling",
            f"PTP A->B back within {SETTLE_BAND_DEG} deg of the attitude the loop holds "
            f"about {ptp['flight_s']:.0f} s after the motion",
            f"{lo_s:.0f} to {hi_s:.0f} s",
            lambda m: m["ptp"]["settling_time_s"],
            lambda m: lo_s <= m["ptp"]["settling_time_s"] <= hi_s,
            lambda m: [
                (m["ptp"]["settling_time_s"] - ptp["flight_s"])
                / (ptp["flight_s"] * ptp["relative_tolerance"])
            ],
        ),
        _PaperTarget(
            "coordination_start",
            "every variant of experiment 3 starts at the phase plane's origin (value: the "
            "largest pitch at a forward leg's start)",
            f"at most {start['max_deg']} deg, hinge",
            worst_start,
            lambda m: worst_start(m) <= start["max_deg"],
            lambda m: [max(0.0, worst_start(m) + _MARGIN_DEG - start["max_deg"]) / 0.02],
        ),
        *(
            _feedback_pitch(extreme, word, fb[f"{extreme}_deg"], fb["tolerance_deg"])
            for extreme, word in (("min", "minimum"), ("max", "maximum"))
        ),
        _PaperTarget(
            "coordination_feedforward_dip",
            f"(b) feedforward: first dip at least {ff['first_dip_deg']:+.2f} deg",
            "hinge, 0.1 deg scale",
            lambda m: m[ffw]["first_dip_deg"],
            lambda m: m[ffw]["first_dip_deg"] >= ff["first_dip_deg"],
            lambda m: [max(0.0, ff["first_dip_deg"] + _MARGIN_DEG - m[ffw]["first_dip_deg"]) / 0.1],
        ),
        _PaperTarget(
            "coordination_feedforward_overshoot",
            f"(b) feedforward: peak over {ff['peak_margin_deg']} deg above (a)'s and (c)'s"
            " (value: the margin)",
            f"hinge, {ff['peak_margin_deg']} deg scale",
            ff_peak_margin,
            lambda m: ff_peak_margin(m) > ff["peak_margin_deg"],
            lambda m: [
                max(0.0, ff["peak_margin_deg"] + _MARGIN_DEG - ff_peak_margin(m))
                / ff["peak_margin_deg"]
            ],
        ),
        _PaperTarget(
            "coordination_offset_range",
            "(c) offset: the smallest pitch range of (a), (b), (c) (value: (c)'s minus the "
            "next smallest)",
            "hinge, 0.05 deg scale",
            lambda m: m[off]["pitch_range_deg"] - _others(m, "pitch_range_deg", off),
            lambda m: m[off]["pitch_range_deg"] < _others(m, "pitch_range_deg", off),
            lambda m: [
                max(
                    0.0,
                    m[off]["pitch_range_deg"] + _MARGIN_DEG - _others(m, "pitch_range_deg", off),
                )
                / 0.05
            ],
        ),
        _PaperTarget(
            "coordination_offset_settling",
            "(c) offset: the fastest settling of (a), (b), (c) (value: (c)'s minus the next "
            "fastest, s)",
            "hinge, 10 s scale",
            lambda m: m[off]["settling_time_s"] - _others(m, "settling_time_s", off),
            lambda m: m[off]["settling_time_s"] < _others(m, "settling_time_s", off),
            lambda m: [
                max(0.0, m[off]["settling_time_s"] + _MARGIN_S - _others(m, "settling_time_s", off))
                / 10.0
            ],
        ),
    ]


def _flight_of(plan: Plan, gains: AcsGains, ws: DynamicsWorkspace) -> Flight:
    pred = predict_with(ws, plan, gains)
    return Flight(
        t_s=pred.t_s,
        quat_orbit_from_base_xyzw=pred.quat_orbit_from_base_xyzw,
        joints_rad=pred.joints_rad,
        joint_targets_rad=pred.joints_rad,
        wheel_momentum_nms=pred.wheel_momentum_nms,
        rejected=0,
    )


def _metrics(
    fly: Callable[[Plan], Flight], plans: Mapping[str, Plan]
) -> dict[str, dict[str, float]]:
    """The targets' metrics of the PTP and experiment 3 as ``fly`` flies them."""
    ptp = plans["ptp"]
    flight = fly(ptp)
    out = {
        "ptp": {
            "peak_attitude_deg": float(np.max(flight.attitude_deg)),
            "settling_time_s": ptp_settling_s(flight, ptp),
        }
    }
    coordination = plans["coordination"]
    flight = fly(coordination)
    for label, name in (("(a)", "feedback"), ("(b)", "feedforward"), ("(c)", "offset")):
        out[f"coordination_{name}"] = coordination_metrics(flight, coordination, label)
    return out


def _predicted_metrics(
    ws: DynamicsWorkspace, plans: Mapping[str, Plan], gains: AcsGains
) -> dict[str, dict[str, float]]:
    return _metrics(lambda plan: _flight_of(plan, gains, ws), plans)


def _unfitted_rows(ws: DynamicsWorkspace) -> list[TargetRow]:
    """The paper's targets the law does not shape, reported for completeness."""
    from planner.gjm import plan_gjm

    lim = _paper_limits()["gjm_base_pitch"]
    value = float(plan_gjm(ws).metrics["base_pitch_change_deg"])
    holds = abs(value - lim["flight_deg"]) <= lim["tolerance_deg"]
    return [
        TargetRow(
            "gjm_base_pitch",
            f"GJM base pitch change {lim['flight_deg']:+.2f} deg",
            f"+-{lim['tolerance_deg']} deg",
            value,
            value,
            holds,
            holds,
            "prediction",
            "not fitted: GJM flies in free drift, the law does not act",
        ),
        TargetRow(
            "reactionless_grows_with_speed",
            "reactionless reaction grows with speed",
            "fast leg over 1.2x the slow leg",
            None,
            None,
            None,
            None,
            "prediction",
            "not fitted: the reaction comes from joint-servo lag (servo gains), not the law",
        ),
    ]


def _vehicle_metrics(
    values: Mapping[str, float], ws: DynamicsWorkspace, plans: Mapping[str, Plan]
) -> dict[str, dict[str, float]]:
    """The fit's metrics flown through the vehicle (truth simulation), on the same plans as
    the prediction's (the PTP with its long settling wait)."""
    from spacecraft._calibration import fly_plan
    from spacecraft.vehicle_config import VehicleConfig

    config = VehicleConfig(acs_gains=gains_from_parameters(ws, values))
    return _metrics(lambda plan: fly_plan(plan, config), plans)


def _rows(
    targets: Sequence[_PaperTarget],
    start: Mapping[str, Mapping[str, float]],
    fit: Mapping[str, Mapping[str, float]],
    source: str,
    note: Callable[[_PaperTarget], str] = lambda t: "",
) -> list[TargetRow]:
    """Each target's row: its value and verdict at the start's and the fit's metrics."""
    return [
        TargetRow(
            t.id,
            t.target,
            t.tolerance,
            float(t.value(start)),
            float(t.value(fit)),
            bool(t.holds(start)),
            bool(t.holds(fit)),
            source,
            note(t),
        )
        for t in targets
    ]


def _faithful_note(
    target: _PaperTarget,
    predicted: Mapping[str, Mapping[str, float]],
    flown: Mapping[str, Mapping[str, float]],
) -> str:
    """Where the prediction's verdict at the fit is not the vehicle's, say so."""
    if target.holds(predicted) == target.holds(flown):
        return ""
    return (
        f"the prediction gave {target.value(predicted):.4g} "
        f"({'holds' if target.holds(predicted) else 'does not hold'}): not faithful here"
    )


def fit_to_paper(
    parameters: Sequence[str] = ("bandwidth_radps", "damping_ratio"),
    *,
    ws: DynamicsWorkspace | None = None,
    start: Mapping[str, float] | None = None,
    max_evaluations: int = 40,
    progress: Progress | None = None,
    check_vehicle: bool = False,
) -> CalibrationResult:
    """Fit the law to the paper's targets that it shapes, on the prediction (about 2 s per
    evaluation); with ``check_vehicle`` the start and the fit are also flown through the
    vehicle (:func:`spacecraft._calibration.fly_plan`, the same plans, about 5 s each) and their
    rows added with source ``vehicle``."""
    names = check_parameters(parameters)
    ws = ws or DynamicsWorkspace(default_model())
    # the PTP with a settling wait long enough to measure a slow law's settling, experiment
    # 3 as the demo pass flies it (spacecraft._calibration.calibration_plans)
    plans = calibration_plans(ws)
    targets = _paper_targets()
    first = start_values(names, start)

    @memoised
    def metrics(values: dict[str, float]) -> dict[str, dict[str, float]]:
        return _predicted_metrics(ws, plans, gains_from_parameters(ws, values))

    def residuals(values: dict[str, float]) -> Array:
        m = metrics(values)
        return np.array([x for t in targets for x in t.residuals(m)], dtype=np.float64)

    objective, values, _, r, message = solve(names, first, residuals, max_evaluations, progress)
    m0, m1 = metrics(first), metrics(values)
    r0 = np.array([x for t in targets for x in t.residuals(m0)])
    rows = _rows(targets, m0, m1, "prediction")
    rows += _unfitted_rows(ws)
    if check_vehicle:
        flown = memoised(lambda v: _vehicle_metrics(v, ws, plans))
        v0, v1 = flown(first), flown(values)
        rows += _rows(targets, v0, v1, "vehicle", lambda t: _faithful_note(t, m1, v1))
    # no standard errors: the targets' residuals are hinges and tolerances, not noise
    fit = (objective, values, None, r, message)
    return CalibrationResult.of_fit("paper", first, fit, r0, rows)
