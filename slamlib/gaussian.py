"""Gaussian filters: the Kalman filter and EKF localization with landmarks.

* :func:`kf_predict`, :func:`kf_update` -- the linear Kalman filter (Table 3.1),
  written in the common ``x, P, F, Q, H, R`` notation of linear filtering.
* :func:`ekf_predict`, :func:`ekf_update` -- one prediction with the velocity
  motion model and one update with a range-bearing measurement of a known
  landmark (Table 7.2).
* :func:`landmark_mahalanobis`, :func:`associate_ml` -- data association by
  the nearest neighbour in squared Mahalanobis distance with a gate.
* :func:`ekf_localization_known`, :func:`ekf_localization_unknown` -- a full
  filter step (prediction plus every measurement of the step, applied one after
  the other) with known and with unknown correspondences (Tables 7.2, 7.3);
  :func:`ekf_localization_run` runs either over a simulated
  :class:`~slamlib.sim.LandmarkRun`, :func:`ekf_localization_batch` many runs
  at once (for Monte-Carlo studies).

Notation of the Kalman filter (Table 3.1 writes the same filter as
``A_t, B_t, R_t, C_t, Q_t``):

=================  =======================  ==================
quantity           here (``kf_*``)          Table 3.1
=================  =======================  ==================
state transition   ``F``                    ``A_t``
control matrix     ``B``                    ``B_t``
process noise      ``Q``                    ``R_t``
measurement model  ``H``                    ``C_t``
measurement noise  ``R``                    ``Q_t``
=================  =======================  ==================

The EKF functions use the book's notation: ``M`` is the control-noise
covariance ``(2, 2)`` of ``[v, omega]`` and ``Q`` the measurement-noise
covariance ``(2, 2)`` of ``[r, phi]``.

Every function returns new arrays (no argument is modified), wraps every
returned heading and every bearing innovation to ``[-pi, pi)`` and returns
covariances symmetrised as ``(Sigma + Sigma^T) / 2``. The predict and update
functions broadcast over leading axes, so a batch of independent filters goes
through the same call.

References
----------
Thrun, Burgard & Fox, *Probabilistic Robotics* (2005), Table 3.1 (Kalman
filter), Table 3.3 (EKF), Sec. 7.4 with Table 7.2 (EKF localization with known
correspondences) and Table 7.3 (unknown correspondences).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ._checks import (as_array, as_covariance, as_index, as_indices, as_matrix, as_returned, as_rows, as_scalar,
                      as_threshold, as_vector, check_batch, check_callable, small_ok)
from .angles import _wrap1, wrap_angle
from .motion import _arc, _arc1_floats
from .sensors import _landmark_measurement, _rb1

__all__ = [
    "Gaussian",
    "kf_predict",
    "kf_update",
    "ekf_predict",
    "ekf_update",
    "landmark_mahalanobis",
    "associate_ml",
    "ekf_localization_known",
    "ekf_localization_unknown",
    "EKFRunResult",
    "ekf_localization_run",
    "ekf_localization_batch",
]

#: Default association gate on the squared Mahalanobis distance: the 99 %
#: quantile of the chi-square distribution with 2 degrees of freedom,
#: ``-2 ln(0.01)``.
DEFAULT_GATE = float(-2.0 * np.log(0.01))


class _GaussianFields(NamedTuple):
    mean: np.ndarray
    cov: np.ndarray


class Gaussian(_GaussianFields):
    """A Gaussian belief ``N(mean, cov)``; unpacks as ``mean, cov = g``.

    ``Gaussian(mean, cov)`` checks its fields cheaply (finite float arrays,
    ``mean (..., n)``, ``cov (..., n, n)``; a string or ``None`` is refused)
    and stores them as float64 arrays; the library's cores bundle their
    already-checked results without the check.

    Attributes
    ----------
    mean : ndarray, shape (..., n)
        Mean vector(s).
    cov : ndarray, shape (..., n, n)
        Covariance matrix (matrices), symmetric positive semi-definite.
    """

    __slots__ = ()

    def __new__(cls, mean, cov):
        mean = as_vector(mean, "mean", copy=False)
        cov = as_matrix(cov, "cov", mean.shape[-1], mean.shape[-1], copy=False, ref="mean")
        return tuple.__new__(cls, (mean, cov))


def _gaussian(mean, cov):
    """The unchecked constructor of the cores."""
    return tuple.__new__(Gaussian, (mean, cov))


# --------------------------------------------------------------------------- algebra helpers
def _T(A):
    return A.swapaxes(-1, -2)


def _sym(S):
    S = S + S.swapaxes(-1, -2)
    S *= 0.5  # (S + S^T) / 2, exactly symmetric
    return S


def _mv(A, x):
    """Matrix-vector product over leading axes."""
    if A.ndim == 2 and x.ndim == 1:
        return np.dot(A, x)
    return (A @ x[..., None])[..., 0]


def _mm(A, B):
    """Matrix product over leading axes (``numpy.dot`` for two plain matrices: less overhead than ``@``)."""
    if A.ndim == 2 and B.ndim == 2:
        return np.dot(A, B)
    return A @ B


def _gain(PHt, S):
    """``K = PHt S^-1`` for a symmetric positive definite ``S`` (explicit inverse when ``S`` is 1x1 or 2x2)."""
    if S.ndim == 2 and 1 <= S.shape[0] <= 2:
        if S.shape[0] == 1:
            return PHt / S[0, 0]
        (a, b), (_, d) = S.tolist()
        det = a * d - b * b
        # S^-1 = [[d, -b], [-b, a]] / (a d - b^2) for the symmetric S = [[a, b], [b, d]]
        return _mm(PHt, np.array([[d / det, -b / det], [-b / det, a / det]]))
    return _T(np.linalg.solve(S, _T(PHt)))


# --------------------------------------------------------------------------- linear Kalman filter
def kf_predict(x, P, F, Q, *, B=None, u=None):
    """Kalman filter prediction.

    Parameters
    ----------
    x : ndarray, shape (n,) or (..., n)
        Mean of the belief at time ``t-1``.
    P : ndarray, shape (n, n) or (..., n, n)
        Its covariance, symmetric positive semi-definite.
    F : ndarray, shape (n, n) or (..., n, n)
        State-transition matrix (``A_t`` of Table 3.1).
    Q : ndarray, shape (n, n) or (..., n, n)
        Process-noise covariance (``R_t`` of Table 3.1).
    B : ndarray, shape (n, k) or (..., n, k), keyword-only, optional
        Control matrix; given together with `u`.
    u : ndarray, shape (k,) or (..., k), keyword-only, optional
        Control vector.

    Returns
    -------
    Gaussian
        ``(x_bar (..., n), P_bar (..., n, n))`` with ``x_bar = F x + B u`` and
        ``P_bar = F P F^T + Q``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 3.1 lines 2-3.
    """
    if B is None and u is None and small_ok((x,), (F,), (P, Q)) and P.shape == F.shape == Q.shape == (x.size,) * 2:
        return _kf_predict(x, P, F, Q)  # one small filter, every check passed at once
    x = as_vector(x, "x", copy=False)
    n = x.shape[-1]
    P = as_covariance(P, "P", n, batched=True, copy=False, ref="x")
    F = as_matrix(F, "F", n, n, copy=False, ref="x")
    Q = as_covariance(Q, "Q", n, batched=True, copy=False, ref="x")
    if B is None and u is None and x.ndim == 1 and P.ndim == 2 and F.ndim == 2 and Q.ndim == 2:
        return _kf_predict(x, P, F, Q)  # one filter: nothing to broadcast
    if (B is None) != (u is None):
        raise ValueError("B and u must be given together (or both omitted)")
    named = [(x, 1, "x"), (P, 2, "P"), (F, 2, "F"), (Q, 2, "Q")]
    if B is not None:
        B = as_matrix(B, "B", n, copy=False, ref="x")
        u = as_vector(u, "u", B.shape[-1], copy=False, ref="B")
        named += [(B, 2, "B"), (u, 1, "u")]
    check_batch(*named)
    return _kf_predict(x, P, F, Q, B, u)


def _kf_predict(x, P, F, Q, B=None, u=None):
    if B is None and x.ndim == 1 and P.ndim == 2 and F.ndim == 2 and Q.ndim == 2:  # one filter
        # x_bar = F x, P_bar = F P F^T + Q  (Table 3.1 lines 2-3), symmetrised
        P_bar = np.dot(np.dot(F, P), F.T)
        P_bar += Q
        return _gaussian(np.dot(F, x), _sym(P_bar))
    # x_bar = F x + B u  (Table 3.1 line 2, F = A_t)
    x_bar = _mv(F, x)
    if B is not None:
        x_bar = x_bar + _mv(B, u)
    # P_bar = F P F^T + Q  (Table 3.1 line 3, Q = R_t)
    P_bar = F @ P @ _T(F) + Q
    return _gaussian(x_bar, _sym(P_bar))


def kf_update(x, P, z, H, R):
    """Kalman filter measurement update.

    Parameters
    ----------
    x : ndarray, shape (n,) or (..., n)
        Predicted mean.
    P : ndarray, shape (n, n) or (..., n, n)
        Predicted covariance.
    z : ndarray, shape (k,) or (..., k)
        Measurement.
    H : ndarray, shape (k, n) or (..., k, n)
        Measurement matrix (``C_t`` of Table 3.1).
    R : ndarray, shape (k, k) or (..., k, k)
        Measurement-noise covariance (``Q_t`` of Table 3.1), positive definite.

    Returns
    -------
    Gaussian
        ``(x (..., n), P (..., n, n))``: ``K = P H^T (H P H^T + R)^-1``,
        ``x + K (z - H x)``, ``(I - K H) P``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 3.1 lines 4-6.
    """
    if small_ok((x, z), (H,), (P, R)) and P.shape == (x.size,) * 2 and H.shape == (z.size, x.size) \
            and R.shape == (z.size,) * 2:
        return _kf_update(x, P, z, H, R)  # one small filter, every check passed at once
    x = as_vector(x, "x", copy=False)
    n = x.shape[-1]
    P = as_covariance(P, "P", n, batched=True, copy=False, ref="x")
    z = as_vector(z, "z", copy=False)
    k = z.shape[-1]
    H = as_matrix(H, "H", k, n, copy=False, ref="z and x")
    R = as_covariance(R, "R", k, definite=True, batched=True, copy=False, ref="z")
    check_batch((x, 1, "x"), (P, 2, "P"), (z, 1, "z"), (H, 2, "H"), (R, 2, "R"))
    return _kf_update(x, P, z, H, R)


def _kf_update(x, P, z, H, R):
    # S = H P H^T + R, K = P H^T S^-1  (Table 3.1 line 4, H = C_t, R = Q_t)
    PHt = _mm(P, _T(H))
    S = _sym(_mm(H, PHt) + R)
    K = _gain(PHt, S)
    # x = x_bar + K (z - H x_bar)  (Table 3.1 line 5)
    x_new = x + _mv(K, z - _mv(H, x))
    # P = (I - K H) P_bar  (Table 3.1 line 6)
    P_new = P - _mm(_mm(K, H), P)
    return _gaussian(x_new, _sym(P_new))


# --------------------------------------------------------------------------- EKF localization
def _ekf_predict(mu, Sigma, u, dt, M):
    if mu.ndim == 1 and u.ndim == 1 and Sigma.ndim == 2 and M.ndim == 2:  # one pose: the scalar path
        return _ekf_predict1(mu, Sigma, u, dt, M)
    mu_bar, G, V = _arc(mu, u, dt)  # g(u, mu), G, V  (Table 7.2 lines 2-4, 6)
    # Sigma_bar = G Sigma G^T + V M V^T  (Table 7.2 line 7)
    Sigma_bar = G @ Sigma @ _T(G) + V @ M @ _T(V)
    return _gaussian(mu_bar, _sym(Sigma_bar))


def _ekf_predict1(mu, Sigma, u, dt, M):
    """:func:`_ekf_predict` of one pose in Python floats (the tests check it equals the array path).

    ``G = I + [a, b, 0]^T e_3^T`` has two non-trivial entries, so ``G Sigma G^T``
    and ``V M V^T`` take a few dozen multiplications, fewer than the matrix
    products cost to set up.
    """
    # g(u, mu), G[0, 2] = a, G[1, 2] = b, V = [[p, q], [r, s], [0, dt]]  (Table 7.2 lines 2-4, 6)
    xn, yn, thn, a, b, p, q, r, s = _arc1_floats(mu, u, dt)
    (s00, s01, s02), (s10, s11, s12), (s20, s21, s22) = Sigma.tolist()
    (m00, m01), (m10, m11) = M.tolist()
    # G Sigma: rows 0 and 1 gain a (resp. b) times row 2
    t00, t01, t02 = s00 + a * s20, s01 + a * s21, s02 + a * s22
    t10, t11, t12 = s10 + b * s20, s11 + b * s21, s12 + b * s22
    # V M
    w00, w01 = p * m00 + q * m10, p * m01 + q * m11
    w10, w11 = r * m00 + s * m10, r * m01 + s * m11
    w20, w21 = dt * m10, dt * m11
    # Sigma_bar = G Sigma G^T + V M V^T  (Table 7.2 line 7), symmetrised as (A + A^T) / 2
    c00 = (t00 + a * t02) + (w00 * p + w01 * q)
    c11 = (t11 + b * t12) + (w10 * r + w11 * s)
    c22 = s22 + w21 * dt
    c01 = 0.5 * (((t01 + b * t02) + (w00 * r + w01 * s)) + ((t10 + a * t12) + (w10 * p + w11 * q)))
    c02 = 0.5 * ((t02 + w01 * dt) + ((s20 + a * s22) + (w20 * p + w21 * q)))
    c12 = 0.5 * ((t12 + w11 * dt) + ((s21 + b * s22) + (w20 * r + w21 * s)))
    cov = np.array([[c00, c01, c02], [c01, c11, c12], [c02, c12, c22]])
    return _gaussian(np.array([xn, yn, thn]), cov)


def ekf_predict(mu, Sigma, u, dt, M):
    """EKF prediction with the velocity motion model.

    Parameters
    ----------
    mu : ndarray, shape (3,) or (..., 3)
        Mean pose ``[x, y, theta]`` at time ``t-1``.
    Sigma : ndarray, shape (3, 3) or (..., 3, 3)
        Its covariance, symmetric positive semi-definite.
    u : ndarray, shape (2,) or (..., 2)
        Control ``[v, omega]``.
    dt : float
        Duration of the control, non-negative seconds.
    M : ndarray, shape (2, 2) or (..., 2, 2)
        Control-noise covariance of ``[v, omega]`` (e.g.
        :func:`~slamlib.motion.velocity_noise_cov`).

    Returns
    -------
    Gaussian
        ``(mu_bar (..., 3), Sigma_bar (..., 3, 3))``: ``mu_bar = g(u, mu)``
        (exact arc, heading wrapped) and ``Sigma_bar = G Sigma G^T + V M V^T``
        with the Jacobians ``G = dg/dx`` and ``V = dg/du`` at ``(mu, u)``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 7.2 lines 2-7.
    """
    mu = as_vector(mu, "mu", 3, copy=False)
    Sigma = as_covariance(Sigma, "Sigma", 3, batched=True, copy=False)
    u = as_vector(u, "u", 2, copy=False)
    dt = as_scalar(dt, "dt", nonnegative=True)
    M = as_covariance(M, "M", 2, batched=True, copy=False)
    check_batch((mu, 1, "mu"), (Sigma, 2, "Sigma"), (u, 1, "u"), (M, 2, "M"))
    return _ekf_predict(mu, Sigma, u, dt, M)


def _innovation(mu_bar, Sigma_bar, z, m, Q):
    """Innovation ``nu`` (bearing wrapped), its covariance ``S`` and ``H``."""
    if mu_bar.ndim == 1 and m.ndim == 1 and z.ndim == 1:  # one pose, one landmark: the scalar path
        r, phi, dx, dy, q = _rb1(mu_bar[0], mu_bar[1], mu_bar[2], m[0], m[1])  # (Table 7.2 lines 11-12)
        # H = d h / d x  (Table 7.2 line 13)
        H = np.array([[-dx / r, -dy / r, 0.0], [dy / q, -dx / q, -1.0]])
        nu = np.array([z[0] - r, _wrap1(z[1] - phi)])  # bearing innovation wrapped to [-pi, pi)
    else:
        z_hat, H, _ = _landmark_measurement(mu_bar, m)  # (Table 7.2 lines 11-13)
        nu = z - z_hat
        nu[..., 1] = wrap_angle(nu[..., 1])  # bearing innovation wrapped to [-pi, pi)
    # S = H Sigma_bar H^T + Q  (Table 7.2 line 14)
    S = _sym(_mm(_mm(H, Sigma_bar), _T(H)) + Q)
    return nu, S, H


def _ekf_update(mu_bar, Sigma_bar, z, m, Q):
    nu, S, H = _innovation(mu_bar, Sigma_bar, z, m, Q)
    SigHt = _mm(Sigma_bar, _T(H))
    # K = Sigma_bar H^T S^-1  (Table 7.2 line 15)
    K = _gain(SigHt, S)
    # mu = mu_bar + K (z - z_hat)  (Table 7.2 line 16)
    mu = mu_bar + _mv(K, nu)
    if mu.ndim == 1:
        mu[2] = _wrap1(mu[2])
    else:
        mu[..., 2] = wrap_angle(mu[..., 2])
    # Sigma = (I - K H) Sigma_bar  (Table 7.2 line 17)
    Sigma = Sigma_bar - _mm(_mm(K, H), Sigma_bar)
    return _gaussian(mu, _sym(Sigma))


def ekf_update(mu_bar, Sigma_bar, z, m, Q):
    """EKF update with one range-bearing measurement of a known landmark.

    Parameters
    ----------
    mu_bar : ndarray, shape (3,) or (..., 3)
        Predicted mean pose.
    Sigma_bar : ndarray, shape (3, 3) or (..., 3, 3)
        Predicted covariance.
    z : ndarray, shape (2,) or (..., 2)
        Measurement ``[r, phi]``.
    m : ndarray, shape (2,) or (..., 2)
        Position of the measured landmark.
    Q : ndarray, shape (2, 2) or (..., 2, 2)
        Measurement-noise covariance of ``[r, phi]``, positive definite.

    Returns
    -------
    Gaussian
        ``(mu (..., 3), Sigma (..., 3, 3))`` with ``S = H Sigma_bar H^T + Q``,
        ``K = Sigma_bar H^T S^-1``, ``mu = mu_bar + K nu`` (``nu = z - z_hat``
        with its bearing wrapped; heading of `mu` wrapped) and
        ``Sigma = (I - K H) Sigma_bar``.

    Raises
    ------
    ValueError
        If `m` coincides with the position of `mu_bar` (the bearing is
        undefined there).

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 7.2 lines 10-17.
    """
    mu_bar = as_vector(mu_bar, "mu_bar", 3, copy=False)
    Sigma_bar = as_covariance(Sigma_bar, "Sigma_bar", 3, batched=True, copy=False)
    z = as_vector(z, "z", 2, copy=False)
    m = as_vector(m, "m", 2, copy=False)
    Q = as_covariance(Q, "Q", 2, definite=True, batched=True, copy=False)
    check_batch((mu_bar, 1, "mu_bar"), (Sigma_bar, 2, "Sigma_bar"), (z, 1, "z"), (m, 1, "m"), (Q, 2, "Q"))
    return _ekf_update(mu_bar, Sigma_bar, z, m, Q)


def _mahalanobis(mu_bar, Sigma_bar, z, landmarks, Q):
    """Squared Mahalanobis distances ``(K,)`` of ``z`` to every landmark."""
    if landmarks.shape[0] == 0:
        return np.zeros(0)
    nu, S, _ = _innovation(mu_bar, Sigma_bar, z, landmarks, Q)
    # d = nu^T S^-1 nu  (squared Mahalanobis distance: the exponent of Table 7.3 line 16)
    return np.einsum("...i,...i->...", nu, np.linalg.solve(S, nu[..., None])[..., 0])


def landmark_mahalanobis(mu_bar, Sigma_bar, z, landmarks, Q):
    """Squared Mahalanobis distance of one measurement to every landmark.

    Parameters
    ----------
    mu_bar : ndarray, shape (3,)
        Predicted mean pose.
    Sigma_bar : ndarray, shape (3, 3)
        Predicted covariance.
    z : ndarray, shape (2,)
        Measurement ``[r, phi]``.
    landmarks : ndarray, shape (K, 2)
        Candidate landmark positions (``K`` may be 0).
    Q : ndarray, shape (2, 2)
        Measurement-noise covariance, positive definite.

    Returns
    -------
    ndarray, shape (K,)
        ``d_k = nu_k^T S_k^-1 nu_k`` with ``nu_k = z - h(mu_bar, m_k)`` (bearing
        wrapped) and ``S_k = H_k Sigma_bar H_k^T + Q``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 7.3 lines 10-15 (the quantities
    that enter the association), Eq. 3.1 (Gaussian exponent).
    """
    mu_bar = as_array(mu_bar, "mu_bar", (3,))
    Sigma_bar = as_covariance(Sigma_bar, "Sigma_bar", 3, batched=True, copy=False)
    z = as_array(z, "z", (2,))
    landmarks = as_array(landmarks, "landmarks", (None, 2))
    Q = as_covariance(Q, "Q", 2, definite=True, batched=True, copy=False)
    if Sigma_bar.ndim != 2 or Q.ndim != 2:
        raise ValueError("Sigma_bar must have shape (3, 3) and Q shape (2, 2)")
    return _mahalanobis(mu_bar, Sigma_bar, z, landmarks, Q)


def _associate(d, gate):
    if d.size == 0:
        return -1
    j = int(np.argmin(d))  # first minimum: ties go to the smallest index
    return j if d[j] <= gate else -1


def associate_ml(mu_bar, Sigma_bar, z, landmarks, Q, gate):
    """Nearest-neighbour data association with a Mahalanobis gate.

    Parameters
    ----------
    mu_bar : ndarray, shape (3,)
        Predicted mean pose.
    Sigma_bar : ndarray, shape (3, 3)
        Predicted covariance.
    z : ndarray, shape (2,)
        Measurement ``[r, phi]``.
    landmarks : ndarray, shape (K, 2)
        Candidate landmark positions; ``K = 0`` is allowed.
    Q : ndarray, shape (2, 2)
        Measurement-noise covariance, positive definite.
    gate : float
        Non-negative threshold on the squared Mahalanobis distance (e.g.
        ``slamlib.gaussian.DEFAULT_GATE``, the 99 % chi-square quantile with 2 degrees of
        freedom); ``numpy.inf`` accepts every measurement.

    Returns
    -------
    int
        Index ``j`` of the landmark with the smallest ``d_j = nu^T S^-1 nu``
        (see :func:`landmark_mahalanobis`; ties go to the smallest index), or
        ``-1`` if ``d_j > gate`` or ``K = 0``. ``d_j == gate`` is a match.

    Notes
    -----
    Table 7.3 picks the landmark of largest likelihood, which also weighs
    ``det(2 pi S)``; the nearest neighbour in Mahalanobis distance drops that
    factor, so a far, uncertain landmark does not win merely because its
    ``S`` is large.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 7.3 lines 10-16 (with the Mahalanobis
    distance in place of the likelihood).
    """
    d = landmark_mahalanobis(mu_bar, Sigma_bar, z, landmarks, Q)
    gate = as_threshold(gate, "gate")
    return _associate(d, gate)


def _step_inputs(mu, Sigma, u, z, landmarks, dt, M, Q):
    mu = as_array(mu, "mu", (3,))
    Sigma = as_covariance(Sigma, "Sigma", 3, batched=True, copy=False)
    u = as_array(u, "u", (2,))
    z = as_rows(z, "z", 2)
    landmarks = as_array(landmarks, "landmarks", (None, 2))
    dt = as_scalar(dt, "dt", nonnegative=True)
    M = as_covariance(M, "M", 2, batched=True, copy=False)
    Q = as_covariance(Q, "Q", 2, definite=True, batched=True, copy=False)
    if Sigma.ndim != 2 or M.ndim != 2 or Q.ndim != 2:
        raise ValueError("Sigma must have shape (3, 3), M and Q shape (2, 2)")
    return mu, Sigma, u, z, landmarks, dt, M, Q


def _known_step(mu, Sigma, u, z, ids, landmarks, dt, M, Q, predict=_ekf_predict, update=_ekf_update):
    mu, Sigma = predict(mu, Sigma, u, dt, M)
    for zi, j in zip(z, ids):  # for all observed features  (Table 7.2 line 9)
        mu, Sigma = update(mu, Sigma, zi, landmarks[j], Q)
    return _gaussian(mu, Sigma)


def ekf_localization_known(mu, Sigma, u, z, ids, landmarks, dt, M, Q):
    """One step of EKF localization with known correspondences.

    Parameters
    ----------
    mu : ndarray, shape (3,)
        Mean pose at time ``t-1``.
    Sigma : ndarray, shape (3, 3)
        Its covariance.
    u : ndarray, shape (2,)
        Control ``[v, omega]``.
    z : ndarray, shape (K, 2)
        The step's measurements ``[r, phi]`` (``K`` may be 0).
    ids : ndarray of int, shape (K,)
        Index into `landmarks` of each measurement (the correspondences).
    landmarks : ndarray, shape (N, 2)
        The map.
    dt : float
        Duration of the control, seconds.
    M : ndarray, shape (2, 2)
        Control-noise covariance.
    Q : ndarray, shape (2, 2)
        Measurement-noise covariance, positive definite.

    Returns
    -------
    Gaussian
        ``(mu (3,), Sigma (3, 3))`` after :func:`ekf_predict` and one
        :func:`ekf_update` per measurement, applied in order (each update
        linearises at the mean left by the previous one).

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 7.2.
    """
    mu, Sigma, u, z, landmarks, dt, M, Q = _step_inputs(mu, Sigma, u, z, landmarks, dt, M, Q)
    ids = as_indices(ids, "ids", landmarks.shape[0], (z.shape[0],), ref="z")
    return _known_step(mu, Sigma, u, z, ids, landmarks, dt, M, Q)


def _nearest(mu, Sigma, z, landmarks, Q, gate):
    return _associate(_mahalanobis(mu, Sigma, z, landmarks, Q), gate)


def _unknown_step(mu, Sigma, u, z, landmarks, dt, M, Q, gate, predict=_ekf_predict, update=_ekf_update,
                  associate=_nearest):
    mu, Sigma = predict(mu, Sigma, u, dt, M)
    ids = np.full(z.shape[0], -1, dtype=np.intp)
    for i, zi in enumerate(z):  # for all observed features  (Table 7.3 line 9)
        # j(i) = argmin_k d_k, gated  (Table 7.3 line 16, nearest neighbour)
        j = associate(mu, Sigma, zi, landmarks, Q, gate)
        ids[i] = j
        if j >= 0:
            mu, Sigma = update(mu, Sigma, zi, landmarks[j], Q)
    return _gaussian(mu, Sigma), ids


def ekf_localization_unknown(mu, Sigma, u, z, landmarks, dt, M, Q, *, gate=DEFAULT_GATE):
    """One step of EKF localization with unknown correspondences.

    Parameters
    ----------
    mu : ndarray, shape (3,)
        Mean pose at time ``t-1``.
    Sigma : ndarray, shape (3, 3)
        Its covariance.
    u : ndarray, shape (2,)
        Control ``[v, omega]``.
    z : ndarray, shape (K, 2)
        The step's measurements; some may be clutter (no landmark).
    landmarks : ndarray, shape (N, 2)
        The map.
    dt : float
        Duration of the control, seconds.
    M : ndarray, shape (2, 2)
        Control-noise covariance.
    Q : ndarray, shape (2, 2)
        Measurement-noise covariance, positive definite.
    gate : float, keyword-only
        Squared-Mahalanobis gate of :func:`associate_ml`; a measurement whose
        nearest landmark lies beyond it is discarded as an outlier.

    Returns
    -------
    belief : Gaussian
        ``(mu (3,), Sigma (3, 3))`` after the prediction and the updates.
    ids : ndarray of int, shape (K,)
        The landmark chosen for each measurement, ``-1`` for a gated outlier.

    Notes
    -----
    Measurements are handled in order: each is associated against the belief
    left by the previous update and then applied, so later associations use
    the sharper belief.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 7.3 (association by nearest
    Mahalanobis neighbour with a gate, cf. Sec. 7.5).
    """
    mu, Sigma, u, z, landmarks, dt, M, Q = _step_inputs(mu, Sigma, u, z, landmarks, dt, M, Q)
    gate = as_threshold(gate, "gate")
    return _unknown_step(mu, Sigma, u, z, landmarks, dt, M, Q, gate)


class EKFRunResult(NamedTuple):
    """Output of :func:`ekf_localization_run`.

    Attributes
    ----------
    mu : ndarray, shape (T+1, 3)
        Posterior means, ``mu[0]`` the initial belief.
    Sigma : ndarray, shape (T+1, 3, 3)
        Posterior covariances.
    ids : tuple of ndarray of int, shape (K_t,)
        Correspondences used at each step (``-1`` marks a gated measurement);
        the given ones when correspondences are known, except those the
        validation gate rejected.
    n_gated : int
        Measurements rejected by the gate (``-1`` in `ids`).
    """

    mu: np.ndarray
    Sigma: np.ndarray
    ids: tuple
    n_gated: int = 0


def _gated_known_step(mu, Sigma, u, z, ids, landmarks, dt, M, Q, gate, predict=_ekf_predict, update=_ekf_update):
    """:func:`_known_step` with a validation gate; returns the belief and the ids used (``-1``: gated)."""
    mu, Sigma = predict(mu, Sigma, u, dt, M)
    used = ids.copy()
    for k, (zi, j) in enumerate(zip(z, ids)):  # for all observed features  (Table 7.2 line 9)
        # validation gate on nu^T S^-1 nu, S = H Sigma_bar H^T + Q  (Table 7.2 lines 11-14)
        if _mahalanobis(mu, Sigma, zi, landmarks[j:j + 1], Q)[0] > gate:
            used[k] = -1
            continue
        mu, Sigma = update(mu, Sigma, zi, landmarks[j], Q)
    return Gaussian(mu, Sigma), used


def _run_steps(ekf_predict, ekf_update, associate_ml):
    """The prediction, update and association of :func:`ekf_localization_run`: the cores, or the caller's functions.

    A caller's function is called with the contract's arguments (copies, so that it
    cannot change the filter's state) and what it returns is checked.
    """
    predict, update, associate = _ekf_predict, _ekf_update, _nearest
    if ekf_predict is not None:
        def predict(mu, Sigma, u, dt, M):
            out = ekf_predict(mu.copy(), Sigma.copy(), u.copy(), dt, M.copy())
            return _gaussian(*as_returned(out, "ekf_predict", (3,), (3, 3)))
    if ekf_update is not None:
        def update(mu_bar, Sigma_bar, z, m, Q):
            out = ekf_update(mu_bar.copy(), Sigma_bar.copy(), z.copy(), m.copy(), Q.copy())
            return _gaussian(*as_returned(out, "ekf_update", (3,), (3, 3)))
    if associate_ml is not None:
        def associate(mu_bar, Sigma_bar, z, landmarks, Q, gate):
            j = associate_ml(mu_bar.copy(), Sigma_bar.copy(), z.copy(), landmarks.copy(), Q.copy(), gate)
            return as_index(j, "associate_ml(...)", landmarks.shape[0], lower=-1)
    return predict, update, associate


def ekf_localization_run(run, *, known=True, mu0=None, Sigma0=None, M=None, Q=None, gate=None, ekf_predict=None,
                         ekf_update=None, associate_ml=None, on_step=None):
    """Run EKF localization over a whole simulated run.

    Parameters
    ----------
    run : LandmarkRun
        A run of :func:`~slamlib.sim.simulate_landmark_run`; the filter uses
        its ``landmarks``, ``dt``, commanded controls ``u (T, 2)``,
        measurements ``z`` and, when `known`, correspondences ``ids``.
    known : bool, keyword-only
        Known correspondences (Table 7.2) or nearest-neighbour association
        with a gate (Table 7.3).
    mu0 : ndarray, shape (3,), keyword-only, optional
        Initial mean; defaults to ``run.x0``.
    Sigma0 : ndarray, shape (3, 3), keyword-only, optional
        Initial covariance; defaults to ``diag(0.01, 0.01, 0.001)``.
    M, Q : ndarray, shape (2, 2), keyword-only, optional
        Noise covariances assumed by the filter; default to the run's.
    gate : float, optional, keyword-only
        Gate on the squared Mahalanobis distance (normalised innovation
        squared) ``nu^T S^-1 nu``. With unknown correspondences it is the
        association gate of :func:`associate_ml`; with known ones a
        validation gate: a measurement beyond it from its landmark is
        rejected as an outlier. ``None`` (default) takes ``run.gate`` if the
        run has that attribute (real-data loaders set it, e.g.
        :func:`~slamlib.datasets.mrclam.load_mrclam`), else no gate with
        known correspondences and :data:`DEFAULT_GATE` with unknown ones;
        ``numpy.inf`` turns it off.
    ekf_predict : callable, optional, keyword-only
        ``ekf_predict(mu, Sigma, u, dt, M) -> (mu_bar, Sigma_bar)`` in place of
        the filter's own prediction (Table 7.2 lines 2-7): :func:`ekf_predict`
        itself, or a student's version of it, as the autograder plugs it in.
        ``None`` (default): the library's core.
    ekf_update : callable, optional, keyword-only
        ``ekf_update(mu_bar, Sigma_bar, z, m, Q) -> (mu, Sigma)`` in place of
        the update with one measurement of landmark ``m`` (Table 7.2 lines
        10-17), as :func:`ekf_update`.
    associate_ml : callable, optional, keyword-only
        Unknown correspondences only: ``associate_ml(mu_bar, Sigma_bar, z,
        landmarks, Q, gate) -> j`` in place of the nearest-neighbour
        association of each measurement, as :func:`associate_ml` (``j = -1``
        discards the measurement).
    on_step : callable, optional, keyword-only
        ``on_step(t)`` is called at the start of step ``t`` (before its
        prediction), e.g. for progress reports, or so that the functions
        above know which step they serve.

    Returns
    -------
    EKFRunResult
        ``(mu (T+1, 3), Sigma (T+1, 3, 3), ids, n_gated)``.

    Notes
    -----
    The functions given for `ekf_predict`, `ekf_update` and `associate_ml`
    are called with the homework contract's arguments, at the point of the
    algorithm where the filter would do that work itself, on copies of the
    filter's arrays (they cannot change its state); their results are
    checked (shapes, finite values, an integer index in ``[-1, N)``) and a
    bad one raises ``ValueError`` (``TypeError`` for an index that is not an
    integer) naming the function. Exceptions they raise pass through
    unchanged.

    References
    ----------
    Thrun, Burgard & Fox (2005), Tables 7.2 and 7.3; Bar-Shalom, Li &
    Kirubarajan (2001) (validation gate).
    """
    for attr in ("landmarks", "dt", "x0", "u", "z", "ids", "M", "Q"):
        if not hasattr(run, attr):
            raise TypeError(f"run must be a LandmarkRun (missing attribute {attr!r})")
    landmarks = as_array(run.landmarks, "run.landmarks", (None, 2))
    u = as_array(run.u, "run.u", (None, 2))
    dt = as_scalar(run.dt, "run.dt", nonnegative=True)
    mu = as_array(run.x0 if mu0 is None else mu0, "mu0", (3,))
    Sigma = as_covariance(np.diag([0.01, 0.01, 0.001]) if Sigma0 is None else Sigma0, "Sigma0", 3, batched=True,
                          copy=False)
    M = as_covariance(run.M if M is None else M, "M", 2, batched=True, copy=False)
    Q = as_covariance(run.Q if Q is None else Q, "Q", 2, definite=True, batched=True, copy=False)
    if gate is None:
        gate = getattr(run, "gate", np.inf if known else DEFAULT_GATE)
    gate = as_threshold(gate, "gate")
    T = u.shape[0]
    if len(run.z) != T or len(run.ids) != T:
        raise ValueError(f"run.z and run.ids must hold one entry per control ({T}), got {len(run.z)} and {len(run.ids)}")
    check_callable(ekf_predict, "ekf_predict", "(mu, Sigma, u, dt, M)")
    check_callable(ekf_update, "ekf_update", "(mu_bar, Sigma_bar, z, m, Q)")
    check_callable(associate_ml, "associate_ml", "(mu_bar, Sigma_bar, z, landmarks, Q, gate)")
    check_callable(on_step, "on_step", "(t)")
    if known and associate_ml is not None:
        raise ValueError("associate_ml needs known=False (with known correspondences nothing is associated)")
    predict, update, associate = _run_steps(ekf_predict, ekf_update, associate_ml)
    mus = np.empty((T + 1, 3))
    Sigmas = np.empty((T + 1, 3, 3))
    mus[0], Sigmas[0] = mu, Sigma
    used = []
    n_gated = 0
    for t in range(T):
        if on_step is not None:
            on_step(t)
        z = as_rows(run.z[t], f"run.z[{t}]", 2)
        if known:
            ids = as_indices(run.ids[t], "ids", landmarks.shape[0], (z.shape[0],), ref="z")
            if gate < np.inf:
                (mu, Sigma), ids = _gated_known_step(mu, Sigma, u[t], z, ids, landmarks, dt, M, Q, gate, predict,
                                                     update)
            else:
                mu, Sigma = _known_step(mu, Sigma, u[t], z, ids, landmarks, dt, M, Q, predict, update)
        else:
            (mu, Sigma), ids = _unknown_step(mu, Sigma, u[t], z, landmarks, dt, M, Q, gate, predict, update, associate)
        n_gated += int(np.sum(ids < 0))
        mus[t + 1], Sigmas[t + 1] = mu, Sigma
        used.append(ids)
    return EKFRunResult(mus, Sigmas, tuple(used), n_gated)


def ekf_localization_batch(runs, *, mu0=None, Sigma0=None, M=None, Q=None):
    """EKF localization with known correspondences over many runs at once.

    The runs are filtered independently, but each prediction and each
    measurement slot is one vectorised call over all runs, which makes
    Monte-Carlo studies (NEES) fast. The result equals
    :func:`ekf_localization_run` applied to each run in turn.

    Parameters
    ----------
    runs : sequence of LandmarkRun
        ``N`` runs with the same number of steps ``T`` and the same ``dt``
        (landmarks, controls and measurements may differ).
    mu0 : ndarray, shape (3,) or (N, 3), keyword-only, optional
        Initial means; default to each run's ``x0``.
    Sigma0 : ndarray, shape (3, 3) or (N, 3, 3), keyword-only, optional
        Initial covariances; default to ``diag(0.01, 0.01, 0.001)``.
    M, Q : ndarray, shape (2, 2) or (N, 2, 2), keyword-only, optional
        Noise covariances assumed by the filter; default to each run's.

    Returns
    -------
    EKFRunResult
        ``(mu (N, T+1, 3), Sigma (N, T+1, 3, 3), ids)``, ``ids[n]`` the
        correspondences of run ``n``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 7.2.
    """
    runs = list(runs)
    if not runs:
        raise ValueError("runs must hold at least one LandmarkRun")
    for k, run in enumerate(runs):
        for attr in ("landmarks", "dt", "x0", "u", "z", "ids", "M", "Q"):
            if not hasattr(run, attr):
                raise TypeError(f"runs[{k}] must be a LandmarkRun (missing attribute {attr!r})")
    N = len(runs)
    u = np.stack([as_array(r.u, f"runs[{k}].u", (None, 2)) for k, r in enumerate(runs)]) if len(
        {np.shape(r.u) for r in runs}) == 1 else None
    if u is None:
        raise ValueError("runs must all have the same number of steps")
    T = u.shape[1]
    dt = as_scalar(runs[0].dt, "runs[0].dt", nonnegative=True)
    if any(float(r.dt) != dt for r in runs):
        raise ValueError("runs must all have the same dt")

    def per_run(value, default, name, shape):
        if value is None:
            return np.stack([as_array(default(r), f"runs[{k}].{name}", shape) for k, r in enumerate(runs)])
        arr = as_array(value, name, ndim=(len(shape), len(shape) + 1))
        if arr.shape[-len(shape):] != shape or (arr.ndim > len(shape) and arr.shape[0] != N):
            raise ValueError(f"{name} must have shape {shape} or ({N}, {', '.join(map(str, shape))}), got {arr.shape}")
        return np.broadcast_to(arr, (N,) + shape).copy()

    mu = per_run(mu0, lambda r: r.x0, "mu0", (3,))
    Sigma = per_run(Sigma0, lambda r: np.diag([0.01, 0.01, 0.001]), "Sigma0", (3, 3))
    Mf = per_run(M, lambda r: r.M, "M", (2, 2))
    Qf = per_run(Q, lambda r: r.Q, "Q", (2, 2))
    as_covariance(Sigma, "Sigma0", 3, batched=True, copy=False)
    as_covariance(Mf, "M", 2, batched=True, copy=False)
    as_covariance(Qf, "Q", 2, definite=True, batched=True, copy=False)

    # pack the measurements of step t into slots: z (N, K_max, 2), landmark (N, K_max, 2), valid (N, K_max)
    packed = []
    for t in range(T):
        zs = [as_rows(r.z[t], f"runs[{k}].z[{t}]", 2) for k, r in enumerate(runs)]
        ids = [as_indices(r.ids[t], "ids", r.landmarks.shape[0], (z.shape[0],), ref="z") for r, z in zip(runs, zs)]
        k_max = max(z.shape[0] for z in zs)
        Z = np.zeros((N, k_max, 2))
        Mk = np.zeros((N, k_max, 2))
        valid = np.zeros((N, k_max), dtype=bool)
        for n, (r, z, j) in enumerate(zip(runs, zs, ids)):
            Z[n, : len(j)] = z
            Mk[n, : len(j)] = np.asarray(r.landmarks)[j]
            valid[n, : len(j)] = True
        packed.append((Z, Mk, valid))

    mus = np.empty((N, T + 1, 3))
    Sigmas = np.empty((N, T + 1, 3, 3))
    mus[:, 0], Sigmas[:, 0] = mu, Sigma
    for t in range(T):
        mu, Sigma = _ekf_predict(mu, Sigma, u[:, t], dt, Mf)  # (Table 7.2 lines 2-7)
        Z, Mk, valid = packed[t]
        for k in range(Z.shape[1]):  # the k-th measurement of every run that has one (line 10)
            sel = valid[:, k]
            if sel.all():
                mu, Sigma = _ekf_update(mu, Sigma, Z[:, k], Mk[:, k], Qf)
            else:
                mu_s, Sigma_s = _ekf_update(mu[sel], Sigma[sel], Z[sel, k], Mk[sel, k], Qf[sel])
                mu, Sigma = mu.copy(), Sigma.copy()
                mu[sel], Sigma[sel] = mu_s, Sigma_s
        mus[:, t + 1], Sigmas[:, t + 1] = mu, Sigma
    ids = tuple(tuple(np.asarray(i, dtype=np.intp) for i in r.ids) for r in runs)
    return EKFRunResult(mus, Sigmas, ids)
