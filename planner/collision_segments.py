"""Collision bodies generated from a robot model, for an arm whose URDF has none we can read
(a vendor's ``package://`` meshes): the shapes the shipped robots draw and check.

- each arm link: a capsule of ``radius_m`` along its segment, from its joint to the next
  joint (the hand point for the last), a sphere of ``radius_m`` where the segment has no
  length;
- the hand: a sphere of ``hand_radius_m`` at the hand point, on the last link;
- the base: its box (the description's ``[base]`` or base box visual), if it has one.

Allowed to touch (like an SRDF's disabled pairs, the way MoveIt's setup assistant makes
them): each joint's two bodies (the base and link 1, link k and k + 1, the last link and the
hand), and every pair nearer than ``clearance_m`` at the reference pose (their design
joins them: a checked pair there would refuse every plan). docs/robots.md, "A vendor's URDF".
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from planner.collision import (
    AllowedContact,
    CollisionBody,
    CollisionModel,
    CollisionShape,
    ShapeSet,
    body_poses,
)
from planner.model import RobotModel

__all__ = ["generated_contacts", "segment_collision_model"]

Array = NDArray[np.float64]

_ADJACENT = "generated: the two bodies of one joint"
_TOUCHING = "generated: nearer than the clearance rule at the reference pose"


def _frozen(a: Array) -> Array:
    out = np.array(a, dtype=np.float64)
    out.setflags(write=False)
    return out


def _segment(start: Array, end: Array, radius_m: float) -> CollisionShape:
    d = end - start
    length = float(np.linalg.norm(d))
    if length < 1e-9:
        return CollisionShape("sphere", (radius_m,), _frozen(np.eye(3)), _frozen(start))
    z = d / length
    helper = np.eye(3)[int(np.argmin(np.abs(z)))]
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    rot = np.column_stack([x, np.cross(z, x), z])
    return CollisionShape("capsule", (radius_m, length), _frozen(rot), _frozen(0.5 * (start + end)))


def _with_touching(
    model: RobotModel,
    bodies: tuple[CollisionBody, ...],
    contacts: list[AllowedContact],
    clearance_m: float,
) -> CollisionModel:
    """``bodies`` with ``contacts`` allowed and, besides, every pair they leave checked that
    is nearer than ``clearance_m`` at the reference pose."""
    trial = CollisionModel(bodies, tuple(contacts))
    rots, trans = body_poses(model, model.reference_joints)
    distances = ShapeSet(trial).pair_distances_m(trial.pairs, rots[0], trans[0])
    touching = [
        AllowedContact((bodies[i].name, bodies[j].name), _TOUCHING)
        for (i, j), d in zip(trial.pairs, distances, strict=True)
        if d < clearance_m
    ]
    return CollisionModel(bodies, (*contacts, *touching))


def segment_collision_model(
    model: RobotModel,
    *,
    base_name: str,
    radius_m: float,
    hand_radius_m: float,
    clearance_m: float,
    base_box_size_m: tuple[float, float, float] | None,
    base_box_centre_robot_m: Array | None,
    allowed: tuple[AllowedContact, ...] = (),
) -> CollisionModel:
    """The generated bodies and their allowed contacts (see the module doc), with
    ``allowed`` (the description's own) besides."""
    bodies: list[CollisionBody] = []
    if base_box_size_m is not None and base_box_centre_robot_m is not None:
        box = CollisionShape(
            "box", base_box_size_m, _frozen(np.eye(3)), _frozen(base_box_centre_robot_m)
        )
        bodies.append(CollisionBody(base_name, 0, (box,)))
    ends = [link.joint_pos_robot_m for link in model.links[1:]] + [model.hand_pos_robot_m]
    for k, (link, end) in enumerate(zip(model.links, ends, strict=True)):
        shape = _segment(np.asarray(link.joint_pos_robot_m), np.asarray(end), radius_m)
        bodies.append(CollisionBody(link.name, k + 1, (shape,)))
    hand = CollisionShape(
        "sphere", (hand_radius_m,), _frozen(np.eye(3)), _frozen(model.hand_pos_robot_m)
    )
    bodies.append(CollisionBody("hand", model.n_joints, (hand,)))
    names = [b.name for b in bodies]
    contacts = [
        *allowed,
        *(AllowedContact((names[i], names[i + 1]), _ADJACENT) for i in range(len(names) - 1)),
    ]
    return _with_touching(model, tuple(bodies), contacts, clearance_m)


def generated_contacts(
    model: RobotModel, collision: CollisionModel, clearance_m: float
) -> CollisionModel:
    """``collision`` (a URDF's own bodies: a vendor's meshes) with the contacts this module
    generates allowed besides its own: each joint's two sides (bodies of joints k and k + 1)
    and every pair nearer than ``clearance_m`` at the reference pose
    (``[flight_rules] generated_allowed_contact = true``)."""
    bodies = collision.bodies
    contacts = list(collision.allowed)
    for i, j in collision.pairs:
        if abs(bodies[i].joint - bodies[j].joint) == 1:
            contacts.append(AllowedContact((bodies[i].name, bodies[j].name), _ADJACENT))
    return _with_touching(model, bodies, contacts, clearance_m)
