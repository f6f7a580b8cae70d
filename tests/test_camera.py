"""Tests of slamlib.camera: projection and its Jacobians, triangulation, the essential matrix, RANSAC, matching."""

import numpy as np
import pytest

import slamlib as sl

K = sl.calibration_matrix(520.0, 500.0, 320.0, 240.0)


def _pose(rng, scale=1.0):
    return sl.pose_matrix(sl.so3_exp(rng.normal(size=3) * 0.3), rng.normal(size=3) * scale)


def _perturb(T, d):
    R, t = T[:3, :3], T[:3, 3]
    return sl.pose_matrix(R @ sl.so3_exp(d[3:]), t + R @ d[:3])


def _points_in_front(rng, T, n, near=3.0, far=9.0):
    pc = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(near, far, n)])
    return pc @ T[:3, :3].T + T[:3, 3]


def _two_views(rng, n=60, baseline=1.0):
    T1 = _pose(rng)
    T2 = _perturb(T1, np.r_[rng.normal(size=3) * 0.2 + [baseline, 0, 0], rng.normal(size=3) * 0.05])
    P = _points_in_front(rng, T1, n)
    return T1, T2, P


# --------------------------------------------------------------------------- projection
def test_project_matches_the_pinhole_formula():
    rng = np.random.default_rng(2)
    T = _pose(rng)
    P = _points_in_front(rng, T, 10)
    uv, _, _ = sl.project(K, T, P)
    pc = (P - T[:3, 3]) @ T[:3, :3]
    np.testing.assert_allclose(uv, np.column_stack([520 * pc[:, 0] / pc[:, 2] + 320, 500 * pc[:, 1] / pc[:, 2] + 240]))


def test_project_jacobians_match_finite_differences():
    rng = np.random.default_rng(3)
    for _ in range(5):
        T = _pose(rng, 3.0)
        P = _points_in_front(rng, T, 6, near=1.0)
        _, Jp, Jx = sl.project(K, T, P)
        h = 1e-6
        num_p = np.stack([(sl.project(K, _perturb(T, h * e), P)[0] - sl.project(K, _perturb(T, -h * e), P)[0]) / (2 * h)
                          for e in np.eye(6)], -1)
        num_x = np.stack([(sl.project(K, T, P + h * e)[0] - sl.project(K, T, P - h * e)[0]) / (2 * h)
                          for e in np.eye(3)], -1)
        np.testing.assert_allclose(Jp, num_p, atol=1e-4, rtol=1e-6)
        np.testing.assert_allclose(Jx, num_x, atol=1e-4, rtol=1e-6)


def test_project_refuses_points_behind_the_camera_and_bad_poses():
    with pytest.raises(ValueError, match="P must lie in front"):
        sl.project(K, np.eye(4), np.array([[0.0, 0.0, -1.0]]))
    bad = np.eye(4)
    bad[0, 0] = -1.0
    with pytest.raises(ValueError, match="T_wc"):
        sl.project(K, bad, np.array([[0.0, 0.0, 1.0]]))
    with pytest.raises(ValueError, match="K must be"):
        sl.project(np.eye(3) * 2, np.eye(4), np.array([[0.0, 0.0, 1.0]]))
    with pytest.raises(ValueError, match="P must have shape"):
        sl.project(K, np.eye(4), np.array([0.0, 0.0, 1.0]))


# --------------------------------------------------------------------------- triangulation
def test_triangulate_exact_pixels_recovers_the_points():
    rng = np.random.default_rng(4)
    T1, T2, P = _two_views(rng)
    uv1, uv2 = sl.project(K, T1, P)[0], sl.project(K, T2, P)[0]
    np.testing.assert_allclose(sl.triangulate(K, T1, T2, uv1, uv2), P, atol=1e-8)


def test_triangulate_noisy_pixels_is_the_dlt_of_the_contract():
    """The homogeneous DLT in pixel rows (HZ 12.2), checked against an independent 4x4 SVD per point."""
    rng = np.random.default_rng(5)
    T1, T2, P = _two_views(rng, n=8)
    uv1 = sl.project(K, T1, P)[0] + rng.normal(0, 2.0, (8, 2))
    uv2 = sl.project(K, T2, P)[0] + rng.normal(0, 2.0, (8, 2))
    got = sl.triangulate(K, T1, T2, uv1, uv2)
    C = [K @ np.column_stack([T[:3, :3].T, -T[:3, :3].T @ T[:3, 3]]) for T in (T1, T2)]
    for k in range(8):
        A = np.array([uv1[k, 0] * C[0][2] - C[0][0], uv1[k, 1] * C[0][2] - C[0][1],
                      uv2[k, 0] * C[1][2] - C[1][0], uv2[k, 1] * C[1][2] - C[1][1]])
        X = np.linalg.svd(A)[2][-1]
        np.testing.assert_allclose(got[k], X[:3] / X[3], rtol=1e-9)
    assert np.abs(got - P).max() < 1.0


# --------------------------------------------------------------------------- essential matrix
def _normalized_matches(rng, n=60, noise=0.0):
    T1, T2, P = _two_views(rng, n)
    x1 = sl.to_normalized(K, sl.project(K, T1, P)[0] + rng.normal(0, noise, (n, 2)))
    x2 = sl.to_normalized(K, sl.project(K, T2, P)[0] + rng.normal(0, noise, (n, 2)))
    rel = np.linalg.inv(T1) @ T2  # camera 2 in camera 1's frame
    return x1, x2, rel


def test_eight_point_exact_matches_satisfy_the_epipolar_constraint_and_recover_the_motion():
    rng = np.random.default_rng(6)
    x1, x2, rel = _normalized_matches(rng)
    E = sl.eight_point(x1, x2)
    h1, h2 = np.c_[x1, np.ones(len(x1))], np.c_[x2, np.ones(len(x2))]
    assert np.abs(np.einsum("ni,ij,nj->n", h2, E, h1)).max() < 1e-12
    np.testing.assert_allclose(np.linalg.svd(E)[1], [1, 1, 0], atol=1e-12)
    T, P, front = sl.recover_pose(E, x1, x2)
    assert front.all()
    np.testing.assert_allclose(T[:3, :3], rel[:3, :3], atol=1e-9)
    np.testing.assert_allclose(T[:3, 3], rel[:3, 3] / np.linalg.norm(rel[:3, 3]), atol=1e-9)


def test_eight_point_uses_hartley_normalisation():
    """On noisy pixel-scale data, the normalised algorithm differs from the unnormalised one and is what HZ 11.1 gives."""
    rng = np.random.default_rng(7)
    x1, x2, _ = _normalized_matches(rng, n=30, noise=1.0)
    x1, x2 = x1 + 3.0, x2 - 2.0  # far from the origin: normalisation matters

    def norm(x):
        c = x.mean(0)
        s = np.sqrt(2) / np.linalg.norm(x - c, axis=1).mean()
        return np.array([[s, 0, -s * c[0]], [0, s, -s * c[1]], [0, 0, 1]])

    T1, T2 = norm(x1), norm(x2)
    a = np.c_[x1, np.ones(30)] @ T1.T
    b = np.c_[x2, np.ones(30)] @ T2.T
    A = np.einsum("ni,nj->nij", b, a).reshape(30, 9)
    F = np.linalg.svd(A)[2][-1].reshape(3, 3)
    U, _, Vt = np.linalg.svd(T2.T @ F @ T1)
    E_ref = U @ np.diag([1, 1, 0]) @ Vt
    E = sl.eight_point(x1, x2)
    s = np.sign(np.sum(E * E_ref))
    np.testing.assert_allclose(s * E, E_ref, atol=1e-9)


def _true_essential(rel):
    """``E = [t]x R`` of the motion ``x2 = R x1 + t`` between the cameras of ``rel`` (camera 2 in camera 1's frame)."""
    R, t = rel[:3, :3].T, -rel[:3, :3].T @ rel[:3, 3]
    return sl.lie.hat(t / np.linalg.norm(t)) @ R


def _matches_with_outliers(rng, *, noise):
    """200 matches of :func:`_normalized_matches` at `noise` px, 60 of them (30 %) replaced by uniform outliers."""
    x1, x2, rel = _normalized_matches(rng, n=200, noise=noise)
    out = rng.choice(200, 60, replace=False)
    x2 = x2.copy()
    x2[out] = rng.uniform(-0.6, 0.6, (60, 2))
    return x1, x2, rel


def test_ransac_finds_the_true_consensus_and_stops_early():
    """30 % outliers, 0.5 px noise, a threshold of 2 px: RANSAC's inliers are the true geometry's.

    A scene is right when RANSAC's inliers differ from the matches the true ``E`` accepts
    (outliers that fall near their epipolar line included) by at most 3, and its rotation
    is within 0.015 rad (the eight-point fit to all true matches: at most 0.012 over 1000
    scenes). Measured over 1500 scenes (seeds 1408-2907, not the ones the method was
    developed on): 5 not right (two a wrong local optimum missing 17 and 21 true matches,
    three with 3-4 accepted outliers, two of them pulling the rotation 0.018 and 0.024 rad). At most one of
    four scenes may be wrong: false failure ~6 (0.0033)^2 ~ 7e-5. Without the refinement
    (``refine=False``) 104 of 300 scenes are not right by the old bounds (68 miss more than
    14 true matches).
    """
    wrong, iterations = 0, []
    for seed in range(8, 12):
        x1, x2, rel = _matches_with_outliers(np.random.default_rng(seed), noise=0.5)
        res = sl.essential_ransac(x1, x2, threshold=2.0 / 520, rng=np.random.default_rng(seed - 8))
        np.testing.assert_allclose(np.linalg.svd(res.E)[1], [1.0, 1.0, 0.0], atol=1e-9)  # still essential
        truth_accepts = sl.sampson_distance(_true_essential(rel), x1, x2) < (2.0 / 520) ** 2
        T, _, _ = sl.recover_pose(res.E, x1[res.inliers], x2[res.inliers])
        ang = np.linalg.norm(sl.lie.so3_log(T[:3, :3].T @ rel[:3, :3]))
        wrong += (res.inliers != truth_accepts).sum() > 3 or ang > 0.015
        iterations.append(res.iterations)
    assert wrong <= 1
    # the adaptive count stops near N(0.7) = 117 samples, far before max_iter (at most 634 over the 1500 scenes)
    assert max(iterations) < 2000 and np.median(iterations) < 300


def test_ransac_adaptive_count_stops_after_one_sample_without_outliers():
    rng = np.random.default_rng(12)
    x1, x2, _ = _normalized_matches(rng, n=50)
    res = sl.essential_ransac(x1, x2, threshold=1e-4, rng=rng)
    assert res.iterations == 1 and res.inliers.all()
    # half outliers: many more samples, as N = log(1 - p) / log(1 - w^8) demands
    x2 = x2.copy()
    x2[::2] = rng.uniform(-0.5, 0.5, (25, 2))
    res = sl.essential_ransac(x1, x2, threshold=1e-4, rng=rng)
    assert 100 < res.iterations <= sl.ransac_iterations(0.5, 8, 0.999)
    np.testing.assert_array_equal(res.inliers, np.arange(50) % 2 == 1)


def test_ransac_skips_degenerate_samples():
    """A sample whose fit is not finite (repeated keypoints: SIFT gives one per orientation at a spot) or fails."""
    rng = np.random.default_rng(13)
    x1, x2, _ = _normalized_matches(rng, n=30)
    calls = []

    def flaky(a, b):
        calls.append(len(a))
        if len(calls) == 1:
            return np.full((3, 3), np.nan)
        if len(calls) == 2:
            raise np.linalg.LinAlgError("SVD did not converge")
        return sl.eight_point(a, b)

    res = sl.essential_ransac(x1, x2, threshold=1e-4, rng=np.random.default_rng(0), eight_point=flaky)
    assert res.inliers.all() and res.iterations == 3


def test_ransac_cheirality_rejects_the_wrong_models_of_a_loose_threshold():
    """2 px noise, 30 % outliers, a threshold of 16 px (8 sigma): a wrong model explains as many matches as the truth.

    Many of its "inliers" then lie behind a camera; counting only matches in front of both cameras
    (``cheirality=True``) rejects it. Measured over 300 scenes of this family (``_normalized_matches``
    with these settings; scene seeds 50000-50299 of the evaluation, RANSAC seeds 7000-7299, not these):
    rotation off by more than 5 deg (twice the q99 of the eight-point fit to all true matches,
    2.3 deg) in 91 scenes with ``cheirality=False`` and 7 with ``True`` (2.3 %, Wilson 95 % up to
    4.7 %). At most 2 of these 10 scenes may be wrong: false failure ~1e-3 at 2.3 %, ~1e-2 at 4.7 %.
    On these 10 scenes ``cheirality=True`` is wrong in 1; ``False`` is wrong in 2 (the count alone
    would not tell them apart) and returns inliers behind a camera in 9, which the first assertion catches.
    """
    wrong = 0
    for seed in range(20, 30):
        x1, x2, rel = _matches_with_outliers(np.random.default_rng(seed), noise=2.0)
        res = sl.essential_ransac(x1, x2, threshold=16.0 / 520, rng=np.random.default_rng(seed), cheirality=True)
        T, _, front = sl.recover_pose(res.E, x1[res.inliers], x2[res.inliers])
        assert front.all()  # the inliers are the matches in front of both cameras
        wrong += np.linalg.norm(sl.lie.so3_log(T[:3, :3].T @ rel[:3, :3])) > np.radians(5.0)
    assert wrong <= 2


def test_ransac_refuses_a_cheirality_that_is_not_a_bool():
    rng = np.random.default_rng(13)
    x1, x2, _ = _normalized_matches(rng, n=30)
    with pytest.raises(TypeError, match="cheirality must be a bool"):
        sl.essential_ransac(x1, x2, threshold=1e-4, rng=rng, cheirality=1)
    with pytest.raises(TypeError, match="cheirality must be a bool"):
        sl.two_view_reconstruction(K, x1 * 520 + 320, x2 * 500 + 240, threshold=1.0, rng=rng, cheirality="yes")


def test_ransac_refuses_a_refine_that_is_not_a_bool():
    rng = np.random.default_rng(13)
    x1, x2, _ = _normalized_matches(rng, n=30)
    with pytest.raises(TypeError, match="refine must be a bool"):
        sl.essential_ransac(x1, x2, threshold=1e-4, rng=rng, refine="no")
    with pytest.raises(TypeError, match="refine must be a bool"):
        sl.two_view_reconstruction(K, x1 * 520 + 320, x2 * 500 + 240, threshold=1.0, rng=rng, refine=0)


def test_ransac_iterations_formula():
    assert sl.ransac_iterations(0.5, 8, 0.99) == int(np.ceil(np.log(0.01) / np.log(1 - 0.5**8)))
    assert sl.ransac_iterations(1.0, 8, 0.99) == 1
    assert sl.ransac_iterations(0.0, 8, 0.99) == np.inf
    with pytest.raises(ValueError, match="confidence"):
        sl.ransac_iterations(0.5, 8, 1.0)


def test_decompose_essential_gives_four_solutions_one_in_front():
    rng = np.random.default_rng(9)
    x1, x2, rel = _normalized_matches(rng)
    Rs, ts = sl.decompose_essential(sl.eight_point(x1, x2))
    assert Rs.shape == (4, 3, 3) and ts.shape == (4, 3)
    np.testing.assert_allclose(np.linalg.det(Rs), 1.0)
    ok = [np.allclose(R, rel[:3, :3].T, atol=1e-8) for R in Rs]
    assert sum(ok) == 2


def test_epipolar_lines_pass_through_the_matches():
    rng = np.random.default_rng(10)
    x1, x2, _ = _normalized_matches(rng)
    L = sl.epipolar_lines(sl.eight_point(x1, x2), x1)
    assert np.abs(np.einsum("ni,ni->n", L, np.c_[x2, np.ones(len(x2))])).max() < 1e-12


def test_eight_point_needs_eight_matches():
    with pytest.raises(ValueError, match="at least 8"):
        sl.eight_point(np.zeros((7, 2)), np.zeros((7, 2)))
    with pytest.raises(ValueError, match="x2 must have the shape"):
        sl.eight_point(np.zeros((9, 2)), np.zeros((8, 2)))


# --------------------------------------------------------------------------- matching
def test_match_descriptors_ratio_test_and_cross_check():
    rng = np.random.default_rng(11)
    d2 = rng.normal(size=(50, 16))
    perm = rng.permutation(50)[:30]
    d1 = d2[perm] + rng.normal(0, 0.05, (30, 16))
    j0 = int(np.setdiff1d(np.arange(50), perm)[0])  # a descriptor of image 2 that no true match uses
    amb = d2[j0] + 1e-3  # equally close to two descriptors of image 2: the ratio test drops it
    d2 = np.vstack([d2, d2[j0] + 2e-3])
    m = sl.match_descriptors(np.vstack([d1, amb]), d2)
    np.testing.assert_array_equal(m, np.column_stack([np.arange(30), perm]))
    assert m.dtype.kind == "i"
    with pytest.raises(ValueError, match="d2 must have shape"):
        sl.match_descriptors(d1, d2[:, :5])


def test_balbianello_matches_give_a_consistent_essential_matrix():
    from slamlib.datasets import load_balbianello_keys

    k1, k2 = load_balbianello_keys(1), load_balbianello_keys(2)
    m = sl.match_descriptors(k1.descriptors, k2.descriptors)
    assert len(m) > 300
    Kb = k1.K
    x1 = sl.to_normalized(Kb, k1.uv[m[:, 0]])
    x2 = sl.to_normalized(Kb, k2.uv[m[:, 1]])
    res = sl.essential_ransac(x1, x2, threshold=2.0 / Kb[0, 0], rng=np.random.default_rng(0))
    assert res.inliers.mean() > 0.6
    T, P, front = sl.recover_pose(res.E, x1[res.inliers], x2[res.inliers])
    assert front.mean() > 0.95
