"""SE(3)/SO(3) algebra: exp/log round trips, quaternions, inverses (with hypothesis)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from geometry import se3

finite = st.floats(-3.0, 3.0, allow_nan=False)
vec3 = st.tuples(finite, finite, finite).map(np.array)


def _is_rotation(rot: np.ndarray) -> bool:
    return np.allclose(rot.T @ rot, np.eye(3), atol=1e-9) and np.isclose(np.linalg.det(rot), 1.0)


@settings(max_examples=200, deadline=None)
@given(vec3)
def test_so3_exp_log_round_trip(w: np.ndarray) -> None:
    rot = se3.exp_so3(w)
    assert _is_rotation(rot)
    back = se3.exp_so3(se3.log_so3(rot))
    np.testing.assert_allclose(back, rot, atol=1e-7)


@settings(max_examples=200, deadline=None)
@given(vec3, vec3)
def test_se3_exp_log_round_trip(v: np.ndarray, w: np.ndarray) -> None:
    pose = se3.exp_se3(np.concatenate([v, w]))
    back = se3.exp_se3(se3.log_se3(pose))
    np.testing.assert_allclose(back, pose, atol=1e-6)


@settings(max_examples=200, deadline=None)
@given(vec3)
def test_quaternion_round_trip(w: np.ndarray) -> None:
    rot = se3.exp_so3(w)
    q = se3.quat_from_matrix(rot)
    assert q[0] >= 0.0 and np.isclose(np.linalg.norm(q), 1.0)
    np.testing.assert_allclose(se3.matrix_from_quat(q), rot, atol=1e-9)


def test_quaternion_convention_is_w_first() -> None:
    # 90 degrees about z: (cos 45, 0, 0, sin 45).
    q = se3.quat_from_matrix(se3.rotation_about(np.array([0, 0, 1.0]), np.pi / 2))
    np.testing.assert_allclose(q, [np.sqrt(0.5), 0, 0, np.sqrt(0.5)], atol=1e-12)


def test_quat_multiply_matches_matrices() -> None:
    rng = np.random.default_rng(0)
    a, b = se3.random_rotation(rng), se3.random_rotation(rng)
    qa, qb = se3.quat_from_matrix(a), se3.quat_from_matrix(b)
    np.testing.assert_allclose(se3.matrix_from_quat(se3.quat_multiply(qa, qb)), a @ b, atol=1e-12)


def test_log_near_pi_is_finite_and_exact() -> None:
    for axis in (np.array([1.0, 0, 0]), np.array([0, 1.0, 1.0]), np.array([1.0, -2.0, 0.5])):
        for angle in (np.pi, np.pi - 1e-9, np.pi - 1e-5, np.pi - 2e-3):
            rot = se3.rotation_about(axis, angle)
            w = se3.log_so3(rot)
            assert np.all(np.isfinite(w))
            np.testing.assert_allclose(se3.exp_so3(w), rot, atol=1e-7)
            assert abs(np.linalg.norm(w) - angle) < 1e-6


def test_small_angles_and_zero() -> None:
    for w in (np.zeros(3), np.array([1e-12, 0, 0]), np.array([1e-7, -2e-7, 3e-8])):
        np.testing.assert_allclose(se3.log_so3(se3.exp_so3(w)), w, atol=1e-15)
        xi = np.concatenate([np.array([0.1, -0.2, 0.3]), w])
        np.testing.assert_allclose(se3.log_se3(se3.exp_se3(xi)), xi, atol=1e-12)


def test_invert_and_transform_points() -> None:
    rng = np.random.default_rng(1)
    a_from_b = se3.make_pose(se3.random_rotation(rng), rng.normal(size=3))
    pts = rng.normal(size=(10, 3))
    there = se3.transform_points(a_from_b, pts)
    back = se3.transform_points(se3.invert(a_from_b), there)
    np.testing.assert_allclose(back, pts, atol=1e-12)
    np.testing.assert_allclose(se3.invert(a_from_b), np.linalg.inv(a_from_b), atol=1e-12)


def test_zero_quaternion_gives_identity() -> None:
    np.testing.assert_array_equal(se3.matrix_from_quat(np.zeros(4)), np.eye(3))
