"""Tests of slamlib._checks: validation names the argument and what was expected."""

import numpy as np
import pytest

import slamlib as sl
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


@pytest.mark.parametrize("n", [2, 3, 4, 6, 8])
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
    assert not c.small_ok((), (), (np.eye(c.SMALL_COV + 1),))


@pytest.mark.parametrize("n", [4, 5, 6, 8])
def test_small_covariances_up_to_8x8_are_checked_without_an_eigendecomposition(n, monkeypatch):
    # a Cholesky factorisation decides from 4x4 to 8x8, so one filter step's checks stay cheap at every size
    rng = np.random.default_rng(n)
    B = rng.normal(size=(n, n))
    P = B @ B.T + np.eye(n)
    x, F = rng.normal(size=n), rng.normal(size=(n, n))

    def refuse(*args, **kwargs):
        raise AssertionError("eigvalsh called")

    monkeypatch.setattr(np.linalg, "eigvalsh", refuse)
    assert c.small_ok((x,), (F,), (P, P))
    c.as_covariance(P, "P", n, definite=True)
    c.as_covariance(P.tolist(), "P", n)  # the general path too
    # what the factorisation cannot accept still goes the long way, and is refused there
    monkeypatch.undo()
    for bad, match in ((P - 10 * np.abs(P).max() * np.eye(n), "positive semi-definite"),
                       (P + np.triu(np.ones((n, n)), 1), "symmetric")):
        assert not c.small_ok((x,), (F,), (bad, P))
        with pytest.raises(ValueError, match=match):
            c.as_covariance(bad, "P", n)



@pytest.mark.parametrize("n", [2, 3, 4, 5, 6, 8])
def test_small_ok_refuses_a_covariance_with_any_nonfinite_entry(n):
    # from 4x4 an exactly symmetric covariance is not scanned for NaN or infinity: the Cholesky
    # factorisation's pivots must reveal one in every place, in one triangle or in both
    rng = np.random.default_rng(40 + n)
    B = rng.normal(size=(n, n))
    P = B @ B.T + np.eye(n)
    assert c.small_ok((), (), (P,))
    for i in range(n):
        for j in range(i, n):
            for bad in (np.nan, np.inf, -np.inf):
                for both in (False, True):
                    Pb = P.copy()
                    Pb[i, j] = bad
                    if both:
                        Pb[j, i] = bad
                    assert not c.small_ok((), (), (Pb,)), (i, j, bad, both)
                    with pytest.raises(ValueError, match="P"):
                        c.as_covariance(Pb, "P", n)


def test_small_ok_remembers_only_the_values_it_accepted():
    # a covariance accepted once (a filter's noise) is accepted again without a second factorisation;
    # the same array changed in place is checked again, and a bad one still gets the error naming it
    rng = np.random.default_rng(44)
    n = 5
    B = rng.normal(size=(n, n))
    Q = B @ B.T + np.eye(n)
    P = Q + np.eye(n)
    x, F = rng.normal(size=n), rng.normal(size=(n, n))
    assert c.small_ok((x,), (F,), (P, Q))
    assert Q.tobytes() in c._ACCEPTED
    Q[0, 0] = -1.0  # in place: no longer positive definite
    assert not c.small_ok((x,), (F,), (P, Q))
    with pytest.raises(ValueError, match="Q must be positive semi-definite"):
        sl.kf_predict(x, P, F, Q)
    assert F.tobytes() in c._FINITE  # a model matrix found finite is remembered too, and checked again
    F[2, 1] = np.nan  # once changed in place
    assert not c.small_ok((x,), (F,), (P,))
    with pytest.raises(ValueError, match="F must be finite"):
        sl.kf_predict(x, P, F, P)
    F[2, 1] = 0.5
    for k in range(3 * c._N_ACCEPTED):  # a running filter's ever new P: the memory stays small
        assert c.small_ok((x,), (F + k,), (P + k * np.eye(n),))
    assert len(c._ACCEPTED) <= c._N_ACCEPTED and len(c._FINITE) <= c._N_ACCEPTED

# --------------------------------------------------------------------------- checks the filters and graphs share
def test_thresholds_choices_types_and_record_fields():
    import math
    from typing import NamedTuple

    assert c.as_threshold(9.2, "gate") == 9.2 and c.as_threshold(np.inf, "gate") == math.inf
    assert c.as_threshold(None, "gate", optional=True, none=math.inf) == math.inf
    assert c.as_threshold(None, "gate", optional=True) is None
    assert c.as_threshold(0.0, "gate") == 0.0
    for value, kw, exc, msg in [
        (None, {}, TypeError, "gate must be a real number"),  # None only where it is optional
        (-1.0, {}, ValueError, "gate must be non-negative"),
        (np.nan, {}, ValueError, "gate must be non-negative"),
        (0.0, dict(positive=True), ValueError, "gate must be positive"),
        (np.inf, dict(finite=True), ValueError, "gate must be finite"),
    ]:
        with pytest.raises(exc, match=msg):
            c.as_threshold(value, "gate", **kw)

    choices = {"S": "innovation covariance", "text": "the course text's erratum"}
    assert c.check_choice("text", "weight_cov", choices) == "text"
    with pytest.raises(ValueError, match=r"weight_cov must be 'S' \(innovation covariance\) or 'text' .*got 'R'"):
        c.check_choice("R", "weight_cov", choices)
    with pytest.raises(ValueError, match="weight_cov must be .*got 3"):
        c.check_choice(3, "weight_cov", choices)
    with pytest.raises(ValueError, match="weight_cov='Q' is gone: use 'text'"):
        c.check_choice("Q", "weight_cov", choices, removed={"Q": "use 'text'"})

    class Rec(NamedTuple):
        a: np.ndarray
        b: np.ndarray

    with pytest.raises(TypeError, match=r"state must be a Rec \(from make\), got tuple"):
        c.check_type((1, 2), Rec, "state", "from make")
    r = Rec(np.zeros((2, 3)), np.zeros(2))
    assert c.check_field_shapes(r, "state", {"a": (2, 3), "b": (2,)}) is r
    with pytest.raises(ValueError, match=r"state\.b must have shape \(3,\), got \(2,\)"):
        c.check_field_shapes(r, "state", {"a": (2, 3), "b": (3,)})
    with pytest.raises(ValueError, match=r"free must have shape \(2, 2\) \(to match belief\), got \(2, 3\)"):
        c.as_mask(np.ones((2, 3)), "free", ndim=2, shape=(2, 2), ref="belief")


def test_invertible_covariance_kernel_and_slam_state():
    Q = np.diag([0.1, 0.02]) ** 2
    np.testing.assert_array_equal(c.as_invertible_covariance(Q, "Q", 2, max_log_det=600.0), Q)
    np.testing.assert_array_equal(c.as_invertible_covariance(np.eye(3), "Q", 3, max_log_det=1.0), np.eye(3))
    with pytest.raises(ValueError, match="Q is out of the representable range: log det Q = -1382"):
        c.as_invertible_covariance(np.eye(2) * 1e-300, "Q", 2, max_log_det=600.0)
    with pytest.raises(ValueError, match="Q is out of the representable range: log det Q = 1382"):
        c.as_invertible_covariance(np.eye(2) * 1e300, "Q", 2, max_log_det=600.0)  # det overflows; slogdet does not
    with pytest.raises(ValueError, match="Q must be positive definite"):
        c.as_invertible_covariance(np.diag([1.0, 0.0]), "Q", 2, max_log_det=600.0)

    k = c.as_kernel([0.25, 0.5, 0.25], "kernel", 1)
    np.testing.assert_array_equal(k, [0.25, 0.5, 0.25])
    with pytest.raises(ValueError, match=r"kernel must have an odd length along every axis.*\(3, 2\)"):
        c.as_kernel(np.full((3, 2), 1 / 6), "kernel", 2)
    with pytest.raises(ValueError, match="kernel must sum to 1"):
        c.as_kernel([0.5, 0.5, 0.5], "kernel", 1)

    mu = np.arange(7.0)
    assert c.as_slam_mean(mu) is not mu and np.array_equal(c.as_slam_mean(mu), mu)
    for bad in (np.zeros(2), np.zeros(4), np.zeros((1, 5))):
        with pytest.raises(ValueError, match=r"mu must (have shape \(3\+2N,\)|have 1 dimensions)"):
            c.as_slam_mean(bad)
    m, S = c.as_slam_state(mu, np.eye(7), "mu_bar", "Sigma_bar")
    assert np.array_equal(S, np.eye(7))
    with pytest.raises(ValueError, match=r"Sigma_bar must have shape \(7, 7\).*\(to match mu_bar\)"):
        c.as_slam_state(mu, np.eye(5), "mu_bar", "Sigma_bar")
    with pytest.raises(ValueError, match="Sigma must be positive semi-definite"):
        c.as_slam_state(mu, -np.eye(7))


def test_rigid_transforms_and_index_sets():
    th = 0.3
    R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    R2, t2 = c.as_rigid_transform(R, [1.0, 2.0])
    assert np.array_equal(R2, R) and np.array_equal(t2, [1.0, 2.0])
    for bad in (2 * R, np.diag([1.0, -1.0])):  # not orthonormal; a reflection
        with pytest.raises(ValueError, match=r"T\.R must be a rotation matrix"):
            c.as_rigid_transform(bad, [0.0, 0.0], ("T.R", "T.t"))
    with pytest.raises(ValueError, match=r"T\.t must have shape \(2,\)"):
        c.as_rigid_transform(R, [0.0, 0.0, 0.0], ("T.R", "T.t"))

    assert c.as_index_set([3, np.int64(0), 3], "fixed", 4) == (0, 3)
    for value, exc, msg in [
        (3, TypeError, "fixed must be a sequence of pose indices, got int"),
        ([0, 1.0], TypeError, "fixed must hold integer pose indices, got 1.0"),
        ([True], TypeError, "fixed must hold integer pose indices"),
        ([0, 4], ValueError, r"fixed holds pose 4, outside 0\.\.3"),
        ([-1], ValueError, r"fixed holds pose -1, outside 0\.\.3"),
        ([], ValueError, "fixed must hold at least one pose: an anchor"),
    ]:
        with pytest.raises(exc, match=msg):
            c.as_index_set(value, "fixed", 4, what="pose", why="an anchor")


def test_edges_information_and_pose_graphs():
    e = c.as_edges([[0, 1], [1.0, 2.0]], "edges", 3)
    assert e.dtype == np.int64 and e.tolist() == [[0, 1], [1, 2]]
    assert c.as_edges(np.zeros((0, 2)), "edges", 3).shape == (0, 2)
    assert c.as_edges(np.zeros((0, 2), dtype=np.int32), "edges", 3).dtype == np.int64
    for value, exc, msg in [
        ([[0, 1.5]], TypeError, "edges must be an integer array of index pairs"),
        ([[0, 1, 2]], ValueError, r"edges must have shape \(E, 2\)"),
        ([[0, 1], [2, 3]], ValueError, r"edges\[1\] = \[2, 3\] refers to a pose outside 0\.\.2$"),
        ([[0, 1], [-1, 0]], ValueError, r"edges\[1\] = \[-1, 0\] refers to a pose outside"),
        ([[0, 1], [2, 2]], ValueError, r"edges\[1\] joins pose 2 to itself"),
    ]:
        with pytest.raises(exc, match=msg):
            c.as_edges(value, "edges", 3)
    # pairs of two kinds of node: the second bound is the second column's
    assert c.as_edges([[2, 4], [1, 1]], "obs", 3, 5).tolist() == [[2, 4], [1, 1]]
    with pytest.raises(ValueError, match=r"obs\[0\] = \[0, 5\] refers to a pose outside 0\.\.2 or a landmark outside 0\.\.4"):
        c.as_edges([[0, 5]], "obs", 3, 5)
    with pytest.raises(ValueError, match=r"obs\[1\] = \[3, 0\] refers to a pose outside"):
        c.as_edges([[0, 0], [3, 0]], "obs", 3, 5)

    W = np.stack([np.eye(3)] * 4)
    assert np.array_equal(c.as_information(W, "Omega", 4, 3), W)
    assert c.as_information(np.zeros((0, 2, 2)), "Omega", 0, 2).shape == (0, 2, 2)
    bad = W.copy()
    bad[2, 0, 1] = 0.5
    with pytest.raises(ValueError, match=r"Omega\[2\] must be symmetric"):
        c.as_information(bad, "Omega", 4, 3)
    bad = W.copy()
    bad[3] = np.diag([1.0, 1.0, 0.0])
    with pytest.raises(ValueError, match=r"Omega\[3\] must be positive definite"):
        c.as_information(bad, "Omega", 4, 3)
    with pytest.raises(ValueError, match=r"Omega must have shape \(5, 3, 3\)"):
        c.as_information(W, "Omega", 5, 3)

    X = np.zeros((3, 3))
    out = c.as_pose_graph(X, [[0, 1], [1, 2]], np.zeros((2, 3)), W[:2])
    assert [a.shape for a in out] == [(3, 3), (2, 2), (2, 3), (2, 3, 3)]
    with pytest.raises(ValueError, match="g.X must hold at least one pose"):
        c.as_pose_graph(np.zeros((0, 3)), [], np.zeros((0, 3)), W[:0], ("g.X", "g.e", "g.Z", "g.W"))
    with pytest.raises(ValueError, match=r"g\.Z must have shape \(2, 3\)"):
        c.as_pose_graph(X, [[0, 1], [1, 2]], np.zeros((3, 3)), W[:2], ("g.X", "g.e", "g.Z", "g.W"))
    with pytest.raises(ValueError, match=r"g\.e\[0\] = \[0, 3\]"):
        c.as_pose_graph(X, [[0, 3]], np.zeros((1, 3)), W[:1], ("g.X", "g.e", "g.Z", "g.W"))


def test_range_bearing_measurement():
    np.testing.assert_array_equal(c.as_range_bearing([2.0, -0.5]), [2.0, -0.5])
    for bad, msg in (([0.0, 0.1], r"z must have a positive range z\[0\], got 0.0"),
                     ([-1.0, 0.1], "z must have a positive range"), ([1.0, np.nan], "z must be finite"),
                     ([1.0, 0.1, 0.0], r"z must have shape \(2,\)")):
        with pytest.raises(ValueError, match=msg):
            c.as_range_bearing(bad)
