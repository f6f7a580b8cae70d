"""Exercise 1: motion and sensor models (velocity and odometry models, landmarks, beam model)."""

from __future__ import annotations

import numpy as np

import slamlib as sl

from ..context import Out, RngSeed
from ..spec import Exercise
from ..stats import (P_THRESHOLD, odometry_independence_problem, odometry_ks_pvalues, odometry_moment_problem,
                     odometry_noise, odometry_repeated_noise_problem, odometry_variances)
from .common import check_fd, fd_jacobian, random_pose

EX = Exercise(
    "motion_sensor_models",
    "Motion and sensor models",
    notebook="01_motion_sensor_models.ipynb",
    functions={
        "velocity_motion": "(x, u, dt)",
        "sample_motion_model_odometry": "(x, u, alpha, *, rng)",
        "motion_model_odometry": "(x_next, u, x, alpha)",
        "landmark_measurement": "(x, m)",
        "landmark_from_measurement": "(x, z)",
        "beam_range_finder_model": "(z, z_star, *, z_max, sigma_hit, lambda_short, w_hit, w_short, w_max, w_rand)",
    },
)

X_NEXT, G_OUT, V_OUT = Out("x_next", (3,)), Out("G", (3, 3)), Out("V", (3, 2))


# =========================================================================== velocity_motion
def _vm_case(rng, *, omega=None, heading=None):
    x = random_pose(rng, heading=heading)
    v = rng.uniform(-1.0, 2.0)
    w = rng.choice([-1, 1]) * rng.uniform(0.05, 1.5) if omega is None else omega
    dt = rng.uniform(0.05, 1.0)
    return x, np.array([v, w]), float(dt)


def _sharp_turns(rng):
    """A left and a right sharp turn, ``|omega dt|`` in [1.2, 3] and ``v >= 0.5``: far from the series of small turns."""
    return [(random_pose(rng), np.array([rng.uniform(0.5, 2.0), s * rng.uniform(2.0, 3.0)]),
             float(rng.uniform(0.6, 1.0))) for s in (1.0, -1.0)]


def _vm(ctx, x, u, dt):
    return ctx.expect(ctx.call(x, u, dt), X_NEXT, G_OUT, V_OUT)


def _check_vm(ctx, x, u, dt):
    """Call velocity_motion and compare all three results with slamlib's."""
    x_next, G, V = _vm(ctx, x, u, dt)
    ref = sl.velocity_motion(x, u, dt)
    ctx.close("x_next", x_next, ref[0], atol=1e-9, rtol=1e-9, angles=[2])
    ctx.close("G", G, ref[1], atol=1e-8, rtol=1e-7)
    ctx.close("V", V, ref[2], atol=1e-8, rtol=1e-6)
    return x_next, G, V


@EX.test("velocity_motion", "arc motion on random poses and controls", weight=6,
         hint="x_next follows the exact arc of Table 5.3 without noise: x' = x - v/w sin(theta) + v/w sin(theta + w dt), "
              "y' = y + v/w cos(theta) - v/w cos(theta + w dt), theta' = wrap(theta + w dt).")
def _(ctx):
    for _ in range(8):
        x, u, dt = _vm_case(ctx.rng)
        x_next, _, _ = _vm(ctx, x, u, dt)
        ref = sl.velocity_motion(x, u, dt)
        ctx.close("x_next", x_next, ref[0], atol=1e-9, rtol=1e-9, angles=[2])


@EX.test("velocity_motion", "heading wrapped to [-pi, pi)", weight=3,
         hint="Wrap the new heading theta + omega dt to [-pi, pi), e.g. (a + pi) % (2 pi) - pi.")
def _(ctx):
    rng = ctx.rng
    cases = [(3.0, 1.0, 0.5), (-3.0, -1.2, 0.5), (np.pi - 1e-3, 0.4, 0.25), (-3.1, 6.0, 1.0)]
    # seeded cases across the cut as well: the heading before the step and theta + omega dt on either side of +-pi
    for s in (1.0, -1.0):
        th = s * (np.pi - rng.uniform(1e-3, 0.3))
        cases.append((th, s * rng.uniform(1.0, 3.0), float(rng.uniform(0.2, 0.6))))
    for th, w, dt in cases:
        x = np.array([rng.uniform(-5.0, 5.0), rng.uniform(-5.0, 5.0), th])
        u = np.array([rng.uniform(0.2, 1.5), w])
        x_next, _, _ = _vm(ctx, x, u, dt)
        ref = sl.velocity_motion(x, u, dt)
        ctx.wrapped("the heading x_next[2]", x_next[2])
        ctx.close("x_next", x_next, ref[0], atol=1e-9, rtol=1e-9, angles=[2])


@EX.test("velocity_motion", "Jacobian G = d x_next / d x", weight=4,
         hint="G is the identity except G[0, 2] = d x'/d theta and G[1, 2] = d y'/d theta (Table 7.2 line 3).")
def _(ctx):
    for _ in range(6):
        x, u, dt = _vm_case(ctx.rng)
        _, G, _ = _vm(ctx, x, u, dt)
        ref = sl.velocity_motion(x, u, dt)
        ctx.close("G", G, ref[1], atol=1e-8, rtol=1e-7)


@EX.test("velocity_motion", "Jacobian V = d x_next / d u", weight=4,
         hint="V holds the derivatives of (x', y', theta') with respect to v and omega (Table 7.2 line 4); "
              "the omega column needs the quotient rule on v/omega.")
def _(ctx):
    for x, u, dt in [_vm_case(ctx.rng) for _ in range(6)] + _sharp_turns(ctx.rng):
        _, _, V = _vm(ctx, x, u, dt)
        ref = sl.velocity_motion(x, u, dt)
        ctx.close("V", V, ref[2], atol=1e-8, rtol=1e-6)


@EX.test("velocity_motion", "straight-line limit (|omega| < 1e-6)", weight=3,
         hint="For abs(omega) < 1e-6 use the straight-line formulas of the contract instead of dividing by omega.")
def _(ctx):
    for w in (0.0, 5e-7, -1e-8, 0.0):
        x, u, dt = _vm_case(ctx.rng, omega=w)
        x_next, G, V = _vm(ctx, x, u, dt)
        ref = sl.velocity_motion(x, u, dt)
        ctx.close("x_next", x_next, ref[0], atol=1e-9, rtol=1e-9, angles=[2])
        ctx.close("G", G, ref[1], atol=1e-9, rtol=1e-9)
        ctx.close("V", V, ref[2], atol=1e-9, rtol=1e-9)


@EX.test("velocity_motion", "small turn rates (1e-6 <= |omega| < 1e-2)", weight=2, visibility="hidden",
         hint="Between 1e-6 and 1e-2 the arc formulas must still be used; V may lose some precision (1e-3 relative).")
def _(ctx):
    for w in (2e-6, -3e-5, 4e-3, -9e-3):
        x, u, dt = _vm_case(ctx.rng, omega=w)
        x_next, G, V = _vm(ctx, x, u, dt)
        ref = sl.velocity_motion(x, u, dt)
        ctx.close("x_next", x_next, ref[0], atol=1e-7, rtol=1e-7, angles=[2])
        ctx.close("G", G, ref[1], atol=1e-7, rtol=1e-7)
        scale = float(np.abs(ref[2]).max())
        ctx.close("V", V, ref[2], atol=1e-3 * scale, rtol=1e-3)


@EX.test("velocity_motion", "Jacobians match finite differences of your x_next", weight=3, visibility="hidden",
         hint="Your G and V disagree with the numerical derivatives of your own x_next: check signs and which "
              "angle (theta or theta + omega dt) each term uses.")
def _(ctx):
    for _ in range(3):
        x, u, dt = _vm_case(ctx.rng)
        _, G, V = _check_vm(ctx, x, u, dt)
        fx = fd_jacobian(lambda xx: _vm(ctx, xx, u, dt)[0], x, angle_out=[2])
        fu = fd_jacobian(lambda uu: _vm(ctx, x, uu, dt)[0], u, angle_out=[2])
        ctx.last_call = ctx.describe_call("velocity_motion", (x, u, dt), {})
        check_fd(ctx, "G", G, fx)
        check_fd(ctx, "V", V, fu)


# =========================================================================== sample_motion_model_odometry
def _odo_sample(ctx, x, u, alpha, seed, global_seed=None):
    ret = ctx.call_fn("sample_motion_model_odometry", (x, u, alpha), {"rng": RngSeed(seed)}, global_seed=global_seed)
    return ctx.expect(ret, Out("samples", x.shape))


@EX.test("sample_motion_model_odometry", "shape, dtype and wrapped headings", weight=3,
         hint="Return an (M, 3) float array with one sample per input pose, headings wrapped to [-pi, pi).")
def _(ctx):
    M = 500
    x = np.stack([random_pose(ctx.rng, heading=ctx.rng.uniform(2.8, 3.14)) for _ in range(M)])
    u = np.array([0.3, 1.2, 0.4])
    alpha = np.array([0.05, 0.01, 0.02, 0.01])
    out = _odo_sample(ctx, x, u, alpha, 11)
    ctx.wrapped("sampled headings", out[:, 2])
    _moment_check(ctx, x, out, u, alpha)


@EX.test("sample_motion_model_odometry", "no noise when alpha = 0", weight=4,
         hint="With alpha = 0 every sample is the noise-free odometry motion of Table 5.6 lines 5-7.")
def _(ctx):
    M = 50
    x = np.stack([random_pose(ctx.rng) for _ in range(M)])
    u = np.array([ctx.rng.uniform(-3, 3), ctx.rng.uniform(0.1, 2.0), ctx.rng.uniform(-3, 3)])
    alpha = np.zeros(4)
    out = _odo_sample(ctx, x, u, alpha, 12)
    ref = sl.sample_motion_model_odometry(x, u, alpha, rng=np.random.default_rng(12))
    ctx.close("samples", out, ref, atol=1e-9, rtol=1e-9, angles=[2])


def _moment_check(ctx, x, out, u, alpha):
    """The noise recovered from the samples has the contract's mean and variance (z-bound, see stats)."""
    problem = odometry_moment_problem(x, out, u, alpha)
    if problem:
        ctx.fail(problem)


def _ks_check(ctx, x, out, u, alpha):
    names = ("rot1", "trans", "rot2")
    pvals = odometry_ks_pvalues(x, out, u, alpha)
    noise = odometry_noise(x, out, u)
    var = odometry_variances(u, alpha)
    for name, p, d, v in zip(names, pvals, noise, var):
        if p < P_THRESHOLD:
            ctx.fail(f"the {name} noise recovered from your samples does not follow N(0, {v:.4g}) "
                     f"(Kolmogorov-Smirnov p-value {p:.2g} < {P_THRESHOLD:g}): its standard deviation is "
                     f"{np.std(d):.4g}, expected {np.sqrt(v):.4g}, and its mean {np.mean(d):.3g}, expected 0")


_KS_SCENARIOS = (
    (np.array([0.4, 2.5, -0.3]), np.array([0.05, 0.01, 0.02, 0.01])),
    (np.array([2.5, 0.5, 3.0]), np.array([0.2, 0.1, 0.004, 0.0002])),
)


@EX.test("sample_motion_model_odometry", "noise distribution of Table 5.6 (KS tests)", weight=5,
         hint="Each increment gets Gaussian noise whose VARIANCE is a1 rot1^2 + a2 trans^2 (rot1), "
              "a3 trans^2 + a4 (rot1^2 + rot2^2) (trans), a1 rot2^2 + a2 trans^2 (rot2): "
              "pass its square root as the standard deviation.")
def _(ctx):
    M = 20000
    for k, (u, alpha) in enumerate(_KS_SCENARIOS):
        x = np.tile(random_pose(ctx.rng), (M, 1))
        out = _odo_sample(ctx, x, u, alpha, 1000 + k)
        _ks_check(ctx, x, out, u, alpha)


#: The "three independent noises" scenario: standard deviations 0.24, 0.22, 0.27 (no wrap; trans 2.0 is 8.9 sd from 0).
_INDEPENDENCE_SCENARIO = (np.array([0.6, 2.0, -0.8]), np.array([0.05, 0.01, 0.01, 0.01]))


@EX.test("sample_motion_model_odometry", "three independent noises per pose", weight=3,
         hint="Draw the three noises of a pose independently (Table 5.6 samples each one on its own): three "
              "separate rng draws, never one standard normal scaled by the three standard deviations.")
def _(ctx):
    M = 20000
    u, alpha = _INDEPENDENCE_SCENARIO
    x = np.tile(random_pose(ctx.rng), (M, 1))
    out = _odo_sample(ctx, x, u, alpha, 3000)
    _moment_check(ctx, x, out, u, alpha)
    problem = odometry_independence_problem(x, out, u, alpha)
    if problem:
        ctx.fail(problem)


#: poses of the hidden "each pose moves with its own noise" test: a correct sampler's false alarm is
#: ``stats.repeated_noise_false_alarm(OWN_NOISE_POSES)`` (7e-14)
OWN_NOISE_POSES = 20000


@EX.test("sample_motion_model_odometry", "each pose moves with its own noise", weight=3, visibility="hidden",
         hint="Draw independent noise for every one of the M poses and apply it relative to that pose's heading.")
def _(ctx):
    M = OWN_NOISE_POSES
    x = np.stack([random_pose(ctx.rng) for _ in range(M)])
    u = np.array([-0.6, 0.8, 0.9])
    alpha = np.array([0.03, 0.02, 0.02, 0.005])
    out = _odo_sample(ctx, x, u, alpha, 2000)
    _ks_check(ctx, x, out, u, alpha)
    problem = odometry_repeated_noise_problem(x, out, u, alpha)
    if problem:
        ctx.fail(problem)


@EX.test("sample_motion_model_odometry", "draws only from rng", weight=2, visibility="hidden",
         hint="Use only the rng argument (rng.normal / rng.standard_normal), never np.random.* or the random module.")
def _(ctx):
    M = 200
    x = np.stack([random_pose(ctx.rng) for _ in range(M)])
    u = np.array([0.2, 0.9, -0.4])
    alpha = np.array([0.05, 0.01, 0.02, 0.01])
    a = _odo_sample(ctx, x, u, alpha, 77, global_seed=1)
    b = _odo_sample(ctx, x, u, alpha, 77, global_seed=2)
    if not np.array_equal(a, b):
        i = tuple(int(k) for k in np.argwhere(a != b)[0])
        ctx.fail("two calls with the same rng seed gave different samples: the function draws from a source "
                 f"other than rng (the global NumPy or Python random state); expected identical samples, got "
                 f"samples[{i[0]}, {i[1]}] = {a[i]:.6g} and {b[i]:.6g}")
    c = _odo_sample(ctx, x, u, alpha, 78, global_seed=1)
    if np.array_equal(a, c):
        ctx.fail("two calls with different rng seeds gave identical samples: the noise does not come from rng "
                 "(expected different samples for different seeds)")
    _moment_check(ctx, x, a, u, alpha)


# =========================================================================== motion_model_odometry
def _mmo(ctx, x_next, u, x, alpha):
    return ctx.expect(ctx.call(x_next, u, x, alpha), Out("p", (x.shape[0],)))


def _hypotheses(rng, M, u, spread, beyond=0):
    """M poses ``x`` and ``x_next`` reached by increments ``u + spread N(0, I)`` (translation kept positive).

    ``beyond``: the first ``beyond`` hypotheses turn by ``rot1`` and ``rot2`` just beyond
    ``+-pi`` on the sides of ``u[0]`` and ``u[2]``, so that ``u - [rot1_hat, rot2_hat]``
    (the hats wrapped) needs the wrap too.
    """
    x = np.stack([random_pose(rng) for _ in range(M)])
    inc = u + spread * rng.standard_normal((M, 3))
    inc[:, 1] = np.abs(inc[:, 1]) + 0.05
    if beyond:
        inc[:beyond, 0] = np.sign(u[0]) * (np.pi + rng.uniform(0.01, 0.15, beyond))
        inc[:beyond, 2] = np.sign(u[2]) * (np.pi + rng.uniform(0.01, 0.15, beyond))
    x_next = np.empty_like(x)
    x_next[:, 0] = x[:, 0] + inc[:, 1] * np.cos(x[:, 2] + inc[:, 0])
    x_next[:, 1] = x[:, 1] + inc[:, 1] * np.sin(x[:, 2] + inc[:, 0])
    x_next[:, 2] = np.mod(x[:, 2] + inc[:, 0] + inc[:, 2] + np.pi, 2 * np.pi) - np.pi
    return x, x_next


@EX.test("motion_model_odometry", "density on random hypotheses", weight=6,
         hint="Recover rot1_hat, trans_hat, rot2_hat from x -> x_next (Table 5.5 lines 5-7) and multiply the three "
              "normal densities (Table 5.2) of the differences, each with the variance evaluated at the hat values.")
def _(ctx):
    for _ in range(3):
        u = np.array([ctx.rng.uniform(-1.5, 1.5), ctx.rng.uniform(0.3, 2.0), ctx.rng.uniform(-1.5, 1.5)])
        alpha = ctx.rng.uniform(0.01, 0.2, size=4)
        x, x_next = _hypotheses(ctx.rng, 50, u, 0.15)
        p = _mmo(ctx, x_next, u, x, alpha)
        ref = sl.motion_model_odometry(x_next, u, x, alpha)
        ctx.close("density", p, ref, atol=1e-12 * float(ref.max()), rtol=1e-6)


@EX.test("motion_model_odometry", "angle differences wrapped", weight=4,
         hint="Wrap rot1 - rot1_hat and rot2 - rot2_hat to [-pi, pi) before evaluating their densities.")
def _(ctx):
    u = np.array([3.05, 1.0, -3.05])
    alpha = np.array([0.05, 0.02, 0.05, 0.01])
    x, x_next = _hypotheses(ctx.rng, 40, u, 0.1, beyond=8)
    p = _mmo(ctx, x_next, u, x, alpha)
    ref = sl.motion_model_odometry(x_next, u, x, alpha)
    ctx.close("density", p, ref, atol=1e-12 * float(ref.max()), rtol=1e-6)


@EX.test("motion_model_odometry", "variances at the hypothesis increments", weight=5, visibility="hidden",
         hint="Table 5.5 evaluates the variances at the increments recovered from x -> x_next (the hat values), "
              "not at the control u.")
def _(ctx):
    u = np.array([0.1, 0.4, -0.1])
    alpha = np.array([0.3, 0.2, 0.3, 0.2])
    x, x_next = _hypotheses(ctx.rng, 60, u, 0.6)
    p = _mmo(ctx, x_next, u, x, alpha)
    ref = sl.motion_model_odometry(x_next, u, x, alpha)
    ctx.close("density", p, ref, atol=1e-12 * float(ref.max()), rtol=1e-6)


# =========================================================================== landmark_measurement
Z_HAT, HX_OUT, HM_OUT = Out("z_hat", (2,)), Out("Hx", (2, 3)), Out("Hm", (2, 2))


def _lm_cases(rng, n):
    cases = []
    for _ in range(n):
        x = random_pose(rng)
        m = x[:2] + rng.uniform(0.5, 6.0) * np.array([np.cos(a := rng.uniform(-np.pi, np.pi)), np.sin(a)])
        cases.append((x, m))
    # landmarks straight behind the robot: the bearing sits at +-pi
    cases.append((np.array([0.0, 0.0, 0.0]), np.array([-4.0, 1e-3])))
    cases.append((np.array([0.0, 0.0, 0.0]), np.array([-4.0, -1e-3])))
    cases.append((np.array([1.0, 2.0, 3.0]), np.array([-2.0, 2.5])))
    return cases


def _across_cases(rng):
    """Two poses and landmarks whose unwrapped bearing atan2(dy, dx) - theta lies below -pi, then above +pi.

    The heading and the landmark's direction have opposite signs and magnitudes in
    [2, 3], so the unwrapped bearing is -+[4, 6]: it needs the wrap, and wraps to
    +-[0.28, 2.28], far from the cut.
    """
    cases = []
    for s in (1.0, -1.0):
        x = random_pose(rng, heading=s * rng.uniform(2.0, 3.0))
        a = -s * rng.uniform(2.0, 3.0)
        cases.append((x, x[:2] + rng.uniform(0.5, 6.0) * np.array([np.cos(a), np.sin(a)])))
    return cases


def _lm(ctx, x, m):
    return ctx.expect(ctx.call(x, m), Z_HAT, HX_OUT, HM_OUT)


@EX.test("landmark_measurement", "expected measurement z_hat", weight=5,
         hint="z_hat = [sqrt(q), wrap(atan2(m_y - y, m_x - x) - theta)] with q = dx^2 + dy^2 (Eq. 6.40).")
def _(ctx):
    for x, m in _lm_cases(ctx.rng, 8) + _across_cases(ctx.rng):
        z, _, _ = _lm(ctx, x, m)
        ref = sl.landmark_measurement(x, m)
        ctx.wrapped("the bearing z_hat[1]", z[1])
        ctx.close("z_hat", z, ref[0], atol=1e-9, rtol=1e-9, angles=[1])


@EX.test("landmark_measurement", "Jacobian Hx with respect to the pose", weight=4,
         hint="Hx = [[-dx/r, -dy/r, 0], [dy/q, -dx/q, -1]] (Table 7.2 line 13).")
def _(ctx):
    for x, m in _lm_cases(ctx.rng, 6):
        _, Hx, _ = _lm(ctx, x, m)
        ref = sl.landmark_measurement(x, m)
        ctx.close("Hx", Hx, ref[1], atol=1e-9, rtol=1e-7)


@EX.test("landmark_measurement", "Jacobian Hm with respect to the landmark", weight=3,
         hint="Hm = d z_hat / d m is minus the position columns of Hx: [[dx/r, dy/r], [-dy/q, dx/q]].")
def _(ctx):
    for x, m in _lm_cases(ctx.rng, 6):
        _, _, Hm = _lm(ctx, x, m)
        ref = sl.landmark_measurement(x, m)
        ctx.close("Hm", Hm, ref[2], atol=1e-9, rtol=1e-7)


@EX.test("landmark_measurement", "Jacobians match finite differences of your z_hat", weight=3, visibility="hidden",
         hint="Your Jacobians disagree with the numerical derivatives of your own z_hat.")
def _(ctx):
    for x, m in _lm_cases(ctx.rng, 3)[:3]:
        z, Hx, Hm = _lm(ctx, x, m)
        ref = sl.landmark_measurement(x, m)
        ctx.close("z_hat", z, ref[0], atol=1e-9, rtol=1e-9, angles=[1])
        ctx.close("Hx", Hx, ref[1], atol=1e-9, rtol=1e-7)
        ctx.close("Hm", Hm, ref[2], atol=1e-9, rtol=1e-7)
        fx = fd_jacobian(lambda xx: _lm(ctx, xx, m)[0], x, angle_out=[1])
        fm = fd_jacobian(lambda mm: _lm(ctx, x, mm)[0], m, angle_out=[1])
        ctx.last_call = ctx.describe_call("landmark_measurement", (x, m), {})
        check_fd(ctx, "Hx", Hx, fx)
        check_fd(ctx, "Hm", Hm, fm)


# =========================================================================== landmark_from_measurement
def _lfm(ctx, x, z):
    return ctx.expect(ctx.call(x, z), Out("m", (2,)))


@EX.test("landmark_from_measurement", "landmark position from pose and measurement", weight=6,
         hint="m = [x + r cos(theta + phi), y + r sin(theta + phi)] (the inverse of Eq. 6.40).")
def _(ctx):
    for _ in range(8):
        x = random_pose(ctx.rng)
        z = np.array([ctx.rng.uniform(0.2, 8.0), ctx.rng.uniform(-np.pi, np.pi)])
        m = _lfm(ctx, x, z)
        ctx.close("m", m, sl.landmark_from_measurement(x, z), atol=1e-9, rtol=1e-9)


@EX.test("landmark_from_measurement", "inverse of landmark_measurement (round trip)", weight=4, visibility="hidden",
         hint="Measuring the landmark you return from x must give back z.")
def _(ctx):
    for _ in range(6):
        x = random_pose(ctx.rng)
        m_true = ctx.rng.uniform(-8, 8, size=2)
        z = sl.landmark_measurement(x, m_true)[0]
        m = _lfm(ctx, x, z)
        ctx.close("m", m, m_true, atol=1e-9, rtol=1e-9)


# =========================================================================== beam_range_finder_model
def _beam_params(rng):
    w = rng.dirichlet([4.0, 2.0, 1.0, 1.0])
    return {"z_max": float(rng.uniform(8.0, 12.0)), "sigma_hit": float(rng.uniform(0.1, 0.6)),
            "lambda_short": float(rng.uniform(0.2, 1.5)), "w_hit": float(w[0]), "w_short": float(w[1]),
            "w_max": float(w[2]), "w_rand": float(w[3])}


def _beam(ctx, z, z_star, params):
    return ctx.expect(ctx.call(z, z_star, **params), Out("p", z.shape))


@EX.test("beam_range_finder_model", "mixture on random beams", weight=6,
         hint="p = w_hit p_hit + w_short p_short + w_max p_max + w_rand p_rand (Table 6.1 line 5, Eqs. 6.4-6.10).")
def _(ctx):
    for _ in range(3):
        params = _beam_params(ctx.rng)
        zm = params["z_max"]
        K = 60
        z_star = ctx.rng.uniform(0.5, zm, size=K)
        z = np.clip(z_star + ctx.rng.normal(0, 1.0, size=K), 0.0, zm - 1e-3)
        z[:6] = ctx.rng.uniform(0, zm, size=6)
        p = _beam(ctx, z, z_star, params)
        ctx.close("p", p, sl.beam_range_finder_model(z, z_star, **params), atol=1e-12, rtol=1e-9)


@EX.test("beam_range_finder_model", "truncated normal near 0 and z_max", weight=3,
         hint="p_hit is N(z; z_star, sigma_hit^2) divided by its mass on [0, z_max], "
              "eta^-1 = Phi((z_max - z_star)/sigma) - Phi(-z_star/sigma).")
def _(ctx):
    params = _beam_params(ctx.rng)
    params["sigma_hit"] = 1.0
    zm = params["z_max"]
    z = np.linspace(0.0, zm - 1e-2, 25)
    for zs in (0.05, zm - 0.05, 0.5 * zm):
        z_star = np.full(z.shape, zs)
        p = _beam(ctx, z, z_star, params)
        ctx.close("p", p, sl.beam_range_finder_model(z, z_star, **params), atol=1e-12, rtol=1e-9)


@EX.test("beam_range_finder_model", "boundaries: z = 0, z = z_star, z = z_max", weight=3,
         hint="p_short is non-zero on the closed interval [0, z_star]; p_max = 1 for z >= z_max; "
              "p_rand = 1/z_max on [0, z_max) only; p_hit is non-zero on [0, z_max] only (0 beyond z_max).")
def _(ctx):
    params = _beam_params(ctx.rng)
    zm = params["z_max"]
    z_star = np.array([3.0, 3.0, 3.0, 3.0, zm, zm * 0.5, zm - 0.05])
    z = np.array([0.0, 3.0, zm, zm + 0.5, zm, zm * 0.5, zm + 0.05])
    p = _beam(ctx, z, z_star, params)
    ctx.close("p", p, sl.beam_range_finder_model(z, z_star, **params), atol=1e-12, rtol=1e-9)


@EX.test("beam_range_finder_model", "density integrates to the weights", weight=3, visibility="hidden",
         hint="With all weights given, the integral of p over [0, z_max) must be w_hit + w_short + w_rand "
              "(the point mass w_max sits at z_max).")
def _(ctx):
    params = _beam_params(ctx.rng)
    zm = params["z_max"]
    z = np.linspace(0.0, zm, 40001)[:-1]
    z_star = np.full(z.shape, 0.6 * zm)
    p = _beam(ctx, z, z_star, params)
    ctx.close("p", p, sl.beam_range_finder_model(z, z_star, **params), atol=1e-12, rtol=1e-9)
    integral = float(np.sum(0.5 * (p[1:] + p[:-1]) * np.diff(z)))
    want = params["w_hit"] + params["w_short"] + params["w_rand"]
    if abs(integral - want) > 2e-3:
        ctx.fail(f"the density integrates to {integral:.5f} over [0, z_max), expected {want:.5f}")
