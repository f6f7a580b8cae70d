"""Tests of slamlib.motion against theory: Jacobians, limits, moments, densities."""

import numpy as np
import pytest
from scipy import stats

import slamlib as sl
from slamlib import motion


def ro(a):
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


def naive_arc(x, u, dt):
    """Table 5.3 as printed (divides by omega)."""
    v, w = u
    r = v / w
    th = x[2]
    return np.array([x[0] - r * np.sin(th) + r * np.sin(th + w * dt), x[1] + r * np.cos(th) - r * np.cos(th + w * dt), th + w * dt])


def naive_V(x, u, dt):
    v, w = u
    th = x[2]
    s0, c0, s1, c1 = np.sin(th), np.cos(th), np.sin(th + w * dt), np.cos(th + w * dt)
    return np.array([
        [(-s0 + s1) / w, v * (s0 - s1) / w**2 + v * c1 * dt / w],
        [(c0 - c1) / w, -v * (c0 - c1) / w**2 + v * s1 * dt / w],
        [0.0, dt],
    ])


def fd_jac(f, x0, h=1e-6, wrap_last=True):
    cols = []
    for i in range(len(x0)):
        e = np.zeros(len(x0))
        e[i] = h
        d = f(x0 + e) - f(x0 - e)
        if wrap_last:
            d[-1] = sl.wrap_angle(d[-1])
        cols.append(d / (2 * h))
    return np.stack(cols, axis=-1)


# ---------------------------------------------------------------- velocity_motion
@pytest.mark.parametrize("u", [(1.3, 0.7), (-0.8, 1.9), (2.0, -0.4), (1.0, 0.0), (0.5, 3e-7)])
def test_velocity_motion_jacobians_match_finite_differences(u):
    x = np.array([0.4, -1.2, 2.9])
    dt = 0.7
    _, G, V = sl.velocity_motion(x, np.array(u), dt)
    # G and V are the derivatives of the branch the point lies in; keep the FD inside it
    Gfd = fd_jac(lambda xx: sl.velocity_motion(xx, np.array(u), dt)[0], x)
    h = 1e-8 if abs(u[1]) < 1e-6 else 1e-6
    Vfd = fd_jac(lambda uu: sl.velocity_motion(x, uu, dt)[0], np.array(u, float), h=h)
    np.testing.assert_allclose(G, Gfd, atol=1e-7)
    if abs(u[1]) < 1e-6:
        # the omega column in the straight-line branch is the contract's limit, FD only on v
        np.testing.assert_allclose(V[:, 0], Vfd[:, 0], atol=1e-7)
    else:
        np.testing.assert_allclose(V, Vfd, atol=1e-6)


def test_velocity_motion_matches_table_5_3():
    rng = np.random.default_rng(0)
    for _ in range(50):
        x = rng.uniform([-5, -5, -np.pi], [5, 5, np.pi])
        u = rng.uniform([-2, -2], [2, 2])
        dt = rng.uniform(0.05, 2.0)
        xn, _, V = sl.velocity_motion(x, u, dt)
        ref = naive_arc(x, u, dt)
        np.testing.assert_allclose(xn[:2], ref[:2], atol=1e-12)
        assert abs(sl.angle_diff(xn[2], ref[2])) < 1e-12
        np.testing.assert_allclose(V, naive_V(x, u, dt), atol=1e-9)


def test_velocity_motion_straight_line_branch_is_contract():
    x = np.array([1.0, 2.0, 0.6])
    v, dt = 1.7, 0.9
    for w in (0.0, 5e-7, -9.9e-7):
        xn, G, V = sl.velocity_motion(x, np.array([v, w]), dt)
        c, s = np.cos(x[2]), np.sin(x[2])
        np.testing.assert_allclose(xn, [x[0] + v * dt * c, x[1] + v * dt * s, sl.wrap_angle(x[2] + w * dt)], atol=1e-15)
        np.testing.assert_allclose(G, [[1, 0, -v * dt * s], [0, 1, v * dt * c], [0, 0, 1]], atol=1e-15)
        np.testing.assert_allclose(V, [[dt * c, -v * dt**2 * s / 2], [dt * s, v * dt**2 * c / 2], [0, dt]], atol=1e-15)


def test_velocity_motion_continuous_across_threshold():
    x = np.array([0.3, -0.2, -2.2])
    v, dt = 2.5, 1.3
    for sign in (1, -1):
        below = sl.velocity_motion(x, np.array([v, sign * np.nextafter(1e-6, 0)]), dt)
        above = sl.velocity_motion(x, np.array([v, sign * 1e-6]), dt)
        for a, b in zip(below, above):
            # the branches differ by O(v dt^2 omega) = O(1e-6)
            np.testing.assert_allclose(a, b, atol=5e-6 * v * dt**2)


def test_velocity_V_near_zero_within_contract_tolerance():
    """For 1e-6 <= |omega| < 1e-2 the printed arc formula and ours agree to 1e-3 relative."""
    x = np.array([0.0, 0.0, 0.8])
    v, dt = 1.1, 0.5
    for w in np.r_[np.logspace(-6, -2.01, 20), -np.logspace(-6, -2.01, 20)]:
        _, _, V = sl.velocity_motion(x, np.array([v, w]), dt)
        Vn = naive_V(x, (v, w), dt)
        scale = np.abs(V).max()
        assert np.max(np.abs(V - Vn)) <= 1e-3 * scale
        # and against the omega -> 0 limit, to first order in omega dt
        _, _, V0 = sl.velocity_motion(x, np.array([v, 0.0]), dt)
        assert np.max(np.abs(V - V0)) <= abs(w) * dt * scale


def test_velocity_motion_batched_equals_looped_and_wraps():
    rng = np.random.default_rng(1)
    x = rng.uniform([-3, -3, -np.pi], [3, 3, np.pi], size=(4, 5, 3))
    u = rng.uniform([-1, -3], [1, 3], size=(5, 2))
    u[0, 1] = 0.0
    xn, G, V = sl.velocity_motion(ro(x), ro(u), 0.8)
    assert xn.shape == (4, 5, 3) and G.shape == (4, 5, 3, 3) and V.shape == (4, 5, 3, 2)
    for i in range(4):
        for j in range(5):
            a, b, c = sl.velocity_motion(x[i, j], u[j], 0.8)
            np.testing.assert_allclose(xn[i, j], a, atol=1e-14)
            np.testing.assert_allclose(G[i, j], b, atol=1e-14)
            np.testing.assert_allclose(V[i, j], c, atol=1e-14)
    assert np.all((xn[..., 2] >= -np.pi) & (xn[..., 2] < np.pi))


def test_velocity_motion_full_circle_returns_home():
    x = np.array([1.0, 1.0, 0.3])
    n = 200
    w = 2 * np.pi / n
    for _ in range(n):
        x, _, _ = sl.velocity_motion(x, np.array([0.5, w]), 1.0)
    np.testing.assert_allclose(x[:2], [1.0, 1.0], atol=1e-10)
    assert abs(sl.angle_diff(x[2], 0.3)) < 1e-10


def test_velocity_noise_cov():
    M = sl.velocity_noise_cov(ro([2.0, 0.5]), ro([0.1, 0.2, 0.3, 0.4]))
    np.testing.assert_allclose(M, [[0.1 * 4 + 0.2 * 0.25, 0], [0, 0.3 * 4 + 0.4 * 0.25]])
    Mb = sl.velocity_noise_cov(np.array([[2.0, 0.5], [1.0, -1.0]]), [0.1, 0.2, 0.3, 0.4])
    assert Mb.shape == (2, 2, 2)
    np.testing.assert_allclose(Mb[0], M)


# ---------------------------------------------------------------- velocity sampler / density
def test_sample_velocity_first_order_moments():
    """Small noise: x' ~ N(f(x,u), V M V^T + gamma term), checked by moments."""
    rng = np.random.default_rng(2)
    x = np.array([0.5, -0.5, 0.4])
    u = np.array([1.0, 0.5])
    dt = 1.0
    alpha = np.array([1e-4, 1e-4, 2e-4, 2e-4, 5e-5, 5e-5])
    n = 200_000
    X = sl.sample_motion_model_velocity(ro(np.tile(x, (n, 1))), ro(u), dt, ro(alpha), rng=rng)
    mean, _, V = sl.velocity_motion(x, u, dt)
    M = sl.velocity_noise_cov(u, alpha[:4])
    C = V @ M @ V.T
    C[2, 2] += (alpha[4] * u[0] ** 2 + alpha[5] * u[1] ** 2) * dt**2
    err = X - mean
    err[:, 2] = sl.wrap_angle(err[:, 2])
    # mean: sampling error plus the second-order bias, O(var(omega) v dt^3)
    bias = (M[1, 1] * u[0] * dt**3 + M[0, 0] * dt) / 2
    assert np.all(np.abs(err.mean(axis=0)) <= 4 * np.sqrt(np.diag(C) / n) + bias)
    np.testing.assert_allclose(np.cov(err.T), C, rtol=0.03, atol=1e-7)


def test_sample_velocity_heading_ks_and_single_pose():
    rng = np.random.default_rng(3)
    alpha = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.2])
    u = np.array([1.0, 1.5])
    dt = 0.5
    X = sl.sample_motion_model_velocity(np.zeros((5000, 3)), u, dt, alpha, rng=rng)
    # only gamma is noisy: theta' = wrap(omega dt + N(0, a6 w^2) dt)
    d = sl.angle_diff(X[:, 2], u[1] * dt)
    sd = np.sqrt(alpha[5] * u[1] ** 2) * dt
    assert stats.kstest(d / sd, "norm").pvalue > 0.01
    one = sl.sample_motion_model_velocity(np.zeros(3), u, dt, alpha, rng=np.random.default_rng(0))
    assert one.shape == (3,)


def test_motion_model_velocity_inverts_the_arc():
    rng = np.random.default_rng(4)
    alpha = np.full(6, 0.05)
    for _ in range(20):
        x = rng.uniform([-2, -2, -np.pi], [2, 2, np.pi])
        u = rng.uniform([-1.5, -2], [1.5, 2])
        dt = 0.5
        xn, _, _ = sl.velocity_motion(x, u, dt)
        v_hat, w_hat, g_hat = motion._velocity_inverse(xn, x, dt)
        np.testing.assert_allclose([v_hat, w_hat, g_hat], [u[0], u[1], 0.0], atol=1e-9)


def test_motion_model_velocity_integrates_to_one_with_jacobian():
    """Table 5.1 is a density of (v_hat, w_hat, gamma_hat); over x' it needs 1/|J|."""
    x = np.array([0.0, 0.0, 0.3])
    u = np.array([1.0, 0.8])
    dt = 1.0
    alpha = np.array([0.004, 0.002, 0.004, 0.002, 0.002, 0.002])
    mean, _, _ = sl.velocity_motion(x, u, dt)
    # integrate over a box of +-5 sigma around the mean
    rng = np.random.default_rng(5)
    S = sl.sample_motion_model_velocity(np.tile(x, (20000, 1)), u, dt, alpha, rng=rng)
    sd = S.std(axis=0)
    axes = [np.linspace(mean[i] - 6 * sd[i], mean[i] + 6 * sd[i], 61) for i in range(3)]
    gx, gy, gt = np.meshgrid(*axes, indexing="ij")
    pts = np.stack([gx, gy, gt], -1).reshape(-1, 3)
    p = sl.motion_model_velocity(pts, u, x, dt, alpha)
    v_hat, w_hat, _ = motion._velocity_inverse(pts, x, dt)
    jac = np.abs(v_hat) * dt**4 * np.sinc(w_hat * dt / 2 / np.pi) ** 2 / 2
    cell = np.prod([a[1] - a[0] for a in axes])
    total = np.sum(p / jac) * cell
    assert abs(total - 1.0) < 0.02


def test_motion_model_velocity_log_and_shape():
    x = np.zeros((7, 3))
    xn = np.tile([1.0, 0.1, 0.2], (7, 1))
    p = sl.motion_model_velocity(ro(xn), ro([1.0, 0.2]), ro(x), 1.0, ro(np.full(6, 0.1)))
    lp = sl.motion_model_velocity(xn, [1.0, 0.2], x, 1.0, np.full(6, 0.1), log=True)
    assert p.shape == (7,)
    np.testing.assert_allclose(np.log(p), lp)


# ---------------------------------------------------------------- odometry
def test_odometry_from_poses_roundtrip_and_convention():
    rng = np.random.default_rng(6)
    a = rng.uniform([-5, -5, -np.pi], [5, 5, np.pi], size=(100, 3))
    b = rng.uniform([-5, -5, -np.pi], [5, 5, np.pi], size=(100, 3))
    u = sl.odometry_from_poses(ro(a), ro(b))
    assert u.shape == (100, 3) and np.all(u[:, 1] >= 0)
    back = sl.odometry_motion(a, u)
    np.testing.assert_allclose(back[:, :2], b[:, :2], atol=1e-12)
    np.testing.assert_allclose(sl.angle_diff(back[:, 2], b[:, 2]), 0, atol=1e-12)
    # rotation on the spot: rot1 = 0, the whole turn is rot2
    u0 = sl.odometry_from_poses([1.0, 2.0, 3.0], [1.0, 2.0, -3.0])
    np.testing.assert_allclose(u0, [0.0, 0.0, sl.wrap_angle(-6.0)])
    # Table 5.5 lines 2-4 on a hand example: go from origin facing +x to (0, 1) facing -x
    np.testing.assert_allclose(sl.odometry_from_poses([0, 0, 0], [0, 1, np.pi]), [np.pi / 2, 1.0, np.pi / 2], atol=1e-15)


def test_sample_odometry_noise_variances_match_contract():
    rng = np.random.default_rng(7)
    u = np.array([0.4, 1.5, -0.3])
    alpha = np.array([0.05, 0.01, 0.02, 0.03])
    n = 100_000
    x = np.tile([0.2, -0.1, 0.5], (n, 1))
    X = sl.sample_motion_model_odometry(ro(x), ro(u), ro(alpha), rng=rng)
    h = sl.odometry_from_poses(x, X)
    r1, t, r2 = u
    var = [alpha[0] * r1**2 + alpha[1] * t**2, alpha[2] * t**2 + alpha[3] * (r1**2 + r2**2), alpha[0] * r2**2 + alpha[1] * t**2]
    e = np.stack([sl.angle_diff(h[:, 0], r1), h[:, 1] - t, sl.angle_diff(h[:, 2], r2)], 1)
    assert np.all(np.abs(e.mean(axis=0)) <= 4 * np.sqrt(np.array(var) / n))
    np.testing.assert_allclose(e.var(axis=0), var, rtol=0.02)
    # each noise is normal: KS on the standardised (wrapped) errors
    for i in range(3):
        assert stats.kstest(e[:20000, i] / np.sqrt(var[i]), "norm").pvalue > 0.01
    # and independent
    assert np.max(np.abs(np.corrcoef(e.T) - np.eye(3))) < 0.02


def test_motion_model_odometry_matches_formula():
    u = np.array([0.3, 1.0, 0.1])
    alpha = np.array([0.1, 0.05, 0.08, 0.02])
    x = np.array([[0.0, 0.0, 0.0], [1.0, -1.0, 2.0]])
    xn = sl.odometry_motion(x, np.array([[0.35, 0.9, 0.05], [0.2, 1.2, 0.3]]))
    p = sl.motion_model_odometry(ro(xn), ro(u), ro(x), ro(alpha))
    h = sl.odometry_from_poses(x, xn)
    ref = []
    for r1h, th, r2h in h:
        v1 = alpha[0] * r1h**2 + alpha[1] * th**2
        v2 = alpha[2] * th**2 + alpha[3] * (r1h**2 + r2h**2)
        v3 = alpha[0] * r2h**2 + alpha[1] * th**2
        ref.append(stats.norm.pdf(u[0] - r1h, scale=np.sqrt(v1)) * stats.norm.pdf(u[1] - th, scale=np.sqrt(v2))
                   * stats.norm.pdf(u[2] - r2h, scale=np.sqrt(v3)))
    np.testing.assert_allclose(p, ref, rtol=1e-12)
    np.testing.assert_allclose(np.log(p), sl.motion_model_odometry(xn, u, x, alpha, log=True), rtol=1e-12)


def test_motion_model_odometry_integrates_to_one_with_jacobian():
    """Table 5.5 is a density over (rot1, trans, rot2); over x' it carries 1/trans_hat."""
    x = np.array([0.5, 0.5, 0.2])
    u = np.array([0.3, 2.0, -0.2])
    alpha = np.array([0.002, 0.001, 0.002, 0.001])
    mean = sl.odometry_motion(x, u)
    rng = np.random.default_rng(8)
    S = sl.sample_motion_model_odometry(np.tile(x, (20000, 1)), u, alpha, rng=rng)
    sd = S.std(axis=0)
    axes = [np.linspace(mean[i] - 6 * sd[i], mean[i] + 6 * sd[i], 61) for i in range(3)]
    g = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    p = sl.motion_model_odometry(g, u, x, alpha)
    trans_hat = sl.odometry_from_poses(x, g)[:, 1]
    total = np.sum(p / trans_hat) * np.prod([a[1] - a[0] for a in axes])
    assert abs(total - 1.0) < 0.02


def test_motion_model_odometry_same_pose_is_finite():
    p = sl.motion_model_odometry(np.zeros((2, 3)), [0.0, 0.0, 0.0], np.zeros((2, 3)), [0.1, 0.1, 0.1, 0.1])
    assert np.all(np.isfinite(p))


def test_odometry_batched_equals_looped():
    rng = np.random.default_rng(9)
    x = rng.normal(size=(6, 3))
    u = np.array([0.2, 1.0, -0.4])
    alpha = np.array([0.1, 0.02, 0.05, 0.01])
    xn = sl.sample_motion_model_odometry(x, u, alpha, rng=rng)
    p = sl.motion_model_odometry(xn, u, x, alpha)
    for k in range(6):
        assert sl.motion_model_odometry(xn[k], u, x[k], alpha) == pytest.approx(p[k], rel=1e-13)
    np.testing.assert_allclose(sl.odometry_motion(x, u)[2], sl.odometry_motion(x[2], u))


def test_samplers_are_reproducible_and_use_given_rng_only():
    a = sl.sample_motion_model_odometry(np.zeros((5, 3)), [0.1, 1, 0.1], [0.1] * 4, rng=np.random.default_rng(11))
    b = sl.sample_motion_model_odometry(np.zeros((5, 3)), [0.1, 1, 0.1], [0.1] * 4, rng=np.random.default_rng(11))
    np.testing.assert_array_equal(a, b)
    c = sl.sample_motion_model_velocity(np.zeros((5, 3)), [1, 0.1], 1.0, [0.1] * 6, rng=np.random.default_rng(11))
    d = sl.sample_motion_model_velocity(np.zeros((5, 3)), [1, 0.1], 1.0, [0.1] * 6, rng=np.random.default_rng(11))
    np.testing.assert_array_equal(c, d)


# ---------------------------------------------------------------- inputs
@pytest.mark.parametrize("call, name", [
    (lambda: sl.velocity_motion(np.zeros(2), np.zeros(2), 1.0), "x"),
    (lambda: sl.velocity_motion(np.zeros(3), np.zeros(3), 1.0), "u"),
    (lambda: sl.velocity_motion(np.zeros(3), [np.nan, 0], 1.0), "u"),
    (lambda: sl.velocity_motion(np.zeros(3), np.zeros(2), -1.0), "dt"),
    (lambda: sl.velocity_motion(np.zeros((2, 3)), np.zeros((3, 2)), 1.0), "x"),
    (lambda: sl.velocity_noise_cov([1, 1], [0.1, -0.1, 0.1, 0.1]), "alpha"),
    (lambda: sl.sample_motion_model_velocity(np.zeros(3), [1, 1], 1.0, [0.1] * 5, rng=np.random.default_rng(0)), "alpha"),
    (lambda: sl.sample_motion_model_velocity(np.zeros(3), [1, 1], 1.0, [0.1] * 6, rng=np.random.RandomState(0)), "rng"),
    (lambda: sl.sample_motion_model_odometry(np.zeros((4, 3)), [1, 1], [0.1] * 4, rng=np.random.default_rng(0)), "u"),
    (lambda: sl.sample_motion_model_odometry(np.zeros((4, 3)), [0, 1, 0], [0.1] * 4, rng=0), "rng"),
    (lambda: sl.sample_motion_model_odometry(np.zeros((4, 3)), [0, 1, 0], [-0.1] * 4, rng=np.random.default_rng(0)), "alpha"),
    (lambda: sl.motion_model_odometry(np.zeros((4, 2)), [0, 1, 0], np.zeros((4, 3)), [0.1] * 4), "x_next"),
    (lambda: sl.motion_model_velocity(np.zeros(3), [0, 1], np.zeros(3), 0.0, [0.1] * 6), "dt"),
    (lambda: sl.odometry_from_poses(np.zeros(3), [0, np.inf, 0]), "x_next"),
    (lambda: sl.odometry_motion(np.zeros(3), np.zeros(2)), "u"),
])
def test_bad_inputs_name_the_argument(call, name):
    with pytest.raises((ValueError, TypeError), match=name):
        call()


def test_no_input_is_modified():
    x = ro(np.tile([0.1, 0.2, 3.1], (4, 1)))
    args = [ro([1.0, 0.3]), ro(np.full(6, 0.01)), ro([0.1, 0.5, 0.2]), ro([0.01] * 4)]
    copies = [a.copy() for a in (x, *args)]
    sl.velocity_motion(x, args[0], 0.5)
    sl.sample_motion_model_velocity(x, args[0], 0.5, args[1], rng=np.random.default_rng(0))
    sl.motion_model_velocity(x, args[0], x, 0.5, args[1])
    sl.sample_motion_model_odometry(x, args[2], args[3], rng=np.random.default_rng(0))
    sl.motion_model_odometry(x, args[2], x, args[3])
    sl.odometry_from_poses(x, x)
    sl.odometry_motion(x, args[2])
    for a, c in zip((x, *args), copies):
        np.testing.assert_array_equal(a, c)
