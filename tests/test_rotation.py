"""The scalar rotation kernels against scipy.spatial.transform.Rotation."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbstudy.numerics import rotation as r

RNG = np.random.default_rng(7)


def random_quaternion():
    return tuple(Rotation.random(random_state=RNG).as_quat())


def test_quat_mul_matches_scipy_composition():
    a, b = random_quaternion(), random_quaternion()
    expected = (Rotation.from_quat(a) * Rotation.from_quat(b)).as_quat()
    got = np.array(r.quat_mul(a, b))
    assert np.allclose(got * np.sign(got[3]), expected * np.sign(expected[3]), atol=1e-15)


def test_rotate_and_inverse_match_scipy():
    q, v = random_quaternion(), tuple(RNG.normal(size=3))
    assert np.allclose(r.quat_rotate(q, v), Rotation.from_quat(q).apply(v), atol=1e-14)
    assert np.allclose(r.quat_rotate_inverse(q, v), Rotation.from_quat(q).inv().apply(v), atol=1e-14)


@pytest.mark.parametrize("angle", [0.0, 1e-9, 5e-5, 1e-4, 0.3, 3.0])
def test_quat_exp_matches_rotvec(angle):
    axis = RNG.normal(size=3)
    v = tuple(angle * axis / np.linalg.norm(axis))
    expected = Rotation.from_rotvec(v).as_quat()
    assert np.allclose(r.quat_exp(v), expected, atol=1e-16, rtol=1e-15)


def test_cayley_is_rotation_by_2_atan_half_norm():
    v = np.array([0.3, -0.4, 1.2])
    angle = 2 * np.arctan(np.linalg.norm(v) / 2)
    expected = Rotation.from_rotvec(angle * v / np.linalg.norm(v)).as_quat()
    assert np.allclose(r.quat_cayley(tuple(v)), expected, atol=1e-15)


@pytest.mark.parametrize("k", [0, 1, 2])
def test_quat_times_axis_is_right_product_with_pure_axis(k):
    q = random_quaternion()
    axis = [0.0, 0.0, 0.0, 0.0]
    axis[k] = 1.0
    assert np.allclose(r.quat_times_axis(q, k), r.quat_mul(q, tuple(axis)), atol=0)


@pytest.mark.parametrize("k", [0, 1, 2])
def test_axis_rotation_composes_like_scipy(k):
    q = random_quaternion()
    rotvec = np.zeros(3)
    rotvec[k] = 0.7
    expected = (Rotation.from_quat(q) * Rotation.from_rotvec(rotvec)).as_quat()
    got = r.quat_mul_axis_rotation(q, k, np.sin(0.35), np.cos(0.35))
    assert np.allclose(got, expected, rtol=0, atol=1e-15) or np.allclose(got, -expected, rtol=0, atol=1e-15)


def test_solve3_matches_numpy():
    m = RNG.normal(size=(3, 3)) + 3 * np.eye(3)
    rhs = RNG.normal(size=3)
    got = r.solve3(tuple(tuple(row) for row in m), tuple(rhs))
    assert np.allclose(got, np.linalg.solve(m, rhs), rtol=1e-13)


def test_skew_matmul():
    a, d = np.array([1.0, -2.0, 0.5]), np.array([1.0, 2.0, 3.0])
    skew = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    assert np.allclose(np.array(r.skew_matmul(tuple(a), tuple(d))), skew @ np.diag(d))
