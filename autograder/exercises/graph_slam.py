"""Exercise 6: graph SLAM (edge error, normal equations, a Gauss-Newton step) and ICP's alignment step.

Pose graphs are drawn from the test's generator: a random walk of ``n`` poses,
odometry edges ``(i, i+1)`` and a few loop closures (some pointing backwards,
``j < i``), noisy measurements, random symmetric positive-definite information
matrices and an initial guess perturbed from the truth. The end-to-end tests plug
the student's function into slamlib's own optimiser
(:func:`slamlib.optimize_pose_graph` with ``step=``) and ICP loop
(:func:`slamlib.icp` with ``align=``), and every call inside them is compared with
slamlib on that call's inputs first.
"""

from __future__ import annotations

import numpy as np

import slamlib as sl

from ..context import Fail, Out, wrap
from ..spec import Exercise
from .common import check_fd, fd_jacobian, spd

EX = Exercise(
    "graph_slam",
    "Graph SLAM and scan alignment",
    notebook="06_graph_slam.ipynb",
    functions={
        "edge_error": "(xi, xj, z)",
        "build_linear_system": "(X, edges, Z, Omega)",
        "gauss_newton_step": "(X, edges, Z, Omega)",
        "icp_align": "(P, Q)",
    },
)


# =========================================================================== scenarios
def _pose(rng, extent=5.0, heading=None):
    th = rng.uniform(-np.pi, np.pi) if heading is None else heading
    return np.array([rng.uniform(-extent, extent), rng.uniform(-extent, extent), th])


def _graph(rng, n=8, closures=4, init_noise=(0.3, 0.15), meas_noise=(0.05, 0.02), first=None, headings=None):
    """A random pose graph: ``(X0, edges, Z, Omega, X_true)``.

    Odometry edges ``(i, i+1)`` plus ``closures`` loop closures between poses at
    least two apart, about half of them stored backwards (``i > j``). ``headings``
    (shape ``(n,)``, NaN for "random"): true headings imposed on some poses.
    """
    steps = np.column_stack([rng.uniform(0.5, 1.5, n - 1), rng.normal(0.0, 0.2, n - 1), rng.uniform(-0.9, 0.9, n - 1)])
    X = np.empty((n, 3))
    X[0] = _pose(rng, extent=2.0) if first is None else first
    for k in range(n - 1):
        X[k + 1] = sl.compose(X[k], steps[k])
        if headings is not None and np.isfinite(headings[k + 1]):
            X[k + 1, 2] = headings[k + 1]
    pairs = [(k, k + 1) for k in range(n - 1)]
    while len(pairs) < n - 1 + closures:
        i, j = (int(v) for v in rng.choice(n, size=2, replace=False))
        if abs(i - j) >= 2:
            pairs.append((i, j))
    edges = np.array(pairs, dtype=np.int64)
    Z = sl.relative(X[edges[:, 0]], X[edges[:, 1]])
    Z = Z + rng.normal(0.0, [meas_noise[0], meas_noise[0], meas_noise[1]], size=Z.shape)
    Z[:, 2] = wrap(Z[:, 2])
    Omega = np.stack([spd(rng, 3, scale=rng.uniform(20.0, 400.0), cond=30.0) for _ in range(len(edges))])
    X0 = X + rng.normal(0.0, [init_noise[0], init_noise[0], init_noise[1]], size=X.shape)
    X0[:, 2] = wrap(X0[:, 2])
    return X0, edges, Z, Omega, X


def _edge_case(rng):
    """Two poses and a measurement of the second from the first, the measurement off by a little."""
    xi, xj = _pose(rng), _pose(rng)
    z = sl.relative(xi, xj) + rng.normal(0.0, [0.3, 0.3, 0.2])
    z[2] = wrap(z[2])
    return xi, xj, z


def _in(ctx, what, k, fn):
    """Run one step of an end-to-end loop; a failure names the step."""
    try:
        return fn()
    except Fail as exc:
        raise Fail(f"{what} {k}: {exc}") from None


# =========================================================================== edge_error
def _check_edge_error(ctx, xi, xj, z):
    """Call edge_error and compare e, A and B with slamlib's."""
    e, A, B = ctx.expect(ctx.call(xi, xj, z), Out("e", (3,)), Out("A", (3, 3)), Out("B", (3, 3)))
    ref = sl.edge_error(xi, xj, z)
    ctx.wrapped("the heading error e[2]", e[2])
    ctx.close("e", e, ref[0], atol=1e-9, rtol=1e-9, angles=[2])
    ctx.close("A", A, ref[1], atol=1e-9, rtol=1e-7)
    ctx.close("B", B, ref[2], atol=1e-9, rtol=1e-7)
    return e, A, B


@EX.test("edge_error", "error and Jacobians of random edges", weight=10,
         hint="e = [R(theta_z)^T (R(theta_i)^T (t_j - t_i) - t_z), wrap(theta_j - theta_i - theta_z)] "
              "(Grisetti et al. 2010, Eq. 30); A = de/dxi, B = de/dxj (Eq. 32): the translation rows of B are "
              "R_z^T R_i^T, those of A are -R_z^T R_i^T and R_z^T dR_i^T/dtheta_i (t_j - t_i).")
def _(ctx):
    for _ in range(6):
        _check_edge_error(ctx, *_edge_case(ctx.rng))


@EX.test("edge_error", "heading error wrapped", weight=4,
         hint="Wrap theta_j - theta_i - theta_z to [-pi, pi): it can lie anywhere in (-3 pi, 3 pi).")
def _(ctx):
    for th_i, th_j, th_z in ((3.0, -3.0, 0.1), (-3.0, 3.0, -0.2), (0.5, -2.9, 2.8), (-2.0, 2.5, -2.6)):
        xi, xj, z = _edge_case(ctx.rng)
        xi[2], xj[2], z[2] = th_i, th_j, th_z
        _check_edge_error(ctx, xi, xj, z)


@EX.test("edge_error", "A and B match finite differences of your e", weight=5, visibility="hidden",
         hint="Your A or B disagrees with the numerical derivatives of your own e with respect to xi or xj.")
def _(ctx):
    for _ in range(2):
        xi, xj, z = _edge_case(ctx.rng)
        _, A, B = _check_edge_error(ctx, xi, xj, z)
        num_a = fd_jacobian(lambda v: _check_edge_error(ctx, v, xj, z)[0], xi, angle_out=[2])
        num_b = fd_jacobian(lambda v: _check_edge_error(ctx, xi, v, z)[0], xj, angle_out=[2])
        ctx.last_call = ctx.describe_call("edge_error", (xi, xj, z), {})
        check_fd(ctx, "A", A, num_a)
        check_fd(ctx, "B", B, num_b)


def _dense_step(X, edges, Z, Omega, system):
    """One Gauss-Newton iteration, first pose fixed, from ``system(X) -> (H, b)`` (dense solve)."""
    H, b = system(X)
    dx = np.linalg.solve(H[3:, 3:], -b[3:])
    out = X.copy()
    out[1:] += dx.reshape(-1, 3)
    out[:, 2] = wrap(out[:, 2])
    return out


def _e2e(ctx, what, X0, edges, Z, Omega, step, *, max_iter=6):
    """Gauss-Newton through slamlib's optimiser with ``step``; final poses and chi2 compared with the reference's."""
    try:
        got = sl.optimize_pose_graph(X0, edges, Z, Omega, method="gn", max_iter=max_iter, step=step)
    except (ValueError, TypeError, np.linalg.LinAlgError) as exc:
        ctx.fail(f"{what}: Gauss-Newton could not use your result ({exc})")
    ctx.last_call = None
    ref = sl.optimize_pose_graph(X0, edges, Z, Omega, method="gn", max_iter=max_iter)
    ctx.close(f"{what}: the optimised poses", got.X, ref.X, atol=1e-7, rtol=1e-6, angles=[2])
    ctx.close(f"{what}: chi2 per iteration", got.chi2, ref.chi2, atol=1e-8, rtol=1e-6)
    if not got.chi2[-1] < 0.5 * got.chi2[0]:
        ctx.fail(f"{what}: chi2 went from {got.chi2[0]:.4g} to only {got.chi2[-1]:.4g}")


@EX.test("edge_error", "pose graph optimised with your edge_error", weight=5, visibility="hidden",
         hint="Plugged into Gauss-Newton on a small pose graph (H and b summed from your e, A and B), your edge "
              "error must reach the reference's poses.")
def _(ctx):
    X0, edges, Z, Omega, _ = _graph(ctx.rng, n=6, closures=2)

    def system(X):
        n = X.shape[0]
        H, b = np.zeros((3 * n, 3 * n)), np.zeros(3 * n)
        for k, (i, j) in enumerate(edges):
            e, A, B = _check_edge_error(ctx, X[i], X[j], Z[k])
            J = np.zeros((3, 3 * n))
            J[:, 3 * i:3 * i + 3], J[:, 3 * j:3 * j + 3] = A, B
            H += J.T @ Omega[k] @ J
            b += J.T @ Omega[k] @ e
        return H, b

    it = [0]

    def step(X, edges_, Z_, Omega_):
        it[0] += 1
        return _in(ctx, "Gauss-Newton iteration", it[0], lambda: _dense_step(X, edges_, Z_, Omega_, system))

    _e2e(ctx, "Gauss-Newton with your edge_error", X0, edges, Z, Omega, step, max_iter=4)


# =========================================================================== build_linear_system
def _check_system(ctx, X, edges, Z, Omega):
    """Call build_linear_system and compare H and b with slamlib's (a sparse H is judged as a dense array)."""
    m = 3 * X.shape[0]
    H, b = ctx.expect(ctx.call(X, edges, Z, Omega), Out("H", (m, m)), Out("b", (m,)))
    Hr, br = sl.build_linear_system(X, edges, Z, Omega)
    Hr = Hr.toarray()
    ctx.close("H", H, Hr, atol=1e-9 * max(1.0, float(np.abs(Hr).max())), rtol=1e-7)
    ctx.close("b", b, br, atol=1e-9 * max(1.0, float(np.abs(br).max())), rtol=1e-7)
    return H, b


@EX.test("build_linear_system", "H and b of a small pose graph", weight=10,
         hint="For each edge k = (i, j): H[ii] += A^T Omega A, H[ij] += A^T Omega B, H[ji] += B^T Omega A, "
              "H[jj] += B^T Omega B, b[i] += A^T Omega e, b[j] += B^T Omega e, with [i] the rows 3i..3i+2 "
              "(Grisetti et al. 2010, Algorithm 1 lines 4-11). Fix no pose here.")
def _(ctx):
    for n, c in ((4, 1), (7, 3), (9, 5)):
        _check_system(ctx, *_graph(ctx.rng, n=n, closures=c)[:4])


@EX.test("build_linear_system", "repeated edges and edges stored backwards", weight=6,
         hint="Add (+=) each edge's blocks: two edges may join the same poses, and an edge may go from a later "
              "pose to an earlier one (i > j). Writing a block with = keeps only the last edge.")
def _(ctx):
    X0, edges, Z, Omega, _ = _graph(ctx.rng, n=6, closures=2)
    # the same pair measured twice, and once backwards
    extra = np.array([[1, 2], [2, 1], [4, 0]])
    Zx = sl.relative(X0[extra[:, 0]], X0[extra[:, 1]]) + ctx.rng.normal(0.0, 0.1, (3, 3))
    Zx[:, 2] = wrap(Zx[:, 2])
    Ox = np.stack([spd(ctx.rng, 3, scale=100.0) for _ in range(3)])
    _check_system(ctx, X0, np.vstack([edges, extra]), np.vstack([Z, Zx]), np.concatenate([Omega, Ox]))
    # a graph of two poses and one backward edge only
    _check_system(ctx, X0[:2], np.array([[1, 0]]), Zx[1:2], Ox[1:2])


@EX.test("build_linear_system", "a larger graph (60 poses)", weight=5, visibility="hidden",
         hint="Place every edge's blocks at rows and columns 3i..3i+2 and 3j..3j+2 of its own poses.")
def _(ctx):
    _check_system(ctx, *_graph(ctx.rng, n=60, closures=25)[:4])


@EX.test("build_linear_system", "pose graph optimised with your build_linear_system", weight=5, visibility="hidden",
         hint="Plugged into Gauss-Newton on a small pose graph, your H and b must lead to the reference's poses.")
def _(ctx):
    X0, edges, Z, Omega, _ = _graph(ctx.rng, n=10, closures=4)
    it = [0]

    def step(X, edges_, Z_, Omega_):
        it[0] += 1
        return _in(ctx, "Gauss-Newton iteration", it[0],
                   lambda: _dense_step(X, edges_, Z_, Omega_, lambda Y: _check_system(ctx, Y, edges_, Z_, Omega_)))

    _e2e(ctx, "Gauss-Newton with your build_linear_system", X0, edges, Z, Omega, step)


# =========================================================================== gauss_newton_step
def _check_step(ctx, X, edges, Z, Omega):
    """Call gauss_newton_step and compare the new poses with slamlib's."""
    got = ctx.expect(ctx.call(X, edges, Z, Omega), Out("X_new", X.shape))
    ref = sl.gauss_newton_step(X, edges, Z, Omega)
    ctx.wrapped("the headings X_new[:, 2]", got[:, 2])
    ctx.close("X_new", got, ref, atol=1e-8, rtol=1e-6, angles=[2])
    return got


@EX.test("gauss_newton_step", "one iteration on small pose graphs", weight=10,
         hint="Build H and b, solve H[3:, 3:] dx = -b[3:] (the first pose fixed: Grisetti et al. 2010, "
              "Algorithm 1 lines 12-13), and add dx to poses 1..n-1.")
def _(ctx):
    for n, c in ((3, 1), (6, 2), (10, 4)):
        _check_step(ctx, *_graph(ctx.rng, n=n, closures=c)[:4])


def _graph_across_cut(rng, th, n=7):
    """A graph whose step carries the odd poses' headings across the +-pi cut: ``(X0, edges, Z, Omega)``.

    Pose 0 is ``[3, -2, th]``; the odd poses start at ``sign(th) (pi - 0.01)`` and their
    true headings lie 0.15-0.35 rad further on, across the cut, so one Gauss-Newton
    step takes them beyond ``+-pi`` unless they are wrapped.
    """
    s = np.sign(th)
    odd = np.arange(n) % 2 == 1
    start = s * (np.pi - 0.01)
    headings = np.where(odd, wrap(start + s * rng.uniform(0.15, 0.35, n)), np.nan)
    X0, edges, Z, Omega, _ = _graph(rng, n=n, closures=3, first=np.array([3.0, -2.0, th]), headings=headings)
    X0[:, 2] = np.where(odd, start, X0[:, 2])
    X0[0] = [3.0, -2.0, th]
    return X0, edges, Z, Omega


@EX.test("gauss_newton_step", "first pose unchanged and headings wrapped", weight=6,
         hint="Pose 0 keeps its values exactly (it is not at the origin here); every other heading is wrapped "
              "to [-pi, pi) after the update.")
def _(ctx):
    for th in (np.pi - 0.02, -np.pi + 0.02):
        X0, edges, Z, Omega = _graph_across_cut(ctx.rng, th)
        got = _check_step(ctx, X0, edges, Z, Omega)
        ctx.close("X_new[0] (the fixed first pose)", got[0], X0[0], atol=1e-12, rtol=0.0, angles=[2])


@EX.test("gauss_newton_step", "pose graph optimised with your gauss_newton_step", weight=10, visibility="hidden",
         hint="Iterated by slamlib's optimiser (Gauss-Newton, stop on a small relative change of chi2), your "
              "step must reach the reference's poses and chi2.")
def _(ctx):
    X0, edges, Z, Omega, _ = _graph(ctx.rng, n=12, closures=5, init_noise=(0.4, 0.25))
    it = [0]

    def step(X, edges_, Z_, Omega_):
        it[0] += 1
        return _in(ctx, "Gauss-Newton iteration", it[0], lambda: _check_step(ctx, X, edges_, Z_, Omega_))

    _e2e(ctx, "Gauss-Newton with your gauss_newton_step", X0, edges, Z, Omega, step, max_iter=8)


# =========================================================================== icp_align
def _check_align(ctx, P, Q):
    """Call icp_align and compare R and t with slamlib's."""
    R, t = ctx.expect(ctx.call(P, Q), Out("R", (2, 2)), Out("t", (2,)))
    Rr, tr = sl.icp_align(P, Q)
    ctx.close("R", R, Rr, atol=1e-8, rtol=1e-8)
    ctx.close("t", t, tr, atol=1e-8 * max(1.0, float(np.abs(Q).max())), rtol=1e-7)
    return R, t


def _rot(a):
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def _matched(rng, K, noise=0.02):
    P = rng.uniform(-4.0, 4.0, (K, 2)) * rng.uniform(0.3, 1.0, 2)
    R, t = _rot(rng.uniform(-np.pi, np.pi)), rng.uniform(-3.0, 3.0, 2)
    return P, P @ R.T + t + rng.normal(0.0, noise, (K, 2))


@EX.test("icp_align", "rotation and translation of matched points", weight=10,
         hint="Subtract the centroids, C = sum (q_k - mu_q)(p_k - mu_p)^T = U S V^T, R = U V^T, "
              "t = mu_q - R mu_p (Besl & McKay 1992; Umeyama 1991, Eqs. 38-42).")
def _(ctx):
    for K, noise in ((5, 0.0), (20, 0.02), (60, 0.1), (8, 0.5)):
        _check_align(ctx, *_matched(ctx.rng, K, noise))


@EX.test("icp_align", "a proper rotation when the best fit is a reflection", weight=5,
         hint="When det(U V^T) = -1, use R = U diag(1, -1) V^T: R must be a rotation (det R = +1), never a "
              "reflection (Umeyama 1991, Eq. 39).")
def _(ctx):
    for _ in range(3):
        P, Q = _matched(ctx.rng, 12, 0.01)
        Q = Q * np.array([1.0, -1.0])  # a mirror image: the best orthogonal map is a reflection
        R, _ = _check_align(ctx, P, Q)
        if not np.linalg.det(R) > 0:
            ctx.fail(f"det R = {np.linalg.det(R):.6f}: R is a reflection, not a rotation")


@EX.test("icp_align", "two points, and points far from the origin", weight=3, visibility="hidden",
         hint="K = 2 points fix the rotation; centre both sets on their centroids before the SVD.")
def _(ctx):
    P, Q = _matched(ctx.rng, 2, 0.0)
    _check_align(ctx, P, Q)
    P, Q = _matched(ctx.rng, 15, 0.05)
    _check_align(ctx, P + 50.0, Q + np.array([-40.0, 60.0]))


def _room_scan(rng, n=180):
    """Points on the walls of a room with a pillar, seen from inside (a synthetic laser scan)."""
    walls = [((-4, -3), (5, -3)), ((5, -3), (5, 4)), ((5, 4), (-4, 4)), ((-4, 4), (-4, -3)),
             ((1, 0), (2, 0)), ((2, 0), (2, 1.5)), ((2, 1.5), (1, 1.5))]
    lengths = np.array([np.hypot(b[0] - a[0], b[1] - a[1]) for a, b in walls])
    k = rng.choice(len(walls), size=n, p=lengths / lengths.sum())
    s = rng.uniform(0.0, 1.0, n)
    a = np.array([w[0] for w in walls], dtype=float)[k]
    b = np.array([w[1] for w in walls], dtype=float)[k]
    return a + s[:, None] * (b - a)


@EX.test("icp_align", "ICP with your icp_align aligns two scans", weight=6, visibility="hidden",
         hint="Plugged into point-to-point ICP (slamlib.icp) on two scans of a room, every alignment step must "
              "match the reference and ICP must reach the reference's pose.")
def _(ctx):
    target = _room_scan(ctx.rng)
    pose = np.array([ctx.rng.uniform(-0.25, 0.25), ctx.rng.uniform(-0.25, 0.25), ctx.rng.uniform(-0.15, 0.15)])
    # the source scan: the room seen from `pose`, fresh samples with noise
    world = _room_scan(ctx.rng)
    c, s = np.cos(pose[2]), np.sin(pose[2])
    Rp = np.array([[c, -s], [s, c]])
    source = (world - pose[:2]) @ Rp + ctx.rng.normal(0.0, 0.01, world.shape)
    it = [0]

    def align(P, Q):
        it[0] += 1
        return _in(ctx, "ICP round", it[0], lambda: _check_align(ctx, P, Q))

    kw = dict(method="point_to_point", max_iter=40, max_dist=0.5, trim=0.9)
    try:
        got = sl.icp(source, target, **kw, align=align)
    except (ValueError, TypeError, np.linalg.LinAlgError) as exc:
        ctx.fail(f"ICP could not use your result ({exc})")
    ctx.last_call = None
    ref = sl.icp(source, target, **kw)
    ctx.close("the ICP pose", got.pose, ref.pose, atol=1e-6, rtol=1e-6, angles=[2])
    if got.iterations != ref.iterations:
        ctx.fail(f"ICP took {got.iterations} rounds with your icp_align, {ref.iterations} with the reference")
