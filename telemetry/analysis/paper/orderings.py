"""The orderings of experiments 1 and 3 on a pass (which leg, which variant is larger or
faster), beside the flight's, for the report's tables and the figures
(:mod:`telemetry.analysis.paper`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from telemetry.analysis.paper.documents import (
    Doc,
    Sources,
    legs_fast_slow,
    motions_of,
    number,
    ordered,
    settling_values,
)

__all__ = [
    "FLIGHT_FASTEST_SETTLING",
    "FLIGHT_LARGEST_PEAK",
    "FLIGHT_RANGE_ORDER",
    "REACTION_MEASURES",
    "OrderingRow",
    "phase_plane_ordering",
    "reaction_ordering",
]

#: Experiment 3 in flight (paper 3.5, Fig. 9): pitch range (c) < (a) < (b); (c) settles
#: fastest; (b) overshoots most.
FLIGHT_RANGE_ORDER = ("(c)", "(a)", "(b)")
FLIGHT_FASTEST_SETTLING = "(c)"
FLIGHT_LARGEST_PEAK = "(b)"


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
        return {k: number(v.get(key)) for k, v in variants.items()}

    complete = {"(a)", "(b)", "(c)"} <= set(variants)
    rng, settle, peak = values("pitch_range_deg"), settling_values(variants), values("peak_deg")
    for k, v in variants.items():  # documents stored before peak_deg had pitch_max_deg only
        if peak.get(k) is None:
            peak[k] = number(v.get("pitch_max_deg"))

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
    ptp = motions_of(src, "ptp")
    pair = legs_fast_slow(src)
    rows: list[list[Any]] = []
    for label, key, unit in REACTION_MEASURES:
        p = number(ptp[0].get(key)) if ptp else None
        f = None if pair is None else number(pair[0].get(key))
        s = None if pair is None else number(pair[1].get(key))
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
