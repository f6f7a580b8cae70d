"""Tests of slamlib.visual_odometry: stereo triangulation, 3-D alignment, trajectory errors, the KITTI drive."""

import numpy as np
import pytest

import slamlib as sl
from slamlib.datasets import load_kitti_vo, simulate_stereo_drive, stereo_vo_segment

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


def _rigidly_moved(T, R, t):
    out = T.copy()
    out[:, :3, :3] = R @ T[:, :3, :3]
    out[:, :3, 3] = T[:, :3, 3] @ R.T + t
    return out


def test_ate_after_alignment_ignores_a_rigid_motion_of_the_whole_trajectory():
    d = load_kitti_vo()
    moved = _rigidly_moved(d.T_wc, sl.so3_exp(np.array([0.02, -0.05, 0.03])), np.array([0.5, -0.2, 1.0]))
    ate, rpe_t, rpe_r = sl.trajectory_errors(moved, d.T_wc, align=True)
    assert ate == pytest.approx(0.0, abs=1e-9)
    assert (rpe_t, rpe_r) == pytest.approx((0.0, 0.0), abs=1e-9)  # relative errors see no rigid motion either
    assert sl.trajectory_errors(moved, d.T_wc)[0] > 0.5  # without alignment the offset counts
    # noise on the positions: the aligned ATE is at most the unaligned one
    noisy = d.T_wc.copy()
    noisy[:, :3, 3] += np.random.default_rng(3).normal(0, 0.05, (len(noisy), 3))
    assert sl.trajectory_errors(noisy, d.T_wc, align=True)[0] <= sl.trajectory_errors(noisy, d.T_wc)[0]
    with pytest.raises(TypeError, match="align"):
        sl.trajectory_errors(moved, d.T_wc, align="yes")


def test_relative_pose_errors_are_the_segments_behind_the_mean():
    d = load_kitti_vo()
    scaled = d.T_wc.copy()
    scaled[:, :3, 3] = 1.1 * d.T_wc[:, :3, 3]
    trans, rot = sl.relative_pose_errors(scaled, d.T_wc, delta=10)
    assert trans.shape == rot.shape == (len(d.T_wc) - 10,)
    np.testing.assert_allclose(trans, 10.0, rtol=0.05)
    _, rpe_t, rpe_r = sl.trajectory_errors(scaled, d.T_wc, delta=10)
    assert rpe_t == pytest.approx(trans.mean()) and rpe_r == pytest.approx(rot.mean())
    with pytest.raises(ValueError, match="delta"):
        sl.relative_pose_errors(scaled, d.T_wc, delta=len(d.T_wc))
    with pytest.raises(ValueError, match="T_ref"):
        sl.relative_pose_errors(scaled, d.T_wc[:-1])


@pytest.mark.parametrize("kw, name", [({"threshold": -1.0}, "threshold"), ({"max_depth": 0.0}, "max_depth"),
                                      ({"ba_iterations": 0}, "ba_iterations"), ({"robust": "tukey"}, "robust"),
                                      ({"robust_scale": -2.0}, "robust_scale"),
                                      ({"ransac_iterations": 0}, "ransac_iterations"), ({"window": 2}, "window")])
def test_visual_odometry_refuses_bad_parameters_by_name(kw, name):
    d = stereo_vo_segment(load_kitti_vo(), 0, 4)
    with pytest.raises((ValueError, TypeError), match=name):
        sl.stereo_visual_odometry(d, rng=np.random.default_rng(0), **kw)


def test_kernel_width_and_ransac_samples_reach_the_pipeline():
    d = stereo_vo_segment(load_kitti_vo(), 0, 8)
    base = sl.stereo_visual_odometry(d, rng=np.random.default_rng(0), window=3, ba_iterations=2)
    wide = sl.stereo_visual_odometry(d, rng=np.random.default_rng(0), window=3, ba_iterations=2, robust_scale=50.0)
    assert np.abs(wide.T_wc - base.T_wc).max() > 1e-6
    one = sl.stereo_visual_odometry(d, rng=np.random.default_rng(0), ba=False, ransac_iterations=1)
    many = sl.stereo_visual_odometry(d, rng=np.random.default_rng(0), ba=False)
    assert np.abs(one.T_wc - many.T_wc).max() > 1e-6


def test_segment_of_a_drive_is_a_drive_of_its_own():
    d = load_kitti_vo()
    s = stereo_vo_segment(d, 38, 77)
    np.testing.assert_array_equal(s.T_wc, d.T_wc[38:])
    assert s.frame.min() == 0 and s.frame.max() == 38
    np.testing.assert_array_equal(s.uL, d.uL[d.frame >= 38])
    with pytest.raises(ValueError, match="stop"):
        stereo_vo_segment(d, 10, 11)
    with pytest.raises(TypeError, match="data"):
        stereo_vo_segment(d._asdict(), 0, 5)


def test_simulated_drive_is_exact_without_noise_and_has_the_asked_share_of_wrong_tracks():
    clean = simulate_stereo_drive(rng=np.random.default_rng(5), n_frames=12, noise_px=0.0, outlier_rate=0.0)
    assert np.all(clean.uL > clean.uR) and np.all(np.diff(clean.frame) >= 0)
    assert np.bincount(clean.landmark).min() >= 2  # every track spans two frames at least
    assert np.bincount(clean.frame).min() > 200
    vo = sl.stereo_visual_odometry(clean, rng=np.random.default_rng(0), ba=False)
    np.testing.assert_allclose(vo.T_wc, clean.T_wc, atol=1e-8)  # exact stereo points: exact motion
    bad = simulate_stereo_drive(rng=np.random.default_rng(5), n_frames=12, noise_px=0.0, outlier_rate=0.3)
    np.testing.assert_array_equal(bad.landmark, clean.landmark)
    changed = np.mean((bad.uL != clean.uL) | (bad.v != clean.v))
    assert 0.25 < changed < 0.31  # 30 % drawn, a few replaced by themselves or an identical pixel
    with pytest.raises(ValueError, match="outlier_rate"):
        simulate_stereo_drive(rng=np.random.default_rng(5), outlier_rate=1.0)


def test_default_parameters_hold_on_a_simulated_drive_with_wrong_tracks_and_noise():
    d = simulate_stereo_drive(rng=np.random.default_rng(7), n_frames=25, noise_px=1.0, outlier_rate=0.2)
    vo = sl.stereo_visual_odometry(d, rng=np.random.default_rng(0))
    ate, rpe_t, rpe_r = sl.trajectory_errors(vo.T_wc, d.T_wc, align=True)
    _, rpe_f2f, _ = sl.trajectory_errors(vo.T_wc_frame_to_frame, d.T_wc, align=True)
    assert rpe_t < 1.0 and ate < 0.1  # percent, metres against the true poses
    assert rpe_t < 0.25 * rpe_f2f


def test_defaults_are_the_choice_of_the_cross_validation_study():
    import inspect
    import json
    from pathlib import Path

    study = json.loads((Path(__file__).parents[1] / "chapters" / "data" / "vo_study.json").read_text())
    sig = inspect.signature(sl.stereo_visual_odometry).parameters
    defaults = {name: sig[name].default for name in study["final"]}
    assert defaults == study["final"]
