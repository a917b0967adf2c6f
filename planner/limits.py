"""Live limits: the monitored quantities, their severity bands, and the live clearance.

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
nominal passes: ``hikoboshi model limits --fly``).

:class:`ClearanceWatch` is the live hand clearance from measured joints with the flight
rules' collision checker (:mod:`planner.collision`), asking coal only when the answer could
matter: a pair's distance shrinks by no more than its bodies' relative path,
``d_p(q') >= d_p(q) - sum_k C[p, k] |q'_k - q_k|`` (``C[p, k]``: the reach of joint k to the
moving body of pair p, :func:`planner.collision.reach_bounds`), so a pair is asked again only
when that lower bound is at or below the watched threshold, and every pair after
``max_age`` answers from the bounds. A batch is first tried against one bound, the last
answer less ``max_k C[:, k] . |q - q_last|`` (every pair was at least the last answer
there): a still arm costs three numpy operations a batch. The value returned is exact
whenever it is at or below the threshold, and otherwise an honest lower bound above it: the
band it falls in is always the exact clearance's band.

Pure: reads no file, imports nothing of the telemetry, the spacecraft or the server.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from enum import StrEnum
from types import MappingProxyType
from typing import Any, Literal, Protocol

import numpy as np
from numpy.typing import NDArray

from planner.collision import (
    CollisionModel,
    CollisionShape,
    check_collision_model,
    reach_bounds,
)
from planner.errors import InvalidInput
from planner.model import RobotModel

__all__ = [
    "DEFAULT_LIMITS",
    "QUANTITIES",
    "RED",
    "SEVERITIES",
    "SEVERITY_RANK",
    "Bands",
    "ClearanceWatch",
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


@dataclass(frozen=True)
class Limits:
    """A robot's bands, by quantity name (every quantity of :data:`QUANTITIES` when built
    by :meth:`from_table`)."""

    bands: Mapping[str, Bands]

    def __post_init__(self) -> None:
        for name, bands in self.bands.items():
            _quantity(name, "limits")
            if bands.quantity != name:
                raise InvalidInput(f"limits: bands of {bands.quantity!r} filed as {name!r}")
        object.__setattr__(self, "bands", MappingProxyType(dict(self.bands)))

    @classmethod
    def from_table(cls, table: Mapping[str, object], *, where: str = "[limits]") -> Limits:
        """A ``[limits]`` table, ``{quantity: {severity: threshold}}``, over
        :data:`DEFAULT_LIMITS` (a quantity left out takes its default). Refused with
        :class:`InvalidInput` naming the bad key and value."""
        return cls({**DEFAULT_LIMITS.bands, **_bands_from_table(table, where)})

    def to_table(self) -> dict[str, dict[str, float]]:
        return {name: bands.to_dict() for name, bands in self.bands.items()}

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


class _HasCollision(Protocol):
    @property
    def model(self) -> RobotModel: ...
    @property
    def collision(self) -> CollisionModel | None: ...


class ClearanceWatch:
    """Live clearance from measured joints with the flight-rules checker (coal), evaluated
    only when needed (the module docstring): a pair is asked again when its lower bound
    ``d - C |dq|`` is at or below ``threshold_m`` (the largest clearance threshold watched;
    ``inf``: every pair at every call), and every pair after ``max_age`` answers from the
    bounds.
    ``source``: a robot description (its ``model`` and ``collision``) or a
    ``(model, collision)`` pair. State: the pairs' last exact distances (one watch per
    stream of joints; :meth:`reset` forgets them)."""

    #: rows whose bounds are computed at once between two refreshes (a batch's look-ahead)
    LOOKAHEAD = 16

    def __init__(
        self,
        source: _HasCollision | tuple[RobotModel, CollisionModel],
        threshold_m: float,
        *,
        max_age: int = 600,
    ) -> None:
        maybe: CollisionModel | None
        if isinstance(source, tuple):
            model, maybe = source
            name = ""
        else:
            model, maybe = source.model, source.collision
            name = str(getattr(source, "name", ""))
        self.collision = check_collision_model(maybe, name or "robot")
        self.model = model
        if math.isnan(threshold_m) or threshold_m == -math.inf:
            raise InvalidInput(f"clearance threshold must be a number, got {threshold_m!r}")
        if max_age < 1:
            raise InvalidInput(f"max_age must be >= 1, got {max_age!r}")
        self.threshold_m = float(threshold_m)
        self.max_age = int(max_age)
        self.pairs = self.collision.pairs
        n = model.n_joints
        #: C[p, k] (m/rad): pair p's relative motion per radian of joint k
        self.lever = _pair_levers(self.collision, model, self.pairs)
        self._frame_of = [b.joint for b in self.collision.bodies]
        axes = np.array([link.joint_axis_robot for link in model.links], dtype=np.float64)
        kx = np.zeros((n, 3, 3))
        kx[:, 0, 1], kx[:, 0, 2] = -axes[:, 2], axes[:, 1]
        kx[:, 1, 0], kx[:, 1, 2] = axes[:, 2], -axes[:, 0]
        kx[:, 2, 0], kx[:, 2, 1] = -axes[:, 1], axes[:, 0]
        self._kx, self._kx2 = kx, kx @ kx
        self._points = np.array([link.joint_pos_robot_m for link in model.links])
        self._coal: tuple[Any, list[list[Any]], dict[int, list[Any]]] | None = None
        self._distance: Array | None = None  # (P,) exact at _at
        self._lever_max = self.lever.max(axis=0) if len(self.pairs) else np.zeros(n)
        self._last_joints = np.zeros(n)  # the last row answered, and its answer
        self._last_m = math.nan
        self._at: Array = np.zeros((len(self.pairs), n))
        self._age = 0
        #: calls answered (joint vectors), refreshes (calls that asked coal), pairs asked
        self.calls = 0
        self.refreshes = 0
        self.pair_queries = 0

    def reset(self) -> None:
        """Forget the last exact distances (the next call asks every pair)."""
        self._distance = None
        self._age = 0
        self._last_m = math.nan

    def pair_distances_m(self, joints_rad: Array) -> Array:
        """Every checked pair's exact distance at ``joints_rad`` (``pairs`` order; no
        skipping, no state)."""
        R, t = self._poses(self._row(joints_rad))
        return self._exact(R, t, range(len(self.pairs)))

    def exact_m(self, joints_rad: Array) -> float:
        """The exact least distance over every checked pair at ``joints_rad`` (what
        :meth:`clearance_m` is tested against)."""
        return float(np.min(self.pair_distances_m(joints_rad)))

    def clearance_m(self, joints_rad: Array) -> float:
        """The clearance at ``joints_rad``: exact when at or below the threshold, else a
        lower bound of it above the threshold (NaN for non-finite joints)."""
        return float(self.clearances_m(self._row(joints_rad)[None, :])[0])

    def clearances_m(self, joints_rad: Array) -> Array:
        """:meth:`clearance_m` of each row of ``joints_rad`` ``(m, n)``, in order (the
        bounds of up to :attr:`LOOKAHEAD` rows at once)."""
        q = np.atleast_2d(np.asarray(joints_rad, dtype=np.float64))
        m = q.shape[0]
        if q.shape[1] != self.model.n_joints:
            raise InvalidInput(
                f"joints have {q.shape[1]} values; the robot has {self.model.n_joints} joints"
            )
        if self._distance is not None and m <= self.max_age - self._age:
            # The common case in three operations: every pair's distance at q is at least
            # its distance at the last answered joints q_g less lever_max |q - q_g|, and
            # the last answer was at most the least of them.
            bound = self._last_m - np.abs(q - self._last_joints) @ self._lever_max
            if np.all(bound > self.threshold_m):  # False for NaN
                self.calls += m
                self._age += m
                out: Array = bound
                return out
        out = np.full(m, math.nan)
        finite = np.all(np.isfinite(q), axis=1)
        rows = np.flatnonzero(finite)
        self.calls += int(rows.size)
        i = 0
        while i < rows.size:
            if self._distance is None or self._age >= self.max_age:
                stale: NDArray[np.intp] | None = None
                first = 0
            else:
                block = rows[i : i + min(self.LOOKAHEAD, self.max_age - self._age)]
                dq = np.abs(q[block][:, None, :] - self._at[None, :, :])
                bound = self._distance[None, :] - np.einsum("rpk,pk->rp", dq, self.lever)
                low = bound <= self.threshold_m
                hit = np.flatnonzero(low.any(axis=1))
                first = int(hit[0]) if hit.size else block.size
                out[block[:first]] = bound[:first].min(axis=1)
                self._age += first
                i += first
                if first == block.size:
                    continue
                stale = np.flatnonzero(low[first])
            row = rows[i]
            R, t = self._poses(q[row])
            if stale is None:
                self._distance = self._exact(R, t, range(len(self.pairs)))
                self._at[:] = q[row]
                self._age = 0
                out[row] = float(np.min(self._distance))
            else:
                assert self._distance is not None
                fresh = self._exact(R, t, stale)
                self._distance[stale] = fresh
                self._at[stale] = q[row]
                self._age += 1
                rest = bound[first].copy()
                rest[stale] = fresh
                out[row] = float(np.min(rest))
            self.refreshes += 1
            i += 1
        if rows.size:
            self._last_joints = q[rows[-1]].copy()
            self._last_m = float(out[rows[-1]])
        return out

    def _row(self, joints_rad: Array) -> Array:
        q = np.asarray(joints_rad, dtype=np.float64).reshape(-1)
        if q.shape[0] != self.model.n_joints:
            raise InvalidInput(
                f"joints have {q.shape[0]} values; the robot has {self.model.n_joints} joints"
            )
        return q

    def _poses(self, q: Array) -> tuple[Array, Array]:
        """:func:`planner.collision.body_poses` at one joint vector ``q`` ``(n,)``: each
        joint's moving frame ``(n + 1, 3, 3)``, ``(n + 1, 3)`` (the joints' skew matrices
        kept from the constructor; every joint's rotation at once, then the chain)."""
        n = q.shape[0]
        s = np.sin(q)[:, None, None]
        c = (1.0 - np.cos(q))[:, None, None]
        rots = np.eye(3) + s * self._kx + c * self._kx2
        offsets = self._points - np.einsum("jab,jb->ja", rots, self._points)
        R = np.empty((n + 1, 3, 3))
        t = np.empty((n + 1, 3))
        R[0] = np.eye(3)
        t[0] = 0.0
        for j in range(n):
            t[j + 1] = R[j] @ offsets[j] + t[j]
            R[j + 1] = R[j] @ rots[j]
        return R, t

    def _exact(self, R: Array, t: Array, which: Iterable[int] | NDArray[np.intp]) -> Array:
        """Each pair's exact distance with the body frames at ``(R, t)`` (one sample)."""
        import coal  # imported where a distance is asked for, not with the planner

        if self._coal is None:
            request = coal.DistanceRequest()
            request.enable_signed_distance = True
            request.rel_err = 0.0
            request.abs_err = 0.0
            geometries = [[s.geometry() for s in b.shapes] for b in self.collision.bodies]
            fixed = {
                b: [_transform(coal, np.eye(3), np.zeros(3), s) for s in body.shapes]
                for b, body in enumerate(self.collision.bodies)
                if body.joint == 0
            }
            self._coal = (request, geometries, fixed)
        request, geometries, fixed = self._coal
        placed = dict(fixed)
        result = coal.DistanceResult()
        out = []
        for p in which:
            a, b = self.pairs[int(p)]
            for body in (a, b):
                if body not in placed:
                    j = self._frame_of[body]
                    placed[body] = [
                        _transform(coal, R[j], t[j], s) for s in self.collision.bodies[body].shapes
                    ]
            best = math.inf
            for ga, ta in zip(geometries[a], placed[a], strict=True):
                for gb, tb in zip(geometries[b], placed[b], strict=True):
                    result.clear()  # a result keeps the least distance it has seen
                    best = min(best, float(coal.distance(ga, ta, gb, tb, request, result)))
            out.append(best)
        self.pair_queries += len(out)
        return np.array(out, dtype=np.float64)


def _transform(coal_module: Any, rot: Array, pos: Array, shape: CollisionShape) -> Any:
    return coal_module.Transform3s(rot @ shape.rot_robot_from_shape, rot @ shape.pos_robot_m + pos)


def _pair_levers(
    collision: CollisionModel, model: RobotModel, pairs: tuple[tuple[int, int], ...]
) -> Array:
    """``C[p, k]``: how far one body of pair p can move relative to the other per radian of
    joint k (the reach of joint k to the body the joints between them move; 0 for the
    joints that move both or neither)."""
    rho = reach_bounds(model, collision)
    out = np.zeros((len(pairs), model.n_joints))
    for p, (a, b) in enumerate(pairs):
        ja, jb = collision.bodies[a].joint, collision.bodies[b].joint
        lo, hi, moving = (ja, jb, b) if ja < jb else (jb, ja, a)
        out[p, lo:hi] = rho[lo:hi, moving]
    return out
