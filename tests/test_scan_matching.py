"""Tests of slamlib.scan_matching: closed-form alignment, ICP, covariance and degeneracy, scans."""

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

import slamlib as sl


def _rot(a):
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def _move(pose, pts):
    return pts @ _rot(pose[2]).T + pose[:2]


def _cast(pose, segments, angles, max_range=30.0):
    """Exact ranges of beams from `pose` (3,) against line segments (S, 2, 2) (a tiny polygon world)."""
    a = pose[2] + angles
    d = np.stack([np.cos(a), np.sin(a)], axis=1)  # (K, 2)
    p0, p1 = segments[:, 0], segments[:, 1]
    e = p1 - p0  # (S, 2)
    w = p0 - pose[:2]  # (S, 2)
    den = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]  # cross(d, e)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (w[None, :, 0] * e[None, :, 1] - w[None, :, 1] * e[None, :, 0]) / den  # range along the beam
        u = (w[None, :, 0] * d[:, None, 1] - w[None, :, 1] * d[:, None, 0]) / den  # position on the segment
    ok = (np.abs(den) > 1e-12) & (s > 0) & (u >= 0) & (u <= 1)
    r = np.where(ok, s, np.inf).min(axis=1)
    return np.minimum(r, max_range)


def _box(x0, y0, x1, y1):
    c = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    return np.stack([c, np.roll(c, -1, axis=0)], axis=1)


# a 10 m x 8 m room with a pillar and a cupboard: every direction constrained
ROOM = np.concatenate([_box(-3.0, -4.0, 7.0, 4.0), _box(2.0, 1.0, 2.6, 1.6), _box(4.5, -4.0, 6.0, -3.0)])
# a corridor 2.6 m wide and 200 m long: nothing fixes the position along it within 30 m
CORRIDOR = np.array([[[-100.0, -1.3], [100.0, -1.3]], [[-100.0, 1.3], [100.0, 1.3]]])
ANGLES = -np.pi / 2 + np.arange(180) * np.pi / 180


def _scan_points(world, pose, rng=None, noise=0.0):
    z = _cast(pose, world, ANGLES)
    if rng is not None:
        z = z + rng.normal(0.0, noise, z.shape)
    return sl.scan_to_points(z, ANGLES, max_range=30.0)


# --------------------------------------------------------------------------- icp_align (the contract)
def test_icp_align_recovers_a_known_transform_exactly():
    rng = np.random.default_rng(0)
    for _ in range(20):
        P = rng.normal(size=(rng.integers(2, 50), 2)) * 3.0
        a = rng.uniform(-np.pi, np.pi)
        t = rng.normal(size=2) * 5.0
        R, t_hat = sl.icp_align(P, P @ _rot(a).T + t)
        np.testing.assert_allclose(R, _rot(a), atol=1e-12)
        np.testing.assert_allclose(t_hat, t, atol=1e-11)


def _brute_cost(P, Q):
    """The least cost over all rotations, found by a 1-D search (the optimal t is mu_q - R mu_p)."""
    mp, mq = P.mean(0), Q.mean(0)

    def cost(a):
        return np.sum((((P - mp) @ _rot(a).T) - (Q - mq)) ** 2)

    grid = np.linspace(-np.pi, np.pi, 721)
    a0 = grid[np.argmin([cost(a) for a in grid])]
    return minimize_scalar(cost, bounds=(a0 - 0.01, a0 + 0.01), method="bounded", options={"xatol": 1e-12}).fun


def test_icp_align_reflection_case_returns_the_best_rotation():
    """Mirror-image point sets: U V^T is a reflection; the answer must still be a rotation, the best one."""
    rng = np.random.default_rng(1)
    P = rng.normal(size=(12, 2)) * [3.0, 1.0]
    Q = P * [1.0, -1.0] + [0.5, 2.0]  # mirrored in the x axis, then shifted
    U, _, Vt = np.linalg.svd((Q - Q.mean(0)).T @ (P - P.mean(0)))
    assert np.linalg.det(U @ Vt) < 0  # the unconstrained optimum is a reflection
    R, t = sl.icp_align(P, Q)
    np.testing.assert_allclose(R.T @ R, np.eye(2), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
    cost = np.sum((P @ R.T + t - Q) ** 2)
    assert cost == pytest.approx(_brute_cost(P, Q), rel=1e-9)
    # and on noisy, non-mirrored data it is the least-squares optimum too
    Qn = P @ _rot(0.7).T + [1.0, -1.0] + rng.normal(size=P.shape) * 0.3
    R, t = sl.icp_align(P, Qn)
    assert np.sum((P @ R.T + t - Qn) ** 2) == pytest.approx(_brute_cost(P, Qn), rel=1e-9)


def test_icp_align_bad_input_names_the_argument():
    P = np.zeros((5, 2))
    with pytest.raises(ValueError, match="P must be finite"):
        sl.icp_align(np.where(np.eye(5, 2) > 0, np.nan, 1.0), P)
    with pytest.raises(ValueError, match=r"Q must be finite"):
        sl.icp_align(P, np.full((5, 2), np.inf))
    with pytest.raises(ValueError, match=r"P must have shape \(\*, 2\)"):
        sl.icp_align(np.zeros((5, 3)), np.zeros((5, 3)))
    with pytest.raises(ValueError, match=r"K = 2"):
        sl.icp_align(np.zeros((1, 2)), np.zeros((1, 2)))
    with pytest.raises(ValueError, match=r"Q must have the shape of P"):
        sl.icp_align(np.zeros((5, 2)), np.zeros((4, 2)))
    with pytest.raises(TypeError, match="P"):
        sl.icp_align("points", P)
    P0 = np.arange(10.0).reshape(5, 2)
    sl.icp_align(P0, P0 + 1.0)
    np.testing.assert_array_equal(P0, np.arange(10.0).reshape(5, 2))  # arguments unchanged


# --------------------------------------------------------------------------- scans
def test_scan_to_points_geometry_and_bad_input():
    z = np.array([1.0, 2.0, 81.83, 0.5])
    a = np.array([-np.pi / 2, 0.0, 0.3, np.pi / 2])
    pts = sl.scan_to_points(z, a, max_range=81.83, sensor_offset=0.25)
    np.testing.assert_allclose(pts, [[0.25, -1.0], [2.25, 0.0], [0.25, 0.5]], atol=1e-15)
    assert sl.scan_to_points(z, a, max_range=81.83, min_range=0.6).shape == (2, 2)
    with pytest.raises(ValueError, match="ranges must be finite"):
        sl.scan_to_points([1.0, np.nan], [0.0, 0.1], max_range=10.0)
    with pytest.raises(ValueError, match=r"ranges \(3,\) and angles \(2,\) must have the same length"):
        sl.scan_to_points([1.0, 2.0, 3.0], [0.0, 0.1], max_range=10.0)
    with pytest.raises(ValueError, match="ranges must be non-negative"):
        sl.scan_to_points([1.0, -2.0], [0.0, 0.1], max_range=10.0)
    with pytest.raises(ValueError, match="max_range"):
        sl.scan_to_points([1.0, 2.0], [0.0, 0.1], max_range=-1.0)


# --------------------------------------------------------------------------- ICP on synthetic worlds
TRUTH = np.array([0.35, -0.2, 0.12])  # pose of the second scan seen from the first


@pytest.mark.parametrize("method", ["point_to_line", "point_to_point"])
def test_icp_recovers_a_known_motion_in_a_room(method):
    x1 = np.array([0.0, 0.0, 0.2])
    x2 = sl.compose(x1, TRUTH)
    target, source = _scan_points(ROOM, x1), _scan_points(ROOM, x2)  # two real scans: different samples of the walls
    res = sl.icp(source, target, np.zeros(3), method=method, max_iter=100, trim=1.0, max_dist=0.5)
    assert res.converged and not res.degenerate, res.reason
    tol = 2e-3 if method == "point_to_line" else 3e-2  # point-to-point is biased by the sampling of the walls
    np.testing.assert_allclose(res.pose[:2], TRUTH[:2], atol=tol)
    assert abs(sl.angle_diff(res.pose[2], TRUTH[2])) < tol / 2
    assert res.history.shape == (res.iterations + 1, 3)
    np.testing.assert_array_equal(res.history[0], 0.0)
    np.testing.assert_array_equal(res.history[-1], res.pose)


def test_point_to_line_converges_in_fewer_iterations_than_point_to_point():
    rng = np.random.default_rng(3)
    its = {"point_to_line": [], "point_to_point": []}
    for _ in range(10):
        x1 = np.r_[rng.uniform(-1, 4, 2) * [1, 0.5], rng.uniform(-np.pi, np.pi)]
        x2 = sl.compose(x1, TRUTH + rng.normal(size=3) * [0.1, 0.1, 0.03])
        target, source = _scan_points(ROOM, x1), _scan_points(ROOM, x2)
        for method in its:
            res = sl.icp(source, target, np.zeros(3), method=method, max_iter=200, tol=1e-5, trim=1.0, max_dist=1.0)
            its[method].append(res.iterations)
    assert np.mean(its["point_to_line"]) < 0.5 * np.mean(its["point_to_point"]), its


def test_icp_covariance_matches_the_spread_over_noise_seeds():
    """sigma^2 (J^T J)^-1 predicts the scatter of the estimate when the ranges are noisy (1 cm)."""
    rng = np.random.default_rng(4)
    x1 = np.array([0.5, 0.3, 0.0])
    x2 = sl.compose(x1, TRUTH)
    est, covs = [], []
    for _ in range(40):
        target = _scan_points(ROOM, x1, rng, 0.01)
        source = _scan_points(ROOM, x2, rng, 0.01)
        res = sl.icp(source, target, TRUTH, trim=1.0, max_dist=0.5, tol=1e-7, max_iter=50)
        est.append(res.pose)
        covs.append(res.cov)
    err = np.array(est) - TRUTH
    emp = np.cov(err.T)
    pred = np.mean(covs, axis=0)
    ratio = np.diag(emp) / np.diag(pred)
    # the J^T J covariance ignores the noise of the target's normals and of the association, so it is
    # optimistic by a small factor (Censi 2007), never by orders of magnitude
    assert np.all((ratio > 0.5) & (ratio < 6.0)), ratio
    assert np.all(np.linalg.eigvalsh(pred) > 0)
    # and the estimate is unbiased: the mean error is within 4 standard errors of zero
    assert np.all(np.abs(err.mean(0)) < 4 * np.sqrt(np.diag(emp) / 40) + 1e-4), (err.mean(0), np.sqrt(np.diag(emp)))


def test_degeneracy_check_fires_in_a_corridor_and_not_in_a_room():
    x1 = np.array([0.0, 0.1, 0.05])
    x2 = sl.compose(x1, [0.5, 0.05, 0.02])
    corr = sl.icp(_scan_points(CORRIDOR, x2), _scan_points(CORRIDOR, x1), np.zeros(3), max_dist=1.0)
    assert corr.degenerate
    assert "translation along" in corr.reason and "not constrained" in corr.reason
    # the weak direction is the corridor's axis, seen from the first scan (heading 0.05)
    axis = np.array([np.cos(-0.05), np.sin(-0.05)])
    assert abs(corr.weak_direction[:2] @ axis) > 0.99
    assert corr.min_information < 0.02
    # the position across the corridor and the heading are still measured
    assert abs(corr.pose[2] - 0.02) < 2e-3
    room = sl.icp(_scan_points(ROOM, x2), _scan_points(ROOM, x1), np.zeros(3), max_dist=1.0)
    assert not room.degenerate and room.reason == ""
    assert room.min_information > 0.05


def test_icp_with_too_few_matches_is_reported_not_accepted():
    target = _scan_points(ROOM, np.zeros(3))
    far = target + [50.0, 0.0]  # nothing within the gate
    res = sl.icp(far, target, np.zeros(3))
    assert not res.converged and res.degenerate and "matched" in res.reason


def test_icp_bad_input():
    pts = _scan_points(ROOM, np.zeros(3))
    bad = pts.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="source must be finite"):
        sl.icp(bad, pts)
    with pytest.raises(ValueError, match="target must be finite"):
        sl.icp(pts, bad)
    with pytest.raises(ValueError, match=r"source must have shape \(\*, 2\)"):
        sl.icp(np.zeros((5, 3)), pts)
    with pytest.raises(ValueError, match="target must hold at least 3 points"):
        sl.icp(pts, pts[:2])
    with pytest.raises(ValueError, match=r"init must have shape \(3,\)"):
        sl.icp(pts, pts, np.zeros(2))
    with pytest.raises(ValueError, match="method"):
        sl.icp(pts, pts, method="plane")
    with pytest.raises(ValueError, match="trim"):
        sl.icp(pts, pts, trim=1.5)
    with pytest.raises(ValueError, match="max_dist"):
        sl.icp(pts, pts, max_dist=0.0)


# --------------------------------------------------------------------------- ICP on the CMU log
@pytest.fixture(scope="module")
def log():
    from slamlib.datasets.cmu import load_cmu_log

    return load_cmu_log()


def test_icp_recovers_a_known_transform_of_a_real_cmu_scan(log):
    rng = np.random.default_rng(5)
    for k in (0, 150, 400, 650):
        pts = sl.scan_to_points(log.ranges[k], log.angles, max_range=40.0, sensor_offset=log.sensor_offset)
        truth = np.array([0.25, -0.15, 0.08])
        # the perturbed copy: moved rigidly, with 1 cm of noise on every point
        moved = _move(sl.compose(np.zeros(3), truth), pts) + rng.normal(size=pts.shape) * 0.01
        res = sl.icp(pts, moved, np.zeros(3))
        assert res.converged and not res.degenerate, (k, res.reason)
        np.testing.assert_allclose(res.pose[:2], truth[:2], atol=0.01)
        assert abs(sl.angle_diff(res.pose[2], truth[2])) < 0.005


def test_icp_between_consecutive_cmu_scans_agrees_with_odometry(log):
    """Over 0.2 m steps the wheel odometry is good to a few cm; ICP must land near it, not far away."""
    index, _ = sl.odometry_steps(log.laser_pose)
    gaps = []
    for a, b in zip(index[40:80], index[41:81]):
        init = sl.relative(log.laser_pose[a], log.laser_pose[b])
        src = sl.scan_to_points(log.ranges[b], log.angles, max_range=40.0, sensor_offset=log.sensor_offset)
        tgt = sl.scan_to_points(log.ranges[a], log.angles, max_range=40.0, sensor_offset=log.sensor_offset)
        res = sl.icp(src, tgt, init)
        gaps.append(np.hypot(*(res.pose[:2] - init[:2])))
    assert np.median(gaps) < 0.05 and np.max(gaps) < 0.3, (np.median(gaps), np.max(gaps))


def test_icp_align_option_is_the_point_to_point_step():
    """align= (how the autograder plugs in a student's icp_align) replaces the closed-form step and nothing else."""
    rng = np.random.default_rng(31)
    pose = np.array([0.2, -0.1, 0.08])
    target = _scan_points(ROOM, np.zeros(3), rng, 0.01)
    source = _scan_points(ROOM, pose, rng, 0.01)
    seen = []

    def align(P, Q):
        seen.append(P.shape[0])
        return sl.icp_align(P, Q)

    ref = sl.icp(source, target, method="point_to_point")
    got = sl.icp(source, target, method="point_to_point", align=align)
    assert len(seen) == got.iterations == ref.iterations
    np.testing.assert_array_equal(got.pose, ref.pose)
    np.testing.assert_array_equal(got.history, ref.history)
    # point-to-line never calls it
    line = sl.icp(source, target, method="point_to_line", align=align)
    assert len(seen) == got.iterations and line.converged
    # a wrong alignment changes the result
    bad = sl.icp(source, target, method="point_to_point", align=lambda P, Q: (np.eye(2), np.zeros(2)), max_iter=5)
    assert np.abs(bad.pose).max() == 0.0
    with pytest.raises(TypeError, match="align must be callable"):
        sl.icp(source, target, align="svd")
