"""Scan matching: rigid alignment of 2-D point sets and the iterative closest point algorithm.

Two laser scans taken from nearby poses see the same walls. Scan matching finds
the rigid motion that lays one scan onto the other, and so measures the robot's
motion between the two scans far more precisely than wheel odometry.

* :func:`icp_align` is the closed-form step: given matched points, the rotation
  and translation minimising the sum of squared distances (SVD of the
  cross-covariance, Besl & McKay 1992 / Umeyama 1991, reflections excluded).
* :func:`icp` alternates nearest-neighbour association (``scipy.spatial.cKDTree``)
  with that step (*point-to-point*, Besl & McKay 1992) or with a Gauss-Newton
  step on the distances of the points to the target's local lines
  (*point-to-line*, Chen & Medioni 1992; Censi 2008); pairs farther apart than
  a gate and, optionally, the worst fraction of pairs are rejected as outliers.
  It returns the alignment with a covariance (the Gauss-Newton approximation
  of the inverse Hessian of the point-to-line cost, scaled by the residual
  variance) and a *degeneracy check*: in a long featureless corridor the
  point-to-line cost is flat along the corridor, its information matrix has a
  near-zero eigenvalue, and the result says so instead of returning an
  arbitrary translation.
* :func:`scan_to_points` turns a range scan into points in the robot frame.

Frames. A pose ``[x, y, theta]`` is also the rigid transform taking points of
its frame into the parent frame: ``p_parent = R(theta) p + [x, y]``. The
result of ``icp(source, target)`` is the pose of the source scan's frame in the
target scan's frame, so for scans ``i`` (target) and ``j`` (source) it is
``X_i^-1 X_j`` (:func:`~slamlib.graph_slam.relative`), the relative-pose
measurement ``Z_ij`` of a pose graph (g2o's ``EDGE_SE2``).

References
----------
P. J. Besl, N. D. McKay, "A method for registration of 3-D shapes", IEEE TPAMI
14(2):239-256, 1992. Y. Chen, G. Medioni, "Object modelling by registration of
multiple range images", Image and Vision Computing 10(3):145-155, 1992.
A. Censi, "An ICP variant using a point-to-line metric", ICRA 2008; "An
accurate closed-form estimate of ICP's covariance", ICRA 2007. F. Lu, E. Milios,
"Robot pose estimation in unknown environments by matching 2D range scans",
Journal of Intelligent and Robotic Systems 18:249-275, 1997. S. Umeyama (1991),
Eqs. 39-42. Thrun, Burgard & Fox, *Probabilistic Robotics* (2005), Sec. 6.3
(range scans), Table 6.3 lines 4-5 (beam end points).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from ._checks import as_array, as_index, as_scalar, as_scan
from .angles import wrap_angle

__all__ = ["icp_align", "scan_to_points", "ICPResult", "icp"]

_METHODS = ("point_to_line", "point_to_point")
_TWO_PI = 2.0 * math.pi


# --------------------------------------------------------------------------- closed-form alignment
def _rigid_fit(P, Q):
    """Unchecked core of :func:`icp_align`: ``(R, t)`` minimising ``sum |R p_k + t - q_k|^2``."""
    mp = P.mean(axis=0)
    mq = Q.mean(axis=0)
    # cross-covariance Sigma_qp = sum (q_k - mq)(p_k - mp)^T  (Umeyama Eq. 38; Besl & McKay Sec. III.C)
    C = (Q - mq).T @ (P - mp)
    U, _, Vt = np.linalg.svd(C)
    # S = diag(1, det(U) det(V)) keeps det R = +1: a reflection is never returned  (Umeyama Eq. 39)
    d = 1.0 if np.linalg.det(U) * np.linalg.det(Vt) >= 0 else -1.0
    R = U @ np.diag([1.0, d]) @ Vt  # R = U S V^T  (Umeyama Eq. 40)
    t = mq - R @ mp  # t = mu_q - R mu_p  (Umeyama Eq. 42)
    return R, t


def icp_align(P, Q):
    """Closed-form rigid alignment of matched 2-D points (the step inside ICP).

    Parameters
    ----------
    P : ndarray, shape (K, 2)
        Points to move, ``K >= 2``.
    Q : ndarray, shape (K, 2)
        Their matches: row ``k`` of `Q` is the partner of row ``k`` of `P`.

    Returns
    -------
    R : ndarray, shape (2, 2)
        Rotation, ``R^T R = I`` and ``det R = +1``.
    t : ndarray, shape (2,)
        Translation; ``R @ P[k] + t`` is the aligned point.

    Raises
    ------
    ValueError
        If `P` or `Q` is not ``(K, 2)``, holds NaN or inf, their shapes differ,
        or ``K < 2``.

    Notes
    -----
    With centroids ``mu_p``, ``mu_q`` and the cross-covariance
    ``C = sum (q_k - mu_q)(p_k - mu_p)^T = U S V^T``, the minimiser of
    ``sum_k |R p_k + t - q_k|^2`` over rotations is ``R = U diag(1, d) V^T``
    with ``d = det(U) det(V)``: when the best orthogonal matrix ``U V^T`` is a
    reflection (``d = -1``, e.g. for mirror-image point sets), the
    constrained optimum flips the axis of the smaller singular value. Then
    ``t = mu_q - R mu_p``. If the points of `P` all coincide, every rotation
    is optimal and the one returned is whatever the SVD gives.

    References
    ----------
    Besl & McKay (1992), Sec. III.C; Umeyama (1991), Eqs. 38-42 (scale 1);
    Arun, Huang & Blostein (1987) for the reflection case.
    """
    P = as_array(P, "P", (None, 2))
    Q = as_array(Q, "Q", (None, 2))
    if P.shape[0] < 2:
        raise ValueError(f"P must hold at least K = 2 points to fix a rotation, got K = {P.shape[0]}")
    if Q.shape != P.shape:
        raise ValueError(f"Q must have the shape of P {P.shape} (row k matches row k), got {Q.shape}")
    return _rigid_fit(P, Q)


# --------------------------------------------------------------------------- scans
def scan_to_points(ranges, angles, *, max_range, min_range=0.0, sensor_offset=0.0):
    """End points of a range scan in the robot frame.

    Parameters
    ----------
    ranges : ndarray, shape (K,)
        Measured ranges [m], finite and non-negative.
    angles : ndarray, shape (K,)
        Beam angles relative to the heading [rad] (the CMU log: ``-pi/2 + k pi/180``).
    max_range : float, keyword-only
        Readings at or beyond it are dropped (no return: the CMU laser reports
        81.83 m); smaller values also drop long, imprecise readings.
    min_range : float, keyword-only
        Readings below it are dropped (returns from the robot itself).
    sensor_offset : float, keyword-only
        Distance of the laser ahead of the robot centre [m] (0.25 m on the CMU robot).

    Returns
    -------
    ndarray, shape (K', 2)
        ``[offset + z cos(a), z sin(a)]`` of the kept readings, in beam order.

    Raises
    ------
    ValueError
        If `ranges` holds NaN, inf or negative values, or `ranges` and
        `angles` differ in length.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 6.3 lines 4-5 (end point of a beam, in
    the robot frame here: pose at the origin).
    """
    ranges, angles = as_scan(ranges, angles)
    max_range = as_scalar(max_range, "max_range", positive=True, finite=False)
    min_range = as_scalar(min_range, "min_range", nonnegative=True)
    off = as_scalar(sensor_offset, "sensor_offset")
    return _scan_points(ranges, angles, max_range, min_range, off)


def _scan_points(ranges, angles, max_range, min_range, off):
    keep = (ranges < max_range) & (ranges >= min_range)
    z, a = ranges[keep], angles[keep]
    # x_z = x_sens + z cos(theta_sens), y_z = z sin(theta_sens) for a pose at the origin  (Table 6.3 lines 4-5)
    return np.column_stack([off + z * np.cos(a), z * np.sin(a)])


# --------------------------------------------------------------------------- ICP
class _Target(NamedTuple):
    """A target point set prepared once: its KD-tree and local line normals."""

    points: np.ndarray  # (N, 2)
    tree: cKDTree
    normals: np.ndarray  # (N, 2) unit normals of the local lines
    planar: np.ndarray  # (N,) bool: the neighbourhood is a line (normal usable)


def _prepare_target(points, k=5, max_spread=0.5, max_flatness=0.2):
    """KD-tree and normals (PCA of the `k` nearest neighbours) of a target point set.

    A point's normal is usable when its `k` neighbours lie within `max_spread`
    metres and their smaller principal variance is at most `max_flatness` times
    the larger one (they form a line, not a blob or a corner).
    """
    tree = cKDTree(points)
    n = points.shape[0]
    k = min(k, n)
    dist, nn = tree.query(points, k=k)
    nb = points[nn.reshape(n, k)]  # (N, k, 2)
    nb = nb - nb.mean(axis=1, keepdims=True)
    sxx = np.mean(nb[..., 0] ** 2, axis=1)
    syy = np.mean(nb[..., 1] ** 2, axis=1)
    sxy = np.mean(nb[..., 0] * nb[..., 1], axis=1)
    # principal axis of the 2x2 covariance [[sxx, sxy], [sxy, syy]]; the normal is perpendicular to it
    phi = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    normals = np.column_stack([-np.sin(phi), np.cos(phi)])
    half, rad = 0.5 * (sxx + syy), np.sqrt((0.5 * (sxx - syy)) ** 2 + sxy**2)
    lam_max, lam_min = half + rad, half - rad
    far = np.asarray(dist).reshape(n, k).max(axis=1)
    planar = (far <= max_spread) & (lam_min <= max_flatness * lam_max) & (lam_max > 0) & (k >= 3)
    return _Target(points, tree, normals, planar)


@dataclass(frozen=True, eq=False)
class ICPResult:
    """Result of :func:`icp`.

    Attributes
    ----------
    pose : ndarray, shape (3,)
        ``[t_x, t_y, theta]``: the source frame in the target frame
        (``q = R(theta) p + t``); for scans ``i`` (target) and ``j`` (source)
        the relative pose ``X_i^-1 X_j``.
    iterations : int
        Association-and-alignment rounds done.
    converged : bool
        The last step moved less than the tolerances before `max_iter`.
    rmse : float
        Root-mean-square distance [m] of the matched pairs at the end
        (point-to-point distances, for either method).
    n_matched : int
        Pairs kept at the end (inside the gate, not trimmed).
    match_fraction : float
        ``n_matched`` over the number of source points.
    cov : ndarray, shape (3, 3)
        Covariance of `pose`: ``sigma^2 (J^T J)^-1`` of the point-to-line
        residuals at the end, ``sigma^2`` their variance (pseudo-inverse when
        singular).
    information : ndarray, shape (3, 3)
        ``J^T J / sigma^2``.
    degenerate : bool
        The point-to-line cost does not pin down all three degrees of
        freedom (see `reason`); also True when too few pairs were matched.
    reason : str
        Why the result is degenerate ("" when it is not).
    min_information : float
        Smallest eigenvalue of the normalised information ``D J^T J D / n``,
        ``D = diag(1, 1, 1/L)`` with ``L`` the RMS radius of the matched source
        points: the share of points constraining the weakest direction.
    weak_direction : ndarray, shape (3,)
        Its eigenvector in ``(t_x, t_y, L theta)``.
    history : ndarray, shape (iterations + 1, 3)
        The pose after each round, starting with the initial guess.
    method : str
        ``"point_to_line"`` or ``"point_to_point"``.
    """

    pose: np.ndarray
    iterations: int
    converged: bool
    rmse: float
    n_matched: int
    match_fraction: float
    cov: np.ndarray
    information: np.ndarray
    degenerate: bool
    reason: str
    min_information: float
    weak_direction: np.ndarray
    history: np.ndarray
    method: str

    @property
    def R(self):
        """Rotation matrix ``R(theta)``, shape (2, 2)."""
        c, s = np.cos(self.pose[2]), np.sin(self.pose[2])
        return np.array([[c, -s], [s, c]])

    @property
    def t(self):
        """Translation, shape (2,)."""
        return self.pose[:2].copy()


def _transform(pose, pts):
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return np.column_stack([c * pts[:, 0] - s * pts[:, 1] + pose[0], s * pts[:, 0] + c * pts[:, 1] + pose[1]])


def _associate(tgt, moved, max_dist, trim, need_normal):
    """Nearest target point of each moved source point; mask of the pairs kept."""
    d, j = tgt.tree.query(moved, k=1, distance_upper_bound=max_dist)
    keep = d <= max_dist  # unmatched points have d = inf and j = N
    j[~keep] = 0
    if need_normal:
        keep &= tgt.planar[j]
    n = int(np.count_nonzero(keep))
    if trim < 1.0 and n:
        # trimmed ICP: keep the closest fraction of the gated pairs
        dk = d[keep]
        m = max(1, int(np.ceil(trim * n)))
        limit = np.partition(dk, m - 1)[m - 1]
        keep &= d <= limit
    return d, j, keep


def _line_jacobian(tgt, moved, j, t):
    """Point-to-line residuals ``r = n^T (R p + t - q)`` and their Jacobian in ``(t_x, t_y, theta)``.

    `moved` are the source points ``R p + t`` already moved by the pose with translation `t`.
    """
    n = tgt.normals[j]
    diff = moved - tgt.points[j]
    r = n[:, 0] * diff[:, 0] + n[:, 1] * diff[:, 1]
    J = np.empty((r.size, 3))
    J[:, :2] = n  # dr/dt = n^T
    # dr/dtheta = n^T perp(R p), perp(R p) = R p rotated by 90 degrees, R p = moved - t
    J[:, 2] = -n[:, 0] * (moved[:, 1] - t[1]) + n[:, 1] * (moved[:, 0] - t[0])
    return r, J


def _icp(src, tgt, init, method, max_iter, max_dist, trim, tol_t, tol_r, min_matches, align=None):
    """Unchecked ICP core: `src` (N, 2) onto prepared target `tgt`, from pose `init` (3,)."""
    pose = init.copy()
    history = [pose.copy()]
    converged = False
    line = method == "point_to_line"
    it = 0
    for it in range(1, max_iter + 1):
        moved = _transform(pose, src)
        _, j, keep = _associate(tgt, moved, max_dist, trim, line)
        if np.count_nonzero(keep) < max(min_matches, 3):
            break
        if line:
            # one Gauss-Newton step on sum_k (n_k^T (R p_k + t - q_k))^2  (Chen & Medioni 1992; Censi 2008)
            r, J = _line_jacobian(tgt, moved[keep], j[keep], pose)
            H = J.T @ J
            g = J.T @ r
            # Levenberg damping only where H is near-singular (a corridor): the step stays bounded
            H = H + 1e-9 * max(np.trace(H), 1e-12) * np.eye(3)
            delta = -np.linalg.solve(H, g)
            new = pose + delta  # the heading is wrapped once, at the end
        else:
            # closed-form step on the matched pairs  (Besl & McKay 1992, Sec. III.C)
            R, t = (align or _rigid_fit)(src[keep], tgt.points[j[keep]])
            new = np.array([t[0], t[1], np.arctan2(R[1, 0], R[0, 0])])
        step_t = math.hypot(new[0] - pose[0], new[1] - pose[1])
        step_r = abs(math.remainder(new[2] - pose[2], _TWO_PI))  # |wrapped difference|, scalar
        # a two-cycle: the associations flip between two sets and the pose between two values
        back = history[-2] if len(history) > 1 else pose
        cycle = (math.hypot(new[0] - back[0], new[1] - back[1]) < tol_t
                 and abs(math.remainder(new[2] - back[2], _TWO_PI)) < tol_r)
        pose = new
        history.append(pose.copy())
        if step_t < tol_t and step_r < tol_r or cycle:
            converged = True
            break
    pose = np.array([pose[0], pose[1], wrap_angle(pose[2])])
    history = np.array(history)
    history[:, 2] = wrap_angle(history[:, 2])
    return pose, it, converged, history


def _assess(tgt, src, pose, max_dist, trim, min_matches, degeneracy):
    """Fit, covariance and degeneracy of the final alignment (point-to-line Hessian for either method)."""
    moved = _transform(pose, src)
    d, j, keep = _associate(tgt, moved, max_dist, trim, False)
    n_matched = int(np.count_nonzero(keep))
    rmse = float(np.sqrt(np.mean(d[keep] ** 2))) if n_matched else np.inf
    line = keep & tgt.planar[j]
    nl = int(np.count_nonzero(line))
    nan3 = np.full((3, 3), np.nan)
    if nl < max(min_matches, 4):
        reason = f"only {nl} matched points lie on lines (need {max(min_matches, 4)}): the alignment is not constrained"
        return n_matched, rmse, nan3, np.zeros((3, 3)), True, reason, 0.0, np.full(3, np.nan)
    r, J = _line_jacobian(tgt, moved[line], j[line], pose)
    H = J.T @ J
    # residual variance sigma^2 = sum r^2 / (n - 3); covariance sigma^2 (J^T J)^-1  (Gauss-Newton; Censi 2007 Sec. II)
    sigma2 = max(float(r @ r) / (nl - 3), 1e-8)
    info = H / sigma2
    L = float(np.sqrt(np.mean(np.sum(src[line] ** 2, axis=1)))) or 1.0
    D = np.array([1.0, 1.0, 1.0 / L])
    Hn = H * np.outer(D, D) / nl  # per-point information, rotation in metres of arc at radius L
    lam, vec = np.linalg.eigh(Hn)
    weak = vec[:, 0] * np.sign(vec[np.argmax(np.abs(vec[:, 0])), 0])
    cov = sigma2 * np.linalg.pinv(H, rcond=1e-12)
    degenerate = bool(lam[0] < degeneracy)
    reason = ""
    if degenerate:
        if abs(weak[2]) < 0.5:
            what = f"translation along ({weak[0]:+.2f}, {weak[1]:+.2f}) in the target frame"
        else:
            what = "the rotation"
        reason = (f"{what} is not constrained: smallest normalised information {lam[0]:.3g} < {degeneracy:g} "
                  "(a featureless corridor or a single wall)")
    return n_matched, rmse, cov, info, degenerate, reason, float(lam[0]), weak


def icp(source, target, init=None, *, method="point_to_line", max_iter=30, max_dist=0.3, trim=0.8, tol=1e-4,
        min_matches=10, normal_k=5, degeneracy=0.02, align=None):
    """Iterative closest point: align a 2-D point set (a scan) to another.

    Each round moves the source points by the current pose, pairs each with
    its nearest target point (``cKDTree``), drops pairs farther apart than
    `max_dist` (and, if ``trim < 1``, all but the closest `trim` fraction), and
    updates the pose:

    * ``"point_to_point"``: the closed-form alignment of the pairs
      (:func:`icp_align`), minimising ``sum |R p + t - q|^2`` (Besl & McKay);
    * ``"point_to_line"``: one Gauss-Newton step on ``sum (n^T (R p + t - q))^2``,
      the distances to the target's local lines with normals ``n`` from a PCA
      of each target point's `normal_k` nearest neighbours (Chen & Medioni;
      Censi's PLICP). It converges in a few rounds where point-to-point
      crawls along walls.

    It stops when a round moves the pose by less than `tol` (metres and
    radians) or after `max_iter` rounds.

    Parameters
    ----------
    source : ndarray, shape (N, 2)
        Points to move (the newer scan, in its own frame).
    target : ndarray, shape (M, 2)
        Reference points (the older scan or a local map, in its frame).
    init : ndarray, shape (3,), optional
        Initial guess of the pose of the source frame in the target frame,
        e.g. from odometry; default zero.
    method : {"point_to_line", "point_to_point"}, keyword-only
        The error minimised.
    max_iter : int, keyword-only
        Most rounds.
    max_dist : float, keyword-only
        Gate [m]: pairs farther apart are outliers (parts seen in one scan only).
    trim : float, keyword-only
        Fraction in ``(0, 1]`` of the gated pairs kept, the closest ones
        (trimmed ICP, Chetverikov et al. 2002). On the CMU log a person walks
        along with the robot; matching their legs pulls scan-to-scan ICP
        towards zero motion, and trimming the worst 20 % of the pairs removes
        them (ICP odometry's ATE against the reference track falls from
        1.6 m with ``trim=1`` to 0.3 m).
    tol : float, keyword-only
        Convergence tolerance on a round's change of translation [m] and rotation [rad].
    min_matches : int, keyword-only
        Fewest pairs to continue; fewer ends the run unconverged and degenerate.
    normal_k : int, keyword-only
        Neighbours of a target point used for its normal (>= 3).
    degeneracy : float, keyword-only
        Threshold on the smallest eigenvalue of the normalised point-to-line
        information (see :class:`ICPResult`): below it the result is flagged
        `degenerate`. 0.02 means: fewer than about 2 % of the matched points
        constrain the weakest direction.
    align : callable, optional, keyword-only
        ``align(P, Q) -> (R, t)`` used in place of :func:`icp_align` by
        ``"point_to_point"`` (for instance a student's alignment, as the
        autograder plugs it in); ignored by ``"point_to_line"``.

    Returns
    -------
    ICPResult
        Pose, convergence, fit, covariance, the degeneracy verdict and the
        pose after each round.

    Raises
    ------
    ValueError
        On NaN or inf in the points, wrong shapes, fewer than 3 target points,
        an unknown `method` or out-of-range options.

    References
    ----------
    Besl & McKay (1992); Chen & Medioni (1992); Censi (2008, PLICP; 2007,
    covariance); Lu & Milios (1997, scan matching for pose estimation);
    Thrun, Burgard & Fox (2005), Sec. 6.3.
    """
    src = as_array(source, "source", (None, 2))
    tgt = as_array(target, "target", (None, 2))
    if tgt.shape[0] < 3:
        raise ValueError(f"target must hold at least 3 points, got {tgt.shape[0]}")
    if src.shape[0] < 1:
        raise ValueError("source must hold at least 1 point")
    init = np.zeros(3) if init is None else as_array(init, "init", (3,))
    if method not in _METHODS:
        raise ValueError(f"method must be one of {_METHODS}, got {method!r}")
    max_iter = as_index(max_iter, "max_iter", lower=1)
    max_dist = as_scalar(max_dist, "max_dist", positive=True)
    trim = as_scalar(trim, "trim", positive=True)
    if trim > 1.0:
        raise ValueError(f"trim must be in (0, 1], got {trim}")
    tol = as_scalar(tol, "tol", positive=True)
    min_matches = as_index(min_matches, "min_matches", lower=3)
    normal_k = as_index(normal_k, "normal_k", lower=3)
    degeneracy = as_scalar(degeneracy, "degeneracy", nonnegative=True)
    if align is not None and not callable(align):
        raise TypeError(f"align must be callable align(P, Q) -> (R, t), got {type(align).__name__}")
    target_prep = _prepare_target(tgt, k=normal_k)
    return _icp_result(src, target_prep, init, method, max_iter, max_dist, trim, tol, min_matches, degeneracy,
                       align=align)


def _icp_result(src, tgt, init, method, max_iter, max_dist, trim, tol, min_matches, degeneracy, align=None):
    """Run the core and assess its result (unchecked; shared by :func:`icp` and the SLAM pipeline)."""
    pose, it, converged, history = _icp(src, tgt, init, method, max_iter, max_dist, trim, tol, tol, min_matches,
                                        align=align)
    n_matched, rmse, cov, info, degenerate, reason, lam, weak = _assess(tgt, src, pose, max_dist, trim, min_matches,
                                                                        degeneracy)
    if not converged and not reason and n_matched < min_matches:
        degenerate, reason = True, f"only {n_matched} pairs inside the gate (need {min_matches})"
    return ICPResult(pose=pose, iterations=it, converged=converged, rmse=rmse, n_matched=n_matched,
                     match_fraction=n_matched / src.shape[0], cov=cov, information=info, degenerate=degenerate,
                     reason=reason, min_information=lam, weak_direction=weak, history=history, method=method)
