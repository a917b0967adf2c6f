"""Live limits: the monitored quantities and their severity bands.

What the ground watches on every frame and the vehicle on every control tick
(docs/robots.md, "Limits"; SPEC 8, "live limits"): a catalogue of quantities
(:data:`QUANTITIES`, names fixed), each with bands at Yamcs's five severities
(:class:`Severity`: watch < warning < distress < critical < severe; COSMOS's yellow is about
warning, its red about critical). A quantity's :class:`Bands` give a threshold for any
subset of the levels, strictly ordered: increasing with severity for a "high" quantity (in a
band when the value is at or above its threshold), decreasing for a "low" one (at or
below). A red band (critical, severe) of a *safing* quantity makes the vehicle safe itself.

:class:`Limits` is a robot's bands for every quantity: a description's ``[limits]`` table
(:meth:`Limits.from_table`, which refuses bad tables with :class:`~planner.errors.
InvalidInput`) over the built-in :data:`DEFAULT_LIMITS` (derived for ETS-VII from its
nominal passes: ``hikoboshi model limits --fly``). The live clearance, the one quantity
that needs the robot's geometry, is measured by :class:`planner.clearance_watch.
ClearanceWatch`.

Pure: reads no file, imports nothing of the telemetry, the spacecraft or the server.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum
from types import MappingProxyType
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from planner.errors import InvalidInput

__all__ = [
    "DEFAULT_LIMITS",
    "MAX_PERSISTENCE",
    "QUANTITIES",
    "RED",
    "SEVERITIES",
    "SEVERITY_RANK",
    "Bands",
    "Limits",
    "QuantitySpec",
    "Severity",
    "channel_names",
]

Array = NDArray[np.float64]


class Severity(StrEnum):
    """Yamcs's five alarm levels, least severe first."""

    WATCH = "watch"
    WARNING = "warning"
    DISTRESS = "distress"
    CRITICAL = "critical"
    SEVERE = "severe"


#: The levels in order of severity.
SEVERITIES: tuple[Severity, ...] = tuple(Severity)
SEVERITY_RANK: Mapping[Severity, int] = MappingProxyType(
    {severity: rank for rank, severity in enumerate(SEVERITIES, start=1)}
)
#: The lowest red level: a band at or above it of a safing quantity safes the vehicle.
RED = Severity.CRITICAL


@dataclass(frozen=True)
class QuantitySpec:
    """One monitored quantity: ``direction`` "high" (in a band at or above a threshold) or
    "low" (at or below); ``per``: one channel per base axis, wheel, joint, or one alone;
    ``source``: computed from each frame, or from the link by the ground's timer;
    ``safing``: its red limit makes the vehicle safe itself."""

    name: str
    label: str
    unit: str
    direction: Literal["high", "low"]
    per: Literal["axis", "wheel", "joint", "none"]
    source: Literal["frame", "link"]
    safing: bool


def _spec(
    name: str,
    label: str,
    unit: str,
    direction: Literal["high", "low"],
    per: Literal["axis", "wheel", "joint", "none"],
    source: Literal["frame", "link"] = "frame",
    safing: bool = False,
) -> tuple[str, QuantitySpec]:
    return name, QuantitySpec(name, label, unit, direction, per, source, safing)


#: Every monitored quantity, by name (docs/robots.md, "Limits", says what each measures).
QUANTITIES: Mapping[str, QuantitySpec] = MappingProxyType(
    dict(
        [
            _spec("attitude_error_deg", "Attitude error", "deg", "high", "axis", safing=True),
            _spec("body_rate_degps", "Body rate", "deg/s", "high", "none"),
            _spec(
                "wheel_momentum_fraction",
                "Wheel momentum",
                "of limit",
                "high",
                "wheel",
                safing=True,
            ),
            _spec("wheel_speed_rpm", "Wheel speed", "rpm", "high", "wheel"),
            _spec(
                "joint_tracking_error_deg",
                "Joint tracking error",
                "deg",
                "high",
                "joint",
                safing=True,
            ),
            _spec("joint_limit_distance_deg", "Joint limit distance", "deg", "low", "joint"),
            _spec("clearance_m", "Clearance", "m", "low", "none", safing=True),
            _spec("schedule_occupancy", "Schedule occupancy", "of capacity", "high", "none"),
            _spec("frames_behind", "Frames behind", "frames", "high", "none", source="link"),
            _spec("frame_age_s", "Frame age", "s", "high", "none", source="link"),
        ]
    )
)

_AXES = ("x", "y", "z")


def channel_names(quantity: str, n_joints: int, n_wheels: int) -> tuple[str, ...]:
    """The channels of ``quantity`` for a robot: ``("x", "y", "z")``, ``("joint1", ...)``,
    ``("wheel1", ...)``, or ``("",)`` for a scalar."""
    spec = _quantity(quantity, "channel_names")
    if spec.per == "axis":
        return _AXES
    if spec.per == "joint":
        return tuple(f"joint{i}" for i in range(1, n_joints + 1))
    if spec.per == "wheel":
        return tuple(f"wheel{i}" for i in range(1, n_wheels + 1))
    return ("",)


def _quantity(name: str, where: str) -> QuantitySpec:
    try:
        return QUANTITIES[name]
    except KeyError:
        raise InvalidInput(
            f"{where}: unknown quantity {name!r}; known: {', '.join(QUANTITIES)}"
        ) from None


@dataclass(frozen=True)
class Bands:
    """One quantity's thresholds, least severe first (at least one, strictly ordered:
    increasing for a "high" quantity, decreasing for a "low" one)."""

    quantity: str
    thresholds: tuple[tuple[Severity, float], ...]

    def __post_init__(self) -> None:
        where = f"limits of {self.quantity!r}"
        spec = _quantity(self.quantity, where)
        if not self.thresholds:
            raise InvalidInput(f"{where}: no band (give at least one of {_levels()})")
        seen: set[Severity] = set()
        ranks = []
        for severity, value in self.thresholds:
            if not isinstance(severity, Severity):
                raise InvalidInput(f"{where}: {severity!r} is not a severity ({_levels()})")
            if severity in seen:
                raise InvalidInput(f"{where}: {severity.value} given twice")
            seen.add(severity)
            ranks.append(SEVERITY_RANK[severity])
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise InvalidInput(f"{where}: {severity.value} must be a number, got {value!r}")
            if not math.isfinite(value):
                raise InvalidInput(f"{where}: {severity.value} must be finite, got {value!r}")
            if spec.direction == "high" and value <= 0.0:
                raise InvalidInput(
                    f"{where}: {severity.value} = {value!r} must be > 0 ({self.quantity} is "
                    "never negative: a threshold at 0 would always fire)"
                )
        if ranks != sorted(ranks):
            raise InvalidInput(f"{where}: bands must be listed least severe first")
        values = [float(v) for _, v in self.thresholds]
        for (lo_sev, lo), (hi_sev, hi) in zip(self.thresholds, self.thresholds[1:], strict=False):
            ordered = hi > lo if spec.direction == "high" else hi < lo
            if not ordered:
                relation = "above" if spec.direction == "high" else "below"
                raise InvalidInput(
                    f"{where}: {hi_sev.value} = {hi!r} must be strictly {relation} "
                    f"{lo_sev.value} = {lo!r} ({self.quantity} alarms when "
                    f"{'high' if spec.direction == 'high' else 'low'})"
                )
        object.__setattr__(
            self,
            "thresholds",
            tuple((s, v) for (s, _), v in zip(self.thresholds, values, strict=True)),
        )

    @property
    def spec(self) -> QuantitySpec:
        return QUANTITIES[self.quantity]

    @property
    def direction(self) -> Literal["high", "low"]:
        return QUANTITIES[self.quantity].direction

    def classify(self, value: float) -> Severity | None:
        """The most severe band ``value`` is in, None when within limits (or NaN)."""
        found = None
        if self.direction == "high":
            for severity, threshold in self.thresholds:
                if value >= threshold:
                    found = severity
        else:
            for severity, threshold in self.thresholds:
                if value <= threshold:
                    found = severity
        return found

    def classify_array(self, values: Array) -> NDArray[np.int8]:
        """:meth:`classify` of every element as a rank (0: within limits, 1 watch .. 5
        severe), any shape; NaN is within limits."""
        v = np.asarray(values, dtype=np.float64)
        out = np.zeros(v.shape, dtype=np.int8)
        with np.errstate(invalid="ignore"):
            for severity, threshold in self.thresholds:
                hit = v >= threshold if self.direction == "high" else v <= threshold
                out[hit] = SEVERITY_RANK[severity]
        return out

    def threshold(self, severity: Severity) -> float | None:
        for s, value in self.thresholds:
            if s is severity:
                return value
        return None

    def red(self) -> tuple[Severity, float] | None:
        """The lowest red band (critical, else severe), None when it has none."""
        for s, value in self.thresholds:
            if SEVERITY_RANK[s] >= SEVERITY_RANK[RED]:
                return s, value
        return None

    @property
    def least(self) -> float:
        """The least severe band's threshold (the first to be crossed)."""
        return self.thresholds[0][1]

    def to_dict(self) -> dict[str, float]:
        return {s.value: v for s, v in self.thresholds}


def _levels() -> str:
    return ", ".join(s.value for s in SEVERITIES)


#: The most consecutive samples a persistence may ask for (at 10 Hz, 100 s).
MAX_PERSISTENCE = 1000


@dataclass(frozen=True)
class Limits:
    """A robot's bands, by quantity name (every quantity of :data:`QUANTITIES` when built
    by :meth:`from_table`), and its ``persistence`` (as COSMOS's limits have one): a channel
    must be in a band for this many consecutive samples (frames, or the link's checks)
    before its alarm is raised; 1, the default, raises on the first."""

    bands: Mapping[str, Bands]
    persistence: int = 1

    def __post_init__(self) -> None:
        n = self.persistence
        if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= MAX_PERSISTENCE:
            raise InvalidInput(
                f"[limits].persistence: must be a whole number of samples from 1 to "
                f"{MAX_PERSISTENCE}, got {n!r}"
            )
        for name, bands in self.bands.items():
            _quantity(name, "limits")
            if bands.quantity != name:
                raise InvalidInput(f"limits: bands of {bands.quantity!r} filed as {name!r}")
        object.__setattr__(self, "bands", MappingProxyType(dict(self.bands)))

    @classmethod
    def from_table(cls, table: Mapping[str, object], *, where: str = "[limits]") -> Limits:
        """A ``[limits]`` table, ``{quantity: {severity: threshold}}`` and an optional
        ``persistence = N``, over :data:`DEFAULT_LIMITS` (a quantity left out takes its
        default). Refused with :class:`InvalidInput` naming the bad key and value."""
        if not isinstance(table, Mapping):
            raise InvalidInput(f"{where}: must be a table, got {table!r}")
        quantities = {k: v for k, v in table.items() if k != "persistence"}
        persistence = table.get("persistence", 1)
        bands = {**DEFAULT_LIMITS.bands, **_bands_from_table(quantities, where)}
        return cls(bands, persistence)  # type: ignore[arg-type]  # checked by __post_init__

    def to_table(self) -> dict[str, dict[str, float] | int]:
        out: dict[str, dict[str, float] | int] = {
            name: bands.to_dict() for name, bands in self.bands.items()
        }
        if self.persistence != 1:
            out["persistence"] = self.persistence
        return out

    def safing_limits(self) -> dict[str, float]:
        """The red threshold of each safing quantity that has one."""
        out = {}
        for name, bands in self.bands.items():
            red = bands.red()
            if bands.spec.safing and red is not None:
                out[name] = red[1]
        return out

    def __getitem__(self, quantity: str) -> Bands:
        return self.bands[quantity]

    def get(self, quantity: str) -> Bands | None:
        return self.bands.get(quantity)


def _bands_from_table(table: Mapping[str, object], where: str) -> dict[str, Bands]:
    if not isinstance(table, Mapping):
        raise InvalidInput(f"{where}: must be a table, got {table!r}")
    out = {}
    for name, item in table.items():
        element = f"{where[:-1]}.{name}]" if where.startswith("[") else f"{where}.{name}"
        if name not in QUANTITIES:
            raise InvalidInput(
                f"{element}: unknown quantity {name!r}; known: {', '.join(QUANTITIES)}"
            )
        if not isinstance(item, Mapping):
            raise InvalidInput(f"{element}: must be a table of severity = threshold, got {item!r}")
        if not item:
            raise InvalidInput(f"{element}: empty; give at least one of {_levels()}")
        unknown = sorted(str(k) for k in item if k not in {s.value for s in SEVERITIES})
        if unknown:
            raise InvalidInput(
                f"{element}: unknown severity {', '.join(unknown)}; known: {_levels()} "
                "(COSMOS's yellow is about warning, its red about critical)"
            )
        pairs = tuple((s, item[s.value]) for s in SEVERITIES if s.value in item)
        try:
            out[name] = Bands(name, pairs)
        except InvalidInput as exc:
            message = str(exc)
            raise InvalidInput(f"{element}: {message.split(': ', 1)[-1]}") from None
    return out


#: The built-in bands: ETS-VII's (examples/robots/ets7/ets7.toml gives the same numbers with
#: how each was derived; docs/robots.md, "Limits"). ``hikoboshi model limits --fly``
#: measures the nominal worst they keep clear of.
DEFAULT_LIMITS: Limits = Limits(
    _bands_from_table(
        {
            "attitude_error_deg": {"watch": 1.25, "warning": 2.0, "critical": 3.0},
            "body_rate_degps": {"watch": 0.15, "warning": 0.3, "distress": 0.6},
            "wheel_momentum_fraction": {
                "watch": 0.25,
                "warning": 0.5,
                "distress": 0.8,
                "critical": 0.9,
            },
            "wheel_speed_rpm": {"watch": 275.0, "warning": 640.0, "distress": 1020.0},
            "joint_tracking_error_deg": {"watch": 2.25, "warning": 2.6, "critical": 3.0},
            "joint_limit_distance_deg": {"watch": 35.0, "warning": 10.0, "distress": 2.0},
            "clearance_m": {"watch": 0.085, "warning": 0.06, "critical": 0.03},
            "schedule_occupancy": {"watch": 0.7, "warning": 0.85, "distress": 0.95},
            "frames_behind": {"watch": 100.0, "warning": 3000.0, "distress": 9000.0},
            "frame_age_s": {"watch": 10.0, "warning": 180.0, "distress": 600.0},
        },
        "DEFAULT_LIMITS",
    )
)
