"""The paper's flight results (:data:`PAPER_RESULTS`), each with the check that measures it on
a pass's stored documents (:mod:`telemetry.analysis.paper`, which says how a verdict follows).

Each :class:`PaperResult` names the flight's number, the paper section it comes from
(Yoshida et al. 2002; SPEC sections 3 and 4) and our criterion, whose numbers are its
``limits`` (the check reads them from there, nowhere else).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from telemetry.analysis.paper.documents import (
    Sources,
    analysis_part,
    legs_fast_slow,
    motions_of,
    number,
    ordered,
    settling_values,
    variants_of,
)

__all__ = ["PAPER_RESULTS", "Measured", "PaperResult", "missing"]


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


def missing(what: str) -> Measured:
    """A result this pass does not measure, and why (``holds`` None: never a pass)."""
    return Measured(f"not measured: {what}", None)


# --- the checks ----------------------------------------------------------------------------


def _ptp_settling(r: PaperResult, src: Sources) -> Measured:
    ptp = motions_of(src, "ptp")
    if not ptp:
        return missing("no PTP motion analysed")
    m = ptp[0]
    band = (analysis_part(src, "reaction") or {}).get("settle_band_deg")
    settle = number(m.get("settling_time_s"))
    if settle is None:
        if m.get("frames") and number(m.get("peak_excursion_deg")) is not None:
            end = number(m.get("window_end_s")) or math.nan
            return Measured(f"not settled within its window (to {end:.0f} s)", False)
        return missing("PTP settling not computed")
    tol = r.limits.get("tolerance_s", r.limits["flight_s"] * r.limits["relative_tolerance"])
    lo, hi = r.limits["flight_s"] - tol, r.limits["flight_s"] + tol
    peak = number(m.get("peak_excursion_deg"))
    text = f"{settle:.1f} s (band {band} deg)" + ("" if peak is None else f"; peak {peak:.2f} deg")
    return Measured(text, lo <= settle <= hi)


def _reactionless_little(r: PaperResult, src: Sources) -> Measured:
    ptp, legs = motions_of(src, "ptp"), motions_of(src, "reactionless")
    if not ptp or not legs:
        return missing("PTP or reactionless legs not analysed")
    ptp_peak = number(ptp[0].get("peak_excursion_deg"))
    peaks = [number(m.get("peak_excursion_deg")) for m in legs]
    settles = [number(m.get("settling_time_s")) for m in legs]
    if ptp_peak is None or any(p is None for p in peaks):
        return missing("attitude excursions not computed")
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
    pair = legs_fast_slow(src)
    if pair is None:
        return missing("fewer than two reactionless legs with a hand speed")
    fast, slow = pair
    a, b = (
        number(fast.get("rms_reaction_momentum_nms")),
        number(slow.get("rms_reaction_momentum_nms")),
    )
    if a is None or b is None:
        return missing("reaction momentum not computed")
    text = (
        f"RMS |H~bm phi'| {a:.4f} N m s at {fast['peak_hand_speed_mps']:.4f} m/s against "
        f"{b:.4f} N m s at {slow['peak_hand_speed_mps']:.4f} m/s"
    )
    ra, rb = number(fast.get("peak_residual_deg")), number(slow.get("peak_residual_deg"))
    if ra is not None and rb is not None:
        text += f" (attitude residual {ra:.4f} against {rb:.4f} deg)"
    return Measured(text, a > r.limits["min_ratio"] * b)


def _gjm_base_pitch(r: PaperResult, src: Sources) -> Measured:
    hand = analysis_part(src, "hand_attitude") or {}
    legs = [h for h in hand.get("holds", []) if h.get("span") == "legs"]
    pair = legs[0].get("base_pitch_change_range_deg") if legs else None
    if not isinstance(pair, list) or len(pair) != 2 or None in pair:
        return missing("GJM base pitch not computed")
    lo, hi = float(pair[0]), float(pair[1])
    extreme = lo if abs(lo) >= abs(hi) else hi
    holds = abs(extreme - r.limits["flight_deg"]) <= r.limits["tolerance_deg"]
    return Measured(f"{extreme:+.3f} deg (range {lo:+.3f} to {hi:+.3f})", holds)


def _gjm_hand_hold(r: PaperResult, src: Sources) -> Measured:
    hand = analysis_part(src, "hand_attitude") or {}
    spans = [h for h in hand.get("holds", []) if h.get("span") != "legs"]
    values = [number(h.get("hand_change_max_deg")) for h in spans]
    if not spans or any(v is None for v in values):
        return missing("GJM hand attitude not computed")
    worst = max(v for v in values if v is not None)
    text = ", ".join(f"{h.get('span')} {v:.3f}" for h, v in zip(spans, values, strict=True))
    return Measured(text + " deg", worst <= r.limits["max_deg"])


def _variants_start(r: PaperResult, src: Sources) -> Measured:
    v = variants_of(src)
    starts = {k: number(x.get("start_pitch_deg")) for k, x in v.items()}
    if set(starts) < {"(a)", "(b)", "(c)"} or None in starts.values():
        return missing("variants (a), (b), (c) not all analysed from their start")
    worst = max(abs(float(x or 0.0)) for x in starts.values())
    text = ", ".join(f"{k} {float(x or 0.0):+.3f}" for k, x in sorted(starts.items()))
    return Measured(f"start pitch {text} deg", worst <= r.limits["max_deg"])


def _feedback_range(r: PaperResult, src: Sources) -> Measured:
    a = variants_of(src).get("(a)")
    lo = None if a is None else number(a.get("pitch_min_deg"))
    hi = None if a is None else number(a.get("pitch_max_deg"))
    if lo is None or hi is None:
        return missing("variant (a) not analysed")
    tol = r.limits["tolerance_deg"]
    holds = abs(lo - r.limits["min_deg"]) <= tol and abs(hi - r.limits["max_deg"]) <= tol
    return Measured(f"{lo:+.2f} to {hi:+.2f} deg", holds)


def _feedforward(r: PaperResult, src: Sources) -> Measured:
    v = variants_of(src)
    b = v.get("(b)")
    dip = None if b is None else number(b.get("first_dip_deg"))
    peaks = {k: number(x.get("pitch_max_deg")) for k, x in v.items()}
    if dip is None or peaks.get("(b)") is None or len(peaks) < 3 or None in peaks.values():
        return missing("variants (a), (b), (c) not all analysed")
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
    v = variants_of(src)
    values = {k: number(x.get(key)) for k, x in v.items()}
    if set(values) < {"(a)", "(b)", "(c)"}:
        return None
    return {k: float(x) for k, x in values.items() if x is not None}, values


def _offset_range(r: PaperResult, src: Sources) -> Measured:
    found = _offset_numbers(src, "pitch_range_deg")
    if found is None or None in found[1].values():
        return missing("variants (a), (b), (c) not all analysed")
    rng = found[0]
    smallest = min(rng, key=lambda k: rng[k]) == "(c)" and list(rng.values()).count(rng["(c)"]) == 1
    return Measured(f"range {ordered(rng, 'deg')}", smallest)


def _offset_settling(r: PaperResult, src: Sources) -> Measured:
    settles = settling_values(variants_of(src))
    if set(settles) < {"(a)", "(b)", "(c)"}:
        return missing("variants (a), (b), (c) not all analysed")
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
        with_gg = number((seg.get("with_gg") or {}).get("rms_residual_angle_deg"))
        without = number((seg.get("without_gg") or {}).get("rms_residual_angle_deg"))
        if with_gg is None or without is None:
            return missing("a re-simulated segment lacks its residual")
        pairs.append((seg.get("t_start_s"), with_gg, without))
    if not pairs:
        return missing("gravity-gradient re-simulation absent or failed")
    holds = all(w > r.limits["min_improvement"] * g for _, g, w in pairs)
    text = "; ".join(f"from {t} s: {g:.4f} with, {w:.4f} deg without" for t, g, w in pairs)
    return Measured("RMS residual " + text, holds)


def _identification(r: PaperResult, src: Sources) -> Measured:
    doc = src.identification
    if doc is None:
        return missing("inertia identification absent or failed")
    est, err = doc.get("parameters_kgm2") or {}, doc.get("standard_error_kgm2") or {}
    ref = (doc.get("reference") or {}).get("parameters_kgm2") or {}
    worst: tuple[float, str] | None = None
    for name, truth in ref.items():
        value, sigma = number(est.get(name)), number(err.get(name))
        if value is None or not sigma or number(truth) is None:
            return missing(f"{name} not identified")
        ratio = abs(value - float(truth)) / sigma
        worst = max(worst or (ratio, name), (ratio, name))
    if worst is None:
        return missing("no reference inertia")
    name = worst[1]
    text = (
        f"largest difference {worst[0]:.1f} standard errors ({name} {est[name]:.1f} +- "
        f"{err[name]:.1f} against {ref[name]})"
    )
    return Measured(text, worst[0] <= r.limits["max_sigma"])


def _endpoint(r: PaperResult, src: Sources) -> Measured:
    end = analysis_part(src, "endpoint") or {}
    angle, joints = (
        number(end.get("attitude_error_angle_deg")),
        number(end.get("max_joint_error_deg")),
    )
    if angle is None or joints is None:
        return missing("non-holonomic end point not analysed")
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
