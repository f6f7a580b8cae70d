"""FastSLAM 1.0: a Rao-Blackwellised particle filter for landmark SLAM.

Each particle ``k`` carries a sampled robot pose ``x^[k]`` and, for every
landmark ``j`` it has seen, a 2-D Gaussian ``N(mu_j^[k], Sigma_j^[k])``. The
factorisation of the SLAM posterior (course text Eq. 17.4; Thrun et al.,
Chapter 13)

``p(x_{1:t}, m | z_{1:t}, u_{1:t}) = p(x_{1:t} | z_{1:t}, u_{1:t}) prod_j p(m_j | x_{1:t}, z_{1:t})``

lets a particle filter sample the path while one small EKF per landmark and
per particle tracks the map given that path.

Everything is vectorised over particles: a :class:`FastSLAMState` holds
``poses (M, 3)``, landmark means ``mu (M, N, 2)``, covariances
``Sigma (M, N, 2, 2)``, a ``seen (M, N)`` mask with observation counters
``counts (M, N)`` and normalised ``log_weights (M,)``, for a preallocated
capacity of ``N`` landmarks per particle. The steps
(:func:`fastslam_predict`, :func:`fastslam_update_known`,
:func:`fastslam_update_unknown`, :func:`fastslam_resample`) are pure: they
return a new state and never write into the one they are given.

The importance weight of a measurement of a known landmark is the density of
the innovation under the *innovation* covariance ``S = H Sigma H^T + Q``.
The course text's Algorithm 3 prints ``Q^-1`` (the measurement noise) in the
exponent; that is an erratum (it ignores the landmark's own uncertainty and
makes the weights far too peaked). ``weight_cov="Q"`` reproduces the erratum
for demonstrations only.

References
----------
Course text, Eq. 17.4 and Algorithm 3 (FastSLAM 1.0).
Thrun, Burgard & Fox, *Probabilistic Robotics* (2005), Chapter 13 (the
factored posterior), Table 13.1 (known correspondences), Table 13.2 (unknown
correspondences). Montemerlo et al. (2002), FastSLAM.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.special import logsumexp

from .particle import effective_sample_size, low_variance_resample, normalize_log_weights
from ._checks import as_array, as_covariance, as_scalar, check_rng
from .angles import circular_mean, wrap_angle
from .motion import _control_sqrt, sample_motion_model_velocity, velocity_motion
from .sensors import landmark_from_measurement, landmark_measurement

__all__ = [
    "fastslam_init_landmark",
    "fastslam_update_landmark",
    "FastSLAMState",
    "fastslam_initial_state",
    "fastslam_predict",
    "fastslam_update_known",
    "fastslam_update_unknown",
    "fastslam_resample",
    "fastslam_estimate",
    "fastslam_map_moments",
    "fastslam_default_p0",
    "FastSLAMResult",
    "run_fastslam",
]

_LOG_2PI = float(np.log(2.0 * np.pi))
_WEIGHT_COVS = ("S", "Q")


# --------------------------------------------------------------------------- 2x2 algebra
def _T(A):
    """Transpose of the trailing 2x2 blocks."""
    return np.swapaxes(A, -1, -2)


def _mm(A, B):
    """Batched product of trailing 2x2 blocks, written out (faster than matmul for 2x2)."""
    out = np.empty(np.broadcast_shapes(A.shape, B.shape))
    a00, a01, a10, a11 = A[..., 0, 0], A[..., 0, 1], A[..., 1, 0], A[..., 1, 1]
    b00, b01, b10, b11 = B[..., 0, 0], B[..., 0, 1], B[..., 1, 0], B[..., 1, 1]
    out[..., 0, 0] = a00 * b00 + a01 * b10
    out[..., 0, 1] = a00 * b01 + a01 * b11
    out[..., 1, 0] = a10 * b00 + a11 * b10
    out[..., 1, 1] = a10 * b01 + a11 * b11
    return out


def _inv(A):
    """Determinant and inverse of 2x2 blocks: ``inv [[a, b], [c, d]] = [[d, -b], [-c, a]] / (ad - bc)``."""
    det = A[..., 0, 0] * A[..., 1, 1] - A[..., 0, 1] * A[..., 1, 0]
    inv = np.empty(A.shape)
    inv[..., 0, 0] = A[..., 1, 1] / det
    inv[..., 0, 1] = -A[..., 0, 1] / det
    inv[..., 1, 0] = -A[..., 1, 0] / det
    inv[..., 1, 1] = A[..., 0, 0] / det
    return det, inv


def _sym(A):
    return 0.5 * (A + _T(A))


# --------------------------------------------------------------------------- cores (no validation)
def _init_core(x, z, Q):
    """Mean and covariance of a new landmark (Table 13.1 lines 7-9); broadcasts ``x (..., 3)``, ``z (..., 2)``."""
    mu = landmark_from_measurement(x, z)  # mu_j = h^-1(z, x)  (Table 13.1 line 7)
    _, _, H = landmark_measurement(x, mu)  # H = h'(mu_j, x)  (Table 13.1 line 8)
    _, Hinv = _inv(H)
    Sigma = _sym(_mm(_mm(Hinv, Q), _T(Hinv)))  # Sigma_j = H^-1 Q (H^-1)^T  (Table 13.1 line 9)
    return mu, Sigma


def _innovation(H, Sigma, Q):
    """``H Sigma`` and ``S = H Sigma H^T + Q`` for batches of 2x2 blocks, written out per component.

    Returns ``(a00, a01, a10, a11)`` of ``A = H Sigma`` and ``(S00, S01, S11)``
    of the symmetric ``S``; component arithmetic on contiguous arrays is several
    times faster than batched 2x2 ``matmul``.
    """
    h00, h01, h10, h11 = H[..., 0, 0], H[..., 0, 1], H[..., 1, 0], H[..., 1, 1]
    s00, s11 = Sigma[..., 0, 0], Sigma[..., 1, 1]
    s01 = 0.5 * (Sigma[..., 0, 1] + Sigma[..., 1, 0])
    a00 = h00 * s00 + h01 * s01
    a01 = h00 * s01 + h01 * s11
    a10 = h10 * s00 + h11 * s01
    a11 = h10 * s01 + h11 * s11
    # S = H Sigma H^T + Q  (Table 13.1 line 14 and Table 13.2, where Thrun calls it Q)
    S00 = a00 * h00 + a01 * h01 + Q[0, 0]
    S01 = a00 * h10 + a01 * h11 + 0.5 * (Q[0, 1] + Q[1, 0])
    S11 = a10 * h10 + a11 * h11 + Q[1, 1]
    return (a00, a01, a10, a11), (S00, S01, S11), (s00, s01, s11)


def _log_gauss_2(nu0, nu1, C00, C01, C11):
    """``log N(nu; 0, C)`` from the components of 2-vectors and symmetric 2x2 covariances."""
    det = C00 * C11 - C01 * C01
    maha = (nu0 * nu0 * C11 - 2.0 * nu0 * nu1 * C01 + nu1 * nu1 * C00) / det
    return -0.5 * maha - _LOG_2PI - 0.5 * np.log(det)


def _update_core(x, mu, Sigma, z, Q, weight_cov="S"):
    """Per-particle landmark EKF update and log importance weight (Table 13.1 lines 12-18)."""
    z_hat, _, H = landmark_measurement(x, mu)  # z_hat = h(mu_j, x), H = h'(mu_j, x)  (Table 13.1 lines 12-13)
    nu0 = z[..., 0] - z_hat[..., 0]
    nu1 = wrap_angle(z[..., 1] - z_hat[..., 1])
    (a00, a01, a10, a11), (S00, S01, S11), (s00, s01, s11) = _innovation(H, Sigma, Q)
    det = S00 * S11 - S01 * S01
    i00, i01, i11 = S11 / det, -S01 / det, S00 / det  # S^-1
    # K = Sigma H^T S^-1 = (H Sigma)^T S^-1  (Table 13.1 line 15)
    K00 = a00 * i00 + a10 * i01
    K01 = a00 * i01 + a10 * i11
    K10 = a01 * i00 + a11 * i01
    K11 = a01 * i01 + a11 * i11
    mu_new = np.empty(z_hat.shape)
    # mu = mu + K (z - z_hat)  (Table 13.1 line 16)
    mu_new[..., 0] = mu[..., 0] + K00 * nu0 + K01 * nu1
    mu_new[..., 1] = mu[..., 1] + K10 * nu0 + K11 * nu1
    # Sigma = (I - K H) Sigma = Sigma - K (H Sigma)  (Table 13.1 line 17), symmetric
    Sigma_new = np.empty(H.shape)
    Sigma_new[..., 0, 0] = s00 - (K00 * a00 + K01 * a10)
    Sigma_new[..., 0, 1] = Sigma_new[..., 1, 0] = s01 - 0.5 * (K00 * a01 + K01 * a11 + K10 * a00 + K11 * a10)
    Sigma_new[..., 1, 1] = s11 - (K10 * a01 + K11 * a11)
    if weight_cov == "S":
        # w = |2 pi S|^-1/2 exp(-1/2 nu^T S^-1 nu)  (Table 13.1 line 18)
        log_w = _log_gauss_2(nu0, nu1, S00, S01, S11)
    else:
        # erratum of the course text's Algorithm 3: Q^-1 (measurement noise only) in the exponent
        log_w = _log_gauss_2(nu0, nu1, Q[0, 0], 0.5 * (Q[0, 1] + Q[1, 0]), Q[1, 1])
    return mu_new, Sigma_new, log_w


def _check_weight_cov(weight_cov):
    if weight_cov not in _WEIGHT_COVS:
        raise ValueError(f"weight_cov must be 'S' (innovation covariance) or 'Q' (the erratum), got {weight_cov!r}")
    return weight_cov


def _check_Q(Q):
    Q = as_covariance(Q, "Q", 2)
    if np.linalg.eigvalsh(Q).min() <= 0:
        raise ValueError("Q must be positive definite")
    return Q


def _poses_arg(x, name="x"):
    x = as_array(x, name, ndim=(1, 2))
    if x.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (M, 3) or (3,), got {x.shape}")
    return x


def _z_arg(z):
    z = as_array(z, "z", (2,))
    if z[0] <= 0:
        raise ValueError(f"z must have a positive range z[0], got {z[0]}")
    return z


# --------------------------------------------------------------------------- contract functions
def fastslam_init_landmark(x, z, Q):
    """Initialise one landmark's Gaussian in every particle from its first measurement.

    Parameters
    ----------
    x : ndarray, shape (M, 3)
        Particle poses ``[x, y, theta]`` (a single pose ``(3,)`` is accepted
        and gives unbatched results).
    z : ndarray, shape (2,)
        Measurement ``[r, phi]`` of the new landmark, ``r > 0``.
    Q : ndarray, shape (2, 2)
        Measurement-noise covariance of ``[r, phi]``, positive definite.

    Returns
    -------
    mu : ndarray, shape (M, 2)
        Landmark means from the inverse measurement model, ``h^-1(z, x)``.
    Sigma : ndarray, shape (M, 2, 2)
        ``H^-1 Q H^-T`` with ``H = Hm`` the Jacobian of ``h`` with respect to
        the landmark, evaluated at the new mean.

    References
    ----------
    Course text, Algorithm 3 (new landmark). Thrun, Burgard & Fox (2005),
    Table 13.1 lines 7-9.
    """
    x = _poses_arg(x)
    z = _z_arg(z)
    Q = _check_Q(Q)
    return _init_core(x, z, Q)


def fastslam_update_landmark(x, mu, Sigma, z, Q, *, weight_cov="S", log=False):
    """EKF update of one landmark in every particle, with the importance weight.

    Parameters
    ----------
    x : ndarray, shape (M, 3)
        Particle poses (a single pose ``(3,)`` with ``mu (2,)``,
        ``Sigma (2, 2)`` gives unbatched results).
    mu : ndarray, shape (M, 2)
        Each particle's prior mean of the observed landmark.
    Sigma : ndarray, shape (M, 2, 2)
        Each particle's prior covariance of that landmark.
    z : ndarray, shape (2,)
        Measurement ``[r, phi]``.
    Q : ndarray, shape (2, 2)
        Measurement-noise covariance, positive definite.
    weight_cov : {"S", "Q"}, keyword-only
        Covariance of the importance weight. ``"S"`` (default, correct):
        ``S = H Sigma H^T + Q``. ``"Q"`` reproduces the erratum of the course
        text's Algorithm 3, ``N(nu; 0, Q)``, which ignores the landmark's
        uncertainty; it exists only to demonstrate why that is wrong.
    log : bool, keyword-only
        Return ``log w`` instead of ``w`` (what the filter uses: many
        landmarks in view underflow ``w``, never ``log w``).

    Returns
    -------
    mu_new : ndarray, shape (M, 2)
        ``mu + K nu`` with ``K = Sigma H^T S^-1``.
    Sigma_new : ndarray, shape (M, 2, 2)
        ``(I - K H) Sigma`` (symmetrised).
    w : ndarray, shape (M,)
        Unnormalised importance weight ``N(nu; 0, S)``, ``nu = z - z_hat``
        with its bearing wrapped (``log w`` if `log`).

    Notes
    -----
    ``H = Hm`` is the Jacobian of ``h`` with respect to the landmark, at each
    particle's pose and prior landmark mean.

    References
    ----------
    Course text, Algorithm 3 (known landmark). Thrun, Burgard & Fox (2005),
    Table 13.1 lines 12-18 (where ``Q`` names the innovation covariance).
    """
    x = _poses_arg(x)
    batch = x.shape[:-1]
    mu = as_array(mu, "mu", batch + (2,))
    Sigma = as_array(Sigma, "Sigma", batch + (2, 2))
    if not np.allclose(Sigma, _T(Sigma), rtol=1e-9, atol=1e-12 * max(1.0, float(np.abs(Sigma).max(initial=0.0)))):
        raise ValueError("Sigma must hold symmetric 2x2 covariances")
    z = _z_arg(z)
    Q = _check_Q(Q)
    _check_weight_cov(weight_cov)
    if np.any(np.hypot(mu[..., 0] - x[..., 0], mu[..., 1] - x[..., 1]) < 1e-9):
        raise ValueError("mu coincides with a particle pose x: the measurement Jacobian is undefined")
    mu_new, Sigma_new, log_w = _update_core(x, mu, Sigma, z, Q, weight_cov)
    return mu_new, Sigma_new, (log_w if log else np.exp(log_w))


# --------------------------------------------------------------------------- the particle set
class FastSLAMState(NamedTuple):
    """The FastSLAM 1.0 particle set, one array per quantity.

    Attributes
    ----------
    poses : ndarray, shape (M, 3)
        Each particle's current pose ``x_t^[k]``.
    mu : ndarray, shape (M, N, 2)
        Landmark means ``mu_j^[k]``; meaningless where ``seen`` is False.
    Sigma : ndarray, shape (M, N, 2, 2)
        Landmark covariances ``Sigma_j^[k]``.
    seen : ndarray of bool, shape (M, N)
        Whether slot ``j`` of particle ``k`` holds a landmark.
    counts : ndarray of int, shape (M, N)
        Observation counter ``i_j^[k]`` of Table 13.2 (number of times the
        landmark was observed, less misses when pruning is on).
    log_weights : ndarray, shape (M,)
        Normalised log importance weights (``logsumexp == 0``).

    Notes
    -----
    ``N`` is a preallocated capacity; with known correspondences slot ``j``
    is landmark ``j``. Every particle owns its arrays' rows: no two particles
    share storage, and the step functions return new arrays instead of
    writing into a state.

    References
    ----------
    Thrun, Burgard & Fox (2005), Chapter 13 (a particle: path sample and N
    landmark Gaussians), Table 13.2 (counters).
    """

    poses: np.ndarray
    mu: np.ndarray
    Sigma: np.ndarray
    seen: np.ndarray
    counts: np.ndarray
    log_weights: np.ndarray

    @property
    def n_particles(self) -> int:
        """Number of particles ``M``."""
        return self.poses.shape[0]

    @property
    def capacity(self) -> int:
        """Landmark slots per particle ``N``."""
        return self.mu.shape[1]

    @property
    def weights(self) -> np.ndarray:
        """Normalised weights ``exp(log_weights)``, shape ``(M,)``."""
        return normalize_log_weights(self.log_weights)


def _check_state(state, name="state"):
    if not isinstance(state, FastSLAMState):
        raise TypeError(f"{name} must be a FastSLAMState (from fastslam_initial_state), got {type(state).__name__}")
    M, N = state.seen.shape
    shapes = {"poses": (M, 3), "mu": (M, N, 2), "Sigma": (M, N, 2, 2), "counts": (M, N), "log_weights": (M,)}
    for field, shape in shapes.items():
        if getattr(state, field).shape != shape:
            raise ValueError(f"{name}.{field} must have shape {shape}, got {getattr(state, field).shape}")
    return state


def fastslam_initial_state(x0, n_particles, capacity):
    """A particle set whose particles all sit at the start pose with empty maps.

    Parameters
    ----------
    x0 : ndarray, shape (3,)
        Start pose; SLAM fixes the map frame by it, so all particles share it.
    n_particles : int
        Number of particles ``M >= 1``.
    capacity : int
        Landmark slots per particle ``N >= 1`` (grown automatically by the
        unknown-correspondence update when full).

    Returns
    -------
    FastSLAMState
        Uniform log weights ``-log M``; no landmark seen.

    References
    ----------
    Course text, Algorithm 3. Thrun, Burgard & Fox (2005), Table 13.1 (the
    particle set it starts from).
    """
    x0 = as_array(x0, "x0", (3,))
    M = _as_count(n_particles, "n_particles")
    N = _as_count(capacity, "capacity")
    x0 = x0.copy()
    x0[2] = wrap_angle(x0[2])
    return FastSLAMState(
        poses=np.tile(x0, (M, 1)),
        mu=np.zeros((M, N, 2)),
        Sigma=np.zeros((M, N, 2, 2)),
        seen=np.zeros((M, N), dtype=bool),
        counts=np.zeros((M, N), dtype=np.int64),
        log_weights=np.full(M, -np.log(M)),
    )


def _as_count(value, name):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be an integer, got {type(value).__name__}")
    if value < 1:
        raise ValueError(f"{name} must be at least 1, got {value}")
    return int(value)


def _normalised(log_w):
    return log_w - logsumexp(log_w)


def fastslam_predict(state, u, dt, *, rng, M=None, alpha=None):
    """Sample every particle's next pose from the velocity motion model.

    Parameters
    ----------
    state : FastSLAMState
        Particle set at ``t - 1``.
    u : ndarray, shape (2,)
        Commanded control ``[v, omega]``.
    dt : float
        Duration of the control (seconds).
    rng : numpy.random.Generator, keyword-only
        Source of the motion noise.
    M : ndarray, shape (2, 2), optional, keyword-only
        Control-noise covariance: each particle moves along the exact arc of
        its own control ``u + N(0, M)`` (the noise model of
        :func:`slamlib.simulate_landmark_run`). Draws one
        ``standard_normal((n_particles, 2))``.
    alpha : ndarray, shape (6,), optional, keyword-only
        Instead of `M`: the noise parameters of Table 5.3, sampled by
        :func:`slamlib.sample_motion_model_velocity`. Give exactly one of
        `M` and `alpha`.

    Returns
    -------
    FastSLAMState
        New poses; the maps and weights are those of `state` (shared, never
        written: every step builds new arrays for what it changes).

    References
    ----------
    Course text, Algorithm 3 (sample pose). Thrun, Burgard & Fox (2005),
    Table 13.1 line 4, Table 5.3.
    """
    _check_state(state)
    check_rng(rng)
    if (M is None) == (alpha is None):
        raise ValueError("give exactly one of M (control-noise covariance) and alpha (Table 5.3 parameters)")
    u = as_array(u, "u", (2,))
    dt = as_scalar(dt, "dt", nonnegative=True)
    if alpha is not None:
        # x_t^[k] ~ p(x_t | x_{t-1}^[k], u_t)  (Table 13.1 line 4, Table 5.3)
        poses = sample_motion_model_velocity(state.poses, u, dt, alpha, rng=rng)
    else:
        poses = _sample_arc(state.poses, u, dt, _control_sqrt(as_covariance(M, "M", 2)), rng)
    return state._replace(poses=poses)


def _sample_arc(poses, u, dt, L, rng):
    # u^[k] = u + N(0, M); x_t^[k] = arc(x_{t-1}^[k], u^[k])  (Table 13.1 line 4)
    u_k = u + rng.standard_normal((poses.shape[0], 2)) @ L.T
    return velocity_motion(poses, u_k, dt)[0]


def _rounds(ids):
    """Split observation indices so that no landmark appears twice in a round."""
    order = np.argsort(ids, kind="stable")
    sid = ids[order]
    first = np.r_[True, sid[1:] != sid[:-1]]
    start = np.maximum.accumulate(np.where(first, np.arange(sid.size), 0))
    occurrence = np.empty(ids.size, dtype=np.int64)
    occurrence[order] = np.arange(sid.size) - start
    return [np.flatnonzero(occurrence == r) for r in range(int(occurrence.max(initial=-1)) + 1)]


def _grow(state, need):
    """Copy of `state` with at least `need` landmark slots."""
    M, N = state.seen.shape
    if need <= N:
        return state
    N2 = max(need, 2 * N)
    mu = np.zeros((M, N2, 2))
    Sigma = np.zeros((M, N2, 2, 2))
    seen = np.zeros((M, N2), dtype=bool)
    counts = np.zeros((M, N2), dtype=np.int64)
    mu[:, :N], Sigma[:, :N], seen[:, :N], counts[:, :N] = state.mu, state.Sigma, state.seen, state.counts
    return state._replace(mu=mu, Sigma=Sigma, seen=seen, counts=counts)


def _z_matrix(z):
    z = as_array(z, "z", ndim=(1, 2))
    if z.ndim == 1:
        if z.size != 0:
            raise ValueError(f"z must have shape (K, 2), got {z.shape}")
        z = z.reshape(0, 2)
    if z.shape[-1] != 2:
        raise ValueError(f"z must have shape (K, 2), got {z.shape}")
    return z


def fastslam_update_known(state, z, ids, Q, *, weight_cov="S"):
    """Incorporate a step's measurements with known correspondences, all particles at once.

    Parameters
    ----------
    state : FastSLAMState
        Particle set after the motion update.
    z : ndarray, shape (K, 2)
        Measurements ``[r, phi]`` of the step (``K = 0`` allowed).
    ids : ndarray of int, shape (K,)
        Landmark index of each measurement (the correspondences ``c_t``);
        slots are grown if an index exceeds the capacity.
    Q : ndarray, shape (2, 2)
        Measurement-noise covariance.
    weight_cov : {"S", "Q"}, keyword-only
        Importance-weight covariance; ``"Q"`` is the course text's erratum,
        for demonstrations only (see :func:`fastslam_update_landmark`).

    Returns
    -------
    FastSLAMState
        Updated landmark Gaussians, counters and normalised log weights. A
        landmark seen for the first time is initialised (its factor ``p0`` is
        the same for every particle and cancels); measurements of seen
        landmarks multiply the weight by ``N(nu; 0, S)``.

    Notes
    -----
    All measurements of a step are processed together as ``(M, K)`` batches;
    a landmark measured twice in one step is processed in a second round, so
    the result equals processing the measurements one by one.

    References
    ----------
    Course text, Algorithm 3. Thrun, Burgard & Fox (2005), Table 13.1
    lines 5-18 (one measurement there; several multiply the weights).
    """
    _check_state(state)
    z = _z_matrix(z)
    ids = np.asarray(ids)
    if ids.shape != (z.shape[0],) or (ids.size and ids.dtype.kind not in "iu"):
        raise ValueError(f"ids must be integers of shape ({z.shape[0]},), got {ids.shape} dtype {ids.dtype}")
    if np.any(ids < 0):
        raise ValueError("ids must be non-negative landmark indices")
    Q = _check_Q(Q)
    _check_weight_cov(weight_cov)
    keep = z[:, 0] > 0
    z, ids = z[keep], ids[keep].astype(np.int64)
    if z.shape[0] == 0:
        return state
    state = _grow(state, int(ids.max()) + 1)
    return _update_known_core(state, z, ids, Q, weight_cov)


def _update_known_core(state, z, ids, Q, weight_cov, copy=True):
    """Known-correspondence update of all particles; ``copy=False`` writes into `state`'s arrays."""
    if copy:
        mu, Sigma = state.mu.copy(), state.Sigma.copy()
        seen, counts = state.seen.copy(), state.counts.copy()
    else:
        mu, Sigma, seen, counts = state.mu, state.Sigma, state.seen, state.counts
    log_w = state.log_weights.copy()
    x = state.poses[:, None, :]  # (M, 1, 3)
    for obs in _rounds(ids):
        j, zk = ids[obs], z[obs]  # (k,), (k, 2)
        new = ~seen[:, j]  # (M, k): never seen before  (Table 13.1 line 6)
        fresh, known = new.all(axis=0), (~new).all(axis=0)
        if np.all(fresh | known):  # the usual case: all particles agree on which landmarks are new
            if known.any():
                jk = j[known]
                mu_u, Sigma_u, lw = _update_core(x, mu[:, jk], Sigma[:, jk], zk[known], Q, weight_cov)  # (12-18)
                mu[:, jk], Sigma[:, jk] = mu_u, Sigma_u
                log_w = log_w + lw.sum(axis=1)
            if fresh.any():
                # mu_j = h^-1(z, x), Sigma_j = H^-1 Q H^-T; w = p0, equal for all particles  (Table 13.1 lines 7-10)
                mu[:, j[fresh]], Sigma[:, j[fresh]] = _init_core(x, zk[fresh], Q)
        else:
            mu_init, Sigma_init = _init_core(x, zk, Q)
            # the update must not see the placeholder mean of an unseen slot
            mu_old = np.where(new[..., None], mu_init, mu[:, j])
            Sigma_old = np.where(new[..., None, None], Sigma_init, Sigma[:, j])
            mu_upd, Sigma_upd, lw = _update_core(x, mu_old, Sigma_old, zk, Q, weight_cov)
            mu[:, j] = np.where(new[..., None], mu_old, mu_upd)
            Sigma[:, j] = np.where(new[..., None, None], Sigma_old, Sigma_upd)
            log_w = log_w + np.where(new, 0.0, lw).sum(axis=1)  # new: w = p0 for all  (Table 13.1 line 10)
        seen[:, j] = True
        counts[:, j] += 1
    return FastSLAMState(state.poses, mu, Sigma, seen, counts, _normalised(log_w))


def fastslam_default_p0(Q, gate=13.815510557964274):
    """Default new-landmark likelihood ``p0`` for unknown correspondences.

    Parameters
    ----------
    Q : ndarray, shape (2, 2)
        Measurement-noise covariance.
    gate : float
        Squared Mahalanobis distance at which ``p0`` equals the measurement
        density; the default is the 99.9 % quantile of chi-square with two
        degrees of freedom.

    Returns
    -------
    float
        ``p0 = N(d^2 = gate; 0, Q) = exp(-gate / 2) / |2 pi Q|^(1/2)``: a
        measurement whose best match is less likely than a perfectly known
        landmark seen at that distance starts a new landmark.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 13.2 (the new-feature likelihood ``p0``).
    """
    Q = _check_Q(Q)
    gate = as_scalar(gate, "gate", positive=True)
    return float(np.exp(-0.5 * gate - _LOG_2PI - 0.5 * np.log(np.linalg.det(Q))))


def fastslam_update_unknown(state, z, Q, *, p0=None, weight_cov="S", max_range=None, fov=None):
    """Incorporate a step's measurements with unknown correspondences (per-particle ML association).

    Parameters
    ----------
    state : FastSLAMState
        Particle set after the motion update.
    z : ndarray, shape (K, 2)
        Measurements ``[r, phi]`` of the step, processed one after the other.
    Q : ndarray, shape (2, 2)
        Measurement-noise covariance.
    p0 : float, optional, keyword-only
        Likelihood of a new landmark (Table 13.2 ``p0``); default
        :func:`fastslam_default_p0` of `Q`.
    weight_cov : {"S", "Q"}, keyword-only
        Importance-weight covariance of a matched measurement; ``"Q"`` is the
        course text's erratum (see :func:`fastslam_update_landmark`). The
        association itself always uses ``S``.
    max_range : float, optional, keyword-only
        Sensor range. When given, the landmark counters are maintained as in
        Table 13.2: a landmark inside the perceptual range
        (``r <= max_range`` and ``|phi| <= fov / 2``) that no measurement of
        the step matched loses one count and is removed below zero.
    fov : float, optional, keyword-only
        Full field of view (radians), default ``2 pi``; used with `max_range`.

    Returns
    -------
    FastSLAMState
        Updated particle set, capacity grown if a particle ran out of slots.

    Notes
    -----
    For each measurement and each particle ``k`` the likelihood
    ``w_j = N(nu_j; 0, S_j)`` of every seen landmark ``j`` is computed; the
    correspondence is ``argmax_j w_j`` over the seen landmarks and a new one
    with ``w_{N+1} = p0`` (a tie goes to the existing landmark with the
    smallest index). The particle's weight is multiplied by that maximum; a
    matched landmark gets the EKF update, a new one is initialised in the
    particle's first free slot with count 1.

    References
    ----------
    Course text, Algorithm 3 with maximum-likelihood data association.
    Thrun, Burgard & Fox (2005), Table 13.2.
    """
    _check_state(state)
    z = _z_matrix(z)
    Q = _check_Q(Q)
    _check_weight_cov(weight_cov)
    log_p0 = np.log(fastslam_default_p0(Q) if p0 is None else as_scalar(p0, "p0", positive=True))
    if max_range is not None:
        max_range = as_scalar(max_range, "max_range", positive=True)
    half_fov = np.pi if fov is None else 0.5 * as_scalar(fov, "fov", positive=True)
    if fov is not None and max_range is None:
        raise ValueError("fov needs max_range (the perceptual range) as well")
    return _update_unknown_core(state, z, Q, log_p0, weight_cov, max_range, half_fov)


def _update_unknown_core(state, z, Q, log_p0, weight_cov, max_range, half_fov, copy=True):
    """Unknown-correspondence update; ``copy=False`` may write into `state`'s arrays."""
    z = z[z[:, 0] > 0]
    M = state.n_particles
    need = int(state.seen.sum(axis=1).max(initial=0)) + z.shape[0]
    grown = _grow(state, need)
    if copy and grown is state:
        mu, Sigma = state.mu.copy(), state.Sigma.copy()
        seen, counts = state.seen.copy(), state.counts.copy()
    else:
        mu, Sigma, seen, counts = grown.mu, grown.Sigma, grown.seen, grown.counts
    log_w = state.log_weights.copy()
    matched = np.zeros_like(seen)
    x = state.poses
    rows = np.arange(M)
    used = np.flatnonzero(seen.any(axis=0))
    # slots at and beyond hi stay empty in every particle during this step (a new landmark takes the
    # particle's first free slot, at most one more per measurement)
    hi = min(seen.shape[1], (int(used[-1]) + 1 if used.size else 0) + z.shape[0])
    # the pose is fixed within the step: predict every landmark once, then refresh only what changes
    # z_hat_j = h(mu_j, x), H_j = h'(mu_j, x), S_j = H_j Sigma_j H_j^T + Q for every landmark j  (Table 13.2)
    mu_safe = np.where(seen[:, :hi, None], mu[:, :hi], x[:, None, :2] + 1.0)  # keep h defined on empty slots
    z_hat, _, H = landmark_measurement(x[:, None, :], mu_safe)
    _, S_parts, _ = _innovation(H, Sigma[:, :hi], Q)
    S = np.stack(S_parts, axis=-1)  # (M, hi, 3): S00, S01, S11

    def refresh(k, jk):
        zh, _, Hk = landmark_measurement(x[k], mu[k, jk])
        z_hat[k, jk] = zh
        S[k, jk] = np.stack(_innovation(Hk, Sigma[k, jk], Q)[1], axis=-1)

    for zk in z:
        sn = seen[:, :hi]
        nu1 = wrap_angle(zk[1] - z_hat[..., 1])
        # w_j = N(nu_j; 0, S_j)  (Table 13.2)
        ll = np.where(sn, _log_gauss_2(zk[0] - z_hat[..., 0], nu1, S[..., 0], S[..., 1], S[..., 2]), -np.inf)
        j = np.argmax(ll, axis=1)  # ties: smallest index
        best = ll[rows, j]
        is_new = best < log_p0  # c_hat = new landmark when p0 beats every w_j  (Table 13.2)
        old = ~is_new
        if old.any():
            k, jk = rows[old], j[old]
            # EKF update of landmark c_hat  (Table 13.2)
            mu_n, Sigma_n, lw = _update_core(x[k], mu[k, jk], Sigma[k, jk], zk, Q, weight_cov)
            mu[k, jk], Sigma[k, jk] = mu_n, Sigma_n
            counts[k, jk] += 1  # i_j = i_j + 1  (Table 13.2)
            matched[k, jk] = True
            # w = max_j w_j  (Table 13.2); the erratum swaps its covariance for Q
            log_w[k] += best[old] if weight_cov == "S" else lw
            refresh(k, jk)
        if is_new.any():
            k = rows[is_new]
            slot = np.argmin(seen[k], axis=1)  # first free slot (slot < hi, see above)
            mu_i, Sigma_i = _init_core(x[k], zk, Q)  # mu = h^-1(z, x), Sigma = H^-1 Q H^-T  (Table 13.2)
            mu[k, slot], Sigma[k, slot] = mu_i, Sigma_i
            seen[k, slot] = True
            counts[k, slot] = 1  # i_{N+1} = 1  (Table 13.2)
            matched[k, slot] = True
            log_w[k] += log_p0  # w = p0  (Table 13.2)
            refresh(k, slot)
    if max_range is not None:
        mu_safe = np.where(seen[..., None], mu, x[:, None, :2] + 1.0)
        z_hat, _, _ = landmark_measurement(x[:, None, :], mu_safe)
        in_view = seen & (z_hat[..., 0] <= max_range) & (np.abs(z_hat[..., 1]) <= half_fov)
        miss = in_view & ~matched
        counts = counts - miss  # i_j = i_j - 1 for unmatched landmarks in range  (Table 13.2)
        drop = seen & (counts < 0)  # discard landmark j when i_j < 0  (Table 13.2)
        seen = seen & ~drop
        counts = np.where(seen, counts, 0)
    return FastSLAMState(x, mu, Sigma, seen, counts, _normalised(log_w))


def fastslam_resample(state, *, rng, indices=None):
    """Resample the particles, copying each survivor's whole map.

    Parameters
    ----------
    state : FastSLAMState
        Weighted particle set.
    rng : numpy.random.Generator
        Source of the one uniform draw of low-variance resampling.
    indices : ndarray of int, shape (M,), optional, keyword-only
        Use these ancestor indices instead of drawing them.

    Returns
    -------
    new_state : FastSLAMState
        Particles ``indices[k]`` of `state`, with uniform log weights. Every
        array is a new one built by fancy indexing, so each particle owns its
        map: changing one particle's landmark never changes another's, even
        where both descend from the same ancestor.
    indices : ndarray of int, shape (M,)
        The ancestor of each new particle.

    References
    ----------
    Course text, Algorithm 3 (resampling). Thrun, Burgard & Fox (2005),
    Table 13.1 lines 24-28, Table 4.4 (low-variance sampler).
    """
    _check_state(state)
    check_rng(rng)
    M = state.n_particles
    if indices is None:
        idx = np.asarray(low_variance_resample(state.weights, rng=rng), dtype=np.int64)
    else:
        idx = np.asarray(indices)
        if idx.shape != (M,) or idx.dtype.kind not in "iu":
            raise ValueError(f"indices must be integers of shape ({M},), got {idx.shape} dtype {idx.dtype}")
        if np.any(idx < 0) or np.any(idx >= M):
            raise ValueError(f"indices must lie in [0, {M})")
        idx = idx.astype(np.int64)
    # fancy indexing copies: each new particle gets its own rows  (Table 13.1 lines 25-27)
    new = FastSLAMState(
        poses=state.poses[idx],
        mu=state.mu[idx],
        Sigma=state.Sigma[idx],
        seen=state.seen[idx],
        counts=state.counts[idx],
        log_weights=np.full(M, -np.log(M)),
    )
    return new, idx


def fastslam_estimate(state):
    """Weighted mean pose and the index of the most likely particle.

    Parameters
    ----------
    state : FastSLAMState
        Weighted particle set.

    Returns
    -------
    pose : ndarray, shape (3,)
        Weighted mean of the positions and weighted circular mean of the
        headings.
    best : int
        Index of the particle with the largest weight (its map is the map
        estimate: maps of different particles cannot be averaged when their
        data associations differ).

    References
    ----------
    Thrun, Burgard & Fox (2005), Chapter 13 (the particle set represents the
    posterior; a point estimate is read off it).
    """
    _check_state(state)
    return _estimate(state.poses, state.weights)


def _estimate(poses, w):
    pose = np.empty(3)
    pose[:2] = w @ poses[:, :2]
    pose[2] = circular_mean(poses[:, 2], w)
    return pose, int(np.argmax(w))


def fastslam_map_moments(state, slots):
    """Mean and covariance of the map implied by the whole particle set.

    Parameters
    ----------
    state : FastSLAMState
        Weighted particle set; the landmarks in `slots` must be seen in every
        particle.
    slots : ndarray of int, shape (L,)
        Landmark slots to include, in this order.

    Returns
    -------
    mean : ndarray, shape (2L,)
        ``sum_k w_k mu^[k]`` with ``mu^[k] = [mu_{s1}^[k], mu_{s2}^[k], ...]``.
    cov : ndarray, shape (2L, 2L)
        Law of total covariance over the particles (the mixture's covariance):
        ``sum_k w_k blockdiag(Sigma^[k]) + sum_k w_k (mu^[k] - mean)(mu^[k] - mean)^T``.
        Each particle's own covariance is block-diagonal (landmarks are
        independent given the path); all correlation between landmarks comes
        from the second term, the spread of the particles' maps.

    References
    ----------
    Course text, Eq. 17.4. Thrun, Burgard & Fox (2005), Chapter 13 (the factored posterior:
    correlations live in the particle set).
    """
    _check_state(state)
    idx = np.asarray(slots)
    if idx.ndim != 1 or (idx.size and idx.dtype.kind not in "iu"):
        raise ValueError(f"slots must be a 1-D array of integers, got shape {idx.shape} dtype {idx.dtype}")
    if np.any(idx < 0) or np.any(idx >= state.capacity):
        raise ValueError(f"slots must lie in [0, {state.capacity})")
    if not state.seen[:, idx].all():
        raise ValueError("every landmark in slots must be seen in every particle")
    w = state.weights
    mu = state.mu[:, idx].reshape(state.n_particles, -1)
    mean = w @ mu
    d = mu - mean
    cov = np.einsum("k,ki,kj->ij", w, d, d)  # spread of the particles' maps
    within = np.einsum("k,klij->lij", w, state.Sigma[:, idx])  # E[Sigma^[k]], one 2x2 block per landmark
    for a in range(idx.size):
        cov[2 * a:2 * a + 2, 2 * a:2 * a + 2] += within[a]
    return mean, cov


# --------------------------------------------------------------------------- whole runs
class FastSLAMResult(NamedTuple):
    """What :func:`run_fastslam` returns.

    Attributes
    ----------
    x_est : ndarray, shape (T+1, 3)
        Weighted mean pose at every step (the filtering estimate).
    x_cov : ndarray, shape (T+1, 3, 3)
        Weighted covariance of the particle poses about `x_est` (heading
        deviations wrapped), for consistency checks (NEES).
    path_best : ndarray, shape (T+1, 3)
        Full path of the final most likely particle, traced back through its
        ancestors (FastSLAM's path posterior sample).
    landmarks : ndarray, shape (N, 2)
        Map of the final most likely particle (slot ``j``; with known
        correspondences slot ``j`` is landmark ``j``).
    landmark_cov : ndarray, shape (N, 2, 2)
        Its landmark covariances.
    seen : ndarray of bool, shape (N,)
        Which slots of that map hold a landmark.
    ess : ndarray, shape (T,)
        Effective sample size after each measurement update, before resampling.
    resampled : ndarray of bool, shape (T,)
        Whether the particles were resampled at each step.
    n_landmarks : ndarray of int, shape (T+1,)
        Landmarks in the most likely particle's map at each step.
    n_ancestors : ndarray of int, shape (T+1,)
        Number of distinct poses at each time among the final particles'
        paths (path degeneracy: it decays to 1 going back in time).
    state : FastSLAMState
        The particle set after the last update (before any final resampling).
    """

    x_est: np.ndarray
    x_cov: np.ndarray
    path_best: np.ndarray
    landmarks: np.ndarray
    landmark_cov: np.ndarray
    seen: np.ndarray
    ess: np.ndarray
    resampled: np.ndarray
    n_landmarks: np.ndarray
    n_ancestors: np.ndarray
    state: FastSLAMState


def _pose_cov(poses, w, mean):
    d = poses - mean
    d[:, 2] = wrap_angle(d[:, 2])
    return np.einsum("k,ki,kj->ij", w, d, d)


def _run_attr(run, name):
    if not hasattr(run, name):
        raise TypeError(f"run must be a LandmarkRun (from slamlib.simulate_landmark_run); it has no {name!r}")
    return getattr(run, name)


def run_fastslam(run, *, n_particles, rng, known=True, M=None, alpha=None, Q=None, p0=None, weight_cov="S",
                 resample_threshold=0.5, capacity=None, max_range=None, fov=None):
    """Run FastSLAM 1.0 over a simulated landmark run.

    Parameters
    ----------
    run : LandmarkRun
        From :func:`slamlib.simulate_landmark_run`: uses ``x0``, ``dt``, the
        commanded controls ``u (T, 2)``, measurements ``z`` (``T`` arrays of
        shape ``(K_t, 2)``) and, with `known`, their landmark ``ids``
        (measurements with id ``-1``, clutter, are skipped then). Measurements
        with a non-positive range (possible with additive range noise close
        to a landmark) carry no usable bearing and are skipped.
    n_particles : int, keyword-only
        Number of particles ``M``.
    rng : numpy.random.Generator, keyword-only
        Source of motion noise and resampling.
    known : bool, keyword-only
        Known correspondences (Table 13.1) or per-particle maximum-likelihood
        association (Table 13.2).
    M : ndarray, shape (2, 2), optional, keyword-only
        Control-noise covariance assumed by the filter; default the run's ``M``.
    alpha : ndarray, shape (6,), optional, keyword-only
        Sample the motion with Table 5.3's parameters instead of `M`.
    Q : ndarray, shape (2, 2), optional, keyword-only
        Measurement noise assumed by the filter; default the run's ``Q``.
    p0 : float, optional, keyword-only
        New-landmark likelihood (unknown correspondences).
    weight_cov : {"S", "Q"}, keyword-only
        ``"Q"`` is the course text's erratum, for demonstrations only.
    resample_threshold : float, keyword-only
        Resample when the effective sample size is below
        ``resample_threshold * M``; ``1.0`` resamples after every update with
        non-uniform weights, as Algorithm 3 does.
    capacity : int, optional, keyword-only
        Initial landmark slots (default: the run's number of landmarks).
    max_range, fov : float, optional, keyword-only
        Perceptual range for the landmark counters of Table 13.2.

    Returns
    -------
    FastSLAMResult
        Estimated trajectory, map, ESS and degeneracy over time.

    References
    ----------
    Course text, Algorithm 3. Thrun, Burgard & Fox (2005), Tables 13.1
    and 13.2.
    """
    n = _as_count(n_particles, "n_particles")
    check_rng(rng)
    _check_weight_cov(weight_cov)
    thr = as_scalar(resample_threshold, "resample_threshold", nonnegative=True)
    x0 = as_array(_run_attr(run, "x0"), "run.x0", (3,))
    dt = as_scalar(_run_attr(run, "dt"), "run.dt", positive=True)
    u = as_array(_run_attr(run, "u"), "run.u", (None, 2))
    zs = _run_attr(run, "z")
    T = u.shape[0]
    if len(zs) != T:
        raise ValueError(f"run.z must hold one measurement array per control ({T}), got {len(zs)}")
    ids = _run_attr(run, "ids") if known else None
    if alpha is not None:
        if M is not None:
            raise ValueError("give at most one of M and alpha")
        alpha = as_array(alpha, "alpha", (6,))
        if np.any(alpha < 0):
            raise ValueError("alpha must be non-negative")
        L = None
    else:
        L = _control_sqrt(as_covariance(_run_attr(run, "M") if M is None else M, "M", 2))
    Q = _check_Q(_run_attr(run, "Q") if Q is None else Q)
    if capacity is None:
        capacity = max(1, int(np.asarray(_run_attr(run, "landmarks")).shape[0]))
    log_p0 = None
    if not known:
        log_p0 = np.log(fastslam_default_p0(Q) if p0 is None else as_scalar(p0, "p0", positive=True))
        if max_range is not None:
            max_range = as_scalar(max_range, "max_range", positive=True)
        half_fov = np.pi if fov is None else 0.5 * as_scalar(fov, "fov", positive=True)

    state = fastslam_initial_state(x0, n, capacity)
    poses_hist = np.empty((T + 1, n, 3))  # row h: the particles after step h - 1's update
    parents = np.empty((T + 1, n), dtype=np.int64)  # row h: ancestors in row h - 1 of row h's particles
    x_est = np.empty((T + 1, 3))
    x_cov = np.zeros((T + 1, 3, 3))
    ess = np.empty(T)
    resampled = np.zeros(T, dtype=bool)
    n_lm = np.zeros(T + 1, dtype=np.int64)
    poses_hist[0] = state.poses
    x_est[0] = state.poses[0]
    identity = np.arange(n)
    parents[:2] = identity
    for t in range(T):
        if L is None:
            poses = sample_motion_model_velocity(state.poses, u[t], dt, alpha, rng=rng)
        else:
            poses = _sample_arc(state.poses, u[t], dt, L, rng)
        state = state._replace(poses=poses)
        zt = _z_matrix(zs[t])
        if known:
            idt = np.asarray(ids[t])
            if idt.shape != (zt.shape[0],) or (idt.size and idt.dtype.kind not in "iu"):
                raise ValueError(f"run.ids[{t}] must be integers of shape ({zt.shape[0]},), got {idt.shape}")
            keep = (zt[:, 0] > 0) & (idt >= 0)  # id -1 marks clutter (slamlib.add_clutter)
            zt, idt = zt[keep], idt[keep]
            if zt.shape[0]:
                idt = idt.astype(np.int64)
                state = _update_known_core(_grow(state, int(idt.max()) + 1), zt, idt, Q, weight_cov, copy=False)
        else:
            state = _update_unknown_core(state, zt, Q, log_p0, weight_cov, max_range, half_fov, copy=False)
        poses_hist[t + 1] = state.poses
        w = np.exp(state.log_weights)  # normalised: logsumexp(log_weights) = 0
        x_est[t + 1], best = _estimate(state.poses, w)
        x_cov[t + 1] = _pose_cov(state.poses, w, x_est[t + 1])
        n_lm[t + 1] = int(state.seen[best].sum())
        ess[t] = effective_sample_size(w)
        if t == T - 1:
            break  # keep the last weights: they pick the final most likely particle
        if ess[t] < thr * n:
            state, parents[t + 2] = fastslam_resample(state, rng=rng)
            resampled[t] = True
        else:
            parents[t + 2] = identity
    return _finish(state, poses_hist, parents, x_est, x_cov, ess, resampled, n_lm)


def _finish(last, poses_hist, parents, x_est, x_cov, ess, resampled, n_lm):
    T = poses_hist.shape[0] - 1
    best = int(np.argmax(last.log_weights))
    lineage = np.arange(last.n_particles)  # each final particle's ancestor in row h
    b = best
    path = np.empty((T + 1, 3))
    n_anc = np.empty(T + 1, dtype=np.int64)
    for h in range(T, -1, -1):
        path[h] = poses_hist[h, b]
        n_anc[h] = np.unique(lineage).size
        if h > 0:
            b = parents[h][b]
            lineage = parents[h][lineage]
    return FastSLAMResult(
        x_est=x_est,
        x_cov=x_cov,
        path_best=path,
        landmarks=last.mu[best].copy(),
        landmark_cov=last.Sigma[best].copy(),
        seen=last.seen[best].copy(),
        ess=ess,
        resampled=resampled,
        n_landmarks=n_lm,
        n_ancestors=n_anc,
        state=last,
    )
