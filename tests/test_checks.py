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


# --------------------------------------------------------------------------- covariances: the fast path agrees with the full check
def _full_check(A, definite):
    """The definition: symmetric within 1e-9 and eigenvalues above -1e-9 max|eig| (or above 0 when definite)."""
    if np.abs(A - A.T).max() > c.SYM_RTOL * max(1.0, np.abs(A).max()):
        return False
    eig = np.linalg.eigvalsh(A)
    if definite:
        return eig.min() > 0
    return eig.min() >= -c.PSD_RTOL * max(1.0, np.abs(eig).max())


@pytest.mark.parametrize("n", [2, 3])
def test_as_covariance_small_path_agrees_with_eigenvalues(n):
    rng = np.random.default_rng(n)
    accepted = rejected = 0
    for k in range(3000):
        B = rng.normal(size=(n, n)) * 10.0 ** rng.integers(-4, 4)
        kind = k % 4
        if kind == 0:
            A = B @ B.T  # PD (or nearly singular)
        elif kind == 1:
            A = B + B.T  # indefinite mostly
        elif kind == 2:
            v = B[:, :1]
            A = v @ v.T  # rank one: PSD, singular
        else:
            A = B @ B.T
            A[0, -1] += 1e-6 * (1.0 + abs(A[0, -1]))  # slightly asymmetric
        for definite in (False, True):
            want = _full_check(A, definite)
            try:
                c.as_covariance(A, "A", n, definite=definite)
                got = True
            except ValueError:
                got = False
            assert got == want, (A, definite)
            accepted += got
            rejected += not got
    assert accepted > 1000 and rejected > 1000  # both branches exercised


def test_as_covariance_small_path_rejects_nonfinite():
    for bad in (np.nan, np.inf, -np.inf):
        for i in range(3):
            for j in range(3):
                A = np.eye(3)
                A[i, j] = bad
                with pytest.raises(ValueError, match="A must be finite"):
                    c.as_covariance(A, "A", 3)


def test_as_covariance_batched_copy_and_messages():
    P = np.stack([np.eye(3), 2 * np.eye(3)])
    with pytest.raises(ValueError, match=r"A must have shape \(3, 3\), got \(2, 3, 3\)"):
        c.as_covariance(P, "A", 3)
    out = c.as_covariance(P, "A", 3, batched=True)
    assert out is not P and np.array_equal(out, P)
    assert c.as_covariance(P, "A", 3, batched=True, copy=False) is P
    bad = P.copy()
    bad[1, 2, 2] = -1.0
    with pytest.raises(ValueError, match="A must be positive semi-definite"):
        c.as_covariance(bad, "A", 3, batched=True)
    with pytest.raises(ValueError, match="A must be positive definite"):
        c.as_covariance(np.zeros((2, 2)), "A", 2, definite=True)
    with pytest.raises(ValueError, match=r"A must have shape \(2, 2\) or \(\.\.\., 2, 2\) \(to match z\)"):
        c.as_covariance(np.eye(3), "A", 2, ref="z")


def test_vectors_and_matrices():
    x = np.array([1.0, 2.0])
    assert c.as_vector(x, "x", 2, copy=False) is x
    assert c.as_vector(x, "x", 2) is not x
    np.testing.assert_array_equal(c.as_vector([[1, 2], [3, 4]], "x", 2), [[1.0, 2.0], [3.0, 4.0]])
    with pytest.raises(ValueError, match=r"x must have shape \(3,\) or \(\.\.\., 3\), got \(2,\)"):
        c.as_vector(x, "x", 3)
    with pytest.raises(ValueError, match="x must have shape"):
        c.as_vector(1.0, "x", 3)
    with pytest.raises(ValueError, match="x must be finite"):
        c.as_vector([1.0, np.nan], "x")
    with pytest.raises(ValueError, match=r"F must have shape \(2, 3\)"):
        c.as_matrix(np.eye(3), "F", 2, 3)
    with pytest.raises(ValueError, match="F must be a matrix"):
        c.as_matrix(x, "F")
    big = np.full(4, 1e308)  # a sum that overflows is not mistaken for an infinite entry
    assert c.as_vector(big, "x") is not None


def test_batches_rows_and_broadcasts_name_both_arguments():
    a, b = np.zeros((4, 3)), np.zeros((5, 3, 3))
    with pytest.raises(ValueError, match=r"a \(4, 3\), b \(5, 3, 3\)"):
        c.check_batch((a, 1, "a"), (b, 2, "b"))
    assert c.check_batch((np.zeros(3), 1, "a"), (np.eye(3), 2, "b")) == ()
    assert c.check_batch((a, 1, "a"), (np.zeros((1, 3, 3)), 2, "b")) == (4,)
    with pytest.raises(ValueError, match=r"m must have one row per row of z \(2\), got 3"):
        c.check_rows((np.zeros((2, 2)), "z"), (np.zeros((3, 2)), "m"))
    with pytest.raises(ValueError, match=r"a \(2,\), b \(3,\)"):
        c.check_broadcast((np.zeros(2), "a"), (np.zeros(3), "b"))


def test_poses_weights_probabilities_counts_indices():
    assert c.as_poses([[0, 0, 0]], "p").shape == (1, 3)
    with pytest.raises(ValueError, match=r"p must have shape \(\*, 3\)"):
        c.as_poses(np.zeros((2, 2)), "p")
    with pytest.raises(ValueError, match="p must hold at least one pose"):
        c.as_poses(np.zeros((0, 3)), "p", allow_empty=False)
    assert c.as_poses(np.zeros((2, 5, 3)), "p", batched=True).shape == (2, 5, 3)
    np.testing.assert_allclose(c.as_weights([1.0, 3.0], "w"), [0.25, 0.75])
    for bad, msg in (([], "at least one"), ([-1.0, 2.0], "non-negative"), ([0.0, 0.0], "positive sum"),
                     ([1e308, 1e308], "sums to infinity")):
        with pytest.raises(ValueError, match=f"w .*{msg}|w {msg}|w must {msg}|{msg}"):
            c.as_weights(bad, "w")
    for bad, msg in (([], "at least one"), ([np.nan, 0.0], "NaN"), ([np.inf, 0.0], r"\+inf"),
                     ([-np.inf, -np.inf], "every log-weight is -inf")):
        with pytest.raises(ValueError, match=msg):
            c.as_log_weights(bad, "lw")
    with pytest.raises(ValueError, match=r"lw must have shape \(3,\) \(to match poses\)"):
        c.as_log_weights(np.zeros(2), "lw", 3, ref="poses")
    assert c.as_probability(0.5, "p") == 0.5
    with pytest.raises(ValueError, match=r"p must be a probability in \[0, 1\]"):
        c.as_probability(1.5, "p")
    with pytest.raises(ValueError, match="d must sum to 1"):
        c.as_probabilities([0.5, 0.6], "d", sums_to_one=True)
    with pytest.raises(ValueError, match=r"d must hold probabilities in \[0, 1\]"):
        c.as_probabilities([0.5, 1.6], "d")
    assert c.as_count(np.int32(3), "n") == 3
    for bad, exc in ((-1, ValueError), (2.5, TypeError), (True, TypeError), ("3", TypeError)):
        with pytest.raises(exc, match="n must"):
            c.as_count(bad, "n")
    np.testing.assert_array_equal(c.as_indices([], "ids", 3), np.zeros(0, dtype=np.intp))
    with pytest.raises(ValueError, match=r"ids must hold indices in \[0, 3\)"):
        c.as_indices([0, 3], "ids", 3)
    with pytest.raises(TypeError, match="ids must be an integer array"):
        c.as_indices([0.5], "ids", 3)
    with pytest.raises(ValueError, match=r"ids must have shape \(2,\) \(to match z\)"):
        c.as_indices([0], "ids", 3, (2,), ref="z")


def test_rows_masks_types_and_bools():
    assert c.as_rows([], "z", 2).shape == (0, 2)
    with pytest.raises(ValueError, match=r"z must have shape \(K, 2\)"):
        c.as_rows(np.zeros((2, 3)), "z", 2)
    np.testing.assert_array_equal(c.as_mask([0, 1, 1.0], "f"), [False, True, True])
    with pytest.raises(ValueError, match="f must hold booleans"):
        c.as_mask([0, 2], "f")
    assert c.check_type(3, int, "k") == 3
    with pytest.raises(TypeError, match="k must be a int or float, got str"):
        c.check_type("a", (int, float), "k")
    with pytest.raises(TypeError, match="s must hold real numbers"):
        c.as_array(True, "s", bools=False)
    with pytest.raises(ValueError, match="s must be non-negative"):
        c.as_array([1.0, -2.0], "s", nonnegative=True)


def test_small_ok_never_passes_what_the_full_checks_refuse():
    rng = np.random.default_rng(5)
    passed = 0
    for k in range(2000):
        n = 3
        x = rng.normal(size=n)
        F = rng.normal(size=(n, n))
        B = rng.normal(size=(n, n))
        P = B @ B.T if k % 3 else B + B.T
        Q = np.diag(rng.uniform(-0.1, 1.0, n))
        for arr in (x, F, P, Q):
            if rng.random() < 0.1:
                arr.flat[rng.integers(arr.size)] = rng.choice([np.nan, np.inf, -np.inf, 1e308])
        ok = c.small_ok((x,), (F,), (P, Q))
        try:
            c.as_vector(x, "x")
            c.as_matrix(F, "F")
            c.as_covariance(P, "P", 3, definite=True)
            c.as_covariance(Q, "Q", 3, definite=True)
            full = True
        except ValueError:
            full = False
        assert not ok or full
        passed += ok
    assert passed > 300
    assert not c.small_ok((np.zeros(3, dtype=np.float32),))  # anything unusual goes the long way
    assert not c.small_ok((), (np.zeros(3),))
    assert not c.small_ok((), (), (np.eye(4),))
