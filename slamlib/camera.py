"""The pinhole camera and two-view geometry.

* :func:`project`: the pinhole model with calibration ``K``, and its Jacobians with
  respect to a perturbation of the camera pose and to the point (the building block
  of bundle adjustment).
* :func:`match_descriptors`: nearest-neighbour matching of feature descriptors with
  Lowe's ratio test.
* :func:`eight_point`: the essential matrix from eight or more matches (Hartley's
  normalisation, projection onto the essential manifold);
  :func:`essential_ransac` wraps it in RANSAC with the adaptive iteration count and
  refines promising samples robustly on the essential manifold;
  :func:`decompose_essential` / :func:`recover_pose` turn it into the relative
  rotation and translation direction with the cheirality test.
* :func:`triangulate`: linear (DLT) triangulation of matched pixels.

Frames. A camera pose ``T_wc (4, 4)`` maps camera coordinates to world coordinates,
``[[R, t], [0, 0, 0, 1]]``; a world point ``P`` is ``p_c = R^T (P - t)`` in the
camera, whose z axis looks forward, x right, y down. The pixel of
``p_c = [X, Y, Z]`` is ``[fx X/Z + cx, fy Y/Z + cy]``. A pose is perturbed by
``delta = [rho, phi]`` (translation first) as ``T (+) delta = (R Exp(phi), t + R rho)``.
*Normalised image coordinates* are pixels with ``K^-1`` applied: ``[X/Z, Y/Z]``.

References
----------
R. Hartley, A. Zisserman, *Multiple View Geometry in Computer Vision*, 2nd ed.,
Cambridge University Press, 2004 (HZ): Sec. 6.1 (the pinhole camera), Sec. 9.6
(the essential matrix and its four decompositions, Result 9.19), Sec. 11.2 (the
normalised eight-point algorithm), Sec. 12.2 (linear triangulation), Sec. 4.7.1
(RANSAC's number of samples, Eq. 4.18). R. Hartley, "In defense of the eight-point
algorithm", IEEE TPAMI 19(6), 1997. D. G. Lowe, "Distinctive image features from
scale-invariant keypoints", IJCV 60(2), 2004, Sec. 7.1 (the ratio test).
M. A. Fischler, R. C. Bolles, "Random sample consensus", CACM 24(6), 1981. O. Chum, J. Matas,
J. Kittler, "Locally optimized RANSAC", DAGM 2003. U. Helmke, K. Hueper, P. Y. Lee, J. Moore,
"Essential matrix estimation using Gauss-Newton iterations on a manifold", IJCV 74(2), 2007.
A. E. Beaton, J. W. Tukey, "The fitting of power series, meaning polynomials, illustrated on
band-spectroscopic data", Technometrics 16(2), 1974 (the biweight).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from ._checks import as_array, as_count, as_matrix, as_scalar, check_rng
from .lie import _skew, _so3_exp

__all__ = ["calibration_matrix", "pose_matrix", "project", "triangulate", "to_normalized", "eight_point",
           "sampson_distance", "ransac_iterations", "EssentialResult", "essential_ransac", "decompose_essential",
           "recover_pose", "TwoViewResult", "two_view_reconstruction", "match_descriptors", "epipolar_lines"]


# =========================================================================== poses and calibration
def calibration_matrix(fx, fy, cx, cy):
    """The calibration matrix of a pinhole camera (HZ Eq. 6.4, no skew).

    Parameters
    ----------
    fx, fy : float
        Focal lengths in pixels, positive.
    cx, cy : float
        Principal point in pixels.

    Returns
    -------
    ndarray, shape (3, 3)
        ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``.
    """
    fx = as_scalar(fx, "fx", positive=True)
    fy = as_scalar(fy, "fy", positive=True)
    return np.array([[fx, 0.0, as_scalar(cx, "cx")], [0.0, fy, as_scalar(cy, "cy")], [0.0, 0.0, 1.0]])


def pose_matrix(R, t):
    """The homogeneous pose ``[[R, t], [0, 0, 0, 1]]``.

    Parameters
    ----------
    R : ndarray, shape (..., 3, 3)
        Rotations.
    t : ndarray, shape (..., 3)
        Translations.

    Returns
    -------
    ndarray, shape (..., 4, 4)
    """
    R = as_matrix(R, "R", 3, 3)
    t = as_array(t, "t", ndim=None)
    if t.shape != R.shape[:-1]:
        raise ValueError(f"t must have shape {R.shape[:-1]} (to match R), got {t.shape}")
    T = np.zeros(R.shape[:-2] + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def _as_calibration(K, name="K"):
    K = as_array(K, name, (3, 3))
    if not (K[0, 0] > 0 and K[1, 1] > 0) or K[0, 1] != 0 or K[1, 0] != 0 or np.any(K[2] != [0.0, 0.0, 1.0]):
        raise ValueError(f"{name} must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0, got {K.tolist()}")
    return K


def _as_pose3(T, name):
    T = as_array(T, name, (4, 4))
    R = T[:3, :3]
    if np.any(T[3] != [0.0, 0.0, 0.0, 1.0]) or not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or \
            np.linalg.det(R) <= 0:
        raise ValueError(f"{name} must be a rigid transform [[R, t], [0, 0, 0, 1]] with R a rotation")
    return T


# =========================================================================== projection
def _project(K, R, t, P):
    """Unchecked core of :func:`project`, batched: ``R (..., 3, 3)``, ``t (..., 3)``, ``P (..., 3)``.

    ``K`` is ``(3, 3)`` or ``(..., 3, 3)``. Returns ``(uv, J_pose, J_point, p_c)``.
    """
    fx, fy, cx, cy = K[..., 0, 0], K[..., 1, 1], K[..., 0, 2], K[..., 1, 2]
    pc = np.einsum("...ji,...j->...i", R, P - t)  # p_c = R^T (P - t)
    X, Y, Z = pc[..., 0], pc[..., 1], pc[..., 2]
    iz = 1.0 / Z
    uv = np.stack([fx * X * iz + cx, fy * Y * iz + cy], axis=-1)  # (HZ Eq. 6.5)
    # d uv / d p_c = [[fx/Z, 0, -fx X/Z^2], [0, fy/Z, -fy Y/Z^2]]
    zero = np.zeros_like(Z)
    Jc = np.stack([np.stack([fx * iz, zero, -fx * X * iz * iz], -1),
                   np.stack([zero, fy * iz, -fy * Y * iz * iz], -1)], -2)
    # p_c(T (+) delta) = Exp(-phi) (p_c - rho): d p_c/d rho = -I, d p_c/d phi = [p_c]x
    J_pose = np.concatenate([-Jc, Jc @ _skew(pc)], axis=-1)
    J_point = Jc @ np.swapaxes(R, -1, -2)  # d p_c / dP = R^T
    return uv, J_pose, J_point, pc


def project(K, T_wc, P):
    """Pixels of world points seen by a pinhole camera, and their Jacobians.

    Parameters
    ----------
    K : ndarray, shape (3, 3)
        Calibration ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``.
    T_wc : ndarray, shape (4, 4)
        Camera pose, camera-to-world.
    P : ndarray, shape (N, 3)
        World points (in front of the camera).

    Returns
    -------
    uv : ndarray, shape (N, 2)
        ``[fx X/Z + cx, fy Y/Z + cy]`` for ``p_c = R^T (P - t) = [X, Y, Z]``.
    J_pose : ndarray, shape (N, 2, 6)
        Derivative of ``uv`` with respect to ``delta = [rho, phi]`` at 0, the pose
        perturbed as ``(R Exp(phi), t + R rho)``: ``d uv/d p_c [-I, [p_c]x]``.
    J_point : ndarray, shape (N, 2, 3)
        Derivative of ``uv`` with respect to ``P``: ``d uv/d p_c R^T``.

    Raises
    ------
    ValueError
        If an argument has the wrong shape or is not finite, `K` is not a
        calibration matrix, `T_wc` is not a rigid transform, or a point is not in
        front of the camera (``Z <= 0``).

    References
    ----------
    Hartley & Zisserman (2004), Eqs. 6.4-6.6; Barfoot, *State Estimation for
    Robotics* (2017), Sec. 7.1.8 (perturbations of poses).
    """
    K = _as_calibration(K)
    T_wc = _as_pose3(T_wc, "T_wc")
    P = as_array(P, "P", (None, 3))
    uv, J_pose, J_point, pc = _project(K, T_wc[:3, :3], T_wc[:3, 3], P)
    if np.any(pc[:, 2] <= 0):
        raise ValueError(f"P must lie in front of the camera (Z > 0); point {int(np.argmin(pc[:, 2]))} has "
                         f"Z = {pc[:, 2].min():.6g}")
    return uv, J_pose, J_point


def to_normalized(K, uv):
    """Normalised image coordinates of pixels: the pixels with ``K^-1`` applied.

    Parameters
    ----------
    K : ndarray, shape (3, 3)
        Calibration.
    uv : ndarray, shape (N, 2)
        Pixels.

    Returns
    -------
    ndarray, shape (N, 2)
        ``[(u - cx) / fx, (v - cy) / fy]``: the first two entries of ``K^-1 [u, v, 1]``.
    """
    K = _as_calibration(K)
    uv = as_array(uv, "uv", (None, 2))
    return np.column_stack([(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1]])


# =========================================================================== triangulation
def _camera_matrix(K, T_wc):
    """``K [R^T, -R^T t]``, the ``(3, 4)`` projection matrix of a camera (HZ Eq. 6.8)."""
    R, t = T_wc[:3, :3], T_wc[:3, 3]
    return K @ np.column_stack([R.T, -R.T @ t])


def _triangulate(P1, P2, uv1, uv2):
    """Unchecked core of :func:`triangulate`: DLT from projection matrices ``P1``, ``P2`` ``(3, 4)``."""
    # rows u p^3 - p^1, v p^3 - p^2 of each view  (HZ Sec. 12.2)
    A = np.stack([uv1[:, :1] * P1[2] - P1[0], uv1[:, 1:] * P1[2] - P1[1],
                  uv2[:, :1] * P2[2] - P2[0], uv2[:, 1:] * P2[2] - P2[1]], axis=1)
    X = np.linalg.svd(A)[2][:, -1]  # right singular vector of the smallest singular value
    return X[:, :3] / X[:, 3:]


def triangulate(K, T_wc1, T_wc2, uv1, uv2):
    """Linear (DLT) triangulation of matched pixels in two calibrated views.

    Parameters
    ----------
    K : ndarray, shape (3, 3)
        Calibration of both cameras.
    T_wc1, T_wc2 : ndarray, shape (4, 4)
        Camera poses, camera-to-world.
    uv1, uv2 : ndarray, shape (N, 2)
        Matched pixels: row ``k`` of both is the same point.

    Returns
    -------
    ndarray, shape (N, 3)
        World points: for each match the right singular vector of the smallest
        singular value of ``A = [u1 p_1^3 - p_1^1; v1 p_1^3 - p_1^2; u2 p_2^3 - p_2^1;
        v2 p_2^3 - p_2^2]`` (``p_k^i`` the rows of ``P_k = K [R_k^T, -R_k^T t_k]``),
        dehomogenised. Rows are in pixels, unscaled.

    References
    ----------
    Hartley & Zisserman (2004), Sec. 12.2 (the homogeneous method).
    """
    K = _as_calibration(K)
    T1 = _as_pose3(T_wc1, "T_wc1")
    T2 = _as_pose3(T_wc2, "T_wc2")
    uv1 = as_array(uv1, "uv1", (None, 2))
    uv2 = as_array(uv2, "uv2", (None, 2))
    if uv1.shape != uv2.shape:
        raise ValueError(f"uv2 must have the shape of uv1 {uv1.shape}, got {uv2.shape}")
    return _triangulate(_camera_matrix(K, T1), _camera_matrix(K, T2), uv1, uv2)


# =========================================================================== the essential matrix
def _hartley(x):
    """``(T (3, 3), x_n (N, 2))``: centroid to the origin, mean distance sqrt(2) (HZ Algorithm 4.2)."""
    c = x.mean(axis=0)
    s = math.sqrt(2.0) / np.mean(np.linalg.norm(x - c, axis=1))
    T = np.array([[s, 0.0, -s * c[0]], [0.0, s, -s * c[1]], [0.0, 0.0, 1.0]])
    return T, s * (x - c)


def _eight_point(x1, x2):
    """Unchecked core of :func:`eight_point`."""
    T1, a = _hartley(x1)
    T2, b = _hartley(x2)
    one = np.ones(len(a))
    # each match gives one row of A f = 0: [x2, 1] F [x1, 1]^T = 0  (HZ Eq. 11.3)
    A = np.column_stack([b[:, 0] * a[:, 0], b[:, 0] * a[:, 1], b[:, 0],
                         b[:, 1] * a[:, 0], b[:, 1] * a[:, 1], b[:, 1], a[:, 0], a[:, 1], one])
    F = np.linalg.svd(A)[2][-1].reshape(3, 3)
    E = T2.T @ F @ T1  # denormalise  (HZ Algorithm 11.1 (iii))
    U, _, Vt = np.linalg.svd(E)
    return U @ np.diag([1.0, 1.0, 0.0]) @ Vt  # the closest essential matrix  (HZ Sec. 9.6.1)


def _as_matches(x1, x2, minimum):
    x1 = as_array(x1, "x1", (None, 2))
    x2 = as_array(x2, "x2", (None, 2))
    if x1.shape != x2.shape:
        raise ValueError(f"x2 must have the shape of x1 {x1.shape}, got {x2.shape}")
    if x1.shape[0] < minimum:
        raise ValueError(f"x1 and x2 must hold at least {minimum} matches, got {x1.shape[0]}")
    return x1, x2


def eight_point(x1, x2):
    """The essential matrix of ``N >= 8`` matches by the normalised eight-point algorithm.

    Parameters
    ----------
    x1, x2 : ndarray, shape (N, 2)
        Matches in normalised image coordinates (pixels with ``K^-1`` applied),
        ``N >= 8``.

    Returns
    -------
    E : ndarray, shape (3, 3)
        ``[x2, 1] E [x1, 1]^T ~ 0``, with singular values ``(1, 1, 0)``; its sign is
        arbitrary.

    Notes
    -----
    Each point set is translated so that its centroid is at the origin and scaled
    so that the mean distance to it is ``sqrt(2)`` (``T1``, ``T2``); the right
    singular vector of the smallest singular value of the ``(N, 9)`` design
    matrix, read row by row, is ``F``; ``E = T2^T F T1`` is projected onto the
    essential matrices, ``U diag(1, 1, 0) V^T``.

    References
    ----------
    Hartley & Zisserman (2004), Algorithm 11.1 and Sec. 9.6.1; Hartley (1997).
    """
    x1, x2 = _as_matches(x1, x2, 8)
    return _eight_point(x1, x2)


def _sampson(E, x1, x2):
    h1 = np.column_stack([x1, np.ones(len(x1))])
    h2 = np.column_stack([x2, np.ones(len(x2))])
    Ex1 = h1 @ E.T
    Etx2 = h2 @ E
    num = np.einsum("ij,ij->i", h2, Ex1) ** 2
    return num / (Ex1[:, 0] ** 2 + Ex1[:, 1] ** 2 + Etx2[:, 0] ** 2 + Etx2[:, 1] ** 2)


def _sampson_signed(E, x1, x2, dE=None):
    """Signed Sampson distances ``r (N,)`` of the matches, and ``dr/dE . dE_k (N, K)`` for directions ``dE (K, 3, 3)``.

    ``r = x2^T E x1 / sqrt(g)``, ``g = (E x1)_1^2 + (E x1)_2^2 + (E^T x2)_1^2 + (E^T x2)_2^2``
    (homogeneous ``x1``, ``x2``); ``r^2`` is :func:`sampson_distance`.
    """
    h1 = np.column_stack([x1, np.ones(len(x1))])
    h2 = np.column_stack([x2, np.ones(len(x2))])
    a, b = h1 @ E.T, h2 @ E  # E x1, E^T x2
    num = np.einsum("ij,ij->i", h2, a)
    g = a[:, 0] ** 2 + a[:, 1] ** 2 + b[:, 0] ** 2 + b[:, 1] ** 2
    r = num / np.sqrt(g)
    if dE is None:
        return r
    da = np.einsum("kij,nj->nki", dE[:, :2], h1)  # (dE_k x1)_{1,2}
    db = np.einsum("kji,nj->nki", dE[:, :, :2], h2)  # (dE_k^T x2)_{1,2}
    dnum = np.einsum("ni,kij,nj->nk", h2, dE, h1)
    dg = 2.0 * (np.einsum("ni,nki->nk", a[:, :2], da) + np.einsum("ni,nki->nk", b[:, :2], db))
    return r, dnum / np.sqrt(g)[:, None] - (num / (2.0 * g**1.5))[:, None] * dg


_E_DIAG = np.diag([1.0, 1.0, 0.0])
_GEN = _skew(np.eye(3))  # [e_k]x, the generators of so(3)
_LO_SHARE = 0.25  # samples explaining more than this share of the best's support are refined (a minimal sample's
# eight-point fit is noisy: it may explain only a few of the matches its refinement explains)
_TUKEY_SCALE = 1.5  # the biweight's scale in inlier thresholds: beyond it a match has no weight


def _refine_essential(E, x1, x2, c, iters=10):
    """Robust Gauss-Newton refinement of ``E`` on the essential manifold over all matches.

    Minimises ``sum rho(r_i)``, Tukey's biweight with scale `c` of the signed Sampson
    distances, by iteratively reweighted Gauss-Newton steps: matches with
    ``|r| >= c`` have no weight, so outliers drop out as the fit improves. ``E`` is
    kept essential by the parametrisation ``E = U Exp(a) diag(1, 1, 0) Exp(b)^T V^T``
    with ``b_3 = 0`` (a rotation about the third axis on both sides leaves
    ``diag(1, 1, 0)`` unchanged): five degrees of freedom, the dimension of the
    manifold. A step is kept only if it lowers the cost, so the result is never worse
    than `E` in that cost; it may be non-finite only where `E` is.
    """
    U, _, Vt = np.linalg.svd(E)
    U, Vt = U * np.linalg.det(U), Vt * np.linalg.det(Vt)  # rotations (E's sign is free)

    def cost(r):
        return np.sum(1.0 - np.clip(1.0 - (r / c) ** 2, 0.0, None) ** 3)

    with np.errstate(all="ignore"):
        r = _sampson_signed(U @ _E_DIAG @ Vt, x1, x2)
        f = cost(r)
        for _ in range(iters):
            sw = np.clip(1.0 - (r / c) ** 2, 0.0, None)  # the square root of Tukey's IRLS weight
            sel = sw > 0
            if sel.sum() < 5:
                break
            dE = np.concatenate([U @ _GEN @ _E_DIAG @ Vt, -(U @ _E_DIAG @ _GEN[:2] @ Vt)])  # dE/da_k, dE/db_k
            _, J = _sampson_signed(U @ _E_DIAG @ Vt, x1[sel], x2[sel], dE)
            try:
                d = -np.linalg.lstsq(J * sw[sel, None], r[sel] * sw[sel], rcond=None)[0]
            except np.linalg.LinAlgError:
                break
            Un, Vtn = U @ _so3_exp(d[:3]), _so3_exp(np.r_[d[3:], 0.0]).T @ Vt
            rn = _sampson_signed(Un @ _E_DIAG @ Vtn, x1, x2)
            fn = cost(rn)
            if not fn < f:
                break
            U, Vt, r, f, done = Un, Vtn, rn, fn, f - fn <= 1e-10 * f
            if done:
                break
    return U @ _E_DIAG @ Vt


def sampson_distance(E, x1, x2):
    """Squared Sampson distance of each match to the epipolar geometry of ``E`` (HZ Eq. 11.9).

    Parameters
    ----------
    E : ndarray, shape (3, 3)
    x1, x2 : ndarray, shape (N, 2)
        Matches (normalised image coordinates).

    Returns
    -------
    ndarray, shape (N,)
        ``(x2^T E x1)^2 / ((E x1)_1^2 + (E x1)_2^2 + (E^T x2)_1^2 + (E^T x2)_2^2)``, in the
        squared units of ``x1``, ``x2``: the first-order geometric error of the match.
    """
    E = as_array(E, "E", (3, 3))
    x1, x2 = _as_matches(x1, x2, 0)
    return _sampson(E, x1, x2)


def ransac_iterations(inlier_ratio, sample_size=8, confidence=0.999):
    """Samples RANSAC needs to draw one all-inlier sample with probability `confidence`.

    Parameters
    ----------
    inlier_ratio : float
        ``w`` in ``[0, 1]``.
    sample_size : int
        ``s``, matches per sample (8 for the eight-point algorithm).
    confidence : float
        ``p`` in ``(0, 1)``.

    Returns
    -------
    int or float
        ``N = log(1 - p) / log(1 - w^s)`` (HZ Eq. 4.18), rounded up; 1 for ``w = 1``,
        ``inf`` for ``w = 0``.
    """
    w = as_scalar(inlier_ratio, "inlier_ratio", nonnegative=True)
    if w > 1:
        raise ValueError(f"inlier_ratio must be in [0, 1], got {w}")
    s = as_count(sample_size, "sample_size", minimum=1)
    p = as_scalar(confidence, "confidence", positive=True)
    if p >= 1:
        raise ValueError(f"confidence must be in (0, 1), got {p}")
    return _ransac_iterations(w, s, p)


def _ransac_iterations(w, s, p):
    good = w**s
    if good >= 1.0:
        return 1
    if good <= 0.0:
        return math.inf
    return math.ceil(math.log(1.0 - p) / math.log1p(-good))


class EssentialResult(NamedTuple):
    """Result of :func:`essential_ransac`.

    Attributes
    ----------
    E : ndarray, shape (3, 3)
        Essential matrix of the best sample, refitted (eight-point) on its inliers and
        refined (unless ``refine=False``); singular values ``(1, 1, 0)``.
    inliers : ndarray of bool, shape (N,)
        Matches whose Sampson distance to ``E`` is below the threshold (and, with
        ``cheirality=True``, in front of both cameras for ``E``'s best decomposition).
    iterations : int
        Samples drawn.
    """

    E: np.ndarray
    inliers: np.ndarray
    iterations: int


def essential_ransac(x1, x2, *, threshold, rng, confidence=0.999, max_iter=2000, eight_point=None, refine=True,
                     cheirality=False):
    """The essential matrix of matches with outliers: eight-point inside RANSAC, refined robustly.

    Parameters
    ----------
    x1, x2 : ndarray, shape (N, 2)
        Matches in normalised image coordinates, ``N >= 8``.
    threshold : float, keyword-only
        Inlier threshold on the Sampson *distance* (the square root of
        :func:`sampson_distance`), in normalised units: a pixel threshold divided
        by the focal length.
    rng : numpy.random.Generator, keyword-only
        Draws each sample of 8 distinct matches (``rng.choice(N, 8, replace=False)``).
    confidence : float, keyword-only
        Probability of drawing at least one all-inlier sample: after each better
        sample the number of samples is recomputed from its inlier ratio
        (:func:`ransac_iterations`), the adaptive stopping rule.
    max_iter : int, keyword-only
        Upper bound on the samples.
    eight_point : callable, keyword-only
        Hook replacing :func:`eight_point` (each sample's fit and the final refit).
    refine : bool, keyword-only
        Refine samples on the essential manifold (local optimisation, see Notes).
        ``False`` gives plain RANSAC with Chum's simplest local optimisation: each
        sample that beats the best so far is refitted (eight-point) on its inliers.
    cheirality : bool, keyword-only
        Count as inliers only the matches within the threshold that also lie in front
        of both cameras, for the one of ``E``'s four decompositions with the most such
        matches (:func:`recover_pose`'s test, from the signs of the two depths). It
        scores every sample, the refinement and the final refit. ``False`` counts
        every match within the threshold.

    Returns
    -------
    EssentialResult

    Notes
    -----
    The eight-point fit minimises an algebraic error, and its projection onto the
    essential matrices ignores the data; from eight noisy matches it may explain
    only a few of the others. At an inlier threshold of a few noise deviations
    RANSAC then keeps an estimate that misses many true matches, and the adaptive
    count (which assumes that an all-inlier sample finds them) stops the search
    early. So each sample that explains more than a quarter as many matches as the
    best so far is refined over all matches: Gauss-Newton on the signed Sampson
    distances, weighted by Tukey's biweight with scale ``1.5 * threshold`` (matches
    beyond it have no weight), over ``E = U Exp(a) diag(1, 1, 0) Exp(b)^T V^T``
    (five degrees of freedom, so ``E`` stays essential). The refinement replaces the
    sample when it explains more matches, and polishes the final refit when it
    explains at least as many. It maximises the consensus better than the linear
    fit, so where a wrong model explains as many matches as the true one (a
    threshold of many noise deviations, a second rigidly moving object, a planar
    scene) it finds that one as readily. Counting as inliers only the matches in front
    of both cameras (``cheirality=True``) rejects many such models: over 300 scenes
    with a threshold of 8 noise deviations the rotation was off by more than 5 deg in
    30 % of them without it and 2.3 % with it, and on a nearly planar scene in 98 % and
    43 %. It is off by default because at a short baseline (a twentieth of the scene's
    depth) the depths of noisy matches change sign, and the true model loses more than
    10 of its matches in 6 of 43 scenes (none without), at up to twice the time.

    References
    ----------
    Fischler & Bolles (1981); Hartley & Zisserman (2004), Algorithm 4.5 (adaptive
    number of samples), Sec. 11.4.3 (Sampson distance) and Sec. 11.6; Chum, Matas &
    Kittler (2003) (local optimisation); Helmke et al. (2007) (Gauss-Newton on the
    essential manifold); Beaton & Tukey (1974) (the biweight).
    """
    x1, x2 = _as_matches(x1, x2, 8)
    thr2 = as_scalar(threshold, "threshold", positive=True) ** 2
    check_rng(rng)
    p = as_scalar(confidence, "confidence", positive=True)
    if p >= 1:
        raise ValueError(f"confidence must be in (0, 1), got {p}")
    max_iter = as_count(max_iter, "max_iter", minimum=1)
    if not isinstance(refine, (bool, np.bool_)):
        raise TypeError(f"refine must be a bool, got {type(refine).__name__}")
    if not isinstance(cheirality, (bool, np.bool_)):
        raise TypeError(f"cheirality must be a bool, got {type(cheirality).__name__}")
    fit = _eight_point if eight_point is None else (lambda a, b: np.asarray(eight_point(a, b), dtype=float))
    n = len(x1)

    def score(E, floor=-1):
        """The inliers of ``E``: within the threshold and, with `cheirality`, in front of both cameras.

        The cheirality test is skipped when no more than `floor` matches are within the threshold (the caller
        then rejects ``E`` either way: the test only removes inliers).
        """
        inl = _sampson(E, x1, x2) < thr2
        if cheirality and inl.sum() > floor:
            idx = np.flatnonzero(inl)
            inl[idx] = _in_front(E, x1[idx], x2[idx])
        return inl

    def consensus(idx, floor=-1):
        """``(E, inliers)`` of a fit to the matches ``idx``, or None for a degenerate set (no finite fit)."""
        if len(idx) < 8:
            return None
        try:
            with np.errstate(all="ignore"):
                E = fit(x1[idx], x2[idx])
        except np.linalg.LinAlgError:
            return None
        if not np.all(np.isfinite(E)):
            return None  # e.g. repeated keypoints
        return E, score(E, floor)

    def polish(E):
        """``(E, inliers)`` refined robustly from ``E``, or None for a non-finite result."""
        E = _refine_essential(E, x1, x2, _TUKEY_SCALE * math.sqrt(thr2))
        return (E, score(E)) if np.all(np.isfinite(E)) else None

    best, best_E = np.zeros(n, dtype=bool), None
    needed, it = max_iter, 0
    while it < min(needed, max_iter):
        it += 1
        floor = (_LO_SHARE if refine else 1.0) * best.sum()
        cand = consensus(rng.choice(n, 8, replace=False), floor)
        if cand is None or cand[1].sum() <= floor:
            continue
        # local optimisation (Chum et al. 2003), kept if it explains more: the robust refinement from the new
        # best or, without it, the eight-point refit on its inliers
        lo = polish(cand[0]) if refine else consensus(np.flatnonzero(cand[1]))
        cand = lo if lo is not None and lo[1].sum() > cand[1].sum() else cand
        if cand[1].sum() <= best.sum():
            continue
        best_E, best = cand
        needed = _ransac_iterations(best.mean(), 8, p)
    if best.sum() < 8:
        raise ValueError("RANSAC found no essential matrix with 8 inliers; raise threshold or check the matches")
    final = consensus(np.flatnonzero(best))  # refit on all inliers; kept only if it explains at least as many
    E, inl = final if final is not None and final[1].sum() >= best.sum() else (best_E, best)
    polished = polish(E) if refine else None
    if polished is not None and polished[1].sum() >= inl.sum():
        E, inl = polished
    return EssentialResult(E, inl, it)


# =========================================================================== relative pose
def decompose_essential(E):
    """The four ``(R, t)`` of an essential matrix (HZ Result 9.19).

    With ``E = U diag(1, 1, 0) V^T`` (``U``, ``V`` rotations) and
    ``W = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]``: ``R in {U W V^T, U W^T V^T}``,
    ``t = +-u_3`` (unit length). ``x2 = R x1 + t`` maps camera-1 coordinates to
    camera 2's for the right one of the four.

    Parameters
    ----------
    E : ndarray, shape (3, 3)

    Returns
    -------
    R : ndarray, shape (4, 3, 3)
    t : ndarray, shape (4, 3)
    """
    E = as_array(E, "E", (3, 3))
    return _decompose(E)


def _decompose(E):
    U, _, Vt = np.linalg.svd(E)
    U = U * np.sign(np.linalg.det(U))
    Vt = Vt * np.sign(np.linalg.det(Vt))
    W = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    Ra, Rb = U @ W @ Vt, U @ W.T @ Vt
    u3 = U[:, 2]
    return np.stack([Ra, Ra, Rb, Rb]), np.stack([u3, -u3, u3, -u3])


def _in_front(E, x1, x2):
    """Mask ``(N,)`` of the matches in front of both cameras for the decomposition of ``E`` that has the most.

    For ``x2 = R x1 + t`` the depths ``l1``, ``l2`` of the rays ``f1 = [x1, 1]``, ``f2 = [x2, 1]`` solve
    ``l2 f2 = l1 R f1 + t``; crossing with ``f2`` and with ``R f1`` gives them up to the positive factor
    ``|R f1 x f2|^2``: ``l1 ~ (f2 x t) . c``, ``l2 ~ (R f1 x t) . c``, ``c = R f1 x f2``. Negating ``t``
    negates both, so two rotations give the four decompositions' tests (HZ Result 9.19, Sec. 9.6.3).
    """
    Rs, ts = _decompose(E)
    t = ts[0]
    h1 = np.column_stack([x1, np.ones(len(x1))])
    h2 = np.column_stack([x2, np.ones(len(x2))])
    best = np.zeros(len(x1), dtype=bool)
    for R in (Rs[0], Rs[2]):
        a = h1 @ R.T  # R f1
        c = np.cross(a, h2)
        s1 = np.einsum("ij,ij->i", np.cross(h2, t), c)
        s2 = np.einsum("ij,ij->i", np.cross(a, t), c)
        for front in ((s1 > 0) & (s2 > 0), (s1 < 0) & (s2 < 0)):  # +t, -t
            if front.sum() > best.sum():
                best = front
    return best


def recover_pose(E, x1, x2):
    """Relative pose from an essential matrix: the decomposition that puts the points in front of both cameras.

    Parameters
    ----------
    E : ndarray, shape (3, 3)
    x1, x2 : ndarray, shape (N, 2)
        Matches in normalised image coordinates (the inliers).

    Returns
    -------
    T_wc2 : ndarray, shape (4, 4)
        Pose of camera 2 in camera 1's frame (camera 1 at the identity), with a
        translation of unit length (the scale is unobservable from two views).
    P : ndarray, shape (N, 3)
        The matches triangulated in camera 1's frame.
    in_front : ndarray of bool, shape (N,)
        Points with positive depth in both cameras (the cheirality test).

    References
    ----------
    Hartley & Zisserman (2004), Sec. 9.6.3 (the one of four solutions with the
    points in front of both cameras).
    """
    E = as_array(E, "E", (3, 3))
    x1, x2 = _as_matches(x1, x2, 1)
    Rs, ts = _decompose(E)
    P1 = np.eye(3, 4)
    best = None
    for R, t in zip(Rs, ts):
        P = _triangulate(P1, np.column_stack([R, t]), x1, x2)
        front = (P[:, 2] > 0) & ((P @ R.T + t)[:, 2] > 0)
        if best is None or front.sum() > best[0].sum():
            best = (front, R, t, P)
    front, R, t, P = best
    T = np.eye(4)
    T[:3, :3] = R.T  # x2 = R x1 + t: camera 2 sits at -R^T t, rotated by R^T
    T[:3, 3] = -R.T @ t
    return T, P, front


class TwoViewResult(NamedTuple):
    """Result of :func:`two_view_reconstruction`.

    Attributes
    ----------
    T_wc2 : ndarray, shape (4, 4)
        Camera 2 in camera 1's frame, translation of unit length.
    points : ndarray, shape (M, 3)
        The inliers in front of both cameras, triangulated (camera 1's frame).
    inliers : ndarray of int, shape (M,)
        Indices of those matches.
    E : ndarray, shape (3, 3)
    """

    T_wc2: np.ndarray
    points: np.ndarray
    inliers: np.ndarray
    E: np.ndarray


def two_view_reconstruction(K, uv1, uv2, *, threshold, rng, confidence=0.999, max_iter=2000, eight_point=None,
                            triangulate=None, refine=True, cheirality=False):
    """Relative motion and points from matched pixels of two photographs of one calibrated camera.

    RANSAC over eight-point fits, refined robustly (:func:`essential_ransac`,
    `threshold` in pixels), the decomposition with the most points in front of both cameras
    (:func:`recover_pose`), and the DLT triangulation in pixels
    (:func:`triangulate`, camera 1 at the identity) of the inliers in front.

    Parameters
    ----------
    K : ndarray, shape (3, 3)
    uv1, uv2 : ndarray, shape (N, 2)
        Matched pixels.
    threshold : float, keyword-only
        Inlier threshold on the Sampson distance, in pixels (divided by ``fx``).
    rng : numpy.random.Generator, keyword-only
        RANSAC's samples.
    confidence, max_iter, refine, cheirality : keyword-only
        As in :func:`essential_ransac`.
    eight_point, triangulate : callable, keyword-only
        Hooks replacing :func:`eight_point` and :func:`triangulate`.

    Returns
    -------
    TwoViewResult

    References
    ----------
    Hartley & Zisserman (2004), Sec. 9.6, 11.6, 12.2.
    """
    K = _as_calibration(K)
    uv1 = as_array(uv1, "uv1", (None, 2))
    uv2 = as_array(uv2, "uv2", (None, 2))
    if uv1.shape != uv2.shape:
        raise ValueError(f"uv2 must have the shape of uv1 {uv1.shape}, got {uv2.shape}")
    thr = as_scalar(threshold, "threshold", positive=True) / K[0, 0]
    x1 = np.column_stack([(uv1[:, 0] - K[0, 2]) / K[0, 0], (uv1[:, 1] - K[1, 2]) / K[1, 1]])
    x2 = np.column_stack([(uv2[:, 0] - K[0, 2]) / K[0, 0], (uv2[:, 1] - K[1, 2]) / K[1, 1]])
    res = essential_ransac(x1, x2, threshold=thr, rng=rng, confidence=confidence, max_iter=max_iter,
                           eight_point=eight_point, refine=refine, cheirality=cheirality)
    inl = np.flatnonzero(res.inliers)
    T2, _, front = recover_pose(res.E, x1[inl], x2[inl])
    keep = inl[front]
    if triangulate is None:
        P = _triangulate(_camera_matrix(K, np.eye(4)), _camera_matrix(K, T2), uv1[keep], uv2[keep])
    else:
        P = np.asarray(triangulate(K, np.eye(4), T2, uv1[keep], uv2[keep]), dtype=float)
    return TwoViewResult(T2, P, keep, res.E)


def epipolar_lines(E, x1):
    """Epipolar lines in image 2 of points of image 1 (HZ Sec. 9.2).

    Parameters
    ----------
    E : ndarray, shape (3, 3)
    x1 : ndarray, shape (N, 2)
        Points of image 1 (normalised coordinates).

    Returns
    -------
    ndarray, shape (N, 3)
        ``l2 = E [x1, 1]`` scaled so that ``a^2 + b^2 = 1``: ``a x + b y + c`` is the
        signed distance of ``[x, y]`` in image 2 from the line.
    """
    E = as_array(E, "E", (3, 3))
    x1 = as_array(x1, "x1", (None, 2))
    lines = np.column_stack([x1, np.ones(len(x1))]) @ E.T
    return lines / np.linalg.norm(lines[:, :2], axis=1, keepdims=True)


# =========================================================================== feature matching
def match_descriptors(d1, d2, *, ratio=0.8, mutual=True):
    """Match feature descriptors by nearest neighbour with Lowe's ratio test.

    Parameters
    ----------
    d1 : ndarray, shape (N1, D)
    d2 : ndarray, shape (N2, D)
        Descriptors (e.g. 128-dimensional SIFT), ``N2 >= 2``.
    ratio : float, keyword-only
        A match ``i -> j`` is kept when the distance to the nearest neighbour
        ``j`` is below `ratio` times the distance to the second nearest.
    mutual : bool, keyword-only
        Also require ``i`` to be the nearest neighbour of ``j`` in `d1`
        (the cross-check).

    Returns
    -------
    ndarray of int, shape (M, 2)
        Index pairs ``(i, j)``, sorted by ``i``.

    References
    ----------
    Lowe (2004), Sec. 7.1 (ratio 0.8 rejects 90 % of the false matches and 5 % of the correct ones).
    """
    d1 = as_array(d1, "d1", ndim=2)
    d2 = as_array(d2, "d2", (None, d1.shape[1]), ref="d1")
    if len(d2) < 2:
        raise ValueError(f"d2 must hold at least 2 descriptors for the ratio test, got {len(d2)}")
    r = as_scalar(ratio, "ratio", positive=True)
    dist, idx = cKDTree(d2).query(d1, k=2)
    keep = dist[:, 0] < r * dist[:, 1]  # Lowe's ratio test
    i = np.flatnonzero(keep)
    j = idx[keep, 0]
    if mutual:
        back = cKDTree(d1).query(d2[j], k=1)[1]
        ok = back == i
        i, j = i[ok], j[ok]
    return np.column_stack([i, j]).astype(np.int64)
