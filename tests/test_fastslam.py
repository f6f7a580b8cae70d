"""FastSLAM 1.0 (slamlib.fastslam) against closed forms, EKF updates and theory."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats
from scipy.special import logsumexp

import slamlib as sl

Q = np.diag([0.1, 0.02]) ** 2


# --------------------------------------------------------------------------- explicit formulas
def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def _h(x, m):
    """Range-bearing measurement of m from pose x, written out."""
    dx, dy = m[0] - x[0], m[1] - x[1]
    return np.array([np.hypot(dx, dy), _wrap(np.arctan2(dy, dx) - x[2])])


def _Hm(x, m):
    """d h / d m = [[dx/r, dy/r], [-dy/q, dx/q]], written out."""
    dx, dy = m[0] - x[0], m[1] - x[1]
    q = dx * dx + dy * dy
    r = np.sqrt(q)
    return np.array([[dx / r, dy / r], [-dy / q, dx / q]])


def _ekf(x, mu, Sigma, z, Q):
    """One 2x2 EKF update of a landmark with the weight N(nu; 0, S), using np.linalg."""
    H = _Hm(x, mu)
    nu = z - _h(x, mu)
    nu[1] = _wrap(nu[1])
    S = H @ Sigma @ H.T + Q
    K = Sigma @ H.T @ np.linalg.inv(S)
    w = stats.multivariate_normal(mean=np.zeros(2), cov=S).pdf(nu)
    return mu + K @ nu, (np.eye(2) - K @ H) @ Sigma, w


def _random_spd(rng, n, scale):
    A = rng.normal(size=(n, 2, 2)) * scale
    return A @ np.swapaxes(A, 1, 2) + 0.01 * scale**2 * np.eye(2)


def _particles(rng, n):
    x = np.empty((n, 3))
    x[:, :2] = rng.uniform(-5, 5, size=(n, 2))
    x[:, 2] = rng.uniform(-np.pi, np.pi, size=n)
    return x


@pytest.fixture(scope="module")
def world():
    rng = np.random.default_rng(7)
    landmarks = rng.uniform(-12, 12, size=(25, 2))
    u = sl.loop_controls(250, v=1.0, omega=0.12)
    run = sl.simulate_landmark_run(landmarks, u, 0.2, x0=np.array([0.0, -8.0, 0.0]), M=np.diag([0.1, 0.05]) ** 2,
                                   Q=np.diag([0.2, 0.03]) ** 2, max_range=8.0, fov=np.pi, rng=rng)
    return run


# --------------------------------------------------------------------------- contract functions
def test_init_landmark_mean_and_covariance_are_the_inverse_measurement():
    rng = np.random.default_rng(0)
    x = _particles(rng, 7)
    z = np.array([4.0, 0.7])
    mu, Sigma = sl.fastslam_init_landmark(x, z, Q)
    assert mu.shape == (7, 2) and Sigma.shape == (7, 2, 2)
    for k in range(7):
        expect = x[k, :2] + z[0] * np.array([np.cos(x[k, 2] + z[1]), np.sin(x[k, 2] + z[1])])
        np.testing.assert_allclose(mu[k], expect, rtol=0, atol=1e-12)
        np.testing.assert_allclose(_h(x[k], mu[k]), z, atol=1e-12)
        Hinv = np.linalg.inv(_Hm(x[k], mu[k]))
        np.testing.assert_allclose(Sigma[k], Hinv @ Q @ Hinv.T, rtol=1e-10, atol=1e-15)
        # seen from where it was initialised, the new landmark predicts exactly the sensor noise
        H = _Hm(x[k], mu[k])
        np.testing.assert_allclose(H @ Sigma[k] @ H.T, Q, rtol=1e-9, atol=1e-15)


def test_update_landmark_equals_closed_form_ekf_and_gaussian_weight():
    rng = np.random.default_rng(1)
    n = 9
    x = _particles(rng, n)
    mu = x[:, :2] + rng.uniform(2, 6, size=(n, 1)) * np.c_[np.cos(x[:, 2] + 0.3), np.sin(x[:, 2] + 0.3)]
    Sigma = _random_spd(rng, n, 0.3)
    z = np.array([4.2, 0.25])
    mu_new, Sigma_new, w = sl.fastslam_update_landmark(x, mu, Sigma, z, Q)
    _, _, log_w = sl.fastslam_update_landmark(x, mu, Sigma, z, Q, log=True)
    assert mu_new.shape == (n, 2) and Sigma_new.shape == (n, 2, 2) and w.shape == (n,)
    for k in range(n):
        m_e, S_e, w_e = _ekf(x[k], mu[k], Sigma[k], z, Q)
        np.testing.assert_allclose(mu_new[k], m_e, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(Sigma_new[k], S_e, rtol=1e-8, atol=1e-12)
        np.testing.assert_allclose(w[k], w_e, rtol=1e-10, atol=0)
        np.testing.assert_allclose(log_w[k], np.log(w_e), rtol=1e-12, atol=1e-12)


def test_update_wraps_the_bearing_innovation():
    x = np.array([[0.0, 0.0, 0.0]])
    mu = np.array([[-5.0, 0.05]])  # bearing just below pi
    Sigma = np.array([np.diag([0.05, 0.05])])
    z = np.array([5.0, -np.pi + 0.01])  # just above -pi: the innovation is small, not ~ -2 pi
    mu_new, _, w = sl.fastslam_update_landmark(x, mu, Sigma, z, Q)
    _, _, w_e = _ekf(x[0], mu[0], Sigma[0], z, Q)
    np.testing.assert_allclose(w[0], w_e, rtol=1e-10)
    assert w[0] > 1e-3  # an unwrapped innovation would give a weight of ~exp(-1e4)
    assert np.linalg.norm(mu_new[0] - mu[0]) < 0.2


def _text_weight(x, mu, Sigma, z, Q):
    """The course text's Algorithm 3 as printed: det(2 pi S)^(-1/2) exp(-1/2 nu^T Q^-1 nu)."""
    H = _Hm(x, mu)
    nu = z - _h(x, mu)
    nu[1] = _wrap(nu[1])
    S = H @ Sigma @ H.T + Q
    return np.exp(-0.5 * nu @ np.linalg.solve(Q, nu)) / np.sqrt(np.linalg.det(2 * np.pi * S))


def test_weight_cov_text_is_the_course_texts_formula_and_agrees_only_for_a_certain_landmark():
    rng = np.random.default_rng(2)
    x = _particles(rng, 5)
    mu = x[:, :2] + np.c_[np.cos(x[:, 2]), np.sin(x[:, 2])] * 6.0
    z = np.array([6.3, 0.05])
    certain = np.tile(1e-12 * np.eye(2), (5, 1, 1))
    _, _, wS = sl.fastslam_update_landmark(x, mu, certain, z, Q)
    _, _, wT = sl.fastslam_update_landmark(x, mu, certain, z, Q, weight_cov="text")
    np.testing.assert_allclose(wT, wS, rtol=1e-6)
    Sigma = _random_spd(rng, 5, 0.3)
    _, _, wT = sl.fastslam_update_landmark(x, mu, Sigma, z, Q, weight_cov="text")
    for k in range(5):  # S in the normaliser, Q^-1 in the exponent, whatever the landmark's covariance
        np.testing.assert_allclose(wT[k], _text_weight(x[k], mu[k], Sigma[k], z, Q), rtol=1e-10)
    # two particles at one pose with a landmark of 1 m standard deviation: A expects z exactly, B's mean is
    # 0.3 m nearer. Under S = H Sigma H^T + Q (range variance 1.01 m^2) B is about as likely as A; the
    # text's exponent scores the 0.3 m as three range sigmas of Q and cuts B's relative weight to exp(-4.5).
    pose = np.zeros((2, 3))
    mu = np.array([[6.3, 0.0], [6.0, 0.0]])
    z = np.array([6.3, 0.0])
    uncertain = np.tile(np.eye(2), (2, 1, 1))
    m1, s1, wS = sl.fastslam_update_landmark(pose, mu, uncertain, z, Q)
    m2, s2, wT = sl.fastslam_update_landmark(pose, mu, uncertain, z, Q, weight_cov="text")
    np.testing.assert_array_equal(m1, m2)  # only the weight differs, never the EKF update
    np.testing.assert_array_equal(s1, s2)
    ratio_S = _ekf(pose[1], mu[1], uncertain[1], z, Q)[2] / _ekf(pose[0], mu[0], uncertain[0], z, Q)[2]
    np.testing.assert_allclose(wS[1] / wS[0], ratio_S, rtol=1e-10)
    assert ratio_S > 0.9
    ratio_T = _text_weight(pose[1], mu[1], uncertain[1], z, Q) / _text_weight(pose[0], mu[0], uncertain[0], z, Q)
    np.testing.assert_allclose(wT[1] / wT[0], ratio_T, rtol=1e-10)
    assert ratio_T < 1.1 * np.exp(-0.5 * 0.3**2 / Q[0, 0])
    with pytest.raises(ValueError, match="weight_cov='text'"):
        sl.fastslam_update_landmark(pose, mu, uncertain, z, Q, weight_cov="Q")


@pytest.mark.parametrize("lam", [3.0, 10.0])
def test_ess_of_S_and_text_weights_match_theory(lam):
    # Particles at one pose whose landmark means are spread as their covariance says, mu_k ~ N(m, Sigma),
    # Sigma = lam * H^-1 Q H^-T, so nu_k ~ N(0, lam Q) (to first order). For weights exp(-nu^T C^-1 nu / 2):
    # ESS / M -> det(I + 2 C^-1 A)^(1/2) / det(I + C^-1 A) with A = lam Q; C = S = (1 + lam) Q gives
    # (1 + 3 lam)(1 + lam) / (1 + 2 lam)^2 (>= 3/4), the text's exponent C = Q gives (1 + 2 lam) / (1 + lam)^2
    # (-> 0).
    x = np.array([0.0, 0.0, 0.3])
    m = np.array([15.0, 8.0])
    z = _h(x, m)
    Qs = np.diag([0.1, 0.01]) ** 2
    _, S0 = sl.fastslam_init_landmark(x[None], z, Qs)
    n = 40_000
    rng = np.random.default_rng(3)
    Sigma = lam * S0[0]
    mu = m + rng.multivariate_normal(np.zeros(2), Sigma, size=n)
    xs, Sig = np.tile(x, (n, 1)), np.tile(Sigma, (n, 1, 1))
    ess = {}
    for wc in ("S", "text"):
        _, _, lw = sl.fastslam_update_landmark(xs, mu, Sig, z, Qs, weight_cov=wc, log=True)
        ess[wc] = sl.effective_sample_size(np.exp(lw - lw.max())) / n
    assert ess["S"] == pytest.approx((1 + 3 * lam) * (1 + lam) / (1 + 2 * lam) ** 2, abs=0.02)
    # the text's normaliser |2 pi S|^-1/2 is (nearly) the same for all these particles: only its exponent counts
    assert ess["text"] == pytest.approx((1 + 2 * lam) / (1 + lam) ** 2, abs=0.02)
    assert ess["text"] < 0.6 * ess["S"]


def test_contract_functions_batched_equals_looped():
    rng = np.random.default_rng(4)
    n = 6
    x = _particles(rng, n)
    z = np.array([3.0, -0.4])
    mu_b, Sigma_b = sl.fastslam_init_landmark(x, z, Q)
    for k in range(n):
        mu_1, Sigma_1 = sl.fastslam_init_landmark(x[k:k + 1], z, Q)
        np.testing.assert_allclose(mu_b[k], mu_1[0], rtol=0, atol=1e-14)
        np.testing.assert_allclose(Sigma_b[k], Sigma_1[0], rtol=1e-14, atol=0)
    Sigma = _random_spd(rng, n, 0.2)
    mu = mu_b + rng.normal(scale=0.2, size=(n, 2))
    out = sl.fastslam_update_landmark(x, mu, Sigma, z, Q)
    for k in range(n):
        one = sl.fastslam_update_landmark(x[k:k + 1], mu[k:k + 1], Sigma[k:k + 1], z, Q)
        single = sl.fastslam_update_landmark(x[k], mu[k], Sigma[k], z, Q)
        for a, b, c in zip(out, one, single):
            np.testing.assert_allclose(a[k], b[0], rtol=1e-13, atol=1e-15)
            np.testing.assert_allclose(a[k], c, rtol=1e-13, atol=1e-15)


def _readonly(*arrays):
    out = []
    for a in arrays:
        a = np.array(a)
        a.setflags(write=False)
        out.append(a)
    return out


def test_contract_functions_do_not_modify_inputs():
    rng = np.random.default_rng(5)
    x = _particles(rng, 4)
    mu = x[:, :2] + 3.0
    Sigma = _random_spd(rng, 4, 0.2)
    z = np.array([4.0, 0.2])
    copies = [a.copy() for a in (x, mu, Sigma, z, Q)]
    # read-only inputs: an in-place write would raise
    xr, mur, Sr, zr, Qr = _readonly(x, mu, Sigma, z, Q)
    sl.fastslam_init_landmark(xr, zr, Qr)
    sl.fastslam_update_landmark(xr, mur, Sr, zr, Qr)
    sl.fastslam_init_landmark(x, z, Q)
    sl.fastslam_update_landmark(x, mu, Sigma, z, Q)
    for a, c in zip((x, mu, Sigma, z, Q), copies):
        np.testing.assert_array_equal(a, c)


# --------------------------------------------------------------------------- the filter
def _dead_reckoning(run):
    x = np.empty((run.n_steps + 1, 3))
    x[0] = run.x0
    for t in range(run.n_steps):
        x[t + 1] = sl.velocity_motion(x[t], run.u[t], run.dt)[0]
    return x


def test_one_particle_without_motion_noise_is_an_ekf_per_landmark(world):
    run = world
    zero = np.zeros((2, 2))
    state = sl.fastslam_initial_state(run.x0, 1, 4)
    rng = np.random.default_rng(0)
    pose = np.array(run.x0)
    mus, Sigmas = {}, {}
    for t in range(run.n_steps):
        state = sl.fastslam_predict(state, run.u[t], run.dt, M=zero, rng=rng)
        state = sl.fastslam_update_known(state, run.z[t], run.ids[t], Q=run.Q)
        pose = sl.velocity_motion(pose, run.u[t], run.dt)[0]
        for z, j in zip(run.z[t], run.ids[t]):
            if j not in mus:  # first sighting: inverse measurement, Sigma = H^-1 Q H^-T
                mus[j] = pose[:2] + z[0] * np.array([np.cos(pose[2] + z[1]), np.sin(pose[2] + z[1])])
                Hinv = np.linalg.inv(_Hm(pose, mus[j]))
                Sigmas[j] = Hinv @ run.Q @ Hinv.T
            else:
                mus[j], Sigmas[j], _ = _ekf(pose, mus[j], Sigmas[j], z, run.Q)
    np.testing.assert_allclose(state.poses[0], pose, atol=1e-12)
    assert sorted(mus) == list(np.flatnonzero(state.seen[0]))
    for j in mus:
        np.testing.assert_allclose(state.mu[0, j], mus[j], rtol=0, atol=1e-9)
        np.testing.assert_allclose(state.Sigma[0, j], Sigmas[j], rtol=1e-7, atol=1e-14)
    # and the whole-run helper gives the same map and the dead-reckoned path
    res = sl.run_fastslam(run, n_particles=1, M=zero, rng=np.random.default_rng(1))
    np.testing.assert_allclose(res.x_est, _dead_reckoning(run), atol=1e-9)
    np.testing.assert_allclose(res.landmarks[res.seen], state.mu[0][state.seen[0]], atol=1e-12)


def test_one_particle_without_motion_noise_matches_ekf_slam(world):
    # With no motion noise and a known start, EKF SLAM's pose covariance stays zero, so its landmarks
    # decouple into independent 2x2 EKFs: FastSLAM with one particle. EKF SLAM starts a landmark from a
    # large finite prior variance (1e4 m^2), hence agreement to O(1e-4) rather than to round-off.
    run = world
    zero = np.zeros((2, 2))
    ekf = sl.run_ekf_slam(run, known=True, M=zero)
    fs = sl.run_fastslam(run, n_particles=1, M=zero, rng=np.random.default_rng(0))
    np.testing.assert_allclose(fs.x_est, ekf.x, atol=1e-9)
    np.testing.assert_allclose(fs.landmarks[ekf.landmark_ids], ekf.landmarks, rtol=0, atol=1e-4)
    np.testing.assert_allclose(fs.landmark_cov[ekf.landmark_ids], ekf.landmark_cov, rtol=1e-3, atol=1e-9)


def _state_with_maps(n, N, rng):
    st = sl.fastslam_initial_state(np.zeros(3), n, N)
    return st._replace(
        poses=rng.normal(size=(n, 3)),
        mu=rng.normal(size=(n, N, 2)) * 5,
        Sigma=np.tile(0.1 * np.eye(2), (n, N, 1, 1)) + rng.uniform(0, 0.01, size=(n, N, 1, 1)),
        seen=np.ones((n, N), dtype=bool),
        counts=np.ones((n, N), dtype=np.int64),
        log_weights=sl.normalize_log_weights(rng.normal(size=n), log=True),
    )


def _maps_alias(maps):
    """True if any two particles' map arrays share memory."""
    return any(np.shares_memory(maps[i], maps[j]) for i in range(len(maps)) for j in range(i + 1, len(maps)))


def test_resampling_gives_every_particle_its_own_map():
    rng = np.random.default_rng(8)
    st = _state_with_maps(6, 5, rng)
    before = [a.copy() for a in st]
    idx = np.array([0, 0, 0, 2, 2, 5])
    new, anc = sl.fastslam_resample(st, rng=rng, indices=idx)
    np.testing.assert_array_equal(anc, idx)
    np.testing.assert_array_equal(new.mu, st.mu[idx])
    np.testing.assert_allclose(new.log_weights, -np.log(6))
    # no storage shared with the old particle set, nor between any two new particles
    for field in ("poses", "mu", "Sigma", "seen", "counts"):
        assert not np.shares_memory(getattr(new, field), getattr(st, field))
        assert not _maps_alias([getattr(new, field)[k] for k in range(6)])
    # writing into one copy changes no other copy of the same ancestor, nor the ancestor
    new.mu[0, 1] += 100.0
    new.Sigma[3, 2] *= 7.0
    np.testing.assert_array_equal(new.mu[1], st.mu[0])
    np.testing.assert_array_equal(new.mu[2], st.mu[0])
    np.testing.assert_array_equal(new.Sigma[4], st.Sigma[2])
    for a, b in zip(st, before):
        np.testing.assert_array_equal(a, b)
    # the check above does catch a resampler that hands out references to the ancestor's map
    # (a list of per-particle map arrays where survivors of one ancestor point at the same array)
    maps = [st.mu[k].copy() for k in range(6)]
    aliased = [maps[i] for i in idx]
    assert _maps_alias(aliased)


def test_resampled_copies_diverge_under_later_updates():
    rng = np.random.default_rng(9)
    st = _state_with_maps(4, 3, rng)
    new, _ = sl.fastslam_resample(st, rng=rng, indices=np.array([1, 1, 1, 1]))
    new = new._replace(poses=new.poses + np.array([[0, 0, 0], [0.3, 0, 0], [0, 0.3, 0], [0, 0, 0.05]]))
    z = sl.landmark_measurement(st.poses[1], st.mu[1, 2])[0][None]
    upd = sl.fastslam_update_known(new, z, np.array([2]), Q)
    moved = upd.mu[:, 2]
    assert all(np.linalg.norm(moved[i] - moved[j]) > 1e-3 for i in range(4) for j in range(i + 1, 4))
    np.testing.assert_array_equal(new.mu[:, 2], np.tile(st.mu[1, 2], (4, 1)))  # the input is untouched


def test_low_variance_resampling_is_used():
    rng = np.random.default_rng(10)
    st = _state_with_maps(50, 2, rng)
    _, idx = sl.fastslam_resample(st, rng=np.random.default_rng(3))
    np.testing.assert_array_equal(idx, sl.low_variance_resample(st.weights, rng=np.random.default_rng(3)))


def test_log_weights_stay_finite_with_200_landmarks_in_view():
    rng = np.random.default_rng(11)
    n, N = 50, 200
    truth = np.array([0.0, 0.0, 0.1])
    lm = rng.uniform(-30, 30, size=(N, 2))
    st = sl.fastslam_initial_state(truth, n, N)
    poses = truth + rng.normal(scale=[0.5, 0.5, 0.05], size=(n, 3))
    st = st._replace(poses=poses, mu=np.tile(lm, (n, 1, 1)) + rng.normal(scale=0.05, size=(n, N, 2)),
                     Sigma=np.tile(0.05**2 * np.eye(2), (n, N, 1, 1)), seen=np.ones((n, N), dtype=bool))
    z = sl.landmark_measurement(truth, lm)[0] + rng.multivariate_normal(np.zeros(2), Q, size=N)
    new = sl.fastslam_update_known(st, z, np.arange(N), Q)
    assert np.all(np.isfinite(new.log_weights))
    assert logsumexp(new.log_weights) == pytest.approx(0.0, abs=1e-12)
    assert new.weights.sum() == pytest.approx(1.0, rel=1e-12)
    assert 1.0 <= sl.effective_sample_size(new.weights) <= n
    # the weights span more than the whole double range (about 1418 nats from the smallest subnormal to
    # the largest double): in linear space the same product must underflow or overflow
    assert np.ptp(new.log_weights) > 1500
    w = np.ones(n)
    with np.errstate(over="ignore", under="ignore"):
        for j in range(N):
            w *= sl.fastslam_update_landmark(poses, st.mu[:, j], st.Sigma[:, j], z[j], Q)[2]
    assert np.any((w == 0.0) | np.isinf(w))
    # the most likely particle is the one closest to the truth
    d = np.linalg.norm((poses - truth)[:, :2], axis=1) + 10 * np.abs(poses[:, 2] - truth[2])
    assert np.argmax(new.log_weights) in np.argsort(d)[:3]


def test_update_known_all_at_once_equals_one_by_one():
    rng = np.random.default_rng(12)
    st = _state_with_maps(20, 6, rng)
    st = st._replace(seen=st.seen & (np.arange(6) < 4))  # slots 4, 5 not seen yet
    ids = np.array([1, 4, 1, 0, 5, 4])  # repeated landmarks, and new ones seen twice
    truth = np.array([0.1, -0.2, 0.05])
    z = sl.landmark_measurement(truth, np.vstack([st.mu[0, [1, 0, 1, 0]], [[3.0, 2.0], [-2.0, 4.0]]]))[0]
    z = z[[0, 4, 2, 3, 5, 4]] + rng.normal(scale=0.05, size=(6, 2))
    z = z.copy()
    z[:, 0] = np.abs(z[:, 0])
    together = sl.fastslam_update_known(st, z, ids, Q)
    one = st
    for k in range(6):
        one = sl.fastslam_update_known(one, z[k:k + 1], ids[k:k + 1], Q)
    for a, b in zip(together, one):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)


def test_state_steps_do_not_modify_their_input():
    rng = np.random.default_rng(13)
    st = _state_with_maps(10, 4, rng)
    st = sl.FastSLAMState(*_readonly(*st))
    before = [a.copy() for a in st]
    z = np.array([[3.0, 0.1], [5.0, -1.0]])
    sl.fastslam_predict(st, np.array([1.0, 0.1]), 0.1, M=np.diag([0.1, 0.05]) ** 2, rng=rng)
    sl.fastslam_update_known(st, z, np.array([0, 3]), Q)
    sl.fastslam_update_unknown(st, z, Q, max_range=6.0)
    sl.fastslam_resample(st, rng=rng)
    sl.fastslam_estimate(st)
    for a, b in zip(st, before):
        np.testing.assert_array_equal(a, b)


def test_predict_with_control_covariance_has_the_theoretical_heading_spread():
    # theta' = theta + omega_k dt exactly, so the heading spread is sigma_omega dt
    st = sl.fastslam_initial_state(np.array([1.0, 2.0, 0.3]), 20_000, 1)
    Mc = np.diag([0.2, 0.1]) ** 2
    new = sl.fastslam_predict(st, np.array([1.0, 0.5]), 0.5, M=Mc, rng=np.random.default_rng(14))
    dth = sl.angle_diff(new.poses[:, 2], 0.3)
    assert dth.mean() == pytest.approx(0.25, abs=3 * 0.05 / np.sqrt(20_000))
    assert dth.std() == pytest.approx(0.05, rel=0.03)
    # without noise it is the exact arc; with alpha it is slamlib's Table 5.3 sampler
    det = sl.fastslam_predict(st, np.array([1.0, 0.5]), 0.5, M=np.zeros((2, 2)), rng=np.random.default_rng(0))
    np.testing.assert_allclose(det.poses, np.tile(sl.velocity_motion(st.poses[0], [1.0, 0.5], 0.5)[0], (20_000, 1)))
    alpha = np.array([0.01, 0.0, 0.0, 0.01, 0.0, 0.001])
    a = sl.fastslam_predict(st, np.array([1.0, 0.5]), 0.5, alpha=alpha, rng=np.random.default_rng(5))
    b = sl.sample_motion_model_velocity(st.poses, np.array([1.0, 0.5]), 0.5, alpha, rng=np.random.default_rng(5))
    np.testing.assert_array_equal(a.poses, b)


def test_estimate_is_the_weighted_mean_with_a_circular_heading():
    st = sl.fastslam_initial_state(np.zeros(3), 3, 1)
    st = st._replace(poses=np.array([[0.0, 0.0, np.pi - 0.1], [2.0, 0.0, -np.pi + 0.1], [4.0, 4.0, 0.0]]),
                     log_weights=np.log(np.array([0.45, 0.45, 0.1])))
    pose, best = sl.fastslam_estimate(st)
    np.testing.assert_allclose(pose[:2], [1.3, 0.4])
    assert abs(sl.angle_diff(pose[2], np.pi)) < 0.02  # not the arithmetic mean ~ 0
    assert best == 0


def test_default_p0_is_the_density_at_the_gate():
    p0 = sl.fastslam_default_p0(Q, gate=9.0)
    nu = np.array([3 * 0.1, 0.0])  # Mahalanobis distance 9 under Q
    assert p0 == pytest.approx(stats.multivariate_normal(np.zeros(2), Q).pdf(nu), rel=1e-12)


def test_unknown_correspondences_recover_the_landmark_count(world):
    run = world
    res = sl.run_fastslam(run, n_particles=60, known=False, rng=np.random.default_rng(15),
                          max_range=run.max_range, fov=run.fov)
    seen_ids = np.unique(np.concatenate(run.ids))
    est = res.landmarks[res.seen]
    assert abs(est.shape[0] - seen_ids.size) <= 2
    # every true landmark has an estimate nearby
    d = np.linalg.norm(run.landmarks[seen_ids][:, None] - est[None], axis=2).min(axis=1)
    assert np.median(d) < 0.5 and d.max() < 1.0


def test_unknown_correspondences_match_known_ones_for_one_noiseless_particle():
    # no control noise in the world either: the one particle is the true path, and with landmarks at
    # least 3 m apart and 1 cm / 0.01 rad measurements maximum likelihood always picks the right one
    rng = np.random.default_rng(18)
    grid = np.stack(np.meshgrid(np.arange(-9.0, 10.0, 4.5), np.arange(-9.0, 10.0, 4.5)), axis=-1).reshape(-1, 2)
    landmarks = grid + rng.uniform(-0.7, 0.7, size=grid.shape)
    zero = np.zeros((2, 2))
    run = sl.simulate_landmark_run(landmarks, sl.loop_controls(200, v=1.0, omega=0.15), 0.2,
                                   x0=np.array([0.0, -6.5, 0.0]), M=zero, Q=np.diag([0.01, 0.01]) ** 2,
                                   max_range=7.0, fov=np.pi, rng=rng)
    known = sl.run_fastslam(run, n_particles=1, M=zero, rng=np.random.default_rng(0))
    unknown = sl.run_fastslam(run, n_particles=1, M=zero, known=False, rng=np.random.default_rng(0))
    a = known.landmarks[known.seen]
    b = unknown.landmarks[unknown.seen]
    assert a.shape == b.shape
    order = [int(np.argmin(np.linalg.norm(b - p, axis=1))) for p in a]
    assert sorted(order) == list(range(len(b)))
    np.testing.assert_allclose(b[order], a, atol=1e-9)


def test_counters_remove_a_landmark_that_is_not_seen_again():
    st = sl.fastslam_initial_state(np.zeros(3), 1, 4)
    real, ghost = np.array([4.0, 1.0]), np.array([3.0, -2.0])
    st = st._replace(mu=np.array([[real, ghost, [0, 0], [0, 0]]], dtype=float),
                     Sigma=np.tile(0.01 * np.eye(2), (1, 4, 1, 1)),
                     seen=np.array([[True, True, False, False]]), counts=np.array([[3, 1, 0, 0]]))
    z = sl.landmark_measurement(np.zeros(3), real)[0][None]
    history = []
    for _ in range(2):  # the ghost is in range and unmatched: 1 -> 0 (kept) -> -1 (removed)
        st = sl.fastslam_update_unknown(st, z, Q, max_range=10.0)
        history.append((st.counts[0, :2].tolist(), st.seen[0].tolist()))
    assert history == [([4, 0], [True, True, False, False]), ([5, 0], [True, False, False, False])]
    # out of range the counter is left alone
    st2 = st._replace(seen=np.array([[True, True, False, False]]), counts=np.array([[3, 0, 0, 0]]))
    st2 = sl.fastslam_update_unknown(st2, z, Q, max_range=3.5)
    assert st2.seen[0, 1] and st2.counts[0, 1] == 0


def test_run_tracks_ancestry_and_ess(world):
    run = world
    never = sl.run_fastslam(run, n_particles=30, resample_threshold=0.0, rng=np.random.default_rng(16))
    assert not never.resampled.any()
    np.testing.assert_array_equal(never.n_ancestors, 30)
    always = sl.run_fastslam(run, n_particles=30, resample_threshold=1.0, rng=np.random.default_rng(16))
    uneven = always.ess[:-1] < 30 * (1 - 1e-12)  # threshold 1: resample whenever the weights are uneven
    np.testing.assert_array_equal(always.resampled[:-1], uneven)
    assert uneven.sum() > 0.9 * (run.n_steps - 1) and not always.resampled[-1]
    assert np.all(np.diff(always.n_ancestors) >= 0)  # lineages only merge going back in time
    assert always.n_ancestors[0] == 1 and always.n_ancestors[-1] <= 30
    for res in (never, always):
        assert res.ess.shape == (run.n_steps,)
        assert np.all((res.ess >= 1 - 1e-9) & (res.ess <= 30 + 1e-9))
        best = int(np.argmax(res.state.log_weights))
        np.testing.assert_array_equal(res.path_best[-1], res.state.poses[best])
        np.testing.assert_array_equal(res.landmarks, res.state.mu[best])
        step = np.linalg.norm(np.diff(res.path_best[:, :2], axis=0), axis=1)
        assert step.max() < 1.0 * run.dt + 0.1  # one particle's own path: no jumps between lineages


def test_known_correspondences_beat_dead_reckoning(world):
    run = world
    res = sl.run_fastslam(run, n_particles=300, rng=np.random.default_rng(17))
    ate = sl.ate_rmse(res.x_est, run.x_true)
    assert ate < 0.75 * sl.ate_rmse(_dead_reckoning(run), run.x_true)
    assert sl.landmark_rmse(res.landmarks[res.seen], run.landmarks[res.seen]) < 0.5
    assert np.all(np.isfinite(res.x_cov)) and np.all(np.linalg.eigvalsh(res.x_cov) >= -1e-12)


# --------------------------------------------------------------------------- bad input
x3 = np.zeros((2, 3))
mu2 = np.array([[3.0, 0.0], [0.0, 3.0]])
S2 = np.tile(np.eye(2), (2, 1, 1))
z2 = np.array([3.0, 0.1])


@pytest.mark.parametrize("call, match", [
    (lambda: sl.fastslam_init_landmark(np.zeros((2, 2)), z2, Q), "x must have shape"),
    (lambda: sl.fastslam_init_landmark(x3, np.array([3.0, 0.1, 0.0]), Q), "z must have shape"),
    (lambda: sl.fastslam_init_landmark(x3, np.array([-1.0, 0.1]), Q), "positive range"),
    (lambda: sl.fastslam_init_landmark(x3, np.array([np.nan, 0.1]), Q), "z must be finite"),
    (lambda: sl.fastslam_init_landmark(x3, z2, np.array([[1.0, 0.5], [0.0, 1.0]])), "Q must be symmetric"),
    (lambda: sl.fastslam_init_landmark(x3, z2, np.zeros((2, 2))), "Q must be positive definite"),
    (lambda: sl.fastslam_update_landmark(x3, mu2[:1], S2, z2, Q), "mu must have shape"),
    (lambda: sl.fastslam_update_landmark(x3, mu2, S2[:, :1], z2, Q), "Sigma must have shape"),
    (lambda: sl.fastslam_update_landmark(x3, mu2, S2 + [[0, 1], [0, 0]], z2, Q), "Sigma must hold symmetric"),
    (lambda: sl.fastslam_update_landmark(x3, np.zeros((2, 2)), S2, z2, Q), "mu coincides"),
    (lambda: sl.fastslam_update_landmark(x3, mu2, S2, z2, Q, weight_cov="R"), "weight_cov"),
    (lambda: sl.fastslam_initial_state(np.zeros(3), 0, 5), "n_particles"),
    (lambda: sl.fastslam_initial_state(np.zeros(3), 5.0, 5), "n_particles"),
    (lambda: sl.fastslam_initial_state(np.zeros(2), 5, 5), "x0 must have shape"),
    (lambda: sl.fastslam_initial_state(np.zeros(3), 5, 0), "capacity"),
    (lambda: sl.fastslam_predict((1, 2), [1, 0], 0.1, M=np.eye(2), rng=np.random.default_rng()), "state must be"),
    (lambda: sl.fastslam_predict(sl.fastslam_initial_state(np.zeros(3), 2, 2), [1, 0], 0.1, M=np.eye(2), rng=0),
     "rng must be"),
    (lambda: sl.fastslam_predict(sl.fastslam_initial_state(np.zeros(3), 2, 2), [1, 0], 0.1,
                                 rng=np.random.default_rng()), "exactly one of M"),
    (lambda: sl.fastslam_predict(sl.fastslam_initial_state(np.zeros(3), 2, 2), [1, 0], -0.1, M=np.eye(2),
                                 rng=np.random.default_rng()), "dt must be non-negative"),
    (lambda: sl.fastslam_update_known(sl.fastslam_initial_state(np.zeros(3), 2, 2), np.ones((2, 2)),
                                      np.array([0]), Q), "ids must be integers of shape"),
    (lambda: sl.fastslam_update_known(sl.fastslam_initial_state(np.zeros(3), 2, 2), np.ones((1, 2)),
                                      np.array([-1]), Q), "ids must be non-negative"),
    (lambda: sl.fastslam_update_known(sl.fastslam_initial_state(np.zeros(3), 2, 2), np.ones((1, 3)),
                                      np.array([0]), Q), "z must have shape"),
    (lambda: sl.fastslam_update_unknown(sl.fastslam_initial_state(np.zeros(3), 2, 2), np.ones((1, 2)), Q,
                                        p0=0.0), "p0 must be positive"),
    (lambda: sl.fastslam_update_unknown(sl.fastslam_initial_state(np.zeros(3), 2, 2), np.ones((1, 2)), Q,
                                        fov=1.0), "fov needs max_range"),
    (lambda: sl.fastslam_resample(sl.fastslam_initial_state(np.zeros(3), 3, 2), rng=np.random.default_rng(),
                                  indices=np.array([0, 1, 3])), r"indices must lie in \[0, 3\)"),
    (lambda: sl.run_fastslam(object(), n_particles=3, rng=np.random.default_rng()), "run must be a LandmarkRun"),
    (lambda: sl.fastslam_default_p0(Q, gate=-1.0), "gate must be positive"),
])
def test_bad_input_raises_naming_the_argument(call, match):
    with pytest.raises((ValueError, TypeError), match=match):
        call()


def test_run_rejects_bad_options(world):
    with pytest.raises(ValueError, match="weight_cov"):
        sl.run_fastslam(world, n_particles=3, weight_cov="q", rng=np.random.default_rng())
    with pytest.raises(ValueError, match="at most one of M and alpha"):
        sl.run_fastslam(world, n_particles=3, M=np.eye(2), alpha=np.zeros(6), rng=np.random.default_rng())
    with pytest.raises(ValueError, match="resample_threshold must be non-negative"):
        sl.run_fastslam(world, n_particles=3, resample_threshold=-1.0, rng=np.random.default_rng())


# --------------------------------------------------------------------------- the particle set against theory
def test_map_moments_are_the_mixture_moments():
    rng = np.random.default_rng(19)
    st = _state_with_maps(5, 4, rng)
    slots = np.array([2, 0])
    mean, cov = sl.fastslam_map_moments(st, slots)
    w = st.weights
    # one particle: its own block-diagonal covariance
    one, _ = sl.fastslam_resample(st, rng=rng, indices=np.full(5, 3))
    m1, c1 = sl.fastslam_map_moments(one, slots)
    np.testing.assert_allclose(m1, st.mu[3, slots].ravel())
    expect = np.zeros((4, 4))
    expect[:2, :2], expect[2:, 2:] = st.Sigma[3, 2], st.Sigma[3, 0]
    np.testing.assert_allclose(c1, expect, atol=1e-15)
    # the mixture: sample a particle by weight, then the landmarks from its Gaussians
    n = 200_000
    k = rng.choice(5, size=n, p=w)
    draws = np.concatenate([st.mu[k, s] + np.einsum("nij,nj->ni", np.linalg.cholesky(st.Sigma[k, s]),
                                                        rng.standard_normal((n, 2))) for s in slots], axis=1)
    np.testing.assert_allclose(mean, draws.mean(axis=0), atol=0.05)
    np.testing.assert_allclose(cov, np.cov(draws.T), atol=0.15, rtol=0.02)
    with pytest.raises(ValueError, match="seen in every particle"):
        sl.fastslam_map_moments(st._replace(seen=np.zeros_like(st.seen)), slots)


def test_many_particles_reproduce_the_ekf_slam_posterior(world):
    # Early in a run, where linearisation is good and depletion has not set in, FastSLAM's particle set
    # (pose moments, and map moments by the law of total covariance) matches EKF SLAM's Gaussian.
    run = world
    T = 20
    ekf = sl.run_ekf_slam(run, snapshots=(T,))
    state = sl.fastslam_initial_state(run.x0, 5000, 25)
    rng = np.random.default_rng(20)
    for t in range(T):
        state = sl.fastslam_predict(state, run.u[t], run.dt, M=run.M, rng=rng)
        state = sl.fastslam_update_known(state, run.z[t], run.ids[t], run.Q)
        if sl.effective_sample_size(state.weights) < 2500 and t < T - 1:
            state, _ = sl.fastslam_resample(state, rng=rng)
    pose, _ = sl.fastslam_estimate(state)
    d = sl.pose_error(state.poses, pose)
    cov = np.einsum("k,ki,kj->ij", state.weights, d, d)
    std_ekf = np.sqrt(np.diag(ekf.Sigma_x[T]))
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), std_ekf, rtol=0.1)
    assert np.all(np.abs(sl.pose_error(pose, ekf.x[T])) < 0.3 * std_ekf)
    mu_e, Sigma_e, ids = ekf.snapshots[T]
    mean, C = sl.fastslam_map_moments(state, ids)
    E = Sigma_e[3:, 3:]
    np.testing.assert_allclose(np.sqrt(np.diag(C)), np.sqrt(np.diag(E)), rtol=0.1)
    assert np.all(np.abs(mean - mu_e[3:]) < 0.3 * np.sqrt(np.diag(E)))
    rho = lambda A: A / np.sqrt(np.outer(np.diag(A), np.diag(A)))  # noqa: E731
    np.testing.assert_allclose(rho(C), rho(E), atol=0.15)


def test_update_unknown_batched_equals_per_particle():
    # each particle associates on its own: the vectorised update equals updating the particles one by one
    # (weights compared through pairs with particle 0, since a one-particle set always normalises to 0)
    rng = np.random.default_rng(21)
    n = 8
    st = _state_with_maps(n, 6, rng)
    first4 = np.tile(np.arange(6) < 4, (n, 1))
    st = st._replace(poses=rng.normal(scale=[0.03, 0.03, 0.003], size=(n, 3)),
                     mu=st.mu[:1] + rng.normal(scale=0.05, size=(n, 6, 2)),
                     Sigma=np.tile(0.05 * np.eye(2), (n, 6, 1, 1)), seen=first4, counts=first4.astype(np.int64))
    truth = np.zeros(3)
    z = sl.landmark_measurement(truth, np.vstack([st.mu[0, [2, 0]], [[6.0, 6.0]]]))[0]
    z = z + rng.normal(scale=0.02, size=z.shape)
    both = sl.fastslam_update_unknown(st, z, Q, max_range=30.0)
    for k in range(n):
        pair = sl.FastSLAMState(*(a[[0, k]] for a in st))
        pair = pair._replace(log_weights=st.log_weights[[0, k]] - logsumexp(st.log_weights[[0, k]]))
        one = sl.fastslam_update_unknown(pair, z, Q, max_range=30.0)
        for field in ("mu", "Sigma", "seen", "counts"):
            np.testing.assert_allclose(getattr(one, field)[1], getattr(both, field)[k], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(one.log_weights[1] - one.log_weights[0],
                                   both.log_weights[k] - both.log_weights[0], rtol=1e-10, atol=1e-9)
    # the measurement of the far point started a new landmark everywhere; the others matched slots 2 and 0
    assert both.seen[:, 4].all() and (both.counts[:, [0, 2]] == 2).all()
