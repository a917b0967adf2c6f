"""The live clearance: the ``clearance_m`` limit (:mod:`planner.limits`) measured from the
joints on every frame on the ground and on every control tick on the vehicle.

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

The bodies are posed by :class:`planner.collision.PoseChain` and their distances asked through
:class:`planner.collision.ShapeSet`, as the flight rules' fine grid and the post-pass flown
clearance (``server.services.clearance``) do: one engine, so a value at or below the
threshold is the analysis's at that frame. The watch evaluates every row it is given; what
it cannot see is the motion between two rows (docs/robots.md, "Limits": the bound).

Pure: reads no file, imports nothing of the telemetry, the spacecraft or the server.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from planner.clearance_sampling import pair_motion_coefficients
from planner.collision import CollisionModel, PoseChain, ShapeSet, check_collision_model
from planner.errors import InvalidInput
from planner.model import RobotModel

__all__ = ["ClearanceWatch"]

Array = NDArray[np.float64]


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
        self.lever = pair_motion_coefficients(self.collision, model, self.pairs)
        self._chain = PoseChain(model)
        self._shapes: ShapeSet | None = None  # made at the first exact distance (coal)
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
        lower bound of it above the threshold (NaN for non-finite joints). (The vehicle asks
        at every control tick: a still arm costs the bound alone.)"""
        q = self._row(joints_rad)
        still = self._still(q, 1)
        if still is not None:
            return float(still)
        return float(self.clearances_m(q[None, :])[0])

    def clearances_m(self, joints_rad: Array) -> Array:
        """:meth:`clearance_m` of each row of ``joints_rad`` ``(m, n)``, in order (the
        bounds of up to :attr:`LOOKAHEAD` rows at once)."""
        q = np.atleast_2d(np.asarray(joints_rad, dtype=np.float64))
        m = q.shape[0]
        if q.shape[1] != self.model.n_joints:
            raise InvalidInput(
                f"joints have {q.shape[1]} values; the robot has {self.model.n_joints} joints"
            )
        still = self._still(q, m)
        if still is not None:
            out: Array = still
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

    def _still(self, q: Array, m: int) -> Array | None:
        """The common case in three operations: every pair's distance at ``q`` (a row, or
        ``m`` rows) is at least its distance at the last answered joints ``q_g`` less
        ``lever_max |q - q_g|``, and the last answer was at most the least of them. That
        bound when it is above the threshold at every row, else None."""
        if self._distance is None or m > self.max_age - self._age:
            return None
        bound = self._last_m - np.abs(q - self._last_joints) @ self._lever_max
        if not (bound > self.threshold_m).all():  # False for NaN
            return None
        self.calls += m
        self._age += m
        out: Array = bound
        return out

    def _row(self, joints_rad: Array) -> Array:
        q = np.asarray(joints_rad, dtype=np.float64).reshape(-1)
        if q.shape[0] != self.model.n_joints:
            raise InvalidInput(
                f"joints have {q.shape[0]} values; the robot has {self.model.n_joints} joints"
            )
        return q

    def _poses(self, q: Array) -> tuple[Array, Array]:
        """The body frames at one joint vector ``q`` ``(n,)`` (:class:`planner.collision.
        PoseChain`): ``(n + 1, 3, 3)``, ``(n + 1, 3)``."""
        R, t = self._chain.poses(q[None, :])
        return R[0], t[0]

    def _exact(self, R: Array, t: Array, which: Iterable[int] | NDArray[np.intp]) -> Array:
        """Each pair's exact distance with the body frames at ``(R, t)`` (one sample)."""
        if self._shapes is None:
            self._shapes = ShapeSet(self.collision)
        pairs = [self.pairs[int(p)] for p in which]
        self.pair_queries += len(pairs)
        return self._shapes.pair_distances_m(pairs, R, t)
