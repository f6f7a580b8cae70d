"""Exercise 2: EKF localization (prediction, update, nearest-neighbour association)."""

from __future__ import annotations

import numpy as np

import slamlib as sl

from .. import loops
from ..context import Out
from ..spec import Exercise
from .common import random_pose, spd

EX = Exercise(
    "ekf_localization",
    "EKF localization",
    notebook="02_ekf_localization.ipynb",
    functions={
        "ekf_predict": "(mu, Sigma, u, dt, M)",
        "ekf_update": "(mu_bar, Sigma_bar, z, m, Q)",
        "associate_ml": "(mu_bar, Sigma_bar, z, landmarks, Q, gate)",
    },
)

MU_BAR, SIGMA_BAR = Out("mu_bar", (3,)), Out("Sigma_bar", (3, 3))
MU, SIGMA = Out("mu", (3,)), Out("Sigma", (3, 3))
INDEX = Out("index", (), "index")


def _belief(rng, heading=None):
    return random_pose(rng, heading=heading), spd(rng, 3, scale=0.2)


def _control(rng, omega=None):
    w = rng.choice([-1, 1]) * rng.uniform(0.05, 1.5) if omega is None else omega
    return np.array([rng.uniform(-0.5, 2.0), w]), float(rng.uniform(0.05, 0.5))


def _sharp_controls(rng):
    """A left and a right sharp turn, ``|omega dt|`` in [1.8, 3.2] and ``v >= 0.5``: V far from its small-turn series."""
    return [(np.array([rng.uniform(0.5, 2.0), s * rng.uniform(3.0, 4.0)]), float(rng.uniform(0.6, 0.8)))
            for s in (1.0, -1.0)]


# =========================================================================== ekf_predict
def _predict(ctx, mu, Sigma, u, dt, M):
    mu_bar, S = ctx.expect(ctx.call(mu, Sigma, u, dt, M), MU_BAR, SIGMA_BAR)
    ctx.wrapped("the heading mu_bar[2]", mu_bar[2])
    return mu_bar, S


def _check_predict(ctx, mu, Sigma, u, dt, M, scaled=False):
    """Call ekf_predict and compare both results with slamlib's (``scaled``: atol relative to max |Sigma_bar|)."""
    mu_bar, S = _predict(ctx, mu, Sigma, u, dt, M)
    ref = sl.ekf_predict(mu, Sigma, u, dt, M)
    ctx.close("mu_bar", mu_bar, ref[0], atol=1e-9, rtol=1e-9, angles=[2])
    ctx.close("Sigma_bar", S, ref[1], atol=1e-9 * (max(1.0, np.abs(ref[1]).max()) if scaled else 1.0), rtol=1e-7)
    if scaled:
        return mu_bar, S
    return S


@EX.test("ekf_predict", "mean and covariance on random beliefs", weight=10,
         hint="mu_bar is the noise-free exact-arc motion of mu; Sigma_bar = G Sigma G^T + V M V^T with G and V "
              "evaluated at (mu, u) (Table 7.2 lines 2-7).")
def _(ctx):
    for _ in range(6):
        mu, Sigma = _belief(ctx.rng)
        u, dt = _control(ctx.rng)
        _check_predict(ctx, mu, Sigma, u, dt, spd(ctx.rng, 2, scale=0.05))
    for u, dt in _sharp_controls(ctx.rng):
        mu, Sigma = _belief(ctx.rng)
        _check_predict(ctx, mu, Sigma, u, dt, spd(ctx.rng, 2, scale=0.5))


@EX.test("ekf_predict", "straight-line motion (omega = 0)", weight=3,
         hint="For abs(omega) < 1e-6 use the straight-line limit of the motion and of its Jacobians.")
def _(ctx):
    for w in (0.0, 1e-8, -3e-7):
        mu, Sigma = _belief(ctx.rng)
        u, dt = _control(ctx.rng, omega=w)
        _check_predict(ctx, mu, Sigma, u, dt, spd(ctx.rng, 2, scale=0.05))


@EX.test("ekf_predict", "small turn rates (1e-6 <= |omega| < 1e-2)", weight=2, visibility="hidden",
         hint="Between 1e-6 and 1e-2 the arc formulas must still be used; V (and so V M V^T) may lose some "
              "precision (1e-3 relative).")
def _(ctx):
    for w in (2e-6, -3e-5, 1.5e-3, -9e-3):
        mu, Sigma = _belief(ctx.rng)
        u, dt = _control(ctx.rng, omega=w)
        M = spd(ctx.rng, 2, scale=0.05)
        mu_bar, S = _predict(ctx, mu, Sigma, u, dt, M)
        ref = sl.ekf_predict(mu, Sigma, u, dt, M)
        _, _, V = sl.velocity_motion(mu, u, dt)
        scale = float(np.abs(V @ M @ V.T).max())
        ctx.close("mu_bar", mu_bar, ref[0], atol=1e-7, rtol=1e-7, angles=[2])
        ctx.close("Sigma_bar", S, ref[1], atol=1e-9 + 3e-3 * scale, rtol=1e-7)


@EX.test("ekf_predict", "heading wrapped to [-pi, pi)", weight=4,
         hint="Wrap the predicted heading to [-pi, pi).")
def _(ctx):
    for th, w in ((3.05, 1.0), (-3.05, -1.0), (np.pi - 1e-4, 0.3)):
        mu, Sigma = _belief(ctx.rng, heading=th)
        u = np.array([0.8, w])
        _check_predict(ctx, mu, Sigma, u, 0.4, spd(ctx.rng, 2, scale=0.05))


@EX.test("ekf_predict", "covariance symmetric", weight=4, visibility="hidden",
         hint="G Sigma G^T + V M V^T is symmetric; make sure both terms use the transposes on the right.")
def _(ctx):
    for _ in range(4):
        mu, Sigma = _belief(ctx.rng)
        Sigma = Sigma * 50.0
        u, dt = _control(ctx.rng)
        S = _check_predict(ctx, mu, Sigma, u, dt, spd(ctx.rng, 2, scale=2.0))
        ctx.symmetric("Sigma_bar", S)


@EX.test("ekf_predict", "EKF localization run with your ekf_predict", weight=12, visibility="hidden", timeout=10,
         hint="Your ekf_predict, combined with the reference ekf_update on a simulated run, must track the robot "
              "as well as the reference filter.")
def _(ctx):
    sc = loops.scenario("localization", ctx.rng)

    def predict(t, mu, Sigma, u, dt, M):
        return _check_predict(ctx, mu, Sigma, u, dt, M, scaled=True)

    try:
        traj, _ = loops.ekf_localization_loop(sc, predict=predict)
    except loops.LoopError as exc:
        ctx.fail(str(exc))
    ctx.last_call = None
    loops.compare_ate(ctx, "EKF localization", traj, loops.reference("ekf_known", sc), sc.run)


# =========================================================================== ekf_update
def _update(ctx, mu_bar, Sigma_bar, z, m, Q):
    mu, S = ctx.expect(ctx.call(mu_bar, Sigma_bar, z, m, Q), MU, SIGMA)
    ctx.wrapped("the heading mu[2]", mu[2])
    return mu, S


def _meas_case(rng, mu_bar, behind=False):
    """A landmark and a noisy measurement of it; `behind`: z and z_hat on opposite sides of the +-pi cut."""
    side = rng.choice([-1, 1])
    if behind:  # z_hat's bearing within 0.02 rad of +-pi, on the side `side`
        ang = mu_bar[2] + np.pi - side * rng.uniform(0.002, 0.02)
    else:
        ang = mu_bar[2] + rng.uniform(-2.5, 2.5)
    m = mu_bar[:2] + rng.uniform(1.0, 6.0) * np.array([np.cos(ang), np.sin(ang)])
    z_hat = sl.landmark_measurement(mu_bar, m)[0]
    z = z_hat + rng.normal(0.0, [0.2, 0.05])
    if behind:  # the measured bearing just across the cut: z - z_hat is about -+2 pi before wrapping
        z[1] = z_hat[1] + side * (np.pi - abs(z_hat[1]) + rng.uniform(0.002, 0.05))
    z[1] = sl.wrap_angle(z[1])
    return z, m


def _check_update(ctx, mu_bar, Sigma_bar, z, m, Q, scaled=False):
    """Call ekf_update and compare both results with slamlib's (``scaled``: atol relative to max |Sigma_bar|)."""
    mu, S = _update(ctx, mu_bar, Sigma_bar, z, m, Q)
    ref = sl.ekf_update(mu_bar, Sigma_bar, z, m, Q)
    ctx.close("mu", mu, ref[0], atol=1e-9, rtol=1e-8, angles=[2])
    ctx.close("Sigma", S, ref[1], atol=1e-10 * (max(1.0, np.abs(Sigma_bar).max()) if scaled else 1.0), rtol=1e-7)
    return mu, S


@EX.test("ekf_update", "mean and covariance on random beliefs", weight=12,
         hint="S = H Sigma_bar H^T + Q, K = Sigma_bar H^T S^-1, mu = mu_bar + K (z - z_hat), "
              "Sigma = (I - K H) Sigma_bar, with z_hat and H at mu_bar (Table 7.2 lines 10-17).")
def _(ctx):
    for _ in range(6):
        mu_bar, Sigma_bar = _belief(ctx.rng)
        z, m = _meas_case(ctx.rng, mu_bar)
        _check_update(ctx, mu_bar, Sigma_bar, z, m, spd(ctx.rng, 2, scale=0.05))


@EX.test("ekf_update", "bearing innovation wrapped", weight=8,
         hint="Wrap the bearing component of the innovation z - z_hat to [-pi, pi) before multiplying by K, "
              "and wrap the updated heading.")
def _(ctx):
    for th in (0.3, np.pi - 0.01, -np.pi + 0.02):
        mu_bar, Sigma_bar = _belief(ctx.rng, heading=th)
        z, m = _meas_case(ctx.rng, mu_bar, behind=True)
        _check_update(ctx, mu_bar, Sigma_bar, z, m, np.diag([0.05, 0.02]))
    # a heading at pi - 1e-4 corrected both ways: one of the two updated headings crosses +-pi
    mu_bar, Sigma_bar, m = _near_cut(ctx.rng)
    z_hat = sl.landmark_measurement(mu_bar, m)[0]
    for db in (-0.3, 0.3):
        z = z_hat + np.array([0.0, db])
        z[1] = sl.wrap_angle(z[1])
        _check_update(ctx, mu_bar, Sigma_bar, z, m, np.diag([0.05, 0.02]))


def _near_cut(rng):
    """A belief with heading ``pi - 1e-4`` whose heading variance dominates, and a landmark ``m``.

    ``Sigma_bar`` is a small random covariance (scale 0.02) plus 0.3 on the heading, so
    a bearing innovation of ``+-0.3`` moves the heading by about ``-+0.27``: one of the
    two updates takes it across the cut.
    """
    mu_bar, Sigma_bar = random_pose(rng, heading=np.pi - 1e-4), spd(rng, 3, scale=0.02)
    Sigma_bar[2, 2] += 0.3
    ang = mu_bar[2] + rng.uniform(-2.5, 2.5)
    return mu_bar, Sigma_bar, mu_bar[:2] + rng.uniform(1.0, 6.0) * np.array([np.cos(ang), np.sin(ang)])


@EX.test("ekf_update", "covariance symmetric and not larger than the prior", weight=5, visibility="hidden",
         hint="(I - K H) Sigma_bar is symmetric and Sigma_bar - Sigma is positive semi-definite: an update never "
              "adds uncertainty.")
def _(ctx):
    for _ in range(4):
        mu_bar, Sigma_bar = _belief(ctx.rng)
        z, m = _meas_case(ctx.rng, mu_bar)
        _, S = _check_update(ctx, mu_bar, Sigma_bar, z, m, spd(ctx.rng, 2, scale=0.05))
        ctx.symmetric("Sigma", S)
        D = Sigma_bar - 0.5 * (S + S.T)
        if np.linalg.eigvalsh(D).min() < -1e-9 * max(1.0, np.abs(Sigma_bar).max()):
            ctx.fail("Sigma_bar - Sigma has a negative eigenvalue: the update increased the uncertainty")


@EX.test("ekf_update", "EKF localization run with your ekf_update", weight=15, visibility="hidden",
         hint="Your ekf_update, combined with the reference ekf_predict on a simulated run, must track the robot "
              "as well as the reference filter.")
def _(ctx):
    sc = loops.scenario("localization", ctx.rng)

    def update(t, mu, Sigma, z, m, Q):
        return _check_update(ctx, mu, Sigma, z, m, Q, scaled=True)

    try:
        traj, _ = loops.ekf_localization_loop(sc, update=update)
    except loops.LoopError as exc:
        ctx.fail(str(exc))
    ctx.last_call = None
    loops.compare_ate(ctx, "EKF localization", traj, loops.reference("ekf_known", sc), sc.run)


# =========================================================================== associate_ml
def _assoc(ctx, mu_bar, Sigma_bar, z, landmarks, Q, gate):
    return ctx.expect(ctx.call(mu_bar, Sigma_bar, z, landmarks, Q, gate), INDEX)


def _clear_case(rng, nonzero=False):
    """A belief, landmarks and a measurement whose nearest neighbour is unambiguous.

    The measurement comes from landmark ``k`` and ``k`` is the nearest neighbour;
    ``nonzero``: ``k >= 1``, so that a function returning a constant 0 cannot pass.
    """
    while True:
        mu_bar = random_pose(rng, extent=2.0)
        Sigma_bar = spd(rng, 3, scale=0.5, cond=50.0)
        K = int(rng.integers(3, 8))
        landmarks = mu_bar[:2] + rng.uniform(-6, 6, size=(K, 2))
        k = int(rng.integers(1 if nonzero else 0, K))
        z = sl.landmark_measurement(mu_bar + rng.normal(0, [0.3, 0.3, 0.1]), landmarks[k])[0]
        Q = spd(rng, 2, scale=0.1)
        d = sl.landmark_mahalanobis(mu_bar, Sigma_bar, z, landmarks, Q)
        ds = np.sort(d)
        if int(np.argmin(d)) == k and ds[1] > ds[0] * (1 + 1e-3) + 1e-6:
            return mu_bar, Sigma_bar, z, landmarks, Q


@EX.test("associate_ml", "nearest neighbour in Mahalanobis distance", weight=8,
         hint="For each landmark k: nu_k = z - h(mu_bar, m_k) (bearing wrapped), S_k = H_k Sigma_bar H_k^T + Q, "
              "d_k = nu_k^T S_k^-1 nu_k; return the k with the smallest d_k (not the largest likelihood, which "
              "also weighs det S_k).")
def _(ctx):
    for i in range(10):
        mu_bar, Sigma_bar, z, landmarks, Q = _clear_case(ctx.rng, nonzero=i % 2 == 0)
        got = _assoc(ctx, mu_bar, Sigma_bar, z, landmarks, Q, 1e6)
        want = sl.associate_ml(mu_bar, Sigma_bar, z, landmarks, Q, 1e6)
        if got != want:
            d = sl.landmark_mahalanobis(mu_bar, Sigma_bar, z, landmarks, Q)
            ctx.fail(f"returned {got}, expected {want}; the squared Mahalanobis distances are "
                     f"{np.array2string(d, precision=4)}")


@EX.test("associate_ml", "gate, equality at the gate and an empty map", weight=6,
         hint="Return -1 when the smallest distance exceeds gate or there are no landmarks; a distance equal to "
              "the gate still counts as a match. The gates here sit just below and above the smallest distance, so "
              "d_k = nu_k^T S_k^-1 nu_k must be exact: S_k = H_k Sigma_bar H_k^T + Q with H_k at mu_bar, and the "
              "bearing of nu_k wrapped.")
def _(ctx):
    # an exactly representable case: S = I and nu = (0.5, 0), so d = 0.25 exactly
    mu0, S0, Q0 = np.zeros(3), np.zeros((3, 3)), np.eye(2)
    lm0, z0 = np.array([[1.0, 0.0]]), np.array([1.5, 0.0])
    for gate in (0.25, 0.2499, 1.0):
        got = _assoc(ctx, mu0, S0, z0, lm0, Q0, gate)
        want = sl.associate_ml(mu0, S0, z0, lm0, Q0, gate)
        if got != want:
            ctx.fail(f"returned {got}, expected {want} (the distance is exactly 0.25, the gate {gate})")
    mu_bar, Sigma_bar, z, landmarks, Q = _clear_case(ctx.rng)
    got = _assoc(ctx, mu_bar, Sigma_bar, z, np.zeros((0, 2)), Q, 10.0)
    if got != -1:
        ctx.fail(f"returned {got} for an empty map (landmarks of shape (0, 2)), expected -1")
    _probe_gate(ctx, mu_bar, Sigma_bar, z, landmarks, Q)
    # a landmark straight behind the robot: the bearing innovation must be wrapped
    mu_bar = random_pose(ctx.rng, extent=2.0)
    ang = mu_bar[2] + np.pi + 1e-3
    landmarks = mu_bar[:2] + np.array([[3.0 * np.cos(ang), 3.0 * np.sin(ang)], [-4.0, 5.0]])
    z = np.array([3.05, np.pi - 2e-3])
    _probe_gate(ctx, mu_bar, spd(ctx.rng, 3, scale=0.3), z, landmarks, spd(ctx.rng, 2, scale=0.1))


def _probe_gate(ctx, mu_bar, Sigma_bar, z, landmarks, Q):
    """Gates just below and just above the smallest distance: the answer depends on its exact value."""
    d = sl.landmark_mahalanobis(mu_bar, Sigma_bar, z, landmarks, Q)
    for gate in (d.min() * (1 - 1e-6), d.min() * (1 + 1e-6)):
        got = _assoc(ctx, mu_bar, Sigma_bar, z, landmarks, Q, float(gate))
        want = sl.associate_ml(mu_bar, Sigma_bar, z, landmarks, Q, float(gate))
        if got != want:
            ctx.fail(f"returned {got}, expected {want}: the smallest squared Mahalanobis distance is "
                     f"{d.min():.10g} and the gate {gate:.10g} (the distances are {np.array2string(d, precision=6)})")


@EX.test("associate_ml", "ties go to the smallest index", weight=4, visibility="hidden",
         hint="When two landmarks are equally close, return the smaller index (np.argmin does).")
def _(ctx):
    for _ in range(3):
        mu_bar, Sigma_bar, z, landmarks, Q = _clear_case(ctx.rng, nonzero=True)
        best = sl.associate_ml(mu_bar, Sigma_bar, z, landmarks, Q, 1e6)
        dup = np.vstack([landmarks, landmarks[best], landmarks[best]])
        got = _assoc(ctx, mu_bar, Sigma_bar, z, dup, Q, 1e6)
        if got != best:
            ctx.fail(f"landmarks {best}, {len(landmarks)} and {len(landmarks) + 1} are identical and nearest; "
                     f"returned {got}, expected {best}")


@EX.test("associate_ml", "EKF localization with unknown correspondences", weight=7, visibility="hidden",
         hint="Plugged into EKF localization with unknown correspondences, your association must choose the "
              "same landmarks as the reference.")
def _(ctx):
    sc = loops.scenario("localization", ctx.rng)

    def associate(t, mu, Sigma, z, landmarks, Q, gate):
        got = _assoc(ctx, mu, Sigma, z, landmarks, Q, gate)
        want = sl.associate_ml(mu, Sigma, z, landmarks, Q, gate)
        if got != want:
            ctx.fail(f"at step {t}: returned {got}, expected {want}; the squared Mahalanobis distances are "
                     f"{np.array2string(sl.landmark_mahalanobis(mu, Sigma, z, landmarks, Q), precision=4)} "
                     f"(gate {gate:.4g})")
        return got

    try:
        traj, ids = loops.ekf_localization_loop(sc, known=False, associate=associate)
    except loops.LoopError as exc:
        ctx.fail(str(exc))
    ctx.last_call = None
    ref_traj, ref_ids = loops.reference("ekf_unknown", sc)
    agree = float(np.mean(np.array(ids) == np.array(ref_ids))) if len(ids) == len(ref_ids) else 0.0
    if agree < 0.98:
        ctx.fail(f"your associations agree with the reference's for {100 * agree:.1f} % of the measurements "
                 "(98 % needed)")
    loops.compare_ate(ctx, "EKF localization with unknown correspondences", traj, ref_traj, sc.run)
