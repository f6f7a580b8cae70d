"""SO(3) and SE(3): exp/log round trips (near 0 and near pi), Jacobians against finite
differences, the perturbation convention, batching, and bad inputs."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm, logm

from slamlib import lie


def _random_w(rng, n, max_angle=np.pi):
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    return axis * rng.uniform(0, max_angle, size=(n, 1))


def _random_T(rng, n):
    return lie.se3_exp(np.concatenate([rng.normal(size=(n, 3)), _random_w(rng, n, 3.0)], 1))


# --------------------------------------------------------------------------- so3


def test_skew_vee():
    w = np.array([0.3, -1.2, 2.0])
    v = np.array([1.0, 2.0, -0.5])
    np.testing.assert_allclose(lie.skew(w) @ v, np.cross(w, v))
    np.testing.assert_allclose(lie.vee(lie.skew(w)), w)
    assert lie.hat is lie.skew


def test_so3_exp_matches_matrix_exponential():
    rng = np.random.default_rng(0)
    for w in _random_w(rng, 20):
        np.testing.assert_allclose(lie.so3_exp(w), expm(lie.skew(w)), atol=1e-13)


def test_so3_exp_at_zero_and_small_angles():
    np.testing.assert_array_equal(lie.so3_exp(np.zeros(3)), np.eye(3))
    for a in (1e-12, 1e-8, 1e-5, 1e-3, 1e-2):
        w = a * np.array([0.6, -0.8, 0.0])
        R = lie.so3_exp(w)
        # R - I = [w]x + [w]x^2 / 2 + [w]x^3 / 6 + O(a^4): relative accuracy on the off-diagonal part
        ref = lie.skew(w) + 0.5 * lie.skew(w) @ lie.skew(w) + lie.skew(w) @ lie.skew(w) @ lie.skew(w) / 6
        off = ~np.eye(3, dtype=bool)
        np.testing.assert_allclose((R - np.eye(3))[off], ref[off], atol=1e-15 * a + a ** 4, rtol=0)
        np.testing.assert_allclose(np.diag(R), np.diag(np.eye(3) + 0.5 * lie.skew(w) @ lie.skew(w)), atol=2.3e-16)


def test_so3_log_round_trip_all_angles():
    rng = np.random.default_rng(1)
    w = _random_w(rng, 500)
    np.testing.assert_allclose(lie.so3_log(lie.so3_exp(w)), w, atol=1e-12)


@pytest.mark.parametrize("angle", [0.0, 1e-15, 1e-10, 1e-6, 1e-3, 2.0, 2 * np.pi / 3, np.pi - 1e-3, np.pi - 1e-6,
                                   np.pi - 1e-9, np.pi - 1e-12])
def test_so3_log_near_zero_and_pi(angle):
    axis = np.array([2.0, -1.0, 0.5]) / np.linalg.norm([2.0, -1.0, 0.5])
    w = angle * axis
    got = lie.so3_log(lie.so3_exp(w))
    np.testing.assert_allclose(got, w, atol=1e-12)
    np.testing.assert_allclose(lie.so3_exp(got), lie.so3_exp(w), atol=1e-14)


def test_so3_log_at_pi_either_sign():
    axis = np.array([0.0, 0.6, 0.8])
    got = lie.so3_log(lie.so3_exp(np.pi * axis))
    assert np.isclose(np.linalg.norm(got), np.pi, atol=1e-12)
    assert np.allclose(got, np.pi * axis, atol=1e-7) or np.allclose(got, -np.pi * axis, atol=1e-7)


def test_so3_log_matches_scipy_logm():
    rng = np.random.default_rng(2)
    for w in _random_w(rng, 10, 3.0):
        R = lie.so3_exp(w)
        np.testing.assert_allclose(lie.skew(lie.so3_log(R)), np.real(logm(R)), atol=1e-9)


def _num_jac(f, x, eps=1e-6):
    cols = []
    for k in range(x.size):
        d = np.zeros(x.size)
        d[k] = eps
        cols.append((f(x + d) - f(x - d)) / (2 * eps))
    return np.stack(cols, -1)


@pytest.mark.parametrize("angle", [0.0, 1e-4, 0.5, 2.0, 3.0])
def test_so3_right_jacobian_finite_differences(angle):
    w = angle * np.array([0.36, 0.48, 0.8])
    R = lie.so3_exp(w)
    num = _num_jac(lambda d: lie.so3_log(R.T @ lie.so3_exp(w + d)), np.zeros(3))
    np.testing.assert_allclose(lie.so3_right_jacobian(w), num, atol=1e-8)
    num_inv = _num_jac(lambda d: lie.so3_log(R @ lie.so3_exp(d)), np.zeros(3))
    np.testing.assert_allclose(lie.so3_right_jacobian_inv(w), num_inv, atol=1e-7)
    np.testing.assert_allclose(lie.so3_right_jacobian(w) @ lie.so3_right_jacobian_inv(w), np.eye(3), atol=1e-12)
    np.testing.assert_allclose(lie.so3_left_jacobian(w), lie.so3_right_jacobian(-w), atol=1e-15)
    np.testing.assert_allclose(lie.so3_left_jacobian_inv(w), np.linalg.inv(lie.so3_left_jacobian(w)), atol=1e-12)


def test_so3_right_jacobian_inv_finite_near_pi():
    w = (np.pi - 1e-9) * np.array([1.0, 0.0, 0.0])
    assert np.all(np.isfinite(lie.so3_right_jacobian_inv(w)))


# --------------------------------------------------------------------------- quaternions and angles


def test_quaternion_round_trip_and_known_value():
    np.testing.assert_allclose(lie.quat_to_so3([0.0, 0.0, np.sin(0.25), np.cos(0.25)]), lie.so3_exp([0, 0, 0.5]),
                               atol=1e-15)
    rng = np.random.default_rng(3)
    R = lie.so3_exp(_random_w(rng, 50))
    q = lie.so3_to_quat(R)
    assert np.all(q[:, 3] >= 0)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-15)
    np.testing.assert_allclose(lie.quat_to_so3(q), R, atol=1e-14)
    np.testing.assert_allclose(lie.quat_to_so3(-3.0 * q), R, atol=1e-14)  # sign and scale free


def test_euler_round_trip_and_gimbal_lock():
    rpy = np.array([0.3, -0.7, 2.5])
    Rx = lie.so3_exp([rpy[0], 0, 0])
    Ry = lie.so3_exp([0, rpy[1], 0])
    Rz = lie.so3_exp([0, 0, rpy[2]])
    np.testing.assert_allclose(lie.euler_to_so3(rpy), Rz @ Ry @ Rx, atol=1e-15)
    np.testing.assert_allclose(lie.so3_to_euler(lie.euler_to_so3(rpy)), rpy, atol=1e-12)
    # at pitch = pi/2 only yaw - roll is seen: two different triples give one rotation
    a = lie.euler_to_so3([0.4, np.pi / 2, 1.0])
    b = lie.euler_to_so3([0.0, np.pi / 2, 0.6])
    np.testing.assert_allclose(a, b, atol=1e-15)
    np.testing.assert_allclose(lie.euler_to_so3(lie.so3_to_euler(a)), a, atol=1e-12)


# --------------------------------------------------------------------------- se3


def test_se3_exp_matches_matrix_exponential_and_log_round_trip():
    rng = np.random.default_rng(4)
    xi = np.concatenate([rng.normal(size=(30, 3)), _random_w(rng, 30, 3.1)], 1)
    for x in xi:
        M = np.zeros((4, 4))
        M[:3, :3] = lie.skew(x[3:])
        M[:3, 3] = x[:3]
        np.testing.assert_allclose(lie.se3_exp(x), expm(M), atol=1e-12)
    np.testing.assert_allclose(lie.se3_log(lie.se3_exp(xi)), xi, atol=1e-11)
    np.testing.assert_allclose(lie.se3_log(np.eye(4)), np.zeros(6), atol=0)


def test_se3_compose_inverse_adjoint():
    rng = np.random.default_rng(5)
    T1, T2 = _random_T(rng, 2)
    np.testing.assert_allclose(lie.se3_compose(T1, T2), T1 @ T2)
    np.testing.assert_allclose(lie.se3_inverse(T1), np.linalg.inv(T1), atol=1e-13)
    xi = rng.normal(size=6)
    np.testing.assert_allclose(T1 @ lie.se3_exp(xi) @ np.linalg.inv(T1), lie.se3_exp(lie.se3_adjoint(T1) @ xi),
                               atol=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_se3_right_jacobian_inv_finite_differences(seed):
    rng = np.random.default_rng(seed)
    xi = np.concatenate([rng.normal(size=3), _random_w(rng, 1, 2.5)[0]])
    T = lie.se3_exp(xi)
    num = _num_jac(lambda d: lie.se3_log(T @ lie.se3_exp(d)), np.zeros(6))
    np.testing.assert_allclose(lie.se3_right_jacobian_inv(xi), num, atol=1e-7)
    for scale in (1e-5, 1e-9, 0.0):  # series branch
        x = scale * xi
        num = _num_jac(lambda d: lie.se3_log(lie.se3_exp(x) @ lie.se3_exp(d)), np.zeros(6))
        np.testing.assert_allclose(lie.se3_right_jacobian_inv(x), num, atol=1e-8)


def test_plus_minus_convention():
    rng = np.random.default_rng(6)
    T = _random_T(rng, 1)[0]
    delta = np.array([0.1, -0.2, 0.3, 0.05, 0.2, -0.1])
    P = lie.se3_plus(T, delta)
    R, t = T[:3, :3], T[:3, 3]
    np.testing.assert_allclose(P[:3, :3], R @ lie.so3_exp(delta[3:]))
    np.testing.assert_allclose(P[:3, 3], t + R @ delta[:3])
    np.testing.assert_allclose(lie.se3_minus(P, T), delta, atol=1e-14)
    # to first order the perturbation is the right-multiplied exponential
    d = 1e-7 * delta
    np.testing.assert_allclose(lie.se3_plus(T, d), T @ lie.se3_exp(d), atol=1e-13)


def test_batched_equals_looped():
    rng = np.random.default_rng(7)
    xi = rng.normal(size=(4, 5, 6))
    T = lie.se3_exp(xi)
    assert T.shape == (4, 5, 4, 4)
    for i in range(4):
        for j in range(5):
            np.testing.assert_allclose(T[i, j], lie.se3_exp(xi[i, j]), atol=1e-15)
            np.testing.assert_allclose(lie.se3_log(T)[i, j], lie.se3_log(T[i, j]), atol=1e-15)
            np.testing.assert_allclose(lie.se3_right_jacobian_inv(xi)[i, j], lie.se3_right_jacobian_inv(xi[i, j]))
    np.testing.assert_allclose(lie.so3_log(T[..., :3, :3])[1, 2], lie.so3_log(T[1, 2, :3, :3]), atol=1e-15)
    assert lie.se3_compose(T, T[0, 0]).shape == (4, 5, 4, 4)


def test_bad_inputs_name_the_argument():
    with pytest.raises(ValueError, match="w must"):
        lie.so3_exp([1.0, 2.0])
    with pytest.raises(ValueError, match="w must be finite"):
        lie.so3_exp([np.nan, 0, 0])
    with pytest.raises(ValueError, match="R must be a rotation"):
        lie.so3_log(2 * np.eye(3))
    with pytest.raises(ValueError, match="R must be a rotation"):
        lie.so3_log(np.diag([1.0, 1.0, -1.0]))
    bad = np.eye(4)
    bad[3, 0] = 1.0
    with pytest.raises(ValueError, match="T must be a homogeneous pose"):
        lie.se3_log(bad)
    with pytest.raises(ValueError, match="T1 must"):
        lie.se3_compose(np.eye(3), np.eye(4))
    with pytest.raises(ValueError, match="q must be non-zero"):
        lie.quat_to_so3(np.zeros(4))
    with pytest.raises(ValueError, match="delta must"):
        lie.se3_plus(np.eye(4), np.zeros(3))


def test_functions_do_not_modify_inputs():
    rng = np.random.default_rng(8)
    T = _random_T(rng, 3)
    T0 = T.copy()
    xi = rng.normal(size=(3, 6))
    xi0 = xi.copy()
    lie.se3_log(T), lie.se3_inverse(T), lie.se3_plus(T, xi), lie.se3_exp(xi), lie.se3_right_jacobian_inv(xi)
    np.testing.assert_array_equal(T, T0)
    np.testing.assert_array_equal(xi, xi0)


def test_top_level_rotations_are_lie_s():
    """Exercise 7's references ``sl.so3_exp``/``sl.so3_log`` are lie's functions, not a second copy."""
    import slamlib as sl

    assert sl.so3_exp is lie.so3_exp and sl.so3_log is lie.so3_log
