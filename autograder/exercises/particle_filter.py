"""Exercise 3: particle-filter building blocks (weights, effective sample size, resampling, likelihood)."""

from __future__ import annotations

import numpy as np

import slamlib as sl

from .. import loops
from ..context import Out, RngSeed
from ..spec import Exercise
from ..stats import P_THRESHOLD, offspring_chi2_pvalue
from .common import random_pose, spd

EX = Exercise(
    "particle_filter",
    "Particle filter",
    notebook="03_particle_filter.ipynb",
    functions={
        "normalize_log_weights": "(log_w)",
        "effective_sample_size": "(w)",
        "low_variance_resample": "(w, *, rng)",
        "landmark_likelihood": "(particles, z, m, Q)",
    },
)


# =========================================================================== normalize_log_weights
def _norm(ctx, log_w):
    return ctx.expect(ctx.call(log_w), Out("w", log_w.shape))


def _check_norm(ctx, log_w):
    w = _norm(ctx, log_w)
    ref = sl.normalize_log_weights(log_w)
    ctx.close("w", w, ref, atol=1e-15, rtol=1e-9)
    if np.any(w < 0) or abs(w.sum() - 1.0) > 1e-9:
        ctx.fail(f"the weights must be non-negative and sum to 1; they sum to {w.sum():.12g}")


@EX.test("normalize_log_weights", "random log-weights", weight=8,
         hint="w = exp(log_w - logsumexp(log_w)); subtract the maximum before exponentiating.")
def _(ctx):
    for M in (5, 100, 1000):
        _check_norm(ctx, ctx.rng.normal(0.0, 5.0, size=M))


@EX.test("normalize_log_weights", "log-weights of magnitude 1e4 do not overflow", weight=7,
         hint="exp(1e4) overflows and exp(-1e4) underflows: shift by max(log_w) first (or use "
              "scipy.special.logsumexp).")
def _(ctx):
    for base in (1e4, -1e4):
        _check_norm(ctx, base + ctx.rng.normal(0.0, 3.0, size=200))
    _check_norm(ctx, np.array([1e4, 1e4 - 1.0, 9990.0, -1e4, 0.0]))


@EX.test("normalize_log_weights", "equal log-weights and a single particle", weight=5, visibility="hidden",
         hint="Equal log-weights give 1/M each; a single particle gets weight 1.")
def _(ctx):
    _check_norm(ctx, np.array([-3.7]))
    _check_norm(ctx, np.full(64, 12.5))
    _check_norm(ctx, np.full(10, -700.0))
    # seeded: a single particle and equal log-weights of any value, and log-weights equal up to 1e-3 (a function
    # that returns 1/M whatever it is given passes the special cases but not these)
    rng = ctx.rng
    _check_norm(ctx, rng.uniform(-800.0, 800.0, size=1))
    for M in rng.integers(2, 200, size=2):
        c = rng.uniform(-800.0, 800.0)
        _check_norm(ctx, np.full(int(M), c))
        _check_norm(ctx, c + rng.normal(0.0, 1e-3, size=int(M)))


# =========================================================================== effective_sample_size
def _ess(ctx, w):
    return float(ctx.expect(ctx.call(w), Out("ess", ())))


def _check_ess(ctx, w):
    got = _ess(ctx, w)
    ctx.close("ess", got, sl.effective_sample_size(w), atol=1e-12, rtol=1e-10)


@EX.test("effective_sample_size", "normalised weights", weight=6,
         hint="ESS = (sum w)^2 / sum(w^2), a float.")
def _(ctx):
    for M in (10, 100, 1000):
        _check_ess(ctx, ctx.rng.dirichlet(np.full(M, 0.5)))


@EX.test("effective_sample_size", "unnormalised weights", weight=5,
         hint="The weights need not sum to 1: use (sum w)^2 / sum(w^2), not 1 / sum(w^2).")
def _(ctx):
    for scale in (37.5, 1e-3, 2.0e3):
        _check_ess(ctx, scale * ctx.rng.dirichlet(np.full(50, 1.0)))


@EX.test("effective_sample_size", "uniform and degenerate weights", weight=4, visibility="hidden",
         hint="Equal weights give M; all weight on one particle gives 1.")
def _(ctx):
    _check_ess(ctx, np.full(40, 0.025))
    w = np.zeros(30)
    w[7] = 1.0
    _check_ess(ctx, w)
    _check_ess(ctx, np.array([0.0, 2.0, 0.0, 2.0]))
    # seeded: nearly uniform weights, and nearly degenerate ones (one dominant particle, a few small weights, zeros
    # elsewhere); counting the non-zero weights passes the special cases above but not these
    rng = ctx.rng
    M = int(rng.integers(10, 200))
    _check_ess(ctx, rng.uniform(0.1, 10.0) * (1.0 + rng.uniform(-0.05, 0.05, size=M)))
    w = np.zeros(M)
    w[rng.choice(M, size=4, replace=False)] = np.r_[1.0, rng.uniform(1e-3, 1e-2, size=3)] * rng.uniform(0.1, 10.0)
    _check_ess(ctx, w)


# =========================================================================== low_variance_resample
def _resample(ctx, w, seed, global_seed=None):
    ret = ctx.call_fn("low_variance_resample", (w,), {"rng": RngSeed(seed)}, global_seed=global_seed)
    return ctx.expect(ret, Out("indices", w.shape, "int"))


def _check_lvr(ctx, w, seed):
    """Call low_variance_resample with a generator seeded ``seed``; the indices must be slamlib's."""
    got = _resample(ctx, w, seed)
    ref = sl.low_variance_resample(w, rng=np.random.default_rng(seed))
    ctx.equal("indices", got, ref)
    return got


@EX.test("low_variance_resample", "indices of Table 4.4 with the single draw", weight=12,
         hint="Normalise w, draw exactly one r = rng.uniform(0.0, 1.0 / M), then index m is the first i with "
              "cumsum(w)[i] >= r + m / M (clipped to M - 1), compared as computed (a pointer equal to a cumulative "
              "weight goes to that particle); return an integer array.")
def _(ctx):
    for k, M in enumerate((10, 50, 200, 7)):
        w = ctx.rng.dirichlet(np.full(M, 0.7))
        _check_lvr(ctx, w, 300 + k)
    w = np.zeros(12)
    w[[2, 9]] = [0.25, 0.75]
    _check_lvr(ctx, w, 310)
    w, seed = _tie_case(ctx.rng)
    _check_lvr(ctx, w, seed)


def _tie_case(rng, M=8):
    """Weights whose cumulative sum equals the pointer ``r + 4 / M`` exactly (the seed fixes ``r``).

    ``w[1] = r + 1/2`` and ``w[-1] = 1 - w[1]`` sum to exactly 1 in any order, so
    normalising changes nothing, and ``cumsum(w)[1] >= r + 4 / M`` holds with
    equality: pointers 0-4 go to particle 1, pointers 5-7 to particle ``M - 1``. The
    seed is chosen so that ``(cumsum(w)[1] - r) M`` rounds below 4, where counting
    pointers by a formula instead of comparing them goes wrong.
    """
    while True:
        seed = int(rng.integers(2**31))
        r = np.random.default_rng(seed).uniform(0.0, 1.0 / M)
        c = r + 4 / M
        if (c - r) * M < 4:
            w = np.zeros(M)
            w[1], w[-1] = c, 1.0 - c
            return w, seed


@EX.test("low_variance_resample", "unnormalised weights", weight=6,
         hint="Normalise the weights before comparing the cumulative sum with r + m / M.")
def _(ctx):
    for k, scale in enumerate((3.7, 0.01, 250.0)):
        w = scale * ctx.rng.dirichlet(np.full(30, 1.0))
        _check_lvr(ctx, w, 400 + k)


def _counts(idx, M):
    return np.bincount(idx, minlength=M)


@EX.test("low_variance_resample", "offspring counts are floor or ceil of M w", weight=7, visibility="hidden",
         hint="Low-variance resampling draws particle i either floor(M w_i) or ceil(M w_i) times.")
def _(ctx):
    M = 40
    for k in range(12):
        w = ctx.rng.dirichlet(np.full(M, 0.8))
        idx = _check_lvr(ctx, w, 500 + k)
        if idx.min() < 0 or idx.max() >= M:
            ctx.fail(f"indices must lie in [0, {M}), got range [{idx.min()}, {idx.max()}]")
        c = _counts(idx, M)
        Mw = M * w / w.sum()
        bad = (c < np.floor(Mw - 1e-9)) | (c > np.ceil(Mw + 1e-9))
        if np.any(bad):
            i = int(np.argmax(bad))
            ctx.fail(f"particle {i} with M w = {Mw[i]:.4f} was drawn {c[i]} times")


@EX.test("low_variance_resample", "offspring counts unbiased (chi-square)", weight=5, visibility="hidden",
         hint="On average particle i must be drawn M w_i times: check the comparison cumsum(w)[i] >= r + m / M "
              "and that r is drawn from [0, 1/M).")
def _(ctx):
    M, R = 20, 300
    w = ctx.rng.dirichlet(np.full(M, 1.0))
    total = np.zeros(M)
    for k in range(R):
        idx = _check_lvr(ctx, w, 600 + k)
        if idx.min() < 0 or idx.max() >= M:
            ctx.fail(f"indices must lie in [0, {M}), got range [{idx.min()}, {idx.max()}]")
        total += _counts(idx, M)
    p = offspring_chi2_pvalue(total, w, R)
    ctx.last_call = f"low_variance_resample(w, rng=...) for {R} seeds"
    if p < P_THRESHOLD:
        exp = R * M * w / w.sum()
        i = int(np.argmax(np.abs(total - exp)))
        ctx.fail(f"the offspring counts over {R} resamplings do not average M w (chi-square p-value {p:.2g} < "
                 f"{P_THRESHOLD:g}); e.g. particle {i}: drawn {int(total[i])} times, expected {exp[i]:.1f}")


@EX.test("low_variance_resample", "particle filter run with your resampler", weight=5, visibility="hidden",
         hint="Plugged into a particle filter, your resampler must give the reference filter's track.")
def _(ctx):
    sc = loops.scenario("localization", ctx.rng)

    def resample(t, w, seed):
        return _check_lvr(ctx, w, seed)

    try:
        traj = loops.particle_filter_loop(sc, resample=resample)
    except loops.LoopError as exc:
        ctx.fail(str(exc))
    ctx.last_call = None
    loops.compare_ate(ctx, "particle filter", traj, loops.reference("pf", sc), sc.run, rel=0.1, abs_tol=0.02)


# =========================================================================== landmark_likelihood
def _lik(ctx, particles, z, m, Q):
    return ctx.expect(ctx.call(particles, z, m, Q), Out("p", (particles.shape[0],)))


def _particles(rng, M, centre=None, spread=0.5):
    c = random_pose(rng) if centre is None else centre
    p = c + rng.normal(0.0, [spread, spread, 0.3], size=(M, 3))
    p[:, 2] = sl.wrap_angle(p[:, 2])
    return p, c


def _check_lik(ctx, particles, z, m, Q):
    """Call landmark_likelihood and compare with slamlib's densities."""
    p = _lik(ctx, particles, z, m, Q)
    ref = sl.landmark_likelihood(particles, z, m, Q)
    ctx.close("p", p, ref, atol=1e-12 * max(float(ref.max()), 1e-300), rtol=1e-8)
    return p


@EX.test("landmark_likelihood", "densities for random particles", weight=10,
         hint="For each particle: z_hat = h(x_k, m), nu = z - z_hat (bearing wrapped), "
              "p_k = exp(-nu^T Q^-1 nu / 2) / (2 pi sqrt(det Q)).")
def _(ctx):
    for _ in range(4):
        particles, c = _particles(ctx.rng, 200)
        m = c[:2] + ctx.rng.uniform(-5, 5, size=2)
        z = sl.landmark_measurement(c, m)[0] + ctx.rng.normal(0, [0.1, 0.05])
        _check_lik(ctx, particles, z, m, np.diag([0.2**2, 0.1**2]))


@EX.test("landmark_likelihood", "bearing difference wrapped", weight=8,
         hint="When the landmark is behind the particles the bearing difference must be wrapped to [-pi, pi).")
def _(ctx):
    c = np.array([1.0, 1.0, 0.0])
    particles, _ = _particles(ctx.rng, 150, centre=c, spread=0.2)
    m = np.array([-3.0, 1.0])
    for zb in (np.pi - 0.01, -np.pi + 0.01):
        _check_lik(ctx, particles, np.array([4.0, zb]), m, np.diag([0.3**2, 0.2**2]))


@EX.test("landmark_likelihood", "correlated measurement noise Q", weight=6, visibility="hidden",
         hint="Use the full matrix Q (its inverse and determinant), not only its diagonal.")
def _(ctx):
    for _ in range(3):
        particles, c = _particles(ctx.rng, 100)
        m = c[:2] + ctx.rng.uniform(-5, 5, size=2)
        z = sl.landmark_measurement(c, m)[0]
        Q = spd(ctx.rng, 2, scale=0.05, cond=5.0)
        Q[0, 1] = Q[1, 0] = 0.8 * np.sqrt(Q[0, 0] * Q[1, 1])
        _check_lik(ctx, particles, z, m, Q)


@EX.test("landmark_likelihood", "particle filter run with your landmark_likelihood", weight=6, visibility="hidden",
         hint="Plugged into a particle filter, your likelihood must give the reference filter's track.")
def _(ctx):
    sc = loops.scenario("localization", ctx.rng)

    def likelihood(t, particles, z, m, Q):
        return _check_lik(ctx, particles, z, m, Q)

    try:
        traj = loops.particle_filter_loop(sc, likelihood=likelihood)
    except loops.LoopError as exc:
        ctx.fail(str(exc))
    ctx.last_call = None
    loops.compare_ate(ctx, "particle filter", traj, loops.reference("pf", sc), sc.run, rel=0.1, abs_tol=0.02)
