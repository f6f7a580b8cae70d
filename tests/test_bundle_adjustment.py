"""Tests of slamlib.bundle_adjustment: the Schur complement, back-substitution, and LM over cameras and points."""

import numpy as np
import pytest

import slamlib as sl
from slamlib.datasets import load_balbianello, load_dubrovnik


def _look_at(c, target):
    z = (target - c) / np.linalg.norm(target - c)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    return sl.pose_matrix(np.column_stack([x, np.cross(z, x), z]), c)


def _scene(rng, n_cam=5, n_pt=40, noise=0.5):
    K = sl.calibration_matrix(600.0, 600.0, 320.0, 240.0)
    P = rng.uniform(-2.0, 2.0, (n_pt, 3))
    T = np.stack([_look_at(np.array([8 * np.sin(a), rng.normal(0, 0.3), -8 * np.cos(a)]), rng.normal(0, 0.2, 3))
                  for a in np.linspace(-0.6, 0.6, n_cam)])
    cam = np.repeat(np.arange(n_cam), n_pt)
    point = np.tile(np.arange(n_pt), n_cam)
    uv = np.concatenate([sl.project(K, Tc, P)[0] for Tc in T]) + rng.normal(0.0, noise, (len(cam), 2))
    return K, T, P, cam, point, uv


def _perturbed(rng, T, P, sd_t=0.1, sd_p=0.1):
    T0 = T.copy()
    T0[1:, :3, 3] += rng.normal(0.0, sd_t, (len(T) - 1, 3))
    return T0, P + rng.normal(0.0, sd_p, P.shape)


def _arrow(rng, C, P):
    """A random SPD matrix with the arrow pattern of bundle adjustment (H_pp block-diagonal) and a b."""
    n = 6 * C + 3 * P
    J = np.zeros((4 * P * C, n))
    r = 0
    for j in range(P):
        for c in range(C):
            J[r:r + 2, 6 * c:6 * c + 6] = rng.normal(size=(2, 6))
            J[r:r + 2, 6 * C + 3 * j:6 * C + 3 * j + 3] = rng.normal(size=(2, 3))
            r += 2
    H = J.T @ J + 0.1 * np.eye(n)
    return H, rng.normal(size=n)


# --------------------------------------------------------------------------- the Schur complement
@pytest.mark.parametrize("C, P", [(1, 3), (2, 5), (4, 20)])
def test_schur_and_back_substitution_solve_the_full_system(C, P):
    rng = np.random.default_rng(C * 10 + P)
    H, b = _arrow(rng, C, P)
    S, s = sl.schur_complement(H, b, C)
    m = 6 * C
    np.testing.assert_allclose(S, H[:m, :m] - H[:m, m:] @ np.linalg.solve(H[m:, m:], H[m:, :m]), atol=1e-9)
    dx_c = np.linalg.solve(S, -s)
    dx = np.concatenate([dx_c, sl.back_substitute(H, b, C, dx_c)])
    np.testing.assert_allclose(dx, np.linalg.solve(H, -b), atol=1e-9)


def test_schur_complement_refuses_a_wrong_layout():
    H, b = _arrow(np.random.default_rng(0), 2, 3)
    with pytest.raises(ValueError, match="n_cameras"):
        sl.schur_complement(H, b, 4)
    with pytest.raises(ValueError, match="b must have shape"):
        sl.schur_complement(H, b[:-1], 2)
    with pytest.raises(ValueError, match="dx_cameras"):
        sl.back_substitute(H, b, 2, np.zeros(6))


# --------------------------------------------------------------------------- bundle adjustment
def test_bundle_adjustment_reaches_the_noise_floor_and_the_truth():
    rng = np.random.default_rng(1)
    K, T, P, cam, point, uv = _scene(rng)
    T0, P0 = _perturbed(rng, T, P)
    T0[1] = T[1]  # the gauge (camera 0, and camera 1's coordinate that fix_scale holds) at the truth
    res = sl.bundle_adjust(T0, P0, K, cam, point, uv, fix_scale=True)
    assert res.converged
    dof = 2 * len(cam) - (6 * (len(T) - 1) - 1 + 3 * len(P))
    # sigma = 0.5 px: the minimum of sum |e|^2 is about sigma^2 (2 O - n) (chi-square with n parameters removed)
    assert 0.7 < res.cost[-1] / (0.25 * dof) < 1.3
    np.testing.assert_array_equal(res.T_wc[0], T0[0])  # the gauge: camera 0 untouched
    assert np.abs(res.points - P).max() < 0.1 and np.abs(P0 - P).max() > 0.2


@pytest.mark.parametrize("solver", ["sparse", "dense"])
def test_schur_and_full_solves_give_the_same_iterates(solver):
    rng = np.random.default_rng(2)
    K, T, P, cam, point, uv = _scene(rng, n_cam=4, n_pt=25)
    T0, P0 = _perturbed(rng, T, P)
    a = sl.bundle_adjust(T0, P0, K, cam, point, uv, linear_solver="schur", max_iter=5, rtol=0.0)
    b = sl.bundle_adjust(T0, P0, K, cam, point, uv, linear_solver=solver, max_iter=5, rtol=0.0)
    np.testing.assert_allclose(a.cost, b.cost, rtol=1e-8)
    np.testing.assert_allclose(a.points, b.points, atol=1e-8)


def test_fix_scale_holds_one_coordinate_of_the_second_camera():
    rng = np.random.default_rng(3)
    K, T, P, cam, point, uv = _scene(rng, n_cam=3, n_pt=20)
    T0, P0 = _perturbed(rng, T, P)
    res = sl.bundle_adjust(T0, P0, K, cam, point, uv, fix_scale=True)
    base0 = T0[1, :3, :3].T @ (T0[1, :3, 3] - T0[0, :3, 3])
    k = int(np.argmax(np.abs(base0)))
    # the held coordinate of rho is zero at every step: camera 1's position along its own axis k is kept
    moved = T0[1, :3, :3].T @ (res.T_wc[1, :3, 3] - T0[1, :3, 3])
    assert abs(moved[k]) < 0.05 * np.abs(moved).max() + 1e-9 or np.abs(moved).max() < 1e-9


def test_robust_kernel_resists_wrong_observations():
    rng = np.random.default_rng(4)
    K, T, P, cam, point, uv = _scene(rng)
    bad = rng.choice(len(uv), 12, replace=False)
    uv = uv.copy()
    uv[bad] += rng.choice([-1.0, 1.0], (12, 2)) * rng.uniform(30.0, 60.0, (12, 2))
    T0, P0 = _perturbed(rng, T, P)
    plain = sl.bundle_adjust(T0, P0, K, cam, point, uv, fix_scale=True)
    robust = sl.bundle_adjust(T0, P0, K, cam, point, uv, fix_scale=True, robust="cauchy")
    good = np.ones(len(uv), bool)
    good[bad] = False
    clean = sl.bundle_adjust(T0, P0, K, cam[good], point[good], uv[good], fix_scale=True)
    # the error against the truth is mostly the gauge (the scale is held at camera 1's perturbed position), so
    # the reference is the adjustment without the wrong observations, which shares it: over 300 scenes the
    # robust points' median deviation from it was 0.0006-0.07 times the plain points'
    dev_plain = np.median(np.linalg.norm(plain.points - clean.points, axis=1))
    dev_robust = np.median(np.linalg.norm(robust.points - clean.points, axis=1))
    assert dev_robust < 0.25 * dev_plain
    assert robust.weights[bad].max() < 0.05 and np.median(robust.weights) > 0.8  # 300 scenes: <= 0.0033, >= 0.95


def test_hooks_equal_the_library_and_are_called():
    rng = np.random.default_rng(5)
    K, T, P, cam, point, uv = _scene(rng, n_cam=3, n_pt=10)
    T0, P0 = _perturbed(rng, T, P)
    calls = {"project": 0, "exp": 0, "schur": 0, "back": 0}

    def count(name, f):
        def g(*a):
            calls[name] += 1
            return f(*a)
        return g

    a = sl.bundle_adjust(T0, P0, K, cam, point, uv, max_iter=4, rtol=0.0)
    b = sl.bundle_adjust(T0, P0, K, cam, point, uv, max_iter=4, rtol=0.0, project=count("project", sl.project),
                         so3_exp=count("exp", sl.so3_exp), schur_complement=count("schur", sl.schur_complement),
                         back_substitute=count("back", sl.back_substitute))
    np.testing.assert_allclose(a.cost, b.cost, rtol=1e-10)
    assert calls["schur"] == calls["back"] == 4 and calls["exp"] == 4 * 3 and calls["project"] == 5 * 3
    with pytest.raises(ValueError, match="together"):
        sl.bundle_adjust(T0, P0, K, cam, point, uv, schur_complement=sl.schur_complement)


def test_bundle_adjust_refuses_bad_inputs():
    rng = np.random.default_rng(6)
    K, T, P, cam, point, uv = _scene(rng, n_cam=2, n_pt=5)
    with pytest.raises(ValueError, match="cam must hold indices"):
        sl.bundle_adjust(T, P, K, cam + 5, point, uv)
    with pytest.raises(ValueError, match="one row per observation"):
        sl.bundle_adjust(T, P, K, cam, point, uv[:-1])
    with pytest.raises(ValueError, match="K must have shape"):
        sl.bundle_adjust(T, P, np.stack([K] * 3), cam, point, uv)


# --------------------------------------------------------------------------- real problems, against GTSAM
def _gtsam_cost(pb):
    gtsam = pytest.importorskip("gtsam")
    from gtsam.symbol_shorthand import L, X

    g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
    noise = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    for c in range(len(pb.T_wc)):
        v.insert(X(c), gtsam.Pose3(pb.T_wc[c]))
    for j, Pj in enumerate(pb.points):
        v.insert(L(j), gtsam.Point3(*Pj))
    cal = [gtsam.Cal3_S2(K[0, 0], K[1, 1], 0.0, K[0, 2], K[1, 2]) for K in pb.K]
    for c, j, uv in zip(pb.cam, pb.point, pb.uv):
        g.add(gtsam.GenericProjectionFactorCal3_S2(gtsam.Point2(*uv), noise, X(int(c)), L(int(j)), cal[int(c)]))
    g.add(gtsam.NonlinearEqualityPose3(X(0), gtsam.Pose3(pb.T_wc[0])))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(100)
    params.setRelativeErrorTol(1e-12)
    params.setAbsoluteErrorTol(0.0)
    return g.error(v), g.error(gtsam.LevenbergMarquardtOptimizer(g, v, params).optimize())


@pytest.mark.parametrize("loader", [load_dubrovnik, load_balbianello])
def test_final_cost_equals_gtsam_from_the_same_start(loader):
    pb = loader()
    e0, e1 = _gtsam_cost(pb)
    res = sl.bundle_adjust(pb.T_wc, pb.points, pb.K, pb.cam, pb.point, pb.uv, max_iter=100, rtol=1e-12)
    # GTSAM's error is 1/2 sum |e|^2 (unit sigma)
    assert 0.5 * res.cost[0] == pytest.approx(e0, rel=1e-9)
    assert 0.5 * res.cost[-1] == pytest.approx(e1, rel=1e-6)
    assert res.cost[-1] < res.cost[0]


def test_levenberg_marquardt_raises_the_damping_when_the_damped_system_is_not_positive_definite():
    """A free gauge direction (the scale of a bundle adjustment) leaves ``H`` singular; once the damping has
    shrunk below the rounding of ``H`` the Cholesky factorisation fails. LM takes that as a failed step and
    raises the damping instead of stopping with the error."""
    from slamlib.graph_slam import _optimize

    class Layout:
        diag = (np.arange(2), np.arange(2))

        def values(self, blocks):
            return blocks

        def solve(self, data, rhs):
            if data[1, 1] < 1e-8:  # the gauge direction: positive definite only while damped
                raise np.linalg.LinAlgError("not positive definite")
            return np.linalg.solve(data, rhs)

        def expand(self, dx):
            return dx

    def evaluate(x):  # F = (x0 - 3)^2 + 0 * x1: x1 is a gauge freedom
        r = x[0] - 3.0
        return r * r, r * r, (np.diag([1.0, 0.0]), np.array([r, 0.0])), None

    x, _, cost, it, converged, _ = _optimize(np.array([0.0, 0.0]), evaluate, Layout(), lambda s, d: s + d,
                                             method="lm", max_iter=50, rtol=1e-12, lm_lambda=1e-7)
    assert converged and cost[-1] < 1e-20
    np.testing.assert_allclose(x, [3.0, 0.0], atol=1e-10)
