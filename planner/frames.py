"""Rotation conventions, stated once.

- Quaternions are scalar-last ``(x, y, z, w)`` everywhere in the project (scipy's order).
  MuJoCo's scalar-first order is converted only in :mod:`planner.mujoco_conventions`.
- Roll, pitch, yaw follow SPEC section 7: ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (z-y-x).
- ``rot_a_from_b`` maps coordinates in frame b to frame a, so compositions cancel:
  ``rot_orbit_from_hand = rot_orbit_from_base @ rot_base_from_hand``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

__all__ = [
    "IDENTITY_QUAT_XYZW",
    "matrix_from_quat_xyzw",
    "matrix_from_rpy",
    "quat_xyzw_from_matrix",
    "quat_xyzw_turned_by_rotvec",
    "rotation_angle_rad",
    "rotvec_from_matrix",
    "rpy_from_matrix",
    "skew",
]

IDENTITY_QUAT_XYZW: NDArray[np.float64] = np.array([0.0, 0.0, 0.0, 1.0])


def skew(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """Cross-product matrix: ``skew(a) @ b == np.cross(a, b)``."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def matrix_from_rpy(rpy_rad: NDArray[np.float64]) -> NDArray[np.float64]:
    """``Rz(yaw) Ry(pitch) Rx(roll)`` from ``(roll, pitch, yaw)`` in radians."""
    roll, pitch, yaw = (float(a) for a in rpy_rad)
    return np.asarray(Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix(), dtype=np.float64)


def rpy_from_matrix(rot: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(roll, pitch, yaw)`` in radians of ``Rz(yaw) Ry(pitch) Rx(roll)``.

    At pitch = +-90 deg (gimbal lock) roll is set to 0 and yaw carries the whole
    rotation about the vertical, so the result still rebuilds ``rot`` exactly.
    """
    r = np.asarray(rot, dtype=np.float64)
    pitch = float(np.arctan2(-r[2, 0], np.hypot(r[0, 0], r[1, 0])))
    if np.hypot(r[0, 0], r[1, 0]) < 1e-9:
        roll = 0.0
        # With roll = 0 and pitch = +-90 deg: r[0,1] = -sin(yaw), r[1,1] = cos(yaw).
        yaw = float(np.arctan2(-r[0, 1], r[1, 1]))
    else:
        roll = float(np.arctan2(r[2, 1], r[2, 2]))
        yaw = float(np.arctan2(r[1, 0], r[0, 0]))
    return np.array([roll, pitch, yaw])


def matrix_from_quat_xyzw(quat_xyzw: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation matrix of a scalar-last unit quaternion."""
    x, y, z, w = np.asarray(quat_xyzw, dtype=np.float64).tolist()
    n = x * x + y * y + z * z + w * w
    s = 2.0 / n
    return np.array(
        [
            [1.0 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
            [s * (x * y + z * w), 1.0 - s * (x * x + z * z), s * (y * z - x * w)],
            [s * (x * z - y * w), s * (y * z + x * w), 1.0 - s * (x * x + y * y)],
        ]
    )


def quat_xyzw_from_matrix(rot: NDArray[np.float64]) -> NDArray[np.float64]:
    """Scalar-last unit quaternion with ``w >= 0``.

    A rotation orthonormal to 1e-13 (a product of MuJoCo's frames), which scipy takes as it
    is, goes through :func:`_quat_of` (scipy's steps in scalars: the same numbers, without
    its objects, once per predicted row); any other through scipy (it re-orthogonalises
    what is further off and refuses a reflection)."""
    m = np.asarray(rot, dtype=np.float64)
    if m.shape == (3, 3) and _orthonormal(m.tolist()):
        quat = np.array(_quat_of(m))
    else:
        quat = np.asarray(Rotation.from_matrix(rot).as_quat(), dtype=np.float64)
    return quat if quat[3] >= 0.0 else -quat


def _orthonormal(rows: list[list[float]]) -> bool:
    """``rows @ rows.T`` within 1e-13 of the identity and the determinant positive."""
    for i in range(3):
        for j in range(i, 3):
            a, b = rows[i], rows[j]
            dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
            if abs(dot - (1.0 if i == j else 0.0)) > 1e-13:
                return False
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = rows
    det = r00 * (r11 * r22 - r12 * r21) - r01 * (r10 * r22 - r12 * r20)
    return bool(det + r02 * (r10 * r21 - r11 * r20) > 0.5)


def _quat_of(rot: NDArray[np.float64]) -> tuple[float, float, float, float]:
    """The unit quaternion (x, y, z, w) scipy's ``Rotation.from_matrix`` makes of an
    orthonormal ``rot``: its branch on the largest of the diagonal and the trace, its
    normalisation."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = rot.tolist()
    trace = m00 + m11 + m22
    decision = (m00, m11, m22, trace)
    choice = decision.index(max(decision))  # the first of equals, as argmax
    if choice == 0:
        q = (1 - trace + 2 * m00, m10 + m01, m20 + m02, m21 - m12)
    elif choice == 1:
        q = (m01 + m10, 1 - trace + 2 * m11, m21 + m12, m02 - m20)
    elif choice == 2:
        q = (m02 + m20, m12 + m21, 1 - trace + 2 * m22, m10 - m01)
    else:
        q = (m21 - m12, m02 - m20, m10 - m01, 1 + trace)
    norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return q[0] / norm, q[1] / norm, q[2] / norm, q[3] / norm


def rotation_angle_rad(rot: NDArray[np.float64]) -> float:
    """Angle of a rotation matrix (0 to pi), robust near 0 and pi."""
    return float(np.linalg.norm(Rotation.from_matrix(rot).as_rotvec()))


def rotvec_from_matrix(
    rot: NDArray[np.float64], *, assume_valid: bool = False
) -> NDArray[np.float64]:
    """``Rotation.from_matrix(rot, assume_valid=assume_valid).as_rotvec()`` for one ``rot``:
    where scipy takes ``rot`` as it is (``assume_valid``, or orthonormal to 1e-13: products
    of MuJoCo's frames), its steps in scipy's order in scalars, so the same numbers to the
    bit at a fifth of the cost of its objects (the planners' inner loops call it at every
    step); any other ``rot`` goes to scipy."""
    m = np.asarray(rot, dtype=np.float64)
    if not assume_valid and not (m.shape == (3, 3) and _orthonormal(m.tolist())):
        return np.asarray(Rotation.from_matrix(rot).as_rotvec(), dtype=np.float64)
    x, y, z, w = _quat_of(m)
    if w < 0:  # the canonical quaternion, w >= 0
        x, y, z, w = -x, -y, -z, -w
    angle = 2 * math.atan2(math.sqrt(x * x + y * y + z * z), w)
    if angle <= 1e-3:  # scipy's Taylor series of angle / sin(angle / 2)
        angle2 = angle * angle
        scale = 2 + angle2 / 12 + 7 * angle2 * angle2 / 2880
    else:
        scale = angle / math.sin(angle / 2)
    return np.array([scale * x, scale * y, scale * z])


def quat_xyzw_turned_by_rotvec(
    quat_xyzw: NDArray[np.float64], rotvec: NDArray[np.float64]
) -> NDArray[np.float64]:
    """``(Rotation.from_quat(quat_xyzw) * Rotation.from_rotvec(rotvec)).as_quat()`` with
    ``w >= 0``: scipy's steps in scipy's order (normalise, the rotation vector's quaternion,
    the product, normalise) in scalars, the same numbers to the bit without its objects (the
    vehicle's sensors call it at every sample)."""
    x, y, z, w = np.asarray(quat_xyzw, dtype=np.float64).tolist()
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    rx, ry, rz = np.asarray(rotvec, dtype=np.float64).tolist()
    angle = math.sqrt(rx * rx + ry * ry + rz * rz)
    if angle <= 1e-3:  # scipy's Taylor series of sin(angle / 2) / angle
        angle2 = angle * angle
        scale = 0.5 - angle2 / 48 + angle2 * angle2 / 3840
    else:
        scale = math.sin(angle / 2) / angle
    bx, by, bz, bw = scale * rx, scale * ry, scale * rz, math.cos(angle / 2)
    cx = w * bx + bw * x + (y * bz - z * by)
    cy = w * by + bw * y + (z * bx - x * bz)
    cz = w * bz + bw * z + (x * by - y * bx)
    cw = w * bw - x * bx - y * by - z * bz
    norm = math.sqrt(cx * cx + cy * cy + cz * cz + cw * cw)
    quat = np.array([cx / norm, cy / norm, cz / norm, cw / norm])
    return -quat if quat[3] < 0.0 else quat
