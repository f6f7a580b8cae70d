"""Error metrics for estimates against ground truth, and filter consistency.

Position and heading errors, their root-mean-square over a trajectory, landmark
errors, and the normalised estimation error squared (NEES) with its chi-square
acceptance band.

References
----------
Thrun, Burgard & Fox, *Probabilistic Robotics* (2005), Sec. 3.2-3.3 (Gaussian
filters: the covariance a consistent filter reports); Bar-Shalom, Li &
Kirubarajan (2001), Sec. 5.4 (NEES and its chi-square test).
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from ._checks import as_array, as_covariance, as_index, as_poses, as_scalar, as_vector, check_batch
from .angles import wrap_angle

__all__ = ["pose_error", "ate_rmse", "heading_rmse", "landmark_rmse", "nees", "nees_band"]


def _pair(est, true, shape, names=("est", "true")):
    est = as_array(est, names[0], shape)
    true = as_array(true, names[1], shape)
    if est.shape != true.shape:
        raise ValueError(f"{names[0]} {est.shape} and {names[1]} {true.shape} must have the same shape")
    return est, true


def pose_error(est, true):
    """Pose error ``est - true`` with the heading error wrapped.

    Parameters
    ----------
    est, true : ndarray, shape (..., 3)
        Estimated and true poses; they broadcast.

    Returns
    -------
    ndarray, shape (..., 3)
        ``[x_e - x, y_e - y, wrap(theta_e - theta)]``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 7.5 (wrapped angular differences of pose estimates).
    """
    est = as_poses(est, "est", batched=True)
    true = as_poses(true, "true", batched=True)
    check_batch((est, 1, "est"), (true, 1, "true"))
    err = est - true
    err[..., 2] = wrap_angle(err[..., 2])
    return err


def ate_rmse(est, true):
    """Absolute trajectory error: RMSE of positions.

    Parameters
    ----------
    est, true : ndarray, shape (T, 3)
        Estimated and true poses (the heading is ignored).

    Returns
    -------
    float
        ``sqrt(mean_t |p_est,t - p_t|^2)``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 7.5 (EKF localization: estimate against true pose).
    """
    est, true = _pair(est, true, (None, 3))
    if est.shape[0] == 0:
        raise ValueError("est must hold at least one pose")
    d = est[:, :2] - true[:, :2]
    return float(np.sqrt(np.mean(np.sum(d**2, axis=1))))


def heading_rmse(est, true):
    """RMSE of the wrapped heading error over a trajectory.

    Parameters
    ----------
    est, true : ndarray, shape (T, 3)
        Estimated and true poses.

    Returns
    -------
    float
        ``sqrt(mean_t wrap(theta_est,t - theta_t)^2)`` in radians.

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 7.5.
    """
    est, true = _pair(est, true, (None, 3))
    if est.shape[0] == 0:
        raise ValueError("est must hold at least one pose")
    return float(np.sqrt(np.mean(wrap_angle(est[:, 2] - true[:, 2]) ** 2)))


def landmark_rmse(est, true):
    """RMSE of landmark positions.

    Parameters
    ----------
    est, true : ndarray, shape (N, 2)
        Estimated and true landmark positions, in the same order.

    Returns
    -------
    float
        ``sqrt(mean_j |m_est,j - m_j|^2)``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 10.2 (landmark estimates of EKF SLAM).
    """
    est, true = _pair(est, true, (None, 2))
    if est.shape[0] == 0:
        raise ValueError("est must hold at least one landmark")
    return float(np.sqrt(np.mean(np.sum((est - true) ** 2, axis=1))))


def nees(err, P):
    """Normalised estimation error squared ``err^T P^-1 err``.

    Parameters
    ----------
    err : ndarray, shape (..., n)
        Estimation errors (angles already wrapped, e.g. by :func:`pose_error`).
    P : ndarray, shape (..., n, n)
        Reported covariances (symmetric positive definite); broadcasts
        against `err`.

    Returns
    -------
    ndarray, shape (...)
        NEES values; for a consistent filter each is chi-square with ``n``
        degrees of freedom.

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 3.2 (the quadratic form in the
    multivariate normal); Bar-Shalom, Li & Kirubarajan (2001), Sec. 5.4.2.
    """
    err = as_vector(err, "err")
    n = err.shape[-1]
    P = as_covariance(P, "P", n, definite=True, batched=True, ref="err")
    shape = check_batch((err, 1, "err"), (P, 2, "P"))
    e = np.broadcast_to(err, shape + (n,))
    Pb = np.broadcast_to(P, shape + (n, n))
    try:
        L = np.linalg.cholesky(Pb)
    except np.linalg.LinAlgError:
        raise ValueError("P must be symmetric positive definite") from None
    # err^T P^-1 err = |L^-1 err|^2 with P = L L^T
    y = np.linalg.solve(L, e[..., None])[..., 0]
    return np.sum(y**2, axis=-1)


def nees_band(dof, n_runs, p=0.95):
    """Two-sided acceptance band of the average NEES over Monte-Carlo runs.

    Parameters
    ----------
    dof : int
        Dimension ``n`` of the state whose NEES is averaged.
    n_runs : int
        Number of independent runs ``N`` averaged.
    p : float
        Probability mass inside the band, in ``(0, 1)``.

    Returns
    -------
    lo, hi : float
        ``chi2.ppf((1 -+ p) / 2, n N) / N``: the average of ``N`` NEES values
        of a consistent filter lies in ``[lo, hi]`` with probability `p`.

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 3.2 (the normal whose quadratic form is
    chi-square); Bar-Shalom, Li & Kirubarajan (2001), Sec. 5.4.2.
    """
    dof = as_index(dof, "dof", lower=1)
    n_runs = as_index(n_runs, "n_runs", lower=1)
    p = as_scalar(p, "p")
    if not 0 < p < 1:
        raise ValueError(f"p must be in (0, 1), got {p}")
    k = dof * n_runs
    lo = stats.chi2.ppf((1 - p) / 2, k) / n_runs
    hi = stats.chi2.ppf((1 + p) / 2, k) / n_runs
    return float(lo), float(hi)
