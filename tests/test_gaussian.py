"""Kalman filter and EKF localization (slamlib.gaussian) against theory."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import slamlib as sl
from slamlib.gaussian import DEFAULT_GATE

DT = 0.5
M_NOISE = np.diag([0.05**2, np.deg2rad(1.0) ** 2])
Q_NOISE = np.diag([0.1**2, np.deg2rad(2.0) ** 2])
SIGMA0 = np.diag([0.01, 0.01, np.deg2rad(2.0) ** 2])


def _world():
    return sl.make_landmark_world(15, extent=16.0, min_separation=2.0, rng=np.random.default_rng(7))


def _run(seed, n_steps=80, landmarks=None):
    rng = np.random.default_rng(seed)
    landmarks = _world() if landmarks is None else landmarks
    u = sl.loop_controls(n_steps, v=1.0, omega=0.2)
    x0 = np.array([0.0, -5.0, 0.0])
    run = sl.simulate_landmark_run(landmarks, u, DT, x0=x0, M=M_NOISE, Q=Q_NOISE, max_range=8.0,
                                   fov=np.pi, rng=rng)
    mu0 = x0 + rng.multivariate_normal(np.zeros(3), SIGMA0)
    return run, mu0


def _random_belief(rng, n=3):
    A = rng.normal(size=(n, n))
    return rng.normal(size=n), A @ A.T / n + 0.1 * np.eye(n)


def _frozen(*arrays):
    out = []
    for a in arrays:
        a = np.array(a, dtype=float)
        a.setflags(write=False)
        out.append(a)
    return out


def _assert_sym_psd(S):
    np.testing.assert_array_equal(S, np.swapaxes(S, -1, -2))
    assert np.linalg.eigvalsh(S).min() > -1e-12


# --------------------------------------------------------------------------- linear Kalman filter
def test_kf_scalar_closed_form():
    # scalar: K = P / (P + R), x = x + K (z - x), P = P R / (P + R)
    x, P = sl.kf_update([1.0], [[4.0]], [3.0], [[1.0]], [[1.0]])
    np.testing.assert_allclose(x, [1.0 + 0.8 * 2.0], rtol=1e-14)
    np.testing.assert_allclose(P, [[0.8]], rtol=1e-14)
    x, P = sl.kf_predict([1.0], [[0.8]], [[2.0]], [[0.5]], B=[[1.0]], u=[0.25])
    np.testing.assert_allclose(x, [2.25], rtol=1e-14)
    np.testing.assert_allclose(P, [[4 * 0.8 + 0.5]], rtol=1e-14)


def test_kf_equals_batch_bayesian_posterior():
    # a static state measured n times: the KF posterior is the Gaussian conjugate posterior
    # Sigma = (P0^-1 + sum H^T R^-1 H)^-1, mu = Sigma (P0^-1 x0 + sum H^T R^-1 z)
    rng = np.random.default_rng(3)
    x0, P0 = _random_belief(rng, 4)
    info, vec = np.linalg.inv(P0), np.linalg.solve(P0, x0)
    x, P = x0, P0
    for _ in range(6):
        H = rng.normal(size=(2, 4))
        R = np.diag(rng.uniform(0.1, 1.0, size=2))
        z = rng.normal(size=2)
        x, P = sl.kf_update(x, P, z, H, R)
        info += H.T @ np.linalg.solve(R, H)
        vec += H.T @ np.linalg.solve(R, z)
    P_ref = np.linalg.inv(info)
    np.testing.assert_allclose(P, P_ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(x, P_ref @ vec, rtol=1e-9, atol=1e-12)
    _assert_sym_psd(P)


def test_kf_random_walk_reaches_riccati_steady_state():
    q, r = 0.3, 2.0
    # steady-state prior variance p solves p^2 - q p - q r = 0; posterior p r / (p + r)
    p_bar = 0.5 * (q + np.sqrt(q * q + 4 * q * r))
    x, P = np.zeros(1), np.eye(1) * 10.0
    for z in np.random.default_rng(0).normal(size=200):
        x, P = sl.kf_predict(x, P, np.eye(1), q * np.eye(1))
        x, P = sl.kf_update(x, P, [z], np.eye(1), r * np.eye(1))
    np.testing.assert_allclose(P[0, 0], p_bar * r / (p_bar + r), rtol=1e-10)


def test_kf_batched_equals_looped():
    rng = np.random.default_rng(5)
    xs, Ps = zip(*(_random_belief(rng) for _ in range(4)))
    xs, Ps = np.array(xs), np.array(Ps)
    F = rng.normal(size=(4, 3, 3))
    Qp = np.eye(3) * 0.2
    H = rng.normal(size=(2, 3))
    z = rng.normal(size=(4, 2))
    R = np.diag([0.3, 0.5])
    xb, Pb = sl.kf_update(*sl.kf_predict(xs, Ps, F, Qp), z, H, R)
    for i in range(4):
        xi, Pi = sl.kf_update(*sl.kf_predict(xs[i], Ps[i], F[i], Qp), z[i], H, R)
        np.testing.assert_allclose(xb[i], xi, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(Pb[i], Pi, rtol=1e-12, atol=1e-14)


# --------------------------------------------------------------------------- EKF = KF on the linearised model
def test_ekf_predict_is_kf_on_linearised_motion():
    rng = np.random.default_rng(11)
    for _ in range(5):
        mu, Sigma = _random_belief(rng)
        u = np.array([rng.uniform(0.2, 2.0), rng.uniform(-1.0, 1.0)])
        g, G, V = sl.velocity_motion(mu, u, DT)
        mu_bar, Sigma_bar = sl.ekf_predict(mu, Sigma, u, DT, M_NOISE)
        # affine model x' = G x + (g - G mu) with process noise V M V^T
        x_kf, P_kf = sl.kf_predict(mu, Sigma, G, V @ M_NOISE @ V.T, B=np.eye(3), u=g - G @ mu)
        np.testing.assert_allclose(mu_bar[:2], x_kf[:2], rtol=1e-12, atol=1e-12)
        assert abs(sl.angle_diff(mu_bar[2], x_kf[2])) < 1e-12
        np.testing.assert_allclose(Sigma_bar, P_kf, rtol=1e-12, atol=1e-14)


def test_ekf_update_is_kf_on_linearised_measurement():
    rng = np.random.default_rng(12)
    m = np.array([3.0, 4.0])
    for _ in range(5):
        mu_bar, Sigma_bar = _random_belief(rng)
        mu_bar[2] = sl.wrap_angle(mu_bar[2])
        z_hat, H, _ = sl.landmark_measurement(mu_bar, m)
        z = z_hat + rng.normal(size=2) * [0.1, 0.05]
        mu, Sigma = sl.ekf_update(mu_bar, Sigma_bar, z, m, Q_NOISE)
        # pseudo-measurement z - h(mu_bar) + H mu_bar of the linear model H x
        nu = z - z_hat
        nu[1] = sl.wrap_angle(nu[1])
        x_kf, P_kf = sl.kf_update(mu_bar, Sigma_bar, nu + H @ mu_bar, H, Q_NOISE)
        np.testing.assert_allclose(mu[:2], x_kf[:2], rtol=1e-10, atol=1e-12)
        assert abs(sl.angle_diff(mu[2], x_kf[2])) < 1e-12
        np.testing.assert_allclose(Sigma, P_kf, rtol=1e-10, atol=1e-14)


def test_ekf_predict_exact_when_motion_is_linear():
    # heading known exactly and omega = 0 without noise: x' = x + v dt cos(theta) is
    # affine in (x, y, v), so the EKF covariance is the true covariance of the samples
    rng = np.random.default_rng(21)
    mu = np.array([1.0, -2.0, 0.7])
    Sigma = np.array([[0.2, 0.05, 0.0], [0.05, 0.1, 0.0], [0.0, 0.0, 0.0]])
    M = np.diag([0.3, 0.0])
    u = np.array([1.5, 0.0])
    mu_bar, Sigma_bar = sl.ekf_predict(mu, Sigma, u, DT, M)
    n = 200_000
    x = rng.multivariate_normal(mu, Sigma, size=n, method="eigh")
    uu = u + rng.multivariate_normal(np.zeros(2), M, size=n, method="eigh")
    xn, _, _ = sl.velocity_motion(x, uu, DT)
    np.testing.assert_allclose(xn.mean(axis=0), mu_bar, atol=5 * np.sqrt(Sigma_bar.diagonal().max() / n))
    np.testing.assert_allclose(np.cov(xn.T), Sigma_bar, atol=0.01 * Sigma_bar.max())


# --------------------------------------------------------------------------- contract details
def test_ekf_update_wraps_bearing_innovation():
    m = np.array([-5.0, -0.05])  # bearing from the origin just above -pi
    mu_bar, Sigma_bar = np.zeros(3), np.diag([0.1, 0.1, 0.05])
    z_hat, _, _ = sl.landmark_measurement(mu_bar, m)
    assert z_hat[1] < -np.pi + 0.02
    dphi = -0.03  # true bearing innovation: the measurement wraps to near +pi
    z = np.array([z_hat[0], sl.wrap_angle(z_hat[1] + dphi)])
    assert z[1] > np.pi - 0.03
    mu, Sigma = sl.ekf_update(mu_bar, Sigma_bar, z, m, Q_NOISE)
    # same as the unwrapped measurement z_hat + dphi (which we build by hand)
    mu_ref, Sigma_ref = sl.ekf_update(mu_bar, Sigma_bar, [z_hat[0], z_hat[1] + dphi], m, Q_NOISE)
    np.testing.assert_allclose(mu, mu_ref, atol=1e-12)
    np.testing.assert_allclose(Sigma, Sigma_ref, atol=1e-14)
    assert np.linalg.norm(mu) < 0.1


def test_ekf_heading_wrapped():
    mu, Sigma = sl.ekf_predict([0.0, 0.0, np.pi - 0.01], np.eye(3) * 0.01, [1.0, 1.0], DT, M_NOISE)
    assert -np.pi <= mu[2] < np.pi
    np.testing.assert_allclose(mu[2], np.pi - 0.01 + 0.5 - 2 * np.pi, atol=1e-12)


def test_associate_ml_contract():
    mu, Sigma = np.array([0.0, 0.0, 0.0]), np.diag([0.05, 0.05, 0.01])
    L = np.array([[4.0, 0.0], [0.0, 4.0], [4.0, 0.0], [-3.0, 0.1]])
    z, _, _ = sl.landmark_measurement(mu, L[0])
    z = z + [0.05, 0.0]
    d = sl.landmark_mahalanobis(mu, Sigma, z, L, Q_NOISE)
    assert d.shape == (4,) and d[0] == d[2] > 0
    j = sl.associate_ml(mu, Sigma, z, L, Q_NOISE, 100.0)
    assert j == 0 and isinstance(j, int)  # tie between 0 and 2 goes to the smaller index
    assert sl.associate_ml(mu, Sigma, z, L, Q_NOISE, d[0]) == 0  # d == gate is a match
    assert sl.associate_ml(mu, Sigma, z, L, Q_NOISE, np.nextafter(d[0], 0.0)) == -1
    assert sl.associate_ml(mu, Sigma, z, np.zeros((0, 2)), Q_NOISE, 100.0) == -1
    # by hand: nu^T S^-1 nu with S = H Sigma H^T + Q
    z_hat, H, _ = sl.landmark_measurement(mu, L[1])
    nu = z - z_hat
    nu[1] = sl.wrap_angle(nu[1])
    np.testing.assert_allclose(d[1], nu @ np.linalg.solve(H @ Sigma @ H.T + Q_NOISE, nu), rtol=1e-12)


def test_associate_ml_wraps_bearing():
    mu, Sigma = np.zeros(3), np.diag([0.05, 0.05, 0.01])
    L = np.array([[-5.0, -0.05], [-5.0, 3.0]])
    z_hat, _, _ = sl.landmark_measurement(mu, L[0])
    z = np.array([z_hat[0], sl.wrap_angle(z_hat[1] - 0.02)])  # near +pi
    assert sl.associate_ml(mu, Sigma, z, L, Q_NOISE, DEFAULT_GATE) == 0
    assert sl.landmark_mahalanobis(mu, Sigma, z, L, Q_NOISE)[0] < 1.0


def test_covariances_symmetric_psd_and_inputs_untouched():
    rng = np.random.default_rng(4)
    run, mu0 = _run(31, n_steps=40)
    mu, Sigma = mu0, SIGMA0
    for t in range(run.n_steps):
        args = _frozen(mu, Sigma, run.u[t], M_NOISE)
        before = [a.copy() for a in args]
        mu, Sigma = sl.ekf_predict(*args[:3], DT, args[3])
        for a, b in zip(args, before):
            np.testing.assert_array_equal(a, b)
        _assert_sym_psd(Sigma)
        for z, j in zip(run.z[t], run.ids[t]):
            args = _frozen(mu, Sigma, z, run.landmarks[j], Q_NOISE)
            mu, Sigma = sl.ekf_update(*args)
            _assert_sym_psd(Sigma)
    # a badly scaled update still returns an exactly symmetric PSD matrix
    _, S = _random_belief(rng)
    mu2, S2 = sl.ekf_update([0, 0, 0.3], S * 1e6, [2.0, 0.1], [1.0, 1.5], Q_NOISE * 1e-6)
    _assert_sym_psd(S2)


def test_filter_steps_do_not_mutate():
    run, mu0 = _run(32, n_steps=5)
    t = int(np.argmax([len(z) for z in run.z]))
    args = _frozen(mu0, SIGMA0, run.u[t], run.z[t], run.landmarks, M_NOISE, Q_NOISE)
    ids = np.array(run.ids[t])
    ids.setflags(write=False)
    mu, Sigma, u, z, L, M, Q = args
    sl.ekf_localization_known(mu, Sigma, u, z, ids, L, DT, M, Q)
    sl.ekf_localization_unknown(mu, Sigma, u, z, L, DT, M, Q)
    sl.associate_ml(mu, Sigma, z[0], L, Q, DEFAULT_GATE)


def test_ekf_batched_equals_looped():
    rng = np.random.default_rng(8)
    mus, Sigmas = map(np.array, zip(*(_random_belief(rng) for _ in range(5))))
    us = rng.uniform([0.2, -1.0], [2.0, 1.0], size=(5, 2))
    ms = rng.uniform(-6, 6, size=(5, 2))
    zs = rng.uniform([1.0, -3.0], [5.0, 3.0], size=(5, 2))
    mb, Sb = sl.ekf_predict(mus, Sigmas, us, DT, M_NOISE)
    mu, Su = sl.ekf_update(mb, Sb, zs, ms, Q_NOISE)
    for i in range(5):
        a, b = sl.ekf_predict(mus[i], Sigmas[i], us[i], DT, M_NOISE)
        np.testing.assert_allclose(mb[i], a, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(Sb[i], b, rtol=1e-12, atol=1e-14)
        a, b = sl.ekf_update(a, b, zs[i], ms[i], Q_NOISE)
        np.testing.assert_allclose(mu[i], a, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(Su[i], b, rtol=1e-12, atol=1e-14)


def test_step_functions_equal_predict_then_sequential_updates():
    run, mu0 = _run(33, n_steps=30)
    res = sl.ekf_localization_run(run, mu0=mu0, Sigma0=SIGMA0)
    mu, Sigma = mu0, SIGMA0
    for t in range(run.n_steps):
        mu, Sigma = sl.ekf_predict(mu, Sigma, run.u[t], DT, M_NOISE)
        for z, j in zip(run.z[t], run.ids[t]):
            mu, Sigma = sl.ekf_update(mu, Sigma, z, run.landmarks[j], Q_NOISE)
        np.testing.assert_allclose(res.mu[t + 1], mu, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(res.Sigma[t + 1], Sigma, rtol=1e-12, atol=1e-15)
    t = 3
    step = sl.ekf_localization_known(res.mu[t], res.Sigma[t], run.u[t], run.z[t], run.ids[t], run.landmarks,
                                     DT, M_NOISE, Q_NOISE)
    np.testing.assert_allclose(step.mean, res.mu[t + 1], atol=1e-12)
    assert np.all(np.abs(res.mu[:, 2]) <= np.pi)


# --------------------------------------------------------------------------- consistency and association
def test_ekf_localization_nees_inside_chi2_band():
    n_runs = 40
    # a landmark on the path (range ~0) breaks the linearisation of its bearing: in 25 of 150 worlds a run's NEES
    # reached hundreds to 7000 as the robot drove over one. Landmarks within 1.5 m of the nominal circle are left out
    landmarks = _world()
    landmarks = landmarks[np.abs(np.linalg.norm(landmarks, axis=1) - 5.0) > 1.5]
    runs, starts = zip(*(_run(1000 + k, landmarks=landmarks) for k in range(n_runs)))
    res = sl.ekf_localization_batch(runs, mu0=np.array(starts), Sigma0=SIGMA0)
    nees = sl.nees(sl.pose_error(res.mu, np.array([r.x_true for r in runs])), res.Sigma)
    avg = nees.mean(axis=0)  # average over runs at each time step
    # each step inside its chi2 band of mass 1 - 1e-4 / 81: a consistent filter fails with probability < 1e-4
    # (union bound, whatever the correlation of the steps). Over 100 worlds the averages stayed in [1.95, 4.65],
    # inside [1.48, 5.27]; a covariance x2 (M, Q, Sigma0) went below 1.3 at some step in each
    lo, hi = sl.nees_band(3, n_runs, 1 - 1e-4 / avg.size)
    assert np.all((avg >= lo) & (avg <= hi)), f"NEES {avg.min():.2f}-{avg.max():.2f} outside [{lo:.2f}, {hi:.2f}]"
    # the mean over all steps: 3.02 on average over 100 worlds, sd 0.093; the bounds are 4.5 sd away
    assert 2.6 < nees.mean() < 3.45
    # an overconfident filter (noise underestimated 4x) is caught by the same test (NEES 6.7-18 over 100 worlds)
    run, mu0 = _run(1000, landmarks=landmarks)
    bad = sl.ekf_localization_run(run, mu0=mu0, Sigma0=SIGMA0, M=M_NOISE / 4, Q=Q_NOISE / 4)
    assert sl.nees(sl.pose_error(bad.mu, run.x_true), bad.Sigma).mean() > sl.nees_band(3, n_runs, 0.95)[1]


def _with_clutter(run, rng, rate=2):
    """The run's measurements plus `rate` clutter returns per step (ids -1)."""
    zs, ids = [], []
    for z, j in zip(run.z, run.ids):
        k = rng.poisson(rate)
        clutter = np.column_stack([rng.uniform(0.5, 8.0, k), rng.uniform(-np.pi / 2, np.pi / 2, k)])
        order = rng.permutation(len(z) + k)
        zs.append(np.vstack([z, clutter])[order])
        ids.append(np.concatenate([j, -np.ones(k, int)])[order])
    return zs, ids


def test_unknown_correspondences_pick_landmarks_and_gate_clutter():
    run, mu0 = _run(41, n_steps=120)
    zs, true_ids = _with_clutter(run, np.random.default_rng(42))
    mu, Sigma = mu0, SIGMA0
    chosen = []
    for t in range(run.n_steps):
        (mu, Sigma), ids = sl.ekf_localization_unknown(mu, Sigma, run.u[t], zs[t], run.landmarks, DT,
                                                       M_NOISE, Q_NOISE, gate=DEFAULT_GATE)
        assert ids.shape == (len(zs[t]),) and ids.dtype.kind == "i"
        chosen.append(ids)
    chosen, truth = np.concatenate(chosen), np.concatenate(true_ids)
    real = truth >= 0
    # true returns: at most ~1 % fall outside the 99 % gate; the rest go to their landmark
    assert np.mean(chosen[real] == truth[real]) >= 0.97
    assert np.all((chosen[real] == truth[real]) | (chosen[real] == -1))
    # clutter: the gate rejects nearly all of it
    assert np.mean(chosen[~real] == -1) >= 0.9
    assert sl.ate_rmse(np.vstack([mu]), run.x_true[-1:]) < 0.3
    # the whole run against known correspondences without clutter
    known = sl.ekf_localization_run(run, mu0=mu0, Sigma0=SIGMA0)
    assert np.linalg.norm(mu[:2] - known.mu[-1, :2]) < 0.1


def test_batch_equals_run_by_run():
    landmarks = _world()
    runs, starts = zip(*(_run(2000 + k, n_steps=30, landmarks=landmarks) for k in range(4)))
    Q_filter = np.array([[0.02, 0.001], [0.001, 0.003]])
    res = sl.ekf_localization_batch(runs, mu0=np.array(starts), Sigma0=SIGMA0, Q=Q_filter)
    assert res.mu.shape == (4, 31, 3) and res.Sigma.shape == (4, 31, 3, 3)
    for k, (run, start) in enumerate(zip(runs, starts)):
        one = sl.ekf_localization_run(run, mu0=start, Sigma0=SIGMA0, Q=Q_filter)
        np.testing.assert_allclose(res.mu[k], one.mu, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(res.Sigma[k], one.Sigma, rtol=1e-12, atol=1e-15)
    with pytest.raises(ValueError, match="same number of steps"):
        sl.ekf_localization_batch([runs[0], _run(1, n_steps=5)[0]])
    with pytest.raises(ValueError, match="mu0"):
        sl.ekf_localization_batch(runs, mu0=np.zeros((3, 3)))


def test_unknown_run_without_clutter_matches_known():
    run, mu0 = _run(43)
    known = sl.ekf_localization_run(run, mu0=mu0, Sigma0=SIGMA0)
    unknown = sl.ekf_localization_run(run, known=False, mu0=mu0, Sigma0=SIGMA0, gate=np.inf)
    assert all(np.array_equal(a, b) for a, b in zip(unknown.ids, run.ids))
    np.testing.assert_allclose(unknown.mu, known.mu, atol=1e-12)


def _with_outliers(run, every, seed):
    """Every `every`-th measurement replaced by a gross outlier: bearing turned by about pi, range +2-4 m."""
    rng = np.random.default_rng(seed)
    zs, n = [], 0
    for z in run.z:
        z = np.array(z)
        for k in range(len(z)):
            n += 1
            if n % every == 0:
                z[k] = [z[k, 0] + rng.uniform(2.0, 4.0), sl.wrap_angle(z[k, 1] + np.pi + rng.uniform(-0.2, 0.2))]
        zs.append(z)
    return dataclasses.replace(run, z=tuple(zs)), n // every


def test_known_run_validation_gate_rejects_outliers():
    run, mu0 = _run(44)
    bad_run, n_bad = _with_outliers(run, 25, 45)
    clean = sl.ekf_localization_run(run, mu0=mu0, Sigma0=SIGMA0)
    broken = sl.ekf_localization_run(bad_run, mu0=mu0, Sigma0=SIGMA0)
    gate = -2 * np.log(1e-5)
    gated = sl.ekf_localization_run(bad_run, mu0=mu0, Sigma0=SIGMA0, gate=gate)
    assert n_bad >= 5 and clean.n_gated == broken.n_gated == 0
    assert n_bad <= gated.n_gated <= n_bad + 2
    err = {k: sl.ate_rmse(r.mu, run.x_true) for k, r in (("clean", clean), ("broken", broken), ("gated", gated))}
    assert err["broken"] > 2 * err["clean"] and err["gated"] < 1.2 * err["clean"]
    assert sum(int(np.sum(i < 0)) for i in gated.ids) == gated.n_gated
    # the gate compares nu^T S^-1 nu, the distance of associate_ml: a gate just below a measurement's
    # distance rejects it, just above accepts it
    t = next(t for t in range(run.n_steps) if len(run.z[t]) >= 1)
    mu_b, S_b = sl.ekf_predict(clean.mu[t], clean.Sigma[t], run.u[t], DT, M_NOISE)
    j = int(run.ids[t][0])
    d = sl.landmark_mahalanobis(mu_b, S_b, run.z[t][0], run.landmarks[j:j + 1], Q_NOISE)[0]
    one = dataclasses.replace(run, u=run.u[t:t + 1], z=(run.z[t][:1],), ids=(run.ids[t][:1],))
    ref = sl.ekf_update(mu_b, S_b, run.z[t][0], run.landmarks[j], Q_NOISE)
    lo = sl.ekf_localization_run(one, mu0=clean.mu[t], Sigma0=clean.Sigma[t], gate=d * (1 - 1e-9))
    hi = sl.ekf_localization_run(one, mu0=clean.mu[t], Sigma0=clean.Sigma[t], gate=d * (1 + 1e-9))
    assert lo.n_gated == 1 and hi.n_gated == 0
    np.testing.assert_allclose(hi.mu[1], ref.mean, atol=1e-12)
    np.testing.assert_allclose(lo.mu[1], mu_b, atol=1e-12)


def test_run_gate_defaults_to_the_runs_own_gate():
    run, mu0 = _run(46)
    bad_run, _ = _with_outliers(run, 25, 47)

    class WithGate:
        def __init__(self, base, gate):
            self.base, self.gate = base, gate

        def __getattr__(self, name):
            return getattr(self.base, name)

    by_run = sl.ekf_localization_run(WithGate(bad_run, 20.0), mu0=mu0, Sigma0=SIGMA0)
    by_arg = sl.ekf_localization_run(bad_run, mu0=mu0, Sigma0=SIGMA0, gate=20.0)
    assert by_run.n_gated == by_arg.n_gated > 0
    np.testing.assert_array_equal(by_run.mu, by_arg.mu)
    # unknown correspondences keep DEFAULT_GATE when the run has none
    a = sl.ekf_localization_run(bad_run, known=False, mu0=mu0, Sigma0=SIGMA0)
    b = sl.ekf_localization_run(bad_run, known=False, mu0=mu0, Sigma0=SIGMA0, gate=sl.gaussian.DEFAULT_GATE)
    np.testing.assert_array_equal(a.mu, b.mu)
    assert a.n_gated == b.n_gated > 0


# --------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    "call, name",
    [
        (lambda: sl.ekf_predict(np.zeros(2), np.eye(3), [1, 0], DT, M_NOISE), "mu"),
        (lambda: sl.ekf_predict(np.zeros(3), np.eye(2), [1, 0], DT, M_NOISE), "Sigma"),
        (lambda: sl.ekf_predict(np.zeros(3), [[1, 2, 0], [0, 1, 0], [0, 0, 1]], [1, 0], DT, M_NOISE), "Sigma"),
        (lambda: sl.ekf_predict(np.zeros(3), -np.eye(3), [1, 0], DT, M_NOISE), "Sigma"),
        (lambda: sl.ekf_predict(np.zeros(3), np.eye(3), [1, 0, 0], DT, M_NOISE), "u"),
        (lambda: sl.ekf_predict(np.zeros(3), np.eye(3), [1, 0], -1.0, M_NOISE), "dt"),
        (lambda: sl.ekf_predict(np.zeros(3), np.eye(3), [1, 0], DT, np.eye(3)), "M"),
        (lambda: sl.ekf_predict([0, np.nan, 0], np.eye(3), [1, 0], DT, M_NOISE), "mu"),
        (lambda: sl.ekf_update(np.zeros(3), np.eye(3), [1, 0], [2, 2], np.zeros((2, 2))), "Q"),
        (lambda: sl.ekf_update(np.zeros(3), np.eye(3), [1, 0, 3], [2, 2], Q_NOISE), "z"),
        (lambda: sl.ekf_update(np.zeros(3), np.eye(3), [1, 0], [2, 2, 2], Q_NOISE), "m"),
        (lambda: sl.ekf_update(np.zeros(3), np.eye(3), [1, 0], [0, 0], Q_NOISE), "m"),
        (lambda: sl.associate_ml(np.zeros(3), np.eye(3), [1, 0], np.ones(2), Q_NOISE, 9.0), "landmarks"),
        (lambda: sl.associate_ml(np.zeros(3), np.eye(3), [1, 0], np.ones((2, 2)), Q_NOISE, -1.0), "gate"),
        (lambda: sl.associate_ml(np.zeros(3), np.eye(3), [1, 0], np.ones((2, 2)), Q_NOISE, np.nan), "gate"),
        (lambda: sl.ekf_localization_known(np.zeros(3), np.eye(3), [1, 0], [[1, 0]], [5], np.ones((2, 2)),
                                           DT, M_NOISE, Q_NOISE), "ids"),
        (lambda: sl.ekf_localization_known(np.zeros(3), np.eye(3), [1, 0], [[1, 0]], [0.0], np.ones((2, 2)),
                                           DT, M_NOISE, Q_NOISE), "ids"),
        (lambda: sl.kf_update([0.0], [[1.0]], [1.0], [[1.0, 0.0]], [[1.0]]), "H"),
        (lambda: sl.kf_update([0.0], [[1.0]], [1.0], [[1.0]], [[0.0]]), "R"),
        (lambda: sl.kf_predict([0.0], [[1.0]], [[1.0]], [[1.0]], B=[[1.0]]), "B and u"),
        (lambda: sl.ekf_localization_run(object()), "run"),
    ],
)
def test_bad_input_names_the_argument(call, name):
    with pytest.raises((ValueError, TypeError), match=name):
        call()


# --------------------------------------------------------------------------- the scalar path of one filter
@pytest.mark.parametrize("omega", [0.0, 1e-9, 3e-7, 0.5, -2.0])
def test_one_pose_path_equals_batched_path(omega):
    rng = np.random.default_rng(21)
    mu, Sigma = _random_belief(rng)
    u = np.array([1.3, omega])
    one = sl.ekf_predict(mu, Sigma, u, DT, M_NOISE)  # the scalar motion path
    batch = sl.ekf_predict(mu[None], Sigma[None], u[None], DT, M_NOISE[None])  # the array path
    np.testing.assert_allclose(one.mean, batch.mean[0], rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(one.cov, batch.cov[0], rtol=1e-12, atol=1e-15)
    z, m = np.array([4.0, 2.9]), np.array([-3.0, 2.0])  # bearing innovation near +-pi: wrapped on both paths
    one = sl.ekf_update(one.mean, one.cov, z, m, Q_NOISE)
    batch = sl.ekf_update(batch.mean, batch.cov, z[None], m[None], Q_NOISE[None])
    np.testing.assert_allclose(one.mean, batch.mean[0], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(one.cov, batch.cov[0], rtol=1e-11, atol=1e-15)
    assert np.array_equal(one.cov, one.cov.T)


@pytest.mark.parametrize("k", [1, 2, 3])
def test_kf_update_gain_equals_a_linear_solve(k):
    rng = np.random.default_rng(k)
    x, P = _random_belief(rng, n=4)
    H = rng.normal(size=(k, 4))
    A = rng.normal(size=(k, k))
    R = A @ A.T + 0.1 * np.eye(k)
    z = rng.normal(size=k)
    x_new, P_new = sl.kf_update(x, P, z, H, R)
    S = H @ P @ H.T + R
    K = np.linalg.solve(S, H @ P).T  # K = P H^T S^-1
    np.testing.assert_allclose(x_new, x + K @ (z - H @ x), rtol=1e-11, atol=1e-13)
    np.testing.assert_allclose(P_new, P - K @ H @ P, rtol=1e-10, atol=1e-13)
    one = sl.kf_update(x[None], P[None], z[None], H[None], R[None])  # batched path uses the solver
    np.testing.assert_allclose(one.mean[0], x_new, rtol=1e-12, atol=1e-14)


def test_kf_update_refuses_asymmetric_or_indefinite_R():
    x, P, H = np.zeros(3), np.eye(3), np.eye(2, 3)
    with pytest.raises(ValueError, match="R must be symmetric"):
        sl.kf_update(x, P, np.zeros(2), H, [[1.0, 0.5], [0.0, 1.0]])
    with pytest.raises(ValueError, match="R must be positive definite"):
        sl.kf_update(x, P, np.zeros(2), H, [[1.0, 2.0], [2.0, 1.0]])
    with pytest.raises(ValueError, match="R must be positive definite"):
        sl.kf_update(x, P, np.zeros(2), H, np.zeros((2, 2)))
    with pytest.raises(ValueError, match=r"H must have shape \(2, 3\).*\(to match z and x\)"):
        sl.kf_update(x, P, np.zeros(2), np.eye(3), np.eye(2))


def test_gaussian_checks_its_fields():
    with pytest.raises(TypeError, match="mean must be a numeric array"):
        sl.Gaussian("abc", None)
    with pytest.raises(TypeError, match="cov must be a numeric array"):
        sl.Gaussian(np.zeros(2), None)
    with pytest.raises(ValueError, match=r"cov must have shape \(2, 2\).*\(to match mean\)"):
        sl.Gaussian(np.zeros(2), np.eye(3))
    with pytest.raises(ValueError, match="mean must be finite"):
        sl.Gaussian([np.nan, 0.0], np.eye(2))
    g = sl.Gaussian([1, 2], [[1, 0], [0, 1]])
    assert g.mean.dtype == np.float64 and g.cov.dtype == np.float64
    mean, cov = g  # still a NamedTuple
    assert g._replace(mean=np.ones(2)).mean[0] == 1.0
    assert isinstance(sl.kf_predict(np.zeros(2), np.eye(2), np.eye(2), np.eye(2)), sl.Gaussian)


# --------------------------------------------------------------------------- the run's pluggable steps
class _Recorder:
    """A contract function that records its calls (and may tamper with its arguments)."""

    def __init__(self, fn, tamper=False):
        self.fn, self.tamper, self.calls = fn, tamper, 0

    def __call__(self, *args):
        self.calls += 1
        out = self.fn(*args)
        if self.tamper:  # a function that modifies its arguments must not change the filter
            for a in args:
                if isinstance(a, np.ndarray):
                    a[...] = 0.0
        return out


@pytest.mark.parametrize("gate", [np.inf, 20.0])
def test_run_with_slamlibs_own_functions_plugged_in_is_the_same_run(gate):
    run, mu0 = _run(51)
    bad_run, _ = _with_outliers(run, 25, 52)
    own = sl.ekf_localization_run(bad_run, mu0=mu0, Sigma0=SIGMA0, gate=gate)
    predict, update = _Recorder(sl.ekf_predict, tamper=True), _Recorder(sl.ekf_update, tamper=True)
    steps = []
    plugged = sl.ekf_localization_run(bad_run, mu0=mu0, Sigma0=SIGMA0, gate=gate, ekf_predict=predict,
                                      ekf_update=update, on_step=steps.append)
    np.testing.assert_array_equal(plugged.mu, own.mu)
    np.testing.assert_array_equal(plugged.Sigma, own.Sigma)
    assert plugged.n_gated == own.n_gated and (gate == np.inf) == (own.n_gated == 0)
    assert steps == list(range(run.n_steps)) and predict.calls == run.n_steps
    assert update.calls == sum(len(z) for z in run.z) - own.n_gated
    # unknown correspondences: the association is plugged in too
    own = sl.ekf_localization_run(bad_run, known=False, mu0=mu0, Sigma0=SIGMA0)
    associate = _Recorder(sl.associate_ml, tamper=True)
    plugged = sl.ekf_localization_run(bad_run, known=False, mu0=mu0, Sigma0=SIGMA0, ekf_update=update,
                                      associate_ml=associate)
    np.testing.assert_array_equal(plugged.mu, own.mu)
    assert all(np.array_equal(a, b) for a, b in zip(plugged.ids, own.ids)) and own.n_gated > 0
    assert associate.calls == sum(len(z) for z in run.z)


def test_run_uses_what_the_plugged_in_functions_return():
    run, mu0 = _run(53, n_steps=20)

    def lazy_update(mu_bar, Sigma_bar, z, m, Q):  # a wrong update: the measurement changes nothing
        return mu_bar, Sigma_bar

    res = sl.ekf_localization_run(run, mu0=mu0, Sigma0=SIGMA0, ekf_update=lazy_update)
    blind = sl.ekf_localization_run(dataclasses.replace(run, z=tuple(np.zeros((0, 2)) for _ in run.z),
                                                        ids=tuple(np.zeros(0, int) for _ in run.ids)),
                                    mu0=mu0, Sigma0=SIGMA0)
    np.testing.assert_allclose(res.mu, blind.mu, atol=1e-12)
    first = sl.ekf_localization_run(run, known=False, mu0=mu0, Sigma0=SIGMA0,
                                    associate_ml=lambda mu, S, z, lm, Q, gate: 0)
    assert all(np.all(i == 0) for i in first.ids)


def test_run_refuses_bad_plugged_in_functions_naming_them():
    run, mu0 = _run(54, n_steps=5)
    with pytest.raises(TypeError, match="ekf_predict must be a callable ekf_predict"):
        sl.ekf_localization_run(run, ekf_predict=3)
    with pytest.raises(TypeError, match="on_step"):
        sl.ekf_localization_run(run, on_step="x")
    with pytest.raises(ValueError, match="associate_ml needs known=False"):
        sl.ekf_localization_run(run, associate_ml=sl.associate_ml)
    with pytest.raises(ValueError, match=r"ekf_predict\(\.\.\.\)\[1\] must have shape \(3, 3\)"):
        sl.ekf_localization_run(run, ekf_predict=lambda mu, S, u, dt, M: (mu, S[:2]))
    with pytest.raises(ValueError, match="ekf_update must return a tuple of 2 arrays"):
        sl.ekf_localization_run(run, ekf_update=lambda mu, S, z, m, Q: mu)
    with pytest.raises(ValueError, match=r"ekf_update\(\.\.\.\)\[0\] must be finite"):
        sl.ekf_localization_run(run, ekf_update=lambda mu, S, z, m, Q: (mu * np.nan, S))
    with pytest.raises(ValueError, match=r"associate_ml\(\.\.\.\) must be in \[-1, 15\)"):
        sl.ekf_localization_run(run, known=False, associate_ml=lambda mu, S, z, lm, Q, gate: 15)
    with pytest.raises(TypeError, match=r"associate_ml\(\.\.\.\) must be an integer"):
        sl.ekf_localization_run(run, known=False, associate_ml=lambda mu, S, z, lm, Q, gate: 1.0)
