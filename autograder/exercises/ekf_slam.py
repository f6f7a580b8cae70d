"""Exercise 4: EKF SLAM (prediction, measurement model, landmark initialisation, update, association)."""

from __future__ import annotations

import numpy as np

import slamlib as sl

from .. import loops
from ..context import Out
from ..spec import Exercise
from .common import check_fd, fd_jacobian, random_pose, spd

EX = Exercise(
    "ekf_slam",
    "EKF SLAM",
    notebook="04_ekf_slam.ipynb",
    functions={
        "ekf_slam_predict": "(mu, Sigma, u, dt, M)",
        "ekf_slam_measurement": "(mu, j)",
        "ekf_slam_init_landmark": "(mu, z, j)",
        "ekf_slam_update": "(mu_bar, Sigma_bar, z, j, Q)",
        "ekf_slam_associate": "(mu_bar, Sigma_bar, z, n_seen, Q, alpha)",
    },
)
INDEX = Out("index", (), "index")


def _state(rng, N=4, heading=None, scale=0.2):
    """A random EKF-SLAM belief with N landmarks around the robot and a full covariance."""
    x = random_pose(rng, extent=2.0, heading=heading)
    lm = []
    for _ in range(N):
        a = rng.uniform(-np.pi, np.pi)
        lm.append(x[:2] + rng.uniform(1.0, 6.0) * np.array([np.cos(a), np.sin(a)]))
    mu = np.concatenate([x] + lm) if N else x.copy()
    Sigma = spd(rng, 3 + 2 * N, scale=scale, cond=30.0)
    return mu, Sigma


def _control(rng, omega=None):
    w = rng.choice([-1, 1]) * rng.uniform(0.05, 1.5) if omega is None else omega
    return np.array([rng.uniform(-0.5, 2.0), w]), float(rng.uniform(0.05, 0.5))


def _sharp_controls(rng):
    """A left and a right sharp turn (``|omega dt|`` in [1.6, 2.4], ``v >= 0.5``): V far from its straight-line
    limit and from the series of small turns."""
    return [(np.array([rng.uniform(0.5, 2.0), s * rng.uniform(2.0, 3.0)]), 0.8) for s in (1.0, -1.0)]


# =========================================================================== ekf_slam_predict
def _predict(ctx, mu, Sigma, u, dt, M):
    n = mu.shape[0]
    mu_bar, S = ctx.expect(ctx.call(mu, Sigma, u, dt, M), Out("mu_bar", (n,)), Out("Sigma_bar", (n, n)))
    ctx.wrapped("the heading mu_bar[2]", mu_bar[2])
    return mu_bar, S


def _check_predict(ctx, mu, Sigma, u, dt, M):
    """Call ekf_slam_predict and compare both results with slamlib's (atol scaled by max |Sigma_bar|)."""
    mu_bar, S = _predict(ctx, mu, Sigma, u, dt, M)
    ref = sl.ekf_slam_predict(mu, Sigma, u, dt, M)
    ctx.close("mu_bar", mu_bar, ref[0], atol=1e-9, rtol=1e-9, angles=[2])
    ctx.close("Sigma_bar", S, ref[1], atol=1e-9 * max(1.0, float(np.abs(ref[1]).max())), rtol=1e-7)
    return mu_bar, S


@EX.test("ekf_slam_predict", "robot moves, landmarks stay", weight=8,
         hint="Only the robot pose moves (exact arc); G = I + F_x^T (G_x - I) F_x and "
              "Sigma_bar = G Sigma G^T + F_x^T V M V^T F_x (Algorithm 1 lines 2-5).")
def _(ctx):
    for _ in range(5):
        mu, Sigma = _state(ctx.rng)
        u, dt = _control(ctx.rng)
        _check_predict(ctx, mu, Sigma, u, dt, spd(ctx.rng, 2, scale=0.05))
    for u, dt in _sharp_controls(ctx.rng):
        mu, Sigma = _state(ctx.rng)
        _check_predict(ctx, mu, Sigma, u, dt, spd(ctx.rng, 2, scale=0.5))


@EX.test("ekf_slam_predict", "any number of landmarks (N = 0, 1, 7)", weight=4,
         hint="Size F_x and G from len(mu): the state has 3 + 2N entries, N may be 0.")
def _(ctx):
    for N in (0, 1, 7):
        mu, Sigma = _state(ctx.rng, N=N)
        u, dt = _control(ctx.rng)
        _check_predict(ctx, mu, Sigma, u, dt, spd(ctx.rng, 2, scale=0.05))


@EX.test("ekf_slam_predict", "straight-line motion and wrapped heading", weight=3, visibility="hidden",
         hint="Use the straight-line limit for abs(omega) < 1e-6 and wrap the heading.")
def _(ctx):
    for w, th in ((0.0, 0.5), (1e-8, -1.0), (1.2, np.pi - 0.01)):
        mu, Sigma = _state(ctx.rng, N=3, heading=th)
        u, dt = _control(ctx.rng, omega=w)
        _check_predict(ctx, mu, Sigma, u, dt, spd(ctx.rng, 2, scale=0.05))


@EX.test("ekf_slam_predict", "EKF SLAM run with your ekf_slam_predict", weight=5, visibility="hidden",
         hint="Plugged into EKF SLAM on a simulated run, your prediction must track the robot as well as the "
              "reference.")
def _(ctx):
    sc = loops.scenario("slam", ctx.rng)

    def predict(t, mu, Sigma, u, dt, M):
        return _check_predict(ctx, mu, Sigma, u, dt, M)

    _slam_e2e(ctx, sc, predict=predict)


def _slam_e2e(ctx, sc, *, predict=None, init=None, update=None):
    try:
        traj, lm = loops.ekf_slam_loop(sc, predict=predict, init=init, update=update)
    except loops.LoopError as exc:
        ctx.fail(str(exc))
    ctx.last_call = None
    ref_traj, ref_lm = loops.reference("ekf_slam", sc)
    run = sc.run
    loops.compare_ate(ctx, "EKF SLAM", traj, ref_traj, run)
    seen = ~np.isnan(ref_lm[:, 0])
    err = np.sqrt(np.mean(np.sum((lm[seen] - run.landmarks[seen]) ** 2, axis=1)))
    ref_err = np.sqrt(np.mean(np.sum((ref_lm[seen] - run.landmarks[seen]) ** 2, axis=1)))
    if not np.isfinite(err) or abs(err - ref_err) > 0.05 * ref_err + 0.01:
        ctx.fail(f"EKF SLAM: the landmark error is {err:.4f} m, the reference filter's is {ref_err:.4f} m")


# =========================================================================== ekf_slam_measurement
def _meas(ctx, mu, j):
    n = mu.shape[0]
    return ctx.expect(ctx.call(mu, j), Out("z_hat", (2,)), Out("H", (2, n)))


def _behind(mu, j):
    """Move landmark j straight behind the robot (bearing at +-pi)."""
    mu = mu.copy()
    th = mu[2]
    mu[3 + 2 * j:5 + 2 * j] = mu[:2] + 3.0 * np.array([np.cos(th + np.pi + 1e-4), np.sin(th + np.pi + 1e-4)])
    return mu


def _across(rng, s):
    """A belief and a landmark j whose unwrapped bearing atan2(dy, dx) - theta is -s [4, 6] (beyond -+pi)."""
    mu, _ = _state(rng, N=5, heading=s * rng.uniform(2.0, 3.0))
    j = int(rng.integers(5))
    a = -s * rng.uniform(2.0, 3.0)
    mu[3 + 2 * j:5 + 2 * j] = mu[:2] + rng.uniform(1.0, 6.0) * np.array([np.cos(a), np.sin(a)])
    return mu, j


@EX.test("ekf_slam_measurement", "expected measurement z_hat", weight=6,
         hint="z_hat = [sqrt(q), wrap(atan2(dy, dx) - theta)] with (dx, dy) = m_j - (x, y) (Eq. 17.2); "
              "landmark j lives at mu[3 + 2j], mu[4 + 2j].")
def _(ctx):
    for k in range(8):
        if k >= 6:  # unwrapped bearings below -pi, then above +pi
            mu, j = _across(ctx.rng, 1.0 if k == 6 else -1.0)
        else:
            mu, _ = _state(ctx.rng, N=5)
            j = int(ctx.rng.integers(5))
            if k == 5:
                mu = _behind(mu, j)
        z, _ = _meas(ctx, mu, j)
        ref = sl.ekf_slam_measurement(mu, j)
        ctx.wrapped("the bearing z_hat[1]", z[1])
        ctx.close("z_hat", z, ref[0], atol=1e-9, rtol=1e-9, angles=[1])


@EX.test("ekf_slam_measurement", "Jacobian H = h F_{x,j} in the full state", weight=8,
         hint="H is zero except in the robot columns 0-2 and the landmark columns 3+2j, 4+2j (Eq. 17.3).")
def _(ctx):
    for _ in range(6):
        mu, _ = _state(ctx.rng, N=5)
        j = int(ctx.rng.integers(5))
        _, H = _meas(ctx, mu, j)
        ctx.close("H", H, sl.ekf_slam_measurement(mu, j)[1], atol=1e-9, rtol=1e-7)


@EX.test("ekf_slam_measurement", "H matches finite differences of your z_hat", weight=6, visibility="hidden",
         hint="Your H disagrees with the numerical derivatives of your own z_hat.")
def _(ctx):
    for _ in range(2):
        mu, _ = _state(ctx.rng, N=3)
        j = int(ctx.rng.integers(3))
        z, H = _meas(ctx, mu, j)
        ref = sl.ekf_slam_measurement(mu, j)
        ctx.close("z_hat", z, ref[0], atol=1e-9, rtol=1e-9, angles=[1])
        ctx.close("H", H, ref[1], atol=1e-9, rtol=1e-7)
        num = fd_jacobian(lambda mm: _meas(ctx, mm, j)[0], mu, angle_out=[1])
        ctx.last_call = ctx.describe_call("ekf_slam_measurement", (mu, j), {})
        check_fd(ctx, "H", H, num)


# =========================================================================== ekf_slam_init_landmark
def _init(ctx, mu, z, j):
    return ctx.expect(ctx.call(mu, z, j), Out("mu", mu.shape))


def _check_init(ctx, mu, z, j):
    """Call ekf_slam_init_landmark and compare with slamlib's result."""
    got = _init(ctx, mu, z, j)
    ctx.close("mu", got, sl.ekf_slam_init_landmark(mu, z, j), atol=1e-9, rtol=1e-9, angles=[2])
    return got


@EX.test("ekf_slam_init_landmark", "landmark mean from the first sighting", weight=8,
         hint="m_j = [x + r cos(phi + theta), y + r sin(phi + theta)] written into mu[3 + 2j], mu[4 + 2j] "
              "(Algorithm 1 line 10).")
def _(ctx):
    for _ in range(6):
        mu, _ = _state(ctx.rng, N=4)
        j = int(ctx.rng.integers(4))
        z = np.array([ctx.rng.uniform(0.5, 8.0), ctx.rng.uniform(-np.pi, np.pi)])
        got = _init(ctx, mu, z, j)
        ctx.close("mu", got, sl.ekf_slam_init_landmark(mu, z, j), atol=1e-9, rtol=1e-9, angles=[2])


@EX.test("ekf_slam_init_landmark", "nothing else changes", weight=4,
         hint="Return a copy of mu with only landmark j's two entries replaced; do not modify mu itself.")
def _(ctx):
    for _ in range(4):
        mu, _ = _state(ctx.rng, N=6)
        j = int(ctx.rng.integers(6))
        z = np.array([ctx.rng.uniform(0.5, 8.0), ctx.rng.uniform(-np.pi, np.pi)])
        got = _check_init(ctx, mu, z, j)
        keep = np.ones(mu.shape, bool)
        keep[3 + 2 * j:5 + 2 * j] = False
        ctx.equal("the entries of mu other than landmark j", got[keep], mu[keep])


@EX.test("ekf_slam_init_landmark", "EKF SLAM run with your ekf_slam_init_landmark", weight=3, visibility="hidden",
         hint="Plugged into EKF SLAM on a simulated run, your initialisation must give the reference's map.")
def _(ctx):
    def init(t, mu, z, j):
        return _check_init(ctx, mu, z, j)

    _slam_e2e(ctx, loops.scenario("slam", ctx.rng), init=init)


# =========================================================================== ekf_slam_update
def _update(ctx, mu_bar, Sigma_bar, z, j, Q):
    n = mu_bar.shape[0]
    mu, S = ctx.expect(ctx.call(mu_bar, Sigma_bar, z, j, Q), Out("mu", (n,)), Out("Sigma", (n, n)))
    ctx.wrapped("the heading mu[2]", mu[2])
    return mu, S


def _noisy_z(rng, mu, j):
    z = sl.ekf_slam_measurement(mu, j)[0] + rng.normal(0.0, [0.15, 0.05])
    z[1] = sl.wrap_angle(z[1])
    return z


def _check_update(ctx, mu, Sigma, z, j, Q):
    """Call ekf_slam_update and compare both results with slamlib's (atol scaled by max |Sigma_bar|)."""
    got_mu, got_S = _update(ctx, mu, Sigma, z, j, Q)
    ref = sl.ekf_slam_update(mu, Sigma, z, j, Q)
    ctx.close("mu", got_mu, ref[0], atol=1e-9, rtol=1e-8, angles=[2])
    ctx.close("Sigma", got_S, ref[1], atol=1e-10 * max(1.0, float(np.abs(Sigma).max())), rtol=1e-7)
    return got_mu, got_S


@EX.test("ekf_slam_update", "mean and covariance on random beliefs", weight=10,
         hint="S = H Sigma_bar H^T + Q, K = Sigma_bar H^T S^-1, mu = mu_bar + K (z - z_hat), "
              "Sigma = (I - K H) Sigma_bar (Algorithm 1 lines 17-19).")
def _(ctx):
    for _ in range(5):
        mu, Sigma = _state(ctx.rng, N=4)
        j = int(ctx.rng.integers(4))
        _check_update(ctx, mu, Sigma, _noisy_z(ctx.rng, mu, j), j, spd(ctx.rng, 2, scale=0.05))


@EX.test("ekf_slam_update", "bearing innovation wrapped", weight=5,
         hint="Wrap the bearing of z - z_hat to [-pi, pi) and the updated heading.")
def _(ctx):
    for th in (0.2, np.pi - 0.01):
        mu, Sigma = _state(ctx.rng, N=3, heading=th)
        j = int(ctx.rng.integers(3))
        mu = _behind(mu, j)  # z_hat's bearing is -pi + 1e-4
        z = sl.ekf_slam_measurement(mu, j)[0] + np.array([ctx.rng.normal(0.0, 0.15), -ctx.rng.uniform(0.01, 0.1)])
        z[1] = sl.wrap_angle(z[1])  # just below +pi: z - z_hat is about -2 pi before wrapping
        _check_update(ctx, mu, Sigma, z, j, np.diag([0.05, 0.02]))
    # a heading at pi - 1e-4 corrected both ways: one of the two updates crosses +-pi
    mu, Sigma, j = _near_cut(ctx.rng)
    for db in (-0.3, 0.3):
        z = sl.ekf_slam_measurement(mu, j)[0] + np.array([0.0, db])
        z[1] = sl.wrap_angle(z[1])
        _check_update(ctx, mu, Sigma, z, j, np.diag([0.05, 0.02]))


def _near_cut(rng):
    """A belief (3 landmarks) with heading ``pi - 1e-4`` whose heading variance dominates, and an index ``j``.

    ``Sigma`` is a small random covariance (scale 0.02) plus 0.3 on the heading, so a
    bearing innovation of ``+-0.3`` moves the heading by about ``-+0.27``: one of the
    two updates takes it across the cut.
    """
    mu, Sigma = _state(rng, N=3, heading=np.pi - 1e-4, scale=0.02)
    Sigma[2, 2] += 0.3
    return mu, Sigma, int(rng.integers(3))


@EX.test("ekf_slam_update", "covariance symmetric and not larger than the prior", weight=3, visibility="hidden",
         hint="(I - K H) Sigma_bar is symmetric, and an update never adds uncertainty.")
def _(ctx):
    for _ in range(3):
        mu, Sigma = _state(ctx.rng, N=4)
        j = int(ctx.rng.integers(4))
        _, S = _check_update(ctx, mu, Sigma, _noisy_z(ctx.rng, mu, j), j, spd(ctx.rng, 2, scale=0.05))
        ctx.symmetric("Sigma", S)
        if np.linalg.eigvalsh(Sigma - 0.5 * (S + S.T)).min() < -1e-9 * max(1.0, np.abs(Sigma).max()):
            ctx.fail("Sigma_bar - Sigma has a negative eigenvalue: the update increased the uncertainty")


@EX.test("ekf_slam_update", "EKF SLAM run with your ekf_slam_update", weight=7, visibility="hidden",
         hint="Plugged into EKF SLAM on a simulated run, your update must track the robot and map the landmarks "
              "as well as the reference.")
def _(ctx):
    def update(t, mu, Sigma, z, j, Q):
        return _check_update(ctx, mu, Sigma, z, j, Q)

    _slam_e2e(ctx, loops.scenario("slam", ctx.rng), update=update)


# =========================================================================== ekf_slam_associate
def _assoc(ctx, mu, Sigma, z, n_seen, Q, alpha):
    return ctx.expect(ctx.call(mu, Sigma, z, n_seen, Q, alpha), INDEX)


def _clear_assoc(rng, N=5, k=None):
    """A belief and a measurement of landmark ``k`` (random if None), which is clearly the nearest."""
    want = k
    while True:
        mu, Sigma = _state(rng, N=N, scale=0.05)
        k = int(rng.integers(N)) if want is None else want
        z = _noisy_z(rng, mu, k)
        Q = spd(rng, 2, scale=0.05)
        d = []
        for i in range(N):
            z_hat, H = sl.ekf_slam_measurement(mu, i)
            S = H @ Sigma @ H.T + Q
            nu = z - z_hat
            nu[1] = sl.wrap_angle(nu[1])
            d.append(nu @ np.linalg.solve(S, nu))
        ds = np.sort(d)
        if int(np.argmin(d)) == k and ds[1] > ds[0] * (1 + 1e-3) + 1e-6:
            return mu, Sigma, z, Q


@EX.test("ekf_slam_associate", "nearest landmark by Mahalanobis distance", weight=8,
         hint="For k < n_seen: d_k = nu_k^T S_k^-1 nu_k with S_k = H_k Sigma_bar H_k^T + Q; return the smallest "
              "if d_k <= alpha (Algorithm 2).")
def _(ctx):
    for i in range(8):
        mu, Sigma, z, Q = _clear_assoc(ctx.rng, k=None if i % 2 else int(ctx.rng.integers(1, 5)))
        got = _assoc(ctx, mu, Sigma, z, 5, Q, 1e6)
        want = sl.ekf_slam_associate(mu, Sigma, z, 5, Q, 1e6)
        if got != want:
            ctx.fail(f"returned {got}, expected {want}")


@EX.test("ekf_slam_associate", "new landmark above alpha, and n_seen = 0", weight=5,
         hint="Return n_seen (a new landmark) when every distance exceeds alpha, or when n_seen = 0; a distance "
              "equal to alpha is a match. Some alphas sit just below and above the smallest distance, so "
              "d_k = nu_k^T S_k^-1 nu_k must be exact: S_k = H_k Sigma_bar H_k^T + Q with the full H_k, and the "
              "bearing of nu_k wrapped.")
def _(ctx):
    mu, Sigma, z, Q = _clear_assoc(ctx.rng, k=int(ctx.rng.integers(1, 3)))
    for n_seen, alpha in ((5, 1e-9), (0, 1e6), (0, np.inf), (3, 5.99), (5, 1e6), (5, np.inf)):
        got = _assoc(ctx, mu, Sigma, z, n_seen, Q, alpha)
        want = sl.ekf_slam_associate(mu, Sigma, z, n_seen, Q, alpha)
        if got != want:
            ctx.fail(f"returned {got}, expected {want} (n_seen = {n_seen}, alpha = {alpha:g})")
    # an exactly representable case: Sigma_bar = 0, Q = I and nu = (0.5, 0), so d = 0.25 exactly
    mu0, S0, z0 = np.array([0.0, 0.0, 0.0, 1.0, 0.0]), np.zeros((5, 5)), np.array([1.5, 0.0])
    for alpha in (0.25, 0.2499):
        got = _assoc(ctx, mu0, S0, z0, 1, np.eye(2), alpha)
        want = sl.ekf_slam_associate(mu0, S0, z0, 1, np.eye(2), alpha)
        if got != want:
            ctx.fail(f"returned {got}, expected {want} (the distance is exactly 0.25, alpha {alpha})")
    # alpha just below and above the smallest distance: the answer depends on its exact value
    _probe_alpha(ctx, mu, Sigma, z, 5, Q)
    mu, Sigma, z, Q = _clear_assoc(ctx.rng, k=int(ctx.rng.integers(0, 3)))
    mu = _behind(mu, 3)
    z = np.array([3.02, np.pi - 2e-3])  # landmark 3 is straight behind the robot: wrap the bearing innovation
    _probe_alpha(ctx, mu, Sigma, z, 5, Q)


def _distances(mu, Sigma, z, n_seen, Q):
    d = []
    for i in range(n_seen):
        z_hat, H = sl.ekf_slam_measurement(mu, i)
        nu = z - z_hat
        nu[1] = sl.wrap_angle(nu[1])
        d.append(nu @ np.linalg.solve(H @ Sigma @ H.T + Q, nu))
    return np.array(d)


def _probe_alpha(ctx, mu, Sigma, z, n_seen, Q):
    d = _distances(mu, Sigma, z, n_seen, Q)
    for alpha in (d.min() * (1 - 1e-6), d.min() * (1 + 1e-6)):
        got = _assoc(ctx, mu, Sigma, z, n_seen, Q, float(alpha))
        want = sl.ekf_slam_associate(mu, Sigma, z, n_seen, Q, float(alpha))
        if got != want:
            ctx.fail(f"returned {got}, expected {want}: the smallest squared Mahalanobis distance is "
                     f"{d.min():.10g} and alpha {alpha:.10g} (the distances are {np.array2string(d, precision=6)})")


@EX.test("ekf_slam_associate", "slots beyond n_seen are ignored", weight=4, visibility="hidden",
         hint="Only the first n_seen landmarks are in the map; later slots hold nothing yet.")
def _(ctx):
    for _ in range(3):
        mu, Sigma, z, Q = _clear_assoc(ctx.rng, N=6, k=int(ctx.rng.integers(1, 4)))
        mu = mu.copy()
        m = sl.landmark_from_measurement(mu[:3], z)
        mu[3 + 2 * 4:5 + 2 * 4] = m  # slots 4 = n_seen and 5 match z perfectly but are not in the map yet
        mu[3 + 2 * 5:5 + 2 * 5] = m
        got = _assoc(ctx, mu, Sigma, z, 4, Q, 1e6)
        want = sl.ekf_slam_associate(mu, Sigma, z, 4, Q, 1e6)
        if got != want:
            ctx.fail(f"returned {got}, expected {want} (n_seen = 4)")


@EX.test("ekf_slam_associate", "ties go to the smallest index", weight=3, visibility="hidden",
         hint="When two landmarks are equally close, return the smaller index.")
def _(ctx):
    for _ in range(4):
        while True:  # the nearest landmark with Sigma_bar = 0 must be 1 or 2 (so that a constant answer fails)
            mu, Sigma, z, Q = _clear_assoc(ctx.rng, N=4, k=int(ctx.rng.integers(1, 3)))
            Sigma = np.zeros_like(Sigma)
            best = sl.ekf_slam_associate(mu, Sigma, z, 4, Q, 1e6)
            if best in (1, 2):
                break
        mu = mu.copy()
        lo, hi = best, 3
        mu[3 + 2 * hi:5 + 2 * hi] = mu[3 + 2 * lo:5 + 2 * lo]
        got = _assoc(ctx, mu, Sigma, z, 4, Q, 1e6)
        if got != lo:
            ctx.fail(f"landmarks {lo} and {hi} are identical and nearest; returned {got}, expected {lo}")
