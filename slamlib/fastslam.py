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
The course text's Algorithm 3 writes it
``det(2 pi S)^(-1/2) exp(-1/2 nu Q^-1 nu)``: ``S`` in the normaliser but
``Q^-1`` (the measurement noise) in the exponent. That is an erratum (the
exponent ignores the landmark's own uncertainty and makes the weights far too
peaked); ``weight_cov="text"`` computes the text's formula for
demonstrations only.

FastSLAM 2.0 (Thrun et al. Table 13.3; Montemerlo et al. 2003) samples each
particle's pose from a proposal that includes the step's measurements
(:func:`fastslam2_proposal`, :func:`fastslam2_update_known`,
:func:`fastslam2_update_unknown`; ``run_fastslam(..., version=2)``).

Capacity: a particle set holds ``M x N`` landmark slots of 56 bytes each;
landmark indices must stay below :data:`MAX_LANDMARKS` and a set may not
exceed :data:`MAX_SLOT_BYTES`, so that a wrong index fails with a message
instead of an allocation of many gigabytes.

References
----------
Course text, Eq. 17.4 and Algorithm 3 (FastSLAM 1.0).
Thrun, Burgard & Fox, *Probabilistic Robotics* (2005), Chapter 13 (the
factored posterior), Table 13.1 (known correspondences), Table 13.2 (unknown
correspondences), Table 13.3 (FastSLAM 2.0). Montemerlo et al. (2002),
FastSLAM; Montemerlo et al. (2003), FastSLAM 2.0.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .particle import (_ess, _normalized, _particle_moments, low_variance_resample, normalize_log_weights,
                       particle_gaussian)
from ._checks import (as_array, as_count, as_covariance, as_invertible_covariance, as_poses, as_range_bearing,
                      as_returned, as_rows, as_scalar, as_threshold, check_callable, check_choice, check_field_shapes,
                      check_log_weights, check_rng, check_type)
from .angles import _wrap, wrap_angle
from .motion import _arc, _arc_pose, _control_sqrt, sample_motion_model_velocity, velocity_motion
from .sensors import _landmark_measurement, landmark_from_measurement, landmark_measurement

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
    "FastSLAM2Proposal",
    "fastslam2_proposal",
    "fastslam2_update_known",
    "fastslam2_update_unknown",
    "FastSLAMResult",
    "run_fastslam",
]

_LOG_2PI = float(np.log(2.0 * np.pi))

#: Largest number of landmark slots per particle (landmark indices must be below it).
MAX_LANDMARKS = 100_000
#: Largest memory a particle set's landmark slots may take, ``M x N x 57`` bytes (1 GiB).
MAX_SLOT_BYTES = 2**30
_SLOT_BYTES = 57  # mu 16 + Sigma 32 + counts 8 + seen 1
_MAX_LOG_DET = 600.0  # det Q and 1 / det Q (and those of S) stay far from float64's overflow, e^709
#: Default per-particle validation gate: the 99.999 % point of chi-square with 2 degrees of freedom,
#: ``-2 ln 1e-5`` (about 23.0), the same as EKF SLAM's ``DEFAULT_ALPHA``.
DEFAULT_GATE = float(-2.0 * np.log(1e-5))


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


def _maha_2(nu0, nu1, C00, C01, C11):
    """Squared Mahalanobis distance ``nu^T C^-1 nu`` of 2-vectors, written out."""
    return (nu0 * nu0 * C11 - 2.0 * nu0 * nu1 * C01 + nu1 * nu1 * C00) / (C00 * C11 - C01 * C01)


def _update_core(x, mu, Sigma, z, Q, weight_cov="S", gate=None):
    """Per-particle landmark EKF update and log importance weight (Table 13.1 lines 12-18).

    Returns ``(mu_new, Sigma_new, log_w, outlier)``. With a `gate`, a
    measurement whose squared Mahalanobis distance ``nu^T S^-1 nu`` exceeds it
    is an outlier for that particle: its landmark is left as it was and its
    log weight is the density at the gate (``outlier`` is a boolean mask, else
    ``None``).
    """
    z_hat, _, H = _landmark_measurement(x, mu)  # z_hat = h(mu_j, x), H = h'(mu_j, x)  (Table 13.1 lines 12-13)
    nu0 = z[..., 0] - z_hat[..., 0]
    nu1 = _wrap(z[..., 1] - z_hat[..., 1])
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
    # d = nu^T S^-1 nu
    maha = (nu0 * nu0 * i00 + 2.0 * nu0 * nu1 * i01 + nu1 * nu1 * i11)
    log_norm = -_LOG_2PI - 0.5 * np.log(det)  # log |2 pi S|^-1/2
    if weight_cov == "S":
        # w = |2 pi S|^-1/2 exp(-1/2 nu^T S^-1 nu)  (Table 13.1 line 18)
        log_w = log_norm - 0.5 * maha
    else:
        # the course text's Algorithm 3 as printed: |2 pi S|^-1/2 exp(-1/2 nu Q^-1 nu) (an erratum)
        log_w = log_norm - 0.5 * _maha_2(nu0, nu1, Q[0, 0], 0.5 * (Q[0, 1] + Q[1, 0]), Q[1, 1])
    outlier = None
    if gate is not None:
        outlier = maha > gate  # per-particle validation gate on nu^T S^-1 nu  (chi-square, 2 dof)
        if outlier.any():
            mu_new = np.where(outlier[..., None], mu, mu_new)
            Sigma_new = np.where(outlier[..., None, None], Sigma, Sigma_new)
            # outlier likelihood: the Gaussian density at the gate, |2 pi S|^-1/2 exp(-gate / 2)
            log_w = np.where(outlier, log_norm - 0.5 * gate, log_w)
    return mu_new, Sigma_new, log_w, outlier


#: The choices of ``weight_cov`` and what each means; the one that is gone and what replaced it.
_WEIGHT_COVS = {"S": "innovation covariance", "text": "the course text's erratum"}
_GONE_WEIGHT_COVS = {"Q": "the course text's formula is weight_cov='text' (|2 pi S|^-1/2 exp(-1/2 nu^T Q^-1 nu))"}


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
    x = as_poses(x, "x", ndim=(1, 2))
    z = as_range_bearing(z)
    Q = as_invertible_covariance(Q, "Q", 2, max_log_det=_MAX_LOG_DET)
    return _init_core(x, z, Q)


def fastslam_update_landmark(x, mu, Sigma, z, Q, *, weight_cov="S", log=False, gate=None):
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
    weight_cov : {"S", "text"}, keyword-only
        ``"S"`` (default, correct): ``w = N(nu; 0, S)``,
        ``S = H Sigma H^T + Q``. ``"text"`` computes the course text's
        Algorithm 3 as printed, ``|2 pi S|^-1/2 exp(-1/2 nu^T Q^-1 nu)``
        (``S`` in the normaliser, the measurement noise ``Q`` in the
        exponent), an erratum kept only to demonstrate why it is wrong.
    log : bool, keyword-only
        Return ``log w`` instead of ``w`` (what the filter uses: many
        landmarks in view underflow ``w``, never ``log w``).
    gate : float, optional, keyword-only
        Per-particle validation gate on the squared Mahalanobis distance
        ``d = nu^T S^-1 nu`` (e.g. :data:`DEFAULT_GATE`, the 99.999 % point of
        chi-square with 2 degrees of freedom). Where ``d > gate`` the
        measurement is an outlier for that particle: its landmark is returned
        unchanged and its weight is the outlier likelihood
        ``|2 pi S|^-1/2 exp(-gate / 2)``, the Gaussian's density at the gate.
        Off by default (the homework contract).

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
    x = as_poses(x, "x", ndim=(1, 2))
    batch = x.shape[:-1]
    mu = as_array(mu, "mu", batch + (2,))
    Sigma = as_array(Sigma, "Sigma", batch + (2, 2))
    if not np.allclose(Sigma, _T(Sigma), rtol=1e-9, atol=1e-12 * max(1.0, float(np.abs(Sigma).max(initial=0.0)))):
        raise ValueError("Sigma must hold symmetric 2x2 covariances")
    z = as_range_bearing(z)
    Q = as_invertible_covariance(Q, "Q", 2, max_log_det=_MAX_LOG_DET)
    check_choice(weight_cov, "weight_cov", _WEIGHT_COVS, removed=_GONE_WEIGHT_COVS)
    gate = as_threshold(gate, "gate", optional=True, positive=True, finite=True)
    if np.any(np.hypot(mu[..., 0] - x[..., 0], mu[..., 1] - x[..., 1]) < 1e-9):
        raise ValueError("mu coincides with a particle pose x: the measurement Jacobian is undefined")
    mu_new, Sigma_new, log_w, _ = _update_core(x, mu, Sigma, z, Q, weight_cov, gate)
    return mu_new, Sigma_new, (log_w if log else np.exp(log_w))


# --------------------------------------------------------------------------- shared map storage
# The maps of a particle set live in blocks of _BLOCK landmark slots, in a pool shared by the particles (and by
# the states derived from one another): a particle's map is a row of block indices (its table). Resampling copies
# tables, not maps; an update writes the slots it changes into fresh copies of their blocks (copy-on-write), so a
# block, once written, never changes and states stay pure. A step costs the slots it touches, not the capacity.
_BLOCK = 8  # landmark slots per block (a power of two: _over_block halves it)
_MU, _SIG, _SEEN, _COUNT = slice(0, 2), slice(2, 6), 6, 7  # the float64 fields of a slot: mu, Sigma, seen, count
_NF = 8
# every block's summary, kept with it in the pool: the box of its landmark means (lo x, lo y, hi x, hi y), its
# largest variances in x and in y, and its number of landmarks; a step with unknown correspondences on a large
# map reads the summaries to gather only the blocks it can touch (see _unknown_window). A write marks the
# block's summary stale; it is computed again when next read (steps with known correspondences never read it).
_S_LO, _S_HI, _S_XX, _S_YY, _S_N = slice(0, 2), slice(2, 4), 4, 5, 6
_NS = 7
_EMPTY_SUMMARY = (np.inf, np.inf, -np.inf, -np.inf, -np.inf, -np.inf, 0.0)
#: The slot fields whose maxima _summarize takes: the mean (negated: its minimum), the mean, Sigma_xx, Sigma_yy.
_SUMMARY_FIELDS = np.array([_MU.start, _MU.start + 1, _MU.start, _MU.start + 1, _SIG.start, _SIG.start + 3])


class _Pool:
    """Append-only block storage ``(capacity, _BLOCK, _NF)``; block 0 is the empty block and never written."""

    __slots__ = ("data", "summary", "fresh", "top")

    def __init__(self, capacity):
        n = max(int(capacity), 2)
        self.data = np.empty((n, _BLOCK, _NF))  # only written blocks are ever read
        self.summary = np.empty((n, _NS))  # each block's summary (_summaries)
        self.fresh = np.zeros(n, dtype=bool)  # whether it is up to date
        self.data[0] = 0.0
        self.summary[0] = _EMPTY_SUMMARY
        self.fresh[0] = True
        self.top = 1

    def alloc(self, n):
        """Indices of `n` fresh blocks (growing the storage in place: indices stay valid), or None if full."""
        if self.top + n > self.data.shape[0]:
            return None
        ids = np.arange(self.top, self.top + n, dtype=np.int64)
        self.top += n
        return ids


class _Maps(NamedTuple):
    """A particle set's maps: ``table (M, nb)`` block indices into ``pool``; ``N`` slots per particle."""

    pool: _Pool
    table: np.ndarray
    N: int


def _n_blocks(N):
    return -(-N // _BLOCK)


def _over_block(a, f):
    """``f``-reduction of ``a (n, _BLOCK, ...)`` over its slots, pairwise (several times faster than ``axis=1``;
    ``_BLOCK`` is a power of two)."""
    while a.shape[1] > 1:
        a = f(a[:, :a.shape[1] // 2], a[:, a.shape[1] // 2:])
    return a[:, 0]


def _summarize(pool, ids):
    """Compute the summaries of the pool's blocks `ids` (see :data:`_NS`)."""
    b = np.take(pool.data, ids, axis=0)
    held = b[..., _SEEN] > 0
    # the six extrema of the held slots in one pass, each as a maximum: the means negated (their minima, the
    # box's low corner, are the negated maxima, exactly), the means, Sigma_xx and Sigma_yy
    v = np.take(b, _SUMMARY_FIELDS, axis=2)  # (n, _BLOCK, 6)
    np.negative(v[..., 0:2], out=v[..., 0:2])
    np.copyto(v, -np.inf, where=~held[..., None])
    v = _over_block(v, np.maximum)  # (n, 6)
    out = np.empty((b.shape[0], _NS))
    np.negative(v[:, 0:2], out=out[:, _S_LO])  # an empty block: +inf
    out[:, _S_HI] = v[:, 2:4]
    out[:, _S_XX], out[:, _S_YY] = v[:, 4], v[:, 5]  # the largest Sigma_xx and Sigma_yy
    out[:, _S_N] = np.count_nonzero(held, axis=1)
    pool.summary[ids] = out
    pool.fresh[ids] = True


def _summaries(maps, nb):
    """The summaries ``(M, nb, _NS)`` of the maps' first `nb` block columns, the stale ones computed first."""
    ids = maps.table[:, :nb]
    stale = ~maps.pool.fresh[ids]
    if stale.any():
        _summarize(maps.pool, np.flatnonzero(np.bincount(ids[stale])))  # each once (np.unique is slower)
    return np.take(maps.pool.summary, ids, axis=0)  # (three times faster than indexing with ids)


def _empty_maps(M, N):
    return _Maps(_Pool(64), np.zeros((M, _n_blocks(N)), dtype=np.int64), N)


def _maps_from_dense(mu, Sigma, seen, counts):
    """Block storage holding copies of dense maps (each particle its own blocks)."""
    M, N = seen.shape
    nb = _n_blocks(N)
    d = np.zeros((M, nb * _BLOCK, _NF))
    d[:, :N, _MU] = mu
    d[:, :N, _SIG] = Sigma.reshape(M, N, 4)
    d[:, :N, _SEEN] = seen
    d[:, :N, _COUNT] = counts
    pool = _Pool(1 + M * nb)
    pool.data[1:1 + M * nb] = d.reshape(M * nb, _BLOCK, _NF)  # (the pool has room for two blocks at least)
    pool.top = 1 + M * nb
    return _Maps(pool, np.arange(1, 1 + M * nb, dtype=np.int64).reshape(M, nb), N)


def _split(d):
    """Dense ``(mu, Sigma, seen, counts)`` of gathered slots ``d (..., _NF)`` (a fresh copy: `mu` and
    `Sigma` are views of it)."""
    return d[..., _MU], d[..., _SIG].reshape(d.shape[:-1] + (2, 2)), d[..., _SEEN] > 0, d[..., _COUNT].astype(np.int64)


def _take(maps, cols, rows=None):
    """Slots `cols` of every particle (or of `rows`) as dense copies ``(mu, Sigma, seen, counts)``."""
    table = maps.table if rows is None else maps.table[rows]
    cols = np.asarray(cols, dtype=np.int64)
    return _split(maps.pool.data[table[:, cols // _BLOCK], cols % _BLOCK])


def _particle_map(state, k):
    """Particle `k`'s dense map ``(mu (N, 2), Sigma (N, 2, 2), seen (N,), counts (N,))``."""
    if state._maps is None:
        return tuple(a[k].copy() for a in state._dense)
    maps = state._maps
    d = maps.pool.data[maps.table[k]].reshape(-1, _NF)[:maps.N]
    mu, Sigma, seen, counts = _split(d)
    return np.ascontiguousarray(mu), np.ascontiguousarray(Sigma), seen, counts


def _n_seen(state, k):
    """Number of landmarks in particle `k`'s map."""
    if state._maps is None:
        return int(state._dense[2][k].sum())
    maps = state._maps
    return int(np.count_nonzero(maps.pool.data[maps.table[k], :, _SEEN]))


def _used_slots(maps):
    """One past the last slot any particle may hold a landmark in (a bound: whole blocks)."""
    nz = np.flatnonzero((maps.table != 0).any(axis=0))
    return min(maps.N, (int(nz[-1]) + 1) * _BLOCK) if nz.size else 0


def _compact(maps, extra, inplace=False):
    """The same maps in a pool holding only their live blocks, with room for `extra` more.

    With `inplace` (no other state uses the pool) the pool's own storage is reused when it is large
    enough: fresh memory costs page faults on first write, reused memory does not.
    """
    pool = maps.pool
    live = np.zeros(pool.top, dtype=bool)
    live[maps.table.ravel()] = True
    live[0] = True
    keep = np.flatnonzero(live)
    size = 2 * keep.size + 16 * extra + 64  # room for many steps before the next compaction
    if inplace and size <= pool.data.shape[0]:
        new = pool
        new.data[:keep.size] = np.take(pool.data, keep, axis=0)
        new.summary[:keep.size] = np.take(pool.summary, keep, axis=0)
        new.fresh[:keep.size] = np.take(pool.fresh, keep)
    else:
        new = _Pool(size)
        np.take(pool.data, keep, axis=0, out=new.data[:keep.size])
        np.take(pool.summary, keep, axis=0, out=new.summary[:keep.size])
        np.take(pool.fresh, keep, out=new.fresh[:keep.size])
    new.top = keep.size
    remap = np.cumsum(live) - 1
    return _Maps(new, remap[maps.table], maps.N)


def _put(maps, cols, mu, Sigma, seen, counts, changed=None, inplace=False):
    """`maps` with slots `cols` of every particle set to the dense ``(M, len(cols))`` values.

    Only the pairs (particle, slot) where `changed` (default: all) are written; each block holding one
    is copied to a fresh block first (copy-on-write). With `inplace` the caller gives `maps` up (no other
    state uses its table or its pool's blocks): the table is reused, and a block that no other particle
    refers to is written where it is (the empty block 0 never is).
    """
    cols = np.asarray(cols, dtype=np.int64)
    if cols.size == 0:
        return maps
    M, nb = maps.table.shape
    cb = cols // _BLOCK
    if changed is None:
        ub = np.flatnonzero(np.bincount(cb))  # the blocks written, in every particle
        pk, pb = np.repeat(np.arange(M), ub.size), np.tile(ub, M)
    else:
        kk, cc = np.nonzero(changed)
        if kk.size == 0:
            return maps
        key = kk * nb + cb[cc]
        if np.any(key[1:] < key[:-1]):
            key = np.sort(key)
        key = key[np.r_[True, key[1:] != key[:-1]]]  # the (particle, block) pairs written (np.unique is slow)
        pk, pb = np.divmod(key, nb)
        ub = np.flatnonzero(np.bincount(pb))
    if inplace:  # a block id lives in one column of the table: shared iff it appears twice there
        blocks = maps.table[pk, pb]
        ids = np.sort(maps.table[:, ub].ravel())  # every reference to a block of these columns
        refs = np.searchsorted(ids, blocks, "right") - np.searchsorted(ids, blocks, "left")
        cow = (blocks == 0) | (refs > 1)
        pk, pb = pk[cow], pb[cow]
    ids = maps.pool.alloc(pk.size)
    if ids is None:
        maps = _compact(maps, pk.size, inplace)
        inplace = True  # the compacted table is a new array
        ids = maps.pool.alloc(pk.size)
    table = maps.table if inplace else maps.table.copy()
    data = maps.pool.data
    if ids.size:
        np.take(data, table[pk, pb], axis=0, out=data[ids[0]:ids[0] + ids.size])  # copy on write (ids: a range)
        table[pk, pb] = ids
    if changed is not None:  # only the changed slots' values
        mu, Sigma, seen, counts = mu[kk, cc], Sigma[kk, cc], seen[kk, cc], counts[kk, cc]
    d = np.empty(mu.shape[:-1] + (_NF,))
    d[..., _MU] = mu
    d[..., _SIG] = Sigma.reshape(mu.shape[:-1] + (4,))
    d[..., _SEEN] = seen
    d[..., _COUNT] = counts
    if changed is None:
        written = table[:, cb]
        data[written, cols % _BLOCK] = d
    else:
        written = table[kk, cb[cc]]
        data[written, cols[cc] % _BLOCK] = d
    maps.pool.fresh[written] = False
    return _Maps(maps.pool, table, maps.N)


# --------------------------------------------------------------------------- the particle set
class FastSLAMState:
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
    is landmark ``j``. A state behaves as the named tuple of these six
    arrays (``FastSLAMState(poses, mu, Sigma, seen, counts, log_weights)``,
    iteration, ``_replace``) and is never modified: the step functions
    return new states.

    Inside, the maps are stored the way Montemerlo et al. share them between
    particles: blocks of landmark slots in a pool, each particle a table of
    block indices. Resampling copies the tables, an update copies only the
    blocks it writes (copy-on-write), so a step costs the landmarks it
    touches, not the capacity ``N``. Each block also keeps a summary (the box
    of its landmark means, its largest variances, its number of landmarks),
    so a step with unknown correspondences on a large map gathers only the
    blocks that some particle may reach, and those holding the first free
    slots, instead of every landmark. The dense arrays ``mu``, ``Sigma``,
    ``seen`` and ``counts`` are assembled (read-only) when first read.

    References
    ----------
    Thrun, Burgard & Fox (2005), Chapter 13 (a particle: path sample and N
    landmark Gaussians; Section 13.8, efficient implementation with shared
    landmark trees), Table 13.2 (counters). Montemerlo et al. (2002).
    """

    __slots__ = ("poses", "log_weights", "_maps", "_dense")
    _fields = ("poses", "mu", "Sigma", "seen", "counts", "log_weights")

    def __init__(self, poses, mu, Sigma, seen, counts, log_weights):
        self.poses = poses
        self.log_weights = log_weights
        self._dense = (mu, Sigma, seen, counts)
        self._maps = None

    @classmethod
    def _from_maps(cls, poses, maps, log_weights):
        new = cls.__new__(cls)
        new.poses, new.log_weights, new._maps, new._dense = poses, log_weights, maps, None
        return new

    def _blocks(self):
        """The block storage of the maps (built once from dense arrays given by a caller)."""
        if self._maps is None:
            self._maps = _maps_from_dense(*(np.asarray(a) for a in self._dense))
        return self._maps

    def _arrays(self):
        if self._dense is None:
            maps = self._maps
            M = maps.table.shape[0]
            d = maps.pool.data[maps.table].reshape(M, -1, _NF)[:, :maps.N]
            dense = _split(d)
            for a in dense:
                a.setflags(write=False)
            self._dense = dense
        return self._dense

    mu = property(lambda self: self._arrays()[0], doc="Landmark means, shape (M, N, 2).")
    Sigma = property(lambda self: self._arrays()[1], doc="Landmark covariances, shape (M, N, 2, 2).")
    seen = property(lambda self: self._arrays()[2], doc="Which slots hold a landmark, shape (M, N).")
    counts = property(lambda self: self._arrays()[3], doc="Observation counters, shape (M, N).")

    def __iter__(self):
        return iter((self.poses, self.mu, self.Sigma, self.seen, self.counts, self.log_weights))

    def __len__(self):
        return 6

    def __getitem__(self, i):
        return tuple(self)[i]

    def _replace(self, **fields):
        """A copy with some of the six fields replaced (as for a named tuple)."""
        unknown = set(fields) - set(self._fields)
        if unknown:
            raise ValueError(f"FastSLAMState has no field(s) {sorted(unknown)}")
        if not set(fields) & {"mu", "Sigma", "seen", "counts"}:  # poses or weights only: share the maps
            new = FastSLAMState.__new__(FastSLAMState)
            new.poses = fields.get("poses", self.poses)
            new.log_weights = fields.get("log_weights", self.log_weights)
            new._maps, new._dense = self._maps, self._dense
            return new
        return FastSLAMState(*(fields.get(f, getattr(self, f)) for f in self._fields))

    def _asdict(self):
        return dict(zip(self._fields, self))

    def __repr__(self):
        return f"FastSLAMState(n_particles={self.n_particles}, capacity={self.capacity})"

    @property
    def n_particles(self) -> int:
        """Number of particles ``M``."""
        return self.poses.shape[0]

    @property
    def capacity(self) -> int:
        """Landmark slots per particle ``N``."""
        return self._maps.N if self._maps is not None else np.shape(self._dense[2])[1]

    @property
    def weights(self) -> np.ndarray:
        """Normalised weights ``exp(log_weights)``, shape ``(M,)``."""
        return normalize_log_weights(self.log_weights)


def _check_state(state, name="state"):
    check_type(state, FastSLAMState, name, "from fastslam_initial_state")
    if state._maps is not None:
        M = state._maps.table.shape[0]
        check_field_shapes(state, name, {"poses": (M, 3), "log_weights": (M,)})
        return state
    seen = state._dense[2]
    if np.ndim(seen) != 2:
        raise ValueError(f"{name}.seen must have shape (M, N), got {np.shape(seen)}")
    M, N = np.shape(seen)
    if M == 0:
        raise ValueError(f"{name} must hold at least one particle, got seen of shape {np.shape(seen)}")
    shapes = {"poses": (M, 3), "mu": (M, N, 2), "Sigma": (M, N, 2, 2), "counts": (M, N), "log_weights": (M,)}
    return check_field_shapes(state, name, shapes)


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
        updates when full), at most :data:`MAX_LANDMARKS`, with
        ``n_particles x capacity x 57`` bytes at most :data:`MAX_SLOT_BYTES`.

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
    M = as_count(n_particles, "n_particles", minimum=1)
    N = as_count(capacity, "capacity", minimum=1)
    _check_capacity(M, N, "capacity")
    x0 = x0.copy()
    x0[2] = wrap_angle(x0[2])
    # every particle's map: the empty block in every place (shared storage, see FastSLAMState)
    return FastSLAMState._from_maps(np.tile(x0, (M, 1)), _empty_maps(M, N), np.full(M, -np.log(M)))


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


def _sample_arc(poses, u, dt, L, rng, motion=None):
    # u^[k] = u + N(0, M); x_t^[k] = arc(x_{t-1}^[k], u^[k])  (Table 13.1 line 4)
    u_k = u + rng.standard_normal((poses.shape[0], 2)) @ L.T
    if motion is not None:  # a pluggable motion model (e.g. slamlib.AckermannModel)
        return _motion_pose(motion, poses, u_k, dt)
    return velocity_motion(poses, u_k, dt)[0]


def _motion_pose(motion, x, u, dt):
    """``motion(x, u, dt)[0]``, through the model's ``pose`` method when it has one (no Jacobians computed)."""
    pose = getattr(motion, "pose", None)
    return pose(x, u, dt) if callable(pose) else motion(x, u, dt)[0]


def _rounds(ids):
    """Split observation indices so that no landmark appears twice in a round."""
    order = np.argsort(ids, kind="stable")
    sid = ids[order]
    first = np.r_[True, sid[1:] != sid[:-1]]
    start = np.maximum.accumulate(np.where(first, np.arange(sid.size), 0))
    occurrence = np.empty(ids.size, dtype=np.int64)
    occurrence[order] = np.arange(sid.size) - start
    return [np.flatnonzero(occurrence == r) for r in range(int(occurrence.max(initial=-1)) + 1)]


def _check_capacity(M, N, name):
    """Refuse a particle set whose landmark slots would exceed the documented limits."""
    if N > MAX_LANDMARKS:
        raise ValueError(f"{name} needs {N} landmark slots per particle; at most MAX_LANDMARKS = {MAX_LANDMARKS} "
                         "are supported (landmark indices must be below it)")
    if M * N * _SLOT_BYTES > MAX_SLOT_BYTES:
        raise ValueError(f"{name}: {M} particles x {N} landmark slots would take "
                         f"{M * N * _SLOT_BYTES / 2**30:.2f} GiB; the limit is MAX_SLOT_BYTES = "
                         f"{MAX_SLOT_BYTES / 2**30:.0f} GiB (fewer particles or landmarks)")


def _grow(state, need, name="ids"):
    """Copy of `state` with at least `need` landmark slots."""
    M, N = state.n_particles, state.capacity
    if need <= N:
        return state
    _check_capacity(M, need, name)
    N2 = min(max(need, 2 * N), MAX_LANDMARKS)
    if M * N2 * _SLOT_BYTES > MAX_SLOT_BYTES:
        N2 = need
    maps = state._blocks()  # slots beyond N in the last block are empty: no write reaches them
    extra = np.zeros((M, _n_blocks(N2) - maps.table.shape[1]), dtype=np.int64)  # the empty block
    grown = _Maps(maps.pool, np.concatenate([maps.table, extra], axis=1), N2)
    return FastSLAMState._from_maps(state.poses, grown, state.log_weights)


def _ids_arg(ids, K):
    ids = np.asarray(ids)
    if ids.shape != (K,) or (ids.size and ids.dtype.kind not in "iu"):
        raise ValueError(f"ids must be integers of shape ({K},), got {ids.shape} dtype {ids.dtype}")
    if np.any(ids < 0):
        raise ValueError("ids must be non-negative landmark indices")
    if ids.size and ids.max() >= MAX_LANDMARKS:
        raise ValueError(f"ids must be below MAX_LANDMARKS = {MAX_LANDMARKS} (landmark slots per particle), "
                         f"got {int(ids.max())}")
    return ids.astype(np.int64)


def fastslam_update_known(state, z, ids, Q, *, weight_cov="S", gate=None, return_outliers=False):
    """Incorporate a step's measurements with known correspondences, all particles at once.

    Parameters
    ----------
    state : FastSLAMState
        Particle set after the motion update.
    z : ndarray, shape (K, 2)
        Measurements ``[r, phi]`` of the step (``K = 0`` allowed).
    ids : ndarray of int, shape (K,)
        Landmark index of each measurement (the correspondences ``c_t``),
        below :data:`MAX_LANDMARKS`; slots are grown if an index exceeds the
        capacity (within :data:`MAX_SLOT_BYTES`).
    Q : ndarray, shape (2, 2)
        Measurement-noise covariance.
    weight_cov : {"S", "text"}, keyword-only
        Importance-weight covariance; ``"text"`` is the course text's erratum,
        for demonstrations only (see :func:`fastslam_update_landmark`).
    gate : float, optional, keyword-only
        Per-particle chi-square gate on ``nu^T S^-1 nu`` (see
        :func:`fastslam_update_landmark`); off by default. With a gate the
        landmark counters ``counts`` go up for an accepted sighting and down
        for a rejected one, and a landmark whose counter reaches 0 is
        discarded (``seen`` False), as in :func:`run_fastslam`'s
        `reinit_lost`.
    return_outliers : bool, keyword-only
        Also return the outlier mask.

    Returns
    -------
    FastSLAMState
        Updated landmark Gaussians, counters and normalised log weights. A
        landmark seen for the first time is initialised (its factor ``p0`` is
        the same for every particle and cancels); measurements of seen
        landmarks multiply the weight by ``N(nu; 0, S)``.
    outliers : ndarray of bool, shape (M, K)
        Only with `return_outliers`: which measurement the gate rejected in
        which particle (measurements with a non-positive range are never
        outliers; they are skipped).

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
    z = as_rows(z, "z", 2)
    ids = _ids_arg(ids, z.shape[0])
    Q = as_invertible_covariance(Q, "Q", 2, max_log_det=_MAX_LOG_DET)
    check_choice(weight_cov, "weight_cov", _WEIGHT_COVS, removed=_GONE_WEIGHT_COVS)
    gate = as_threshold(gate, "gate", optional=True, positive=True, finite=True)
    keep = z[:, 0] > 0
    outliers = np.zeros((state.n_particles, z.shape[0]), dtype=bool)
    if not keep.any():
        return (state, outliers) if return_outliers else state
    state = _grow(state, int(ids[keep].max()) + 1)
    new, out = _update_known_core(state, z[keep], ids[keep], Q, weight_cov, gate=gate)
    outliers[:, keep] = out
    return (new, outliers) if return_outliers else new


def _drop_lost(seen, counts, j):
    """Discard, in each particle, the landmarks ``j`` whose gated sightings have caught up with their
    accepted ones (``i_j <= 0``): the slot becomes unseen, and the next sighting re-creates it.

    With known correspondences the per-particle gate keeps gross sightings out of a landmark, and the
    counter ``i_j`` (Table 13.2's landmark existence evidence: +1 for a sighting the gate accepts, -1
    for one it rejects) lets a landmark recover from a wrong first sighting: a landmark placed by a
    misidentified sighting rejects every true one, the first rejection discards it, and the next
    sighting places it anew. A landmark confirmed by many sightings survives as many rejections.
    ``j (k,)`` distinct landmark indices; writes into `seen` and `counts`.
    """
    lost = seen[:, j] & (counts[:, j] <= 0)  # (M, k)
    if lost.any():
        seen[:, j] = seen[:, j] & ~lost  # discard landmark j when i_j <= 0  (Table 13.2)
        counts[:, j] = np.where(lost, 0, counts[:, j])


def _update_known_core(state, z, ids, Q, weight_cov, copy=True, gate=None, reinit=True):
    """Known-correspondence update of all particles; ``copy=False`` writes into `state`'s arrays.

    Returns the new state and the outlier mask ``(M, K)`` of the per-particle
    gate (all False without a `gate`).
    """
    maps = state._blocks()
    cols, lid = np.unique(ids, return_inverse=True)  # the slots this step touches, and each one's column
    mu, Sigma, seen, counts = _take(maps, cols)
    log_w, outliers = _known_local(state.poses, mu, Sigma, seen, counts, z, lid, Q, weight_cov, gate,
                                   state.log_weights, reinit=reinit)
    maps = _put(maps, cols, mu, Sigma, seen, counts, inplace=not copy)
    return FastSLAMState._from_maps(state.poses, maps, _normalized(log_w)), outliers


def _known_local(poses, mu, Sigma, seen, counts, z, ids, Q, weight_cov, gate, log_w, reinit=True):
    """The body of :func:`_update_known_core` on dense maps ``(M, C)`` (written in place); `ids` are
    columns of them. Returns the (unnormalised) log weights and the outlier mask ``(M, K)``. With a
    `gate` and `reinit`, a landmark whose counter reaches 0 is discarded (:func:`_drop_lost`)."""
    log_w = log_w.copy()
    M = poses.shape[0]
    outliers = np.zeros((M, ids.size), dtype=bool)
    x = poses[:, None, :]  # (M, 1, 3)
    for obs in _rounds(ids):
        j, zk = ids[obs], z[obs]  # (k,), (k, 2)
        new = ~seen[:, j]  # (M, k): never seen before  (Table 13.1 line 6)
        fresh, known = new.all(axis=0), (~new).all(axis=0)
        if np.all(fresh | known):  # the usual case: all particles agree on which landmarks are new
            if known.any():
                jk = j[known]
                mu_u, Sigma_u, lw, out = _update_core(x, mu[:, jk], Sigma[:, jk], zk[known], Q, weight_cov, gate)
                mu[:, jk], Sigma[:, jk] = mu_u, Sigma_u  # (Table 13.1 lines 12-17)
                log_w = log_w + lw.sum(axis=1)  # (Table 13.1 line 18), several measurements multiply
                if out is not None:
                    outliers[:, obs[known]] = out
                    counts[:, jk] -= 2 * out  # an outlier is evidence against the landmark: i_j - 1 with the + 1 below
            if fresh.any():
                # mu_j = h^-1(z, x), Sigma_j = H^-1 Q H^-T; w = p0, equal for all particles  (Table 13.1 lines 7-10)
                mu[:, j[fresh]], Sigma[:, j[fresh]] = _init_core(x, zk[fresh], Q)
        else:
            mu_init, Sigma_init = _init_core(x, zk, Q)
            # the update must not see the placeholder mean of an unseen slot
            mu_old = np.where(new[..., None], mu_init, mu[:, j])
            Sigma_old = np.where(new[..., None, None], Sigma_init, Sigma[:, j])
            mu_upd, Sigma_upd, lw, out = _update_core(x, mu_old, Sigma_old, zk, Q, weight_cov, gate)
            mu[:, j] = np.where(new[..., None], mu_old, mu_upd)
            Sigma[:, j] = np.where(new[..., None, None], Sigma_old, Sigma_upd)
            log_w = log_w + np.where(new, 0.0, lw).sum(axis=1)  # new: w = p0 for all  (Table 13.1 line 10)
            if out is not None:
                out = out & ~new
                outliers[:, obs] = out
                counts[:, j] -= 2 * out
        seen[:, j] = True
        counts[:, j] += 1
        if gate is not None and reinit:
            _drop_lost(seen, counts, j)
    return log_w, outliers


def _fastslam_steps(init, update):
    """Checked wrappers of a caller's ``fastslam_init_landmark`` and ``fastslam_update_landmark`` (None stays None).

    Each is called with the contract's arguments on copies; the update's weight
    comes back as ``log w`` (``-inf`` for a weight of zero).
    """
    init_step = update_step = None
    if init is not None:
        def init_step(x, z, Q):
            k = x.shape[0]
            return as_returned(init(x.copy(), z.copy(), Q.copy()), "fastslam_init_landmark", (k, 2), (k, 2, 2))
    if update is not None:
        def update_step(x, mu, Sigma, z, Q):
            k = x.shape[0]
            mu_new, Sigma_new, w = as_returned(update(x.copy(), mu.copy(), Sigma.copy(), z.copy(), Q.copy()),
                                               "fastslam_update_landmark", (k, 2), (k, 2, 2), (k,), nonnegative=(2,))
            with np.errstate(divide="ignore"):
                return mu_new, Sigma_new, np.log(w)
    return init_step, update_step


def _stepwise_known_core(state, z, ids, Q, weight_cov, gate, init, update, reinit=True):
    """:func:`_update_known_core` one measurement at a time, writing into `state`'s arrays.

    ``init(x, z, Q) -> (mu, Sigma)`` and ``update(x, mu, Sigma, z, Q) -> (mu_new,
    Sigma_new, log_w)`` (from :func:`_fastslam_steps`) replace the cores where
    given; with None the cores do that part (and only they apply the `gate`).
    """
    maps = state._blocks()
    cols, ids = np.unique(ids, return_inverse=True)  # the slots this step touches; ids: their columns
    mu, Sigma, seen, counts = _take(maps, cols)
    x = state.poses
    log_w = state.log_weights.copy()
    outliers = np.zeros((x.shape[0], ids.size), dtype=bool)
    for k, (zk, j) in enumerate(zip(z, ids)):
        new = ~seen[:, j]  # never seen before  (Table 13.1 line 6)
        old = ~new
        if old.any():
            if update is None:
                mu_u, Sigma_u, lw, out = _update_core(x[old], mu[old, j], Sigma[old, j], zk, Q, weight_cov, gate)
            else:
                (mu_u, Sigma_u, lw), out = update(x[old], mu[old, j], Sigma[old, j], zk, Q), None
            mu[old, j], Sigma[old, j] = mu_u, Sigma_u  # (Table 13.1 lines 12-17)
            log_w[old] += lw  # (Table 13.1 line 18)
            if out is not None:
                outliers[old, k] = out
                counts[old, j] -= 2 * out  # an outlier is evidence against the landmark: i_j - 1 with the + 1 below
        if new.any():
            # mu_j = h^-1(z, x), Sigma_j = H^-1 Q H^-T; w = p0, equal for all particles  (Table 13.1 lines 7-10)
            mu[new, j], Sigma[new, j] = (_init_core if init is None else init)(x[new], zk, Q)
        seen[:, j] = True
        counts[:, j] += 1
        if gate is not None and update is None and reinit:
            _drop_lost(seen, counts, np.array([j]))
    check_log_weights(log_w, "the log-weights after fastslam_update_landmark's weights")
    maps = _put(maps, cols, mu, Sigma, seen, counts, inplace=True)
    return FastSLAMState._from_maps(state.poses, maps, _normalized(log_w)), outliers


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
    Q = as_invertible_covariance(Q, "Q", 2, max_log_det=_MAX_LOG_DET)
    gate = as_threshold(gate, "gate", positive=True, finite=True)
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
    weight_cov : {"S", "text"}, keyword-only
        Importance weight of a matched measurement; ``"text"`` is the course
        text's erratum (see :func:`fastslam_update_landmark`). The
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
    z = as_rows(z, "z", 2)
    Q = as_invertible_covariance(Q, "Q", 2, max_log_det=_MAX_LOG_DET)
    check_choice(weight_cov, "weight_cov", _WEIGHT_COVS, removed=_GONE_WEIGHT_COVS)
    log_p0, max_range, half_fov = _unknown_options(Q, p0, max_range, fov)
    return _update_unknown_core(state, z, Q, log_p0, weight_cov, max_range, half_fov)


def _unknown_options(Q, p0, max_range, fov):
    """Checked ``log p0``, perceptual range and half field of view of the unknown-correspondence updates."""
    log_p0 = np.log(fastslam_default_p0(Q) if p0 is None else as_scalar(p0, "p0", positive=True))
    if max_range is not None:
        max_range = as_scalar(max_range, "max_range", positive=True)
    half_fov = np.pi if fov is None else 0.5 * as_scalar(fov, "fov", positive=True)
    if fov is not None and max_range is None:
        raise ValueError("fov needs max_range (the perceptual range) as well")
    return log_p0, max_range, half_fov


def _update_unknown_core(state, z, Q, log_p0, weight_cov, max_range, half_fov, copy=True):
    """Unknown-correspondence update; ``copy=False`` may write into `state`'s arrays."""
    z = z[z[:, 0] > 0]
    M = state.n_particles
    if z.shape[0] == 0 and max_range is None:  # nothing to associate or prune: the maps stay as they are
        return FastSLAMState._from_maps(state.poses, state._blocks(), _normalized(state.log_weights.copy()))
    # the blocks some particle may reach (a superset of _candidates' landmarks), or every block when pruning
    # reads every landmark in view
    reach = None if max_range is not None or z.shape[0] == 0 else (
        lambda s: _summaries_in_reach(s, state.poses, z, lambda var: _reach1(var, Q, log_p0)))
    maps, win, (mu, Sigma, seen, counts) = _unknown_window(state, z.shape[0], "ids", reach)
    log_w = state.log_weights.copy()
    matched = np.zeros_like(seen)
    x = state.poses
    rows = np.arange(M)
    used = np.flatnonzero(seen.any(axis=0))
    # slots at and beyond hi stay empty in every particle during this step (a new landmark takes the
    # particle's first free slot, at most one more per measurement)
    hi = min(seen.shape[1], (int(used[-1]) + 1 if used.size else 0) + z.shape[0])
    cols = _candidates(x, mu[:, :hi], Sigma[:, :hi], seen[:, :hi], z, Q, log_p0)
    pos = np.full(hi, -1)
    pos[cols] = np.arange(cols.size)  # column of each candidate slot in z_hat, S and ll
    # the pose is fixed within the step: predict every candidate once, then refresh only what changes
    # z_hat_j = h(mu_j, x), H_j = h'(mu_j, x), S_j = H_j Sigma_j H_j^T + Q for every candidate j  (Table 13.2)
    mu_safe = np.where(seen[:, cols, None], mu[:, cols], x[:, None, :2] + 1.0)  # keep h defined on empty slots
    z_hat, _, H = _landmark_measurement(x[:, None, :], mu_safe)
    _, S_parts, _ = _innovation(H, Sigma[:, cols], Q)
    S = np.stack(S_parts, axis=-1)  # (M, C, 3): S00, S01, S11

    fresh = np.zeros(cols.size, dtype=bool)  # columns whose z_hat and S changed during the step
    if _PREFILTER:  # the candidates of each measurement (see _within_reach), with every refreshed column
        near = _within_reach(z, z_hat[..., 0], z_hat[..., 1], seen[:, cols], np.sqrt(S[..., 0]), np.sqrt(S[..., 2]),
                             _reach_factor(Q, log_p0))

    def refresh(k, jk):
        zh, _, Hk = _landmark_measurement(x[k], mu[k, jk])
        z_hat[k, pos[jk]] = zh
        S[k, pos[jk]] = np.stack(_innovation(Hk, Sigma[k, jk], Q)[1], axis=-1)
        fresh[pos[jk]] = True

    for i, zk in enumerate(z):
        ci = np.flatnonzero(near[i] | fresh) if _PREFILTER else slice(None)
        if _PREFILTER and ci.size == 0:  # no landmark of any particle can beat p0: a new landmark everywhere
            is_new = np.ones(M, dtype=bool)
        else:
            sn = seen[:, cols[ci]]
            zh, Sc = z_hat[:, ci], S[:, ci]
            nu1 = _wrap(zk[1] - zh[..., 1])
            # w_j = N(nu_j; 0, S_j)  (Table 13.2)
            ll = np.where(sn, _log_gauss_2(zk[0] - zh[..., 0], nu1, Sc[..., 0], Sc[..., 1], Sc[..., 2]), -np.inf)
            c = np.argmax(ll, axis=1)  # ties: smallest index (the candidates are in increasing order)
            best = ll[rows, c]
            j = cols[ci][c]
            is_new = best < log_p0  # c_hat = new landmark when p0 beats every w_j  (Table 13.2)
        old = ~is_new
        if old.any():
            k, jk = rows[old], j[old]
            # EKF update of landmark c_hat  (Table 13.2)
            mu_n, Sigma_n, lw, _ = _update_core(x[k], mu[k, jk], Sigma[k, jk], zk, Q, weight_cov)
            mu[k, jk], Sigma[k, jk] = mu_n, Sigma_n
            counts[k, jk] += 1  # i_j = i_j + 1  (Table 13.2)
            matched[k, jk] = True
            # w = max_j w_j  (Table 13.2); the text's erratum puts Q^-1 in the exponent
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
    changed = matched  # updated and new landmarks, and below those that lost a count
    if max_range is not None:
        seen, counts, miss = _prune(x, mu, seen, counts, matched, max_range, half_fov)
        changed = changed | miss
    maps = _put(maps, win, mu, Sigma, seen, counts, changed=changed, inplace=not copy)
    return FastSLAMState._from_maps(x, maps, _normalized(log_w))


def _reach1(var, Q, log_p0):
    """FastSLAM 1.0's margin of :func:`_candidates` for landmarks with ``tr Sigma = var``."""
    c0 = max(-log_p0 - _LOG_2PI - 0.5 * math.log(Q[0, 0] * Q[1, 1] - Q[0, 1] * Q[1, 0]), 0.0) + 1.0
    return np.sqrt(2.0 * c0 * (var + Q[0, 0]))


def _candidates(x, mu, Sigma, seen, z, Q, log_p0):
    """The slots a step's maximum-likelihood association must score (FastSLAM 1.0), in increasing order.

    Every slot that is free in some particle (a new landmark may take it during the
    step), and every landmark that some particle predicts within reach of the step's
    ranges. For any other landmark ``w_j < p0 / e`` for every measurement, so it can
    never be chosen: ``nu^T S^-1 nu >= nu_r^2 / S_rr``, ``det S >= det Q``
    (``S = H Sigma H^T + Q``) and ``S_rr <= Sigma_xx + Sigma_yy + Q_rr``.
    """
    free = ~seen.all(axis=0)
    if z.shape[0] == 0 or seen.shape[1] == 0:
        return np.flatnonzero(free)
    r = np.hypot(mu[..., 0] - x[:, None, 0], mu[..., 1] - x[:, None, 1])
    reach = _reach1(Sigma[..., 0, 0] + Sigma[..., 1, 1], Q, log_p0)
    near = seen & (r >= z[:, 0].min() - reach) & (r <= z[:, 0].max() + reach)
    return np.flatnonzero(free | near.any(axis=0))


#: Per-measurement candidates in the unknown-correspondence updates (False: every landmark of the step's
#: candidate list is scored for every measurement, the reference the tests compare with).
_PREFILTER = True
#: Largest norm of the FastSLAM 2.0 proposal's mean of the control noise (in its standard deviations) for
#: which the per-measurement candidates hold; beyond it a measurement scores every candidate.
_ETA_REACH = 10.0


def _reach_factor(Q, log_p0):
    """``t + _ETA_REACH + 1``, where ``t^2 = 2 (-log p0 - log 2 pi - 1/2 log det Q)``: a landmark whose
    innovation exceeds ``t`` standard deviations in range or bearing has ``N(nu; 0, S) < p0`` for any ``S >= Q``."""
    t2 = 2.0 * (-log_p0 - _LOG_2PI - 0.5 * math.log(Q[0, 0] * Q[1, 1] - Q[0, 1] * Q[1, 0]))
    return math.sqrt(max(t2, 0.0)) + _ETA_REACH + 1.0


def _within_reach(z, zb0, zb1, seen, s0, s1, f):
    """``(K, C)``: may candidate ``j`` win measurement ``i`` in some particle?

    ``zb0, zb1 (M, C)`` are the predicted range and bearing (``zb1`` in
    ``[-pi, pi)``), ``s0, s1 (M, C)`` bounds on the standard deviations of the
    innovation in range and bearing (FastSLAM 1.0: ``sqrt(S_aa)``). A pair whose
    innovation exceeds ``f`` of them in either coordinate has
    ``nu^T S^-1 nu >= nu_a^2 / S_aa > t^2`` (see :func:`_reach_factor`), so its
    likelihood is below ``p0`` and it can never be chosen. FastSLAM 2.0 passes
    radii beyond which a pair fails :func:`_could_win` in that particle
    (:func:`_pair_radii`) with ``f = 1``.
    """
    K, C = z.shape[0], zb0.shape[1]
    t0, t1 = f * s0, f * s1
    i, j = _range_pairs(z, zb0, seen, t0)
    out = np.zeros((K, C), dtype=bool)
    if i.size:
        out[i, j] = _pairs_within(z, i, j, zb0, zb1, seen, t0, t1)
    return out


def _range_pairs(z, zb0, seen, t0):
    """The (measurement, candidate) pairs ``(i, j)`` that may pass :func:`_within_reach`'s test with the range
    radii ``t0 (M, C)``, from a cheaper necessary condition, each candidate on its own: the range must lie in
    the union of the particles' intervals ``[zb0 - t0, zb0 + t0]``, widened by far more than the rounding of
    either test (relative 1e-9 of the largest magnitude involved) so that it never drops a pair the exact
    test keeps."""
    lo = np.where(seen, zb0 - t0, np.inf).min(axis=0)
    hi = np.where(seen, zb0 + t0, -np.inf).max(axis=0)
    slack = 1e-9 * (1.0 + np.abs(z[:, 0]).max(initial=0.0) + np.where(seen, np.abs(zb0) + t0, 0.0).max(axis=0))
    return np.nonzero((z[:, 0, None] >= lo - slack) & (z[:, 0, None] <= hi + slack))  # (pairs,)


def _pairs_within(z, i, j, zb0, zb1, seen, t0, t1):
    """:func:`_within_reach`'s exact test of the pairs ``(i, j)`` (measurement, candidate), every particle,
    with the radii ``t0, t1 (M, C)``: ``(pairs,)`` bool."""
    y0 = np.abs(z[i, 0, None] - zb0.T[j])  # (pairs, M)
    # |wrap(phi_i - zb1)| <= t1 with both bearings in [-pi, pi]: |phi_i - zb1| <= t1 or >= 2 pi - t1
    y1 = np.abs(_wrap(z[:, 1])[i, None] - zb1.T[j])
    t1 = t1.T[j]
    return (seen.T[j] & (y0 <= t0.T[j]) & ((y1 <= t1) | (y1 >= 2.0 * np.pi - t1))).any(axis=1)


#: Maps of at most this many blocks are gathered whole by :func:`_unknown_window`: below it, reading the
#: blocks' summaries costs more than it saves.
_WINDOW_BLOCKS = 32


def _unknown_window(state, K, name, reach=None):
    """The maps grown for `K` new landmarks per particle and, as dense copies, the slots a step with unknown
    correspondences can touch: those some particle uses and the next `K` (a new landmark takes the first
    free slot). Returns ``(maps, cols, (mu, Sigma, seen, counts))``, `cols` the slots gathered.

    With `reach`, a function of the blocks' summaries ``(M, nb, _NS)`` that returns the blocks some particle
    may reach ``(nb,)``, and a map of more than :data:`_WINDOW_BLOCKS` blocks, only those blocks are
    gathered, and for every particle the blocks holding its first `K` free slots, so the window's first free
    slot of a particle is its map's. The summaries are read instead of every slot.
    """
    maps = state._blocks()
    M = state.n_particles
    W = min(maps.N, _used_slots(maps) + K)
    nb = _n_blocks(W)  # whole blocks; slots beyond `used` are empty
    if reach is not None and nb > _WINDOW_BLOCKS:
        summary, d = _summaries(maps, nb), None
        need = int(summary[..., _S_N].sum(axis=1).max(initial=0)) + K
    else:
        summary, d = None, np.take(maps.pool.data, maps.table[:, :nb], axis=0).reshape(M, -1, _NF)
        need = int(np.count_nonzero(d[..., _SEEN], axis=1).max(initial=0)) + K
    if need > maps.N:
        maps = _grow(state, need, name)._maps
        W = min(maps.N, _used_slots(maps) + K)
    nbW = _n_blocks(W)
    if summary is None:
        if nbW > nb:
            d = np.take(maps.pool.data, maps.table[:, :nbW], axis=0).reshape(M, -1, _NF)
        return maps, np.arange(W), _split(d[:, :W])
    summary = _summaries(maps, nbW) if nbW > nb else summary[:, :nbW]
    free = _BLOCK - summary[..., _S_N]  # (the last block's slots beyond W count too: they come last)
    some = np.flatnonzero((free > 0).any(axis=0))  # the blocks where some particle has a free slot
    free = free[:, some]
    before = np.cumsum(free, axis=1) - free  # each particle's free slots in the earlier blocks
    keep = reach(summary)
    keep[some[((free > 0) & (before < K)).any(axis=0)]] = True  # the blocks of every particle's first K free slots
    blocks = np.flatnonzero(keep)
    d = np.take(maps.pool.data, maps.table[:, blocks], axis=0).reshape(M, -1, _NF)
    win = (blocks[:, None] * _BLOCK + np.arange(_BLOCK)).ravel()
    cut = int(np.searchsorted(win, W))  # only the last block can reach beyond the window
    return maps, win[:cut], _split(d[:, :cut])


def _prune(x, mu, seen, counts, matched, max_range, half_fov):
    """Landmark counters of Table 13.2: a landmark in the perceptual range that no measurement matched
    loses a count and is discarded below zero."""
    mu_safe = np.where(seen[..., None], mu, x[:, None, :2] + 1.0)
    z_hat, _, _ = _landmark_measurement(x[:, None, :], mu_safe)
    in_view = seen & (z_hat[..., 0] <= max_range) & (np.abs(z_hat[..., 1]) <= half_fov)
    miss = in_view & ~matched
    counts = counts - miss  # i_j = i_j - 1 for unmatched landmarks in range  (Table 13.2)
    drop = seen & (counts < 0)  # discard landmark j when i_j < 0  (Table 13.2)
    seen = seen & ~drop
    return seen, np.where(seen, counts, 0), miss


# --------------------------------------------------------------------------- FastSLAM 2.0
# The proposal of Table 13.3 linearises the measurement about the predicted pose x_hat = g(x_{t-1}, u_t).
# The motion noise here lives in control space (u_t + N(0, M), as in FastSLAM 1.0 and the simulator), so its
# pose-space covariance R_t = V M V^T (V = dg/du) has rank 2 and no inverse; Table 13.3eeds
# R_t^-1. The same Gaussian is computed in the coordinates eta of the control noise, u_t + L eta with
# L L^T = M and eta ~ N(0, I): the measurement's Jacobian with respect to eta is G = H_x V L, the
# proposal over eta has information P = I + sum_i G_i^T Q_i^-1 G_i and mean P^-1 b with
# b = sum_i G_i^T Q_i^-1 (z_i - z_bar_i), and the sampled pose is the exact arc g(x_{t-1}, u_t + L eta).
# Mapped to pose space to first order this is Table 13.3's N(mu_x, Sigma_x) with R_t = V M V^T (the tests
# check it against the Woodbury form of lines 10-11); all algebra is on 2x2 blocks.


def _inv_sym(C00, C01, C11):
    """Determinant and inverse ``(i00, i01, i11)`` of symmetric 2x2 blocks."""
    det = C00 * C11 - C01 * C01
    return det, (C11 / det, -C01 / det, C00 / det)


def _gauss_parts(g00, g01, g10, g11, Qj, r0, r1):
    """:func:`_gauss_terms` from the components of ``G``."""
    det, (i00, i01, i11) = _inv_sym(*Qj)
    c00 = g00 * i00 + g10 * i01  # C = G^T Qj^-1
    c01 = g00 * i01 + g10 * i11
    c10 = g01 * i00 + g11 * i01
    c11 = g01 * i01 + g11 * i11
    A = (c00 * g00 + c01 * g10, c00 * g01 + c01 * g11, c10 * g01 + c11 * g11)
    b = (c00 * r0 + c01 * r1, c10 * r0 + c11 * r1)
    log_n = -0.5 * (r0 * r0 * i00 + 2.0 * r0 * r1 * i01 + r1 * r1 * i11) - _LOG_2PI - 0.5 * np.log(det)
    return A, b, log_n


def _gauss_terms(G, Qj, r0, r1):
    """``A = G^T Qj^-1 G`` (3 components), ``b = G^T Qj^-1 r`` and ``log N(r; 0, Qj)``, written out."""
    return _gauss_parts(G[..., 0, 0], G[..., 0, 1], G[..., 1, 0], G[..., 1, 1], Qj, r0, r1)


def _predict_terms(x_hat, B, mu, Sigma, Q):
    """Table 13.3for every (particle, landmark): ``z_bar``, ``G = H_x V L`` and ``Q_j``.

    ``x_hat (M, 3)``, ``B = V L (M, 3, 2)``, ``mu (M, K, 2)``, ``Sigma (M, K, 2, 2)``.
    """
    z_bar, Hx, Hm = _landmark_measurement(x_hat[:, None, :], mu)  # z_bar = h(mu_j, x_hat), H_x, H_m
    _, Qj, _ = _innovation(Hm, Sigma, Q)  # Q_j = Q_t + H_m Sigma_j H_m^T
    # G = H_x V L: the measurement's Jacobian with respect to the control noise eta, G_ic = sum_k Hx_ik B_kc (the
    # four components at once)
    b = B[:, None]
    G = Hx[..., :, 0, None] * b[..., 0, None, :] + Hx[..., :, 1, None] * b[..., 1, None, :] \
        + Hx[..., :, 2, None] * b[..., 2, None, :]
    return z_bar, G, Qj


def _sample_eta(P, b, rng, n):
    """Draw ``eta ~ N(P^-1 b, P^-1)`` for 2x2 information blocks ``P = (P00, P01, P11)``; one
    ``rng.standard_normal((n, 2))``."""
    _, (c00, c01, c11) = _inv_sym(*P)  # Sigma_eta = P^-1  (Table 13.3)
    m0 = c00 * b[0] + c01 * b[1]  # mean = P^-1 b
    m1 = c01 * b[0] + c11 * b[1]
    l00 = np.sqrt(c00)  # Cholesky factor of P^-1
    l10 = c01 / l00
    l11 = np.sqrt(np.maximum(c11 - l10 * l10, 0.0))
    e = rng.standard_normal((n, 2))
    eta = np.empty((n, 2))
    eta[:, 0] = m0 + l00 * e[:, 0]  # eta ~ N(mean, P^-1)
    eta[:, 1] = m1 + l10 * e[:, 0] + l11 * e[:, 1]
    return eta


def _posterior_log_factor(P, b):
    """``1/2 b^T P^-1 b - 1/2 log det P``: with ``sum_i log N(r_i; 0, Q_i)`` the log of
    ``N(r; 0, G G^T + Q)`` (matrix determinant lemma and Woodbury)."""
    det, (c00, c01, c11) = _inv_sym(*P)
    return 0.5 * (b[0] * b[0] * c00 + 2.0 * b[0] * b[1] * c01 + b[1] * b[1] * c11) - 0.5 * np.log(det)


def _motion_terms(x_prev, u, dt, L, motion=None):
    """``x_hat = g(x_{t-1}, u_t)`` and ``B = V L`` (Table 13.3; ``V = dg/du``)."""
    x_hat, _, V = _arc(x_prev, u, dt) if motion is None else motion(x_prev, u, dt)
    B = np.einsum("...ij,jk->...ik", V, L)
    return x_hat, B


def _move(x_prev, u, dt, L, eta, motion=None):
    """The sampled pose: the exact arc (or `motion`) of the control ``u + L eta``."""
    if motion is not None:
        return _motion_pose(motion, x_prev, u + eta @ L.T, dt)
    return _arc_pose(x_prev, u + eta @ L.T, dt)


class FastSLAM2Proposal(NamedTuple):
    """FastSLAM 2.0's proposal for one measurement of a known landmark (see :func:`fastslam2_proposal`).

    Attributes
    ----------
    u_mean : ndarray, shape (M, 2)
        Mean of the noisy control ``u_t + L eta`` the pose is moved by.
    u_cov : ndarray, shape (M, 2, 2)
        Its covariance ``L P^-1 L^T``.
    x_mean : ndarray, shape (M, 3)
        First-order pose-space mean ``x_hat + V (u_mean - u_t)`` (Table 13.3).
    x_cov : ndarray, shape (M, 3, 3)
        First-order pose-space covariance ``V u_cov V^T`` (Table 13.3, with ``R_t = V M V^T``).
    log_w : ndarray, shape (M,)
        Log importance weight ``log N(z - z_bar; 0, L)``,
        ``L = H_x R_t H_x^T + H_m Sigma H_m^T + Q`` (Table 13.3).
    """

    u_mean: np.ndarray
    u_cov: np.ndarray
    x_mean: np.ndarray
    x_cov: np.ndarray
    log_w: np.ndarray


def fastslam2_proposal(x, u, dt, M, mu, Sigma, z, Q):
    """FastSLAM 2.0's pose proposal and importance weight for one measurement of a known landmark.

    Parameters
    ----------
    x : ndarray, shape (P, 3)
        Particle poses at ``t - 1``.
    u : ndarray, shape (2,)
        Commanded control ``[v, omega]``.
    dt : float
        Duration of the control (seconds).
    M : ndarray, shape (2, 2)
        Control-noise covariance: the motion is the exact arc of ``u + N(0, M)``.
    mu : ndarray, shape (P, 2)
        Each particle's mean of the measured landmark.
    Sigma : ndarray, shape (P, 2, 2)
        Its covariance.
    z : ndarray, shape (2,)
        Measurement ``[r, phi]``.
    Q : ndarray, shape (2, 2)
        Measurement-noise covariance.

    Returns
    -------
    FastSLAM2Proposal
        The Gaussian the pose is drawn from, in control space (what the
        filter samples: ``x_t = g(x_{t-1}, u_mean + chol(u_cov) n)``) and to
        first order in pose space, and the log weight.

    Notes
    -----
    With ``x_hat = g(x_{t-1}, u)``, ``z_bar = h(mu, x_hat)``, ``H_x``, ``H_m``
    its Jacobians, ``V = dg/du`` and ``R_t = V M V^T``: the proposal is
    ``N(x_hat + Sigma_x H_x^T Q_j^-1 (z - z_bar), Sigma_x)`` with
    ``Sigma_x = (H_x^T Q_j^-1 H_x + R_t^-1)^-1`` and
    ``Q_j = Q + H_m Sigma H_m^T`` (Table 13.3), computed in the
    coordinates of the control noise because ``R_t`` is singular here.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 13.3
    Eqs. 13.45-13.53. Montemerlo et al. (2003), FastSLAM 2.0.
    """
    x = as_poses(x, "x", ndim=(1, 2))
    if x.ndim != 2:
        raise ValueError(f"x must have shape (P, 3), got {x.shape}")
    n = x.shape[0]
    u = as_array(u, "u", (2,))
    dt = as_scalar(dt, "dt", nonnegative=True)
    L = _control_sqrt(as_covariance(M, "M", 2))
    mu = as_array(mu, "mu", (n, 2))
    Sigma = as_array(Sigma, "Sigma", (n, 2, 2))
    z = as_range_bearing(z)
    Q = as_invertible_covariance(Q, "Q", 2, max_log_det=_MAX_LOG_DET)
    x_hat, B = _motion_terms(x, u, dt, L)
    if np.any(np.hypot(mu[:, 0] - x_hat[:, 0], mu[:, 1] - x_hat[:, 1]) < 1e-9):
        raise ValueError("mu coincides with a predicted pose: the measurement Jacobian is undefined")
    z_bar, G, Qj = _predict_terms(x_hat, B, mu[:, None], Sigma[:, None], Q)
    r0 = z[0] - z_bar[:, 0, 0]
    r1 = _wrap(z[1] - z_bar[:, 0, 1])
    A, b, log_n = _gauss_terms(G[:, 0], tuple(q[:, 0] for q in Qj), r0, r1)
    P = (1.0 + A[0], A[1], 1.0 + A[2])
    _, (c00, c01, c11) = _inv_sym(*P)
    eta_mean = np.stack([c00 * b[0] + c01 * b[1], c01 * b[0] + c11 * b[1]], axis=-1)
    eta_cov = np.stack([np.stack([c00, c01], -1), np.stack([c01, c11], -1)], -2)
    u_mean = u + eta_mean @ L.T
    u_cov = L @ eta_cov @ L.T
    x_mean = x_hat + np.einsum("kij,kj->ki", B, eta_mean)
    x_mean[:, 2] = wrap_angle(x_mean[:, 2])
    x_cov = B @ eta_cov @ _T(B)
    log_w = log_n + _posterior_log_factor(P, b)
    return FastSLAM2Proposal(u_mean, 0.5 * (u_cov + _T(u_cov)), x_mean, 0.5 * (x_cov + _T(x_cov)), log_w)


def fastslam2_update_known(state, u, dt, z, ids, Q, *, M, rng, gate=None, return_outliers=False):
    """One FastSLAM 2.0 step with known correspondences: pose proposal, landmark updates, weights.

    Parameters
    ----------
    state : FastSLAMState
        Particle set at ``t - 1`` (FastSLAM 2.0 moves the particles itself:
        its proposal needs the measurements).
    u : ndarray, shape (2,)
        Commanded control ``[v, omega]``.
    dt : float
        Duration of the control (seconds).
    z : ndarray, shape (K, 2)
        Measurements ``[r, phi]`` taken at ``t`` (``K = 0`` allowed: then the
        step is FastSLAM 1.0's motion sample, with the same draw).
    ids : ndarray of int, shape (K,)
        Landmark index of each measurement, below :data:`MAX_LANDMARKS`.
    Q : ndarray, shape (2, 2)
        Measurement-noise covariance.
    M : ndarray, shape (2, 2), keyword-only
        Control-noise covariance (the motion is the exact arc of ``u + N(0, M)``).
    rng : numpy.random.Generator, keyword-only
        Draws one ``standard_normal((n_particles, 2))``.
    gate : float, optional, keyword-only
        Per-particle chi-square gate on ``nu^T L^-1 nu`` (``L`` the
        innovation covariance with the pose uncertainty, Table 13.3):
        a measurement beyond it is an outlier for that particle: left out of
        its proposal, no landmark update, weight the density at the gate; the
        landmark counters work as in :func:`fastslam_update_known`.
    return_outliers : bool, keyword-only
        Also return the outlier mask ``(M, K)``.

    Returns
    -------
    FastSLAMState
        Sampled poses, updated maps and normalised log weights.

    Notes
    -----
    The proposal of every particle uses all measurements of landmarks the
    particle has seen (first occurrence of each landmark in the step): its
    information adds up over them (the several-measurement form of
    Table 13.3), and the weight is their joint marginal
    likelihood given ``x_{t-1}``, ``N(r; 0, G G^T + Q_stack)``, which for one
    measurement is Table 13.3with ``L`` evaluated at the predicted
    pose. The landmarks are then updated by FastSLAM 1.0's EKF at the
    sampled pose (the map given the path). A landmark new to a particle does
    not inform its proposal and is initialised at the sampled pose. A second measurement of the same
    landmark in one step is applied afterwards as a FastSLAM 1.0 update at
    the sampled pose, weighted by ``N(nu; 0, S)``; that keeps the weight
    exact (proposal and target share the first measurement).

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 13.3 (with known correspondences),
    Eqs. 13.45-13.61. Montemerlo et al. (2003), FastSLAM 2.0.
    """
    _check_state(state)
    u = as_array(u, "u", (2,))
    dt = as_scalar(dt, "dt", nonnegative=True)
    z = as_rows(z, "z", 2)
    ids = _ids_arg(ids, z.shape[0])
    Q = as_invertible_covariance(Q, "Q", 2, max_log_det=_MAX_LOG_DET)
    L = _control_sqrt(as_covariance(M, "M", 2))
    check_rng(rng)
    gate = as_threshold(gate, "gate", optional=True, positive=True, finite=True)
    keep = z[:, 0] > 0
    if keep.any():
        state = _grow(state, int(ids[keep].max()) + 1)
    new, out = _update2_known_core(state, u, dt, L, z[keep], ids[keep], Q, rng, gate=gate)
    outliers = np.zeros((state.n_particles, z.shape[0]), dtype=bool)
    outliers[:, keep] = out
    return (new, outliers) if return_outliers else new


def _update2_known_core(state, u, dt, L, z, ids, Q, rng, gate=None, copy=True, motion=None, reinit=True):
    """FastSLAM 2.0 step with known correspondences; returns the state and the outlier mask ``(M, K)``."""
    n = state.n_particles
    x_prev = state.poses
    outliers = np.zeros((n, ids.size), dtype=bool)
    x_hat, B = _motion_terms(x_prev, u, dt, L, motion)
    if ids.size == 0:
        eta = rng.standard_normal((n, 2))  # eta ~ N(0, I): _sample_eta with P = I, b = 0, bit for bit
        return state._replace(poses=_move(x_prev, u, dt, L, eta, motion)), outliers
    maps = state._blocks()
    cols, ids = np.unique(ids, return_inverse=True)  # the slots this step touches; ids: their columns
    mu, Sigma, seen, counts = _take(maps, cols)
    log_w = state.log_weights.copy()
    rounds = _rounds(ids)
    first = rounds[0]
    j, zk = ids[first], z[first]
    known = seen[:, j]  # (M, k)
    mu_j = np.where(known[..., None], mu[:, j], x_hat[:, None, :2] + 1.0)  # keep h defined on empty slots
    Sigma_j = np.where(known[..., None, None], Sigma[:, j], np.eye(2))
    z_bar, G, Qj = _predict_terms(x_hat, B, mu_j, Sigma_j, Q)
    r0 = zk[:, 0] - z_bar[..., 0]  # z_t - z_bar_j  (Table 13.3)
    r1 = _wrap(zk[:, 1] - z_bar[..., 1])
    A, b, log_n = _gauss_terms(G, Qj, r0, r1)
    use = known
    if gate is not None:
        # d = nu^T L^-1 nu with L = G G^T + Q_j, each measurement alone  (Table 13.3)
        L00 = G[..., 0, 0] ** 2 + G[..., 0, 1] ** 2 + Qj[0]
        L01 = G[..., 0, 0] * G[..., 1, 0] + G[..., 0, 1] * G[..., 1, 1] + Qj[1]
        L11 = G[..., 1, 0] ** 2 + G[..., 1, 1] ** 2 + Qj[2]
        out = known & (_maha_2(r0, r1, L00, L01, L11) > gate)
        if out.any():
            use = known & ~out
            # outlier likelihood: the density of N(0, L) at the gate
            log_out = -0.5 * gate - _LOG_2PI - 0.5 * np.log(L00 * L11 - L01 * L01)
            log_w = log_w + np.where(out, log_out, 0.0).sum(axis=1)
            outliers[:, first] = out
    # information of the proposal over eta: P = I + sum_i G_i^T Q_i^-1 G_i, b = sum_i G_i^T Q_i^-1 r_i
    P = (1.0 + np.where(use, A[0], 0.0).sum(axis=1), np.where(use, A[1], 0.0).sum(axis=1),
         1.0 + np.where(use, A[2], 0.0).sum(axis=1))
    bs = (np.where(use, b[0], 0.0).sum(axis=1), np.where(use, b[1], 0.0).sum(axis=1))
    # w = N(r; 0, G M G^T + Q_stack), the marginal likelihood given x_{t-1}  (Table 13.3)
    log_w = log_w + np.where(use, log_n, 0.0).sum(axis=1) + _posterior_log_factor(P, bs)
    x = _move(x_prev, u, dt, L, _sample_eta(P, bs, rng, n), motion)  # x_t ~ N(mu_x, Sigma_x)
    xs = x[:, None, :]
    # landmark EKF at the sampled pose
    mu_u, Sigma_u, _, _ = _update_core(xs, mu_j, Sigma_j, zk, Q)
    mu_i, Sigma_i = _init_core(xs, zk, Q)  # new landmark at the sampled pose
    new = ~known
    mu[:, j] = np.where(use[..., None], mu_u, np.where(new[..., None], mu_i, mu[:, j]))
    Sigma[:, j] = np.where(use[..., None, None], Sigma_u, np.where(new[..., None, None], Sigma_i, Sigma[:, j]))
    seen[:, j] = True
    counts[:, j] += use | new  # i_j = i_j + 1, or 1 for a new landmark
    if gate is not None:
        counts[:, j] -= outliers[:, first]  # i_j = i_j - 1 for a gated sighting
        if reinit:
            _drop_lost(seen, counts, j)
    if len(rounds) > 1:  # repeated landmarks: FastSLAM 1.0 updates at the sampled pose
        rest = np.concatenate(rounds[1:])
        log_w, out2 = _known_local(x, mu, Sigma, seen, counts, z[rest], ids[rest], Q, "S", gate,
                                   _normalized(log_w), reinit=reinit)
        outliers[:, rest] = out2
    maps = _put(maps, cols, mu, Sigma, seen, counts, inplace=not copy)
    return FastSLAMState._from_maps(x, maps, _normalized(log_w)), outliers


def fastslam2_update_unknown(state, u, dt, z, Q, *, M, rng, p0=None, max_range=None, fov=None):
    """One FastSLAM 2.0 step with unknown correspondences (per-particle maximum-likelihood association).

    Parameters
    ----------
    state : FastSLAMState
        Particle set at ``t - 1``.
    u : ndarray, shape (2,)
        Commanded control ``[v, omega]``.
    dt : float
        Duration of the control (seconds).
    z : ndarray, shape (K, 2)
        Measurements ``[r, phi]`` taken at ``t``, associated one after the other.
    Q : ndarray, shape (2, 2)
        Measurement-noise covariance.
    M : ndarray, shape (2, 2), keyword-only
        Control-noise covariance.
    rng : numpy.random.Generator, keyword-only
        Draws one ``standard_normal((n_particles, 2))``.
    p0 : float, optional, keyword-only
        New-landmark likelihood; default :func:`fastslam_default_p0` of `Q`.
    max_range, fov : float, optional, keyword-only
        Perceptual range for the landmark counters, as in
        :func:`fastslam_update_unknown`.

    Returns
    -------
    FastSLAMState
        Sampled poses, updated maps and normalised log weights.

    Notes
    -----
    For each measurement in turn and each particle, every landmark ``j`` the
    particle holds is scored by ``pi_j = N(z - z_bar_j - G_j m; 0, L_j)``,
    ``L_j = G_j C G_j^T + Q_j``, where ``N(m, C)`` is the particle's
    proposal over the control noise given the measurements associated so far
    (the sequential form of Table 13.3with the pose uncertainty
    in the score); the correspondence is ``argmax`` over the landmarks and
    ``p0``, the weight is multiplied by the winner, and a
    matched measurement adds its information to the proposal. A landmark
    takes at most one measurement per step and particle, and a landmark
    started in this step is not a candidate until the next one (it is placed
    after the pose is drawn). The pose is then drawn once, matched landmarks
    get the EKF update at the sampled pose and new ones are initialised there; the counters follow Table 13.2.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 13.3. Montemerlo et al. (2003).
    """
    _check_state(state)
    u = as_array(u, "u", (2,))
    dt = as_scalar(dt, "dt", nonnegative=True)
    z = as_rows(z, "z", 2)
    Q = as_invertible_covariance(Q, "Q", 2, max_log_det=_MAX_LOG_DET)
    L = _control_sqrt(as_covariance(M, "M", 2))
    check_rng(rng)
    log_p0, max_range, half_fov = _unknown_options(Q, p0, max_range, fov)
    return _update2_unknown_core(state, u, dt, L, z, Q, log_p0, max_range, half_fov, rng)


def _could_win(F, log_p0, reach):
    """``(pairs, M)``: may a (measurement, candidate) pair win in a particle while the proposal's mean of the
    control noise stays within `reach` (``|m| <= reach``)?

    `F` holds the pairs' fields (see :func:`_associate2`): ``y = z - z_bar`` (``y_phi`` wrapped), the norms
    ``|G_a|`` of the rows of ``G``, ``s_a = |G_a|^2 + Q_j,aa`` and ``-log 2 pi - 1/2 log det Q_j``. The score
    is ``log N(r; 0, L)`` with ``r = y - G m`` (bearing wrapped), ``L = G C G^T + Q_j`` and ``C <= I`` (the
    proposal's information is at least the prior's ``I``): ``det L >= det Q_j``, ``L_aa <= s_a`` and
    ``|r_a| >= |y_a| - |G_a| |m|``, so ``r^T L^-1 r >= r_a^2 / L_aa >= (|y_a| - |G_a| reach)_+^2 / s_a``. A
    pair whose bound on the score is below ``p0`` (with a slack far above rounding) can never be chosen.
    """
    d0 = np.maximum(np.abs(F[4]) - F[9] * reach, 0.0)
    d1 = np.maximum(np.abs(F[5]) - F[10] * reach, 0.0)
    maha = np.maximum(d0 * d0 / F[11], d1 * d1 / F[12])
    return ~(F[13] - 0.5 * maha < log_p0 - 1e-6 * (1.0 + abs(log_p0)))  # (NaN: kept)


def _pair_radii(d, var, b_xy, b_th, Q, log_p0, reach):
    """Radii ``(r0, r1)`` of the innovation in range and bearing beyond which a candidate fails :func:`_could_win`,
    from bounds on its fields that need neither ``z_bar``'s Jacobians nor ``Q_j`` (``(M, C)``, for
    :func:`_within_reach` with ``f = 1``).

    ``d`` is each particle's predicted range of the candidate, ``var`` its ``tr Sigma``, ``b_xy``, ``b_th``
    ``(M, 1)`` the norms of the position and heading rows of ``B = V L``. With ``h_r``, ``h_phi`` the rows of
    ``H_m`` (``|h_r| = 1``, ``|h_phi| = 1/d``): ``|G_r| <= g_r = b_xy``, ``|G_phi| <= g_phi = b_xy / d + b_th``,
    ``s_a = |G_a|^2 + Q_j,aa <= v_a = g_a^2 + Q_aa + |h_a|^2 tr Sigma`` and ``det Q_j >= det Q``, so a pair that
    passes :func:`_could_win` has ``(|y_a| - g_a reach)_+^2 / v_a <= T^2 = 2 (-log 2 pi - 1/2 log det Q - log p0
    + slack)``, ``|y_a| <= g_a reach + T sqrt(v_a)``, on both axes; the radii are widened by far more than the
    rounding of either test (at ``d = 0``, ``r1 = inf``: any bearing).
    """
    t = _radii_t(Q, log_p0)
    return _range_radius(d, var, b_xy, Q, t, reach), _bearing_radius(d, var, b_xy, b_th, Q, t, reach)


def _radii_t(Q, log_p0):
    """``T`` of :func:`_pair_radii`."""
    c = -_LOG_2PI - 0.5 * np.log(Q[0, 0] * Q[1, 1] - Q[0, 1] * Q[1, 0])
    return np.sqrt(np.maximum(2.0 * (c - log_p0 + 2e-6 * (1.0 + np.abs(log_p0))), 0.0))


def _range_radius(d, var, b_xy, Q, t, reach):
    """``r0`` of :func:`_pair_radii` (``t``: :func:`_radii_t`)."""
    return (reach * b_xy + t * np.sqrt(b_xy * b_xy + Q[0, 0] + var)) * (1.0 + 1e-9) + 1e-9 * (1.0 + d)


def _bearing_radius(d, var, b_xy, b_th, Q, t, reach):
    """``r1`` of :func:`_pair_radii` (``t``: :func:`_radii_t`)."""
    inv_d = np.zeros(d.shape)
    np.divide(1.0, d, out=inv_d, where=d > 0)
    g1 = b_xy * inv_d + b_th
    r1 = (reach * g1 + t * np.sqrt(g1 * g1 + Q[1, 1] + var * (inv_d * inv_d))) * (1.0 + 1e-9) + 1e-9
    r1[d <= 0] = np.inf
    return r1


def _associate2(x_hat, B, mu, Sigma, seen, log_w, z, Q, log_p0, cols, near):
    """FastSLAM 2.0's sequential maximum-likelihood association of a step's measurements (Table 13.3 with
    unknown correspondences) over the candidate slots `cols`.

    ``near (K, C)`` (or None: all) marks each measurement's candidates (:func:`_within_reach`); ``cols=None``:
    none at all (the measurements leave the weights as they are). Returns the
    proposal's information ``P`` and ``b``, ``match (M, K)`` (slot, -1 for a new landmark) and the log
    weights, or None when the proposal's mean moved beyond :data:`_ETA_REACH`, where `near` no longer holds.

    The score of candidate ``j`` given the proposal ``N(m, C)``, ``m = P^-1 b``, ``C = P^-1``, of the
    measurements associated so far is computed in information form: with ``y_j = z - z_bar_j``,
    ``A_j = G_j^T Q_j^-1 G_j`` and ``b_j = G_j^T Q_j^-1 y_j`` (what a match adds to the proposal),
    ``log N(y_j; G_j m, G_j C G_j^T + Q_j) = log N(y_j; 0, Q_j) + phi(P + A_j, b + b_j) - phi(P, b)``
    (:func:`_posterior_log_factor`: matrix determinant lemma and Woodbury, as for the weight of known
    correspondences). Everything but ``phi`` is computed before the loop over the measurements, for every
    (measurement, candidate) pair at once. With `near`, a pair is kept in a particle only if it may win there
    (:func:`_could_win`, per particle, a far tighter test than `near`), and each measurement's kept
    candidates are packed, per particle in increasing order, into as many rows as the particle with the most
    of them needs (about one): every array of the loop is ``(rows, M)``, and a pass of the loop scores one
    measurement's candidates in every particle with a few dozen NumPy calls. The measurements stay
    sequential: one sees the proposal and the landmarks the earlier ones matched. A candidate left out scores
    below ``p0``, so the choices, ``P`` and ``b`` are those of scoring every candidate with the innovation
    ``wrap(y_j - G_j m)``, bit for bit; the weights equal them to rounding (the bearing's innovation is
    wrapped at the predicted pose only, which changes nothing for a candidate that can win).
    """
    n, K = x_hat.shape[0], z.shape[0]
    log_w = log_w.copy()
    rows = np.arange(n)
    S = np.zeros((5, n))  # the proposal over eta: information P = (P00, P01, P11) and b = (b0, b1), prior N(0, I)
    S[0] = S[2] = 1.0
    match = np.full((n, K), -1, dtype=np.int64)  # landmark slot of each measurement, -1: new
    if cols is None or not cols.size:  # no candidate at all: nothing to associate, every measurement a new landmark
        for _ in range(K if cols is not None else 0):
            log_w += log_p0  # w = p0 for every measurement
        return [S[0], S[1], S[2]], [S[3], S[4]], match, log_w
    C = cols.size
    sn = seen[:, cols]
    mu_s = mu[:, cols]  # a copy; empty slots moved next to the particle to keep h defined there
    if not sn.all():
        mu_s[~sn] = np.broadcast_to(x_hat[:, None, :2] + 1.0, mu_s.shape)[~sn]
    z_bar, G, Qj = _predict_terms(x_hat, B, mu_s, Sigma[:, cols], Q)  # Table 13.3 for every candidate
    # the candidates' fields, shape (nf, C, M): h00, h10, h01, h11, zb0, zb1, q00, q11, q01 and, for
    # _could_win, |G_r|, |G_phi|, |G_r|^2 + q00, |G_phi|^2 + q11, -log 2 pi - 1/2 log det Q_j
    nf = 9 if near is None else 14
    FC = np.empty((nf, C, n))
    FC[0:4] = G.reshape(n, C, 4).T[[0, 2, 1, 3]]
    FC[4:6] = z_bar.T
    FC[6], FC[7], FC[8] = Qj[0].T, Qj[2].T, Qj[1].T
    if near is not None:
        gg = FC[0:2] * FC[0:2] + FC[2:4] * FC[2:4]  # |G_a|^2
        np.sqrt(gg, out=FC[9:11])
        np.add(gg, FC[6:8], out=FC[11:13])
        FC[13] = -_LOG_2PI - 0.5 * np.log(FC[6] * FC[7] - FC[8] * FC[8])
    ii, jj = np.nonzero(near) if near is not None else (np.repeat(np.arange(K), C), np.tile(np.arange(C), K))
    off = np.searchsorted(ii, np.arange(K + 1))  # measurement i's pairs: off[i]:off[i + 1], candidates ascending
    F = np.take(FC, jj, axis=1)  # (nf, pairs, M)
    F[4] = (z[ii, 0])[:, None] - F[4]  # y = z_i - z_bar_j (innovation at the predicted pose)
    F[5] = _wrap((z[ii, 1])[:, None] - F[5])
    ok = sn.T[jj]  # (pairs, M): the particle holds the candidate
    if near is not None:
        ok &= _could_win(F, log_p0, _ETA_REACH)
    # pack: per particle, each measurement's kept pairs first (in increasing order), then the others
    order = np.argsort(2 * ii[:, None] + ~ok, axis=0, kind="stable")  # (pairs, M)
    cum = np.zeros((ii.size + 1, n), dtype=np.int64)
    np.cumsum(ok, axis=0, out=cum[1:])
    width = (cum[off[1:]] - cum[off[:-1]]).max(axis=1)  # (K,): rows each measurement needs
    poff = np.zeros(K + 1, dtype=np.int64)
    np.cumsum(width, out=poff[1:])
    src = np.repeat(off[:-1] - poff[:-1], width) + np.arange(poff[-1])  # each packed row's row of `order`
    idx = order[src]  # (packed rows, M): the pair of each packed entry
    Fp = F[:9, idx, rows]  # (9, packed rows, M)
    col = np.where(ok[idx, rows], jj[idx], C)  # its candidate column; C (never available) where left out
    # what a match adds to the proposal, G^T Q_j^-1 G and G^T Q_j^-1 y, and log N(y; 0, Q_j)  (Table 13.3)
    A_, b_, log_n = _gauss_parts(Fp[0], Fp[2], Fp[1], Fp[3], (Fp[6], Fp[8], Fp[7]), Fp[4], Fp[5])
    info = np.stack(A_ + b_)  # (5, packed rows, M)
    # a landmark takes at most one measurement per step and particle: only a particle that keeps the same
    # column for two measurements needs the availability of its columns followed through the loop
    held = col[col < C] * n + np.broadcast_to(rows, col.shape)[col < C]
    avail = None
    if held.size and np.bincount(held).max() > 1:
        avail = np.zeros((C + 1, n), dtype=bool)
        avail[:C] = sn.T
    else:
        log_n = np.where(col < C, log_n, -np.inf)
    phi = _posterior_log_factor(S[0:3], S[3:5])  # phi(P, b) of the proposal so far
    S_seen = np.empty((K, 5, n))  # the proposal each measurement is scored against (the check of _ETA_REACH)
    J = np.zeros((K, n), dtype=np.int64)  # the packed row of each measurement's choice
    won = np.zeros((K, n), dtype=bool)  # and whether it beat p0
    for i in range(K):
        a, e = int(poff[i]), int(poff[i + 1])
        S_seen[i] = S
        if e == a:  # no landmark can beat p0: new everywhere
            log_w += log_p0  # w = p0
            continue
        Sn = info[:, a:e] + S[:, None]  # (5, rows, M): the proposal after a match with each candidate
        phi_n = _posterior_log_factor(Sn[0:3], Sn[3:5])
        # pi_j = N(y_j; G_j m, G_j C G_j^T + Q_j) = N(y_j; 0, Q_j) exp(phi(P + A_j, b + b_j) - phi(P, b))
        ll = log_n[a:e] + (phi_n - phi)
        if avail is not None:
            ll = np.where(avail[col[a:e], rows], ll, -np.inf)
        if e - a == 1:
            best, S_j, phi_j = ll[0], Sn[:, 0], phi_n[0]
        else:
            J[i] = j = np.argmax(ll, axis=0)  # c_hat = argmax_j pi_j; ties: smallest index
            best, S_j, phi_j = ll[j, rows], Sn[:, j, rows], phi_n[j, rows]
        won[i] = old = best >= log_p0
        log_w += np.where(old, best, log_p0)  # w = pi_c_hat, or p0 for a new landmark
        S = np.where(old, S_j, S)  # the match's information joins the proposal
        phi = np.where(old, phi_j, phi)
        if avail is not None:
            k = rows[old]
            avail[col[a + J[i, k], k], k] = False
    if near is not None:  # the proposal's mean m = P^-1 b when each measurement was scored
        _, (c00, c01, c11) = _inv_sym(S_seen[:, 0], S_seen[:, 1], S_seen[:, 2])
        m0 = c00 * S_seen[:, 3] + c01 * S_seen[:, 4]
        m1 = c01 * S_seen[:, 3] + c11 * S_seen[:, 4]
        if float(np.max(m0 * m0 + m1 * m1)) > _ETA_REACH ** 2:
            return None
    if col.size:
        slot = np.append(cols, -1)[col[np.minimum(poff[:-1, None] + J, col.shape[0] - 1), rows]]  # (K, M)
        match[:] = np.where(won, slot, -1).T
    return [S[0], S[1], S[2]], [S[3], S[4]], match, log_w


def _boxes_in_reach(lo, hi, margin, x, z):
    """``(W,)`` bool: may some particle predict a landmark within ``[min range - margin, max range + margin]``
    of the step's ranges, for landmarks whose estimates lie in the boxes ``[lo, hi] (W, 2)``?

    The distances between the box of the particles' positions ``x (M, >=2)`` and each box bound every
    particle's distance to every landmark in it, so with `margin` ``(W,)`` at least each landmark's own
    margin, every landmark that a per-particle test keeps is in a box kept here. An empty box
    (``lo = +inf``) is never kept.
    """
    with np.errstate(invalid="ignore"):  # empty boxes: inf - inf
        _, _, d_min, d_max = _offset_box(lo, hi, x)
        slack = 1e-9 * (1.0 + d_max)  # rounding of the bounds
        return (np.isfinite(d_min) & (d_min - slack <= z[:, 0].max() + margin)
                & (d_max + slack >= z[:, 0].min() - margin))


def _offset_box(lo, hi, x):
    """The box ``[e_lo, e_hi] (W, 2)`` of the offsets ``mu - x`` between the boxes ``[lo, hi]`` of landmark
    estimates and the box of the particles' positions ``x (M, >=2)``, and the least and largest distance
    ``(W,)`` between the two boxes, which bound every particle's distance to every landmark in each box."""
    p_lo, p_hi = x[:, :2].min(axis=0), x[:, :2].max(axis=0)
    e_lo, e_hi = lo - p_hi, hi - p_lo
    gap = np.maximum(np.maximum(e_lo, -e_hi), 0.0)
    far = np.maximum(np.abs(e_lo), np.abs(e_hi))
    return e_lo, e_hi, np.hypot(gap[:, 0], gap[:, 1]), np.hypot(far[:, 0], far[:, 1])


def _margin2(spread, b, Q):
    """FastSLAM 2.0's margin of the per-particle test of :func:`_update2_unknown_core`: ten standard deviations
    of sensor (``sqrt Q_rr``), landmark (``spread = sqrt tr Sigma``) and motion noise (``b``, the norm of the
    motion's ``B = V L``, :func:`_motion_norm`); the bounds pass the largest spread and norm."""
    return 10.0 * (math.sqrt(Q[0, 0]) + spread + b)


def _motion_norm(B):
    """``|B_k|`` (Frobenius) of every particle's ``B = V L``, shape (M,)."""
    return np.sqrt((B * B).sum(axis=(1, 2)))


def _summaries_in_reach(summary, x, z, margin):
    """The blocks ``(nb,)`` that some particle may reach: :func:`_boxes_in_reach` on each block column's box
    over the particles, from the summaries ``(M, nb, _NS)``; ``margin(var)`` gives the margin for the
    column's largest ``tr Sigma``."""
    lo, hi = summary.min(axis=0), summary.max(axis=0)  # every field at once: far faster than field by field
    var = np.maximum(hi[:, _S_XX] + hi[:, _S_YY], 0.0)  # -inf: no landmark
    return _boxes_in_reach(lo[:, _S_LO], hi[:, _S_HI], margin(var), x, z)


def _near_ranges(d, var, seen, z, b, Q):
    """``(M, C)``: FastSLAM 2.0's near test of candidates at distances ``d`` with ``tr Sigma = var`` (each on its
    own): landmarks a particle predicts within reach of the step's ranges, with a margin of ten standard
    deviations of sensor, landmark and motion noise (:func:`_margin2`, ``b (M,)``); any other has a likelihood
    below exp(-50) |2 pi Q|^-1/2, far below p0, and could never be chosen."""
    margin = _margin2(np.sqrt(var), b[:, None], Q)
    return seen & (d >= z[:, 0].min() - margin) & (d <= z[:, 0].max() + margin)


def _column_boxes(mu, Sigma, seen):
    """The box ``lo, hi (W, 2)`` of each column's estimates over the particles that hold it (+inf and -inf, an
    empty box, where none does) and a bound ``(W,)`` on the column's ``tr Sigma``: its largest ``Sigma_xx`` plus
    its largest ``Sigma_yy``."""
    lo, hi = np.empty((mu.shape[1], 2)), np.empty((mu.shape[1], 2))
    for c in range(2):  # one coordinate at a time: a where broadcast over the last axis is several times slower
        m = np.where(seen, mu[..., c], np.nan)  # NaN is ignored by fmin and fmax: only the particles that hold it
        np.fmin.reduce(m, axis=0, out=lo[:, c], initial=np.inf)
        np.fmax.reduce(m, axis=0, out=hi[:, c], initial=-np.inf)
    with np.errstate(invalid="ignore"):
        var = np.fmax.reduce(Sigma[..., 0, 0], axis=0) + np.fmax.reduce(Sigma[..., 1, 1], axis=0)
    return lo, hi, var


def _columns_in_reach(x_hat, B, mu, Sigma, seen, z, Q, boxes=None):
    """Columns ``(W,)`` bool of the dense window whose landmark some particle may predict within reach
    (:func:`_boxes_in_reach` with the box of each column's estimates over the particles that hold it;
    `boxes`: those of :func:`_column_boxes`, if computed already)."""
    lo, hi, var = _column_boxes(mu, Sigma, seen) if boxes is None else boxes
    margin = _margin2(np.sqrt(var), float(_motion_norm(B).max()), Q)
    return _boxes_in_reach(lo, hi, margin, x_hat, z)


def _columns_within(lo, hi, var, x, z, b_xy, b_th, Q, t, reach):
    """Columns ``(C,)`` bool that may hold a candidate of some measurement in some particle (a pair that passes
    :func:`_within_reach`'s test with the radii of :func:`_pair_radii`), from the boxes of their estimates over
    the particles ``lo, hi (C, 2)`` and bounds on their ``tr Sigma`` ``var (C,)`` (:func:`_column_boxes`).

    With the box of the particles' positions ``x (M, 3)``, every offset ``mu - x`` lies in a box: the predicted
    range in ``[d_lo, d_hi]`` (the box's distances) and, when the box leaves out the origin, the direction in
    the arc of the box's corners (the predicted bearing in it less the interval of the headings). The radii
    grow with ``tr Sigma``, ``b_xy``, ``b_th`` ``(M, 1)`` and ``d`` (range) or ``1 / d`` (bearing): at the
    column's bound on ``tr Sigma``, the largest norms, ``d_hi`` and ``d_lo`` they bound every pair's. A column
    is kept when one measurement lies within them on both axes, widened by far more than rounding. An empty
    box (``lo = +inf``) is never kept.
    """
    with np.errstate(invalid="ignore"):  # empty boxes: inf - inf
        e_lo, e_hi, d_lo, d_hi = _offset_box(lo, hi, x)  # (C, 2): the box of mu - x; its distances
        d_lo, d_hi = d_lo * (1.0 - 1e-9), d_hi * (1.0 + 1e-9)
        bxy, bth = float(b_xy.max()), float(b_th.max())
        r0 = _range_radius(d_hi, var, bxy, Q, t, reach)
        r1 = _bearing_radius(d_lo, var, bxy, bth, Q, t, reach)  # inf where the box holds the origin
        # 0 * inf (a gap so small that 1 / d_lo overflows beside zero noise, t = 0 beside an infinite variance)
        # bounds nothing: any range and any bearing, never a dropped candidate
        r0[np.isnan(r0)] = np.inf
        r1[np.isnan(r1)] = np.inf
        # the arc of directions: the corners' directions about the centre's (a box that leaves out the origin
        # spans less than pi), less the interval of the headings about the first particle's
        c = np.arctan2(0.5 * (e_lo[:, 1] + e_hi[:, 1]), 0.5 * (e_lo[:, 0] + e_hi[:, 0]))
        off = _wrap(np.arctan2(np.stack([e_lo[:, 1], e_hi[:, 1], e_lo[:, 1], e_hi[:, 1]], axis=1),
                               np.stack([e_lo[:, 0], e_lo[:, 0], e_hi[:, 0], e_hi[:, 0]], axis=1)) - c[:, None])
        o_lo, o_hi = off.min(axis=1), off.max(axis=1)
        dth = _wrap(x[:, 2] - x[0, 2])
        mid = c + 0.5 * (o_lo + o_hi) - x[0, 2] - 0.5 * (dth.min() + dth.max())
        half = 0.5 * (o_hi - o_lo) + 0.5 * (dth.max() - dth.min())
        slack = 1e-9 * (1.0 + np.abs(z[:, 0]).max(initial=0.0) + d_hi + r0)
        ranged = (z[:, 0, None] >= d_lo - r0 - slack) & (z[:, 0, None] <= d_hi + r0 + slack)  # (K, C)
        beared = np.abs(_wrap(_wrap(z[:, 1])[:, None] - mid)) <= half + r1 + 1e-8
        return np.isfinite(d_lo) & (ranged & beared).any(axis=0)


def _update2_unknown_core(state, u, dt, L, z, Q, log_p0, max_range, half_fov, rng, copy=True, motion=None):
    """FastSLAM 2.0 step with unknown correspondences; ``copy=False`` may write into `state`'s arrays."""
    z = z[z[:, 0] > 0]
    n = state.n_particles
    K = z.shape[0]
    x_prev = state.poses
    if K == 0 and max_range is None:  # nothing to associate or prune: the motion sample, the maps unchanged
        eta = rng.standard_normal((n, 2))  # eta ~ N(0, I): _sample_eta with P = I, b = 0, bit for bit
        return FastSLAMState._from_maps(_move(x_prev, u, dt, L, eta, motion), state._blocks(),
                                        _normalized(state.log_weights.copy()))
    x_hat, B = _motion_terms(x_prev, u, dt, L, motion)
    b = _motion_norm(B)  # (M,): the motion's share of every reach margin of this step
    b_xy = np.sqrt((B[:, :2] ** 2).sum(axis=(1, 2)))[:, None]  # (M, 1): the norms of B's position rows
    b_th = np.sqrt((B[:, 2] ** 2).sum(axis=1))[:, None]  # and of its heading row (_pair_radii)
    t = _radii_t(Q, log_p0)
    # the blocks some particle may reach (the union of the particles' block boxes, a superset of
    # _columns_in_reach), or every block when pruning reads every landmark in view
    reach = None if max_range is not None else (
        lambda s: _summaries_in_reach(s, x_hat, z, lambda var: _margin2(np.sqrt(var), float(b.max()), Q)))
    maps, win, (mu, Sigma, seen, counts) = _unknown_window(state, K, "the landmarks of a particle", reach)
    cols = np.flatnonzero(seen.any(axis=0))
    if cols.size and K:
        boxes = _column_boxes(mu, Sigma, seen)

    def offsets(c):
        """``mu - x_hat`` of the window's columns `c` in every particle, its norm, ``tr Sigma`` and `seen`."""
        dx, dy = mu[:, c, 0] - x_hat[:, None, 0], mu[:, c, 1] - x_hat[:, None, 1]
        return dx, dy, np.hypot(dx, dy), Sigma[:, c, 0, 0] + Sigma[:, c, 1, 1], seen[:, c]

    found, scored = None, False
    if _PREFILTER and cols.size and K:
        # the candidates of each measurement (_within_reach): the pairs that may pass _could_win in some
        # particle, from bounds on its fields that need neither z_bar's Jacobians nor Q_j (_pair_radii), among
        # the columns the near test (_near_ranges) keeps. Every test here takes each column on its own, so they
        # run cheapest first: the columns whose boxes may hold a candidate (_columns_within), the range stage of
        # _within_reach on those, its bearing (phi and r1) and exact stage on the columns with a pair in range,
        # the near test on those with a pair left (_columns_in_reach, a bound of the near test, is only needed
        # below).
        c = cols[_columns_within(*(a[cols] for a in boxes), x_hat, z, b_xy, b_th, Q, t, _ETA_REACH)]
        dx, dy, d, var, sn = offsets(c)
        r0 = _range_radius(d, var, b_xy, Q, t, _ETA_REACH)
        i, j = _range_pairs(z, d, sn, r0)
        inr = np.flatnonzero(np.bincount(j, minlength=c.size))  # the columns with a pair in range
        ju = np.searchsorted(inr, j)
        phi = _wrap(np.arctan2(dy[:, inr], dx[:, inr]) - x_hat[:, None, 2])
        r1 = _bearing_radius(d[:, inr], var[:, inr], b_xy, b_th, Q, t, _ETA_REACH)
        within = np.zeros((K, inr.size), dtype=bool)
        if i.size:
            within[i, ju] = _pairs_within(z, i, ju, d[:, inr], phi, sn[:, inr], r0[:, inr], r1)
        hit = within.any(axis=0)
        inr, within = inr[hit], within[:, hit]
        some = _near_ranges(d[:, inr], var[:, inr], sn[:, inr], z, b, Q).any(axis=0)
        if some.any():
            scored = True
            found = _associate2(x_hat, B, mu, Sigma, seen, state.log_weights, z, Q, log_p0, c[inr[some]],
                                within[:, some])
    if found is None:  # every candidate for every measurement (also when the proposal moved beyond _ETA_REACH)
        if cols.size and K:
            cols = cols[_columns_in_reach(x_hat, B, mu, Sigma, seen, z, Q, boxes)[cols]]  # (a superset, cheaper)
        if cols.size and K:
            _, _, d, var, sn = offsets(cols)
            cols = cols[_near_ranges(d, var, sn, z, b, Q).any(axis=0)]
        if _PREFILTER and not scored and cols.size and K:  # no candidate, though some landmark is near
            found = _associate2(x_hat, B, mu, Sigma, seen, state.log_weights, z, Q, log_p0, cols[:0],
                                np.zeros((K, 0), dtype=bool))
        else:
            found = _associate2(x_hat, B, mu, Sigma, seen, state.log_weights, z, Q, log_p0,
                                cols if cols.size and K else None, None)
    P, b, match, log_w = found
    x = _move(x_prev, u, dt, L, _sample_eta(tuple(P), tuple(b), rng, n), motion)  # x_t ~ proposal
    matched = np.zeros_like(seen)
    kk, ii = np.nonzero(match >= 0)
    if kk.size:
        jj = match[kk, ii]
        # EKF update of the matched landmarks at the sampled pose
        mu[kk, jj], Sigma[kk, jj], _, _ = _update_core(x[kk], mu[kk, jj], Sigma[kk, jj], z[ii], Q)
        counts[kk, jj] += 1
        matched[kk, jj] = True
    new = match < 0
    for i in np.flatnonzero(new.any(axis=0)):  # the measurements that are a new landmark in some particle, in order
        k = np.flatnonzero(new[:, i])
        slot = np.argmin(seen[k], axis=1)  # first free slot
        mu[k, slot], Sigma[k, slot] = _init_core(x[k], z[i], Q)  # new landmark at the sampled pose
        seen[k, slot] = True
        counts[k, slot] = 1  # i_j = 1
        matched[k, slot] = True
    changed = matched  # updated and new landmarks, and below those that lost a count
    if max_range is not None:
        seen, counts, miss = _prune(x, mu, seen, counts, matched, max_range, half_fov)
        changed = changed | miss
    maps = _put(maps, win, mu, Sigma, seen, counts, changed=changed, inplace=not copy)
    return FastSLAMState._from_maps(x, maps, _normalized(log_w))


def fastslam_resample(state, *, rng, indices=None):
    """Resample the particles: each new particle takes a survivor's pose and map.

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
        Particles ``indices[k]`` of `state`, with uniform log weights. The
        maps are shared, not copied: each new particle gets its ancestor's
        table of landmark blocks, and a later update copies only the blocks
        it writes (copy-on-write), so changing one particle's landmark never
        changes another's, even where both descend from the same ancestor,
        and resampling costs ``O(M N / 8)`` indices instead of ``O(M N)``
        landmark Gaussians.
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
    # each new particle takes its ancestor's pose and map  (Table 13.1 lines 25-27); the maps are shared
    # block tables, copied on write, so a later change to one particle's landmark never reaches another's
    maps = state._blocks()
    new = FastSLAMState._from_maps(state.poses[idx], maps._replace(table=maps.table[idx]), np.full(M, -np.log(M)))
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
    g = particle_gaussian(state.poses, state.log_weights, angles=(2,))  # the one weighted pose summary
    return g.mean, int(np.argmax(state.log_weights))


def fastslam_map_moments(state, slots):
    """Mean and covariance of the map implied by the whole particle set.

    Parameters
    ----------
    state : FastSLAMState
        Weighted particle set; the landmarks in `slots` must be seen in every
        particle.
    slots : ndarray of int, shape (L,)
        Landmark slots to include, in this order (``L = 0`` gives an empty
        mean ``(0,)`` and covariance ``(0, 0)``).

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
    if idx.size == 0:  # no landmark: the empty mean and covariance
        return np.zeros(0), np.zeros((0, 0))
    if np.any(idx < 0) or np.any(idx >= state.capacity):
        raise ValueError(f"slots must lie in [0, {state.capacity})")
    mu, Sigma, seen, _ = _take(state._blocks(), idx)
    if not seen.all():
        raise ValueError("every landmark in slots must be seen in every particle")
    w = state.weights
    mu = mu.reshape(state.n_particles, -1)
    mean = w @ mu
    d = mu - mean
    cov = np.einsum("k,ki,kj->ij", w, d, d)  # spread of the particles' maps
    within = np.einsum("k,klij->lij", w, Sigma)  # E[Sigma^[k]], one 2x2 block per landmark
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
    rejected : ndarray, shape (T,)
        Measurements the per-particle gate rejected at each step, averaged
        over the particles with their weights before the step (0 where the
        gate is off; ``rejected.sum()`` is the run's count).
    gate : float or None
        The gate that was used (``None``: no gate).
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
    rejected: np.ndarray
    gate: float | None


def _run_attr(run, name):
    if not hasattr(run, name):
        raise TypeError(f"run must be a LandmarkRun (from slamlib.simulate_landmark_run); it has no {name!r}")
    return getattr(run, name)


def run_fastslam(run, *, n_particles, rng, known=True, M=None, alpha=None, Q=None, p0=None, weight_cov="S",
                 resample_threshold=0.5, capacity=None, max_range=None, fov=None, version=1, gate=None,
                 reinit_lost=True, motion=None, fastslam_init_landmark=None, fastslam_update_landmark=None, on_step=None):
    """Run FastSLAM 1.0 or 2.0 over a landmark run (simulated or a real log).

    Parameters
    ----------
    run : LandmarkRun or MRCLAMRun
        From :func:`slamlib.simulate_landmark_run` or a loader such as
        :func:`slamlib.datasets.mrclam.load_mrclam`: uses ``x0``, ``dt``, the
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
        Known correspondences (Tables 13.1, 13.3) or per-particle
        maximum-likelihood association (Tables 13.2, 13.3).
    M : ndarray, shape (2, 2), optional, keyword-only
        Control-noise covariance assumed by the filter; default the run's ``M``.
    alpha : ndarray, shape (6,), optional, keyword-only
        Sample the motion with Table 5.3's parameters instead of `M`
        (FastSLAM 1.0 only).
    Q : ndarray, shape (2, 2), optional, keyword-only
        Measurement noise assumed by the filter; default the run's ``Q``.
    p0 : float, optional, keyword-only
        New-landmark likelihood (unknown correspondences).
    weight_cov : {"S", "text"}, keyword-only
        ``"text"`` is the course text's erratum (FastSLAM 1.0 only), for
        demonstrations.
    resample_threshold : float, keyword-only
        Resample when the effective sample size is below
        ``resample_threshold * M``; ``1.0`` resamples after every update with
        non-uniform weights, as Algorithm 3 does.
    capacity : int, optional, keyword-only
        Initial landmark slots (default: the run's number of landmarks).
    max_range, fov : float, optional, keyword-only
        Perceptual range for the landmark counters of Table 13.2.
    version : {1, 2}, keyword-only
        FastSLAM 1.0 (the motion model as proposal; default) or 2.0 (the
        proposal includes the step's measurements, Table 13.3).
    gate : float, optional, keyword-only
        Per-particle chi-square gate on the squared Mahalanobis distance
        ``nu^T S^-1 nu`` of a known correspondence's innovation (FastSLAM
        2.0: ``nu^T L^-1 nu``; :func:`fastslam_update_known`,
        :func:`fastslam2_update_known`); a distance above `gate` is an
        outlier for that particle, one equal to it is not, as in
        :func:`slamlib.run_ekf_slam`. ``None`` (default) takes ``run.gate`` if
        the run has that attribute (the real-data loaders set it, e.g.
        :func:`~slamlib.datasets.mrclam.load_mrclam`, whose
        :data:`~slamlib.datasets.mrclam.MRCLAM_GATE` equals
        :data:`DEFAULT_GATE`, the 99.999 % point of chi-square with 2 dof) and
        no gate otherwise (a simulated :class:`slamlib.LandmarkRun`, whose
        noise is exactly the Gaussian the filter assumes); ``numpy.inf``
        turns it off. Real sightings include gross errors (a bearing off by
        pi, a range off by metres) that a Gaussian likelihood turns into a
        collapse of the weights onto whichever particle explains the blunder
        best, and into a landmark pulled metres away in every particle; the
        gate caps such a measurement's influence at that of an innovation on
        the gate. Not used with unknown correspondences (there ``p0`` plays
        that role).
    reinit_lost : bool, keyword-only
        With known correspondences and a `gate`: count, per particle and
        landmark, the sightings the gate accepts (+1) and rejects (-1), Table
        13.2's existence evidence ``i_j``, and discard a landmark when
        ``i_j`` reaches 0, so that the next sighting re-creates it (default
        ``True``). A misidentified sighting that is the first of its barcode places the
        landmark where no true sighting fits; without this every later true
        sighting is rejected, the landmark never recovers, and the robot
        drives blind where it stands. ``False`` keeps a landmark where it was
        placed (FastSLAM with one particle then equals gated EKF SLAM).
    motion : callable, optional, keyword-only
        Motion model ``motion(x, u, dt) -> (x_next, G, V)`` vectorised over
        poses ``(M, 3)`` and controls ``(M, 2)``, e.g.
        :class:`slamlib.AckermannModel` for a car; each particle moves with its
        own noisy control ``u + N(0, M)`` (through ``motion.pose(x, u, dt)``,
        the pose alone, where the model has that method, as
        :class:`~slamlib.AckermannModel` does). Default: the velocity model
        (exact arc). Not with `alpha`.
    fastslam_init_landmark : callable, optional, keyword-only
        ``fastslam_init_landmark(x, z, Q) -> (mu, Sigma)`` in place of the
        initialisation of a landmark seen for the first time (Algorithm 3,
        Table 13.1 lines 7-9) for the particles ``x (k, 3)`` that have not seen
        it: the contract function :func:`fastslam_init_landmark` itself, or a
        student's version of it, as the autograder plugs it in. FastSLAM 1.0
        with known correspondences only, like the next one. ``None``
        (default): the library's core.
    fastslam_update_landmark : callable, optional, keyword-only
        ``fastslam_update_landmark(x, mu, Sigma, z, Q) -> (mu_new, Sigma_new,
        w)`` in place of the landmark update and importance weight of the
        particles that have seen the landmark (Table 13.1 lines 12-18), as
        :func:`fastslam_update_landmark`; needs ``weight_cov="S"`` and no
        `gate`. A weight of zero is allowed (log-weight ``-inf``), as long as
        some particle keeps a positive weight.
    on_step : callable, optional, keyword-only
        ``on_step(t)`` is called at the start of step ``t`` (before the
        particles move), e.g. for progress reports, or so that the functions
        above know which step they serve.

    Returns
    -------
    FastSLAMResult
        Estimated trajectory, map, ESS and degeneracy over time, and the
        measurements the gate rejected.

    Notes
    -----
    With `fastslam_init_landmark` or `fastslam_update_landmark` the
    measurements of a step are processed one at a time (the library's own
    path processes them in batches, with the same result up to rounding),
    and the functions are called with the homework contract's arguments on
    copies of the particles' arrays. Their results are checked (shapes,
    finite values, non-negative weights) and a bad one raises ``ValueError``
    naming the function; exceptions they raise pass through unchanged.

    References
    ----------
    Course text, Algorithm 3. Thrun, Burgard & Fox (2005), Tables 13.1,
    13.2 and 13.3. Montemerlo et al. (2003).
    """
    n = as_count(n_particles, "n_particles", minimum=1)
    check_rng(rng)
    check_choice(weight_cov, "weight_cov", _WEIGHT_COVS, removed=_GONE_WEIGHT_COVS)
    if isinstance(version, bool) or version not in (1, 2):
        raise ValueError(f"version must be 1 (FastSLAM 1.0) or 2 (FastSLAM 2.0), got {version!r}")
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
        if version == 2:
            raise ValueError("version=2 needs the control-noise covariance M (alpha is for FastSLAM 1.0 only)")
        alpha = as_array(alpha, "alpha", (6,))
        if np.any(alpha < 0):
            raise ValueError("alpha must be non-negative")
        L = None
    else:
        L = _control_sqrt(as_covariance(_run_attr(run, "M") if M is None else M, "M", 2))
    if motion is not None and (not callable(motion) or alpha is not None):
        raise ValueError("motion must be a callable motion(x, u, dt) -> (x_next, G, V), used with M (not alpha)")
    if version == 2 and weight_cov != "S":
        raise ValueError("weight_cov='text' is FastSLAM 1.0's erratum; version=2 has its own weight")
    Q = as_invertible_covariance(_run_attr(run, "Q") if Q is None else Q, "Q", 2, max_log_det=_MAX_LOG_DET)
    if gate is None:
        gate = getattr(run, "gate", None)  # the run's gate (real logs); none for simulated runs
    if gate is not None:
        gate = as_threshold(gate, "gate")  # chi-square value on nu^T S^-1 nu
        gate = None if gate == np.inf else gate  # inf: no gate
    check_callable(fastslam_init_landmark, "fastslam_init_landmark", "(x, z, Q)")
    check_callable(fastslam_update_landmark, "fastslam_update_landmark", "(x, mu, Sigma, z, Q)")
    check_callable(on_step, "on_step", "(t)")
    stepwise = fastslam_init_landmark is not None or fastslam_update_landmark is not None
    if stepwise and (not known or version != 1):
        raise ValueError("fastslam_init_landmark and fastslam_update_landmark need known=True and version=1 "
                         "(FastSLAM 1.0 with known correspondences)")
    if fastslam_update_landmark is not None and (gate is not None or weight_cov != "S"):
        raise ValueError("fastslam_update_landmark needs weight_cov='S' and no gate (the contract's update has "
                         "neither)")
    init_step, update_step = _fastslam_steps(fastslam_init_landmark, fastslam_update_landmark)
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
    rejected = np.zeros(T)
    poses_hist[0] = state.poses
    x_est[0] = state.poses[0]
    identity = np.arange(n)
    parents[:2] = identity
    counted = (None, -1, 0)  # the maps and the particle whose landmarks n_lm last counted, and their number
    for t in range(T):
        if on_step is not None:
            on_step(t)
        zt = as_rows(zs[t], "z", 2)
        out = None
        if known:
            idt = np.asarray(ids[t])
            if idt.shape != (zt.shape[0],) or (idt.size and idt.dtype.kind not in "iu"):
                raise ValueError(f"run.ids[{t}] must be integers of shape ({zt.shape[0]},), got {idt.shape}")
            keep = (zt[:, 0] > 0) & (idt >= 0)  # id -1 marks clutter (slamlib.add_clutter)
            zt, idt = zt[keep], idt[keep].astype(np.int64)
            if idt.size and idt.max() >= MAX_LANDMARKS:
                raise ValueError(f"run.ids[{t}] must be below MAX_LANDMARKS = {MAX_LANDMARKS}")
            if zt.shape[0]:
                state = _grow(state, int(idt.max()) + 1, f"run.ids[{t}]")
        prior_w = np.exp(state.log_weights) if known else None  # (only known correspondences reject measurements)
        if version == 2:
            if known:
                state, out = _update2_known_core(state, u[t], dt, L, zt, idt, Q, rng, gate=gate, copy=False,
                                                 motion=motion, reinit=reinit_lost)
            else:
                state = _update2_unknown_core(state, u[t], dt, L, zt, Q, log_p0, max_range, half_fov, rng,
                                              copy=False, motion=motion)
        else:
            if L is None:
                poses = sample_motion_model_velocity(state.poses, u[t], dt, alpha, rng=rng)
            else:
                poses = _sample_arc(state.poses, u[t], dt, L, rng, motion)
            state = state._replace(poses=poses)
            if known:
                if zt.shape[0] and stepwise:
                    state, out = _stepwise_known_core(state, zt, idt, Q, weight_cov, gate, init_step, update_step,
                                                      reinit_lost)
                elif zt.shape[0]:
                    state, out = _update_known_core(state, zt, idt, Q, weight_cov, copy=False, gate=gate,
                                                    reinit=reinit_lost)
            else:
                state = _update_unknown_core(state, zt, Q, log_p0, weight_cov, max_range, half_fov, copy=False)
        if out is not None and out.size:
            rejected[t] = prior_w @ out.sum(axis=1)  # measurements rejected, averaged over the prior weights
        poses_hist[t + 1] = state.poses
        w = np.exp(state.log_weights)  # normalised: logsumexp(log_weights) = 0
        x_est[t + 1], x_cov[t + 1] = _particle_moments(state.poses, np.exp(_normalized(state.log_weights)), (2,))
        best = int(np.argmax(w))
        if state._maps is None or state._maps is not counted[0] or best != counted[1]:
            counted = (state._maps, best, _n_seen(state, best))  # (a step without measurements keeps the maps)
        n_lm[t + 1] = counted[2]
        ess[t] = _ess(w)
        if t == T - 1:
            break  # keep the last weights: they pick the final most likely particle
        if ess[t] < thr * n:
            state, parents[t + 2] = fastslam_resample(state, rng=rng)
            resampled[t] = True
        else:
            parents[t + 2] = identity
    return _finish(state, poses_hist, parents, x_est, x_cov, ess, resampled, n_lm, rejected, gate)


def _finish(last, poses_hist, parents, x_est, x_cov, ess, resampled, n_lm, rejected, gate):
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
    mu, Sigma, seen, _ = _particle_map(last, best)
    return FastSLAMResult(
        x_est=x_est,
        x_cov=x_cov,
        path_best=path,
        landmarks=mu,
        landmark_cov=Sigma,
        seen=seen,
        ess=ess,
        resampled=resampled,
        n_landmarks=n_lm,
        n_ancestors=n_anc,
        state=last,
        rejected=rejected,
        gate=gate,
    )
