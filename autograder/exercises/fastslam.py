"""Exercise 5: FastSLAM 1.0 landmark filters (initialisation and update, vectorised over particles)."""

from __future__ import annotations

import numpy as np

import slamlib as sl

from .. import loops
from ..context import Out
from ..spec import Exercise
from .common import random_pose, spd

EX = Exercise(
    "fastslam",
    "FastSLAM",
    notebook="05_fastslam.ipynb",
    functions={
        "fastslam_init_landmark": "(x, z, Q)",
        "fastslam_update_landmark": "(x, mu, Sigma, z, Q)",
    },
)


def _particles(rng, M, heading=None):
    c = random_pose(rng, extent=3.0, heading=heading)
    p = c + rng.normal(0.0, [0.3, 0.3, 0.1], size=(M, 3))
    p[:, 2] = sl.wrap_angle(p[:, 2])
    return p, c


# =========================================================================== fastslam_init_landmark
def _init(ctx, x, z, Q):
    M = x.shape[0]
    return ctx.expect(ctx.call(x, z, Q), Out("mu", (M, 2)), Out("Sigma", (M, 2, 2)))


def _check_init(ctx, x, z, Q):
    """Call fastslam_init_landmark and compare both results with slamlib's."""
    mu, S = _init(ctx, x, z, Q)
    ref = sl.fastslam_init_landmark(x, z, Q)
    ctx.close("mu", mu, ref[0], atol=1e-9, rtol=1e-9)
    ctx.close("Sigma", S, ref[1], atol=1e-10, rtol=1e-7)
    return mu, S


def _init_case(rng, M=50):
    x, _ = _particles(rng, M)
    z = np.array([rng.uniform(0.5, 8.0), rng.uniform(-np.pi, np.pi)])
    return x, z, spd(rng, 2, scale=0.05)


@EX.test("fastslam_init_landmark", "landmark means from the inverse measurement", weight=12,
         hint="mu_k = [x_k + r cos(theta_k + phi), y_k + r sin(theta_k + phi)] for every particle k.")
def _(ctx):
    for _ in range(4):
        x, z, Q = _init_case(ctx.rng)
        mu, _ = _init(ctx, x, z, Q)
        ctx.close("mu", mu, sl.fastslam_init_landmark(x, z, Q)[0], atol=1e-9, rtol=1e-9)


@EX.test("fastslam_init_landmark", "covariances H^-1 Q H^-T", weight=12,
         hint="H = Hm, the Jacobian of h with respect to the landmark at the new mean; Sigma = H^-1 Q H^-T "
              "(Table 13.1 lines 8-9).")
def _(ctx):
    for _ in range(4):
        x, z, Q = _init_case(ctx.rng)
        _, S = _init(ctx, x, z, Q)
        ctx.close("Sigma", S, sl.fastslam_init_landmark(x, z, Q)[1], atol=1e-10, rtol=1e-7)


@EX.test("fastslam_init_landmark", "covariances symmetric", weight=6, visibility="hidden",
         hint="H^-1 Q H^-T is symmetric: multiply by the transpose of H^-1 on the right.")
def _(ctx):
    for _ in range(3):
        x, z, Q = _init_case(ctx.rng)
        _, S = _check_init(ctx, x, z, Q)
        ctx.symmetric("Sigma", S)


@EX.test("fastslam_init_landmark", "a single particle (M = 1)", weight=4, visibility="hidden",
         hint="x of shape (1, 3) gives mu of shape (1, 2) and Sigma of shape (1, 2, 2).")
def _(ctx):
    x, z, Q = _init_case(ctx.rng, M=1)
    mu, S = _init(ctx, x, z, Q)
    ref = sl.fastslam_init_landmark(x, z, Q)
    ctx.close("mu", mu, ref[0], atol=1e-9, rtol=1e-9)
    ctx.close("Sigma", S, ref[1], atol=1e-10, rtol=1e-7)


@EX.test("fastslam_init_landmark", "FastSLAM run with your fastslam_init_landmark", weight=6, visibility="hidden",
         hint="Plugged into FastSLAM on a simulated run, your initialisation must give the reference's track.")
def _(ctx):
    def init(t, x, z, Q):
        return _check_init(ctx, x, z, Q)

    _fs_e2e(ctx, init=init)


def _fs_e2e(ctx, *, init=None, update=None):
    sc = loops.scenario("slam", ctx.rng)
    try:
        traj = loops.fastslam_loop(sc, init=init, update=update)
    except loops.LoopError as exc:
        ctx.fail(str(exc))
    ctx.last_call = None
    loops.compare_ate(ctx, "FastSLAM", traj, loops.reference("fastslam", sc), sc.run, rel=0.1, abs_tol=0.02)


# =========================================================================== fastslam_update_landmark
def _update(ctx, x, mu, Sigma, z, Q):
    M = x.shape[0]
    return ctx.expect(ctx.call(x, mu, Sigma, z, Q), Out("mu_new", (M, 2)), Out("Sigma_new", (M, 2, 2)),
                      Out("w", (M,)))


def _update_case(rng, M=50, behind=False):
    x, c = _particles(rng, M)
    ang = c[2] + (np.pi + 1e-3 if behind else rng.uniform(-2.5, 2.5))
    m = c[:2] + rng.uniform(1.5, 6.0) * np.array([np.cos(ang), np.sin(ang)])
    mu = m + rng.normal(0.0, 0.3, size=(M, 2))
    Sigma = np.stack([spd(rng, 2, scale=0.1) for _ in range(M)])
    z = sl.landmark_measurement(c, m)[0] + rng.normal(0.0, [0.1, 0.03])
    z[1] = sl.wrap_angle(z[1])
    if behind:
        z[1] = np.pi - 1e-3 if z[1] > 0 else -np.pi + 1e-3
    Q = np.diag([0.1**2, 0.05**2])
    Q[0, 1] = Q[1, 0] = rng.uniform(-0.6, 0.6) * 0.1 * 0.05  # correlated range and bearing noise
    return x, mu, Sigma, z, Q


def _check(ctx, case, which):
    x, mu, Sigma, z, Q = case
    got = _update(ctx, x, mu, Sigma, z, Q)
    ref = sl.fastslam_update_landmark(x, mu, Sigma, z, Q)
    if "mu" in which:
        ctx.close("mu_new", got[0], ref[0], atol=1e-9, rtol=1e-8)
    if "Sigma" in which:
        ctx.close("Sigma_new", got[1], ref[1], atol=1e-10, rtol=1e-7)
    if "w" in which:
        ctx.close("w", got[2], ref[2], atol=1e-12 * max(float(ref[2].max()), 1e-300), rtol=1e-7)
    return got


@EX.test("fastslam_update_landmark", "updated means", weight=12,
         hint="Per particle: z_hat and H = Hm at (x_k, mu_k); S = H Sigma H^T + Q; K = Sigma H^T S^-1; "
              "mu_new = mu + K (z - z_hat) (Table 13.1 lines 12-16).")
def _(ctx):
    for _ in range(4):
        _check(ctx, _update_case(ctx.rng), ("mu",))


@EX.test("fastslam_update_landmark", "updated covariances", weight=10,
         hint="Sigma_new = (I - K H) Sigma for each particle (Table 13.1 line 17).")
def _(ctx):
    for _ in range(4):
        _check(ctx, _update_case(ctx.rng), ("Sigma",))


@EX.test("fastslam_update_landmark", "importance weights N(nu; 0, S)", weight=12,
         hint="w = exp(-nu^T S^-1 nu / 2) / (2 pi sqrt(det S)) with S = H Sigma H^T + Q, the innovation covariance "
              "(not the measurement noise Q alone).")
def _(ctx):
    for _ in range(4):
        _check(ctx, _update_case(ctx.rng), ("w",))


@EX.test("fastslam_update_landmark", "bearing innovation wrapped", weight=8,
         hint="Wrap the bearing of z - z_hat to [-pi, pi) before using it in the mean and in the weight.")
def _(ctx):
    for _ in range(3):
        _check(ctx, _update_case(ctx.rng, behind=True), ("mu", "Sigma", "w"))


@EX.test("fastslam_update_landmark", "covariances symmetric", weight=5, visibility="hidden",
         hint="(I - K H) Sigma is symmetric up to rounding; symmetrise with (S + S^T) / 2 if needed.")
def _(ctx):
    for _ in range(3):
        got = _check(ctx, _update_case(ctx.rng), ("mu", "Sigma", "w"))
        ctx.symmetric("Sigma_new", got[1])


@EX.test("fastslam_update_landmark", "FastSLAM run with your fastslam_update_landmark", weight=13,
         visibility="hidden",
         hint="Plugged into FastSLAM on a simulated run, your update must give the reference's track.")
def _(ctx):
    def update(t, x, mu, Sigma, z, Q):
        return _check(ctx, (x, mu, Sigma, z, Q), ("mu", "Sigma", "w"))

    _fs_e2e(ctx, update=update)
