"""Scoring SLAM estimates against ground truth, up to the gauge freedom.

A SLAM filter only sees controls and relative measurements (ranges and
bearings from the robot), so the posterior pins the robot path and the map down
relative to each other and to the starting pose it was given, not to the frame
the ground truth happens to be expressed in. Moving the whole solution, path and
map together, by any rotation and translation changes no measurement: SLAM fixes
the frame only up to a rigid transform (the *gauge freedom*). Before comparing
an estimate with ground truth we therefore remove the best rigid transform
(:func:`align_se2`, Umeyama's least-squares fit without scale) and score what is
left: the absolute trajectory error (ATE) of the positions, the heading error,
and the landmark error in the same frame.

Conventions used throughout:

* one transform per run, fitted on the trajectory positions and applied to both
  the path and the map (:func:`score_run`); the map is never aligned on its own,
  so a map that is rotated or shifted relative to the path it was built from
  counts as wrong;
* positions in metres, headings in radians, errors as root-mean-square.

The module also holds the noise-free dead-reckoning baseline
(:func:`dead_reckoning`) and residuals against ground truth used to calibrate
noise covariances (:func:`measurement_residuals`, :func:`control_residuals`).

References
----------
S. Umeyama, "Least-squares estimation of transformation parameters between two
point patterns", IEEE TPAMI 13(4):376-380, 1991. Thrun, Burgard & Fox,
*Probabilistic Robotics* (2005), Sec. 10.1 (SLAM estimates are relative to the
initial pose), Sec. 5.3 (velocity motion), Eq. 6.40 (range-bearing model).
"""

from __future__ import annotations

import numbers
from typing import NamedTuple

import numpy as np
from scipy.optimize import linear_sum_assignment

from ._checks import as_array, as_rigid_transform, as_scalar
from .angles import wrap_angle
from .metrics import ate_rmse, heading_rmse, landmark_rmse
from .motion import dead_reckoning  # noqa: F401  (moved to motion; still sl.dead_reckoning)
from .sensors import landmark_measurement

__all__ = [
    "align_se2",
    "apply_se2",
    "TrajectoryScore",
    "score_trajectory",
    "match_landmarks",
    "score_landmarks",
    "RunScore",
    "score_run",
    "NoiseCalibration",
    "calibrate_noise",
    "sighting_correlation",
    "association_errors",
    "format_score_table",
    "measurement_residuals",
    "control_residuals",
]


# --------------------------------------------------------------------------- rigid alignment
def align_se2(est_xy, true_xy):
    """Least-squares rigid transform (rotation and translation) taking `est_xy` onto `true_xy`.

    SLAM fixes the frame of its estimate only up to a rigid transform (the
    gauge freedom: moving path and map together changes no measurement), so an
    estimate is compared with ground truth after removing the best such
    transform. This is Umeyama's closed form with the scale fixed to 1:

    ``min_{R, t} sum_i |true_i - (R est_i + t)|^2``.

    Parameters
    ----------
    est_xy : ndarray, shape (K, 2)
        Estimated points (e.g. trajectory positions), ``K >= 2``.
    true_xy : ndarray, shape (K, 2)
        Corresponding true points.

    Returns
    -------
    R : ndarray, shape (2, 2)
        Rotation (``R^T R = I``, ``det R = +1``; reflections are excluded).
    t : ndarray, shape (2,)
        Translation; ``R @ est_xy[i] + t`` is the aligned point.

    Raises
    ------
    ValueError
        If the shapes differ, ``K < 2``, or the estimated points all coincide
        (the rotation is then undetermined).

    References
    ----------
    Umeyama (1991), Eqs. 40-42 with ``c = 1``; Thrun, Burgard & Fox (2005),
    Sec. 10.1.
    """
    est = as_array(est_xy, "est_xy", (None, 2))
    true = as_array(true_xy, "true_xy", (None, 2))
    if est.shape != true.shape:
        raise ValueError(f"est_xy {est.shape} and true_xy {true.shape} must have the same shape")
    if est.shape[0] < 2:
        raise ValueError(f"est_xy must hold at least 2 points to fix a rotation, got {est.shape[0]}")
    mu_e = est.mean(axis=0)
    mu_t = true.mean(axis=0)
    de = est - mu_e
    dtrue = true - mu_t
    scale = max(1.0, float(np.abs(est).max()))
    if np.sqrt(np.mean(np.sum(de**2, axis=1))) <= 1e-12 * scale:
        raise ValueError("est_xy points all coincide: the rotation of the alignment is undetermined")
    # Sigma_xy = 1/K sum (true_i - mu_t)(est_i - mu_e)^T  (Umeyama Eq. 38)
    cov = dtrue.T @ de / est.shape[0]
    U, _, Vt = np.linalg.svd(cov)
    # S = diag(1, det(U) det(V)) excludes reflections  (Umeyama Eq. 39)
    S = np.diag([1.0, np.sign(np.linalg.det(U) * np.linalg.det(Vt)) or 1.0])
    # R = U S V^T, t = mu_t - R mu_e  (Umeyama Eqs. 40, 42, c = 1)
    R = U @ S @ Vt
    t = mu_t - R @ mu_e
    return R, t


def apply_se2(R, t, x):
    """Apply the rigid transform ``p -> R p + t`` to points or poses.

    Parameters
    ----------
    R : ndarray, shape (2, 2)
        Rotation matrix.
    t : ndarray, shape (2,)
        Translation.
    x : ndarray, shape (..., 2) or (..., 3)
        Points ``[x, y]`` or poses ``[x, y, theta]``; a pose's heading is
        rotated by the angle of `R` and wrapped to ``[-pi, pi)``.

    Returns
    -------
    ndarray, same shape as `x`
        Transformed points or poses.

    References
    ----------
    Umeyama (1991), Eq. 1 (the similarity transform, here with scale 1);
    Thrun, Burgard & Fox (2005), Sec. 10.1.
    """
    R, t = as_rigid_transform(R, t)
    x = as_array(x, "x", ndim=range(1, 33))
    if x.shape[-1] not in (2, 3):
        raise ValueError(f"x must have shape (..., 2) points or (..., 3) poses, got {x.shape}")
    out = x.copy()
    # p' = R p + t
    out[..., :2] = x[..., :2] @ R.T + t
    if x.shape[-1] == 3:
        out[..., 2] = wrap_angle(x[..., 2] + np.arctan2(R[1, 0], R[0, 0]))
    return out


# --------------------------------------------------------------------------- trajectories
class TrajectoryScore(NamedTuple):
    """Result of :func:`score_trajectory`.

    Attributes
    ----------
    ate : float
        Absolute trajectory error: RMSE of the (aligned) positions, metres.
    heading_rmse : float
        RMSE of the (aligned) wrapped heading errors, radians.
    R : ndarray, shape (2, 2)
        Rotation of the alignment (identity without alignment).
    t : ndarray, shape (2,)
        Translation of the alignment (zero without alignment).
    """

    ate: float
    heading_rmse: float
    R: np.ndarray
    t: np.ndarray


def score_trajectory(est, true, *, align=True):
    """Absolute trajectory error and heading RMSE after rigid alignment.

    Parameters
    ----------
    est : ndarray, shape (T, 3)
        Estimated poses.
    true : ndarray, shape (T, 3)
        True poses at the same times.
    align : bool, keyword-only
        Fit the rigid transform of :func:`align_se2` on the positions and
        apply it to `est` first (default). Without it the raw errors are
        scored, which is meaningful only when the estimate was started in the
        ground truth's frame.

    Returns
    -------
    TrajectoryScore
        ``(ate, heading_rmse, R, t)``: ``ate = sqrt(mean_k |R p_k + t - p_k^true|^2)``,
        the heading RMSE after rotating the headings by the angle of ``R``,
        and the transform (to apply to the map of the same run).

    References
    ----------
    Umeyama (1991); Thrun, Burgard & Fox (2005), Sec. 10.1 (gauge of SLAM).
    """
    est = as_array(est, "est", (None, 3))
    true = as_array(true, "true", (None, 3))
    if est.shape != true.shape:
        raise ValueError(f"est {est.shape} and true {true.shape} must have the same shape")
    if est.shape[0] == 0:
        raise ValueError("est must hold at least one pose")
    if align:
        R, t = align_se2(est[:, :2], true[:, :2])
        est = apply_se2(R, t, est)
    else:
        R, t = np.eye(2), np.zeros(2)
    return TrajectoryScore(ate=ate_rmse(est, true), heading_rmse=heading_rmse(est, true), R=R, t=t)


# --------------------------------------------------------------------------- landmarks
def _transform_arg(transform):
    if transform is None:
        return np.eye(2), np.zeros(2)
    if isinstance(transform, TrajectoryScore):
        return as_rigid_transform(transform.R, transform.t, ("transform.R", "transform.t"))
    try:
        R, t = transform
    except (TypeError, ValueError):
        raise TypeError("transform must be None, a TrajectoryScore or a pair (R (2, 2), t (2,))") from None
    return as_rigid_transform(R, t, ("transform[0] (R)", "transform[1] (t)"))


def match_landmarks(est, true, *, transform=None, max_dist=np.inf):
    """One-to-one assignment of estimated to true landmarks (unknown correspondences).

    With unknown correspondences a filter numbers landmarks in the order it
    creates them, so its map must be matched to the true one before scoring:
    the assignment minimising the total distance (Hungarian algorithm) between
    the aligned estimates and the true landmarks.

    Parameters
    ----------
    est : ndarray, shape (N, 2)
        Estimated landmark positions, in any order.
    true : ndarray, shape (L, 2)
        True landmark positions.
    transform : pair (R, t) or TrajectoryScore or None, keyword-only
        Alignment applied to `est` first (the one fitted on the trajectory);
        ``None`` for none.
    max_dist : float, keyword-only
        Pairs farther apart than this (metres, after alignment) are dropped
        from the assignment: an estimate with no true landmark nearby is a
        spurious landmark, not a badly placed one.

    Returns
    -------
    est_idx, true_idx : int ndarrays, shape (P,)
        Matched pairs ``est[est_idx[i]] <-> true[true_idx[i]]``,
        ``P <= min(N, L)``, sorted by ``true_idx``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 10.3 (EKF SLAM with unknown
    correspondences numbers landmarks by first sighting).
    """
    est = as_array(est, "est", (None, 2))
    true = as_array(true, "true", (None, 2))
    R, t = _transform_arg(transform)
    max_dist = as_scalar(max_dist, "max_dist", positive=True, finite=False)
    if np.isnan(max_dist):
        raise ValueError("max_dist must be positive, got nan")
    if est.shape[0] == 0 or true.shape[0] == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    aligned = est @ R.T + t
    d = np.linalg.norm(aligned[:, None, :] - true[None, :, :], axis=-1)
    # pairs beyond max_dist cost more than any admissible assignment, then are dropped
    big = 1.0 + d[np.isfinite(d)].sum() if np.isinf(max_dist) else 1.0 + max_dist * (1 + min(d.shape))
    cost = np.where(d <= max_dist, d, big)
    ei, ti = linear_sum_assignment(cost)
    ok = d[ei, ti] <= max_dist
    ei, ti = ei[ok], ti[ok]
    order = np.argsort(ti)
    return ei[order].astype(np.int64), ti[order].astype(np.int64)


def score_landmarks(est, true, *, transform, seen=None):
    """Landmark RMSE in the frame of the trajectory alignment.

    The map is scored with the transform fitted on the *trajectory* of the
    same run (:func:`score_trajectory`), not with one fitted on the landmarks:
    path and map come out of one joint estimate and share one gauge, the
    trajectory has thousands of poses spread over the whole run while the map
    has a handful of landmarks, and a transform fitted on the landmarks alone
    would absorb three degrees of freedom of map error (reporting an
    optimistic number in a frame different from the ATE's).

    Parameters
    ----------
    est : ndarray, shape (N, 2)
        Estimated landmark positions, row ``j`` estimating ``true[j]`` (for
        unknown correspondences reorder first with :func:`match_landmarks`).
    true : ndarray, shape (N, 2)
        True landmark positions.
    transform : pair (R, t) or TrajectoryScore or None, keyword-only
        The trajectory's alignment, applied to `est`; ``None`` for none.
    seen : bool ndarray, shape (N,), optional, keyword-only
        Landmarks to score (e.g. those the filter has observed); default all.

    Returns
    -------
    float
        ``sqrt(mean_j |R m_j + t - m_j^true|^2)`` over the selected landmarks,
        metres.

    References
    ----------
    Umeyama (1991); Thrun, Burgard & Fox (2005), Sec. 10.1.
    """
    est = as_array(est, "est", (None, 2))
    true = as_array(true, "true", (None, 2))
    if est.shape != true.shape:
        raise ValueError(f"est {est.shape} and true {true.shape} must have the same shape")
    R, t = _transform_arg(transform)
    if seen is not None:
        seen = np.asarray(seen)
        if seen.dtype != bool or seen.shape != (est.shape[0],):
            raise ValueError(f"seen must be a boolean array of shape ({est.shape[0]},), got {seen.dtype} {seen.shape}")
        est, true = est[seen], true[seen]
    if est.shape[0] == 0:
        raise ValueError("no landmark to score (est is empty or seen selects none)")
    return landmark_rmse(est @ R.T + t, true)


# --------------------------------------------------------------------------- table rows
class RunScore(NamedTuple):
    """One row of a results table (:func:`score_run`).

    Attributes
    ----------
    name : str
        Method name.
    ate : float
        Aligned absolute trajectory error, metres.
    heading_rmse : float
        Aligned heading RMSE, radians.
    landmark_rmse : float
        Landmark RMSE in the trajectory's frame, metres (NaN without a map).
    n_landmarks : int
        Landmarks in the estimated map (0 without a map).
    n_matched : int
        Of those, how many were scored (matched to a true landmark).
    """

    name: str
    ate: float
    heading_rmse: float
    landmark_rmse: float
    n_landmarks: int
    n_matched: int


def score_run(name, x_est, x_true, *, landmarks_est=None, landmarks_true=None, seen=None, match=False,
              max_dist=np.inf, align=True):
    """Score one method on one run: a row of the results table.

    The rigid transform is fitted on the trajectory positions
    (:func:`score_trajectory`) and applied to both the trajectory and the map
    (:func:`score_landmarks`).

    Parameters
    ----------
    name : str
        Method name for the table.
    x_est : ndarray, shape (T, 3)
        Estimated poses.
    x_true : ndarray, shape (T, 3)
        True poses at the same times.
    landmarks_est : ndarray, shape (N, 2), optional, keyword-only
        Estimated map; ``None`` for a method without one (dead reckoning).
    landmarks_true : ndarray, shape (L, 2), optional, keyword-only
        True map (required with `landmarks_est`).
    seen : bool ndarray, shape (N,), optional, keyword-only
        Which rows of `landmarks_est` hold a landmark; default all.
    match : bool, keyword-only
        Match estimated to true landmarks with :func:`match_landmarks`
        (unknown correspondences); otherwise row ``j`` is landmark ``j``
        (``N == L``).
    max_dist : float, keyword-only
        Largest match distance (metres) with `match`.
    align : bool, keyword-only
        Remove the best rigid transform first (default).

    Returns
    -------
    RunScore
        ``(name, ate, heading_rmse, landmark_rmse, n_landmarks, n_matched)``.

    References
    ----------
    Umeyama (1991); Thrun, Burgard & Fox (2005), Sec. 10.1.
    """
    if not isinstance(name, str):
        raise TypeError(f"name must be a str, got {type(name).__name__}")
    traj = score_trajectory(x_est, x_true, align=align)
    if landmarks_est is None:
        return RunScore(name, traj.ate, traj.heading_rmse, float("nan"), 0, 0)
    if landmarks_true is None:
        raise ValueError("landmarks_true is required when landmarks_est is given")
    est = as_array(landmarks_est, "landmarks_est", (None, 2))
    true = as_array(landmarks_true, "landmarks_true", (None, 2))
    if seen is not None:
        seen = np.asarray(seen)
        if seen.dtype != bool or seen.shape != (est.shape[0],):
            raise ValueError(f"seen must be a boolean array of shape ({est.shape[0]},), got {seen.dtype} {seen.shape}")
    else:
        seen = np.ones(est.shape[0], dtype=bool)
    transform = (traj.R, traj.t)
    if match:
        rows = np.flatnonzero(seen)
        ei, ti = match_landmarks(est[rows], true, transform=transform, max_dist=max_dist)
        if ei.size == 0:
            return RunScore(name, traj.ate, traj.heading_rmse, float("nan"), int(rows.size), 0)
        lm = score_landmarks(est[rows[ei]], true[ti], transform=transform)
        return RunScore(name, traj.ate, traj.heading_rmse, lm, int(rows.size), int(ei.size))
    if est.shape != true.shape:
        raise ValueError(f"landmarks_est {est.shape} and landmarks_true {true.shape} must have the same shape "
                         "(or pass match=True)")
    if not seen.any():
        return RunScore(name, traj.ate, traj.heading_rmse, float("nan"), 0, 0)
    lm = score_landmarks(est, true, transform=transform, seen=seen)
    n = int(seen.sum())
    return RunScore(name, traj.ate, traj.heading_rmse, lm, n, n)


def format_score_table(rows):
    """Fixed-width text table of :class:`RunScore` rows.

    Parameters
    ----------
    rows : sequence of RunScore
        One row per method.

    Returns
    -------
    str
        Columns ``method``, ``ATE [m]`` and ``landmark RMSE [m]`` with two
        decimals, ``heading [deg]`` (RMSE) with one, and ``matched/mapped``:
        landmarks matched to true ones over landmarks in the estimated map;
        ``-`` where a method has no map.

    References
    ----------
    Umeyama (1991); Thrun, Burgard & Fox (2005), Sec. 10.1.
    """
    rows = list(rows)
    if not all(isinstance(r, RunScore) for r in rows):
        raise TypeError("rows must be RunScore tuples (from score_run)")
    width = max([len("method")] + [len(r.name) for r in rows])
    lines = [f"{'method':<{width}}  {'ATE [m]':>7}  {'heading [deg]':>13}  {'landmark RMSE [m]':>17}  "
             f"{'matched/mapped':>14}"]
    for r in rows:
        lm = "-" if np.isnan(r.landmark_rmse) else f"{r.landmark_rmse:.2f}"
        cnt = "-" if r.n_landmarks == 0 else f"{r.n_matched}/{r.n_landmarks}"
        lines.append(f"{r.name:<{width}}  {r.ate:>7.2f}  {np.degrees(r.heading_rmse):>13.1f}  {lm:>17}  {cnt:>14}")
    return "\n".join(lines)


# --------------------------------------------------------------------------- baselines and calibration
def _run_arrays(x_true, z, ids):
    x_true = as_array(x_true, "x_true", (None, 3))
    if len(z) != x_true.shape[0] - 1 or len(ids) != len(z):
        raise ValueError(f"z and ids must hold one entry per step ({x_true.shape[0] - 1}), got {len(z)} and {len(ids)}")
    return x_true


def measurement_residuals(x_true, z, ids, landmarks):
    """Measurements minus their prediction from the true poses and landmarks.

    Parameters
    ----------
    x_true : ndarray, shape (T + 1, 3)
        True poses; ``z[k]`` was taken at ``x_true[k + 1]``.
    z : sequence of T ndarrays, shape (K_k, 2)
        Measurements ``[r, phi]``.
    ids : sequence of T int ndarrays, shape (K_k,)
        Landmark index of each measurement.
    landmarks : ndarray, shape (N, 2)
        True landmark positions.

    Returns
    -------
    ndarray, shape (sum K_k, 2)
        ``z - h(x_true, m)`` with the bearing residual wrapped, in step order.
        Their covariance is an estimate of ``Q``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Eq. 6.40 (``h``), Sec. 6.3 with Table 6.2
    (learning measurement-model parameters from data).
    """
    x_true = _run_arrays(x_true, z, ids)
    landmarks = as_array(landmarks, "landmarks", (None, 2))
    counts = [np.shape(zk)[0] if np.size(zk) else 0 for zk in z]
    if sum(counts) == 0:
        return np.zeros((0, 2))
    Z = as_array(np.concatenate([np.reshape(zk, (-1, 2)) for zk in z]), "z", (None, 2))
    I = np.concatenate([np.asarray(i, dtype=np.int64).reshape(-1) for i in ids])
    if I.shape[0] != Z.shape[0]:
        raise ValueError("ids must hold one index per measurement in z")
    if I.size and (I.min() < 0 or I.max() >= landmarks.shape[0]):
        raise ValueError(f"ids must index landmarks (0..{landmarks.shape[0] - 1})")
    step = np.repeat(np.arange(len(z)), counts)
    z_hat, _, _ = landmark_measurement(x_true[step + 1], landmarks[I])
    res = Z - z_hat
    res[:, 1] = wrap_angle(res[:, 1])
    return res


def control_residuals(x_true, u, dt, *, window=1):
    """Commanded controls minus the controls the true poses imply.

    Parameters
    ----------
    x_true : ndarray, shape (T + 1, 3)
        True poses at the step times.
    u : ndarray, shape (T, 2)
        Commanded controls ``[v, omega]``.
    dt : float
        Step duration, seconds (positive).
    window : int, keyword-only
        Average the residuals over consecutive blocks of this many steps (a
        trailing partial block is dropped). Ground-truth poses are noisy, and
        differencing them over one short step amplifies that noise; averaging
        over a window shows the error of the controls themselves.

    Returns
    -------
    ndarray, shape (T // window, 2)
        ``u - [v_true, omega_true]``: ``omega_true = wrap(theta_{k+1} - theta_k) / dt``
        and ``v_true`` the speed of the arc through both positions with that
        turn rate.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 5.3 and Eq. 5.9 (exact arc, inverted
    here), Sec. 5.3.3 (why commanded and executed motion differ).
    """
    x_true = as_array(x_true, "x_true", (None, 3))
    u = as_array(u, "u", (None, 2))
    dt = as_scalar(dt, "dt", positive=True)
    if isinstance(window, bool) or not isinstance(window, (numbers.Integral, np.integer)) or window < 1:
        raise ValueError(f"window must be a positive integer, got {window!r}")
    if x_true.shape[0] != u.shape[0] + 1:
        raise ValueError(f"x_true must hold T + 1 = {u.shape[0] + 1} poses for u of shape {u.shape}, "
                         f"got {x_true.shape[0]}")
    w = wrap_angle(x_true[1:, 2] - x_true[:-1, 2]) / dt
    half = 0.5 * w * dt
    d = x_true[1:, :2] - x_true[:-1, :2]
    mid = x_true[:-1, 2] + half
    # chord = v dt sinc(omega dt / 2) along theta + omega dt / 2  (Eq. 5.9 in chord form)
    v = (d[:, 0] * np.cos(mid) + d[:, 1] * np.sin(mid)) / (dt * np.sinc(half / np.pi))
    res = u - np.column_stack([v, w])
    n = (res.shape[0] // int(window)) * int(window)
    return res[:n].reshape(-1, int(window), 2).mean(axis=1)


def sighting_correlation(residuals, ids, *, max_gap=10):
    """Correlation of the errors of consecutive sightings of the same landmark.

    Parameters
    ----------
    residuals : ndarray, shape (S, 2)
        Measurement residuals in step order (:func:`measurement_residuals`).
    ids : sequence of T int ndarrays, shape (K_k,)
        Landmark index of each sighting, per step (``sum K_k = S``).
    max_gap : int, keyword-only
        Pair a sighting with the previous sighting of the same landmark only
        if it is at most this many steps older (positive).

    Returns
    -------
    rho : ndarray, shape (2,)
        Correlation coefficient of the range and of the bearing residuals
        over those pairs. Near 0 for white measurement noise; near 1 when a
        landmark's error persists while the robot keeps seeing it.

    References
    ----------
    Bar-Shalom, Li & Kirubarajan (2001) (whiteness of the measurement
    noise); Thrun, Burgard & Fox (2005), Sec. 6.6 (the
    independence assumption of the measurement model).
    """
    residuals = as_array(residuals, "residuals", (None, 2))
    counts = [len(i) for i in ids]
    if sum(counts) != residuals.shape[0]:
        raise ValueError(f"ids must hold one index per residual ({residuals.shape[0]}), got {sum(counts)}")
    if isinstance(max_gap, bool) or not isinstance(max_gap, (numbers.Integral, np.integer)) or max_gap < 1:
        raise ValueError(f"max_gap must be a positive integer, got {max_gap!r}")
    step = np.repeat(np.arange(len(counts)), counts)
    lm = np.concatenate([np.asarray(i, dtype=np.int64).reshape(-1) for i in ids]) if counts else np.zeros(0, int)
    order = np.lexsort((step, lm))  # by landmark, then time (stable)
    same = (lm[order][1:] == lm[order][:-1]) & (np.diff(step[order]) <= max_gap)
    a, b = order[:-1][same], order[1:][same]
    if a.size < 3:
        raise ValueError("fewer than 3 pairs of consecutive sightings: correlation undefined")
    return np.array([np.corrcoef(residuals[a, c], residuals[b, c])[0, 1] for c in range(2)])


class NoiseCalibration(NamedTuple):
    """What :func:`calibrate_noise` measures on a log with ground truth.

    Attributes
    ----------
    M : ndarray, shape (2, 2)
        Control noise per step, ``diag(sigma_v^2, sigma_omega^2)``.
    Q : ndarray, shape (2, 2)
        Measurement noise, ``diag(sigma_r^2, sigma_phi^2)``, inflated for
        the correlation of consecutive sightings.
    control_std : ndarray, shape (n_windows, 2)
        White-noise-equivalent per-step standard deviations
        ``sqrt(n) std(mean of n residuals)`` for each window ``n``.
    windows : ndarray of int, shape (n_windows,)
        The windows, in steps.
    residual_rms : ndarray, shape (2,)
        Root-mean-square range and bearing residuals (gross outliers left out).
    rho : ndarray, shape (2,)
        Correlation of consecutive residuals of the same landmark
        (:func:`sighting_correlation`).
    n_outliers : int
        Sightings left out as gross outliers.
    """

    M: np.ndarray
    Q: np.ndarray
    control_std: np.ndarray
    windows: np.ndarray
    residual_rms: np.ndarray
    rho: np.ndarray
    n_outliers: int


def calibrate_noise(run, *, windows=(10, 50, 100, 300), max_gap=10, outlier=(1.5, 0.5)):
    """Estimate ``M`` and ``Q`` for a log from its residuals against the ground truth.

    Parameters
    ----------
    run : LandmarkRun or MRCLAMRun
        A run with ``x_true``, ``u``, ``dt``, ``z``, ``ids`` and ``landmarks``.
    windows : sequence of int, keyword-only
        Averaging windows (steps) for the control residuals. The default
        (1 s to 30 s at ``dt = 0.1``) leaves out single steps, whose
        residuals are dominated by the noise of differencing the ground
        truth.
    max_gap : int, keyword-only
        See :func:`sighting_correlation`.
    outlier : (float, float), keyword-only
        Sightings whose range residual exceeds ``outlier[0]`` metres or whose
        bearing residual exceeds ``outlier[1]`` radians are gross outliers
        (a validation gate's job), left out of the statistics.

    Returns
    -------
    NoiseCalibration
        ``M = diag(s^2)`` with ``s`` the largest white-noise-equivalent
        standard deviation over the windows, per component; ``Q =
        diag(q^2)`` with ``q = rms * sqrt((1 + rho) / (1 - rho))``.

    Notes
    -----
    * Control errors that were white would give the same per-step standard
      deviation ``sqrt(n) std(mean of n)`` for every window ``n``. Real
      command errors are partly correlated (a slipping wheel, a wrong wheel
      radius), which makes the value grow with ``n``; taking the largest
      over windows up to the time between landmark sightings sizes ``M`` for
      the drift the filter must absorb, not just the jitter of one step.
    * A filter that treats ``n`` sightings as independent gains ``n`` times
      the information of one. If consecutive errors have correlation
      ``rho`` (an AR(1) process), the mean of ``n`` of them has the variance
      of ``n (1 - rho) / (1 + rho)`` independent ones, so inflating the
      variance by ``(1 + rho) / (1 - rho)`` makes the filter's information
      gain honest.

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 6.3 and Table 6.2 (learning
    measurement-model parameters), Sec. 5.3.3; Bar-Shalom, Li &
    Kirubarajan (2001) (filter consistency, coloured noise).
    """
    for attr in ("x_true", "u", "dt", "z", "ids", "landmarks"):
        if not hasattr(run, attr):
            raise TypeError(f"run must have ground truth (attribute {attr!r} is missing)")
    windows = np.array([int(w) for w in windows])
    if windows.size == 0 or np.any(windows < 1):
        raise ValueError(f"windows must be positive integers, got {windows.tolist()}")
    lim = as_array(outlier, "outlier", (2,))
    res = measurement_residuals(run.x_true, run.z, run.ids, run.landmarks)
    bad = np.any(np.abs(res) > lim, axis=1)
    counts = [len(i) for i in run.ids]
    step_of = np.repeat(np.arange(len(counts)), counts)
    # drop the outliers from the residuals and from the per-step id lists alike
    keep_ids = [np.asarray(i)[~bad[step_of == k]] for k, i in enumerate(run.ids)]
    good = res[~bad]
    if good.shape[0] < 3:
        raise ValueError(f"run must hold at least 3 landmark sightings within the outlier gate to calibrate Q, "
                         f"got {good.shape[0]} (of {res.shape[0]})")
    rms = np.sqrt(np.mean(good**2, axis=0))
    rho = sighting_correlation(good, keep_ids, max_gap=max_gap)
    q = rms * np.sqrt((1 + rho) / (1 - rho))  # variance inflated by (1 + rho) / (1 - rho)
    std = np.array([control_residuals(run.x_true, run.u, run.dt, window=int(w)).std(axis=0) * np.sqrt(w)
                    for w in windows])  # sigma = sqrt(n) sigma_n, white-noise equivalent per step
    s = std.max(axis=0)
    return NoiseCalibration(M=np.diag(s**2), Q=np.diag(q**2), control_std=std, windows=windows,
                            residual_rms=rms, rho=rho, n_outliers=int(bad.sum()))


def association_errors(associations, landmark_ids, ids):
    """Count data-association errors of a SLAM run against the true landmark labels.

    Parameters
    ----------
    associations : sequence of T int ndarrays, shape (K_t,)
        Map slot each measurement updated, ``-1`` for none
        (``EKFSLAMResult.associations``).
    landmark_ids : ndarray of int, shape (L,)
        Unused here except for its length ``L`` (the map size); kept so that
        the call reads like the result it scores.
    ids : sequence of T int ndarrays, shape (K_t,)
        True landmark index of each measurement (the barcodes).

    Returns
    -------
    n_wrong : int
        Measurements that updated a map landmark whose majority label (the
        true landmark most of its updates came from) is not theirs.
    n_used : int
        Measurements that updated a landmark at all.
    n_split : int
        Extra map landmarks: map landmarks whose majority label is also the
        majority label of another, larger one (one true landmark mapped
        twice).

    Notes
    -----
    A map landmark that merges two true ones (two tubes 0.2 m apart) takes
    the label of the one it saw most; every sighting of the other counts
    as wrong.

    References
    ----------
    Neira & Tardos (2001) (association errors counted against ground
    truth).
    """
    L = len(landmark_ids)
    slots = np.concatenate([np.asarray(a, dtype=np.int64).reshape(-1) for a in associations]) if len(associations) else np.zeros(0, int)
    truth = np.concatenate([np.asarray(i, dtype=np.int64).reshape(-1) for i in ids]) if len(ids) else np.zeros(0, int)
    if slots.shape != truth.shape:
        raise ValueError(f"associations and ids must hold one entry per measurement, got {slots.size} and {truth.size}")
    used = slots >= 0
    if np.any(slots >= L):
        raise ValueError(f"associations must index the map of {L} landmarks")
    s, t = slots[used], truth[used]
    if s.size == 0:
        return 0, 0, 0
    n_true = max(int(t.max()) + 1, 1)
    table = np.zeros((L, n_true), dtype=np.int64)
    np.add.at(table, (s, np.maximum(t, 0)), 1)
    label = table.argmax(axis=1)
    n_wrong = int(np.sum(label[s] != t))
    size = table.sum(axis=1)
    n_split = 0
    for lab in np.unique(label[size > 0]):
        n_split += int(np.sum((label == lab) & (size > 0))) - 1
    return n_wrong, int(s.size), n_split
