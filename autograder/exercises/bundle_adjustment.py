"""Exercise 7: rotations, the pinhole camera, two-view geometry and the Schur complement of bundle adjustment.

Scenes are drawn from the test's generator: cameras on an arc around a cloud of
points, all looking at it (every point in front of every camera), pixels with
noise, initial guesses perturbed from the truth. The end-to-end tests plug the
student's function into slamlib's own drivers: bundle adjustment
(:func:`slamlib.bundle_adjust` with ``project=``, ``so3_exp=``,
``schur_complement=`` / ``back_substitute=``) and the two-view reconstruction
(:func:`slamlib.two_view_reconstruction` with ``eight_point=`` and
``triangulate=``, RANSAC drawing from a generator seeded by the test), and every
call inside them is compared with slamlib on that call's inputs first.
"""

from __future__ import annotations

import numpy as np

import slamlib as sl

from ..context import Fail, Out
from ..spec import Exercise
from .common import check_fd

EX = Exercise(
    "bundle_adjustment",
    "Cameras, two-view geometry and bundle adjustment",
    notebook="07_bundle_adjustment.ipynb",
    functions={
        "so3_exp": "(w)",
        "so3_log": "(R)",
        "project": "(K, T_wc, P)",
        "triangulate": "(K, T_wc1, T_wc2, uv1, uv2)",
        "eight_point": "(x1, x2)",
        "schur_complement": "(H, b, n_cameras)",
        "back_substitute": "(H, b, n_cameras, dx_cameras)",
    },
)


# =========================================================================== scenarios
def _unit(rng):
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def _calibration(rng):
    f = rng.uniform(400.0, 900.0)
    return sl.calibration_matrix(f * rng.uniform(0.95, 1.05), f, rng.uniform(250.0, 400.0), rng.uniform(180.0, 300.0))


def _look_at(centre, target, rng):
    """A camera pose at `centre` whose z axis points at `target` (a random roll)."""
    z = target - centre
    z = z / np.linalg.norm(z)
    x = np.cross(_unit(rng) * 0.2 + np.array([0.0, -1.0, 0.0]), z)
    x = x / np.linalg.norm(x)
    return sl.pose_matrix(np.column_stack([x, np.cross(z, x), z]), centre)


def _scene(rng, n_cam=3, n_pt=12, radius=8.0, spread=1.5):
    """``(K, T_wc (C, 4, 4), P (N, 3))``: cameras on an arc around a cloud of points, all in front."""
    K = _calibration(rng)
    target = rng.uniform(-3.0, 3.0, 3)
    P = target + rng.uniform(-spread, spread, (n_pt, 3))
    a0 = rng.uniform(-np.pi, np.pi)
    Ts = []
    for c in range(n_cam):
        a = a0 + 0.35 * c + rng.uniform(-0.05, 0.05)
        centre = target + radius * np.array([np.cos(a), rng.uniform(-0.2, 0.2), np.sin(a)])
        Ts.append(_look_at(centre, target + rng.normal(0.0, 0.3, 3), rng))
    return K, np.stack(Ts), P


def _perturb(T, d):
    R, t = T[:3, :3], T[:3, 3]
    return sl.pose_matrix(R @ sl.so3_exp(d[3:]), t + R @ d[:3])


def _observations(K, T, P, rng, noise=0.5):
    cam = np.repeat(np.arange(len(T)), len(P))
    point = np.tile(np.arange(len(P)), len(T))
    uv = np.concatenate([sl.project(K, Tc, P)[0] for Tc in T]) + rng.normal(0.0, noise, (len(cam), 2))
    return cam, point, uv


def _ba_problem(rng, n_cam=3, n_pt=12):
    """A bundle-adjustment problem with a perturbed initial guess: ``(T0, P0, K, cam, point, uv)``."""
    K, T, P = _scene(rng, n_cam, n_pt)
    cam, point, uv = _observations(K, T, P, rng)
    T0 = np.stack([T[0]] + [_perturb(Tc, np.r_[rng.normal(0, 0.05, 3), rng.normal(0, 0.01, 3)]) for Tc in T[1:]])
    P0 = P + rng.normal(0.0, 0.05, P.shape)
    return T0, P0, K, cam, point, uv


def _normal_equations(rng, n_cam=3, n_pt=10):
    """``(H, b)`` of a bundle-adjustment problem: ``J^T J`` plus LM damping, ``J^T e``, cameras first."""
    T0, P0, K, cam, point, uv = _ba_problem(rng, n_cam, n_pt)
    n = 6 * n_cam + 3 * n_pt
    J = np.zeros((2 * len(cam), n))
    e = np.zeros(2 * len(cam))
    for k, (c, p) in enumerate(zip(cam, point)):
        u, A, B = sl.project(K, T0[c], P0[p:p + 1])
        J[2 * k:2 * k + 2, 6 * c:6 * c + 6] = A[0]
        J[2 * k:2 * k + 2, 6 * n_cam + 3 * p:6 * n_cam + 3 * p + 3] = B[0]
        e[2 * k:2 * k + 2] = u[0] - uv[k]
    H = J.T @ J
    H = H + rng.uniform(1e-3, 1e-1) * np.mean(np.diag(H)) * np.eye(n)
    return 0.5 * (H + H.T), J.T @ e


def _in(ctx, what, k, fn):
    """Run one step of an end-to-end loop; a failure names the step."""
    try:
        return fn()
    except Fail as exc:
        raise Fail(f"{what} {k}: {exc}") from None


class _Counter:
    def __init__(self):
        self.n = 0

    def __call__(self):
        self.n += 1
        return self.n


def _e2e_ba(ctx, what, problem, **hooks):
    """Bundle adjustment through slamlib's driver with the hooks; poses, points and cost per iteration compared."""
    T0, P0, K, cam, point, uv = problem
    kw = dict(max_iter=5, rtol=0.0)  # five iterations whatever the rounding
    try:
        got = sl.bundle_adjust(T0, P0, K, cam, point, uv, **kw, **hooks)
    except (ValueError, TypeError, np.linalg.LinAlgError) as exc:
        ctx.fail(f"{what}: bundle adjustment could not use your result ({exc})")
    ctx.last_call = None
    ref = sl.bundle_adjust(T0, P0, K, cam, point, uv, **kw)
    ctx.close(f"{what}: the cost per iteration", got.cost, ref.cost, atol=1e-8, rtol=1e-6)
    ctx.close(f"{what}: the adjusted camera poses", got.T_wc, ref.T_wc, atol=1e-7, rtol=1e-6)
    ctx.close(f"{what}: the adjusted points", got.points, ref.points, atol=1e-7, rtol=1e-6)
    if not got.cost[-1] < 0.5 * got.cost[0]:
        ctx.fail(f"{what}: the reprojection cost went from {got.cost[0]:.4g} to only {got.cost[-1]:.4g}")


def _e2e_ba_with(ctx, hook, step, check, **others):
    """:func:`_e2e_ba` on a fresh problem with the student's function as hook ``hook``, each call checked first."""
    problem = _ba_problem(ctx.rng, n_cam=3, n_pt=10)
    count = _Counter()

    def plugged(*args):
        return _in(ctx, step, count(), lambda: check(ctx, *args))

    _e2e_ba(ctx, f"bundle adjustment with your {ctx.function}", problem, **{hook: plugged}, **others)


# =========================================================================== so3_exp
def _check_exp(ctx, w, *, small=False):
    """Call so3_exp and compare R with slamlib's (R - I relative to |w| for small angles)."""
    R = ctx.expect(ctx.call(w), Out("R", (3, 3)))
    ref = sl.so3_exp(w)
    a = float(np.linalg.norm(w))
    if small:
        ctx.close("R - I", R - np.eye(3), ref - np.eye(3), atol=1e-9 * a + 1e-300, rtol=1e-9,
                  note=f"(|w| = {a:.3g}: R - I must be accurate relative to |w|)")
    else:
        ctx.close("R", R, ref, atol=1e-11, rtol=1e-10)
    return R


@EX.test("so3_exp", "rotations of random rotation vectors", weight=6,
         hint="Exp(w) = I + sin(a)/a [w]x + (1 - cos a)/a^2 [w]x^2 with a = |w| and [w]x v = w x v (Rodrigues' formula).")
def _(ctx):
    for a in (0.3, 1.0, 2.0, 3.0, np.pi - 1e-3):
        _check_exp(ctx, a * ctx.rng.uniform(0.9, 1.0) * _unit(ctx.rng))
    _check_exp(ctx, ctx.rng.uniform(3.5, 6.0) * _unit(ctx.rng))


@EX.test("so3_exp", "w = 0 and tiny angles", weight=4,
         hint="At w = 0 return the identity (no 0/0); near 0 use the series sin(a)/a = 1 - a^2/6 + ..., "
              "(1 - cos a)/a^2 = 1/2 - a^2/24 + ..., or the form 2 sin^2(a/2)/a^2 that has no cancellation.")
def _(ctx):
    _check_exp(ctx, np.zeros(3), small=False)
    for a in (1e-12, 1e-8, 1e-6, 1e-4):
        _check_exp(ctx, a * ctx.rng.uniform(0.5, 1.0) * _unit(ctx.rng), small=True)


@EX.test("so3_exp", "bundle adjustment with your so3_exp", weight=4, visibility="hidden",
         hint="Plugged into the pose update T (+) delta = (R Exp(phi), t + R rho) of slamlib's bundle adjustment, "
              "your Exp must lead to the reference's cameras and points.")
def _(ctx):
    _e2e_ba_with(ctx, "so3_exp", "pose update", _check_exp)


# =========================================================================== so3_log
def _check_log(ctx, R, *, either_sign=False, small=None):
    """Call so3_log and compare w with slamlib's (up to sign at |w| = pi; relative to |w| when small)."""
    w = ctx.expect(ctx.call(R), Out("w", (3,)))
    ref = sl.so3_log(R)
    if either_sign and float(np.dot(w, ref)) < 0:
        ref = -ref
    if small is not None:
        ctx.close("w", w, ref, atol=1e-9 * small + 1e-300, rtol=1e-9,
                  note=f"(|w| = {small:.3g}: w must be accurate relative to |w|)")
    else:
        ctx.close("w", w, ref, atol=1e-9, rtol=1e-9)
    if np.linalg.norm(w) > np.pi + 1e-12:
        ctx.fail(f"|w| = {np.linalg.norm(w):.15f} exceeds pi")
    return w


@EX.test("so3_log", "rotation vectors of random rotations", weight=6,
         hint="The angle a = atan2(|vee(R - R^T)| / 2, (tr R - 1) / 2) and the axis from vee(R - R^T) / (2 sin a), "
              "w = a axis, |w| <= pi.")
def _(ctx):
    for a in (0.2, 0.9, 1.6, 2.4, 3.0):
        _check_log(ctx, sl.so3_exp(a * _unit(ctx.rng)))


@EX.test("so3_log", "the identity and tiny angles", weight=3,
         hint="R = I gives w = 0; for small angles arccos((tr R - 1)/2) loses the angle to rounding: use atan2 "
              "with vee(R - R^T), and a / sin(a) -> 1.")
def _(ctx):
    _check_log(ctx, np.eye(3))
    for a in (1e-9, 1e-6, 1e-4):
        a = a * ctx.rng.uniform(0.5, 1.0)
        _check_log(ctx, sl.so3_exp(a * _unit(ctx.rng)), small=a)


@EX.test("so3_log", "angles at and near pi", weight=5,
         hint="Near a = pi, sin a ~ 0: take the axis from the symmetric part, (R + R^T)/2 - cos(a) I = (1 - cos a) "
              "n n^T (the column of the largest diagonal entry), and its sign from vee(R - R^T).")
def _(ctx):
    for d in (1e-3, 1e-6, 5e-10):
        _check_log(ctx, sl.so3_exp((np.pi - d * ctx.rng.uniform(0.5, 1.0)) * _unit(ctx.rng)))
    # about a coordinate axis (two components of the axis exactly 0), either way round
    k = int(ctx.rng.integers(3))
    for sign in (1.0, -1.0):
        _check_log(ctx, sl.so3_exp(sign * (np.pi - ctx.rng.uniform(1e-4, 1e-2)) * np.eye(3)[k]))
    n = _unit(ctx.rng)
    _check_log(ctx, 2.0 * np.outer(n, n) - np.eye(3), either_sign=True)  # a half turn: R symmetric


# =========================================================================== project
def _check_project(ctx, K, T, P):
    """Call project and compare uv, J_pose and J_point with slamlib's."""
    n = len(P)
    uv, Jp, Jx = ctx.expect(ctx.call(K, T, P), Out("uv", (n, 2)), Out("J_pose", (n, 2, 6)), Out("J_point", (n, 2, 3)))
    ref = sl.project(K, T, P)
    ctx.close("uv", uv, ref[0], atol=1e-8, rtol=1e-10)
    ctx.close("J_pose", Jp, ref[1], atol=1e-8, rtol=1e-8)
    ctx.close("J_point", Jx, ref[2], atol=1e-8, rtol=1e-8)
    return uv, Jp, Jx


@EX.test("project", "pixels and Jacobians of random scenes", weight=8,
         hint="p_c = R^T (P - t); uv = [fx X/Z + cx, fy Y/Z + cy]; with D = d uv / d p_c = [[fx/Z, 0, -fx X/Z^2], "
              "[0, fy/Z, -fy Y/Z^2]]: J_point = D R^T, J_pose = D [-I, [p_c]x] for T (+) [rho, phi] = "
              "(R Exp(phi), t + R rho).")
def _(ctx):
    for n in (1, 5, 12):
        K, T, P = _scene(ctx.rng, n_cam=2, n_pt=n)
        _check_project(ctx, K, T[ctx.rng.integers(2)], P)


@EX.test("project", "J_pose and J_point match finite differences of your uv", weight=4, visibility="hidden",
         hint="Your Jacobians disagree with numerical derivatives of your own uv: perturb the pose as "
              "(R Exp(phi), t + R rho), translation first.")
def _(ctx):
    K, T, P = _scene(ctx.rng, n_cam=1, n_pt=3)
    T = T[0]
    _, Jp, Jx = _check_project(ctx, K, T, P)
    h = 1e-6
    num_p = np.stack([(_check_project(ctx, K, _perturb(T, h * e), P)[0] - _check_project(ctx, K, _perturb(T, -h * e), P)[0])
                      / (2 * h) for e in np.eye(6)], axis=-1)
    num_x = np.stack([(_check_project(ctx, K, T, P + h * e)[0] - _check_project(ctx, K, T, P - h * e)[0]) / (2 * h)
                      for e in np.eye(3)], axis=-1)
    ctx.last_call = ctx.describe_call("project", (K, T, P), {})
    check_fd(ctx, "J_pose", Jp, num_p, atol=1e-4, rtol=1e-5)
    check_fd(ctx, "J_point", Jx, num_x, atol=1e-4, rtol=1e-5)


@EX.test("project", "bundle adjustment with your project", weight=4, visibility="hidden",
         hint="Plugged into slamlib's bundle adjustment (called once per camera and iteration), your pixels and "
              "Jacobians must lead to the reference's cameras and points.")
def _(ctx):
    _e2e_ba_with(ctx, "project", "projection", _check_project)


# =========================================================================== triangulate
def _check_tri(ctx, K, T1, T2, uv1, uv2, *, scale=10.0):
    """Call triangulate and compare the points with slamlib's."""
    P = ctx.expect(ctx.call(K, T1, T2, uv1, uv2), Out("P", (len(uv1), 3)))
    ref = sl.triangulate(K, T1, T2, uv1, uv2)
    ctx.close("P", P, ref, atol=1e-8 * scale, rtol=1e-7)
    return P


def _two_views(ctx, n, noise, spread=1.5):
    K, T, P = _scene(ctx.rng, n_cam=2, n_pt=n, radius=7.0, spread=spread)
    uv1 = sl.project(K, T[0], P)[0] + ctx.rng.normal(0.0, noise, (n, 2))
    uv2 = sl.project(K, T[1], P)[0] + ctx.rng.normal(0.0, noise, (n, 2))
    return K, T[0], T[1], uv1, uv2


@EX.test("triangulate", "exact pixels of random scenes", weight=6,
         hint="For each match stack the rows u1 p_1^3 - p_1^1, v1 p_1^3 - p_1^2, u2 p_2^3 - p_2^1, v2 p_2^3 - p_2^2 "
              "of P_k = K [R_k^T, -R_k^T t_k] (Hartley & Zisserman, Sec. 12.2); take the last right singular vector "
              "and divide by its 4th entry.")
def _(ctx):
    for n in (1, 6, 15):
        _check_tri(ctx, *_two_views(ctx, n, 0.0))


@EX.test("triangulate", "noisy pixels: the DLT in pixel rows", weight=5,
         hint="On noisy matches the answer depends on how the rows are scaled: use the rows in pixels exactly as "
              "written (do not normalise them or apply K^-1 first).")
def _(ctx):
    for n, noise in ((8, 1.0), (12, 3.0)):
        _check_tri(ctx, *_two_views(ctx, n, noise))


def _two_view_case(ctx, n=40, outliers=4, noise=0.2):
    """Matched pixels of a random two-view scene (a wide one) with a few outliers: ``(K, uv1, uv2)``."""
    K, T1, T2, uv1, uv2 = _two_views(ctx, n, noise, spread=3.0)
    idx = ctx.rng.choice(n, outliers, replace=False)
    uv2 = uv2.copy()
    uv2[idx] += ctx.rng.uniform(30.0, 80.0, (outliers, 2)) * ctx.rng.choice([-1.0, 1.0], (outliers, 2))
    return K, uv1, uv2


def _e2e_two_view(ctx, hook, step, check):
    """Two-view reconstruction through slamlib's driver with the student's function as hook ``hook``.

    Each call is checked first; then the inliers, pose and points are compared with the
    reference run's. The case is redrawn (at most 10 times) until the reference
    reconstruction succeeds on it.
    """
    what = f"two-view reconstruction with your {ctx.function}"
    count = _Counter()

    def plugged(*args):
        return _in(ctx, step, count(), lambda: check(ctx, *args))

    hooks = {hook: plugged}
    kw = dict(threshold=1.5, confidence=0.99, max_iter=100)
    for _ in range(10):
        K, uv1, uv2 = _two_view_case(ctx)
        seed = int(ctx.rng.integers(2**31))
        try:
            ref = sl.two_view_reconstruction(K, uv1, uv2, rng=np.random.default_rng(seed), **kw)
        except ValueError:
            continue
        if len(ref.inliers) >= 20:
            break
    try:
        got = sl.two_view_reconstruction(K, uv1, uv2, rng=np.random.default_rng(seed), **kw, **hooks)
    except (ValueError, TypeError, np.linalg.LinAlgError) as exc:
        ctx.fail(f"{what}: the reconstruction could not use your result ({exc})")
    ctx.last_call = None
    ctx.equal(f"{what}: the inliers in front of both cameras", got.inliers, ref.inliers)
    ctx.close(f"{what}: the relative pose", got.T_wc2, ref.T_wc2, atol=1e-6, rtol=1e-6)
    ctx.close(f"{what}: the points", got.points, ref.points, atol=1e-6, rtol=1e-6)


@EX.test("triangulate", "two-view reconstruction with your triangulate", weight=4, visibility="hidden",
         hint="Plugged into slamlib's two-view reconstruction (RANSAC, pose recovery, then your triangulation of the "
              "inliers), your points must be the reference's.")
def _(ctx):
    _e2e_two_view(ctx, "triangulate", "triangulation", lambda c, *a: _check_tri(c, *a, scale=1.0))


# =========================================================================== eight_point
def _check_eight(ctx, x1, x2):
    """Call eight_point and compare E with slamlib's up to sign."""
    E = ctx.expect(ctx.call(x1, x2), Out("E", (3, 3)))
    ref = sl.eight_point(x1, x2)
    if float(np.sum(E * ref)) < 0:
        ref = -ref
    ctx.close("E (up to sign)", E, ref, atol=1e-6, rtol=1e-6)
    return E


def _normalized_matches(ctx, n, noise, shift=0.0):
    K, T1, T2, uv1, uv2 = _two_views(ctx, n, noise)
    x1 = sl.to_normalized(K, uv1)
    x2 = sl.to_normalized(K, uv2)
    return x1 + shift, x2 - shift


@EX.test("eight_point", "exact and noisy matches", weight=7,
         hint="Hartley-normalise each set (centroid to 0, mean distance sqrt(2)), one row [x2 x1, x2 y1, x2, y2 x1, "
              "y2 y1, y2, x1, y1, 1] per match, F = last right singular vector read row by row, E = T2^T F T1, then "
              "E = U diag(1, 1, 0) V^T (Hartley & Zisserman, Algorithm 11.1).")
def _(ctx):
    for n, noise in ((8, 0.0), (20, 0.0), (30, 0.5), (60, 2.0)):
        _check_eight(ctx, *_normalized_matches(ctx, n, noise))


@EX.test("eight_point", "matches far from the origin (the normalisation matters)", weight=5,
         hint="Translate each set so that its centroid is at the origin and scale it so that the mean distance to "
              "the origin is sqrt(2), before the SVD; undo it with E = T2^T F T1.")
def _(ctx):
    for shift in (2.0, -5.0):
        _check_eight(ctx, *_normalized_matches(ctx, 25, 1.0, shift=shift))


@EX.test("eight_point", "two-view reconstruction with your eight_point", weight=4, visibility="hidden",
         hint="Plugged into RANSAC (each sample of 8 and the refit on the inliers), your essential matrices must "
              "lead to the reference's inliers, pose and points.")
def _(ctx):
    _e2e_two_view(ctx, "eight_point", "eight-point fit", _check_eight)


# =========================================================================== schur_complement
def _check_schur(ctx, H, b, C):
    """Call schur_complement and compare S and s with slamlib's."""
    S, s = ctx.expect(ctx.call(H, b, C), Out("S", (6 * C, 6 * C)), Out("s", (6 * C,)))
    Sr, sr = sl.schur_complement(H, b, C)
    ctx.close("S", S, Sr, atol=1e-9 * max(1.0, float(np.abs(Sr).max())), rtol=1e-7)
    ctx.close("s", s, sr, atol=1e-9 * max(1.0, float(np.abs(sr).max())), rtol=1e-7)
    return S, s


@EX.test("schur_complement", "reduced camera systems of random problems", weight=8,
         hint="S = H_cc - H_cp H_pp^-1 H_pc and s = b_c - H_cp H_pp^-1 b_p, with the 6C camera unknowns first and "
              "H_pp block-diagonal in 3 x 3 (Triggs et al. 1999, Sec. 6.1).")
def _(ctx):
    for C, P in ((1, 4), (2, 6), (3, 10), (4, 15)):
        H, b = _normal_equations(ctx.rng, C, P)
        _check_schur(ctx, H, b, C)


@EX.test("schur_complement", "bundle adjustment with your schur_complement", weight=4, visibility="hidden",
         hint="Plugged into slamlib's Levenberg-Marquardt (your S and s, then slamlib's back-substitution), the "
              "adjusted cameras and points must be the reference's.")
def _(ctx):
    _e2e_ba_with(ctx, "schur_complement", "LM step", _check_schur, back_substitute=sl.back_substitute)


# =========================================================================== back_substitute
def _check_back(ctx, H, b, C, dx_c):
    """Call back_substitute and compare dx_points with slamlib's."""
    n = H.shape[0] - 6 * C
    dx_p = ctx.expect(ctx.call(H, b, C, dx_c), Out("dx_points", (n,)))
    ref = sl.back_substitute(H, b, C, dx_c)
    ctx.close("dx_points", dx_p, ref, atol=1e-9 * max(1.0, float(np.abs(ref).max())), rtol=1e-7)
    return dx_p


@EX.test("back_substitute", "points' steps of random problems", weight=9,
         hint="dx_p = -H_pp^-1 (b_p + H_pc dx_c), H_pp^-1 block by block (3 x 3 per point): then "
              "[dx_c, dx_p] solves H dx = -b.")
def _(ctx):
    for C, P in ((1, 4), (2, 8), (3, 12)):
        H, b = _normal_equations(ctx.rng, C, P)
        S, s = sl.schur_complement(H, b, C)
        dx_c = np.linalg.solve(S, -s)
        dx_p = _check_back(ctx, H, b, C, dx_c)
        res = H @ np.concatenate([dx_c, dx_p]) + b
        if np.abs(res).max() > 1e-6 * max(1.0, float(np.abs(b).max())):
            ctx.fail(f"[dx_cameras, dx_points] does not solve H dx = -b (residual {np.abs(res).max():.3g})")
        # any camera step, not only the solution: the formula must hold as written
        _check_back(ctx, H, b, C, ctx.rng.normal(0.0, 0.1, 6 * C))


@EX.test("back_substitute", "bundle adjustment with your back_substitute", weight=4, visibility="hidden",
         hint="Plugged into slamlib's Levenberg-Marquardt (slamlib's Schur complement, then your back-substitution), "
              "the adjusted cameras and points must be the reference's.")
def _(ctx):
    _e2e_ba_with(ctx, "back_substitute", "LM step", _check_back, schur_complement=sl.schur_complement)
