"""End-to-end checks: the course's filters, with one student function plugged in.

Each loop takes the filter's building blocks as callables, so that a test can run
it twice on the same seeded scenario: once with ``slamlib``'s functions only (the
reference) and once with exactly one of them replaced by the student's function
(called in the child process). The loops follow the algorithms of the chapters
(EKF localization, Table 7.2/7.3; a particle filter, Table 4.3; EKF SLAM,
Algorithm 1; FastSLAM 1.0, Algorithm 3) and use ``slamlib`` for everything else.

A reference building block that rejects what the student's function produced
(say, a covariance that is not symmetric) raises :class:`LoopError`, which the
test reports as a failure at that step.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

import slamlib as sl

__all__ = ["LoopError", "scenario", "ekf_localization_loop", "particle_filter_loop", "ekf_slam_loop",
           "fastslam_loop", "ate"]


class LoopError(Exception):
    """A reference step could not use a value the student's function returned."""


def _ref(step, what, fn, *args, **kwargs):
    try:
        return fn(*args, **kwargs)
    except (ValueError, TypeError, np.linalg.LinAlgError) as exc:
        raise LoopError(f"step {step}: the reference {what} could not use your result ({exc})") from None


@lru_cache(maxsize=None)
def scenario(name):
    """A seeded :class:`~slamlib.sim.LandmarkRun` (cached; the same in every grading)."""
    if name == "localization":
        rng = np.random.default_rng(4242)
        landmarks = sl.make_landmark_world(10, extent=14.0, min_separation=2.0, rng=rng)
        u = sl.loop_controls(80, v=1.0, omega=0.35)
        return sl.simulate_landmark_run(landmarks, u, 0.2, x0=np.array([0.0, -2.857, 0.0]),
                                        M=np.diag([0.02, 0.01]), Q=np.diag([0.15**2, 0.04**2]),
                                        max_range=6.0, fov=1.2 * np.pi, rng=rng)
    if name == "slam":
        rng = np.random.default_rng(5151)
        landmarks = sl.make_landmark_world(8, extent=12.0, min_separation=2.5, rng=rng)
        u = sl.loop_controls(70, v=1.0, omega=0.4)
        return sl.simulate_landmark_run(landmarks, u, 0.2, x0=np.array([0.0, -2.5, 0.0]),
                                        M=np.diag([0.01, 0.005]), Q=np.diag([0.1**2, 0.02**2]),
                                        max_range=7.0, fov=1.5 * np.pi, rng=rng)
    raise KeyError(name)


def ate(est, run):
    """Absolute trajectory error (position RMSE) against the run's true poses."""
    return float(sl.ate_rmse(np.asarray(est), run.x_true))


# --------------------------------------------------------------------------- EKF localization
def ekf_localization_loop(run, *, predict, update, associate=None, gate=None, Sigma0=None):
    """EKF localization (Table 7.2; with ``associate``, nearest-neighbour association as in Table 7.3).

    Returns
    -------
    traj : ndarray, shape (T+1, 3)
    ids : list of int
        The association chosen for each measurement (unknown correspondences only).
    """
    mu = np.array(run.x0, dtype=float)
    Sigma = np.diag([0.01, 0.01, 0.001]) if Sigma0 is None else Sigma0
    traj = [mu]
    chosen = []
    for t in range(run.n_steps):
        mu, Sigma = predict(t, mu, Sigma, np.array(run.u[t]), run.dt, np.array(run.M))
        for i, z in enumerate(run.z[t]):
            z = np.array(z)
            if associate is None:
                j = int(run.ids[t][i])
            else:
                j = associate(t, mu, Sigma, z, np.array(run.landmarks), np.array(run.Q), gate)
                chosen.append(j)
                if j < 0:
                    continue
            mu, Sigma = update(t, mu, Sigma, z, np.array(run.landmarks[j]), np.array(run.Q))
        traj.append(mu)
    return np.array(traj), chosen


def ref_ekf_predict(t, mu, Sigma, u, dt, M):
    return _ref(t, "EKF prediction", sl.ekf_predict, mu, Sigma, u, dt, M)


def ref_ekf_update(t, mu, Sigma, z, m, Q):
    return _ref(t, "EKF update", sl.ekf_update, mu, Sigma, z, m, Q)


def ref_associate(t, mu, Sigma, z, landmarks, Q, gate):
    return _ref(t, "association", sl.associate_ml, mu, Sigma, z, landmarks, Q, gate)


# --------------------------------------------------------------------------- particle filter
def particle_filter_loop(run, *, likelihood, normalize, ess, resample, n_particles=300, seed=77):
    """Particle-filter localization with known landmark correspondences (Table 4.3).

    Motion: each particle follows its own noisy control ``u + N(0, M)`` along the
    exact arc (the simulator's noise model). Weights: the product of the
    landmark likelihoods, accumulated in log space; normalised; resampled when
    the effective sample size drops below half the particles, with the draw's
    generator seeded per step.

    Returns
    -------
    traj : ndarray, shape (T+1, 3)
        Weighted mean pose (circular mean heading) after each step.
    """
    rng = np.random.default_rng(seed)
    Mp = n_particles
    particles = np.array(run.x0) + rng.normal(0.0, [0.1, 0.1, 0.03], size=(Mp, 3))
    particles[:, 2] = sl.wrap_angle(particles[:, 2])
    w = np.full(Mp, 1.0 / Mp)
    L = np.linalg.cholesky(np.array(run.M) + 1e-12 * np.eye(2))
    traj = [np.array(run.x0, dtype=float)]
    for t in range(run.n_steps):
        u_k = np.array(run.u[t]) + rng.standard_normal((Mp, 2)) @ L.T
        particles, _, _ = sl.velocity_motion(particles, u_k, run.dt)
        logw = np.log(np.maximum(w, 1e-300))
        for z, j in zip(run.z[t], run.ids[t]):
            p = likelihood(t, particles, np.array(z), np.array(run.landmarks[j]), np.array(run.Q))
            with np.errstate(divide="ignore"):
                logw = logw + np.log(p)
        if not np.any(np.isfinite(logw)):
            raise LoopError(f"step {t}: every particle got likelihood 0")
        logw = np.where(np.isfinite(logw), logw, -1e300)
        w = normalize(t, logw)
        mean = np.array([np.dot(w, particles[:, 0]), np.dot(w, particles[:, 1]),
                         sl.circular_mean(particles[:, 2], w)])
        traj.append(mean)
        if ess(t, w) < 0.5 * Mp:
            idx = resample(t, w, 10_000 + 97 * t)
            particles = particles[idx]
            w = np.full(Mp, 1.0 / Mp)
    return np.array(traj)


def ref_likelihood(t, particles, z, m, Q):
    return sl.landmark_likelihood(particles, z, m, Q)


def ref_normalize(t, logw):
    return _ref(t, "weight normalisation", sl.normalize_log_weights, logw)


def ref_ess(t, w):
    return _ref(t, "effective sample size", sl.effective_sample_size, w)


def ref_resample(t, w, seed):
    return _ref(t, "resampler", sl.low_variance_resample, w, rng=np.random.default_rng(seed))


# --------------------------------------------------------------------------- EKF SLAM
def ekf_slam_loop(run, *, predict, init, update, prior_var=1e4):
    """EKF SLAM with known correspondences (Algorithm 1), sequential updates.

    Returns
    -------
    traj : ndarray, shape (T+1, 3)
    landmarks : ndarray, shape (N, 2)
        Final landmark estimates (NaN for landmarks never seen).
    """
    N = run.landmarks.shape[0]
    n = 3 + 2 * N
    mu = np.zeros(n)
    mu[:3] = run.x0
    Sigma = np.zeros((n, n))
    Sigma[3:, 3:] = prior_var * np.eye(2 * N)
    seen = np.zeros(N, dtype=bool)
    traj = [mu[:3].copy()]
    for t in range(run.n_steps):
        mu, Sigma = predict(t, mu, Sigma, np.array(run.u[t]), run.dt, np.array(run.M))
        for z, j in zip(run.z[t], run.ids[t]):
            j = int(j)
            z = np.array(z)
            if not seen[j]:
                mu = init(t, mu, z, j)
                seen[j] = True
            mu, Sigma = update(t, mu, Sigma, z, j, np.array(run.Q))
        traj.append(mu[:3].copy())
    lm = mu[3:].reshape(N, 2).copy()
    lm[~seen] = np.nan
    return np.array(traj), lm


def ref_slam_predict(t, mu, Sigma, u, dt, M):
    return _ref(t, "EKF SLAM prediction", sl.ekf_slam_predict, mu, Sigma, u, dt, M)


def ref_slam_init(t, mu, z, j):
    return _ref(t, "landmark initialisation", sl.ekf_slam_init_landmark, mu, z, j)


def ref_slam_update(t, mu, Sigma, z, j, Q):
    return _ref(t, "EKF SLAM update", sl.ekf_slam_update, mu, Sigma, z, j, Q)


# --------------------------------------------------------------------------- FastSLAM
def fastslam_loop(run, *, init, update, n_particles=60, seed=99):
    """FastSLAM 1.0 with known correspondences (Algorithm 3), vectorised over particles.

    Every particle sees a landmark for the first time at the same step (known
    correspondences), so ``init`` and ``update`` are called once per measurement
    for all particles. Resampling (low variance, seeded per step) when the
    effective sample size drops below half the particles.

    Returns
    -------
    traj : ndarray, shape (T+1, 3)
        Weighted mean pose after each step.
    """
    rng = np.random.default_rng(seed)
    Mp = n_particles
    N = run.landmarks.shape[0]
    poses = np.tile(np.array(run.x0, dtype=float), (Mp, 1))
    mu = np.zeros((Mp, N, 2))
    Sig = np.zeros((Mp, N, 2, 2))
    seen = np.zeros(N, dtype=bool)
    logw = np.full(Mp, -np.log(Mp))
    L = np.linalg.cholesky(np.array(run.M) + 1e-12 * np.eye(2))
    Q = np.array(run.Q)
    traj = [np.array(run.x0, dtype=float)]
    for t in range(run.n_steps):
        u_k = np.array(run.u[t]) + rng.standard_normal((Mp, 2)) @ L.T
        poses, _, _ = sl.velocity_motion(poses, u_k, run.dt)
        for z, j in zip(run.z[t], run.ids[t]):
            j = int(j)
            z = np.array(z)
            if z[0] <= 0:
                continue
            if not seen[j]:
                m_new, S_new = init(t, poses, z, Q)
                mu[:, j], Sig[:, j] = m_new, S_new
                seen[j] = True
            else:
                m_new, S_new, w = update(t, poses, mu[:, j].copy(), Sig[:, j].copy(), z, Q)
                mu[:, j], Sig[:, j] = m_new, S_new
                with np.errstate(divide="ignore"):
                    logw = logw + np.log(w)
        if not np.any(np.isfinite(logw)):
            raise LoopError(f"step {t}: every particle got weight 0")
        logw = np.where(np.isfinite(logw), logw, -1e300)
        w = sl.normalize_log_weights(logw)
        traj.append(np.array([np.dot(w, poses[:, 0]), np.dot(w, poses[:, 1]), sl.circular_mean(poses[:, 2], w)]))
        if sl.effective_sample_size(w) < 0.5 * Mp:
            idx = sl.low_variance_resample(w, rng=np.random.default_rng(20_000 + 31 * t))
            poses, mu, Sig = poses[idx], mu[idx], Sig[idx]
            logw = np.full(Mp, -np.log(Mp))
        else:
            logw = np.log(w)
    return np.array(traj)


def ref_fs_init(t, x, z, Q):
    return _ref(t, "landmark initialisation", sl.fastslam_init_landmark, x, z, Q)


def ref_fs_update(t, x, mu, Sigma, z, Q):
    return _ref(t, "landmark update", sl.fastslam_update_landmark, x, mu, Sigma, z, Q)


@lru_cache(maxsize=None)
def reference(name):
    """Reference results of each loop on its scenario (cached per process)."""
    if name == "ekf_known":
        run = scenario("localization")
        return ekf_localization_loop(run, predict=ref_ekf_predict, update=ref_ekf_update)[0]
    if name == "ekf_unknown":
        run = scenario("localization")
        traj, ids = ekf_localization_loop(run, predict=ref_ekf_predict, update=ref_ekf_update,
                                          associate=ref_associate, gate=GATE)
        return traj, tuple(ids)
    if name == "pf":
        return particle_filter_loop(scenario("localization"), likelihood=ref_likelihood, normalize=ref_normalize,
                                    ess=ref_ess, resample=ref_resample)
    if name == "ekf_slam":
        return ekf_slam_loop(scenario("slam"), predict=ref_slam_predict, init=ref_slam_init, update=ref_slam_update)
    if name == "fastslam":
        return fastslam_loop(scenario("slam"), init=ref_fs_init, update=ref_fs_update)
    raise KeyError(name)


#: Association gate of the unknown-correspondence loop: the 99 % quantile of chi-square(2).
GATE = float(-2.0 * np.log(0.01))


def compare_ate(ctx, what, est, ref, run, *, rel=0.05, abs_tol=0.01):
    """Fail unless the ATE of ``est`` is within ``rel * ATE_ref + abs_tol`` of the reference's."""
    a_s, a_r = ate(est, run), ate(ref, run)
    if not np.isfinite(a_s) or abs(a_s - a_r) > rel * a_r + abs_tol:
        ctx.fail(f"{what}: the trajectory error (ATE) is {a_s:.4f} m, the reference filter's is {a_r:.4f} m "
                 f"(allowed difference {rel * a_r + abs_tol:.4f} m)")
    return a_s, a_r
