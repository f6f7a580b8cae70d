"""Tests of slamlib.angles."""

import numpy as np
import pytest
from scipy import stats

import slamlib as sl


def test_wrap_angle_range_and_values():
    a = np.linspace(-50, 50, 10001)
    w = sl.wrap_angle(a)
    assert np.all((w >= -np.pi) & (w < np.pi))
    np.testing.assert_allclose(np.sin(w), np.sin(a), atol=1e-12)
    np.testing.assert_allclose(np.cos(w), np.cos(a), atol=1e-12)
    assert sl.wrap_angle(np.pi) == -np.pi
    assert sl.wrap_angle(-np.pi) == -np.pi
    assert sl.wrap_angle(0.0) == 0.0
    assert isinstance(sl.wrap_angle(1.0), float)
    # tiny negative angles must not come back as +pi
    assert sl.wrap_angle(-1e-18) < np.pi
    assert sl.wrap_angle(np.zeros((2, 3))).shape == (2, 3)


def test_angle_diff():
    assert sl.angle_diff(np.pi - 0.1, -np.pi + 0.1) == pytest.approx(-0.2)
    assert sl.angle_diff(-np.pi + 0.1, np.pi - 0.1) == pytest.approx(0.2)
    np.testing.assert_allclose(sl.angle_diff(np.array([0.0, 1.0]), 1.0), [-1.0, 0.0])


def test_circular_mean():
    # across the cut the mean is pi (returned as -pi), not 0
    assert abs(sl.angle_diff(sl.circular_mean(np.array([np.pi - 0.1, -np.pi + 0.1])), np.pi)) < 1e-12
    assert sl.circular_mean(np.array([0.1, 0.3]), weights=np.array([3.0, 1.0])) == pytest.approx(
        np.arctan2(3 * np.sin(0.1) + np.sin(0.3), 3 * np.cos(0.1) + np.cos(0.3)))
    rng = np.random.default_rng(0)
    a = sl.wrap_angle(3.0 + rng.vonmises(0.0, 4.0, size=(20000,)))
    assert sl.angle_diff(sl.circular_mean(a), 3.0) == pytest.approx(0.0, abs=0.02)
    m = sl.circular_mean(np.stack([a[:100], a[100:200]]), axis=1)
    assert m.shape == (2,)
    # KS: wrapped von Mises around the circular mean
    assert stats.kstest(sl.angle_diff(a, 3.0), stats.vonmises(4.0).cdf).pvalue > 0.01


def test_bad_inputs():
    with pytest.raises(ValueError, match="a must be finite"):
        sl.wrap_angle(np.nan)
    with pytest.raises(ValueError, match="weights"):
        sl.circular_mean(np.zeros(3), weights=-np.ones(3))
    with pytest.raises(TypeError, match="angles"):
        sl.circular_mean("abc")


def test_inputs_not_modified():
    a = np.array([4.0, -7.0])
    a.setflags(write=False)
    sl.wrap_angle(a)
    sl.angle_diff(a, a)
    sl.circular_mean(a)
    np.testing.assert_array_equal(a, [4.0, -7.0])


def test_circular_mean_refuses_zero_weights_and_empty_input():
    with pytest.raises(ValueError, match="weights must not all be zero"):
        sl.circular_mean(np.array([0.1, 0.2]), weights=np.zeros(2))
    with pytest.raises(ValueError, match="weights must not all be zero"):
        sl.circular_mean(np.ones((2, 3)), weights=np.array([[1.0, 1.0, 1.0], [0.0, 0.0, 0.0]]), axis=1)
    with pytest.raises(ValueError, match="angles must hold at least one angle"):
        sl.circular_mean(np.zeros(0))
    with pytest.raises(ValueError, match="axis must be in"):
        sl.circular_mean(np.zeros(3), axis=1)
    with pytest.raises(ValueError, match=r"shapes do not broadcast: a \(2,\), b \(3,\)"):
        sl.angle_diff(np.zeros(2), np.zeros(3))
