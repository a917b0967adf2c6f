"""A pass's stored documents as the paper comparisons read them (:mod:`telemetry.analysis.
paper`): :class:`Sources` holds each stored analysis's ``result`` numbers; the readers below
take the parts the comparisons need, a number only when it is one and finite (anything else
reads as not measured); :func:`ordered` writes labels by increasing value.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

__all__ = [
    "Doc",
    "Sources",
    "analysis_part",
    "legs_fast_slow",
    "motions_of",
    "number",
    "ordered",
    "settling_values",
    "variants_of",
]

Doc = Mapping[str, Any]


@dataclass(frozen=True)
class Sources:
    """The ``result`` numbers of each stored analysis; ``None`` when absent or failed."""

    pass_analysis: Doc | None = None
    identification: Doc | None = None
    resim: Doc | None = None


def number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value) if math.isfinite(value) else None


def analysis_part(src: Sources, key: str) -> Doc | None:
    doc = src.pass_analysis
    value = None if doc is None else doc.get(key)
    return value if isinstance(value, Mapping) else None


def motions_of(src: Sources, kind: str) -> list[Doc]:
    reaction = analysis_part(src, "reaction") or {}
    return [m for m in reaction.get("motions", []) if m.get("kind") == kind]


def variants_of(src: Sources) -> dict[str, Doc]:
    plane = analysis_part(src, "phase_plane") or {}
    return {str(v.get("label")): v for v in plane.get("variants", [])}


def settling_values(variants: Mapping[str, Doc]) -> dict[str, float | None]:
    """Each variant's settling time as ``VariantPhasePlane.settling_rank_s`` gives it, read
    from a stored document: ``inf`` for one flown whole that had not settled by its window's
    end, ``None`` where it was not measured."""
    out: dict[str, float | None] = {}
    for k, v in variants.items():
        value = number(v.get("settling_time_s"))
        flown = (number(v.get("frames", 1)) or 0.0) > 0 and not v.get("note")
        out[k] = math.inf if value is None and v.get("settled") is False and flown else value
    return out


def legs_fast_slow(src: Sources) -> tuple[Doc, Doc] | None:
    legs = [m for m in motions_of(src, "reactionless") if number(m.get("peak_hand_speed_mps"))]
    if len(legs) < 2:
        return None
    legs.sort(key=lambda m: -float(m["peak_hand_speed_mps"]))
    return legs[0], legs[-1]


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
