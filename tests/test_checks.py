"""Tests of slamlib._checks: validation names the argument and what was expected."""

import numpy as np
import pytest

from slamlib import _checks as c


def test_as_array_copies_and_converts():
    src = np.array([1, 2, 3])
    out = c.as_array(src, "v", (3,))
    assert out.dtype == np.float64
    out[0] = 99
    assert src[0] == 1
    np.testing.assert_array_equal(c.as_array([[1.0, 2.0]], "v", (None, 2)), [[1.0, 2.0]])
    assert c.as_array(np.zeros((2, 3, 4)), "v", ndim=(2, 3)).shape == (2, 3, 4)
    assert np.isnan(c.as_array([np.nan], "v", finite=False)[0])


@pytest.mark.parametrize("value, kw, exc, msg", [
    ([1.0, 2.0], dict(shape=(3,)), ValueError, r"v must have shape \(3,\), got \(2,\)"),
    (np.zeros((2, 2)), dict(shape=(None, 3)), ValueError, r"v must have shape \(\*, 3\)"),
    (np.zeros(4), dict(ndim=2), ValueError, "v must have 2 dimensions"),
    ([1.0, np.nan], dict(), ValueError, "v must be finite"),
    ([1.0, np.inf], dict(), ValueError, "v must be finite"),
    ("abc", dict(), TypeError, "v must be a numeric array"),
    (None, dict(), TypeError, "v must be a numeric array"),
    ([1 + 1j], dict(), TypeError, "v must hold real numbers"),
    ([[1, 2], [3]], dict(), ValueError, "v must be a numeric array"),
])
def test_as_array_errors(value, kw, exc, msg):
    with pytest.raises(exc, match=msg):
        c.as_array(value, "v", **kw)


def test_as_scalar():
    assert c.as_scalar(3, "s") == 3.0 and isinstance(c.as_scalar(np.float32(2.5), "s"), float)
    assert c.as_scalar(np.array(1.5), "s") == 1.5
    for value, kw, exc, msg in [
        (True, {}, TypeError, "s must be a real number"),
        ("1", {}, TypeError, "s must be a real number"),
        (np.ones(2), {}, ValueError, "s must be a real scalar"),
        (np.nan, {}, ValueError, "s must be finite"),
        (0.0, dict(positive=True), ValueError, "s must be positive"),
        (-1e-9, dict(nonnegative=True), ValueError, "s must be non-negative"),
    ]:
        with pytest.raises(exc, match=msg):
            c.as_scalar(value, "s", **kw)
    assert c.as_scalar(np.inf, "s", finite=False) == np.inf


def test_as_covariance():
    np.testing.assert_array_equal(c.as_covariance(np.eye(2), "M", 2), np.eye(2))
    c.as_covariance(np.zeros((2, 2)), "M", 2)  # semi-definite is fine
    with pytest.raises(ValueError, match="M must be symmetric"):
        c.as_covariance([[1.0, 0.5], [0.0, 1.0]], "M", 2)
    with pytest.raises(ValueError, match="M must be positive semi-definite"):
        c.as_covariance([[1.0, 2.0], [2.0, 1.0]], "M", 2)
    with pytest.raises(ValueError, match=r"M must have shape \(3, 3\)"):
        c.as_covariance(np.eye(2), "M", 3)


def test_check_rng():
    g = np.random.default_rng(0)
    assert c.check_rng(g) is g
    for bad in (None, 0, np.random.RandomState(0), np.random):
        with pytest.raises(TypeError, match="rng must be a numpy.random.Generator"):
            c.check_rng(bad)
    with pytest.raises(TypeError, match="gen must be"):
        c.check_rng(1, "gen")


def test_as_index():
    assert c.as_index(np.int64(3), "j", 5) == 3
    with pytest.raises(ValueError, match=r"j must be in \[0, 5\), got 5"):
        c.as_index(5, "j", 5)
    with pytest.raises(ValueError, match=r"j must be >= 0, got -1"):
        c.as_index(-1, "j")
    with pytest.raises(TypeError, match="j must be an integer"):
        c.as_index(1.0, "j")
    with pytest.raises(TypeError, match="j must be an integer"):
        c.as_index(True, "j")
