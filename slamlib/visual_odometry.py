"""Stereo visual odometry: frame-to-frame motion from triangulated points, refined by a sliding-window bundle adjustment.

A calibrated stereo pair sees each tracked landmark in both images of a frame; its
disparity ``d = uL - uR`` gives its depth ``Z = fx b / d`` and so its 3-D position in
the left camera (:func:`stereo_triangulate`). The landmarks seen in two consecutive
frames are two clouds of the same points in two camera frames: their rigid alignment
(:func:`align_3d`, Umeyama/Kabsch inside RANSAC with three-point samples) is the motion
between the frames. Chained, these motions drift; after each frame a bundle adjustment
over the last ``window`` frames (:func:`slamlib.bundle_adjust`, the reprojection
errors in both images of each frame, the right camera a fixed ``b`` to the left
one's right, the oldest frame of the window held fixed as the gauge, Cauchy kernel)
refines the newest poses and the points they see.
:func:`trajectory_errors` measures the drift against a reference trajectory: the
absolute trajectory error (RMS of position differences, with no alignment, both starting
at the same pose, or after the best rigid alignment) and the relative pose error over
segments of ``delta`` frames (translation in % of the distance travelled, rotation in
degrees per metre, as the KITTI odometry benchmark reports them).

References
----------
D. Nister, O. Naroditsky, J. Bergen, "Visual odometry", CVPR 2004; D. Scaramuzza, F.
Fraundorfer, "Visual odometry: Part I", IEEE RAM 18(4), 2011; S. Umeyama, "Least-squares
estimation of transformation parameters between two point patterns", IEEE TPAMI 13(4),
1991 (Eqs. 38-42, here in 3-D); A. Geiger, P. Lenz, R. Urtasun, "Are we ready for autonomous
driving? The KITTI vision benchmark suite", CVPR 2012 (the odometry metrics); J. Sturm et al.,
"A benchmark for the evaluation of RGB-D SLAM systems", IROS 2012 (ATE and RPE).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ._checks import as_array, as_count, as_scalar, check_choice, check_rng
from .lie import _so3_log
from .bundle_adjustment import bundle_adjust

__all__ = ["stereo_triangulate", "align_3d", "VOResult", "stereo_visual_odometry", "relative_pose_errors",
           "trajectory_errors"]


def stereo_triangulate(K, baseline, uL, uR, v):
    """Points in the left camera from rectified stereo pixels.

    Parameters
    ----------
    K : ndarray, shape (3, 3)
        Calibration of the (rectified) left camera.
    baseline : float
        ``b``, the right camera's offset along x [m].
    uL, uR, v : ndarray, shape (N,)
        Columns in the left and right images and the shared row; ``uL > uR``.

    Returns
    -------
    ndarray, shape (N, 3)
        ``Z = fx b / (uL - uR)``, ``X = (uL - cx) Z / fx``, ``Y = (v - cy) Z / fy``.
    """
    K = as_array(K, "K", (3, 3))
    b = as_scalar(baseline, "baseline", positive=True)
    uL = as_array(uL, "uL", ndim=1)
    uR = as_array(uR, "uR", (uL.size,), ref="uL")
    v = as_array(v, "v", (uL.size,), ref="uL")
    if np.any(uL - uR <= 0):
        raise ValueError("uL - uR (the disparity) must be positive for every point")
    return _stereo(K, b, uL, uR, v)


def _stereo(K, b, uL, uR, v):
    Z = K[0, 0] * b / (uL - uR)
    return np.column_stack([(uL - K[0, 2]) * Z / K[0, 0], (v - K[1, 2]) * Z / K[1, 1], Z])


def _kabsch(P, Q):
    """``(R, t)`` minimising ``sum |R p_k + t - q_k|^2`` over rotations (Umeyama 1991, Eqs. 38-42, 3-D)."""
    mp, mq = P.mean(axis=0), Q.mean(axis=0)
    U, _, Vt = np.linalg.svd((Q - mq).T @ (P - mp))
    d = 1.0 if np.linalg.det(U) * np.linalg.det(Vt) >= 0 else -1.0
    R = U @ np.diag([1.0, 1.0, d]) @ Vt
    return R, mq - R @ mp


def align_3d(P, Q, *, rng, threshold, scale=None, confidence=0.999, max_iter=500):
    """Rigid motion between two 3-D point clouds with outliers: Kabsch inside RANSAC.

    Parameters
    ----------
    P, Q : ndarray, shape (N, 3)
        Matched points, ``N >= 3``: ``q_k = R p_k + t`` for the inliers.
    rng : numpy.random.Generator, keyword-only
        Draws the three-point samples (``rng.choice(N, 3, replace=False)``).
    threshold : float, keyword-only
        Inlier threshold on ``|R p_k + t - q_k| / scale_k``.
    scale : ndarray, shape (N,), optional, keyword-only
        Per-match scale of the residual (e.g. the depth uncertainty of stereo points,
        ``Z^2 / (fx b)`` per pixel of disparity); ones by default.
    confidence, max_iter : keyword-only
        The adaptive number of samples, as in :func:`slamlib.essential_ransac`.

    Returns
    -------
    R : ndarray, shape (3, 3)
    t : ndarray, shape (3,)
        Refitted on all inliers of the best sample.
    inliers : ndarray of bool, shape (N,)
    """
    P = as_array(P, "P", (None, 3))
    Q = as_array(Q, "Q", P.shape, ref="P")
    if len(P) < 3:
        raise ValueError(f"P must hold at least 3 matches, got {len(P)}")
    check_rng(rng)
    thr = as_scalar(threshold, "threshold", positive=True)
    sc = np.ones(len(P)) if scale is None else as_array(scale, "scale", (len(P),), ref="P")
    p = as_scalar(confidence, "confidence", positive=True)
    max_iter = as_count(max_iter, "max_iter", minimum=1)
    best = np.zeros(len(P), dtype=bool)
    needed, it = max_iter, 0
    while it < min(needed, max_iter):
        it += 1
        idx = rng.choice(len(P), 3, replace=False)
        R, t = _kabsch(P[idx], Q[idx])
        inl = np.linalg.norm(P @ R.T + t - Q, axis=1) < thr * sc
        if inl.sum() > best.sum():
            best = inl
            w3 = inl.mean() ** 3
            needed = 1 if w3 >= 1 else math.ceil(math.log(1 - p) / math.log1p(-w3))
    if best.sum() < 3:
        raise ValueError("align_3d found fewer than 3 inliers")
    R, t = _kabsch(P[best], Q[best])
    return R, t, np.linalg.norm(P @ R.T + t - Q, axis=1) < thr * sc


class VOResult(NamedTuple):
    """Result of :func:`stereo_visual_odometry`.

    Attributes
    ----------
    T_wc : ndarray, shape (F, 4, 4)
        Left-camera poses after the sliding-window bundle adjustment.
    T_wc_frame_to_frame : ndarray, shape (F, 4, 4)
        The poses chained from the frame-to-frame alignments alone.
    inliers : ndarray of int, shape (F,)
        Landmarks of each frame kept by the alignment with the previous one (0 for frame 0).
    """

    T_wc: np.ndarray
    T_wc_frame_to_frame: np.ndarray
    inliers: np.ndarray


def stereo_visual_odometry(data, *, rng, window=3, max_depth=80.0, threshold=1.0, ba=True, ba_iterations=8,
                           robust="cauchy", robust_scale=1.0, ransac_iterations=500):
    """Stereo visual odometry: frame-to-frame 3-D alignment, then a sliding-window bundle adjustment.

    Parameters
    ----------
    data : slamlib.datasets.StereoVOData
        Calibration, stereo measurements ``(frame, landmark, uL, uR, v)`` and the
        reference poses (only the first is used: the start).
    rng : numpy.random.Generator, keyword-only
        RANSAC's samples.
    window : int, keyword-only
        Frames in the bundle adjustment (the oldest held fixed), at least 3.
    max_depth : float, keyword-only
        Landmarks farther than this [m] (small disparity, poor depth) are neither aligned
        nor adjusted.
    threshold : float, keyword-only
        RANSAC inlier threshold in pixels of disparity (the residual divided by the
        depth uncertainty ``Z^2 / (fx b)``).
    ba : bool, keyword-only
        Run the sliding-window bundle adjustment (else frame-to-frame only).
    ba_iterations : int, keyword-only
        Levenberg-Marquardt iterations per window.
    robust : {"cauchy", "huber"} or None, keyword-only
        Kernel of the window's reprojection errors.
    robust_scale : float or None, keyword-only
        The kernel's width in pixels (None: that of :func:`slamlib.bundle_adjust`, 2.45).
    ransac_iterations : int, keyword-only
        Most RANSAC samples per frame (fewer when the adaptive count of
        :func:`align_3d` is reached first).

    Returns
    -------
    VOResult

    Notes
    -----
    The defaults are the choice of a cross-validation on the two halves of the KITTI
    drive of :func:`slamlib.datasets.load_kitti_vo`, checked on simulated drives with
    outliers and pixel noise (``benchmarks/vo_study.py``; chapter 16 reports it).
    """
    check_rng(rng)
    window = as_count(window, "window", minimum=3)
    max_depth = as_scalar(max_depth, "max_depth", positive=True)
    threshold = as_scalar(threshold, "threshold", positive=True)
    ba_iterations = as_count(ba_iterations, "ba_iterations", minimum=1)
    ransac_iterations = as_count(ransac_iterations, "ransac_iterations", minimum=1)
    if robust is not None:
        check_choice(robust, "robust", {"cauchy": "Cauchy kernel", "huber": "Huber kernel"})
    if robust_scale is not None:
        robust_scale = as_scalar(robust_scale, "robust_scale", positive=True)
    K, b = data.K, data.baseline
    frame, lm = data.frame, data.landmark
    F = int(frame.max()) + 1
    pts = _stereo(K, b, data.uL, data.uR, data.v)  # each measurement's point in its left camera
    starts = np.searchsorted(frame, np.arange(F + 1))
    T = np.zeros((F, 4, 4))
    T[0] = data.T_wc[0]
    T_f2f = T.copy()
    n_inl = np.zeros(F, dtype=np.int64)
    sigma_z = pts[:, 2] ** 2 / (K[0, 0] * b)  # depth error per pixel of disparity
    for k in range(1, F):
        a, c = slice(starts[k - 1], starts[k]), slice(starts[k], starts[k + 1])
        common, ia, ic = np.intersect1d(lm[a], lm[c], return_indices=True)
        ia, ic = ia + starts[k - 1], ic + starts[k]
        near = (pts[ia, 2] < max_depth) & (pts[ic, 2] < max_depth)
        ia, ic = ia[near], ic[near]
        # p_{k-1} = R p_k + t: the pose of frame k in frame k-1
        R, t, inl = align_3d(pts[ic], pts[ia], rng=rng, threshold=threshold, scale=sigma_z[ia],
                               max_iter=ransac_iterations)
        n_inl[k] = int(inl.sum())
        rel = np.eye(4)
        rel[:3, :3], rel[:3, 3] = R, t
        T_f2f[k] = T_f2f[k - 1] @ rel
        T[k] = T[k - 1] @ rel
        if ba:
            T = _window_ba(T, k, window, starts, lm, data, pts, max_depth, ba_iterations, robust,
                           robust_scale)
    return VOResult(T, T_f2f, n_inl)


def _window_ba(T, k, window, starts, lm, data, pts, max_depth, iterations, robust, robust_scale):
    """Bundle adjustment of frames ``k - window + 1 .. k`` (the oldest fixed) on both images of each frame."""
    f0 = max(0, k - window + 1)
    sel = np.arange(starts[f0], starts[k + 1])
    sel = sel[pts[sel, 2] < max_depth]
    ids, inv, counts = np.unique(lm[sel], return_inverse=True, return_counts=True)
    keep = counts[inv] >= 2  # landmarks seen in two frames of the window at least
    sel, inv = sel[keep], inv[keep]
    ids, inv = np.unique(inv, return_inverse=True)
    cam = data.frame[sel] - f0
    # initial points: each landmark from its first measurement in the window, through that frame's pose
    first = np.full(ids.size, -1)
    first[inv[::-1]] = sel[::-1]
    f_first = data.frame[first]
    X0 = np.einsum("kij,kj->ki", T[f_first, :3, :3], pts[first]) + T[f_first, :3, 3]
    # both images of every measurement: the left camera, and the right one b to its right
    n = len(sel)
    uv = np.concatenate([np.column_stack([data.uL[sel], data.v[sel]]), np.column_stack([data.uR[sel], data.v[sel]])])
    offset = np.zeros((2 * n, 3))
    offset[n:, 0] = data.baseline
    res = bundle_adjust(T[f0:k + 1], X0, data.K, np.concatenate([cam, cam]), np.concatenate([inv, inv]), uv,
                        fixed=(0,), robust=robust, robust_scale=robust_scale, max_iter=iterations, rtol=1e-8,
                        offset=offset)
    out = T.copy()
    out[f0:k + 1] = res.T_wc
    return out


def relative_pose_errors(T_est, T_ref, *, delta=10):
    """Relative pose errors of every segment of ``delta`` frames, per metre travelled.

    Parameters
    ----------
    T_est, T_ref : ndarray, shape (F, 4, 4)
        Poses (camera-to-world) of the same frames.
    delta : int, keyword-only
        Segment length in frames, ``1 <= delta < F``.

    Returns
    -------
    trans : ndarray, shape (S,)
        ``100 |t_err| / travelled`` of each segment ``(i, i + delta)`` [%], with
        ``E = (T_ref,i^-1 T_ref,j)^-1 (T_est,i^-1 T_est,j)`` and travelled the
        reference's path length over the segment (segments where the reference does
        not move are left out).
    rot : ndarray, shape (S,)
        ``|Log(R_err)| / travelled`` of each segment [deg/m].

    References
    ----------
    Sturm et al. (2012) (RPE); Geiger et al. (2012) (KITTI's errors per length travelled).
    """
    T_est = as_array(T_est, "T_est", (None, 4, 4))
    T_ref = as_array(T_ref, "T_ref", T_est.shape, ref="T_est")
    delta = as_count(delta, "delta", minimum=1)
    if delta >= len(T_est):
        raise ValueError(f"delta must be smaller than the number of frames {len(T_est)}, got {delta}")
    return _relative_errors(T_est, T_ref, delta)


def _relative_errors(T_est, T_ref, delta):
    steps = np.linalg.norm(np.diff(T_ref[:, :3, 3], axis=0), axis=1)
    dist = np.concatenate([[0.0], np.cumsum(steps)])
    i = np.arange(len(T_est) - delta)
    j = i + delta
    rel_ref = np.linalg.inv(T_ref[i]) @ T_ref[j]
    rel_est = np.linalg.inv(T_est[i]) @ T_est[j]
    E = np.linalg.inv(rel_ref) @ rel_est
    length = dist[j] - dist[i]
    ok = length > 1e-6
    trans = np.linalg.norm(E[:, :3, 3], axis=1)[ok] / length[ok]
    rot = np.linalg.norm(_so3_log(E[:, :3, :3]), axis=1)[ok] / length[ok]
    return 100.0 * trans, np.degrees(rot)


def trajectory_errors(T_est, T_ref, *, delta=10, align=False):
    """Drift of an estimated trajectory against a reference: ATE and relative pose errors.

    Parameters
    ----------
    T_est, T_ref : ndarray, shape (F, 4, 4)
        Poses (camera-to-world) of the same frames, starting at the same pose.
    delta : int, keyword-only
        Segment length in frames for the relative errors.
    align : bool, keyword-only
        Compute the ATE after the rigid motion (rotation and translation, no scale:
        stereo observes it) that best aligns the estimated positions with the
        reference's (Umeyama 1991), as Sturm et al. (2012) do; else with none (both
        start at the same pose). The relative errors do not depend on it.

    Returns
    -------
    ate : float
        RMS of the position differences [m].
    rpe_trans : float
        Mean over segments of :func:`relative_pose_errors`' translation [%].
    rpe_rot : float
        Mean of its rotation [deg/m].

    References
    ----------
    Sturm et al. (2012) (ATE, RPE); Geiger et al. (2012) (KITTI's per-length errors).
    """
    T_est = as_array(T_est, "T_est", (None, 4, 4))
    T_ref = as_array(T_ref, "T_ref", T_est.shape, ref="T_est")
    delta = as_count(delta, "delta", minimum=1)
    if delta >= len(T_est):
        raise ValueError(f"delta must be smaller than the number of frames {len(T_est)}, got {delta}")
    if not isinstance(align, (bool, np.bool_)):
        raise TypeError(f"align must be True or False, got {align!r}")
    p, q = T_est[:, :3, 3], T_ref[:, :3, 3]
    if align:
        R, t = _kabsch(p, q)
        p = p @ R.T + t
    ate = float(np.sqrt(np.mean(np.sum((p - q) ** 2, axis=1))))
    trans, rot = _relative_errors(T_est, T_ref, delta)
    return ate, float(trans.mean()), float(rot.mean())
