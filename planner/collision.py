"""The spacecraft's collision geometry and the distances between its bodies (coal).

A robot description's ``<collision>`` shapes (:mod:`planner.description` reads them) become a
:class:`CollisionModel`: one :class:`CollisionBody` per URDF link that has shapes, each rigid
with the base (``joint == 0``: the base and the equipment fixed on it) or with arm link
``joint`` (1-based; a fixed child of link 6, such as the hand, moves with joint 6). Every
shape is stored at the all-zero pose in the robot frame (origin at joint 1, base axes), so
the pose of a body at joints ``q`` is the product of exponentials of the joints before it:
``G_j(q) = exp(xi_1 q_1) ... exp(xi_j q_j)``, each a rotation about joint k's axis through
joint k's position at the zero pose (:func:`body_poses`, vectorised over samples).

Which pairs are checked: every pair of bodies that can move relative to each other (a
different ``joint``), except the pairs the description allows to touch
(``[[flight_rules.allowed_contact]]``, like an SRDF's disabled collisions). Bodies on the same
joint never move relative to each other: their distance is a constant of the design, not of a
plan.

Distances come from coal (the Flexible Collision Library's maintained successor): exact for
the primitive pairs it solves in closed form (sphere, capsule, box pairs) and by GJK/EPA to
its tolerance (1e-6 m here) for the rest, signed (negative: penetration depth). Why coal
rather than MuJoCo's ``mj_geomDistance``: coal is built for distance queries (MuJoCo's
collision pipeline is built for contacts: its box-box and mesh distances beyond the contact
margin are approximate), it takes a URDF's shapes as they are (capsule, cylinder, convex
hull) and returns the nearest points, which the console draws.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from planner.errors import InvalidInput
from planner.model import RobotModel

if TYPE_CHECKING:
    import coal

__all__ = [
    "SHAPE_KINDS",
    "AllowedContact",
    "CollisionBody",
    "CollisionModel",
    "CollisionShape",
    "PairDistance",
    "ShapeSet",
    "body_poses",
    "joint_rotations",
]

Array = NDArray[np.float64]

#: box: full sizes (x, y, z); cylinder and capsule: (radius, length) along the shape's z;
#: sphere: (radius,); convex: () with ``vertices_m`` (the hull's points in the shape frame).
SHAPE_KINDS = ("box", "cylinder", "capsule", "sphere", "convex")

#: GJK/EPA's tolerance on a distance, metres (coal's default is 1e-6 too).
DISTANCE_TOLERANCE_M = 1e-6


@dataclass(frozen=True, eq=False)
class CollisionShape:
    """One collision shape at the all-zero pose, robot frame."""

    kind: str
    dims: tuple[float, ...]
    rot_robot_from_shape: Array
    pos_robot_m: Array
    vertices_m: Array | None = None  # convex: (k, 3) in the shape frame

    def __post_init__(self) -> None:
        expected = {"box": 3, "cylinder": 2, "capsule": 2, "sphere": 1, "convex": 0}
        if self.kind not in expected:
            raise InvalidInput(f"collision shape kind {self.kind!r} is not one of {SHAPE_KINDS}")
        if len(self.dims) != expected[self.kind] or not all(
            math.isfinite(d) and d > 0.0 for d in self.dims
        ):
            raise InvalidInput(
                f"a {self.kind} takes {expected[self.kind]} positive size(s), got {self.dims}"
            )
        if self.kind == "convex" and (
            self.vertices_m is None or self.vertices_m.ndim != 2 or self.vertices_m.shape[0] < 4
        ):
            raise InvalidInput("a convex shape needs at least 4 points (k, 3)")

    @property
    def bounding_radius_m(self) -> float:
        """The radius of a sphere about the shape's origin that holds the whole shape."""
        if self.kind == "box":
            return 0.5 * math.sqrt(sum(d * d for d in self.dims))
        if self.kind == "sphere":
            return self.dims[0]
        if self.kind == "cylinder":
            return math.hypot(self.dims[0], 0.5 * self.dims[1])
        if self.kind == "capsule":
            return self.dims[0] + 0.5 * self.dims[1]
        assert self.vertices_m is not None
        return float(np.max(np.linalg.norm(self.vertices_m, axis=1)))

    def geometry(self) -> coal.CollisionGeometry:
        """The shape as coal's geometry (in the shape's own frame)."""
        import coal  # imported where distances are asked for, not with the planner

        if self.kind == "box":
            return coal.Box(*self.dims)
        if self.kind == "sphere":
            return coal.Sphere(self.dims[0])
        if self.kind == "cylinder":
            return coal.Cylinder(self.dims[0], self.dims[1])
        if self.kind == "capsule":
            return coal.Capsule(self.dims[0], self.dims[1])
        assert self.vertices_m is not None
        points = coal.StdVec_Vec3s()
        for p in self.vertices_m:
            points.append(np.asarray(p, dtype=np.float64))
        return coal.Convex.convexHull(points, False, "")


@dataclass(frozen=True, eq=False)
class CollisionBody:
    """A URDF link's shapes; ``joint`` 0: rigid with the base, i: with arm link i."""

    name: str
    joint: int
    shapes: tuple[CollisionShape, ...]

    @property
    def is_equipment(self) -> bool:
        return self.joint == 0


@dataclass(frozen=True)
class AllowedContact:
    """A pair of bodies that may touch (adjacent links, a link and its mount), and why."""

    bodies: tuple[str, str]
    reason: str


@dataclass(frozen=True, eq=False)
class CollisionModel:
    """Every body's shapes and the pairs allowed to touch; ``pairs`` are the checked ones
    (index pairs into ``bodies``, the lower index first)."""

    bodies: tuple[CollisionBody, ...]
    allowed: tuple[AllowedContact, ...] = ()
    pairs: tuple[tuple[int, int], ...] = field(init=False)

    def __post_init__(self) -> None:
        names = [b.name for b in self.bodies]
        if len(set(names)) != len(names):
            raise InvalidInput(f"collision bodies must have distinct names, got {names}")
        allowed = set()
        for contact in self.allowed:
            for name in contact.bodies:
                if name not in names:
                    raise InvalidInput(
                        f"allowed contact {list(contact.bodies)}: no collision body {name!r} "
                        f"(bodies with <collision> shapes: {names})"
                    )
            allowed.add(frozenset(contact.bodies))
        pairs = tuple(
            (i, j)
            for i in range(len(self.bodies))
            for j in range(i + 1, len(self.bodies))
            if self.bodies[i].joint != self.bodies[j].joint
            and frozenset((names[i], names[j])) not in allowed
        )
        object.__setattr__(self, "pairs", pairs)

    def body(self, name: str) -> CollisionBody:
        for b in self.bodies:
            if b.name == name:
                return b
        raise KeyError(name)

    @property
    def n_shapes(self) -> int:
        return sum(len(b.shapes) for b in self.bodies)


def joint_rotations(axes: Array, angles: Array) -> Array:
    """Rodrigues' rotation for each sample and joint: ``(S, n, 3, 3)`` from unit ``axes``
    ``(n, 3)`` and ``angles`` ``(S, n)``."""
    kx, kx2 = _skews(axes)
    return _rotations(kx, kx2, angles)


def _skews(axes: Array) -> tuple[Array, Array]:
    """Each unit axis's cross-product matrix ``[k]x`` and its square, ``(n, 3, 3)`` each."""
    k = np.asarray(axes, dtype=np.float64)
    kx = np.zeros((k.shape[0], 3, 3))
    kx[:, 0, 1], kx[:, 0, 2] = -k[:, 2], k[:, 1]
    kx[:, 1, 0], kx[:, 1, 2] = k[:, 2], -k[:, 0]
    kx[:, 2, 0], kx[:, 2, 1] = -k[:, 1], k[:, 0]
    return kx, kx @ kx


def _rotations(kx: Array, kx2: Array, angles: Array) -> Array:
    s = np.sin(angles)[..., None, None]
    c = (1.0 - np.cos(angles))[..., None, None]
    out: Array = np.eye(3) + s * kx + c * kx2
    return out


class PoseChain:
    """A robot's joints as a product of exponentials, the parts that do not depend on the
    angles made once: :meth:`poses` is :func:`body_poses` (the flight rules' fine grid, the
    post-pass clearance and the live watch all pose the bodies with it)."""

    def __init__(self, model: RobotModel) -> None:
        self.n_joints = model.n_joints
        self._kx, self._kx2 = _skews(np.array([link.joint_axis_robot for link in model.links]))
        self._points = np.array([link.joint_pos_robot_m for link in model.links])

    def poses(self, joints_rad: Array) -> tuple[Array, Array]:
        """:func:`body_poses` of ``joints_rad`` ``(S, n)``: ``(S, n + 1, 3, 3)``,
        ``(S, n + 1, 3)``."""
        q = np.atleast_2d(np.asarray(joints_rad, dtype=np.float64))
        samples, n = q.shape
        if n != self.n_joints:
            raise InvalidInput(f"joints have {n} columns; the robot has {self.n_joints} joints")
        rots = _rotations(self._kx, self._kx2, q)
        # exp(xi q) = [Rq, p - Rq p]; G_j = G_{j-1} exp(xi_j q_j)
        offsets = self._points - np.einsum("sjab,jb->sja", rots, self._points)
        R = np.empty((samples, n + 1, 3, 3))
        t = np.empty((samples, n + 1, 3))
        R[:, 0] = np.eye(3)
        t[:, 0] = 0.0
        for j in range(n):
            t[:, j + 1] = np.einsum("sab,sb->sa", R[:, j], offsets[:, j]) + t[:, j]
            R[:, j + 1] = R[:, j] @ rots[:, j]
        return R, t


def body_poses(model: RobotModel, joints_rad: Array) -> tuple[Array, Array]:
    """The pose of every joint's moving frame at each sample, robot frame: rotations
    ``(S, n + 1, 3, 3)`` and translations ``(S, n + 1, 3)``; index 0 is the base (identity)
    and index j the product of exponentials of joints 1..j (a point ``x`` at the zero pose
    of a body rigid with link j is at ``R[:, j] @ x + t[:, j]``). A caller that poses the
    same robot again and again keeps its :class:`PoseChain`."""
    return PoseChain(model).poses(joints_rad)


@dataclass(frozen=True)
class PairDistance:
    """The signed distance between two bodies and its nearest points (robot frame)."""

    distance_m: float
    point_a_robot_m: tuple[float, float, float]
    point_b_robot_m: tuple[float, float, float]


class ShapeSet:
    """The model's shapes as coal geometries, built once, and the distance between two
    bodies at given frame poses; counts the queries it makes."""

    def __init__(self, collision: CollisionModel) -> None:
        import coal

        self._coal = coal
        self.collision = collision
        self._geometries = [[s.geometry() for s in b.shapes] for b in collision.bodies]
        self._request = coal.DistanceRequest()
        self._request.enable_signed_distance = True
        self._request.rel_err = 0.0
        self._request.abs_err = 0.0
        self.queries = 0
        self._frames_key: object = None  # the bodies' coal frames at one key (a sample)
        self._frames: dict[int, list[coal.Transform3s]] = {}
        self._result = coal.DistanceResult()  # reused by pair_distances_m (cleared)
        #: the bodies rigid with the base: at the identity in every sample of body_poses
        self._fixed = {
            b: [_transform(np.eye(3), np.zeros(3), s) for s in body.shapes]
            for b, body in enumerate(collision.bodies)
            if body.joint == 0
        }

    def pair_distances_m(
        self, pairs: Sequence[tuple[int, int]], R: Array, t: Array
    ) -> NDArray[np.float64]:
        """Each pair's signed distance (no nearest points: the cheaper query) with every
        body's frame at its joint's ``(R[joint], t[joint])``, one sample of
        :func:`body_poses` (``(n + 1, 3, 3)``, ``(n + 1, 3)``; index 0 the identity)."""
        placed = dict(self._fixed)
        bodies = self.collision.bodies
        coal, request, result = self._coal, self._request, self._result
        out = np.empty(len(pairs))
        for p, (a, b) in enumerate(pairs):
            for body in (a, b):
                if body not in placed:
                    j = bodies[body].joint
                    placed[body] = [_transform(R[j], t[j], s) for s in bodies[body].shapes]
            best = math.inf
            for ga, ta in zip(self._geometries[a], placed[a], strict=True):
                for gb, tb in zip(self._geometries[b], placed[b], strict=True):
                    result.clear()  # a result keeps the least distance it has seen
                    best = min(best, float(coal.distance(ga, ta, gb, tb, request, result)))
                    self.queries += 1
            out[p] = best
        return out

    def distance(
        self,
        a: int,
        b: int,
        rot_a: Array,
        pos_a: Array,
        rot_b: Array,
        pos_b: Array,
        *,
        frames_key: object = None,
    ) -> PairDistance:
        """Bodies ``a`` and ``b`` (indices) with their frames at ``(rot, pos)`` (robot
        frame): the smallest distance over their shape pairs. Calls with the same
        ``frames_key`` (not None; a sample's index), one after another, promise each body the
        same frame: its shapes' coal frames are then made once for them all."""
        best: PairDistance | None = None
        frames_a = self._shape_frames(a, rot_a, pos_a, frames_key)
        frames_b = self._shape_frames(b, rot_b, pos_b, frames_key)
        for geom_a, ta in zip(self._geometries[a], frames_a, strict=True):
            for geom_b, tb in zip(self._geometries[b], frames_b, strict=True):
                result = self._coal.DistanceResult()
                d = float(self._coal.distance(geom_a, ta, geom_b, tb, self._request, result))
                self.queries += 1
                if best is None or d < best.distance_m:
                    pa = result.getNearestPoint1()
                    pb = result.getNearestPoint2()
                    best = PairDistance(
                        d,
                        (float(pa[0]), float(pa[1]), float(pa[2])),
                        (float(pb[0]), float(pb[1]), float(pb[2])),
                    )
        assert best is not None  # every body has a shape
        return best

    def _shape_frames(
        self, body: int, rot: Array, pos: Array, key: object
    ) -> list[coal.Transform3s]:
        if key is not None and key == self._frames_key and body in self._frames:
            return self._frames[body]
        frames = [_transform(rot, pos, shape) for shape in self.collision.bodies[body].shapes]
        if key is not None:
            if key != self._frames_key:
                self._frames_key, self._frames = key, {}
            self._frames[body] = frames
        return frames


def _transform(rot: Array, pos: Array, shape: CollisionShape) -> coal.Transform3s:
    import coal

    return coal.Transform3s(rot @ shape.rot_robot_from_shape, rot @ shape.pos_robot_m + pos)


def check_collision_model(collision: CollisionModel | None, robot: str) -> CollisionModel:
    """``collision`` when it can show a plan clear; :class:`InvalidInput` saying why not."""
    if collision is None or not collision.bodies:
        raise InvalidInput(
            f"robot {robot!r} has no <collision> shapes in its description: its plans cannot be "
            "shown clear of the spacecraft (docs/robots.md, 'Collision geometry and flight "
            "rules')"
        )
    if not any(b.is_equipment for b in collision.bodies):
        raise InvalidInput(
            f"robot {robot!r}: neither the base nor any equipment fixed on it has a <collision> "
            "shape: the arm cannot be shown clear of the spacecraft"
        )
    if all(b.is_equipment for b in collision.bodies):
        raise InvalidInput(
            f"robot {robot!r}: no arm link has a <collision> shape: the arm cannot be shown "
            "clear of the spacecraft"
        )
    return collision


def reach_bounds(model: RobotModel, collision: CollisionModel) -> Array:
    """``rho[k, b]``: an upper bound, at any joint angles, on the distance from joint k's
    position (k = 0..n-1 for joints 1..n) to any point of body b (0 where b is not moved by
    joint k). Joint positions are rigid in the link before them, so the distance from joint k
    to joint j is at most the sum of the fixed offsets between them."""
    points = np.array([link.joint_pos_robot_m for link in model.links])
    n = model.n_joints
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1) if n > 1 else np.zeros(0)
    rho = np.zeros((n, len(collision.bodies)))
    for b, body in enumerate(collision.bodies):
        j = body.joint
        if j == 0:
            continue
        own = points[j - 1]
        extent = max(
            float(np.linalg.norm(s.pos_robot_m - own)) + s.bounding_radius_m for s in body.shapes
        )
        for k in range(j):
            rho[k, b] = float(np.sum(steps[k : j - 1])) + extent
    return rho


def pair_names(collision: CollisionModel, pairs: Sequence[tuple[int, int]]) -> list[str]:
    return [f"{collision.bodies[a].name}/{collision.bodies[b].name}" for a, b in pairs]
