"""Particle filters: importance weights, resampling and a vectorised filter step.

* Weights live in log space: :func:`normalize_log_weights` (``logsumexp``),
  :func:`effective_sample_size`.
* Resamplers, all ``(w, *, rng) -> indices (M,)`` of an integer dtype:
  :func:`multinomial_resample`, :func:`stratified_resample`,
  :func:`systematic_resample` (the same as :func:`low_variance_resample`,
  Table 4.4) and :func:`residual_resample`.
* :func:`landmark_likelihood` -- the range-bearing measurement likelihood of
  every particle.
* :func:`bootstrap_filter_step` -- the generic particle filter (Table 4.3) for
  any state, given a sampler of the motion model and a log-likelihood;
  :func:`particle_filter_step` -- the same for poses with the velocity motion
  model and landmark measurements, :func:`run_particle_filter` over a whole
  run; :func:`particle_gaussian` -- the weighted mean and covariance of a
  particle set.

Nothing loops over particles in Python: every operation is a NumPy array
operation over all ``M`` particles at once.

References
----------
Thrun, Burgard & Fox, *Probabilistic Robotics* (2005), Sec. 4.3 (Table 4.3,
the particle filter; Table 4.4, the low-variance sampler; Sec. 4.3.4,
resampling and the effective sample size).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ._checks import (as_array, as_covariance, as_indices, as_log_weights, as_poses, as_probabilities, as_returned,
                      as_rows, as_scalar, as_weights, check_callable, check_log_weights, check_rng, check_rows)
from .angles import _circular_mean, _wrap, wrap_angle
from .gaussian import _gaussian
from .motion import _arc_pose, _control_sqrt

__all__ = [
    "ParticleSet",
    "PFStepInfo",
    "normalize_log_weights",
    "effective_sample_size",
    "low_variance_resample",
    "systematic_resample",
    "stratified_resample",
    "multinomial_resample",
    "residual_resample",
    "RESAMPLERS",
    "landmark_likelihood",
    "bootstrap_filter_step",
    "particle_filter_step",
    "PFRunResult",
    "run_particle_filter",
    "particle_gaussian",
]

_LOG_2PI = float(np.log(2.0 * np.pi))


class _ParticleSetFields(NamedTuple):
    poses: np.ndarray
    log_weights: np.ndarray


class ParticleSet(_ParticleSetFields):
    """A weighted particle set; unpacks as ``poses, log_weights = ps``.

    ``ParticleSet(poses, log_weights)`` checks its fields (finite ``poses (M,
    d)``, ``log_weights (M,)`` without NaN or ``+inf`` and not all ``-inf``)
    and stores float64 arrays; the filter steps bundle their already-checked
    results without the check.

    Attributes
    ----------
    poses : ndarray, shape (M, d)
        The particles (``d = 3`` for poses ``[x, y, theta]``).
    log_weights : ndarray, shape (M,)
        Normalised log-weights (``logsumexp(log_weights) == 0``).
    """

    __slots__ = ()

    def __new__(cls, poses, log_weights):
        poses = as_array(poses, "poses", ndim=2)
        log_weights = as_log_weights(log_weights, "log_weights", poses.shape[0], ref="poses")
        return tuple.__new__(cls, (poses, log_weights))


def _particle_set(poses, log_weights):
    """The unchecked constructor of the cores."""
    return tuple.__new__(ParticleSet, (poses, log_weights))


class PFStepInfo(NamedTuple):
    """Diagnostics of one particle-filter step.

    Attributes
    ----------
    ess : float
        Effective sample size of the weights *before* any resampling.
    resampled : bool
        Whether the step resampled.
    """

    ess: float
    resampled: bool


# --------------------------------------------------------------------------- weights
def normalize_log_weights(log_w, *, log=False):
    """Normalise log-weights without overflow.

    Parameters
    ----------
    log_w : ndarray, shape (M,)
        Unnormalised log-weights; ``-inf`` (weight zero) is allowed for some
        but not all entries.
    log : bool, keyword-only
        Return the normalised log-weights ``log_w - logsumexp(log_w)`` instead.

    Returns
    -------
    ndarray, shape (M,)
        ``w = exp(log_w - logsumexp(log_w))``: non-negative, summing to 1
        (or their logarithms when `log`).

    Raises
    ------
    ValueError
        If `log_w` is empty, holds NaN or ``+inf``, or every entry is ``-inf``
        (every particle has weight zero, so there is nothing to normalise).

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 4.3 line 5 (importance weights) and
    the normaliser ``eta`` of Table 4.4; ``logsumexp`` keeps it in log space.
    """
    lw = as_log_weights(log_w, "log_w")
    out = _normalized(lw)
    return out if log else np.exp(out)


def _normalized(lw):
    """``log_w - logsumexp(log_w)``, shifted by the maximum first so that large
    magnitudes (1e4) lose no more precision than the input holds."""
    shifted = lw - lw.max()
    # log w = log_w - log sum exp(log_w)  (normalisation of Table 4.3's weights); after the shift the
    # largest term is exp(0) = 1, so the sum lies in [1, M] and plain numpy cannot overflow
    return shifted - np.log(np.exp(shifted).sum())


def _weighted_pose_mean(poses, w):
    """Weighted mean pose of particles ``poses (M, 3)`` with normalised weights ``w (M,)`` (unchecked).

    The position is the weighted mean, the heading the weighted circular mean
    ``atan2(sum w sin theta, sum w cos theta)``, wrapped to ``[-pi, pi)``: the
    one summary of a particle set that every filter reports.
    """
    mean = np.empty(3)
    mean[:2] = w @ poses[:, :2]
    mean[2] = _circular_mean(poses[:, 2], w)  # atan2(sum w sin theta, sum w cos theta)
    return mean


def effective_sample_size(w):
    """Effective sample size of importance weights.

    Parameters
    ----------
    w : ndarray, shape (M,)
        Non-negative weights, normalised or not (not all zero).

    Returns
    -------
    float
        ``(sum w)^2 / sum(w^2)``: ``M`` for equal weights, 1 when a single
        particle carries all the weight.

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 4.3.4 (variance reduction: resample only
    when the weights' variance is high); Kong, Liu & Wong (1994).
    """
    return _ess(as_weights(w, "w", normalize=False))


def _ess(w):
    """Unchecked core of :func:`effective_sample_size` (the filters' per-step hot path)."""
    s = w / w.max()  # scale-free, so huge or tiny weights neither overflow nor underflow
    # ESS = (sum w)^2 / sum w^2
    return float(s.sum() ** 2 / np.sum(s * s))


# --------------------------------------------------------------------------- resamplers
def _indices_from_counts(c, positions, k, x, n):
    """Resampled indices ``searchsorted(c, pos, "left")`` (clipped), in O(M).

    For sorted positions ``pos`` the index of ``pos[m]`` is the first ``i``
    with ``c[i] >= pos[m]``, so particle ``i`` receives ``k[i] - k[i-1]``
    positions, ``k[i] = #{m : pos[m] <= c[i]}``. The caller computes ``k`` in
    closed form from ``x``, a real number for which the count is exact unless
    ``x`` lies within round-off of an integer; those few entries are recounted
    against the positions themselves (``positions()`` builds them only then),
    so the result is exact in floating point. There are `n` positions.
    """
    M = c.size
    frac = x - np.floor(x)
    near = (frac < 1e-7) | (frac > 1.0 - 1e-7)
    if near.any():
        k[near] = np.searchsorted(positions(), c[near], side="right")  # exact count of pos <= c
    np.clip(k, 0, n, out=k)
    k[-1] = n  # positions beyond cumsum(w)[-1] (round-off) go to the last particle
    return np.repeat(np.arange(M), np.diff(k, prepend=0))


def low_variance_resample(w, *, rng):
    """Low-variance (systematic) resampling.

    Parameters
    ----------
    w : ndarray, shape (M,)
        Non-negative weights, normalised or not (not all zero).
    rng : numpy.random.Generator, keyword-only
        Source of the single draw ``r = rng.uniform(0.0, 1.0 / M)``.

    Returns
    -------
    ndarray of int, shape (M,)
        Indices of the drawn particles, in increasing order: index ``m`` is the
        first ``i`` with ``cumsum(w)[i] >= r + m / M`` (``w`` normalised),
        clipped to ``M - 1``. Particle ``i`` is drawn ``floor(M w_i)`` or
        ``ceil(M w_i)`` times.

    Notes
    -----
    Computed in O(M) without a loop over particles: the number of positions
    ``r + m / M`` at or below each ``c_i = cumsum(w)[i]`` is
    ``floor((c_i - r) M) + 1``; the rare ``c_i`` within round-off of a position
    are recounted against the positions themselves, so the result equals
    Table 4.4's loop bit for bit.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 4.4.
    """
    w = as_weights(w, "w")
    check_rng(rng)
    r = rng.uniform(0.0, 1.0 / w.size)  # r = rand(0; M^-1)  (Table 4.4 line 3)
    return _low_variance_indices(w, r, w.size)


def _low_variance_indices(w, r, n):
    """Table 4.4 for normalised weights `w` and the offset ``r`` in ``[0, 1/n)``: `n` indices (``n = M`` in Table 4.4)."""
    c = np.cumsum(w)  # c = w^[1] + ... + w^[i]  (Table 4.4 lines 4, 10)

    def positions():
        return r + np.arange(n) / n  # U = r + (m - 1) n^-1  (Table 4.4 line 7, n draws)

    # i = first index with c_i >= U  (Table 4.4 lines 8-11): the pointers r + m/n <= c_i
    # number floor((c_i - r) n) + 1; particle i receives the difference of successive counts
    x = (c - r) * n
    return _indices_from_counts(c, positions, np.floor(x).astype(np.intp) + 1, x, n)


def systematic_resample(w, *, rng):
    """Systematic resampling: the same as :func:`low_variance_resample`.

    Parameters
    ----------
    w : ndarray, shape (M,)
        Non-negative weights, normalised or not.
    rng : numpy.random.Generator, keyword-only
        Source of the single draw ``rng.uniform(0.0, 1.0 / M)``.

    Returns
    -------
    ndarray of int, shape (M,)
        Indices of the drawn particles (see :func:`low_variance_resample`).

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 4.4.
    """
    return low_variance_resample(w, rng=rng)


def stratified_resample(w, *, rng):
    """Stratified resampling: one uniform draw in each stratum ``[m/M, (m+1)/M)``.

    Parameters
    ----------
    w : ndarray, shape (M,)
        Non-negative weights, normalised or not (not all zero).
    rng : numpy.random.Generator, keyword-only
        Source of the draws ``rng.uniform(size=M)``.

    Returns
    -------
    ndarray of int, shape (M,)
        Index ``m`` is the first ``i`` with ``cumsum(w)[i] >= (m + U_m) / M``,
        clipped to ``M - 1``; increasing order. O(M).

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 4.3.4 (stratified sampling); Douc,
    Cappe & Moulines (2005).
    """
    w = as_weights(w, "w")
    check_rng(rng)
    M = w.size
    c = np.cumsum(w)
    pos = (np.arange(M) + rng.uniform(size=M)) / M  # one position per stratum
    # every stratum below f = floor(c M) lies at or below c; stratum f may hold one more
    x = c * M
    f = np.floor(x).astype(np.intp)
    k = f + ((f < M) & (pos[np.minimum(f, M - 1)] <= c))
    return _indices_from_counts(c, lambda: pos, k, x, M)


def multinomial_resample(w, *, rng):
    """Multinomial resampling: ``M`` independent draws from the weights.

    Parameters
    ----------
    w : ndarray, shape (M,)
        Non-negative weights, normalised or not (not all zero).
    rng : numpy.random.Generator, keyword-only
        Source of the draws ``rng.uniform(size=M)``.

    Returns
    -------
    ndarray of int, shape (M,)
        Index ``m`` is the first ``i`` with ``cumsum(w)[i] >= U_m``, clipped to
        ``M - 1`` (inverse-CDF sampling); the order follows the draws. Each
        lookup is a binary search, so the cost is O(M log M).

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 4.3.2 (drawing with replacement,
    Table 4.3 line 8); Douc, Cappe & Moulines (2005).
    """
    w = as_weights(w, "w")
    check_rng(rng)
    M = w.size
    c = np.cumsum(w)
    idx = np.searchsorted(c, rng.uniform(size=M), side="left")  # draw i with probability w_i
    return np.minimum(idx, M - 1)


def residual_resample(w, *, rng):
    """Residual resampling: ``floor(M w_i)`` copies, the rest drawn multinomially.

    Parameters
    ----------
    w : ndarray, shape (M,)
        Non-negative weights, normalised or not (not all zero).
    rng : numpy.random.Generator, keyword-only
        Source of the draws ``rng.uniform(size=R)``, ``R = M - sum floor(M w)``.

    Returns
    -------
    ndarray of int, shape (M,)
        The deterministic copies in increasing order, then ``R`` indices drawn
        from the residual weights ``M w_i - floor(M w_i)``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 4.3.4 (variance reduction); Douc, Cappe
    & Moulines (2005).
    """
    w = as_weights(w, "w")
    check_rng(rng)
    M = w.size
    mw = M * w
    copies = np.floor(mw).astype(np.intp)  # deterministic part
    surplus = int(copies.sum()) - M
    if surplus > 0:  # round-off made sum(M w) exceed M: trim the largest
        copies[np.argsort(-copies, kind="stable")[:surplus]] -= 1
    fixed = np.repeat(np.arange(M), copies)
    R = M - fixed.size
    if R == 0:
        return fixed
    resid = np.maximum(mw - copies, 0.0)
    c = np.cumsum(resid)
    c = c / c[-1]
    extra = np.minimum(np.searchsorted(c, rng.uniform(size=R), side="left"), M - 1)
    return np.concatenate([fixed, extra])


#: Resamplers by name, for the ``resample`` option of the filter steps.
RESAMPLERS = {
    "systematic": systematic_resample,
    "low_variance": low_variance_resample,
    "stratified": stratified_resample,
    "multinomial": multinomial_resample,
    "residual": residual_resample,
}


# --------------------------------------------------------------------------- measurement likelihood
def _log_landmark_likelihood(poses, z, m, Q):
    """``sum_k log N(wrap(z_k - h(x, m_k)); 0, Q)`` per particle; ``z, m (K, 2)``.

    ``h`` is the range-bearing model of
    :func:`~slamlib.sensors.landmark_measurement` (Eq. 6.40), evaluated here
    without its Jacobians, which the likelihood does not need (the tests check
    both agree). The loop runs over the ``K`` measurements, each step a
    vectorised operation over all particles (contiguous columns stay in cache).
    """
    Qi = np.linalg.inv(Q)
    x, y, th = (np.ascontiguousarray(poses[..., i]) for i in range(3))
    quad = np.zeros(x.shape)
    for (zr, zb), (mx, my) in zip(z, m):
        dx = mx - x
        dy = my - y
        # nu = z - z_hat, z_hat = [sqrt(q), atan2(dy, dx) - theta]  (Eq. 6.40), bearing wrapped
        nr = zr - np.sqrt(dx * dx + dy * dy)
        nb = wrap_angle((zb + th) - np.arctan2(dy, dx))
        quad += Qi[0, 0] * nr * nr + (2.0 * Qi[0, 1]) * nr * nb + Qi[1, 1] * nb * nb
    # log N(nu; 0, Q) = -(log det(2 pi Q) + nu^T Q^-1 nu) / 2, summed over k  (Eq. 3.1 / Table 6.4 line 9)
    log_norm = _LOG_2PI + 0.5 * np.log(np.linalg.det(Q))
    return -0.5 * quad - z.shape[0] * log_norm


def landmark_likelihood(particles, z, m, Q, *, log=False):
    """Likelihood of one range-bearing measurement for every particle.

    Parameters
    ----------
    particles : ndarray, shape (M, 3)
        Poses ``[x, y, theta]`` (any leading axes).
    z : ndarray, shape (2,)
        Measurement ``[r, phi]``.
    m : ndarray, shape (2,)
        Position of the measured landmark.
    Q : ndarray, shape (2, 2)
        Measurement-noise covariance, positive definite.
    log : bool, keyword-only
        Return the log-density (finite however unlikely the measurement).

    Returns
    -------
    ndarray, shape (M,)
        The normalised density ``N(wrap(z - z_hat_k); 0, Q)`` for each
        particle ``k``, ``z_hat_k = h(particles[k], m)``; the bearing
        difference is wrapped to ``[-pi, pi)``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 6.4 (landmark model with known
    correspondence, with a joint Gaussian of covariance ``Q``), Eq. 6.40.
    """
    particles = as_poses(particles, "particles", batched=True)
    z = as_array(z, "z", (2,))
    m = as_array(m, "m", (2,))
    Q = as_covariance(Q, "Q", 2, definite=True)
    ll = _log_landmark_likelihood(particles, z[None], m[None], Q)
    return ll if log else np.exp(ll)


# --------------------------------------------------------------------------- the filter
def _resampler(resample):
    if resample is None or callable(resample):
        return resample
    if isinstance(resample, str) and resample in RESAMPLERS:
        return RESAMPLERS[resample]
    raise ValueError(f"resample must be one of {sorted(RESAMPLERS)}, a callable (w, *, rng) -> indices, or None; got {resample!r}")


def _weigh_and_resample(particles, log_w, rng, resample, ess_threshold, weigh=None):
    if weigh is None:
        log_w = _normalized(log_w)
        w = np.exp(log_w)
        ess = float(np.sum(w) ** 2 / np.sum(w * w))  # (sum w)^2 / sum w^2
    else:  # the caller's normalize_log_weights and effective_sample_size (see _weigher)
        log_w, w, ess = weigh(log_w)
    if resample is not None and (ess_threshold >= 1.0 or ess < ess_threshold * w.size):
        # draw M particles with probability w  (Table 4.3 lines 8-11)
        idx = as_indices(resample(w, rng=rng), "the indices resample returned", w.size, (w.size,))
        return _particle_set(particles[idx], np.full(w.size, -np.log(w.size))), PFStepInfo(ess, True)
    return _particle_set(particles, log_w), PFStepInfo(ess, False)


def _weigher(normalize_log_weights, effective_sample_size):
    """``weigh(log_w) -> (log_w, w, ess)`` of :func:`_weigh_and_resample` from a caller's functions (or None).

    Either function may be None (the library's own computation of that part).
    The caller's functions get copies; their results are checked.
    """
    if normalize_log_weights is None and effective_sample_size is None:
        return None

    def weigh(log_w):
        if normalize_log_weights is None:
            log_w = _normalized(log_w)
            w = np.exp(log_w)
        else:
            w = as_probabilities(normalize_log_weights(log_w.copy()), "normalize_log_weights(...)", log_w.shape,
                                 sums_to_one=True)
            with np.errstate(divide="ignore"):
                log_w = np.log(w)  # -inf: a weight of zero
        if effective_sample_size is None:
            ess = float(np.sum(w) ** 2 / np.sum(w * w))  # (sum w)^2 / sum w^2
        else:
            ess = as_scalar(effective_sample_size(w.copy()), "effective_sample_size(...)", nonnegative=True)
        return log_w, w, ess

    return weigh


def _hooked_log_likelihood(landmark_likelihood, poses, z, m, Q):
    """``sum_k log p_k`` of a caller's ``landmark_likelihood(particles, z_k, m_k, Q) -> p_k (M,)``, one call per measurement."""
    total = np.zeros(poses.shape[0])
    for zk, mk in zip(z, m):
        p = as_returned(landmark_likelihood(poses.copy(), zk.copy(), mk.copy(), Q.copy()), "landmark_likelihood",
                        (poses.shape[0],), nonnegative=(0,))
        with np.errstate(divide="ignore"):
            total += np.log(p)  # -inf: likelihood zero
    return total


def _step_options(rng, resample, ess_threshold):
    check_rng(rng)
    resample = _resampler(resample)
    ess_threshold = as_scalar(ess_threshold, "ess_threshold", nonnegative=True)
    if ess_threshold > 1:
        raise ValueError(f"ess_threshold must be in [0, 1] (a fraction of M), got {ess_threshold}")
    return resample, ess_threshold


def bootstrap_filter_step(particles, log_w, propagate, log_likelihood, *, rng, resample="systematic", ess_threshold=0.5):
    """One step of the generic (bootstrap) particle filter.

    Parameters
    ----------
    particles : ndarray, shape (M, d)
        Particles of the belief at ``t-1``.
    log_w : ndarray, shape (M,)
        Their log-weights (normalised or not).
    propagate : callable
        ``propagate(particles, rng) -> (M, d)``: a sample of the motion model
        ``p(x_t | u_t, x_{t-1})`` for every particle.
    log_likelihood : callable
        ``log_likelihood(particles) -> (M,)``: ``log p(z_t | x_t)`` for the
        propagated particles.
    rng : numpy.random.Generator, keyword-only
        Passed to `propagate` and to the resampler.
    resample : str, callable or None, keyword-only
        ``"systematic"`` (default), ``"low_variance"``, ``"stratified"``,
        ``"multinomial"``, ``"residual"``, a callable ``(w, *, rng) ->
        indices``, or ``None`` (never resample).
    ess_threshold : float, keyword-only
        Resample when the effective sample size falls below
        ``ess_threshold * M``; ``1`` resamples at every step, ``0`` never.

    Returns
    -------
    particles : ParticleSet
        ``(poses (M, d), log_weights (M,))``, log-weights normalised
        (``-log M`` each after resampling).
    info : PFStepInfo
        Effective sample size before resampling, and whether it resampled.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 4.3 (with resampling on low effective
    sample size, Sec. 4.3.4).
    """
    particles = as_array(particles, "particles", ndim=2)
    lw = as_log_weights(log_w, "log_w", particles.shape[0], ref="particles")
    resample, ess_threshold = _step_options(rng, resample, ess_threshold)
    if not callable(propagate):
        raise TypeError("propagate must be a callable (particles, rng) -> particles")
    if not callable(log_likelihood):
        raise TypeError("log_likelihood must be a callable (particles) -> log-likelihoods")
    # sample x_t^[m] ~ p(x_t | u_t, x_{t-1}^[m])  (Table 4.3 line 4)
    moved = np.asarray(propagate(particles, rng), dtype=float)
    if moved.shape != particles.shape:
        raise ValueError(f"propagate must return shape {particles.shape}, got {moved.shape}")
    # w_t^[m] = p(z_t | x_t^[m]), times the weight carried over  (Table 4.3 line 5)
    ll = np.asarray(log_likelihood(moved), dtype=float)
    if ll.shape != lw.shape:
        raise ValueError(f"log_likelihood must return shape {lw.shape}, got {ll.shape}")
    new_lw = lw + ll
    check_log_weights(new_lw, "log_w + log_likelihood")
    return _weigh_and_resample(moved, new_lw, rng, resample, ess_threshold)


def particle_filter_step(particles, log_w, u, z, m, dt, M, Q, *, rng, resample="systematic", ess_threshold=0.5,
                         landmark_likelihood=None, normalize_log_weights=None, effective_sample_size=None):
    """One particle-filter step for poses with landmark measurements.

    Parameters
    ----------
    particles : ndarray, shape (n, 3)
        Poses ``[x, y, theta]`` of the ``n`` particles at ``t-1``.
    log_w : ndarray, shape (n,)
        Their log-weights (normalised or not).
    u : ndarray, shape (2,)
        Commanded control ``[v, omega]``.
    z : ndarray, shape (K, 2)
        The step's measurements ``[r, phi]`` (``K`` may be 0).
    m : ndarray, shape (K, 2)
        Position of the landmark of each measurement (known correspondences,
        e.g. ``landmarks[ids]``).
    dt : float
        Duration of the control, non-negative seconds.
    M : ndarray, shape (2, 2)
        Control-noise covariance: each particle moves with its own
        ``u + N(0, M)`` along the exact arc.
    Q : ndarray, shape (2, 2)
        Measurement-noise covariance, positive definite.
    rng : numpy.random.Generator, keyword-only
        Draws ``standard_normal((n, 2))`` for the motion, then the resampler's
        draws.
    resample : str, callable or None, keyword-only
        As in :func:`bootstrap_filter_step`; a callable ``resample(w, *, rng)
        -> indices`` is called where the step resamples (e.g.
        :func:`low_variance_resample`, or a student's version of it, as the
        autograder plugs it in).
    ess_threshold : float, keyword-only
        As in :func:`bootstrap_filter_step`.
    landmark_likelihood : callable, optional, keyword-only
        ``landmark_likelihood(particles, z_k, m_k, Q) -> p (n,)`` in place of
        the step's own measurement likelihood, called once per measurement
        on the moved particles (as :func:`landmark_likelihood`); the weights
        are multiplied by ``p`` (in log space, ``p = 0`` giving ``-inf``).
        ``None`` (default): the library's core.
    normalize_log_weights : callable, optional, keyword-only
        ``normalize_log_weights(log_w) -> w (n,)`` in place of the
        normalisation of the weights, as :func:`normalize_log_weights`;
        ``log_w`` may hold ``-inf`` (weight zero) when `landmark_likelihood`
        returned zeros.
    effective_sample_size : callable, optional, keyword-only
        ``effective_sample_size(w) -> float`` in place of the step's own
        effective sample size of the normalised weights, as
        :func:`effective_sample_size`.

    Returns
    -------
    particles : ParticleSet
        ``(poses (n, 3), log_weights (n,))``, headings wrapped, log-weights
        normalised.
    info : PFStepInfo
        Effective sample size before resampling, and whether it resampled.

    Notes
    -----
    The functions given for `landmark_likelihood`, `normalize_log_weights`
    and `effective_sample_size` are called with the homework contract's
    arguments (copies of the step's arrays), and their results checked
    (shape; non-negative likelihoods; weights that sum to 1; a non-negative
    effective sample size): a bad one raises ``ValueError`` naming the
    function. Exceptions they raise pass through unchanged.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 4.3 with the velocity motion model
    (Sec. 5.3, sampled as in Table 5.3, control noise as in Table 7.2) and the
    landmark measurement model (Table 6.4).
    """
    particles = as_poses(particles, "particles")
    n = particles.shape[0]
    lw = as_log_weights(log_w, "log_w", n, ref="particles")
    u = as_array(u, "u", (2,))
    z = as_rows(z, "z", 2)
    m = as_rows(m, "m", 2)
    check_rows((z, "z"), (m, "m"))  # one landmark per measurement
    dt = as_scalar(dt, "dt", nonnegative=True)
    M = as_covariance(M, "M", 2)
    Q = as_covariance(Q, "Q", 2, definite=True)
    resample, ess_threshold = _step_options(rng, resample, ess_threshold)
    _check_pf_functions(landmark_likelihood, normalize_log_weights, effective_sample_size)
    return _pf_step(particles, lw, u, z, m, dt, _control_sqrt(M), Q, rng, resample, ess_threshold, landmark_likelihood,
                    _weigher(normalize_log_weights, effective_sample_size))


def _check_pf_functions(landmark_likelihood, normalize_log_weights, effective_sample_size):
    check_callable(landmark_likelihood, "landmark_likelihood", "(particles, z, m, Q)")
    check_callable(normalize_log_weights, "normalize_log_weights", "(log_w)")
    check_callable(effective_sample_size, "effective_sample_size", "(w)")


def _pf_step(particles, lw, u, z, m, dt, L, Q, rng, resample, ess_threshold, likelihood=None, weigh=None):
    """:func:`particle_filter_step` on checked inputs, ``L`` a square root of ``M``; ``likelihood``: a caller's
    ``landmark_likelihood`` or None, ``weigh``: see :func:`_weigher`."""
    n = particles.shape[0]
    # u_hat^[m] = u + N(0, M); x_t^[m] = g(u_hat^[m], x_{t-1}^[m])  (Table 4.3 line 4, Table 5.3)
    eps = rng.standard_normal((n, 2))
    u_hat = u + eps[:, :1] * L[:, 0] + eps[:, 1:] * L[:, 1]  # u + L eps per particle, eps ~ N(0, I)
    moved = _arc_pose(particles, u_hat, dt)
    if z.shape[0]:
        # w^[m] = prod_k p(z_k | x_t^[m], m_k), summed in log space  (Table 4.3 line 5, Table 6.4)
        if likelihood is None:
            new_lw = lw + _log_landmark_likelihood(moved, z, m, Q)
        else:
            new_lw = lw + _hooked_log_likelihood(likelihood, moved, z, m, Q)
            check_log_weights(new_lw, "log_w + log landmark_likelihood(...)")
    else:
        new_lw = lw
    return _weigh_and_resample(moved, new_lw, rng, resample, ess_threshold, weigh)


class PFRunResult(NamedTuple):
    """What :func:`run_particle_filter` returns.

    Attributes
    ----------
    x_est : ndarray, shape (T+1, 3)
        Weighted mean pose (weighted circular mean of the headings):
        ``x_est[0]`` of the initial particles, ``x_est[t+1]`` of the
        particles after step ``t`` (after its resampling, if any).
    ess : ndarray, shape (T,)
        Effective sample size at each step, before resampling.
    resampled : ndarray of bool, shape (T,)
        Whether each step resampled.
    particles : ParticleSet
        The particles and their normalised log-weights after the last step.
    """

    x_est: np.ndarray
    ess: np.ndarray
    resampled: np.ndarray
    particles: ParticleSet


def run_particle_filter(run, particles, *, rng, log_w=None, M=None, Q=None, resample="systematic", ess_threshold=0.5,
                        landmark_likelihood=None, normalize_log_weights=None, effective_sample_size=None,
                        on_step=None):
    """Particle-filter localization over a whole landmark run, known correspondences.

    Each step is :func:`particle_filter_step` with the run's control, the
    step's measurements and the positions of their landmarks.

    Parameters
    ----------
    run : LandmarkRun
        From :func:`~slamlib.sim.simulate_landmark_run`; uses ``landmarks``,
        ``dt``, the commanded controls ``u (T, 2)``, the measurements ``z``
        and their landmark indices ``ids`` and, by default, ``M`` and ``Q``.
    particles : ndarray, shape (n, 3)
        The initial particles (e.g. samples around ``run.x0``), ``n >= 1``.
    rng : numpy.random.Generator, keyword-only
        Source of the motion noise and the resampler's draws.
    log_w : ndarray, shape (n,), optional, keyword-only
        Initial log-weights (normalised or not); equal weights by default.
    M, Q : ndarray, shape (2, 2), optional, keyword-only
        Control- and measurement-noise covariances assumed by the filter;
        default the run's.
    resample : str, callable or None, keyword-only
        The resampler, as in :func:`particle_filter_step`: a callable
        ``resample(w, *, rng) -> indices`` (such as a student's
        :func:`low_variance_resample`) is called wherever a step resamples.
    ess_threshold : float, keyword-only
        Resample when the effective sample size falls below
        ``ess_threshold * n``, as in :func:`particle_filter_step`.
    landmark_likelihood, normalize_log_weights, effective_sample_size : callable, optional, keyword-only
        Functions of the homework contract's signatures in place of the
        filter's own measurement likelihood, weight normalisation and
        effective sample size (:func:`landmark_likelihood`,
        :func:`normalize_log_weights`, :func:`effective_sample_size`, or a
        student's versions, as the autograder plugs them in); see
        :func:`particle_filter_step`. ``None`` (default): the library's cores.
    on_step : callable, optional, keyword-only
        ``on_step(t)`` is called at the start of step ``t``, e.g. for progress
        reports, or so that the functions above know which step they serve.

    Returns
    -------
    PFRunResult
        ``(x_est (T+1, 3), ess (T,), resampled (T,), particles)``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 4.3 (with resampling on low effective
    sample size, Sec. 4.3.4), Table 5.3, Table 6.4.
    """
    for attr in ("landmarks", "dt", "u", "z", "ids", "M", "Q"):
        if not hasattr(run, attr):
            raise TypeError(f"run must be a LandmarkRun (missing attribute {attr!r})")
    landmarks = as_array(run.landmarks, "run.landmarks", (None, 2))
    u = as_array(run.u, "run.u", (None, 2))
    dt = as_scalar(run.dt, "run.dt", nonnegative=True)
    poses = as_poses(particles, "particles", allow_empty=False)
    n = poses.shape[0]
    lw = np.full(n, -np.log(n)) if log_w is None else as_log_weights(log_w, "log_w", n, ref="particles")
    M = as_covariance(run.M if M is None else M, "M", 2)
    Q = as_covariance(run.Q if Q is None else Q, "Q", 2, definite=True)
    resample, ess_threshold = _step_options(rng, resample, ess_threshold)
    _check_pf_functions(landmark_likelihood, normalize_log_weights, effective_sample_size)
    check_callable(on_step, "on_step", "(t)")
    T = u.shape[0]
    if len(run.z) != T or len(run.ids) != T:
        raise ValueError(f"run.z and run.ids must hold one entry per control ({T}), got {len(run.z)} and {len(run.ids)}")
    L = _control_sqrt(M)
    weigh = _weigher(normalize_log_weights, effective_sample_size)
    x_est = np.empty((T + 1, 3))
    ess = np.empty(T)
    resampled = np.zeros(T, dtype=bool)
    x_est[0] = _weighted_pose_mean(poses, np.exp(_normalized(lw)))
    for t in range(T):
        if on_step is not None:
            on_step(t)
        z = as_rows(run.z[t], f"run.z[{t}]", 2)
        ids = as_indices(run.ids[t], f"run.ids[{t}]", landmarks.shape[0], (z.shape[0],), ref=f"run.z[{t}]")
        (poses, lw), (ess[t], resampled[t]) = _pf_step(poses, lw, u[t], z, landmarks[ids], dt, L, Q, rng, resample,
                                                       ess_threshold, landmark_likelihood, weigh)
        x_est[t + 1] = _weighted_pose_mean(poses, np.exp(lw))
    return PFRunResult(x_est, ess, resampled, _particle_set(poses, lw))


def particle_gaussian(particles, log_weights=None, *, angles=()):
    """Weighted mean and covariance of a particle set.

    Parameters
    ----------
    particles : ndarray, shape (M, d)
        The particles.
    log_weights : ndarray, shape (M,), optional
        Log-weights (normalised or not); equal weights if omitted.
    angles : sequence of int, keyword-only
        Columns holding angles (e.g. ``(2,)`` for poses): their mean is the
        weighted circular mean and their deviations are wrapped.

    Returns
    -------
    Gaussian
        ``(mean (d,), cov (d, d))`` with ``cov = sum_m w_m e_m e_m^T``,
        ``e_m = particles[m] - mean`` (angles wrapped).

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 4.3.1 (particles as a sample of the
    belief; moments from the weighted sample).
    """
    p = as_array(particles, "particles", ndim=2)
    n, d = p.shape
    if n == 0:
        raise ValueError("particles must hold at least one particle")
    if log_weights is None:
        w = np.full(n, 1.0 / n)
    else:
        w = np.exp(_normalized(as_log_weights(log_weights, "log_weights", n, ref="particles")))
    cols = []
    for a in angles:
        if isinstance(a, bool) or not isinstance(a, (int, np.integer)) or not 0 <= a < d:
            raise ValueError(f"angles must hold column indices in [0, {d}), got {a!r}")
        cols.append(int(a))
    return _gaussian(*_particle_moments(p, w, cols))


def _particle_moments(p, w, cols):
    """Unchecked core of :func:`particle_gaussian`: ``(mean, cov)`` of particles ``p`` with normalised weights
    ``w``, the columns `cols` angles (the filters' per-step hot path)."""
    mean = w @ p
    for a in cols:
        mean[a] = _circular_mean(p[:, a], w)  # atan2(sum w sin a, sum w cos a)
    e = p - mean
    for a in cols:
        e[:, a] = _wrap(e[:, a])
    cov = (e * w[:, None]).T @ e  # sum_m w_m e_m e_m^T
    return mean, 0.5 * (cov + cov.T)
