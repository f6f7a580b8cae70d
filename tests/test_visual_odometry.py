"""Tests of slamlib.visual_odometry: stereo triangulation, 3-D alignment, trajectory errors, the KITTI drive."""

import numpy as np
import pytest

import slamlib as sl
from slamlib.datasets import load_kitti_vo

K = sl.calibration_matrix(700.0, 700.0, 600.0, 180.0)


def test_stereo_triangulation_inverts_the_stereo_projection():
    rng = np.random.default_rng(0)
    P = np.column_stack([rng.uniform(-5, 5, 20), rng.uniform(-2, 2, 20), rng.uniform(3, 40, 20)])
    b = 0.54
    uL = sl.project(K, np.eye(4), P)[0]
    right = np.eye(4)
    right[0, 3] = b
    uR = sl.project(K, right, P)[0]
    np.testing.assert_allclose(uL[:, 1], uR[:, 1])
    np.testing.assert_allclose(sl.stereo_triangulate(K, b, uL[:, 0], uR[:, 0], uL[:, 1]), P, rtol=1e-10)
    with pytest.raises(ValueError, match="disparity"):
        sl.stereo_triangulate(K, b, uR[:, 0], uL[:, 0], uL[:, 1])


def test_align_3d_recovers_the_motion_despite_outliers():
    rng = np.random.default_rng(1)
    P = rng.uniform(-10, 10, (100, 3))
    R = sl.so3_exp(np.array([0.1, -0.3, 0.2]))
    t = np.array([1.0, -2.0, 0.5])
    Q = P @ R.T + t + rng.normal(0, 0.01, P.shape)
    Q[:25] += rng.uniform(1.0, 3.0, (25, 3))
    R_hat, t_hat, inl = sl.align_3d(P, Q, rng=rng, threshold=0.05)
    np.testing.assert_array_equal(inl, np.arange(100) >= 25)
    np.testing.assert_allclose(R_hat, R, atol=1e-3)
    np.testing.assert_allclose(t_hat, t, atol=1e-2)
    assert np.linalg.det(R_hat) == pytest.approx(1.0)


def test_trajectory_errors_zero_for_the_reference_and_exact_for_a_scaled_copy():
    d = load_kitti_vo()
    np.testing.assert_allclose(sl.trajectory_errors(d.T_wc, d.T_wc), 0.0, atol=1e-12)
    scaled = d.T_wc.copy()
    scaled[:, :3, 3] = d.T_wc[0, :3, 3] + 1.1 * (d.T_wc[:, :3, 3] - d.T_wc[0, :3, 3])
    ate, rpe_t, rpe_r = sl.trajectory_errors(scaled, d.T_wc, delta=10)
    assert rpe_t == pytest.approx(10.0, rel=0.05)  # every segment 10 % too long (the path is nearly straight)
    assert rpe_r == pytest.approx(0.0, abs=1e-9)
    assert ate > 0


def test_visual_odometry_on_the_kitti_drive_bundle_adjustment_reduces_the_drift():
    d = load_kitti_vo()
    first = d.frame < 30
    sub = d._replace(T_wc=d.T_wc[:30], frame=d.frame[first], landmark=d.landmark[first], uL=d.uL[first],
                     uR=d.uR[first], v=d.v[first])
    res = sl.stereo_visual_odometry(sub, rng=np.random.default_rng(0), window=3, ba_iterations=4)
    ate_ba, rpe_ba, _ = sl.trajectory_errors(res.T_wc, sub.T_wc)
    ate_f2f, rpe_f2f, _ = sl.trajectory_errors(res.T_wc_frame_to_frame, sub.T_wc)
    assert res.inliers[1:].min() > 50
    assert ate_ba < 0.5 * ate_f2f and rpe_ba < 0.5 * rpe_f2f
    assert rpe_ba < 1.0  # percent
