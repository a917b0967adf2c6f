"""The paper's flight results and a pass's analyses held against them ("flight against ours").

:data:`PAPER_RESULTS` is the one place where the flight's numbers and our criteria live, each
with the paper section it comes from (Yoshida et al., "Flight experiments of ETS-VII for
advanced space robot control", 2002; SPEC sections 3 and 4). :func:`compare_with_flight`
measures each result on a pass's **stored documents** (the JSON numbers of
:func:`telemetry.analysis.analyse_pass`, the inertia identification and the
gravity-gradient re-simulation, as :mod:`server.services.analyses` stores them), so the
report computes the table for every pass and a recalibration changes only what "ours"
measures, never the flight's numbers or the criteria.

A verdict is computed, never written down: ``reproduced`` when the criterion holds on this
pass's numbers, ``not reproduced`` when it does not, ``not measured`` when the analysis it
needs is absent, failed, or lacks the number (never counted as a pass).

The orderings of experiments 1 and 3 (which leg, which variant is larger or faster) are also
here (:func:`reaction_ordering`, :func:`phase_plane_ordering`), for the report's tables and
the figures.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

__all__ = [
    "FLIGHT_FASTEST_SETTLING",
    "FLIGHT_LARGEST_PEAK",
    "FLIGHT_RANGE_ORDER",
    "MIN_SETTLE_TOLERANCE_S",
    "NOT_MEASURED",
    "NOT_REPRODUCED",
    "PAPER_RESULTS",
    "REPRODUCED",
    "Comparison",
    "Measured",
    "OrderingRow",
    "PaperResult",
    "Predicted",
    "Sources",
    "compare_with_flight",
    "compare_with_plan",
    "ordered",
    "phase_plane_ordering",
    "reaction_ordering",
    "verdict",
]

REPRODUCED = "reproduced"
NOT_REPRODUCED = "not reproduced"
NOT_MEASURED = "not measured"

#: Experiment 3 in flight (paper 3.5, Fig. 9): pitch range (c) < (a) < (b); (c) settles
#: fastest; (b) overshoots most.
FLIGHT_RANGE_ORDER = ("(c)", "(a)", "(b)")
FLIGHT_FASTEST_SETTLING = "(c)"
FLIGHT_LARGEST_PEAK = "(b)"

Doc = Mapping[str, Any]


@dataclass(frozen=True)
class Sources:
    """The ``result`` numbers of each stored analysis; ``None`` when absent or failed."""

    pass_analysis: Doc | None = None
    identification: Doc | None = None
    resim: Doc | None = None


@dataclass(frozen=True)
class Measured:
    """What this pass shows for one result: ``holds`` is ``None`` when not measured."""

    ours: str
    holds: bool | None


@dataclass(frozen=True)
class PaperResult:
    id: str
    result: str
    section: str
    flight: str
    criterion: str
    #: the numbers of ``criterion`` (the check reads them from here, nowhere else)
    limits: Mapping[str, float]
    check: Callable[[PaperResult, Sources], Measured] = field(repr=False)


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


def _num(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value) if math.isfinite(value) else None


def _missing(what: str) -> Measured:
    return Measured(f"not measured: {what}", None)


def _part(src: Sources, key: str) -> Doc | None:
    doc = src.pass_analysis
    value = None if doc is None else doc.get(key)
    return value if isinstance(value, Mapping) else None


def _motions(src: Sources, kind: str) -> list[Doc]:
    reaction = _part(src, "reaction") or {}
    return [m for m in reaction.get("motions", []) if m.get("kind") == kind]


def _variants(src: Sources) -> dict[str, Doc]:
    plane = _part(src, "phase_plane") or {}
    return {str(v.get("label")): v for v in plane.get("variants", [])}


def _settling_values(variants: Mapping[str, Doc]) -> dict[str, float | None]:
    """Each variant's settling time as ``VariantPhasePlane.settling_rank_s`` gives it, read
    from a stored document: ``inf`` for one flown whole that had not settled by its window's
    end, ``None`` where it was not measured."""
    out: dict[str, float | None] = {}
    for k, v in variants.items():
        value = _num(v.get("settling_time_s"))
        flown = (_num(v.get("frames", 1)) or 0.0) > 0 and not v.get("note")
        out[k] = math.inf if value is None and v.get("settled") is False and flown else value
    return out


def _legs_fast_slow(src: Sources) -> tuple[Doc, Doc] | None:
    legs = [m for m in _motions(src, "reactionless") if _num(m.get("peak_hand_speed_mps"))]
    if len(legs) < 2:
        return None
    legs.sort(key=lambda m: -float(m["peak_hand_speed_mps"]))
    return legs[0], legs[-1]


# --- the checks ----------------------------------------------------------------------------


def _ptp_settling(r: PaperResult, src: Sources) -> Measured:
    ptp = _motions(src, "ptp")
    if not ptp:
        return _missing("no PTP motion analysed")
    m = ptp[0]
    band = (_part(src, "reaction") or {}).get("settle_band_deg")
    settle = _num(m.get("settling_time_s"))
    if settle is None:
        if m.get("frames") and _num(m.get("peak_excursion_deg")) is not None:
            end = _num(m.get("window_end_s")) or math.nan
            return Measured(f"not settled within its window (to {end:.0f} s)", False)
        return _missing("PTP settling not computed")
    tol = r.limits.get("tolerance_s", r.limits["flight_s"] * r.limits["relative_tolerance"])
    lo, hi = r.limits["flight_s"] - tol, r.limits["flight_s"] + tol
    peak = _num(m.get("peak_excursion_deg"))
    text = f"{settle:.1f} s (band {band} deg)" + ("" if peak is None else f"; peak {peak:.2f} deg")
    return Measured(text, lo <= settle <= hi)


def _reactionless_little(r: PaperResult, src: Sources) -> Measured:
    ptp, legs = _motions(src, "ptp"), _motions(src, "reactionless")
    if not ptp or not legs:
        return _missing("PTP or reactionless legs not analysed")
    ptp_peak = _num(ptp[0].get("peak_excursion_deg"))
    peaks = [_num(m.get("peak_excursion_deg")) for m in legs]
    settles = [_num(m.get("settling_time_s")) for m in legs]
    if ptp_peak is None or any(p is None for p in peaks):
        return _missing("attitude excursions not computed")
    holds = all(
        p is not None and p < r.limits["excursion_ratio"] * ptp_peak for p in peaks
    ) and all(s is not None and s <= r.limits["settling_s"] for s in settles)
    text = (
        "legs peak "
        + " / ".join(f"{p:.3f}" for p in peaks if p is not None)
        + f" deg against PTP {ptp_peak:.3f} deg; settle "
        + " / ".join("not settled" if s is None else f"{s:.1f}" for s in settles)
        + " s"
    )
    return Measured(text, holds)


def _reactionless_speed(r: PaperResult, src: Sources) -> Measured:
    pair = _legs_fast_slow(src)
    if pair is None:
        return _missing("fewer than two reactionless legs with a hand speed")
    fast, slow = pair
    a, b = _num(fast.get("rms_reaction_momentum_nms")), _num(slow.get("rms_reaction_momentum_nms"))
    if a is None or b is None:
        return _missing("reaction momentum not computed")
    text = (
        f"RMS |H~bm phi'| {a:.4f} N m s at {fast['peak_hand_speed_mps']:.4f} m/s against "
        f"{b:.4f} N m s at {slow['peak_hand_speed_mps']:.4f} m/s"
    )
    ra, rb = _num(fast.get("peak_residual_deg")), _num(slow.get("peak_residual_deg"))
    if ra is not None and rb is not None:
        text += f" (attitude residual {ra:.4f} against {rb:.4f} deg)"
    return Measured(text, a > r.limits["min_ratio"] * b)


def _gjm_base_pitch(r: PaperResult, src: Sources) -> Measured:
    hand = _part(src, "hand_attitude") or {}
    legs = [h for h in hand.get("holds", []) if h.get("span") == "legs"]
    pair = legs[0].get("base_pitch_change_range_deg") if legs else None
    if not isinstance(pair, list) or len(pair) != 2 or None in pair:
        return _missing("GJM base pitch not computed")
    lo, hi = float(pair[0]), float(pair[1])
    extreme = lo if abs(lo) >= abs(hi) else hi
    holds = abs(extreme - r.limits["flight_deg"]) <= r.limits["tolerance_deg"]
    return Measured(f"{extreme:+.3f} deg (range {lo:+.3f} to {hi:+.3f})", holds)


def _gjm_hand_hold(r: PaperResult, src: Sources) -> Measured:
    hand = _part(src, "hand_attitude") or {}
    spans = [h for h in hand.get("holds", []) if h.get("span") != "legs"]
    values = [_num(h.get("hand_change_max_deg")) for h in spans]
    if not spans or any(v is None for v in values):
        return _missing("GJM hand attitude not computed")
    worst = max(v for v in values if v is not None)
    text = ", ".join(f"{h.get('span')} {v:.3f}" for h, v in zip(spans, values, strict=True))
    return Measured(text + " deg", worst <= r.limits["max_deg"])


def _variants_start(r: PaperResult, src: Sources) -> Measured:
    v = _variants(src)
    starts = {k: _num(x.get("start_pitch_deg")) for k, x in v.items()}
    if set(starts) < {"(a)", "(b)", "(c)"} or None in starts.values():
        return _missing("variants (a), (b), (c) not all analysed from their start")
    worst = max(abs(float(x or 0.0)) for x in starts.values())
    text = ", ".join(f"{k} {float(x or 0.0):+.3f}" for k, x in sorted(starts.items()))
    return Measured(f"start pitch {text} deg", worst <= r.limits["max_deg"])


def _feedback_range(r: PaperResult, src: Sources) -> Measured:
    a = _variants(src).get("(a)")
    lo = None if a is None else _num(a.get("pitch_min_deg"))
    hi = None if a is None else _num(a.get("pitch_max_deg"))
    if lo is None or hi is None:
        return _missing("variant (a) not analysed")
    tol = r.limits["tolerance_deg"]
    holds = abs(lo - r.limits["min_deg"]) <= tol and abs(hi - r.limits["max_deg"]) <= tol
    return Measured(f"{lo:+.2f} to {hi:+.2f} deg", holds)


def _feedforward(r: PaperResult, src: Sources) -> Measured:
    v = _variants(src)
    b = v.get("(b)")
    dip = None if b is None else _num(b.get("first_dip_deg"))
    peaks = {k: _num(x.get("pitch_max_deg")) for k, x in v.items()}
    if dip is None or peaks.get("(b)") is None or len(peaks) < 3 or None in peaks.values():
        return _missing("variants (a), (b), (c) not all analysed")
    peak_b = float(peaks["(b)"] or 0.0)
    others = max(float(p or 0.0) for k, p in peaks.items() if k != "(b)")
    holds = dip >= r.limits["first_dip_deg"] and peak_b > others + r.limits["peak_margin_deg"]
    return Measured(
        f"first dip {dip:+.2f} deg; peak {peak_b:+.2f} deg against {others:+.2f} deg (next)",
        holds,
    )


def _offset_numbers(
    src: Sources, key: str
) -> tuple[dict[str, float], dict[str, float | None]] | None:
    v = _variants(src)
    values = {k: _num(x.get(key)) for k, x in v.items()}
    if set(values) < {"(a)", "(b)", "(c)"}:
        return None
    return {k: float(x) for k, x in values.items() if x is not None}, values


def _offset_range(r: PaperResult, src: Sources) -> Measured:
    found = _offset_numbers(src, "pitch_range_deg")
    if found is None or None in found[1].values():
        return _missing("variants (a), (b), (c) not all analysed")
    rng = found[0]
    smallest = min(rng, key=lambda k: rng[k]) == "(c)" and list(rng.values()).count(rng["(c)"]) == 1
    return Measured(f"range {ordered(rng, 'deg')}", smallest)


def _offset_settling(r: PaperResult, src: Sources) -> Measured:
    settles = _settling_values(_variants(src))
    if set(settles) < {"(a)", "(b)", "(c)"}:
        return _missing("variants (a), (b), (c) not all analysed")
    c = settles["(c)"]
    fastest = (
        c is not None
        and math.isfinite(c)
        and all(s is None or s > c for k, s in settles.items() if k != "(c)")
    )
    return Measured(f"settling {ordered(settles, 's', digits=1)}", fastest)


def _gravity_gradient(r: PaperResult, src: Sources) -> Measured:
    segments = [] if src.resim is None else list(src.resim.get("segments", []))
    pairs = []
    for seg in segments:
        with_gg = _num((seg.get("with_gg") or {}).get("rms_residual_angle_deg"))
        without = _num((seg.get("without_gg") or {}).get("rms_residual_angle_deg"))
        if with_gg is None or without is None:
            return _missing("a re-simulated segment lacks its residual")
        pairs.append((seg.get("t_start_s"), with_gg, without))
    if not pairs:
        return _missing("gravity-gradient re-simulation absent or failed")
    holds = all(w > r.limits["min_improvement"] * g for _, g, w in pairs)
    text = "; ".join(f"from {t} s: {g:.4f} with, {w:.4f} deg without" for t, g, w in pairs)
    return Measured("RMS residual " + text, holds)


def _identification(r: PaperResult, src: Sources) -> Measured:
    doc = src.identification
    if doc is None:
        return _missing("inertia identification absent or failed")
    est, err = doc.get("parameters_kgm2") or {}, doc.get("standard_error_kgm2") or {}
    ref = (doc.get("reference") or {}).get("parameters_kgm2") or {}
    worst: tuple[float, str] | None = None
    for name, truth in ref.items():
        value, sigma = _num(est.get(name)), _num(err.get(name))
        if value is None or not sigma or _num(truth) is None:
            return _missing(f"{name} not identified")
        ratio = abs(value - float(truth)) / sigma
        worst = max(worst or (ratio, name), (ratio, name))
    if worst is None:
        return _missing("no reference inertia")
    name = worst[1]
    text = (
        f"largest difference {worst[0]:.1f} standard errors ({name} {est[name]:.1f} +- "
        f"{err[name]:.1f} against {ref[name]})"
    )
    return Measured(text, worst[0] <= r.limits["max_sigma"])


def _endpoint(r: PaperResult, src: Sources) -> Measured:
    end = _part(src, "endpoint") or {}
    angle, joints = _num(end.get("attitude_error_angle_deg")), _num(end.get("max_joint_error_deg"))
    if angle is None or joints is None:
        return _missing("non-holonomic end point not analysed")
    rpy = end.get("attitude_error_deg") or []
    text = f"attitude error {angle:.3f} deg"
    if len(rpy) == 3 and None not in rpy:
        text += " (r, p, y " + ", ".join(f"{x:+.3f}" for x in rpy) + ")"
    text += f"; largest joint error {joints:.4f} deg"
    holds = angle <= r.limits["attitude_deg"] and joints <= r.limits["joint_deg"]
    return Measured(text, holds)


PAPER_RESULTS: tuple[PaperResult, ...] = (
    PaperResult(
        "ptp_settling",
        "Exp. 1: PTP A->B disturbs the attitude strongly and needs a settling wait",
        "paper 3.3, Fig. 5; SPEC 3.1",
        "about 100 s to settle",
        "settling within 100 s +- 30 % (70 to 130 s)",
        {"flight_s": 100.0, "relative_tolerance": 0.30},
        _ptp_settling,
    ),
    PaperResult(
        "reactionless_little_disturbance",
        "Exp. 1: reactionless motion disturbs the attitude very little, no settling wait",
        "paper 3.3, Fig. 5; SPEC 3.1",
        "very little disturbance, no settling wait",
        "each leg's peak excursion under 10 % of the PTP's and settling within 5 s",
        {"excursion_ratio": 0.10, "settling_s": 5.0},
        _reactionless_little,
    ),
    PaperResult(
        "reactionless_grows_with_speed",
        "Exp. 1: the faster reactionless leg, the larger reaction (joint-servo lag)",
        "paper 3.3, Fig. 5 middle; SPEC 3.1",
        "residual reaction grows with speed (0.015 against 0.0075 m/s)",
        "fast leg's RMS |H~bm phi'| over 1.2x the slow leg's (beyond the ~0.005 N m s noise)",
        {"min_ratio": 1.2},
        _reactionless_speed,
    ),
    PaperResult(
        "gjm_base_pitch",
        "Exp. 2: GJM in free drift, the base pitch moves with the arm's reaction",
        "paper 3.4, Fig. 8 top; SPEC 3.2",
        "about -0.6 deg",
        "largest base pitch change -0.6 +- 0.15 deg",
        {"flight_deg": -0.6, "tolerance_deg": 0.15},
        _gjm_base_pitch,
    ),
    PaperResult(
        "gjm_hand_hold",
        "Exp. 2: the hand's inertial attitude is held while the base turns",
        "paper 3.4, Fig. 8 middle; SPEC 3.2",
        "within about +-0.1 deg",
        "largest hand attitude change per leg at most 0.15 deg (0.1 + 0.05)",
        {"max_deg": 0.15},
        _gjm_hand_hold,
    ),
    PaperResult(
        "coordination_start",
        "Exp. 3: every variant starts at the phase plane's origin",
        "paper 3.5, Fig. 9",
        "each trajectory starts at the origin (and returns to it)",
        "every variant's pitch at the start of its forward leg within the report's settling "
        "band, 0.05 deg, of nominal: the one before it had settled",
        {"max_deg": 0.05},
        _variants_start,
    ),
    PaperResult(
        "coordination_feedback_range",
        "Exp. 3 (a) feedback only: pitch range",
        "paper 3.5, Fig. 9 top; SPEC 3.3",
        "-0.5 to +0.4 deg",
        "min -0.5 +- 0.15 deg and max +0.4 +- 0.15 deg",
        {"min_deg": -0.5, "max_deg": 0.4, "tolerance_deg": 0.15},
        _feedback_range,
    ),
    PaperResult(
        "coordination_feedforward",
        "Exp. 3 (b) momentum feedforward: fast first response, then a large positive overshoot",
        "paper 3.5, Fig. 9 middle; SPEC 3.3",
        "first dip within -0.3 deg; strongest positive overshoot",
        "first dip (forward leg) >= -0.3 deg and peak over 0.05 deg above (a)'s and (c)'s",
        {"first_dip_deg": -0.3, "peak_margin_deg": 0.05},
        _feedforward,
    ),
    PaperResult(
        "coordination_offset_range",
        "Exp. 3 (c) offset destination: the smallest pitch range of the three",
        "paper 3.5, Fig. 9 bottom; SPEC 3.3",
        "range (c) < (a) < (b)",
        "(c)'s pitch range the smallest of (a), (b), (c)",
        {},
        _offset_range,
    ),
    PaperResult(
        "coordination_offset_settling",
        "Exp. 3 (c) offset destination: the fastest settling of the three",
        "paper 3.5, Fig. 9 bottom; SPEC 3.3",
        "(c) settles fastest after the arm stops",
        "(c)'s settling time (report's band) the shortest of (a), (b), (c)",
        {},
        _offset_settling,
    ),
    PaperResult(
        "gravity_gradient_drift",
        "Free drift: the slow attitude drift comes from the gravity-gradient torque",
        "paper 3.7, Fig. 12; SPEC 3.2, 4",
        "re-simulation with eq. (11) follows the drift, without it does not",
        "RMS residual without eq. (11) over 1.5x that with it, in every free-drift segment",
        {"min_improvement": 1.5},
        _gravity_gradient,
    ),
    PaperResult(
        "inertia_identification",
        "Inertia identified from momentum conservation, against Table 1",
        "paper 3.2, Table 1; SPEC 4",
        "Table 1 (e.g. Izz 7090 kg m^2)",
        "every parameter within 3 standard errors of Table 1",
        {"max_sigma": 3.0},
        _identification,
    ),
    PaperResult(
        "nonholonomic_endpoint",
        "Exp. 4: non-holonomic end point reached with no on-line correction",
        "paper 3.6, Fig. 11; SPEC 3.4",
        "all states at target except about 0.2 deg of roll",
        "final attitude error at most 0.3 deg (0.2 + 0.1) and joints within 0.1 deg",
        {"attitude_deg": 0.3, "joint_deg": 0.1},
        _endpoint,
    ),
)


def compare_with_flight(
    sources: Sources, results: Sequence[PaperResult] = PAPER_RESULTS
) -> list[Comparison]:
    """One :class:`Comparison` per paper result, measured on ``sources``."""
    out = []
    for r in results:
        try:
            measured = r.check(r, sources)
        except (KeyError, TypeError, ValueError, AttributeError) as exc:  # malformed document
            measured = _missing(f"{type(exc).__name__}: {exc}")
        out.append(
            Comparison(
                r.id, r.result, r.section, r.flight, measured.ours, r.criterion,
                verdict(measured.holds),
            )
        )  # fmt: skip
    return out


# --- orderings --------------------------------------------------------------------------------


def ordered(values: Mapping[str, float | None], unit: str, *, digits: int = 2) -> str:
    """``"(a) 0.55 < (b) 0.76 < (c) 0.84 deg"``: the labels by increasing value (missing
    values last, as "n/a"; infinite ones, a settling that had not happened by the window's
    end, after the finite ones as "not settled")."""
    known = sorted((v, k) for k, v in values.items() if v is not None and math.isfinite(v))
    text = " < ".join(f"{k} {v:.{digits}f}" for v, k in known)
    text = f"{text} {unit}".strip()
    never = [k for k, v in values.items() if v is not None and not math.isfinite(v)]
    if never:
        text += (" < " if known else "") + ", ".join(never) + " not settled by its window's end"
    unknown = [k for k, v in values.items() if v is None]
    if unknown:
        text += (", " if text else "") + ", ".join(f"{k} n/a" for k in unknown)
    return text


@dataclass(frozen=True)
class OrderingRow:
    quantity: str
    ours: str
    flight: str
    holds: bool | None

    def row(self) -> list[Any]:
        return [self.quantity, self.ours, self.flight, self.holds]


def phase_plane_ordering(plane: Doc | None) -> list[OrderingRow]:
    """Experiment 3's orderings (range, settling, peak) on this pass against the flight's."""
    variants = {} if plane is None else {str(v.get("label")): v for v in plane.get("variants", [])}

    def values(key: str) -> dict[str, float | None]:
        return {k: _num(v.get(key)) for k, v in variants.items()}

    complete = {"(a)", "(b)", "(c)"} <= set(variants)
    rng, settle, peak = values("pitch_range_deg"), _settling_values(variants), values("peak_deg")
    for k, v in variants.items():  # documents stored before peak_deg had pitch_max_deg only
        if peak.get(k) is None:
            peak[k] = _num(v.get("pitch_max_deg"))

    def order_of(v: dict[str, float | None]) -> tuple[str, ...] | None:
        if not complete or None in v.values():
            return None
        return tuple(sorted(v, key=lambda k: float(v[k] or 0.0)))

    def extreme(v: dict[str, float | None], label: str, *, largest: bool) -> bool | None:
        if not complete or v.get(label) is None:
            return None
        x = float(v[label] or 0.0)
        others = [float(y) for k, y in v.items() if k != label and y is not None]
        return all((x > y) if largest else (x < y) for y in others)

    range_order = order_of(rng)
    return [
        OrderingRow(
            "pitch range",
            ordered(rng, "deg"),
            " < ".join(FLIGHT_RANGE_ORDER),
            None if range_order is None else range_order == FLIGHT_RANGE_ORDER,
        ),
        OrderingRow(
            "settling time after the back leg",
            ordered(settle, "s", digits=1),
            f"{FLIGHT_FASTEST_SETTLING} fastest",
            extreme(settle, FLIGHT_FASTEST_SETTLING, largest=False),
        ),
        OrderingRow(
            "peak (positive overshoot)",
            ordered(peak, "deg"),
            f"{FLIGHT_LARGEST_PEAK} largest",
            extreme(peak, FLIGHT_LARGEST_PEAK, largest=True),
        ),
    ]


#: Experiment 1's measures, each ``(label, motion key, unit)``: the reaction on the momentum
#: (Fig. 5 middle) beside the attitude (Fig. 5 bottom).
REACTION_MEASURES = (
    ("peak hand speed", "peak_hand_speed_mps", "m/s"),
    ("RMS reaction momentum |H~bm phi'|", "rms_reaction_momentum_nms", "N m s"),
    ("peak reaction momentum |H~bm phi'|", "peak_reaction_momentum_nms", "N m s"),
    ("peak attitude excursion", "peak_excursion_deg", "deg"),
    ("peak attitude residual against the plan", "peak_residual_deg", "deg"),
    ("settling time", "settling_time_s", "s"),
)


def reaction_ordering(reaction: Doc | None) -> tuple[list[list[Any]], list[str]]:
    """Experiment 1's table rows ``[measure, unit, ptp, fast leg, slow leg, fast > slow]``
    and notes naming the legs and stating the ordering on each reaction measure."""
    motions = [] if reaction is None else list(reaction.get("motions", []))
    src = Sources(pass_analysis={"reaction": {"motions": motions}})
    ptp = _motions(src, "ptp")
    pair = _legs_fast_slow(src)
    rows: list[list[Any]] = []
    for label, key, unit in REACTION_MEASURES:
        p = _num(ptp[0].get(key)) if ptp else None
        f = None if pair is None else _num(pair[0].get(key))
        s = None if pair is None else _num(pair[1].get(key))
        larger = None if f is None or s is None or key == "settling_time_s" else f > s
        rows.append([label, unit, p, f, s, larger])
    notes = []
    if pair is None:
        notes.append("fewer than two reactionless legs with a measured hand speed: no ordering")
    else:
        fast, slow = pair
        notes.append(f"fast leg: {fast.get('segment')}; slow leg: {slow.get('segment')}")
        for row in rows[1:5]:
            if row[5] is not None:
                holds = "holds" if row[5] else "does not hold"
                notes.append(
                    f"the faster leg, the larger reaction (flight): {holds} on the {row[0]} "
                    f"({row[3]:.4g} against {row[4]:.4g} {row[1]})"
                )
    return rows, notes


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
            return _num(self.metrics.get(f"{experiment}.{key}"))
        return _num(self.metrics.get(key)) if self.experiment == experiment else None


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
            values: dict[str, float | None] = dict(_settling_values(_variants(src)))
        else:
            values = {k: _num(x.get(key)) for k, x in _variants(src).items()}
        if set(values) < {"(a)", "(b)", "(c)"} or None in values.values():
            return _missing("variants (a), (b), (c) not all analysed")
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
