"""EKF SLAM: known correspondences (Algorithm 1) and unknown ones (Algorithm 2).

The state is the robot pose followed by the landmark positions,
``mu = [x, y, theta, m0x, m0y, ..., m(N-1)x, m(N-1)y]`` of shape ``(3+2N,)``, with a
full ``(3+2N, 3+2N)`` covariance ``Sigma``.

Two implementations of the same mathematics live here.

* **Teaching version**: the contract functions :func:`ekf_slam_predict`,
  :func:`ekf_slam_measurement`, :func:`ekf_slam_init_landmark`,
  :func:`ekf_slam_update` and :func:`ekf_slam_associate` write every line of
  the algorithms with explicit projection matrices ``F_x`` and ``F_{x,j}`` and
  dense ``(3+2N) x (3+2N)`` algebra, exactly as printed. A prediction and an
  update each cost ``O(N^3)``.
* **Fast version**: the :class:`EKFSLAM` filter. Its prediction only touches
  the three robot rows and columns (``O(N)``); an update uses only the five
  non-zero columns of ``H`` and applies the covariance correction
  ``Sigma -= K S K^T = (Sigma H^T) S^-1 (Sigma H^T)^T`` as a symmetric rank-2
  term (``O(N^2)``). The rank-2 terms of up to 32 updates are held back and
  applied to the dense covariance together (every read in between subtracts
  them from what it needs, so each update still sees the exact sequential
  posterior). The buffers are preallocated and doubled when full, so a new
  landmark does not copy the covariance.

:func:`run_ekf_slam` runs either version over a simulated
:class:`~slamlib.sim.LandmarkRun` or a real log, with known or unknown
correspondences, an optional provisional landmark list that keeps clutter out
of the map, a chi-square validation gate on the innovation that rejects gross
outliers (on by default for real logs, which carry a ``gate``), and either
Algorithm 2's nearest neighbour or Joint Compatibility Branch and Bound
(:func:`jcbb_associate`) for the association. The JCBB search works on any
EKF SLAM state ``(mu, Sigma)`` of this layout.

A landmark not seen yet has the course's ``Sigma_0`` entry "infinity"; here it
gets the large finite variance ``prior_var`` on the diagonal and no
correlation, which is the same up to ``O(1 / prior_var)``.

References
----------
Course text, SLAM chapter: Algorithm 1 (EKF SLAM, known correspondences),
Algorithm 2 (unknown correspondences), Eqs. 17.2, 17.3 (range-bearing example,
``H = h F_{x,j}``). Thrun, Burgard & Fox, *Probabilistic Robotics* (2005),
Table 10.1 (known correspondences), Table 10.2 (unknown correspondences),
Sec. 10.3.3 (provisional landmark list). Line numbers in this module are those
of Thrun's tables (the course text's Algorithms 1 and 2 print the same steps
with their own numbering): Table 10.1 lines 2-5 predict, 9-11 initialise a
landmark, 12-19 correct; Table 10.2 line 16 ``Psi_k``, line 17 ``pi_k``,
lines 19-20 ``pi_{N+1} = alpha`` and the arg-min. J. Neira and J. D. Tardos,
"Data association in stochastic mapping using the joint compatibility test",
IEEE Trans. Robotics and Automation 17(6):890-897, 2001 (JCBB).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from scipy import stats

from ._checks import (as_array, as_covariance, as_index, as_indices, as_returned, as_scalar, as_slam_mean,
                      as_slam_state, as_threshold, check_callable)
from .angles import _wrap, _wrap1, wrap_angle
from .motion import STRAIGHT_LINE_OMEGA, _arc1, velocity_motion
from .sensors import MIN_RANGE, _landmark_measurement, _rbh1, landmark_from_measurement, landmark_measurement

__all__ = [
    "ekf_slam_predict",
    "ekf_slam_measurement",
    "ekf_slam_init_landmark",
    "ekf_slam_update",
    "ekf_slam_associate",
    "jcbb_associate",
    "joint_mahalanobis",
    "JCBB_NEW",
    "JCBB_UNPAIRED",
    "EKFSLAM",
    "EKFSLAMResult",
    "run_ekf_slam",
    "DEFAULT_ALPHA",
    "JCBB_ALPHA",
    "DEFAULT_PRIOR_VAR",
]

#: Default new-landmark threshold ``alpha`` on the squared Mahalanobis distance:
#: the 99.999 % quantile of the chi-square distribution with 2 degrees of freedom,
#: ``-2 ln(1e-5)`` (about 23.0). A run makes thousands of measurements, so a
#: 99 % or 99.9 % gate would split landmarks in two now and then.
DEFAULT_ALPHA = float(-2.0 * np.log(1e-5))
#: Default compatibility threshold of JCBB in :func:`run_ekf_slam`: the 99 % quantile of the
#: chi-square distribution with 2 degrees of freedom, ``-2 ln(0.01)`` (about 9.21), as Neira and
#: Tardos use.
JCBB_ALPHA = float(-2.0 * np.log(0.01))
#: Default prior variance (m^2) of a landmark before its first sighting (the
#: finite stand-in for the infinite ``Sigma_0`` entries of Algorithm 1).
DEFAULT_PRIOR_VAR = 1e4
_PENDING_COLS = 64  # columns of pending rank-2 terms (32 updates) before the dense covariance is refreshed


def _innovation(z, z_hat):
    """``nu = z - z_hat`` with the bearing wrapped, for ``(..., 2)`` arrays."""
    nu = z - z_hat
    nu[..., 1] = _wrap(nu[..., 1])
    return nu


def _predicted(mu, Sxx, Sxm, Smm, Q):
    """Expected measurement and innovation covariance of every landmark in `mu`.

    ``Sxx (3, 3)``, ``Sxm (N, 3, 2)``, ``Smm (N, 2, 2)`` are the robot block, the
    robot-landmark blocks and the landmark blocks of ``Sigma``. Returns
    ``z_hat (N, 2)`` and ``S (N, 2, 2)``, ``S_k = H_k Sigma H_k^T + Q`` on the
    five non-zero columns of ``H_k``.
    """
    N = Smm.shape[0]
    lm = mu[3:3 + 2 * N].reshape(N, 2)
    z_hat, _, Hm = _landmark_measurement(mu[:3], lm)  # (Eq. 17.2, 17.3) for every landmark (unchecked core)
    # S_k = H_k Sigma H_k^T + Q on the 5 non-zero columns  (Table 10.2 line 16: Psi_k). The range-bearing
    # model has H_x = [-H_m | c], c = (0, -1)^T, so H_k [x; m] = H_m (m - p) + c theta and
    # S_k = H_m D H_m^T + H_m e c^T + c e^T H_m^T + Sigma_thth c c^T + Q with D = Cov(m - p), e = Cov(m - p, theta):
    # written out per component over the landmarks (batched 2x3 matmuls cost several times more)
    P = Sxm[:, :2, :]  # Cov(p, m)
    d00 = Smm[:, 0, 0] - 2.0 * P[:, 0, 0] + Sxx[0, 0]
    d01 = 0.5 * (Smm[:, 0, 1] + Smm[:, 1, 0]) - P[:, 0, 1] - P[:, 1, 0] + 0.5 * (Sxx[0, 1] + Sxx[1, 0])
    d11 = Smm[:, 1, 1] - 2.0 * P[:, 1, 1] + Sxx[1, 1]
    e0 = Sxm[:, 2, 0] - Sxx[0, 2]
    e1 = Sxm[:, 2, 1] - Sxx[1, 2]
    h00, h01, h10, h11 = Hm[:, 0, 0], Hm[:, 0, 1], Hm[:, 1, 0], Hm[:, 1, 1]
    a00, a01 = h00 * d00 + h01 * d01, h00 * d01 + h01 * d11  # A = H_m D
    a10, a11 = h10 * d00 + h11 * d01, h10 * d01 + h11 * d11
    g0, g1 = h00 * e0 + h01 * e1, h10 * e0 + h11 * e1  # g = H_m e
    Sk = np.empty((N, 2, 2))
    Sk[:, 0, 0] = a00 * h00 + a01 * h01 + Q[0, 0]
    Sk[:, 0, 1] = a00 * h10 + a01 * h11 - g0 + Q[0, 1]
    Sk[:, 1, 0] = a10 * h00 + a11 * h01 - g0 + Q[1, 0]
    Sk[:, 1, 1] = a10 * h10 + a11 * h11 - 2.0 * g1 + Sxx[2, 2] + Q[1, 1]
    return z_hat, Sk


def _nis(Z, z_hat, Sk):
    """``d[i, k] = nu_ik^T S_k^-1 nu_ik`` for measurements ``Z (K, 2)`` and landmarks ``z_hat (N, 2)``, ``S (N, 2, 2)``."""
    nu = _innovation(Z[:, None, :], z_hat[None, :, :])
    det = Sk[:, 0, 0] * Sk[:, 1, 1] - Sk[:, 0, 1] * Sk[:, 1, 0]
    # d_k = nu^T S_k^-1 nu with the 2 x 2 inverse written out  (Table 10.2 line 17: pi_k)
    return (Sk[:, 1, 1] * nu[..., 0] ** 2 - (Sk[:, 0, 1] + Sk[:, 1, 0]) * nu[..., 0] * nu[..., 1]
            + Sk[:, 0, 0] * nu[..., 1] ** 2) / det


def _dense_blocks(Sigma, N):
    """The blocks :func:`_predicted` needs, read from a dense covariance (first `N` landmarks)."""
    n = 3 + 2 * N
    Sxm = Sigma[:3, 3:n].reshape(3, N, 2).transpose(1, 0, 2)
    r = np.arange(3, n, 2)
    Smm = np.empty((N, 2, 2))
    Smm[:, 0, 0] = Sigma[r, r]
    Smm[:, 0, 1] = Smm[:, 1, 0] = Sigma[r, r + 1]
    Smm[:, 1, 1] = Sigma[r + 1, r + 1]
    return Sigma[:3, :3], Sxm, Smm


# --------------------------------------------------------------------------- joint compatibility
#: Pairing codes of :func:`jcbb_associate` for a measurement left out of the best hypothesis.
JCBB_NEW = -1  #: individually compatible with no landmark: a new-landmark candidate
JCBB_UNPAIRED = -2  #: individually compatible with some landmark, but not jointly with the others: rejected


def _joint_threshold(alpha, k, _cache={}):
    """Chi-square quantile with ``2k`` degrees of freedom at the level of `alpha` (2 degrees of freedom)."""
    key = (alpha, k)
    if key not in _cache:
        if not math.isfinite(alpha) or k == 1:
            _cache[key] = alpha  # one pairing: the individual test itself
        else:
            # alpha = chi2.isf(q, 2) with tail q = exp(-alpha / 2); the joint test keeps the same tail
            _cache[key] = float(stats.chi2.isf(math.exp(-0.5 * alpha), 2 * k))
    return _cache[key]


def _jcbb(mu, sub_sigma, Z, d, Q, alpha):
    """Joint Compatibility Branch and Bound over precomputed individual distances.

    `mu` is the state mean, ``sub_sigma(cols)`` returns ``Sigma[cols][:, cols]``,
    ``Z (K, 2)`` the measurements and ``d (K, N)`` their squared Mahalanobis
    distances to the ``N`` landmarks. Returns the pairing ``(K,)`` (a landmark
    index, :data:`JCBB_NEW` or :data:`JCBB_UNPAIRED`) and the joint squared
    Mahalanobis distance of the pairs it makes.
    """
    K = Z.shape[0]
    compat = d <= alpha  # individual compatibility  (Neira & Tardos 2001)
    pairing = np.where(compat.any(axis=1), JCBB_UNPAIRED, JCBB_NEW)
    pi, pj = np.nonzero(compat)  # candidate pairs (measurement, landmark)
    if pi.size == 0:
        return pairing, 0.0
    if np.all(pi == pi[0]):
        # one measurement with candidates: the joint test is the individual one, the best hypothesis the nearest neighbour
        i = int(pi[0])
        pairing[i] = int(np.argmin(np.where(compat[i], d[i], np.inf)))
        return pairing, float(d[i, pairing[i]])
    # sub-state: the robot and the candidate landmarks; H of every pair on it, stacked
    cand = np.unique(pj)
    pos = np.searchsorted(cand, pj)
    cols = np.concatenate([[0, 1, 2], (3 + 2 * cand[:, None] + np.arange(2)).ravel()])
    Sig = sub_sigma(cols)
    P = pi.size
    z_hat, Hx, Hm = landmark_measurement(mu[:3], mu[3 + 2 * pj[:, None] + np.arange(2)])  # (Eqs. 17.2, 17.3)
    H = np.zeros((P, 2, cols.size))
    H[:, :, :3] = Hx
    H[np.arange(P)[:, None, None], np.arange(2)[None, :, None], (3 + 2 * pos)[:, None, None] + np.arange(2)] = Hm
    H = H.reshape(2 * P, cols.size)
    C = H @ Sig @ H.T  # covariance of the stacked predictions, H Sigma H^T  (joint innovation covariance minus Q)
    nu = _innovation(Z[pi], z_hat).ravel()
    by_i = [np.flatnonzero(pi == i) for i in range(K)]
    best_pairs, best_d2 = [], math.inf

    QQ = np.kron(np.eye(K), Q)  # blockdiag(Q, ..., Q)
    pair_rows = 2 * np.arange(P)[:, None] + np.arange(2)

    def joint(sel):
        rows = pair_rows[sel].ravel()
        S = C[rows[:, None], rows] + QQ[:rows.size, :rows.size]
        v = nu[rows]
        # D^2 = nu_H^T S_H^-1 nu_H, the joint Mahalanobis distance  (Neira & Tardos 2001)
        return float(v @ np.linalg.solve(S, v))

    def search(i, sel, used, d2):
        nonlocal best_pairs, best_d2
        if i == K:
            if len(sel) > len(best_pairs) or (len(sel) == len(best_pairs) and d2 < best_d2):
                best_pairs, best_d2 = list(sel), d2
            return
        for p in by_i[i]:  # pair measurement i with each individually compatible landmark
            if pj[p] in used:
                continue
            sel.append(p)
            d2p = joint(sel)
            if d2p <= _joint_threshold(alpha, len(sel)):  # joint compatibility
                search(i + 1, sel, used | {int(pj[p])}, d2p)
            sel.pop()
        if len(sel) + K - i - 1 > len(best_pairs):  # bound: leaving i unpaired can still beat the best
            search(i + 1, sel, used, d2)

    search(0, [], frozenset(), 0.0)
    for p in best_pairs:
        pairing[pi[p]] = pj[p]
    return pairing, best_d2


def jcbb_associate(mu_bar, Sigma_bar, z, n_seen, Q, alpha):
    """Joint Compatibility Branch and Bound data association for EKF SLAM.

    Parameters
    ----------
    mu_bar : ndarray, shape (3+2N,)
        Predicted mean; the robot pose and the first `n_seen` landmarks are
        read.
    Sigma_bar : ndarray, shape (3+2N, 3+2N)
        Predicted covariance.
    z : ndarray, shape (K, 2)
        The step's measurements ``[r, phi]``.
    n_seen : int
        Landmarks in the map, ``0 <= n_seen <= N``.
    Q : ndarray, shape (2, 2)
        Measurement-noise covariance, positive definite.
    alpha : float
        Individual compatibility threshold on the squared Mahalanobis
        distance (2 degrees of freedom), as in :func:`ekf_slam_associate`;
        the joint test of ``k`` pairings uses the chi-square quantile with
        ``2k`` degrees of freedom at the same tail probability
        ``exp(-alpha / 2)``.

    Returns
    -------
    ndarray of int, shape (K,)
        The pairing of the best hypothesis: a landmark index in
        ``[0, n_seen)``, :data:`JCBB_NEW` (``-1``) for a measurement
        individually compatible with no landmark (a new-landmark candidate),
        or :data:`JCBB_UNPAIRED` (``-2``) for one that is compatible with some
        landmark but left out of the best jointly compatible hypothesis.

    Notes
    -----
    A hypothesis pairs measurements with distinct landmarks. It is jointly
    compatible when the joint Mahalanobis distance of its stacked innovation
    ``nu_H`` (bearings wrapped) with the joint covariance
    ``S_H = H_H Sigma_bar H_H^T + blockdiag(Q)`` is within the chi-square
    bound. Branch and bound over the individually compatible pairs (taken
    in measurement order, a measurement may also stay unpaired) returns the
    jointly compatible hypothesis with the most pairings, ties going to the
    smallest joint distance. Unlike the nearest neighbour, which takes each
    measurement on its own, a pairing is accepted only if it is consistent
    with the others: the correlations in ``Sigma_bar`` (a common robot pose
    error shifts every prediction the same way) are used. One measurement
    gives the nearest neighbour's answer.

    References
    ----------
    J. Neira and J. D. Tardos, "Data association in stochastic mapping using
    the joint compatibility test", IEEE Trans. Robotics and Automation
    17(6):890-897, 2001; Thrun, Burgard & Fox (2005), Sec. 10.3 (Table 10.2
    lines 16-17 for the individual test).
    """
    mu_bar, Sigma_bar = as_slam_state(mu_bar, Sigma_bar, "mu_bar", "Sigma_bar")
    z = as_array(z, "z", (None, 2))
    n_seen = as_index(n_seen, "n_seen", (mu_bar.shape[0] - 3) // 2 + 1)
    Q = as_covariance(Q, "Q", 2, definite=True)
    alpha = as_threshold(alpha, "alpha")
    return _dense_jcbb(mu_bar, Sigma_bar, z, n_seen, Q, alpha)


def _dense_jcbb(mu, Sigma, Z, N, Q, alpha):
    if N == 0:
        return np.full(Z.shape[0], JCBB_NEW)
    z_hat, Sk = _predicted(mu, *_dense_blocks(Sigma, N), Q)
    d = _nis(Z, z_hat, Sk)
    return _jcbb(mu, lambda cols: Sigma[np.ix_(cols, cols)], Z, d, Q, alpha)[0]


def joint_mahalanobis(mu_bar, Sigma_bar, z, j, Q):
    """Joint squared Mahalanobis distance of a hypothesis pairing measurements with landmarks.

    Parameters
    ----------
    mu_bar : ndarray, shape (3+2N,)
        Predicted mean.
    Sigma_bar : ndarray, shape (3+2N, 3+2N)
        Predicted covariance.
    z : ndarray, shape (K, 2)
        Measurements.
    j : ndarray of int, shape (K,)
        Landmark paired with each measurement (distinct, in ``[0, N)``).
    Q : ndarray, shape (2, 2)
        Measurement-noise covariance, positive definite.

    Returns
    -------
    float
        ``D^2 = nu^T S^-1 nu`` with the stacked innovation ``nu (2K,)``
        (bearings wrapped) and ``S = H Sigma_bar H^T + blockdiag(Q, ..., Q)``,
        ``H (2K, 3+2N)`` the stacked measurement Jacobians ``h_t^j F_{x,j}``.

    References
    ----------
    Neira & Tardos (2001) (joint compatibility); course text,
    Eqs. 17.2, 17.3.
    """
    mu_bar, Sigma_bar = as_slam_state(mu_bar, Sigma_bar, "mu_bar", "Sigma_bar")
    z = as_array(z, "z", (None, 2))
    j = np.asarray(j)
    N = (mu_bar.shape[0] - 3) // 2
    if j.shape != (z.shape[0],) or (j.size and j.dtype.kind not in "iu"):
        raise ValueError(f"j must be an integer array of shape ({z.shape[0]},), got {j.dtype} {j.shape}")
    if j.size and (j.min() < 0 or j.max() >= N or np.unique(j).size != j.size):
        raise ValueError(f"j must hold distinct landmark indices in [0, {N}), got {j.tolist()}")
    Q = as_covariance(Q, "Q", 2, definite=True)
    Hs, nus = [], []
    for zi, ji in zip(z, j.tolist()):
        z_hat, H = _measurement(mu_bar, ji)  # (Eqs. 17.2, 17.3) with the dense F_{x,j}
        Hs.append(H)
        nus.append(_innovation(zi, z_hat))
    if not Hs:
        return 0.0
    H, nu = np.vstack(Hs), np.concatenate(nus)
    S = H @ Sigma_bar @ H.T + np.kron(np.eye(len(Hs)), Q)  # S_H = H Sigma H^T + blockdiag(Q)
    return float(nu @ np.linalg.solve(S, nu))


# --------------------------------------------------------------------------- teaching version
def _F_x(n):
    """``F_x = [I_3  0]``, shape ``(3, n)`` (Table 10.1 line 2)."""
    F = np.zeros((3, n))
    F[:, :3] = np.eye(3)
    return F


def _F_xj(n, j):
    """``F_{x,j}``, shape ``(5, n)``: picks the robot pose and landmark ``j`` (Table 10.1 line 15)."""
    F = np.zeros((5, n))
    F[:3, :3] = np.eye(3)
    F[3, 3 + 2 * j] = 1.0
    F[4, 4 + 2 * j] = 1.0
    return F


def ekf_slam_predict(mu, Sigma, u, dt, M):
    """EKF SLAM prediction: the robot moves, the landmarks stay put.

    Parameters
    ----------
    mu : ndarray, shape (3+2N,)
        State mean ``[x, y, theta, m0x, m0y, ...]``.
    Sigma : ndarray, shape (3+2N, 3+2N)
        State covariance.
    u : ndarray, shape (2,)
        Velocity control ``[v, omega]``.
    dt : float
        Duration of the control (seconds, non-negative).
    M : ndarray, shape (2, 2)
        Control-noise covariance.

    Returns
    -------
    mu_bar : ndarray, shape (3+2N,)
        Predicted mean: the robot pose moved along the exact arc (heading
        wrapped), the landmarks unchanged.
    Sigma_bar : ndarray, shape (3+2N, 3+2N)
        ``G Sigma G^T + F_x^T R F_x`` with ``G = I + F_x^T (G_x - I) F_x`` and
        ``R = V M V^T``: the robot block and the robot-landmark
        cross-covariances change, the landmark block does not.

    Notes
    -----
    Teaching version: builds the ``(3+2N, 3+2N)`` matrix ``G`` and multiplies
    densely, ``O(N^3)``. :meth:`EKFSLAM.predict` computes the same in ``O(N)``.

    Raises
    ------
    ValueError
        If ``Sigma`` is not a symmetric positive semi-definite ``(3+2N, 3+2N)``
        matrix (the message names it), or another argument is malformed.

    References
    ----------
    Course text, Algorithm 1; Thrun, Burgard & Fox (2005),
    Table 10.1 lines 2-5 and Table 7.2 lines 2-5 (``G``, ``V``, ``M``).
    """
    mu, Sigma = as_slam_state(mu, Sigma)
    u = as_array(u, "u", (2,))
    dt = as_scalar(dt, "dt", nonnegative=True)
    M = as_covariance(M, "M", 2)
    n = mu.shape[0]
    F = _F_x(n)  # F_x = [I 0]  (Table 10.1 line 2)
    x_next, G_x, V = velocity_motion(mu[:3], u, dt)
    delta = x_next - mu[:3]
    delta[2] = wrap_angle(delta[2])
    mu_bar = mu + F.T @ delta  # mu_bar = mu + F_x^T g(u, mu)  (Table 10.1 line 3)
    mu_bar[2] = wrap_angle(mu_bar[2])
    G = np.eye(n) + F.T @ (G_x - np.eye(3)) @ F  # G = I + F_x^T g_x F_x  (Table 10.1 line 4)
    R = V @ M @ V.T  # R = V M V^T  (Table 7.2 line 5, mapped into state space)
    Sigma_bar = G @ Sigma @ G.T + F.T @ R @ F  # Sigma_bar = G Sigma G^T + F_x^T R F_x  (Table 10.1 line 5)
    return mu_bar, 0.5 * (Sigma_bar + Sigma_bar.T)


def _measurement(mu, j):
    n = mu.shape[0]
    a = 3 + 2 * j
    # z_hat = [sqrt(q), atan2(dy, dx) - theta]  (Eq. 17.2; Table 10.1 lines 12-14)
    z_hat, Hx, Hm = landmark_measurement(mu[:3], mu[a:a + 2])
    h = np.hstack([Hx, Hm])  # low-dimensional Jacobian h_t^j, shape (2, 5)
    H = h @ _F_xj(n, j)  # H = h_t^j F_{x,j}  (Eq. 17.3; Table 10.1 line 16)
    return z_hat, H


def ekf_slam_measurement(mu, j):
    """Expected measurement of landmark `j` and its Jacobian in the full state.

    Parameters
    ----------
    mu : ndarray, shape (3+2N,)
        State mean.
    j : int
        Landmark index, ``0 <= j < N``.

    Returns
    -------
    z_hat : ndarray, shape (2,)
        ``h(mu, j) = [sqrt(q), wrap(atan2(dy, dx) - theta)]`` with
        ``(dx, dy) = m_j - (x, y)`` and ``q = dx^2 + dy^2``.
    H : ndarray, shape (2, 3+2N)
        ``H = h_t^j F_{x,j}``: the ``(2, 5)`` Jacobian ``h_t^j`` of ``h`` with
        respect to ``(x, y, theta, m_jx, m_jy)``, spread into the full state by
        ``F_{x,j}``. Only five columns are non-zero.

    Raises
    ------
    ValueError
        If landmark `j` sits on the robot (range 0: bearing undefined).

    References
    ----------
    Course text, Eqs. 17.2 and 17.3, Algorithm 1; Thrun, Burgard &
    Fox (2005), Table 10.1 lines 12-16.
    """
    mu = as_slam_mean(mu)
    j = as_index(j, "j", (mu.shape[0] - 3) // 2)
    return _measurement(mu, j)


def ekf_slam_init_landmark(mu, z, j):
    """Initialise landmark `j`'s mean from its first sighting.

    Parameters
    ----------
    mu : ndarray, shape (3+2N,)
        State mean.
    z : ndarray, shape (2,)
        Measurement ``[r, phi]`` of landmark `j`.
    j : int
        Landmark index, ``0 <= j < N``.

    Returns
    -------
    mu : ndarray, shape (3+2N,)
        A copy of `mu` with ``m_j = [x + r cos(phi + theta), y + r sin(phi +
        theta)]``; nothing else changes (the covariance keeps its prior).

    References
    ----------
    Course text, Algorithm 1; Thrun, Burgard & Fox (2005),
    Table 10.1 line 10.
    """
    mu = as_slam_mean(mu)
    z = as_array(z, "z", (2,))
    j = as_index(j, "j", (mu.shape[0] - 3) // 2)
    out = mu.copy()
    # mu_j = (x + r cos(phi + theta), y + r sin(phi + theta))  (Table 10.1 line 10)
    out[3 + 2 * j:5 + 2 * j] = landmark_from_measurement(mu[:3], z)
    return out


def ekf_slam_update(mu_bar, Sigma_bar, z, j, Q):
    """EKF SLAM correction with one measurement of a known landmark.

    Parameters
    ----------
    mu_bar : ndarray, shape (3+2N,)
        Predicted mean (landmark `j` already initialised).
    Sigma_bar : ndarray, shape (3+2N, 3+2N)
        Predicted covariance.
    z : ndarray, shape (2,)
        Measurement ``[r, phi]`` of landmark `j`.
    j : int
        Landmark index, ``0 <= j < N``.
    Q : ndarray, shape (2, 2)
        Measurement-noise covariance, positive definite.

    Returns
    -------
    mu : ndarray, shape (3+2N,)
        ``mu_bar + K nu`` with ``nu = z - z_hat`` (bearing wrapped) and the
        heading wrapped.
    Sigma : ndarray, shape (3+2N, 3+2N)
        ``(I - K H) Sigma_bar``, symmetrised.

    Notes
    -----
    Teaching version: dense ``(I - K H) Sigma_bar``, ``O(N^3)``.
    :meth:`EKFSLAM.update` computes the same in ``O(N^2)``.

    Raises
    ------
    ValueError
        If ``Sigma_bar`` is not a symmetric positive semi-definite ``(3+2N, 3+2N)``
        matrix (the message names it), or another argument is malformed.

    References
    ----------
    Course text, Algorithm 1, Eqs. 17.2, 17.3; Thrun, Burgard &
    Fox (2005), Table 10.1 lines 12-19.
    """
    mu_bar, Sigma_bar = as_slam_state(mu_bar, Sigma_bar, "mu_bar", "Sigma_bar")
    z = as_array(z, "z", (2,))
    j = as_index(j, "j", (mu_bar.shape[0] - 3) // 2)
    Q = as_covariance(Q, "Q", 2, definite=True)
    n = mu_bar.shape[0]
    z_hat, H = _measurement(mu_bar, j)  # (Table 10.1 lines 12-16)
    S = H @ Sigma_bar @ H.T + Q  # S = H Sigma_bar H^T + Q  (Table 10.1 line 17)
    K = np.linalg.solve(S, H @ Sigma_bar).T  # K = Sigma_bar H^T S^-1  (Table 10.1 line 17)
    nu = _innovation(z, z_hat)
    mu = mu_bar + K @ nu  # mu = mu_bar + K (z - z_hat)  (Table 10.1 line 18)
    mu[2] = wrap_angle(mu[2])
    Sigma = (np.eye(n) - K @ H) @ Sigma_bar  # Sigma = (I - K H) Sigma_bar  (Table 10.1 line 19)
    return mu, 0.5 * (Sigma + Sigma.T)


def ekf_slam_associate(mu_bar, Sigma_bar, z, n_seen, Q, alpha):
    """Maximum-likelihood data association with a new-landmark threshold.

    Parameters
    ----------
    mu_bar : ndarray, shape (3+2N,)
        Predicted mean; only the robot pose and the first `n_seen` landmarks
        are read.
    Sigma_bar : ndarray, shape (3+2N, 3+2N)
        Predicted covariance.
    z : ndarray, shape (2,)
        Measurement ``[r, phi]``.
    n_seen : int
        Number of landmarks in the map so far, ``0 <= n_seen <= N``; slots
        ``n_seen`` and beyond are ignored.
    Q : ndarray, shape (2, 2)
        Measurement-noise covariance, positive definite.
    alpha : float
        New-landmark threshold on the squared Mahalanobis distance
        (non-negative; ``inf`` never creates a landmark).

    Returns
    -------
    int
        In ``[0, n_seen]``: the landmark ``k < n_seen`` with the smallest
        ``d_k = nu_k^T S_k^-1 nu_k`` (``nu_k = z - h(mu_bar, k)``, bearing
        wrapped, ``S_k = H_k Sigma_bar H_k^T + Q``) if ``d_k <= alpha``; ties
        go to the smallest index. ``n_seen`` (a new landmark) when every
        distance exceeds `alpha` or ``n_seen = 0``.

    Notes
    -----
    Setting the distance of the hypothesised new landmark ``N+1`` to
    ``alpha`` and taking the arg-min, as Algorithm 2 does, is the same rule.

    Raises
    ------
    ValueError
        If ``Sigma_bar`` is not a symmetric positive semi-definite ``(3+2N, 3+2N)``
        matrix (the message names it), or another argument is malformed.

    References
    ----------
    Course text, Algorithm 2; Thrun, Burgard & Fox (2005), Table 10.2
    lines 16-20.
    """
    mu_bar, Sigma_bar = as_slam_state(mu_bar, Sigma_bar, "mu_bar", "Sigma_bar")
    z = as_array(z, "z", (2,))
    n_seen = as_index(n_seen, "n_seen", (mu_bar.shape[0] - 3) // 2 + 1)
    Q = as_covariance(Q, "Q", 2, definite=True)
    alpha = as_threshold(alpha, "alpha")
    best, best_d = n_seen, np.inf
    for k in range(n_seen):  # for k = 0, ..., N_t - 1  (Table 10.2)
        z_hat, H = _measurement(mu_bar, k)  # z_hat_k, H_k  (Eqs. 17.2, 17.3)
        S = H @ Sigma_bar @ H.T + Q  # S_k = H_k Sigma_bar H_k^T + Q  (Table 10.2 line 16: Psi_k)
        nu = _innovation(z, z_hat)
        d = float(nu @ np.linalg.solve(S, nu))  # d_k = nu^T S_k^-1 nu  (Table 10.2 line 17: pi_k)
        if d < best_d:  # strict: ties keep the smallest index
            best, best_d = k, d
    # d_{N_t} = alpha; j = argmin_k d_k  (Table 10.2 lines 19-20); a distance equal to alpha is a match
    return best if best_d <= alpha else n_seen


class _PlainEKFSLAM:
    """The teaching version behind the same interface as :class:`EKFSLAM`.

    Holds ``mu`` and ``Sigma`` and calls the contract functions; a new landmark
    is appended (the state grows by concatenation, copying ``Sigma``). ``steps``
    replaces some of them by a caller's functions (see :func:`_plain_steps`).
    """

    def __init__(self, x0, Sigma0, prior_var, steps=None):
        self.mu = np.array(x0, dtype=float)
        self.Sigma = np.array(Sigma0, dtype=float)
        self.prior_var = prior_var
        steps = steps or {}
        self._predict_fn = steps.get("predict", ekf_slam_predict)
        self._init_fn = steps.get("init", ekf_slam_init_landmark)
        self._update_fn = steps.get("update", ekf_slam_update)
        self._associate_fn = steps.get("associate", ekf_slam_associate)

    @property
    def n_landmarks(self):
        return (self.mu.shape[0] - 3) // 2

    @property
    def x(self):
        return self.mu[:3]

    @property
    def Sigma_x(self):
        return self.Sigma[:3, :3]

    def predict(self, u, dt, M):
        self.mu, self.Sigma = self._predict_fn(self.mu, self.Sigma, u, dt, M)

    def add_landmark(self, z):
        j = self.n_landmarks
        n = self.mu.shape[0]
        mu = np.concatenate([self.mu, np.zeros(2)])
        Sigma = np.zeros((n + 2, n + 2))
        Sigma[:n, :n] = self.Sigma
        Sigma[n, n] = Sigma[n + 1, n + 1] = self.prior_var  # Sigma_0 of a landmark not seen before
        self.mu, self.Sigma = self._init_fn(mu, z, j), Sigma
        return j

    def update(self, z, j, Q, gate=math.inf):
        if gate < math.inf:
            z_hat, H = _measurement(self.mu, j)  # (Eqs. 17.2, 17.3)
            nu = _innovation(z, z_hat)
            if nu @ np.linalg.solve(H @ self.Sigma @ H.T + Q, nu) > gate:  # validation gate on nu^T S^-1 nu
                return False
        self.mu, self.Sigma = self._update_fn(self.mu, self.Sigma, z, j, Q)
        return True

    def associate(self, z, Q, alpha):
        return self._associate_fn(self.mu, self.Sigma, z, self.n_landmarks, Q, alpha)

    def jcbb(self, z, Q, alpha):
        return jcbb_associate(self.mu, self.Sigma, z, self.n_landmarks, Q, alpha)

    def landmark_variances(self):
        d = np.diag(self.Sigma)[3:]
        return d[0::2] + d[1::2]


def _plain_steps(predict=None, init=None, update=None, associate=None):
    """The ``steps`` of :class:`_PlainEKFSLAM` for a caller's contract functions (each may be None: the library's).

    Each is called with the contract's arguments, on copies of the filter's
    arrays, and what it returns is checked (shapes, finite; an index in
    ``[0, n_seen]``).
    """
    steps = {}
    if predict is not None:
        def predict_step(mu, Sigma, u, dt, M):
            n = mu.shape[0]
            return as_returned(predict(mu.copy(), Sigma.copy(), u.copy(), dt, M.copy()), "ekf_slam_predict", (n,),
                               (n, n))
        steps["predict"] = predict_step
    if init is not None:
        def init_step(mu, z, j):
            return as_returned(init(mu.copy(), z.copy(), j), "ekf_slam_init_landmark", mu.shape)
        steps["init"] = init_step
    if update is not None:
        def update_step(mu_bar, Sigma_bar, z, j, Q):
            n = mu_bar.shape[0]
            return as_returned(update(mu_bar.copy(), Sigma_bar.copy(), z.copy(), j, Q.copy()), "ekf_slam_update", (n,),
                               (n, n))
        steps["update"] = update_step
    if associate is not None:
        def associate_step(mu_bar, Sigma_bar, z, n_seen, Q, alpha):
            j = associate(mu_bar.copy(), Sigma_bar.copy(), z.copy(), n_seen, Q.copy(), alpha)
            return as_index(j, "ekf_slam_associate(...)", n_seen + 1)
        steps["associate"] = associate_step
    return steps


# --------------------------------------------------------------------------- fast version
class EKFSLAM:
    """Fast EKF SLAM filter that owns growable state buffers.

    Parameters
    ----------
    x0 : ndarray, shape (3,)
        Initial robot pose.
    Sigma0 : ndarray, shape (3, 3), optional
        Initial robot covariance (default zero: the map frame is the robot's
        start, as in Algorithm 1).
    capacity : int, keyword-only
        Landmarks the buffers hold before they first double.
    prior_var : float, keyword-only
        Variance (m^2) given to each coordinate of a new landmark before its
        first update (the finite stand-in for Algorithm 1's infinite
        ``Sigma_0``).

    Attributes
    ----------
    mu : ndarray, shape (3+2N,)
        Read-only view of the current mean.
    Sigma : ndarray, shape (3+2N, 3+2N)
        Read-only view of the current covariance.
    n_landmarks : int
        ``N``.

    Notes
    -----
    Same mathematics as the contract functions, cheaper. Write the covariance
    as ``Sigma = S - P P^T``: a dense matrix ``S`` and an ``n x k`` matrix
    ``P`` of pending rank-2 corrections (``k <= 64``).

    * :meth:`update` reads the five rows ``idx`` of ``Sigma`` where ``H`` is
      non-zero (``Sigma[idx, :] = S[idx, :] - P[idx] P^T``, ``O(N)``), forms
      ``(Sigma H^T)^T = h Sigma[idx, :]`` (``2 x n``) and
      ``S_innov = h (Sigma H^T)[idx] + Q``, and writes the correction
      ``K S_innov K^T = (Sigma H^T) S_innov^-1 (Sigma H^T)^T = W W^T``
      (``W = Sigma H^T L^-T``, ``S_innov = L L^T``) as two new columns of
      ``P``: a symmetric rank-2 update that costs ``O(N)`` now.
    * :meth:`predict` changes only the robot rows and columns: ``S_xx <- G_x S_xx G_x^T
      + R``, ``S_xm <- G_x S_xm`` and ``P_x <- G_x P_x`` (``O(N)``; since
      ``G = I + F_x^T (G_x - I) F_x``, ``G (S - P P^T) G^T = G S G^T - (G P)
      (G P)^T``).
    * When ``P`` is full, or when ``Sigma`` is read, ``S -= P P^T`` is
      applied in one pass (``O(N^2)``, amortised over 32 updates). Every read
      in between subtracts the pending terms from what it needs, so each
      update sees the exact sequential posterior and the results equal the
      teaching version to rounding.
    * The buffers have room for `capacity` landmarks and double when full:
      adding a landmark writes two rows and columns, it does not copy the
      covariance.
    * :meth:`associate` and :meth:`jcbb` compute the distance
      ``nu^T S_k^-1 nu`` only for the landmarks a lower bound does not
      already put beyond the threshold: ``d >= nu_i^2 / S_k,ii`` and each
      ``S_k,ii`` is bounded by variances on the diagonal of ``S`` (``O(N)``
      per measurement, no pending terms, no angle wrapping); the choice is
      the same as over every landmark's distance. (A state given slightly
      below semi-definite, within the checks' rounding tolerance, is bounded
      through ``Sigma + eps I``, ``-eps`` its smallest eigenvalue.)

    The views `mu` and `Sigma` change as the filter runs; copy them to keep a
    snapshot.

    References
    ----------
    Course text, Algorithms 1 and 2, Eqs. 17.2, 17.3; Thrun, Burgard & Fox
    (2005), Tables 10.1 and 10.2; Guivant & Nebot (2001) on delaying the
    full-covariance update.
    """

    #: Motion model ``motion(x, u, dt) -> (x_next, G, V)``; None is the velocity model (exact arc).
    _motion = None

    def __init__(self, x0, Sigma0=None, *, capacity=16, prior_var=DEFAULT_PRIOR_VAR):
        x0 = as_array(x0, "x0", (3,))
        x0[2] = wrap_angle(x0[2])
        Sigma0 = np.zeros((3, 3)) if Sigma0 is None else as_covariance(Sigma0, "Sigma0", 3)
        capacity = as_index(capacity, "capacity", lower=1)
        self.prior_var = as_scalar(prior_var, "prior_var", positive=True)
        self._alloc(capacity)
        self._n = 3
        self._mu[:3] = x0
        self._S[:3, :3] = Sigma0
        self._neg = _negative_part(Sigma0)

    @classmethod
    def from_state(cls, mu, Sigma, *, capacity=None, prior_var=DEFAULT_PRIOR_VAR):
        """Start the filter from a full state.

        Parameters
        ----------
        mu : ndarray, shape (3+2N,)
            State mean.
        Sigma : ndarray, shape (3+2N, 3+2N)
            State covariance.
        capacity : int, optional
            Landmark capacity (at least ``N``; default ``max(16, N + N // 4)``).
        prior_var : float
            Prior variance of landmarks added later.

        Returns
        -------
        EKFSLAM
            A filter holding copies of `mu` and `Sigma`.

        References
        ----------
        Course text, Algorithm 1 (state layout).
        """
        mu, Sigma = as_slam_state(mu, Sigma)
        N = (mu.shape[0] - 3) // 2
        if capacity is None:
            capacity = max(16, N + N // 4)
        capacity = as_index(capacity, "capacity", lower=max(N, 1))
        # Sigma was checked whole: its robot block is not checked again on its own (its own scale)
        f = cls(mu[:3], capacity=capacity, prior_var=prior_var)
        f._n = mu.shape[0]
        f._mu[:f._n] = mu
        f._mu[2] = wrap_angle(mu[2])
        f._S[:f._n, :f._n] = Sigma
        f._neg = _negative_part(Sigma)
        return f

    # ----------------------------------------------------------------- buffers
    def _alloc(self, capacity):
        size = 3 + 2 * capacity
        self._cap = capacity
        self._mu = np.zeros(size)
        self._S = np.zeros((size, size))
        self._Pt = np.zeros((_PENDING_COLS, size))  # P^T: pending corrections, one per row
        self._k = 0

    def _grow(self):
        self._flush()
        n, mu, S = self._n, self._mu, self._S
        self._alloc(2 * self._cap)  # doubling: amortised O(n) per added landmark
        self._mu[:n] = mu[:n]
        self._S[:n, :n] = S[:n, :n]

    def _flush(self):
        """Bring ``S`` up to date: ``S -= P P^T``."""
        n, k, S = self._n, self._k, self._S
        if k:
            Pt = self._Pt[:k, :n]
            # Sigma -= sum_i K_i S_i K_i^T = P P^T  (Table 10.1 line 19, symmetric form)
            S[:n, :n] -= Pt.T @ Pt
            self._k = 0

    @property
    def capacity(self):
        """Landmarks the buffers hold before they double."""
        return self._cap

    @property
    def n_landmarks(self):
        """Number of landmarks ``N`` in the state."""
        return (self._n - 3) // 2

    @property
    def mu(self):
        """Read-only view of the mean, shape ``(3+2N,)``."""
        v = self._mu[:self._n]
        v.flags.writeable = False
        return v

    @property
    def Sigma(self):
        """Read-only view of the covariance, shape ``(3+2N, 3+2N)``."""
        self._flush()
        v = self._S[:self._n, :self._n]
        v.flags.writeable = False
        return v

    @property
    def x(self):
        """Copy of the robot pose, shape ``(3,)``."""
        return self._mu[:3].copy()

    @property
    def Sigma_x(self):
        """Copy of the robot covariance, shape ``(3, 3)``."""
        P3 = self._Pt[:self._k, :3]
        return self._S[:3, :3] - P3.T @ P3

    def landmark_variances(self):
        """``Var(m_jx) + Var(m_jy)`` of every landmark, shape ``(N,)``."""
        n = self._n
        d = np.diagonal(self._S)[3:n] - np.einsum("ki,ki->i", self._Pt[:self._k, 3:n], self._Pt[:self._k, 3:n])
        return d[0::2] + d[1::2]

    def copy(self):
        """An independent copy of the filter (buffers included)."""
        new = object.__new__(EKFSLAM)
        new.__dict__.update(self.__dict__)
        new._mu, new._S, new._Pt = self._mu.copy(), self._S.copy(), self._Pt.copy()
        return new

    # ----------------------------------------------------------------- steps
    def predict(self, u, dt, M):
        """Prediction step in ``O(N)``: only the robot rows and columns change.

        Parameters
        ----------
        u : ndarray, shape (2,)
            Velocity control ``[v, omega]``.
        dt : float
            Duration (seconds, non-negative).
        M : ndarray, shape (2, 2)
            Control-noise covariance.

        Returns
        -------
        EKFSLAM
            The filter itself (updated in place).

        References
        ----------
        Course text, Algorithm 1; Thrun, Burgard & Fox (2005),
        Table 10.1 lines 2-5.
        """
        u = as_array(u, "u", (2,))
        dt = as_scalar(dt, "dt", nonnegative=True)
        M = as_covariance(M, "M", 2)
        self._predict(u, dt, M)
        return self

    def _predict(self, u, dt, M):
        n, k, S = self._n, self._k, self._S
        if self._motion is None:
            x_next, G, V = _arc1(self._mu[:3], u, dt)
        else:  # a pluggable motion model, e.g. slamlib.AckermannModel: (x_next, G, V) of the pose
            x_next, G, V = self._motion(self._mu[:3], u, dt)
        self._mu[:3] = x_next  # mu_bar = mu + F_x^T g(u, mu)  (Table 10.1 line 3)
        dot = np.dot  # the BLAS call of @, with less dispatch on these small matrices
        R = dot(dot(V, M), V.T)  # R = V M V^T  (Table 7.2 line 5)
        Sxx = dot(dot(G, S[:3, :3]), G.T) + R  # robot block of G Sigma G^T + F_x^T R F_x  (Table 10.1 line 5)
        S[:3, :3] = 0.5 * (Sxx + Sxx.T)
        if n > 3:
            Sxm = dot(G, S[:3, 3:n])  # robot-landmark block G_x Sigma_xm  (Table 10.1 line 5)
            S[:3, 3:n] = Sxm
            S[3:n, :3] = Sxm.T
        if k:
            self._Pt[:k, :3] = dot(self._Pt[:k, :3], G.T)  # pending terms: P_x <- G_x P_x

    def add_landmark(self, z):
        """Append a landmark initialised from measurement `z`.

        Parameters
        ----------
        z : ndarray, shape (2,)
            Measurement ``[r, phi]`` from the current robot pose.

        Returns
        -------
        int
            The new landmark's index ``j = N`` (before the call).

        Notes
        -----
        The mean is the inverse measurement (Table 10.1 line 10); the
        covariance of the new landmark is ``prior_var I`` with no correlation,
        as a landmark not yet seen has in ``Sigma_0``. Follow with
        :meth:`update` to fuse `z`. Amortised cost ``O(N)``.

        References
        ----------
        Course text, Algorithm 1; Thrun, Burgard & Fox (2005),
        Table 10.1 line 10.
        """
        return self._add_landmark(as_array(z, "z", (2,)))

    def _add_landmark(self, z):
        if self.n_landmarks == self._cap:
            self._grow()
        j, a = self.n_landmarks, self._n
        # mu_j = (x + r cos(phi + theta), y + r sin(phi + theta))  (Table 10.1 line 10)
        self._mu[a:a + 2] = landmark_from_measurement(self._mu[:3], z)
        self._S[a, a] = self._S[a + 1, a + 1] = self.prior_var
        self._Pt[:, a:a + 2] = 0.0
        self._n += 2
        return j

    def update(self, z, j, Q, *, gate=None):
        """Correction with one measurement of landmark `j`, ``O(N)`` plus the amortised ``O(N^2)`` flush.

        Parameters
        ----------
        z : ndarray, shape (2,)
            Measurement ``[r, phi]``.
        j : int
            Landmark index, ``0 <= j < N``.
        Q : ndarray, shape (2, 2)
            Measurement-noise covariance, positive definite.
        gate : float, optional, keyword-only
            Validation gate on the normalised innovation squared
            ``nu^T S^-1 nu`` (``S = H Sigma H^T + Q``): a measurement beyond
            it is rejected and the filter is left unchanged. Default: no gate.

        Returns
        -------
        EKFSLAM
            The filter itself (updated in place, or unchanged if gated).

        References
        ----------
        Course text, Algorithm 1, Eqs. 17.2, 17.3; Thrun, Burgard
        & Fox (2005), Table 10.1 lines 12-19.
        """
        z = as_array(z, "z", (2,))
        j = as_index(j, "j", self.n_landmarks)
        Q = as_covariance(Q, "Q", 2, definite=True)
        gate = as_threshold(gate, "gate", optional=True, none=math.inf)
        self._update(z, j, Q, gate)
        return self

    def _update(self, z, j, Q, gate=math.inf):
        # The hot path of every measurement: the arguments are checked by the public callers, so this only
        # does the algebra. At small N the cost is the number of NumPy calls, not their size: scalars are
        # Python floats (tolist, item), rows and columns are gathered with take, the index rows of each
        # landmark are built once (_rows), and products are ndarray.dot (the same BLAS call as @, with
        # less dispatch).
        if self._k + 2 > _PENDING_COLS:
            self._flush()
        n, k, mu = self._n, self._k, self._mu
        a = 3 + 2 * j
        idx = _ROWS.get(a)
        if idx is None:
            idx = _rows(a)  # [0, 1, 2, a, a+1]: the five non-zero columns of H
        # z_hat and h_t^j = 1/q [[-r dx, -r dy, 0, r dx, r dy], [dy, -dx, -q, -dy, dx]]  (Eqs. 17.2, 17.3;
        # Table 10.1 lines 12-16), from the five entries of mu it reads (sensors._rbh1)
        r_hat, phi_hat, h = _rbh1(*mu.take(idx).tolist())
        R = self._S.take(idx, 0)[:, :n]  # Sigma[idx, :] = (Sigma F_{x,j}^T)^T, the 5 rows H touches
        if k:
            Pt = self._Pt[:k]
            R -= Pt.take(idx, 1).T.dot(Pt[:, :n])  # minus the pending terms
        HP = h.dot(R)  # (Sigma H^T)^T, shape (2, n)  (Eq. 17.3: H = h F_{x,j})
        i00, i10, i11, e0, e1 = _whiten(HP.take(idx, 1).dot(h.T), Q, z, r_hat, phi_hat)
        if e0 * e0 + e1 * e1 > gate:  # validation gate: nu^T S^-1 nu = |L^-1 nu|^2 > gate
            return False
        Wt = np.array([[i00, 0.0], [i10, i11]]).dot(HP)  # W^T = L^-1 (Sigma H^T)^T: W W^T = K S K^T
        mu[:n] += np.array([e0, e1]).dot(Wt)  # mu += K nu, K = W L^-1  (Table 10.1 line 18)
        mu[2] = _wrap1(mu.item(2))
        self._Pt[k:k + 2, :n] = Wt  # Sigma -= W W^T, applied in _flush  (Table 10.1 line 19)
        self._k = k + 2
        return True

    def step(self, u, dt, M, z, j, Q):
        """One full step with known correspondences: :meth:`predict`, then :meth:`update` for each measurement.

        Parameters
        ----------
        u : ndarray, shape (2,)
            Velocity control ``[v, omega]``.
        dt : float
            Duration (seconds, non-negative).
        M : ndarray, shape (2, 2)
            Control-noise covariance.
        z : ndarray, shape (K, 2)
            Measurements ``[r, phi]``, processed in order.
        j : ndarray of int, shape (K,)
            Landmark index of each measurement, ``0 <= j < N`` (add new
            landmarks with :meth:`add_landmark` first).
        Q : ndarray, shape (2, 2)
            Measurement-noise covariance, positive definite.

        Returns
        -------
        EKFSLAM
            The filter itself (updated in place).

        References
        ----------
        Course text, Algorithm 1; Thrun, Burgard & Fox (2005), Table 10.1.
        """
        u = as_array(u, "u", (2,))
        dt = as_scalar(dt, "dt", nonnegative=True)
        M = as_covariance(M, "M", 2)
        z = as_array(z, "z", (None, 2))
        j = as_indices(j, "j", self.n_landmarks, (z.shape[0],), ref="z")
        Q = as_covariance(Q, "Q", 2, definite=True)
        self._predict(u, dt, M)
        for zi, ji in zip(z.tolist(), j.tolist()):  # Python floats and ints: no NumPy scalars in the loop
            self._update(zi, ji, Q)
        return self

    def mahalanobis(self, z, Q):
        """Squared Mahalanobis distance of `z` to every landmark, vectorised.

        Parameters
        ----------
        z : ndarray, shape (2,)
            Measurement ``[r, phi]``.
        Q : ndarray, shape (2, 2)
            Measurement-noise covariance, positive definite.

        Returns
        -------
        ndarray, shape (N,)
            ``d_k = nu_k^T S_k^-1 nu_k`` with ``S_k = H_k Sigma H_k^T + Q``.

        References
        ----------
        Course text, Algorithm 2; Thrun, Burgard & Fox (2005), Table 10.2
        lines 16-17.
        """
        return self._mahalanobis(as_array(z, "z", (2,)), as_covariance(Q, "Q", 2, definite=True))

    def _mahalanobis(self, z, Q):
        return self._distances(z[None], Q)[0]

    def _blocks(self):
        """Robot block ``(3, 3)``, robot-landmark blocks ``(N, 3, 2)`` and landmark blocks ``(N, 2, 2)`` of ``Sigma``."""
        N, n, k = self.n_landmarks, self._n, self._k
        S, Pt = self._S, self._Pt[:k, :n]
        Sxx = S[:3, :3] - Pt[:, :3].T @ Pt[:, :3]  # robot block
        Sxm = S[:3, 3:n] - Pt[:, :3].T @ Pt[:, 3:]  # robot-landmark blocks, (3, 2N)
        r = np.arange(3, n, 2)
        Smm = np.empty((N, 2, 2))  # landmark diagonal blocks
        Smm[:, 0, 0] = S[r, r]
        Smm[:, 0, 1] = Smm[:, 1, 0] = S[r, r + 1]
        Smm[:, 1, 1] = S[r + 1, r + 1]
        if k:
            Pl = Pt[:, 3:].reshape(k, N, 2)
            Smm -= np.einsum("kni,knj->nij", Pl, Pl)
        return Sxx, Sxm.reshape(3, N, 2).transpose(1, 0, 2), Smm

    def _sub_sigma(self, cols):
        """``Sigma[cols][:, cols]`` with the pending terms subtracted."""
        P = self._Pt[:self._k, cols]
        return self._S[np.ix_(cols, cols)] - P.T @ P

    def _distances(self, Z, Q):
        """Squared Mahalanobis distances of measurements ``Z (K, 2)`` to every landmark, shape ``(K, N)``."""
        N = self.n_landmarks
        if N == 0:
            return np.empty((Z.shape[0], 0))
        z_hat, Sk = _predicted(self._mu[:self._n], *self._blocks(), Q)
        return _nis(Z, z_hat, Sk)

    def jcbb(self, z, Q, alpha):
        """Joint Compatibility Branch and Bound association of a step's measurements.

        Parameters
        ----------
        z : ndarray, shape (K, 2)
            The step's measurements ``[r, phi]``.
        Q : ndarray, shape (2, 2)
            Measurement-noise covariance, positive definite.
        alpha : float
            Individual compatibility threshold (squared Mahalanobis distance).

        Returns
        -------
        ndarray of int, shape (K,)
            Same as :func:`jcbb_associate` with ``n_seen = N``.

        References
        ----------
        Neira & Tardos (2001); Thrun, Burgard & Fox (2005), Table 10.2
        lines 16-17 (individual test).
        """
        return self._jcbb(as_array(z, "z", (None, 2)), as_covariance(Q, "Q", 2, definite=True),
                          as_threshold(alpha, "alpha"))

    def _jcbb(self, Z, Q, alpha):
        N = self.n_landmarks
        if N == 0:
            return np.full(Z.shape[0], JCBB_NEW)
        # only the distances within alpha count (individual compatibility): the others stay infinite
        d = np.full((Z.shape[0], N), np.inf)
        for i, j in zip(*np.nonzero(self._in_reach(Z, Q, alpha))):
            d[i, j] = self._nis1(Z[i], int(j), Q)
        return _jcbb(self._mu[:self._n], self._sub_sigma, Z, d, Q, alpha)[0]

    def associate(self, z, Q, alpha):
        """Data association of Algorithm 2, vectorised over landmarks.

        Parameters
        ----------
        z : ndarray, shape (2,)
            Measurement ``[r, phi]``.
        Q : ndarray, shape (2, 2)
            Measurement-noise covariance, positive definite.
        alpha : float
            New-landmark threshold on the squared Mahalanobis distance.

        Returns
        -------
        int
            Same rule as :func:`ekf_slam_associate` with ``n_seen = N``: the
            closest landmark if its distance is ``<= alpha`` (ties to the
            smallest index), else ``N`` (a new landmark).

        References
        ----------
        Course text, Algorithm 2; Thrun, Burgard & Fox (2005), Table 10.2
        lines 16-20.
        """
        return self._associate(as_array(z, "z", (2,)), as_covariance(Q, "Q", 2, definite=True),
                               as_threshold(alpha, "alpha"))

    def _associate(self, z, Q, alpha):
        N = self.n_landmarks
        best, d_best = N, alpha
        for j in np.flatnonzero(self._in_reach(z[None], Q, alpha)).tolist():
            # ascending: a tie goes to the smallest index  (Table 10.2 lines 16-20)
            d = self._nis1(z, j, Q)
            if d < d_best or (d == d_best and best == N):
                best, d_best = j, d
        return best

    def _in_reach(self, Z, Q, alpha):
        """Mask ``(K, N)`` of the landmarks whose squared Mahalanobis distance to each of ``Z (K, 2)`` may be ``<= alpha``.

        Every landmark the exact test would find within `alpha` is in the mask; most that are not, are not.
        """
        N, n, mu = self.n_landmarks, self._n, self._mu
        x, y, th = mu[:3].tolist()
        lm = mu[3:n].reshape(N, 2)
        dx, dy = lm[:, 0] - x, lm[:, 1] - y
        q = dx * dx + dy * dy
        r = np.sqrt(q)
        if N and r.min() < MIN_RANGE:
            raise ValueError("m coincides with the pose x (range 0): bearing and Jacobians are undefined")
        if math.isinf(alpha):
            return np.ones((Z.shape[0], N), dtype=bool)
        # For a positive definite S, d = nu^T S^-1 nu >= nu_i^2 / S_ii (Cauchy-Schwarz), and each S_ii has
        # an upper bound from variances alone: with T = tr Cov(p) + tr Cov(m_k) (p the robot's position),
        #   range:   S_00 = Var(u^T (m_k - p)) + Q_00 <= 2 T + Q_00                       (u a unit vector)
        #   bearing: S_11 = Var(v^T (m_k - p) / r - theta) + Q_11 <= 4 T / q + 2 Var(theta) + Q_11
        # (Var(a + b) <= 2 Var a + 2 Var b). The diagonal of the dense S bounds Sigma's from above (the
        # pending terms only subtract), and nu_1^2 >= 2 (1 - cos nu_1) = 2 (1 - (c dx + s dy) / r) with
        # (c, s) the measured bearing's direction: an O(KN) test with no angle wrapping and no pending terms.
        # A state given slightly indefinite (the checks accept an eigenvalue down to -1e-9 of the largest) is
        # bounded through Sigma + eps I, which is semi-definite: eps = self._neg added to each variance.
        diag = np.diagonal(self._S)
        eps = self._neg
        T = diag[3:n:2] + diag[4:n:2]
        T += diag.item(0) + diag.item(1) + 4.0 * eps
        a = alpha * (1.0 + 1e-9)  # rounding of the bound never drops a landmark the exact test keeps
        nu0 = r - Z[:, :1]
        near = nu0 * nu0 <= (2.0 * a) * T + a * Q.item(0, 0)
        z1 = Z[:, 1:] + th
        one_minus_cos = 1.0 - (np.cos(z1) * dx + np.sin(z1) * dy) / r
        near &= one_minus_cos <= (2.0 * a) * T / q + (a * (diag.item(2) + eps + 0.5 * Q.item(1, 1)) + 1e-12)
        return near

    def _nis1(self, z, j, Q):
        """``nu^T S^-1 nu`` of measurement `z` against landmark `j` alone, from the five rows of ``H``."""
        k, a = self._k, 3 + 2 * j
        idx = _ROWS.get(a)
        if idx is None:
            idx = _rows(a)
        r_hat, phi_hat, h = _rbh1(*self._mu.take(idx).tolist())  # h_t^j  (Eq. 17.3)
        B = self._S.take(idx, 0).take(idx, 1)  # the (robot, landmark j) block of Sigma
        if k:
            P = self._Pt[:k].take(idx, 1)
            B -= P.T.dot(P)  # minus the pending terms
        _, _, _, e0, e1 = _whiten(h.dot(B).dot(h.T), Q, z, r_hat, phi_hat)
        return e0 * e0 + e1 * e1


def _negative_part(Sigma):
    """``max(0, -lambda_min(Sigma))``: how far a covariance the checks accepted lies below semi-definite."""
    if not Sigma.size:
        return 0.0
    return max(0.0, -float(np.linalg.eigvalsh(Sigma)[0]))


#: Index rows ``[0, 1, 2, a, a+1]`` of the landmark at state offset ``a``, built once per offset by :func:`_rows`.
_ROWS = {}


def _rows(a):
    idx = np.array([0, 1, 2, a, a + 1])
    idx.flags.writeable = False
    _ROWS[a] = idx
    return idx


def _not_pd():
    raise ValueError("innovation covariance S = H Sigma H^T + Q is not positive definite")


def _whiten(HSH, Q, z, r_hat, phi_hat):
    """Factor ``S = H Sigma H^T + Q = L L^T`` (2 x 2, by hand) and whiten the innovation of `z`.

    Returns the entries ``i00, i10, i11`` of ``L^-1`` (lower triangular) and ``e = L^-1 nu``
    (``nu = z - z_hat``, bearing wrapped), so that ``nu^T S^-1 nu = e0^2 + e1^2``; Python floats.
    """
    (b00, b01), (b10, b11) = HSH.tolist()
    (q00, q01), (_, q11) = Q.tolist()
    # S = H Sigma_bar H^T + Q  (Table 10.1 line 17)
    s00, s01, s11 = b00 + q00, 0.5 * (b01 + b10) + q01, b11 + q11
    l00 = math.sqrt(s00) if s00 > 0 else _not_pd()
    l10 = s01 / l00
    rest = s11 - l10 * l10
    l11 = math.sqrt(rest) if rest > 0 else _not_pd()
    i00, i11, i10 = 1.0 / l00, 1.0 / l11, -l10 / (l00 * l11)  # L^-1
    nu0, nu1 = float(z[0]) - r_hat, _wrap1(float(z[1]) - phi_hat)  # nu = z - z_hat, bearing wrapped
    return i00, i10, i11, i00 * nu0, i10 * nu0 + i11 * nu1  # L^-1 nu


# --------------------------------------------------------------------------- provisional list
class _ProvisionalList:
    """Candidate landmarks that must be re-observed before they enter the map.

    A measurement that matches no landmark of the map starts or re-observes a
    candidate: a 2-D Gaussian in the world frame from the inverse measurement,
    ``m = h^-1(x, z)`` with covariance ``J_z Q J_z^T`` (``J_z = Hm^-1``, the
    implicit-function Jacobian of ``h(x, m) = z``). The robot's own
    uncertainty is left out: over the few steps of the window both sightings
    share it, so it does not separate them. A candidate re-observed (squared
    Mahalanobis distance ``<= alpha``) `confirm` times within `window` steps
    of its first sighting becomes a landmark; one that is not is forgotten.
    Measurements that only feed candidates never reach the filter (outlier
    rejection).

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 10.3.3 (provisional landmark list).
    """

    def __init__(self, confirm, window):
        self.confirm, self.window = confirm, window
        self.m = np.empty((0, 2))
        self.P = np.empty((0, 2, 2))
        self.count = np.empty(0, dtype=int)
        self.first = np.empty(0, dtype=int)

    def _keep(self, mask):
        self.m, self.P, self.count, self.first = self.m[mask], self.P[mask], self.count[mask], self.first[mask]

    def observe(self, x, z, Q, alpha, t):
        """Return True when `z` confirms a candidate (or confirmation is off)."""
        if self.confirm <= 1:
            return True
        self._keep(t - self.first < self.window)  # forget candidates older than the window
        m_new = landmark_from_measurement(x, z)
        _, _, Hm = landmark_measurement(x, m_new)
        Jz = np.linalg.inv(Hm)
        P_new = Jz @ Q @ Jz.T  # J_z Q J_z^T: the robot's own uncertainty is shared by both sightings
        if self.m.shape[0]:
            zc, _, Hmc = landmark_measurement(x, self.m)
            Sc = Hmc @ self.P @ Hmc.transpose(0, 2, 1) + Q
            nu = _innovation(z, zc)
            d = np.einsum("ki,ki->k", nu, np.linalg.solve(Sc, nu[..., None])[..., 0])
            best = int(np.argmin(d))
            if d[best] <= alpha:
                self.count[best] += 1
                self.m[best], self.P[best] = m_new, P_new
                if self.count[best] >= self.confirm:
                    self._keep(np.arange(self.m.shape[0]) != best)
                    return True
                return False
        self.m = np.vstack([self.m, m_new])
        self.P = np.concatenate([self.P, P_new[None]])
        self.count = np.append(self.count, 1)
        self.first = np.append(self.first, t)
        return False


# --------------------------------------------------------------------------- full runs
class EKFSLAMResult(NamedTuple):
    """What :func:`run_ekf_slam` returns.

    Attributes
    ----------
    x : ndarray, shape (T+1, 3)
        Robot pose estimates, ``x[0]`` the initial pose, ``x[t+1]`` after
        the step with control ``t`` and measurements ``z[t]``.
    Sigma_x : ndarray, shape (T+1, 3, 3)
        Robot covariances.
    landmarks : ndarray, shape (L, 2)
        Final landmark estimates in the order they entered the map.
    landmark_cov : ndarray, shape (L, 2, 2)
        Their marginal covariances.
    landmark_ids : ndarray of int, shape (L,)
        Ground-truth index (into ``run.landmarks``) of the measurement that
        created each landmark; ``-1`` for a landmark created by clutter. With
        unknown correspondences the filter never reads these, they are for
        evaluation only.
    landmark_var : ndarray, shape (T+1, L)
        ``Var(m_x) + Var(m_y)`` of each landmark over time; NaN before the
        landmark exists.
    n_landmarks : ndarray of int, shape (T+1,)
        Size of the map over time.
    mu : ndarray, shape (3+2L,)
        Final state mean.
    Sigma : ndarray, shape (3+2L, 3+2L)
        Final state covariance.
    snapshots : dict
        ``{t: (mu, Sigma, landmark_ids)}`` copies at the requested steps.
    n_rejected : int
        Measurements the provisional list kept out of the filter.
    n_gated : int
        Measurements the validation gate rejected (normalised innovation
        squared above `gate`), plus, with JCBB, measurements individually
        compatible with a landmark but left out of the best jointly
        compatible hypothesis.
    associations : tuple of T int ndarrays, shape (K_t,)
        The map slot each measurement of step ``t`` updated, ``-1`` when it
        updated nothing (gated, held in the provisional list, or clutter
        skipped with known correspondences). With ``landmark_ids`` this
        scores the association against the truth.
    """

    x: np.ndarray
    Sigma_x: np.ndarray
    landmarks: np.ndarray
    landmark_cov: np.ndarray
    landmark_ids: np.ndarray
    landmark_var: np.ndarray
    n_landmarks: np.ndarray
    mu: np.ndarray
    Sigma: np.ndarray
    snapshots: dict
    n_rejected: int
    n_gated: int = 0
    associations: tuple = ()


def run_ekf_slam(run, *, known=True, fast=True, alpha=DEFAULT_ALPHA, confirm=1, window=10, M=None, Q=None,
                 Sigma0=None, prior_var=DEFAULT_PRIOR_VAR, capacity=16, snapshots=(), association="nn", gate=None,
                 Q_association=None, jcbb_alpha=None, motion=None, ekf_slam_predict=None, ekf_slam_init_landmark=None,
                 ekf_slam_update=None, ekf_slam_associate=None, on_step=None):
    """Run EKF SLAM over a simulated landmark run.

    Parameters
    ----------
    run : LandmarkRun
        From :func:`~slamlib.sim.simulate_landmark_run` (optionally with
        :func:`~slamlib.sim.add_clutter`); uses ``x0``, ``u``, ``dt``, ``z``, ``ids`` and,
        by default, ``M`` and ``Q``.
    known : bool, keyword-only
        Known correspondences (Algorithm 1: ``run.ids`` say which landmark
        each measurement is; clutter, id ``-1``, is skipped) or unknown ones
        (Algorithm 2: association by Mahalanobis distance).
    fast : bool, keyword-only
        Use :class:`EKFSLAM` (default) or the teaching contract functions.
    alpha : float, keyword-only
        New-landmark threshold of Algorithm 2 (squared Mahalanobis distance).
    confirm : int, keyword-only
        Provisional list: sightings a new landmark needs within `window`
        steps before it enters the map; ``1`` (default) is plain Algorithm 2,
        every unmatched measurement starts a landmark.
    window : int, keyword-only
        Steps a candidate has to collect its `confirm` sightings.
    M, Q : ndarray, shape (2, 2), keyword-only
        Noise covariances the filter assumes (default: the run's); `Q`
        positive definite.
    Sigma0 : ndarray, shape (3, 3), keyword-only
        Initial robot covariance (default zero).
    prior_var : float, keyword-only
        Prior variance of a landmark before its first update.
    capacity : int, keyword-only
        Initial landmark capacity of the fast filter.
    snapshots : iterable of int, keyword-only
        Steps ``t`` in ``[0, T]`` at which to keep a copy of the full state.
    motion : callable, optional, keyword-only
        Motion model ``motion(x, u, dt) -> (x_next, G, V)`` (shapes ``(3,)``,
        ``(3, 3)``, ``(3, 2)``), e.g. :class:`slamlib.AckermannModel` for a
        car; default: the velocity model of Table 5.3 (``u = [v, omega]``).
        Needs ``fast=True``.
    association : {"nn", "jcbb"}, keyword-only
        Unknown correspondences only: ``"nn"`` is Algorithm 2, each
        measurement on its own against the current belief (nearest
        neighbour in Mahalanobis distance); ``"jcbb"`` pairs all measurements
        of a step jointly with :func:`jcbb_associate` against the predicted
        belief, then applies the pairings in order. A JCBB measurement
        compatible with no landmark goes through Algorithm 2's test against
        the current belief (so a landmark created earlier in the same step
        can take it), and then, if still new, through the provisional list.
    gate : float, optional, keyword-only
        Validation gate: a measurement whose normalised innovation squared
        ``nu^T S^-1 nu`` (``S = H Sigma_bar H^T + Q``) against the landmark
        it is assigned to exceeds `gate` is rejected as an outlier and
        counted in ``n_gated``. ``None`` (default) takes ``run.gate`` if the
        run has that attribute (the real-data loaders set it, e.g.
        :func:`~slamlib.datasets.mrclam.load_mrclam`) and no gate otherwise
        (the simulator's runs, whose noise is exactly Gaussian); ``numpy.inf``
        turns it off. With unknown correspondences a measurement beyond
        `alpha` from every landmark is a new-landmark candidate, so the gate
        only acts when it is below `alpha`: distances between `gate` and
        `alpha` are then neither a match nor a new landmark, and rejected.

    Q_association : ndarray, shape (2, 2), optional, keyword-only
        Unknown correspondences only: the measurement noise used in the
        association distances (``S = H Sigma_bar H^T + Q_association``, for
        Algorithm 2, JCBB and the provisional list); default `Q`. A `Q`
        inflated for errors that are correlated in time (so that repeated
        sightings are not over-counted in the update) widens the
        association gates far beyond the spread of one sighting; pass the
        spread of one sighting here to keep them tight.

    jcbb_alpha : float, optional, keyword-only
        Individual compatibility threshold of JCBB (squared Mahalanobis
        distance, 2 degrees of freedom; the joint test uses the same tail
        probability with ``2k`` degrees of freedom). Default
        :data:`JCBB_ALPHA`, the 99 % quantile. JCBB prefers the hypothesis
        with the most pairings, so a loose threshold (such as `alpha`, which
        only guards against splitting a landmark in two) lets it pair a
        sighting with a neighbour several standard deviations away rather
        than leave it unpaired; a measurement compatible with nothing at
        this level goes through Algorithm 2's test with `alpha`.
    ekf_slam_predict : callable, optional, keyword-only
        ``ekf_slam_predict(mu, Sigma, u, dt, M) -> (mu_bar, Sigma_bar)`` in
        place of the filter's prediction (Algorithm 1 lines 2-5): the
        contract function :func:`ekf_slam_predict` itself, or a student's
        version of it, as the autograder plugs it in. Needs ``fast=False``
        (like the three below: they work on the dense state of the teaching
        version). ``None`` (default): the library's.
    ekf_slam_init_landmark : callable, optional, keyword-only
        ``ekf_slam_init_landmark(mu, z, j) -> mu`` in place of the
        initialisation of a landmark seen for the first time, as
        :func:`ekf_slam_init_landmark`; it gets the state already grown by the
        new landmark ``j`` (mean zero, variance `prior_var`).
    ekf_slam_update : callable, optional, keyword-only
        ``ekf_slam_update(mu_bar, Sigma_bar, z, j, Q) -> (mu, Sigma)`` in place
        of the update with one measurement of landmark ``j``, as
        :func:`ekf_slam_update` (after the validation `gate`, which stays the
        library's).
    ekf_slam_associate : callable, optional, keyword-only
        Unknown correspondences only: ``ekf_slam_associate(mu_bar, Sigma_bar,
        z, n_seen, Q, alpha) -> j`` in place of Algorithm 2's association, as
        :func:`ekf_slam_associate` (``j = n_seen``: a new landmark).
    on_step : callable, optional, keyword-only
        ``on_step(t)`` is called at the start of step ``t`` (before its
        prediction), e.g. for progress reports, or so that the functions
        above know which step they serve.

    Returns
    -------
    EKFSLAMResult
        Estimates, covariances and map size over time.

    Notes
    -----
    The functions given for `ekf_slam_predict`, `ekf_slam_init_landmark`,
    `ekf_slam_update` and `ekf_slam_associate` are called with the homework
    contract's arguments, where the teaching version calls the library's own,
    on copies of the filter's arrays; their results are checked (shapes,
    finite values, an integer index in ``[0, n_seen]``) and a bad one raises
    ``ValueError`` (``TypeError`` for an index that is not an integer) naming
    the function. Exceptions they raise pass through unchanged.

    Each step predicts with ``u[t]`` and then processes the measurements
    ``z[t]`` one by one in their stored order (sequential updates, each
    re-linearised at the current mean). Gating a measurement is a hard
    decision: a filter whose covariance is over-confident rejects good
    measurements and may never recover, so the gate should be loose (a
    tail probability of ``1e-4`` or less) and the noise consistent.

    References
    ----------
    Course text, Algorithms 1 and 2; Thrun, Burgard & Fox (2005), Tables 10.1,
    10.2 and Sec. 10.3.3 (provisional landmark list); Bar-Shalom, Li &
    Kirubarajan (2001) (validation gate); Neira & Tardos (2001)
    (JCBB).
    """
    for attr in ("x0", "u", "dt", "z", "ids", "M", "Q"):
        if not hasattr(run, attr):
            raise TypeError(f"run must be a LandmarkRun (simulate_landmark_run), it has no attribute {attr!r}")
    x0 = as_array(run.x0, "run.x0", (3,))
    u = as_array(run.u, "run.u", (None, 2))
    dt = as_scalar(run.dt, "run.dt", positive=True)
    T = u.shape[0]
    if len(run.z) != T or len(run.ids) != T:
        raise ValueError(f"run.z and run.ids must hold one entry per control ({T}), "
                         f"got {len(run.z)} and {len(run.ids)}")
    M = as_covariance(run.M if M is None else M, "M", 2)
    Q = as_covariance(run.Q if Q is None else Q, "Q", 2, definite=True)
    Sigma0 = np.zeros((3, 3)) if Sigma0 is None else as_covariance(Sigma0, "Sigma0", 3)
    alpha = as_threshold(alpha, "alpha")
    confirm = as_index(confirm, "confirm", lower=1)
    window = as_index(window, "window", lower=1)
    prior_var = as_scalar(prior_var, "prior_var", positive=True)
    capacity = as_index(capacity, "capacity", lower=1)
    keep = {as_index(t, "snapshots", T + 1) for t in snapshots}
    if motion is not None and (not callable(motion) or not fast):
        raise ValueError("motion must be a callable motion(x, u, dt) -> (x_next, G, V), with fast=True")
    check_callable(ekf_slam_predict, "ekf_slam_predict", "(mu, Sigma, u, dt, M)")
    check_callable(ekf_slam_init_landmark, "ekf_slam_init_landmark", "(mu, z, j)")
    check_callable(ekf_slam_update, "ekf_slam_update", "(mu_bar, Sigma_bar, z, j, Q)")
    check_callable(ekf_slam_associate, "ekf_slam_associate", "(mu_bar, Sigma_bar, z, n_seen, Q, alpha)")
    check_callable(on_step, "on_step", "(t)")
    given = [name for name, fn in (("ekf_slam_predict", ekf_slam_predict), ("ekf_slam_init_landmark",
                                                                          ekf_slam_init_landmark),
                                   ("ekf_slam_update", ekf_slam_update), ("ekf_slam_associate", ekf_slam_associate))
             if fn is not None]
    if given and fast:
        raise ValueError(f"{given[0]} needs fast=False (the functions of the homework contract work on the teaching "
                         "version's dense state)")
    if known and ekf_slam_associate is not None:
        raise ValueError("ekf_slam_associate needs known=False (with known correspondences nothing is associated)")
    if association not in ("nn", "jcbb"):
        raise ValueError(f"association must be 'nn' or 'jcbb', got {association!r}")
    gate = as_threshold(getattr(run, "gate", None) if gate is None else gate, "gate", optional=True, none=math.inf)
    Qa = Q if Q_association is None else as_covariance(Q_association, "Q_association", 2, definite=True)
    alpha_j = JCBB_ALPHA if jcbb_alpha is None else as_threshold(jcbb_alpha, "jcbb_alpha")
    zs = [as_array(z, f"run.z[{t}]", (None, 2)) for t, z in enumerate(run.z)]
    ids = [np.asarray(i, dtype=int) for i in run.ids]
    for t, (z, i) in enumerate(zip(zs, ids)):
        if i.shape != (z.shape[0],):
            raise ValueError(f"run.ids[{t}] must have shape ({z.shape[0]},), got {i.shape}")

    if fast:
        filt = EKFSLAM(x0, Sigma0, capacity=capacity, prior_var=prior_var)
        filt._motion = motion
        predict, update, add, associate, jcbb = filt._predict, filt._update, filt._add_landmark, filt._associate, filt._jcbb
    else:
        filt = _PlainEKFSLAM(x0, Sigma0, prior_var, _plain_steps(ekf_slam_predict, ekf_slam_init_landmark,
                                                                 ekf_slam_update, ekf_slam_associate))
        predict, update, add, associate, jcbb = filt.predict, filt.update, filt.add_landmark, filt.associate, filt.jcbb
    provisional = _ProvisionalList(confirm, window)
    slot_of, landmark_ids = {}, []
    xs = np.empty((T + 1, 3))
    Sxs = np.empty((T + 1, 3, 3))
    n_lm = np.empty(T + 1, dtype=int)
    variances = []
    kept = {}
    n_rejected = n_gated = 0
    used = []

    def record(t, changed=True):
        xs[t] = filt.x
        Sxs[t] = filt.Sigma_x
        n_lm[t] = filt.n_landmarks
        # the prediction leaves the landmark blocks alone (Table 10.1 line 5): without an update or a new
        # landmark the variances are the last step's (the teaching version's steps may be a student's: always read)
        variances.append(filt.landmark_variances() if changed or not fast else variances[-1])
        if t in keep:
            kept[t] = (np.array(filt.mu), np.array(filt.Sigma), np.array(landmark_ids, dtype=int))

    record(0)
    for t in range(T):
        if on_step is not None:
            on_step(t)
        predict(u[t], dt, M)  # (Table 10.1 lines 2-5)
        slots = np.full(len(ids[t]), -1)
        if not known and association == "jcbb" and len(ids[t]) > 1:
            pairing = jcbb(zs[t], Qa, alpha_j)  # all measurements of the step, jointly  (Neira & Tardos 2001)
        else:
            pairing = None
        for m, (z, i) in enumerate(zip(zs[t], ids[t])):  # for all observed features  (Table 10.1 line 7)
            if known:
                if i < 0:
                    continue  # known to be clutter
                j = slot_of.get(int(i))
                if j is None:  # never seen before: initialise  (Table 10.1 lines 9-11)
                    j = slot_of[int(i)] = add(z)
                    landmark_ids.append(int(i))
            else:
                j = JCBB_NEW if pairing is None else int(pairing[m])
                if j == JCBB_UNPAIRED:  # compatible alone, not with the rest of the step
                    n_gated += 1
                    continue
                if j == JCBB_NEW:
                    j = associate(z, Qa, alpha)  # (Algorithm 2; Table 10.2 lines 16-20)
                if j == filt.n_landmarks:  # new landmark hypothesis wins
                    if not provisional.observe(filt.x, z, Qa, alpha, t):
                        n_rejected += 1
                        continue
                    j = add(z)
                    landmark_ids.append(int(i))
            if update(z, j, Q, gate):  # (Table 10.1 lines 12-19)
                slots[m] = j
            else:
                n_gated += 1  # validation gate: an outlier
        used.append(slots)
        record(t + 1, filt.n_landmarks != n_lm[t] or bool((slots >= 0).any()))

    L = filt.n_landmarks
    var = np.full((T + 1, L), np.nan)
    for t, v in enumerate(variances):
        var[t, :v.shape[0]] = v
    mu = np.array(filt.mu)
    Sigma = np.array(filt.Sigma)
    r = np.arange(3, 3 + 2 * L, 2)
    lcov = np.empty((L, 2, 2))
    lcov[:, 0, 0] = Sigma[r, r]
    lcov[:, 0, 1] = lcov[:, 1, 0] = Sigma[r, r + 1]
    lcov[:, 1, 1] = Sigma[r + 1, r + 1]
    return EKFSLAMResult(x=xs, Sigma_x=Sxs, landmarks=mu[3:].reshape(L, 2), landmark_cov=lcov,
                         landmark_ids=np.array(landmark_ids, dtype=int), landmark_var=var, n_landmarks=n_lm,
                         mu=mu, Sigma=Sigma, snapshots=kept, n_rejected=n_rejected, n_gated=n_gated,
                         associations=tuple(used))

