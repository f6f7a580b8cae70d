"""Tests of slamlib.metrics."""

import numpy as np
import pytest
from scipy import stats

import slamlib as sl


def test_pose_error_wraps_heading():
    e = sl.pose_error(np.array([[1.0, 2.0, 3.1]]), np.array([[0.5, 2.5, -3.1]]))
    np.testing.assert_allclose(e, [[0.5, -0.5, 6.2 - 2 * np.pi]], atol=1e-12)
    assert sl.pose_error([0, 0, 0], [0, 0, 0]).shape == (3,)


def test_rmse_values():
    true = np.zeros((4, 3))
    est = np.array([[3.0, 4.0, 0.1], [0.0, 0.0, -0.1], [0.0, 0.0, 2 * np.pi + 0.1], [0.0, 0.0, 0.1]])
    assert sl.ate_rmse(est, true) == pytest.approx(np.sqrt(25 / 4))
    assert sl.heading_rmse(est, true) == pytest.approx(0.1)
    assert sl.landmark_rmse(np.array([[1.0, 1.0], [0.0, 0.0]]), np.zeros((2, 2))) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="true"):
        sl.ate_rmse(est, np.zeros((3, 3)))


def test_nees_is_chi_square_for_consistent_errors():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(3, 3))
    P = A @ A.T + 0.5 * np.eye(3)
    err = rng.multivariate_normal(np.zeros(3), P, size=5000)
    v = sl.nees(err, P)
    assert v.shape == (5000,)
    assert v.mean() == pytest.approx(3.0, abs=4 * np.sqrt(6 / 5000))
    assert stats.kstest(v, stats.chi2(3).cdf).pvalue > 0.01
    # batched covariances
    Ps = np.broadcast_to(P, (5, 3, 3))
    np.testing.assert_allclose(sl.nees(err[:5], Ps), [e @ np.linalg.solve(P, e) for e in err[:5]])


def test_nees_band_coverage():
    lo, hi = sl.nees_band(3, 50, p=0.95)
    assert lo < 3.0 < hi
    rng = np.random.default_rng(1)
    avg = rng.chisquare(3, size=(20000, 50)).mean(axis=1)
    inside = np.mean((avg >= lo) & (avg <= hi))
    assert inside == pytest.approx(0.95, abs=0.01)
    np.testing.assert_allclose([lo, hi], np.array(stats.chi2.interval(0.95, 150)) / 50)


def test_bad_inputs():
    with pytest.raises(ValueError, match="P"):
        sl.nees(np.ones(3), np.eye(2))
    with pytest.raises(ValueError, match="P"):
        sl.nees(np.ones(2), -np.eye(2))
    with pytest.raises(ValueError, match="p"):
        sl.nees_band(3, 10, p=1.5)
    with pytest.raises(TypeError, match="dof"):
        sl.nees_band(2.0, 10)
    with pytest.raises(ValueError, match="est"):
        sl.pose_error(np.zeros(2), np.zeros(3))
    with pytest.raises(ValueError, match="err"):
        sl.nees(np.array([np.nan, 0.0]), np.eye(2))


def test_nees_refuses_asymmetric_or_indefinite_P():
    with pytest.raises(ValueError, match="P must be symmetric"):
        sl.nees(np.ones(2), [[1.0, 0.5], [0.0, 1.0]])
    with pytest.raises(ValueError, match="P must be positive definite"):
        sl.nees(np.ones(2), [[1.0, 2.0], [2.0, 1.0]])
    with pytest.raises(ValueError, match=r"P must have shape \(3, 3\).*\(to match err\)"):
        sl.nees(np.ones(3), np.eye(2))
    with pytest.raises(ValueError, match=r"est \(4, 3\), true \(3, 3\)"):
        sl.pose_error(np.zeros((4, 3)), np.zeros((3, 3)))
