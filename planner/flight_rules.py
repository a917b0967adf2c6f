"""Flight rules: a plan may leave the ground only when its predicted motion keeps every rule.

The paper's arm motions were "verified collision-free by simulator before uplink" (3.1).
:class:`FlightRules` is a robot description's ``[flight_rules]`` (docs/robots.md);
:func:`planner.flight_check.check_plan` evaluates a plan against them and gives a
:class:`FlightRulesReport`: one :class:`RuleRow` per rule (the worst value, the limit, the
verdict and when the worst value happens; for clearance, the two bodies and their nearest
points) and the clearance over time (:class:`ClearanceTrace`). A report travels with its
plan as a dict (``to_dict``, ``from_dict``); :func:`fits_pass_row` is the one row that needs
no motion (the ground re-checks it against the pass a plan is scheduled in).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from planner.attitude_control import AcsMode
from planner.errors import InvalidInput

__all__ = [
    "RULE_NAMES",
    "ClearanceTrace",
    "FlightRules",
    "FlightRulesReport",
    "RuleRow",
    "fits_pass_row",
]


#: Every rule a report may hold, in the order of its rows.
RULE_NAMES = (
    "clearance",
    "self_clearance",
    "attitude_excursion_feedback",
    "attitude_excursion_free_drift",
    "wheel_momentum",
    "joint_limit_margin",
    "hand_speed",
    "fits_pass",
)


@dataclass(frozen=True)
class FlightRules:
    """A description's ``[flight_rules]`` (docs/robots.md); SPEC 8's numbers by default."""

    min_clearance_m: float = 0.10
    max_attitude_excursion_deg: Mapping[str, float] = field(
        default_factory=lambda: {"feedback": 2.0, "free_drift": 2.0}
    )
    max_wheel_momentum_fraction: float = 0.8
    joint_limit_margin_deg: float = 2.0
    max_hand_speed_mps: float = 0.10
    pass_window_s: float | None = None

    def __post_init__(self) -> None:
        for name in ("min_clearance_m", "max_wheel_momentum_fraction", "max_hand_speed_mps"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise InvalidInput(f"flight rule {name} must be > 0, got {value!r}")
        if not (math.isfinite(self.joint_limit_margin_deg) and self.joint_limit_margin_deg >= 0):
            raise InvalidInput(
                "flight rule joint_limit_margin_deg must be >= 0, got "
                f"{self.joint_limit_margin_deg!r}"
            )
        modes = {m.value for m in AcsMode}
        if set(self.max_attitude_excursion_deg) != modes:
            raise InvalidInput(
                "flight rule max_attitude_excursion_deg needs a limit for each mode "
                f"{sorted(modes)}, got {sorted(self.max_attitude_excursion_deg)}"
            )
        for mode, value in self.max_attitude_excursion_deg.items():
            if not (math.isfinite(value) and value > 0.0):
                raise InvalidInput(
                    f"flight rule max_attitude_excursion_deg.{mode} must be > 0, got {value!r}"
                )
        if self.pass_window_s is not None and not (
            math.isfinite(self.pass_window_s) and self.pass_window_s > 0.0
        ):
            raise InvalidInput(f"flight rule pass_window_s must be > 0, got {self.pass_window_s!r}")

    def to_dict(self) -> dict[str, Any]:
        return {
            "min_clearance_m": self.min_clearance_m,
            "max_attitude_excursion_deg": dict(self.max_attitude_excursion_deg),
            "max_wheel_momentum_fraction": self.max_wheel_momentum_fraction,
            "joint_limit_margin_deg": self.joint_limit_margin_deg,
            "max_hand_speed_mps": self.max_hand_speed_mps,
            "pass_window_s": self.pass_window_s,
        }


@dataclass(frozen=True)
class RuleRow:
    """One rule on one plan. ``bound`` "min": the value must be at least ``limit``; "max": at
    most. ``t_s``: when the worst value happens (s from the plan's start; None where the rule
    has no time). Clearance only: ``bodies`` and the nearest ``points_robot_m`` (robot frame:
    origin at joint 1, base axes)."""

    rule: str
    value: float
    limit: float
    unit: str
    bound: str
    passed: bool
    t_s: float | None = None
    bodies: tuple[str, str] | None = None
    points_robot_m: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    detail: str = ""

    @property
    def verdict(self) -> str:
        return "pass" if self.passed else "fail"

    def to_dict(self) -> dict[str, Any]:
        return {
            "rule": self.rule,
            "value": self.value,
            "limit": self.limit,
            "unit": self.unit,
            "bound": self.bound,
            "verdict": self.verdict,
            "t_s": self.t_s,
            "bodies": None if self.bodies is None else list(self.bodies),
            "points_robot_m": None
            if self.points_robot_m is None
            else [list(p) for p in self.points_robot_m],
            "detail": self.detail,
        }

    @classmethod
    def from_dict(cls, doc: Mapping[str, Any]) -> RuleRow:
        bodies = doc.get("bodies")
        points = doc.get("points_robot_m")
        return cls(
            rule=str(doc["rule"]),
            value=float(doc["value"]),
            limit=float(doc["limit"]),
            unit=str(doc["unit"]),
            bound=str(doc["bound"]),
            passed=doc["verdict"] == "pass",
            t_s=None if doc.get("t_s") is None else float(doc["t_s"]),
            bodies=None if bodies is None else (str(bodies[0]), str(bodies[1])),
            points_robot_m=None
            if points is None
            else (
                (float(points[0][0]), float(points[0][1]), float(points[0][2])),
                (float(points[1][0]), float(points[1][1]), float(points[1][2])),
            ),
            detail=str(doc.get("detail", "")),
        )

    def describe(self) -> str:
        """One line for an error message."""
        where = "" if self.t_s is None else f" at t = {self.t_s:.2f} s"
        pair = "" if self.bodies is None else f" between {self.bodies[0]} and {self.bodies[1]}"
        relation = ">=" if self.bound == "min" else "<="
        return (
            f"{self.rule}: {self.value:.4g} {self.unit}{pair}{where}, must be {relation} "
            f"{self.limit:.4g} {self.unit}"
        )


@dataclass(frozen=True)
class ClearanceTrace:
    """The smallest clearance over every checked pair, per command period: ``min_m[k]`` is
    the least over the fine samples in ``(t_s[k-1], t_s[k]]`` (``t_s[0]``: that instant)."""

    t_s: tuple[float, ...]
    min_m: tuple[float, ...]

    def to_dict(self) -> dict[str, Any]:
        return {"t_s": list(self.t_s), "min_m": list(self.min_m)}

    @classmethod
    def from_dict(cls, doc: Mapping[str, Any]) -> ClearanceTrace:
        return cls(
            t_s=tuple(float(v) for v in doc["t_s"]), min_m=tuple(float(v) for v in doc["min_m"])
        )


@dataclass(frozen=True)
class FlightRulesReport:
    """Every rule's row on one plan, how it was checked, and the clearance over time."""

    rows: tuple[RuleRow, ...]
    step_s: float
    n_samples: int
    n_pairs: int
    n_queries: int
    clearance: ClearanceTrace
    robot: str = ""

    @property
    def passed(self) -> bool:
        return all(row.passed for row in self.rows)

    @property
    def failing(self) -> tuple[RuleRow, ...]:
        return tuple(row for row in self.rows if not row.passed)

    def row(self, rule: str) -> RuleRow:
        for row in self.rows:
            if row.rule == rule:
                return row
        raise KeyError(rule)

    def with_row(self, new: RuleRow) -> FlightRulesReport:
        """This report with ``new`` in place of the row of its rule (added when absent)."""
        rows = [new if row.rule == new.rule else row for row in self.rows]
        if new.rule not in {row.rule for row in self.rows}:
            rows.append(new)
        order = {name: i for i, name in enumerate(RULE_NAMES)}
        rows.sort(key=lambda r: order.get(r.rule, len(order)))
        return FlightRulesReport(
            tuple(rows),
            self.step_s,
            self.n_samples,
            self.n_pairs,
            self.n_queries,
            self.clearance,
            self.robot,
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "passed": self.passed,
            "robot": self.robot,
            "rows": [row.to_dict() for row in self.rows],
            "step_s": self.step_s,
            "n_samples": self.n_samples,
            "n_pairs": self.n_pairs,
            "n_queries": self.n_queries,
            "clearance": self.clearance.to_dict(),
        }

    @classmethod
    def from_dict(cls, doc: Mapping[str, Any]) -> FlightRulesReport:
        try:
            return cls(
                rows=tuple(RuleRow.from_dict(r) for r in doc["rows"]),
                step_s=float(doc["step_s"]),
                n_samples=int(doc["n_samples"]),
                n_pairs=int(doc["n_pairs"]),
                n_queries=int(doc["n_queries"]),
                clearance=ClearanceTrace.from_dict(doc["clearance"]),
                robot=str(doc.get("robot", "")),
            )
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise InvalidInput(f"malformed flight-rules report: {exc!r}") from exc


def fits_pass_row(duration_s: float, window_s: float) -> RuleRow:
    """The plan's duration against the window of its pass."""
    return RuleRow(
        rule="fits_pass",
        value=duration_s,
        limit=window_s,
        unit="s",
        bound="max",
        passed=duration_s <= window_s,
        detail="duration within the window",
    )
