"""Statistical checks of samplers, and their false-failure budget.

A statistical test fails when its p-value falls below :data:`P_THRESHOLD`. For
a correct sampler the p-value is uniform on ``[0, 1]`` (or stochastically
larger, for the conservative chi-square below), so each test fails a correct
submission with probability at most ``P_THRESHOLD = 1e-5`` per grader seed. The
whole course runs at most :data:`MAX_STAT_TESTS` such tests per submission, so by
Bonferroni's inequality a correct submission fails any of them with
probability at most ``MAX_STAT_TESTS * P_THRESHOLD = 1e-4`` -- whatever the
seeds. ``python -m autograder calibrate`` checks the uniformity claim
empirically on the reference implementation over many seeds.

The grader's seeds are fixed, so grading itself is deterministic.
"""

from __future__ import annotations

import numpy as np
from scipy import special, stats

__all__ = ["P_THRESHOLD", "MAX_STAT_TESTS", "wrapped_normal_cdf", "ks_pvalue", "odometry_noise",
           "odometry_ks_pvalues", "offspring_chi2_pvalue"]

#: p-value below which a statistical test fails.
P_THRESHOLD = 1e-5
#: Upper bound on the statistical tests one submission meets (summed over all exercises' tests).
MAX_STAT_TESTS = 10


def _wrap(a):
    out = np.mod(np.asarray(a, dtype=float) + np.pi, 2 * np.pi) - np.pi
    return np.where(out >= np.pi, out - 2 * np.pi, out)


def wrapped_normal_cdf(x, sigma):
    """CDF on ``[-pi, pi)`` of ``wrap(e)``, ``e ~ N(0, sigma^2)``."""
    x = np.asarray(x, dtype=float)
    K = int(np.ceil(6.0 * sigma / (2 * np.pi))) + 1
    total = np.zeros_like(x)
    for k in range(-K, K + 1):
        shift = 2 * np.pi * k
        total += special.ndtr((x + shift) / sigma) - special.ndtr((-np.pi + shift) / sigma)
    return np.clip(total, 0.0, 1.0)


def ks_pvalue(samples, cdf):
    """Two-sided one-sample Kolmogorov-Smirnov p-value."""
    return float(stats.kstest(np.asarray(samples, dtype=float), cdf).pvalue)


def odometry_noise(x, x_next, u):
    """Recover the sampled noises from ``x -> x_next`` under odometry control ``u``.

    Returns ``(d_rot1, d_trans, d_rot2)``: the wrapped differences between the
    noisy increments that ``x_next`` implies and the commanded ones. Exact as
    long as the noisy translation stays positive (the tests choose noise levels
    for which a negative one has probability below 1e-10 per sample).
    """
    dx = x_next[:, 0] - x[:, 0]
    dy = x_next[:, 1] - x[:, 1]
    trans = np.hypot(dx, dy)
    rot1 = _wrap(np.arctan2(dy, dx) - x[:, 2])
    rot2 = _wrap(x_next[:, 2] - x[:, 2] - rot1)
    return _wrap(rot1 - u[0]), trans - u[1], _wrap(rot2 - u[2])


def odometry_variances(u, alpha):
    """The contract's noise variances of ``(rot1, trans, rot2)`` (Table 5.6)."""
    r1, t, r2 = u
    a1, a2, a3, a4 = alpha
    return a1 * r1**2 + a2 * t**2, a3 * t**2 + a4 * (r1**2 + r2**2), a1 * r2**2 + a2 * t**2


def odometry_ks_pvalues(x, x_next, u, alpha):
    """KS p-values of the three recovered noises against their distributions.

    The rotation noises are compared with wrapped normals, the translation noise
    with a normal, all with the contract's variances.
    """
    d1, d2, d3 = odometry_noise(x, x_next, u)
    v1, v2, v3 = odometry_variances(u, alpha)
    s1, s2, s3 = np.sqrt([v1, v2, v3])
    return (ks_pvalue(d1, lambda q: wrapped_normal_cdf(q, s1)),
            ks_pvalue(d2, lambda q: special.ndtr(q / s2)),
            ks_pvalue(d3, lambda q: wrapped_normal_cdf(q, s3)))


def offspring_chi2_pvalue(counts, w, n_draws):
    """Pearson chi-square p-value of summed offspring counts against ``n_draws M w``.

    ``counts[i]`` is how many times particle ``i`` was drawn over ``n_draws``
    resamplings of ``M`` particles. For an unbiased resampler ``E[counts] = n_draws M w``;
    for low-variance resampling the counts vary less than multinomial ones, so the
    chi-square reference distribution (``M - 1`` degrees of freedom, particles with
    ``w > 0``) is conservative.
    """
    w = np.asarray(w, dtype=float)
    w = w / w.sum()
    M = w.size
    expected = n_draws * M * w
    keep = expected > 0
    if np.any(counts[~keep] > 0):
        return 0.0
    chi2 = float(np.sum((counts[keep] - expected[keep]) ** 2 / expected[keep]))
    return float(stats.chi2.sf(chi2, df=int(keep.sum()) - 1))
