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

Besides these, :func:`odometry_moment_problem` checks the mean and variance of
sampled noise against bounds that a correct sampler crosses with probability
below ``1e-12`` per check (a z-bound of 7.13 on the mean, chi-square quantiles of
``1e-12`` on the variance); they make a property test (shape, wrapped headings,
use of ``rng``) pay only for samples with the right distribution, and add
nothing noticeable to the false-failure budget above.
:func:`odometry_independence_problem` bounds the pairwise correlations of the
three noises of a pose in the same way: each of its three bounds is crossed by
a correct sampler with probability exactly ``MOMENT_P = 1e-12`` (the normal
scores it correlates are exactly standard normal and independent, so the sample
correlation follows Student's t law), again nothing noticeable in the budget.

A grading is deterministic given its seed.
"""

from __future__ import annotations

import numpy as np
from scipy import special, stats

__all__ = ["P_THRESHOLD", "MAX_STAT_TESTS", "MOMENT_P", "wrapped_normal_cdf", "ks_pvalue", "odometry_noise",
           "odometry_ks_pvalues", "odometry_moment_problem", "odometry_normal_scores", "correlation_bound",
           "odometry_correlations", "odometry_independence_problem", "odometry_repeated_noise_problem",
           "REPEATED_NOISE_TOL", "repeated_noise_false_alarm", "offspring_chi2_pvalue"]

#: p-value below which a statistical test fails.
P_THRESHOLD = 1e-5
#: Upper bound on the statistical tests one submission meets (summed over all exercises' tests).
MAX_STAT_TESTS = 10
#: Two-sided false-failure probability of each bound of :func:`odometry_moment_problem`.
MOMENT_P = 1e-12
#: How close two poses' three noise scores must come for :func:`odometry_repeated_noise_problem` to call them one draw.
REPEATED_NOISE_TOL = 1e-7


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


def odometry_moment_problem(x, x_next, u, alpha):
    """Why the noise recovered from odometry samples has the wrong mean or variance, or ``None``.

    For each of ``rot1``, ``trans`` and ``rot2``, with ``n`` samples and the
    contract's variance ``v``: the sample mean must satisfy
    ``|mean| <= z sqrt(v / n)`` and ``(n - 1) s^2 / v`` must lie between the
    ``MOMENT_P / 2`` and ``1 - MOMENT_P / 2`` quantiles of chi-square with
    ``n - 1`` degrees of freedom (``z`` is the normal quantile of ``MOMENT_P / 2``).
    A zero variance requires zero noise (to 1e-9).
    """
    n = x.shape[0]
    z = float(stats.norm.isf(MOMENT_P / 2))
    lo = float(stats.chi2.ppf(MOMENT_P / 2, n - 1)) / (n - 1)
    hi = float(stats.chi2.isf(MOMENT_P / 2, n - 1)) / (n - 1)
    for name, d, v in zip(("rot1", "trans", "rot2"), odometry_noise(x, x_next, u), odometry_variances(u, alpha)):
        if not np.all(np.isfinite(d)):
            return f"the {name} noise recovered from your samples is not finite"
        if v <= 0:
            if np.max(np.abs(d)) > 1e-9:
                return f"the {name} noise must be zero (its variance is 0), got up to {np.max(np.abs(d)):.3g}"
            continue
        mean, var = float(np.mean(d)), float(np.var(d, ddof=1))
        if abs(mean) > z * np.sqrt(v / n) or not lo <= var / v <= hi:
            return (f"the {name} noise recovered from your samples has mean {mean:.4g} and variance {var:.4g}; "
                    f"expected mean 0 and variance {v:.4g} (Table 5.6: the variance is "
                    f"{'a1 rot1^2 + a2 trans^2' if name != 'trans' else 'a3 trans^2 + a4 (rot1^2 + rot2^2)'})")
    return None


_NOISE_NAMES = ("rot1", "trans", "rot2")


def odometry_normal_scores(x, x_next, u, alpha):
    """The three recovered noises mapped to standard normal scores through their contract distributions.

    Each noise ``d`` with contract CDF ``F`` (a wrapped normal for the rotations, a
    normal for the translation) becomes ``Phi^-1(F(d))``: for a correct sampler the
    scores are exactly standard normal, and the three of a pose are independent
    because Table 5.6 draws the three noises independently. A noise whose variance
    is 0 gives ``None`` (it has no distribution to score).
    """
    out = []
    for d, v, rot in zip(odometry_noise(x, x_next, u), odometry_variances(u, alpha), (True, False, True)):
        if v <= 0:
            out.append(None)
            continue
        s = float(np.sqrt(v))
        q = wrapped_normal_cdf(d, s) if rot else special.ndtr(np.asarray(d, dtype=float) / s)
        out.append(special.ndtri(np.clip(q, 1e-300, 1.0 - 2.0**-53)))
    return out


def correlation_bound(n, p=MOMENT_P):
    """The bound ``r_max`` with ``P(|r| > r_max) = p`` for the sample correlation of ``n`` independent normal pairs.

    Under independence ``t = r sqrt((n - 2) / (1 - r^2))`` follows Student's t with
    ``n - 2`` degrees of freedom, so ``r_max = t_p / sqrt(n - 2 + t_p^2)`` with
    ``t_p`` its ``1 - p / 2`` quantile (``r_max`` is about ``7.14 / sqrt(n)`` for
    ``p = 1e-12`` and large ``n``).
    """
    t = float(stats.t.isf(p / 2, n - 2))
    return t / np.sqrt(n - 2 + t * t)


def odometry_correlations(x, x_next, u, alpha):
    """Pairwise correlations of the normal scores of the noises: ``[(name_a, name_b, r, p_value), ...]``.

    Pairs involving a zero-variance noise are left out. The two-sided p-value is
    exact for a correct sampler (see :func:`correlation_bound`).
    """
    scores = odometry_normal_scores(x, x_next, u, alpha)
    n = x.shape[0]
    out = []
    for i, j in ((0, 1), (0, 2), (1, 2)):
        a, b = scores[i], scores[j]
        if a is None or b is None:
            continue
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))) or np.std(a) == 0 or np.std(b) == 0:
            r = float("nan")
            p = 0.0
        else:
            test = stats.pearsonr(a, b)  # two-sided, exact for independent normal pairs
            r, p = float(test.statistic), float(test.pvalue)
        out.append((_NOISE_NAMES[i], _NOISE_NAMES[j], r, p))
    return out


def odometry_independence_problem(x, x_next, u, alpha):
    """Why the three noises recovered from odometry samples are not independent, or ``None``.

    Each pair's correlation of normal scores (:func:`odometry_correlations`) must
    satisfy ``|r| <= correlation_bound(n)``: a correct sampler crosses each of the
    three bounds with probability ``MOMENT_P``.
    """
    bound = correlation_bound(x.shape[0])
    for a, b, r, _ in odometry_correlations(x, x_next, u, alpha):
        if not abs(r) <= bound:
            return (f"the {a} and {b} noises recovered from your samples are correlated: correlation {r:.3g} "
                    f"(of their normal scores), expected |correlation| <= {bound:.3g} for independent draws "
                    f"(Table 5.6 draws the three noises of a pose independently)")
    return None


def repeated_noise_false_alarm(M, tol=REPEATED_NOISE_TOL):
    """The expected number of pairs among a correct sampler's ``M`` poses whose three normal scores agree within
    ``tol``, or agree with each other's negatives: a bound on :func:`odometry_repeated_noise_problem`'s false alarm.

    Two independent standard normals differ by an ``N(0, 2)`` variable, within ``tol`` with probability
    ``erf(tol / 2)``; a pair of poses matches in all three scores with its cube, in one of two ways (the same or
    the opposite signs), and there are ``M (M - 1) / 2`` pairs. The check compares neighbours of one sort only,
    so it raises fewer alarms (about a third, measured at ``M = 200``, ``tol = 0.02``).
    """
    return float(M * (M - 1) * special.erf(tol / 2.0) ** 3)


def odometry_repeated_noise_problem(x, x_next, u, alpha, tol=REPEATED_NOISE_TOL):
    """Why two poses' noises look drawn once for both (the same three noises, or their negatives), or ``None``.

    The normal scores of the three noises (:func:`odometry_normal_scores`) of a correct sampler are independent
    standard normals for every pose: two of its poses agree within ``tol`` in all three (or in their negatives)
    with probability at most :func:`repeated_noise_false_alarm`, 7e-14 for 20 000 poses and ``tol = 1e-7``. A sampler that reuses a pose's draws for another (``[h, h]``),
    or uses antithetic pairs (``[h, -h]``), makes such pairs exactly. One sort: each row signed so that its first
    score is not negative, then neighbours compared.
    """
    cols = [c for c in odometry_normal_scores(x, x_next, u, alpha) if c is not None]
    if not cols or x.shape[0] < 2:
        return None
    s = np.column_stack(cols)
    if not np.all(np.isfinite(s)):
        return None
    sign = np.where(s[:, 0] < 0, -1.0, 1.0)
    c = s * sign[:, None]
    order = np.lexsort(c.T[::-1])
    close = np.all(np.abs(np.diff(c[order], axis=0)) <= tol, axis=1)
    if not close.any():
        return None
    k = int(np.flatnonzero(close)[0])
    i, j = sorted((int(order[k]), int(order[k + 1])))
    how = "the same noises" if sign[i] == sign[j] else "the same noises with opposite signs"
    return (f"poses {i} and {j} moved with {how} (their three noises agree to {tol:g}): draw new noise for every "
            f"pose, never reuse one pose's draws for another")
