"""planner.frames' scalar conversions give scipy's numbers to the bit (the planners' inner
loops use them in place of scipy's objects; a plan must not change by a rounding)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from planner.frames import quat_xyzw_from_matrix, quat_xyzw_turned_by_rotvec, rotvec_from_matrix


def _rotations(n: int) -> list[np.ndarray]:
    """Products of rotations from a micro-radian to beyond pi (every branch of the
    conversion: each diagonal entry and the trace largest), orthonormal to round-off."""
    rng = np.random.default_rng(11)
    out = []
    for _ in range(n):
        big = Rotation.from_rotvec(rng.normal(size=3) * 10 ** rng.uniform(-6.0, 0.5))
        out.append(big.as_matrix() @ Rotation.from_rotvec(rng.normal(size=3)).as_matrix())
    out += [np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]), np.eye(3)]
    return out


def test_rotvec_and_quaternion_are_scipy_s_to_the_bit() -> None:
    for rot in _rotations(3000):
        want = Rotation.from_matrix(rot, assume_valid=True).as_rotvec()
        assert np.array_equal(rotvec_from_matrix(rot, assume_valid=True), want), rot
        want = Rotation.from_matrix(rot).as_rotvec()
        assert np.array_equal(rotvec_from_matrix(rot), want), rot
        quat = Rotation.from_matrix(rot).as_quat()
        assert np.array_equal(quat_xyzw_from_matrix(rot), quat if quat[3] >= 0 else -quat), rot


def test_a_matrix_off_a_rotation_goes_to_scipy() -> None:
    skewed = np.eye(3)
    skewed[0, 1] = 1e-8  # scipy re-orthogonalises it: the scalar path would not
    quat = quat_xyzw_from_matrix(skewed)
    assert np.array_equal(quat, Rotation.from_matrix(skewed).as_quat())
    assert quat[2] != -1e-8 / np.sqrt(16.0 + 1e-16)  # the scalar path's (m10 - m01) / norm
    assert np.array_equal(rotvec_from_matrix(skewed), Rotation.from_matrix(skewed).as_rotvec())
    with pytest.raises(ValueError, match="determinant"):
        quat_xyzw_from_matrix(np.diag([1.0, 1.0, -1.0]))  # a reflection is refused


def test_a_turned_quaternion_is_scipy_s_to_the_bit() -> None:
    """The sensors' attitude noise: small turns (the Taylor series) and large ones."""
    rng = np.random.default_rng(12)
    for _ in range(3000):
        quat = rng.normal(size=4)  # scipy normalises it, as the scalar path does
        turn = rng.normal(size=3) * 10 ** rng.uniform(-7.0, 0.3)
        want = (Rotation.from_quat(quat) * Rotation.from_rotvec(turn)).as_quat()
        want = -want if want[3] < 0.0 else want
        assert np.array_equal(quat_xyzw_turned_by_rotvec(quat, turn), want), (quat, turn)
