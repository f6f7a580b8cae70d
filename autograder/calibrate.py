"""Calibration of the statistical checks on the reference implementation.

The grader's statistical tests (KS tests of the odometry sampler's three noises
in two scenarios and on independent poses; the chi-square test of low-variance
resampling's offspring counts), and the correlation bounds of the odometry
sampler's "three independent noises per pose" test (as p-values: a bound is
crossed when its p-value falls below ``MOMENT_P = 1e-12``), are run here on ``slamlib``'s own samplers over
many grader seeds, exactly as the tests build their inputs. For a correct
sampler each p-value should be uniform on ``[0, 1]`` (the chi-square one is
conservative, i.e. stochastically larger), so:

* the fraction of p-values below a level ``a`` must not exceed ``a`` beyond
  binomial noise (checked at ``a = 0.001, 0.01, 0.05, 0.1``);
* no p-value may fall below :data:`~autograder.stats.P_THRESHOLD` more often than
  ``P_THRESHOLD`` per test -- with ``n`` seeds one expects ``n * 1e-5`` failures.

With per-test false-failure probability at most ``P_THRESHOLD = 1e-5`` and at
most ``MAX_STAT_TESTS = 10`` statistical tests per submission, a correct
submission fails one of them with probability at most ``1e-4`` (Bonferroni),
whatever the grader's seeds.

``python -m autograder calibrate --seeds 2000`` prints the table; the test suite
runs a reduced version.
"""

from __future__ import annotations

import numpy as np
from scipy import stats as sstats

import slamlib as sl

from .exercises.common import random_pose
from .exercises.motion_sensor_models import _INDEPENDENCE_SCENARIO, _KS_SCENARIOS
from .stats import (MAX_STAT_TESTS, MOMENT_P, P_THRESHOLD, odometry_correlations, odometry_ks_pvalues,
                    offspring_chi2_pvalue)

__all__ = ["odometry_pvalues", "independent_poses_pvalues", "independent_noises_pvalues", "offspring_pvalue",
           "calibrate", "summarize", "main"]


def odometry_pvalues(seed, M=20000):
    """The six KS p-values of the "noise distribution" test for one grader seed."""
    rng = np.random.default_rng([seed, 1])
    out = []
    for k, (u, alpha) in enumerate(_KS_SCENARIOS):
        x = np.tile(random_pose(rng), (M, 1))
        samples = sl.sample_motion_model_odometry(x, u, alpha, rng=np.random.default_rng([seed, 2, k]))
        out.extend(odometry_ks_pvalues(x, samples, u, alpha))
    return out


def independent_poses_pvalues(seed, M=20000):
    """The three KS p-values of the "each pose moves with its own noise" test."""
    rng = np.random.default_rng([seed, 3])
    x = np.column_stack([rng.uniform(-5, 5, M), rng.uniform(-5, 5, M), rng.uniform(-np.pi, np.pi, M)])
    u = np.array([-0.6, 0.8, 0.9])
    alpha = np.array([0.03, 0.02, 0.02, 0.005])
    samples = sl.sample_motion_model_odometry(x, u, alpha, rng=np.random.default_rng([seed, 4]))
    return list(odometry_ks_pvalues(x, samples, u, alpha))


def independent_noises_pvalues(seed, M=20000):
    """The three correlation p-values (pairs of noises) of the "three independent noises per pose" test."""
    rng = np.random.default_rng([seed, 7])
    u, alpha = _INDEPENDENCE_SCENARIO
    x = np.tile(random_pose(rng), (M, 1))
    samples = sl.sample_motion_model_odometry(x, u, alpha, rng=np.random.default_rng([seed, 8]))
    return [p for *_, p in odometry_correlations(x, samples, u, alpha)]


def offspring_pvalue(seed, M=20, R=300):
    """The chi-square p-value of the "offspring counts unbiased" test."""
    rng = np.random.default_rng([seed, 5])
    w = rng.dirichlet(np.full(M, 1.0))
    total = np.zeros(M)
    for k in range(R):
        idx = sl.low_variance_resample(w, rng=np.random.default_rng([seed, 6, k]))
        total += np.bincount(idx, minlength=M)
    return offspring_chi2_pvalue(total, w, R)


CHECKS = {
    "odometry KS (2 scenarios x 3 noises)": odometry_pvalues,
    "odometry KS, independent poses (3 noises)": independent_poses_pvalues,
    "odometry noise correlations (3 pairs; bound at MOMENT_P)": independent_noises_pvalues,
    "resampling chi-square (conservative)": lambda s: [offspring_pvalue(s)],
}


def calibrate(n_seeds, first_seed=0):
    """p-values of every statistical check over ``n_seeds`` grader seeds: name -> 1-D array."""
    return {name: np.array([p for s in range(first_seed, first_seed + n_seeds) for p in fn(s)])
            for name, fn in CHECKS.items()}


def summarize(p, levels=(1e-3, 1e-2, 0.05, 0.1)):
    """Empirical false-rejection rates, their binomial upper bounds and a uniformity test."""
    p = np.asarray(p)
    n = p.size
    rows = []
    for a in levels:
        k = int(np.sum(p < a))
        # one-sided 99.9 % binomial upper limit on the count under the null
        limit = int(sstats.binom.ppf(0.999, n, a))
        rows.append({"level": a, "count": k, "rate": k / n, "limit": limit, "ok": k <= limit})
    return {"n": n, "min": float(p.min()), "below_threshold": int(np.sum(p < P_THRESHOLD)),
            "ks_uniform_p": float(sstats.kstest(p, "uniform").pvalue), "levels": rows}


def main(n_seeds=2000, out=None):
    res = calibrate(n_seeds)
    print(f"Statistical checks on the reference implementation, {n_seeds} grader seeds")
    print(f"threshold p < {P_THRESHOLD:g}; at most {MAX_STAT_TESTS} statistical tests per submission -> "
          f"false failure <= {MAX_STAT_TESTS * P_THRESHOLD:g} per submission (Bonferroni); the correlation bounds "
          f"fail at p < {MOMENT_P:g} each\n")
    ok = True
    for name, p in res.items():
        s = summarize(p)
        print(f"{name}: {s['n']} p-values, min {s['min']:.3g}, below threshold {s['below_threshold']}, "
              f"KS test of uniformity p = {s['ks_uniform_p']:.3g}")
        for r in s["levels"]:
            print(f"   P(p < {r['level']:<6g}) = {r['rate']:.4f}  ({r['count']} <= {r['limit']}: "
                  f"{'ok' if r['ok'] else 'TOO MANY'})")
            ok &= r["ok"]
    if out:
        import csv

        with open(out, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["check", "pvalue"])
            for name, p in res.items():
                w.writerows([name, float(v)] for v in p)
    print("\ncalibration " + ("passed" if ok else "FAILED"))
    return 0 if ok else 1
