"""Simulation of a robot driving among point landmarks.

:func:`simulate_landmark_run` produces the ground truth, the commanded controls
a filter receives and the noisy range-bearing measurements, all from one seeded
generator; :func:`loop_controls` and :func:`figure_eight_controls` make simple
control sequences.

References
----------
Thrun, Burgard & Fox, *Probabilistic Robotics* (2005), Sec. 5.3 (velocity
motion model, Table 5.3) and Sec. 6.6 (range-bearing measurements, Eq. 6.40).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._checks import as_array, as_covariance, as_index, as_scalar, check_rng
from .angles import wrap_angle
from .motion import velocity_motion
from .sensors import landmark_measurement

__all__ = ["LandmarkRun", "simulate_landmark_run", "loop_controls", "figure_eight_controls"]


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
        for the control noise, then at each step ``t``
        ``multivariate_normal(0, Q, size=K_t, method="eigh")`` for the
        measurements in increasing landmark order.

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
    x_true = np.empty((T + 1, 3))
    x_true[0] = x0
    zs, ids = [], []
    all_ids = np.arange(landmarks.shape[0])
    for t in range(T):
        x_true[t + 1], _, _ = velocity_motion(x_true[t], u_true[t], dt)
        if landmarks.shape[0]:
            z_hat, _, _ = landmark_measurement(x_true[t + 1], landmarks)
            seen = (z_hat[:, 0] <= max_range) & (np.abs(z_hat[:, 1]) <= fov / 2)
        else:
            z_hat, seen = np.empty((0, 2)), np.zeros(0, dtype=bool)
        noise = rng.multivariate_normal(np.zeros(2), Q, size=int(seen.sum()), method="eigh")
        z = z_hat[seen] + noise
        z[:, 1] = wrap_angle(z[:, 1])
        zs.append(_readonly(z))
        ids.append(_readonly(all_ids[seen]))
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
