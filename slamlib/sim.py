"""Simulation of a robot driving among point landmarks.

:func:`simulate_landmark_run` produces the ground truth, the commanded controls
a filter receives and the noisy range-bearing measurements, all from one seeded
generator; :func:`loop_controls` and :func:`figure_eight_controls` make simple
control sequences; :func:`add_clutter` adds spurious measurements to a run.

References
----------
Thrun, Burgard & Fox, *Probabilistic Robotics* (2005), Sec. 5.3 (velocity
motion model, Table 5.3), Sec. 6.6 (range-bearing measurements, Eq. 6.40) and
Sec. 10.3.3 (spurious measurements).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ._checks import as_array, as_covariance, as_index, as_scalar, check_rng
from .angles import wrap_angle
from .motion import _arc

__all__ = ["LandmarkRun", "simulate_landmark_run", "loop_controls", "figure_eight_controls", "add_clutter"]


@dataclass(frozen=True, eq=False)
class LandmarkRun:
    """A simulated run among point landmarks (ground truth and measurements).

    Attributes
    ----------
    landmarks : ndarray, shape (N, 2)
        True landmark positions.
    dt : float
        Duration of one control step (seconds).
    x0 : ndarray, shape (3,)
        Initial pose.
    x_true : ndarray, shape (T+1, 3)
        True poses, ``x_true[0] = x0``, ``x_true[t+1]`` after control ``t``.
    u : ndarray, shape (T, 2)
        Commanded controls ``[v, omega]`` (what a filter receives).
    u_true : ndarray, shape (T, 2)
        Executed controls, ``u + N(0, M)``.
    z : tuple of T ndarrays, shape (K_t, 2)
        Measurements ``[r, phi]`` taken at ``x_true[t+1]`` (after step ``t``).
    ids : tuple of T int ndarrays, shape (K_t,)
        Indices into `landmarks` of the landmarks measured in `z`.
    M : ndarray, shape (2, 2)
        Control-noise covariance.
    Q : ndarray, shape (2, 2)
        Measurement-noise covariance of ``[r, phi]``.
    max_range : float
        Largest range at which a landmark is seen.
    fov : float
        Total field of view (radians), centred on the heading.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 5.3 and Eq. 6.40.
    """

    landmarks: np.ndarray
    dt: float
    x0: np.ndarray
    x_true: np.ndarray
    u: np.ndarray
    u_true: np.ndarray
    z: tuple
    ids: tuple
    M: np.ndarray
    Q: np.ndarray
    max_range: float
    fov: float

    @property
    def n_steps(self):
        """Number of control steps ``T``."""
        return self.u.shape[0]


def _readonly(a):
    a = np.array(a)
    a.setflags(write=False)
    return a


def simulate_landmark_run(landmarks, u, dt, *, x0, M, Q, max_range=np.inf, fov=2 * np.pi, rng):
    """Simulate a robot following velocity controls and measuring landmarks.

    At each step ``t`` the executed control is ``u[t] + N(0, M)``; the robot
    moves along the exact arc (:func:`~slamlib.motion.velocity_motion`), then
    measures every landmark within `max_range` whose bearing lies in
    ``[-fov/2, fov/2]``: ``z = h(x_true[t+1], m) + N(0, Q)``, bearing wrapped.

    Parameters
    ----------
    landmarks : ndarray, shape (N, 2)
        Landmark positions.
    u : ndarray, shape (T, 2)
        Commanded controls ``[v, omega]``.
    dt : float
        Step duration (seconds), positive.
    x0 : ndarray, shape (3,), keyword-only
        Initial pose.
    M : ndarray, shape (2, 2), keyword-only
        Control-noise covariance (positive semi-definite).
    Q : ndarray, shape (2, 2), keyword-only
        Measurement-noise covariance (positive semi-definite).
    max_range : float, keyword-only
        Sensing range (``inf`` for unlimited).
    fov : float, keyword-only
        Total field of view in ``(0, 2 pi]``.
    rng : numpy.random.Generator, keyword-only
        Draws, in order: ``multivariate_normal(0, M, size=T, method="eigh")``
        for the control noise, then one
        ``multivariate_normal(0, Q, size=K, method="eigh")`` for all ``K``
        measurements, ordered by time step and then by landmark index.

    Returns
    -------
    LandmarkRun
        Ground truth, controls and measurements (read-only arrays).

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 5.3 (motion), Eq. 6.40 (measurements).
    """
    landmarks = as_array(landmarks, "landmarks", (None, 2))
    u = as_array(u, "u", (None, 2))
    dt = as_scalar(dt, "dt", positive=True)
    x0 = as_array(x0, "x0", (3,))
    M = as_covariance(M, "M", 2)
    Q = as_covariance(Q, "Q", 2)
    max_range = as_scalar(max_range, "max_range", positive=True, finite=False)
    if np.isnan(max_range):
        raise ValueError("max_range must be positive, got nan")
    fov = as_scalar(fov, "fov", positive=True)
    check_rng(rng)
    T = u.shape[0]
    x0 = x0.copy()
    x0[2] = wrap_angle(x0[2])

    u_true = u + rng.multivariate_normal(np.zeros(2), M, size=T, method="eigh")
    # the headings do not depend on the positions: theta_t = theta_0 + sum omega dt, so every
    # step's displacement (Table 5.3 without noise) is computed at once and accumulated
    theta = x0[2] + np.concatenate([[0.0], np.cumsum(u_true[:, 1] * dt)])
    start = np.zeros((T, 3))
    start[:, 2] = theta[:-1]
    step = _arc(start, u_true, dt)[0] if T else np.zeros((0, 3))
    x_true = np.empty((T + 1, 3))
    x_true[:, :2] = x0[:2] + np.concatenate([np.zeros((1, 2)), np.cumsum(step[:, :2], axis=0)])
    x_true[:, 2] = wrap_angle(theta)
    N = landmarks.shape[0]
    if N:
        d = landmarks[None, :, :] - x_true[1:, None, :2]
        rng_ = np.hypot(d[..., 0], d[..., 1])
        bearing = wrap_angle(np.arctan2(d[..., 1], d[..., 0]) - x_true[1:, None, 2])
        seen = (rng_ <= max_range) & (np.abs(bearing) <= fov / 2)
        # z = h(x, m) + N(0, Q)  (Eq. 6.40), time-major then landmark order
        t_idx, j_idx = np.nonzero(seen)
        z_all = np.stack([rng_[t_idx, j_idx], bearing[t_idx, j_idx]], axis=-1)
    else:
        t_idx = j_idx = np.zeros(0, dtype=np.intp)
        z_all = np.zeros((0, 2))
    z_all = z_all + rng.multivariate_normal(np.zeros(2), Q, size=z_all.shape[0], method="eigh")
    z_all[:, 1] = wrap_angle(z_all[:, 1])
    splits = np.searchsorted(t_idx, np.arange(1, T))
    zs = [_readonly(z) for z in np.split(z_all, splits)] if T else []  # (np.split gives one chunk for T = 0)
    ids = [_readonly(i) for i in np.split(j_idx.astype(np.int64), splits)] if T else []
    return LandmarkRun(
        landmarks=_readonly(landmarks), dt=dt, x0=_readonly(x0), x_true=_readonly(x_true), u=_readonly(u),
        u_true=_readonly(u_true), z=tuple(zs), ids=tuple(ids), M=_readonly(M), Q=_readonly(Q),
        max_range=max_range, fov=fov,
    )


def loop_controls(n_steps, *, v, omega):
    """Constant controls: a circle of radius ``v / omega``.

    Parameters
    ----------
    n_steps : int
        Number of steps ``T``.
    v, omega : float, keyword-only
        Speed (m/s) and turn rate (rad/s). With step ``dt`` the circle closes
        after ``2 pi / (|omega| dt)`` steps.

    Returns
    -------
    ndarray, shape (T, 2)
        ``[v, omega]`` repeated.

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 5.3.3 (constant velocity moves on a circle).
    """
    n_steps = as_index(n_steps, "n_steps")
    v = as_scalar(v, "v")
    omega = as_scalar(omega, "omega")
    return np.tile([v, omega], (n_steps, 1)).astype(float)


def figure_eight_controls(n_steps, *, v, omega):
    """Controls tracing a figure eight: a left circle, then a right circle.

    Parameters
    ----------
    n_steps : int
        Number of steps ``T`` (the first ``T // 2`` turn left, the rest right).
    v : float, keyword-only
        Constant speed (m/s).
    omega : float, keyword-only
        Turn rate (rad/s) of the first half; the second half uses ``-omega``.
        The path is a closed figure eight when ``(T // 2) dt |omega| = 2 pi``
        and ``T`` is even.

    Returns
    -------
    ndarray, shape (T, 2)
        ``[v, +-omega]``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 5.3.3.
    """
    n_steps = as_index(n_steps, "n_steps")
    v = as_scalar(v, "v")
    omega = as_scalar(omega, "omega")
    out = np.empty((n_steps, 2))
    out[:, 0] = v
    out[:, 1] = omega
    out[n_steps // 2:, 1] = -omega
    return out


def add_clutter(run, rate, *, rng, max_range=None, min_range=0.5):
    """Add spurious measurements (clutter) to a simulated run.

    Parameters
    ----------
    run : LandmarkRun
        A simulated run.
    rate : float
        Mean number of spurious measurements per step (Poisson), non-negative.
    rng : numpy.random.Generator, keyword-only
        Draws, per step: ``poisson(rate)`` for the count ``c``, then
        ``uniform(min_range, max_range, c)`` ranges,
        ``uniform(-fov/2, fov/2, c)`` bearings and one ``permutation`` that
        mixes them among the true measurements.
    max_range : float, keyword-only
        Largest clutter range (default ``run.max_range``; required when that
        is infinite).
    min_range : float, keyword-only
        Smallest clutter range, positive.

    Returns
    -------
    LandmarkRun
        A copy of `run` whose measurements include the clutter, marked with
        id ``-1`` in ``ids``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 10.3.3 (spurious measurements and the
    provisional landmark list).
    """
    for attr in ("z", "ids", "fov", "max_range"):
        if not hasattr(run, attr):
            raise TypeError(f"run must be a LandmarkRun (simulate_landmark_run), it has no attribute {attr!r}")
    rate = as_scalar(rate, "rate", nonnegative=True)
    check_rng(rng)
    min_range = as_scalar(min_range, "min_range", positive=True)
    if max_range is None:
        if not np.isfinite(run.max_range):
            raise ValueError("max_range must be given when run.max_range is infinite")
        max_range = run.max_range
    max_range = as_scalar(max_range, "max_range", positive=True)
    if max_range <= min_range:
        raise ValueError(f"max_range must exceed min_range ({min_range}), got {max_range}")
    zs, ids = [], []
    for z, i in zip(run.z, run.ids):
        c = int(rng.poisson(rate))
        fake = np.column_stack([rng.uniform(min_range, max_range, c), rng.uniform(-run.fov / 2, run.fov / 2, c)])
        fake[:, 1] = wrap_angle(fake[:, 1]) if c else fake[:, 1]
        allz = np.vstack([np.asarray(z, dtype=float).reshape(-1, 2), fake])
        alli = np.concatenate([np.asarray(i, dtype=int), np.full(c, -1)])
        order = rng.permutation(allz.shape[0])
        zz, ii = allz[order], alli[order]
        zz.setflags(write=False)
        ii.setflags(write=False)
        zs.append(zz)
        ids.append(ii)
    return dataclasses.replace(run, z=tuple(zs), ids=tuple(ids))
