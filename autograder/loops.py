"""End-to-end checks: slamlib's filters, with one student function plugged in.

Each loop is one call of a ``slamlib`` driver (:func:`slamlib.ekf_localization_run`,
:func:`slamlib.run_particle_filter`, :func:`slamlib.run_ekf_slam`,
:func:`slamlib.run_fastslam`) on a seeded scenario, with every building block the
exercises implement plugged into the driver's hooks: the student's function (called
in the child process, through the test's checks) for the one under test and
``slamlib``'s public functions for the others. The reference run plugs
``slamlib``'s functions into all of them, so both runs take exactly the same path
through the driver.

Every scenario is drawn from the test's seeded generator (:func:`scenario`), which
follows the per-submission seed: the landmarks, the circuit, the noise and the
filters' own draws differ between gradings, and the reference run is computed for
each scenario. Nothing a loop passes to a student's function is the same for every
submission, so answers recorded in one grading do not fit the next.

The student's functions are called as ``f(t, *contract arguments)``, ``t`` the step
(the drivers' ``on_step`` says which). A reference function that rejects what the
student's function produced (say, a covariance that is not symmetric), or a driver
that cannot use it, raises :class:`LoopError`, which the test reports as a failure
at that step.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import numpy as np

import slamlib as sl

__all__ = ["LoopError", "Scenario", "scenario", "reference", "ekf_localization_loop", "particle_filter_loop",
           "ekf_slam_loop", "fastslam_loop", "ate"]


class LoopError(Exception):
    """A reference function, or the driver itself, could not use a value the student's function returned."""


_REJECTED = (ValueError, TypeError, np.linalg.LinAlgError)


class _Step:
    """The step the driver is at: its ``on_step`` hook."""

    def __init__(self):
        self.t = 0

    def __call__(self, t):
        self.t = int(t)


def _plug(step, student, reference, what):
    """The hook of one building block: ``student(t, *args)`` if given, else ``slamlib``'s ``reference(*args)``."""
    if student is not None:
        return lambda *args, **kwargs: student(step.t, *args, **kwargs)

    def ref(*args, **kwargs):
        try:
            return reference(*args, **kwargs)
        except _REJECTED as exc:
            raise LoopError(f"step {step.t}: the reference {what} could not use your result ({exc})") from None

    return ref


def _drive(step, driver, *args, **kwargs):
    """``driver(*args, on_step=step, **kwargs)``; a value the driver cannot use is a :class:`LoopError` at that step."""
    try:
        return driver(*args, on_step=step, **kwargs)
    except _REJECTED as exc:
        raise LoopError(f"step {step.t}: the filter could not use your result ({exc})") from None


class Scenario(NamedTuple):
    """One end-to-end scenario of one test: a simulated run and the seeds of the filters' own draws.

    Built by :func:`scenario` from the test's seeded generator, so that it follows
    the per-submission seed: nothing in it is the same from one grading to the next.
    """

    name: str
    seed: int

    @property
    def run(self):
        """The simulated :class:`~slamlib.sim.LandmarkRun` (built once per seed, cached)."""
        return _simulate(self.name, self.seed)

    @property
    def filter_seed(self):
        """Seed of a particle filter's own generator (initial particles, motion noise)."""
        return _derive(self.seed, 1)


def _derive(seed, *path):
    """A 63-bit seed derived from ``seed`` and ``path`` (independent streams of one scenario)."""
    return int(np.random.SeedSequence([int(seed), *path]).generate_state(1, np.uint64)[0] >> np.uint64(1))


def scenario(name, rng):
    """The scenario ``name`` (``"localization"`` or ``"slam"``) drawn from the test's generator ``rng``.

    The seed comes from ``rng`` (the test's generator, itself derived from the
    submission's seed): the landmarks, the circuit (speed, turn rate, start heading),
    the noise of the controls and measurements and the filters' draws all change
    with it.
    """
    if name not in _SCENARIOS:
        raise KeyError(name)
    return Scenario(name, int(rng.integers(2**62)))


#: name -> (landmarks, extent, min_separation, steps, v range, omega range, M, Q, max_range, fov)
_SCENARIOS = {
    "localization": (10, 14.0, 2.0, 80, (0.9, 1.1), (0.32, 0.38), np.diag([0.02, 0.01]),
                     np.diag([0.15**2, 0.04**2]), 6.0, 1.2 * np.pi),
    "slam": (8, 12.0, 2.5, 70, (0.9, 1.1), (0.37, 0.43), np.diag([0.01, 0.005]), np.diag([0.1**2, 0.02**2]),
             7.0, 1.5 * np.pi),
}


@lru_cache(maxsize=16)
def _simulate(name, seed):
    n, extent, sep, steps, v_range, w_range, M, Q, max_range, fov = _SCENARIOS[name]
    rng = np.random.default_rng(seed)
    landmarks = sl.make_landmark_world(n, extent=extent, min_separation=sep, rng=rng)
    v, omega = rng.uniform(*v_range), rng.uniform(*w_range)
    th0 = rng.uniform(-np.pi, np.pi)
    r = v / omega  # a counter-clockwise circle of radius r around the origin, entered at heading th0
    x0 = np.array([r * np.sin(th0), -r * np.cos(th0), th0])
    u = sl.loop_controls(steps, v=v, omega=omega)
    return sl.simulate_landmark_run(landmarks, u, 0.2, x0=x0, M=M, Q=Q, max_range=max_range, fov=fov, rng=rng)


def ate(est, run):
    """Absolute trajectory error (position RMSE) against the run's true poses."""
    return float(sl.ate_rmse(np.asarray(est), run.x_true))


# --------------------------------------------------------------------------- EKF localization
def ekf_localization_loop(sc, *, known=True, predict=None, update=None, associate=None):
    """EKF localization with known correspondences (Table 7.2) or unknown ones (Table 7.3).

    :func:`slamlib.ekf_localization_run` with ``ekf_predict``, ``ekf_update`` and
    (unknown correspondences) ``associate_ml`` plugged in; ``None`` plugs in
    ``slamlib``'s. Unknown correspondences use the gate :data:`GATE`.

    Returns
    -------
    traj : ndarray, shape (T+1, 3)
    ids : list of int
        The association chosen for each measurement (unknown correspondences only).
    """
    if known and associate is not None:
        raise ValueError("associate needs known=False")
    step = _Step()
    res = _drive(step, sl.ekf_localization_run, sc.run, known=known, gate=None if known else GATE,
                 ekf_predict=_plug(step, predict, sl.ekf_predict, "EKF prediction"),
                 ekf_update=_plug(step, update, sl.ekf_update, "EKF update"),
                 associate_ml=None if known else _plug(step, associate, sl.associate_ml, "association"))
    return res.mu, [] if known else [int(j) for ids in res.ids for j in ids]


# --------------------------------------------------------------------------- particle filter
def particle_filter_loop(sc, *, likelihood=None, normalize=None, ess=None, resample=None, n_particles=300):
    """Particle-filter localization with known landmark correspondences (Table 4.3).

    :func:`slamlib.run_particle_filter` from ``n_particles`` particles drawn around
    the start pose, with ``landmark_likelihood``, ``normalize_log_weights``,
    ``effective_sample_size`` and the resampler plugged in (``None``: ``slamlib``'s;
    the resampler is ``low_variance_resample``). Resampling when the effective sample
    size drops below half the particles. The resampler is called as
    ``resample(t, w, seed)`` and draws from a generator seeded per step, so that the
    student's draws and the reference's are the same and the filter's own generator
    (the motion noise) does not depend on them.

    Returns
    -------
    traj : ndarray, shape (T+1, 3)
        Weighted mean pose (circular mean heading) after each step.
    """
    run = sc.run
    rng = np.random.default_rng(sc.filter_seed)
    particles = np.array(run.x0) + rng.normal(0.0, [0.1, 0.1, 0.03], size=(n_particles, 3))
    particles[:, 2] = sl.wrap_angle(particles[:, 2])
    step = _Step()
    draws = _plug(step, resample, lambda w, seed: sl.low_variance_resample(w, rng=np.random.default_rng(seed)),
                  "resampler")

    def resampler(w, *, rng):  # the step's seeded generator, not the filter's rng
        return draws(w, _derive(sc.seed, 2, step.t))

    res = _drive(step, sl.run_particle_filter, run, particles, rng=rng, resample=resampler, ess_threshold=0.5,
                 landmark_likelihood=_plug(step, likelihood, sl.landmark_likelihood, "landmark likelihood"),
                 normalize_log_weights=_plug(step, normalize, sl.normalize_log_weights, "weight normalisation"),
                 effective_sample_size=_plug(step, ess, sl.effective_sample_size, "effective sample size"))
    return res.x_est


# --------------------------------------------------------------------------- EKF SLAM
def ekf_slam_loop(sc, *, predict=None, init=None, update=None, prior_var=1e4):
    """EKF SLAM with known correspondences (Algorithm 1), sequential updates.

    :func:`slamlib.run_ekf_slam` (the teaching version, ``fast=False``: the state
    grows by each new landmark) with ``ekf_slam_predict``, ``ekf_slam_init_landmark``
    and ``ekf_slam_update`` plugged in (``None``: ``slamlib``'s).

    Returns
    -------
    traj : ndarray, shape (T+1, 3)
    landmarks : ndarray, shape (N, 2)
        Final landmark estimates by the run's landmark index (NaN for landmarks never seen).
    """
    run = sc.run
    step = _Step()
    res = _drive(step, sl.run_ekf_slam, run, known=True, fast=False, prior_var=prior_var,
                 ekf_slam_predict=_plug(step, predict, sl.ekf_slam_predict, "EKF SLAM prediction"),
                 ekf_slam_init_landmark=_plug(step, init, sl.ekf_slam_init_landmark, "landmark initialisation"),
                 ekf_slam_update=_plug(step, update, sl.ekf_slam_update, "EKF SLAM update"))
    lm = np.full((run.landmarks.shape[0], 2), np.nan)
    lm[res.landmark_ids] = res.landmarks
    return res.x, lm


# --------------------------------------------------------------------------- FastSLAM
def fastslam_loop(sc, *, init=None, update=None, n_particles=60):
    """FastSLAM 1.0 with known correspondences (Algorithm 3), vectorised over particles.

    :func:`slamlib.run_fastslam` with ``fastslam_init_landmark`` and
    ``fastslam_update_landmark`` plugged in (``None``: ``slamlib``'s); every particle
    sees a landmark for the first time at the same step (known correspondences), so
    each is called once per measurement for all particles. Resampling (low variance)
    when the effective sample size drops below half the particles.

    Returns
    -------
    traj : ndarray, shape (T+1, 3)
        Weighted mean pose after each step.
    """
    step = _Step()
    res = _drive(step, sl.run_fastslam, sc.run, n_particles=n_particles, rng=np.random.default_rng(sc.filter_seed),
                 known=True,
                 resample_threshold=0.5,
                 fastslam_init_landmark=_plug(step, init, sl.fastslam_init_landmark, "landmark initialisation"),
                 fastslam_update_landmark=_plug(step, update, sl.fastslam_update_landmark, "landmark update"))
    return res.x_est


@lru_cache(maxsize=32)
def reference(name, sc):
    """Reference results of loop ``name`` on scenario ``sc``: the same drivers, slamlib's functions.

    Computed for each grading's own scenario (a scenario follows the submission's
    seed); cached only while the same scenario is graded again in this process.
    """
    if name == "ekf_known":
        return ekf_localization_loop(sc)[0]
    if name == "ekf_unknown":
        traj, ids = ekf_localization_loop(sc, known=False)
        return traj, tuple(ids)
    if name == "pf":
        return particle_filter_loop(sc)
    if name == "ekf_slam":
        return ekf_slam_loop(sc)
    if name == "fastslam":
        return fastslam_loop(sc)
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
