"""Probabilistic motion models: velocity (exact arc) and odometry.

Poses are ``[x, y, theta]`` with shape ``(..., 3)``; velocity controls are
``[v, omega]`` applied for ``dt`` seconds, shape ``(..., 2)``; odometry controls
are ``[rot1, trans, rot2]``, shape ``(..., 3)``. Every function broadcasts over
leading axes, so one pose and ``M`` particles go through the same code, and
every returned heading is wrapped to ``[-pi, pi)``.

The exact-arc model is written in its chord form,

``x' = x + v dt cos(theta + omega dt / 2) sinc(omega dt / 2)``,

``y' = y + v dt sin(theta + omega dt / 2) sinc(omega dt / 2)``,

with ``sinc(a) = sin(a) / a``. It equals ``x - v/omega sin(theta) + v/omega
sin(theta + omega dt)`` of Table 5.3 exactly (``sin B - sin A = 2 cos((A+B)/2)
sin((B-A)/2)``) but does not divide by ``omega``, so it stays accurate for
small turn rates.

References
----------
Thrun, Burgard & Fox, *Probabilistic Robotics* (2005), Sec. 5.3 (Tables 5.1,
5.3, Eq. 5.9), Sec. 5.4 (Tables 5.5, 5.6), Table 7.2 (Jacobians ``G``, ``V``
and control noise ``M``).
"""

from __future__ import annotations

import numpy as np

from ._checks import as_array, as_poses, as_scalar, as_vector, check_batch, check_rng
import math

from .angles import _wrap, _wrap1, wrap_angle

__all__ = [
    "velocity_motion",
    "velocity_noise_cov",
    "sample_motion_model_velocity",
    "motion_model_velocity",
    "odometry_from_poses",
    "odometry_motion",
    "sample_motion_model_odometry",
    "motion_model_odometry",
    "dead_reckoning",
]

#: Below this ``abs(omega)`` the velocity model uses the straight-line limit.
STRAIGHT_LINE_OMEGA = 1e-6
#: Below this translation (metres) ``odometry_from_poses`` sets ``rot1 = 0``.
MIN_TRANS = 1e-9
_LOG_2PI = float(np.log(2.0 * np.pi))
#: Variances of the motion densities are floored here, so that a degenerate
#: hypothesis (e.g. ``x_next == x``) gets a large but finite density.
_VAR_FLOOR = 1e-12


# --------------------------------------------------------------------------- helpers
def _sinc(a):
    """``sin(a) / a`` with ``sinc(0) = 1`` (numpy's sinc is ``sin(pi x) / (pi x)``)."""
    return np.sinc(a / np.pi)


def _dsinc(a):
    """Derivative of ``sin(a) / a``: ``(a cos a - sin a) / a^2``, by series near 0."""
    a = np.asarray(a, dtype=float)
    small = np.abs(a) < 1e-3
    safe = np.where(small, 1.0, a)
    direct = (safe * np.cos(safe) - np.sin(safe)) / safe**2
    series = -a / 3.0 + a**3 / 30.0
    return np.where(small, series, direct)


def _log_normal(d, var):
    """``log N(d; 0, var)`` (Table 5.2), elementwise."""
    return -0.5 * (_LOG_2PI + np.log(var)) - 0.5 * d**2 / var


def _arc(x, u, dt):
    """Exact-arc motion and its Jacobians for broadcast pose/control arrays."""
    theta = x[..., 2]
    v = u[..., 0]
    w = u[..., 1]
    phi = w * dt
    a = 0.5 * phi
    c = theta + a
    s = _sinc(a)
    ds = _dsinc(a)
    cos_c, sin_c = np.cos(c), np.sin(c)

    straight = np.abs(w) < STRAIGHT_LINE_OMEGA
    cos_t, sin_t = np.cos(theta), np.sin(theta)
    # straight-line limit of the contract for |omega| < 1e-6; chord form of Table 5.3 otherwise
    cx = np.where(straight, cos_t, cos_c * s)  # (x' - x) / (v dt)
    cy = np.where(straight, sin_t, sin_c * s)  # (y' - y) / (v dt)

    shape = np.broadcast_shapes(x.shape[:-1], u.shape[:-1])
    x_next = np.empty(shape + (3,))
    x_next[..., 0] = x[..., 0] + v * dt * cx
    x_next[..., 1] = x[..., 1] + v * dt * cy
    x_next[..., 2] = wrap_angle(theta + phi)

    # G = d x' / d x  (Table 7.2 line 3)
    G = np.zeros(shape + (3, 3))
    G[..., 0, 0] = 1.0
    G[..., 1, 1] = 1.0
    G[..., 2, 2] = 1.0
    G[..., 0, 2] = -v * dt * cy
    G[..., 1, 2] = v * dt * cx

    # V = d x' / d u  (Table 7.2 line 4), chord form; V[:, 1] -> [-v dt^2 sin/2, v dt^2 cos/2] as omega -> 0
    V = np.zeros(shape + (3, 2))
    V[..., 0, 0] = dt * cx
    V[..., 1, 0] = dt * cy
    half = 0.5 * v * dt * dt
    V[..., 0, 1] = np.where(straight, -half * sin_t, half * (-sin_c * s + cos_c * ds))
    V[..., 1, 1] = np.where(straight, half * cos_t, half * (cos_c * s + sin_c * ds))
    V[..., 2, 1] = dt
    return x_next, G, V


def _arc_pose(x, u, dt):
    """Exact-arc motion without Jacobians, ``x (M, 3)``, ``u (M, 2)``: the path of the particle filters.

    The chord form of :func:`_arc` (``x' = x + v dt cos(theta + w dt / 2) sinc(w dt / 2)`` and
    likewise for ``y``); the particle filters need neither ``G`` nor ``V``, and skipping them
    halves the cost of a step (the tests check it equals :func:`_arc`).
    """
    v, w = u[:, 0], u[:, 1]
    half = (0.5 * dt) * w
    step = (v * dt) * _sinc(half)  # chord length v dt sinc(w dt / 2)
    c = x[:, 2] + half
    out = np.empty(x.shape)
    # x' = x + v dt cos(theta + w dt/2) sinc(w dt/2), y' likewise  (Table 5.3, chord form)
    out[:, 0] = x[:, 0] + step * np.cos(c)
    out[:, 1] = x[:, 1] + step * np.sin(c)
    out[:, 2] = wrap_angle(x[:, 2] + dt * w)  # theta' = theta + w dt  (Table 5.3 line 6)
    return out


def _control_sqrt(M):
    """A square root ``L`` of a positive semi-definite control covariance, ``L L^T = M`` (unchecked)."""
    lam, vec = np.linalg.eigh(M)
    return vec * np.sqrt(np.maximum(lam, 0.0))


def _arc1(x, u, dt):
    """Exact-arc motion of one pose with Python floats: the scalar path of :func:`_arc` (same chord form).

    Returns ``x_next (3,)``, ``G (3, 3)``, ``V (3, 2)``; the tests check it
    against :func:`_arc`.
    """
    xn, yn, thn, g02, g12, v00, v01, v10, v11 = _arc1_floats(x, u, dt)
    # G = d x' / d x, V = d x' / d u  (Table 7.2 lines 3-4)
    G = np.array([[1.0, 0.0, g02], [0.0, 1.0, g12], [0.0, 0.0, 1.0]])
    V = np.array([[v00, v01], [v10, v11], [0.0, dt]])
    return np.array([xn, yn, thn]), G, V


def _arc1_floats(x, u, dt):
    """:func:`_arc1` as floats: ``x', y', theta'``, the entries ``G[0, 2], G[1, 2]`` of ``G`` (the rest is
    the identity) and ``V[0, 0], V[0, 1], V[1, 0], V[1, 1]`` of ``V`` (``V[2] = [0, dt]``)."""
    px, py, th = x.tolist() if type(x) is np.ndarray else map(float, x)
    v, w = u.tolist() if type(u) is np.ndarray else map(float, u)
    if abs(w) < STRAIGHT_LINE_OMEGA:  # straight-line limit of the contract
        cx, cy = math.cos(th), math.sin(th)
        v01, v11 = -0.5 * v * dt * dt * cy, 0.5 * v * dt * dt * cx
    else:  # chord form of Table 5.3: (x' - x) / (v dt) = cos(theta + a) sinc(a), a = omega dt / 2
        a = 0.5 * w * dt
        sa = math.sin(a) / a if a != 0.0 else 1.0
        dsa = (a * math.cos(a) - math.sin(a)) / (a * a) if abs(a) >= 1e-3 else -a / 3.0 + a**3 / 30.0
        cc, sc = math.cos(th + a), math.sin(th + a)
        cx, cy = cc * sa, sc * sa
        half = 0.5 * v * dt * dt
        v01, v11 = half * (-sc * sa + cc * dsa), half * (cc * sa + sc * dsa)
    vdt = v * dt
    return px + vdt * cx, py + vdt * cy, _wrap1(th + w * dt), -vdt * cy, vdt * cx, dt * cx, v01, dt * cy, v11


# --------------------------------------------------------------------------- velocity model
def velocity_motion(x, u, dt):
    """Noise-free exact-arc velocity motion with its Jacobians.

    Parameters
    ----------
    x : ndarray, shape (3,) or (..., 3)
        Pose(s) ``[x, y, theta]``.
    u : ndarray, shape (2,) or (..., 2)
        Control(s) ``[v, omega]``; broadcasts against `x` over leading axes.
    dt : float
        Duration of the control, non-negative seconds.

    Returns
    -------
    x_next : ndarray, shape (..., 3)
        Pose after the arc; heading wrapped to ``[-pi, pi)``.
    G : ndarray, shape (..., 3, 3)
        Jacobian ``d x_next / d x``.
    V : ndarray, shape (..., 3, 2)
        Jacobian ``d x_next / d u``.

    Notes
    -----
    For ``abs(omega) < 1e-6`` the straight-line limit is used, with
    ``G[0, 2] = -v dt sin(theta)``, ``G[1, 2] = v dt cos(theta)`` and
    ``V = [[dt cos, -v dt^2 sin / 2], [dt sin, v dt^2 cos / 2], [0, dt]]``
    (the limit of the arc Jacobian). Otherwise the chord form of the arc
    (module docstring) is used, which is accurate for every ``omega``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 5.3 (without noise), Eq. 5.9;
    Table 7.2 lines 2-4 (``G``, ``V``).
    """
    x = as_poses(x, "x", batched=True)
    u = as_vector(u, "u", 2)
    dt = as_scalar(dt, "dt", nonnegative=True)
    check_batch((x, 1, "x"), (u, 1, "u"))
    return _arc(x, u, dt)


def velocity_noise_cov(u, alpha):
    """Control-noise covariance of the velocity model.

    Parameters
    ----------
    u : ndarray, shape (2,) or (..., 2)
        Control(s) ``[v, omega]``.
    alpha : ndarray, shape (4,)
        Non-negative noise parameters ``[a1, a2, a3, a4]``: the variance of
        ``v`` is ``a1 v^2 + a2 omega^2`` and that of ``omega`` is
        ``a3 v^2 + a4 omega^2`` (the first four parameters of Table 5.3).

    Returns
    -------
    M : ndarray, shape (..., 2, 2)
        ``diag(a1 v^2 + a2 omega^2, a3 v^2 + a4 omega^2)``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 7.2 line 5.
    """
    u = as_vector(u, "u", 2)
    a = as_array(alpha, "alpha", (4,), nonnegative=True)
    v2, w2 = u[..., 0] ** 2, u[..., 1] ** 2
    M = np.zeros(u.shape[:-1] + (2, 2))
    # M = diag(a1 v^2 + a2 w^2, a3 v^2 + a4 w^2)  (Table 7.2 line 5)
    M[..., 0, 0] = a[0] * v2 + a[1] * w2
    M[..., 1, 1] = a[2] * v2 + a[3] * w2
    return M


def sample_motion_model_velocity(x, u, dt, alpha, *, rng):
    """Draw successor poses from the velocity motion model.

    Parameters
    ----------
    x : ndarray, shape (M, 3) or (3,)
        Pose(s) ``[x, y, theta]``.
    u : ndarray, shape (2,) or broadcastable (M, 2)
        Commanded control ``[v, omega]``.
    dt : float
        Duration, non-negative seconds.
    alpha : ndarray, shape (6,)
        Non-negative ``[a1, ..., a6]``: variances ``a1 v^2 + a2 w^2`` (of
        ``v``), ``a3 v^2 + a4 w^2`` (of ``omega``), ``a5 v^2 + a6 w^2`` (of the
        final rotation rate ``gamma``).
    rng : numpy.random.Generator
        Source of randomness: one ``standard_normal(shape + (3,))`` draw, the
        last axis being the ``v``, ``omega`` and ``gamma`` noise.

    Returns
    -------
    ndarray, shape (M, 3) or (3,)
        Samples; headings wrapped.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 5.3.
    """
    x = as_poses(x, "x", ndim=(1, 2))
    u = as_array(u, "u", ndim=(1, 2))
    if u.shape[-1] != 2:
        raise ValueError(f"u must have shape (2,) or (M, 2), got {u.shape}")
    shape = check_batch((x, 1, "x"), (u, 1, "u"))
    dt = as_scalar(dt, "dt", nonnegative=True)
    a = as_array(alpha, "alpha", (6,), nonnegative=True)
    check_rng(rng)
    v, w = u[..., 0], u[..., 1]
    std = np.sqrt(np.stack([a[0] * v**2 + a[1] * w**2, a[2] * v**2 + a[3] * w**2, a[4] * v**2 + a[5] * w**2], axis=-1))
    eps = rng.standard_normal(shape + (3,)) * std
    # v_hat = v + sample(a1 v^2 + a2 w^2), w_hat = ..., gamma_hat = ...  (Table 5.3 lines 1-3)
    u_hat = np.broadcast_to(u, shape + (2,)) + eps[..., :2]
    x_next, _, _ = _arc(np.broadcast_to(x, shape + (3,)), u_hat, dt)
    # theta' = theta + w_hat dt + gamma_hat dt  (Table 5.3 line 6)
    x_next[..., 2] = wrap_angle(x_next[..., 2] + eps[..., 2] * dt)
    return x_next


def _velocity_inverse(x_next, x, dt):
    """Recover ``(v_hat, w_hat, gamma_hat)`` of the arc from ``x`` to ``x_next``.

    The circle through both positions tangent to the heading at ``x`` (Table
    5.1 lines 2-5) is found from the chord: in the robot frame the chord
    points at ``dtheta / 2`` (forward motion) or ``pi + dtheta / 2``
    (backward), and its length is ``|v| dt sinc(dtheta / 2)``. The arc with
    ``|dtheta| <= pi`` is chosen (Table 5.1 with its angle difference
    wrapped and a signed radius).
    """
    dx = x_next[..., 0] - x[..., 0]
    dy = x_next[..., 1] - x[..., 1]
    c, s = np.cos(x[..., 2]), np.sin(x[..., 2])
    fwd = c * dx + s * dy
    left = -s * dx + c * dy
    sign = np.where(fwd >= 0, 1.0, -1.0)
    half = np.arctan2(sign * left, sign * fwd)  # dtheta / 2, in [-pi/2, pi/2]
    chord = sign * np.hypot(dx, dy)
    w_hat = 2.0 * half / dt  # (Table 5.1 line 8)
    v_hat = chord / (dt * _sinc(half))  # = dtheta / dt * r*  (Table 5.1 line 7)
    gamma_hat = wrap_angle(x_next[..., 2] - x[..., 2] - 2.0 * half) / dt  # (Table 5.1 line 9)
    return v_hat, w_hat, gamma_hat


def motion_model_velocity(x_next, u, x, dt, alpha, *, log=False):
    """Density of the velocity motion model.

    Parameters
    ----------
    x_next : ndarray, shape (M, 3) or (3,)
        Hypothesised successor pose(s).
    u : ndarray, shape (2,)
        Control ``[v, omega]``.
    x : ndarray, shape (M, 3) or (3,)
        Pose(s) before the motion; broadcasts against `x_next`.
    dt : float
        Duration, positive seconds.
    alpha : ndarray, shape (6,)
        Noise parameters as in :func:`sample_motion_model_velocity`.
    log : bool, keyword-only
        Return the log-density instead.

    Returns
    -------
    ndarray, shape (M,) or ()
        ``prob(v - v_hat, a1 v^2 + a2 w^2) prob(w - w_hat, a3 v^2 + a4 w^2)
        prob(gamma_hat, a5 v^2 + a6 w^2)`` with normal densities (Table 5.2).

    Notes
    -----
    Like Table 5.1 this is the density of the recovered controls
    ``(v_hat, w_hat, gamma_hat)``; as a density over ``x_next`` it carries the
    Jacobian factor ``1 / (|v_hat| dt^4 sinc(w_hat dt / 2)^2 / 2)``.
    The arc is recovered in a numerically stable chord form (see
    ``_velocity_inverse``); a variance below ``1e-12`` is raised to it.

    References
    ----------
    Thrun, Burgard & Fox (2005), Tables 5.1 and 5.2.
    """
    x_next = as_poses(x_next, "x_next", ndim=(1, 2))
    u = as_array(u, "u", (2,))
    x = as_poses(x, "x", ndim=(1, 2))
    check_batch((x_next, 1, "x_next"), (x, 1, "x"))
    dt = as_scalar(dt, "dt", positive=True)
    a = as_array(alpha, "alpha", (6,), nonnegative=True)
    v, w = u
    v_hat, w_hat, gamma_hat = _velocity_inverse(x_next, x, dt)
    var = np.maximum([a[0] * v**2 + a[1] * w**2, a[2] * v**2 + a[3] * w**2, a[4] * v**2 + a[5] * w**2], _VAR_FLOOR)
    lp = _log_normal(v - v_hat, var[0]) + _log_normal(w - w_hat, var[1]) + _log_normal(gamma_hat, var[2])
    return lp if log else np.exp(lp)


# --------------------------------------------------------------------------- odometry model
def odometry_from_poses(x_prev, x_next):
    """Odometry control ``[rot1, trans, rot2]`` taking one pose to another.

    Parameters
    ----------
    x_prev, x_next : ndarray, shape (..., 3)
        Poses before and after the motion; they broadcast.

    Returns
    -------
    u : ndarray, shape (..., 3)
        ``rot1 = wrap(atan2(dy, dx) - theta)``, ``trans = hypot(dx, dy)`` (never
        negative: backward motion shows up as ``rot1`` near ``pi``),
        ``rot2 = wrap(theta' - theta - rot1)``. When ``trans <= 1e-9`` (a
        rotation on the spot) ``rot1 = 0`` and the whole turn is ``rot2``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 5.5 lines 2-4.
    """
    x_prev = as_poses(x_prev, "x_prev", batched=True)
    x_next = as_poses(x_next, "x_next", batched=True)
    check_batch((x_prev, 1, "x_prev"), (x_next, 1, "x_next"))
    return _odometry_from_poses(x_prev, x_next)


def _odometry_from_poses(x_prev, x_next):
    dx = x_next[..., 0] - x_prev[..., 0]
    dy = x_next[..., 1] - x_prev[..., 1]
    trans = np.hypot(dx, dy)  # (Table 5.5 line 3)
    rot1 = np.where(trans > MIN_TRANS, wrap_angle(np.arctan2(dy, dx) - x_prev[..., 2]), 0.0)  # (line 2)
    rot2 = wrap_angle(x_next[..., 2] - x_prev[..., 2] - rot1)  # (line 4)
    return np.stack(np.broadcast_arrays(rot1, trans, rot2), axis=-1)


def odometry_motion(x, u):
    """Apply an odometry control without noise.

    Parameters
    ----------
    x : ndarray, shape (..., 3)
        Pose(s).
    u : ndarray, shape (..., 3)
        Control(s) ``[rot1, trans, rot2]``; broadcasts against `x`.

    Returns
    -------
    ndarray, shape (..., 3)
        ``[x + trans cos(theta + rot1), y + trans sin(theta + rot1),
        wrap(theta + rot1 + rot2)]``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 5.6 lines 5-7 (without noise).
    """
    x = as_poses(x, "x", batched=True)
    u = as_array(u, "u", ndim=range(1, 33))
    if u.shape[-1] != 3:
        raise ValueError(f"u must have shape (3,) or (..., 3), got {u.shape}")
    check_batch((x, 1, "x"), (u, 1, "u"))
    return _odometry_apply(x, u[..., 0], u[..., 1], u[..., 2])


def _odometry_apply(x, rot1, trans, rot2):
    shape = np.broadcast_shapes(x.shape[:-1], np.shape(rot1), np.shape(trans), np.shape(rot2))
    out = np.empty(shape + (3,))
    heading = x[..., 2] + rot1
    out[..., 0] = x[..., 0] + trans * np.cos(heading)  # (Table 5.6 line 5)
    out[..., 1] = x[..., 1] + trans * np.sin(heading)  # (line 6)
    out[..., 2] = wrap_angle(heading + rot2)  # (line 7)
    return out


def _odometry_vars(rot1, trans, rot2, a):
    # variances of Table 5.5 lines 8-10 / Table 5.6 lines 2-4
    return (
        a[0] * rot1**2 + a[1] * trans**2,
        a[2] * trans**2 + a[3] * (rot1**2 + rot2**2),
        a[0] * rot2**2 + a[1] * trans**2,
    )


def sample_motion_model_odometry(x, u, alpha, *, rng):
    """Draw successor poses from the odometry motion model.

    Parameters
    ----------
    x : ndarray, shape (M, 3) or (3,)
        Pose(s) ``[x, y, theta]``.
    u : ndarray, shape (3,)
        Odometry control ``[rot1, trans, rot2]`` shared by all poses.
    alpha : ndarray, shape (4,)
        Non-negative ``[a1, a2, a3, a4]``. The noises are normal with
        **variances** ``a1 rot1^2 + a2 trans^2`` (rot1),
        ``a3 trans^2 + a4 (rot1^2 + rot2^2)`` (trans) and
        ``a1 rot2^2 + a2 trans^2`` (rot2).
    rng : numpy.random.Generator
        Source of randomness: one ``standard_normal(x.shape[:-1] + (3,))``
        draw, the last axis being the rot1, trans and rot2 noise.

    Returns
    -------
    ndarray, shape (M, 3) or (3,)
        Samples; headings wrapped.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 5.6.
    """
    x = as_poses(x, "x", ndim=(1, 2))
    u = as_array(u, "u", (3,))
    a = as_array(alpha, "alpha", (4,), nonnegative=True)
    check_rng(rng)
    rot1, trans, rot2 = u
    std = np.sqrt(np.array(_odometry_vars(rot1, trans, rot2, a)))
    eps = rng.standard_normal(x.shape[:-1] + (3,)) * std
    # rot1_hat = rot1 - sample(a1 rot1^2 + a2 trans^2), ...  (Table 5.6 lines 2-4)
    return _odometry_apply(x, rot1 - eps[..., 0], trans - eps[..., 1], rot2 - eps[..., 2])


def motion_model_odometry(x_next, u, x, alpha, *, log=False):
    """Density of the odometry motion model.

    Parameters
    ----------
    x_next : ndarray, shape (M, 3) or (3,)
        Hypothesised successor pose(s).
    u : ndarray, shape (3,)
        Odometry control ``[rot1, trans, rot2]``.
    x : ndarray, shape (M, 3) or (3,)
        Pose(s) before the motion; broadcasts against `x_next`.
    alpha : ndarray, shape (4,)
        Noise parameters as in :func:`sample_motion_model_odometry`.
    log : bool, keyword-only
        Return the log-density instead.

    Returns
    -------
    ndarray, shape (M,) or ()
        Product of the three normal densities (Table 5.2) of
        ``wrap(rot1 - rot1_hat)``, ``trans - trans_hat``, ``wrap(rot2 - rot2_hat)``
        with the variances evaluated at the hypothesis increments
        ``(rot1_hat, trans_hat, rot2_hat) = odometry_from_poses(x, x_next)``.

    Notes
    -----
    This is a density over the increments ``(rot1, trans, rot2)``; as a density
    over ``x_next`` it carries the factor ``1 / trans_hat`` (the Jacobian of
    the polar step). A variance below ``1e-12`` (for instance ``x_next == x``)
    is raised to it, so the result stays finite.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 5.5.
    """
    x_next = as_poses(x_next, "x_next", ndim=(1, 2))
    u = as_array(u, "u", (3,))
    x = as_poses(x, "x", ndim=(1, 2))
    check_batch((x_next, 1, "x_next"), (x, 1, "x"))
    a = as_array(alpha, "alpha", (4,), nonnegative=True)
    h = _odometry_from_poses(x, x_next)
    r1h, th, r2h = h[..., 0], h[..., 1], h[..., 2]
    var1, var2, var3 = (np.maximum(vv, _VAR_FLOOR) for vv in _odometry_vars(r1h, th, r2h, a))
    # p1 p2 p3  (Table 5.5 lines 5-8)
    lp = (
        _log_normal(wrap_angle(u[0] - r1h), var1)
        + _log_normal(u[1] - th, var2)
        + _log_normal(wrap_angle(u[2] - r2h), var3)
    )
    return lp if log else np.exp(lp)


# --------------------------------------------------------------------------- dead reckoning
def dead_reckoning(x0, u, dt):
    """Integrate the controls with the noise-free velocity motion model.

    Parameters
    ----------
    x0 : ndarray, shape (3,)
        Initial pose.
    u : ndarray, shape (T, 2)
        Controls ``[v, omega]``.
    dt : float
        Step duration, seconds (non-negative).

    Returns
    -------
    ndarray, shape (T + 1, 3)
        Poses ``x_0 = x0``, ``x_{k+1} = g(u_k, x_k)``; headings wrapped.

    Notes
    -----
    Exact-arc motion has a structure that removes the step-to-step loop: the
    heading after ``k`` steps is ``theta_0 + dt sum_{i<k} omega_i`` whatever
    the positions, and the displacement of step ``k`` depends only on that
    heading and ``u_k``. So all headings come from one cumulative sum, all
    displacements from one batched call of
    :func:`velocity_motion`, and the positions from a second
    cumulative sum. The result equals step-by-step integration up to
    floating-point rounding.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 5.3 (without noise), Eq. 5.9.
    """
    x0 = as_array(x0, "x0", (3,))
    u = as_array(u, "u", (None, 2))
    dt = as_scalar(dt, "dt", nonnegative=True)
    T = u.shape[0]
    theta = np.empty(T + 1)
    theta[0] = x0[2]
    # theta_{k+1} = theta_k + omega_k dt  (Table 5.3 line 7 without noise)
    theta[1:] = x0[2] + np.cumsum(u[:, 1] * dt)
    start = np.zeros((T, 3))
    start[:, 2] = theta[:-1]
    step, _, _ = _arc(start, u, dt)  # displacement of each step from the origin
    out = np.empty((T + 1, 3))
    out[0, :2] = x0[:2]
    out[1:, :2] = x0[:2] + np.cumsum(step[:, :2], axis=0)
    out[:, 2] = wrap_angle(theta)
    return out


# --------------------------------------------------------------------------- Ackermann (car) model
__all__ += ["AckermannModel", "ackermann_motion"]


def _ackermann(x, u, dt, a, b, H, L, jacobians=True):
    """Ackermann motion of the laser pose with its Jacobians (unchecked, broadcasts over leading axes).

    ``jacobians=False`` returns the pose alone (what a particle filter's sampling needs)."""
    x = np.asarray(x, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)
    th, ve, al = x[..., 2], u[..., 0], u[..., 1]
    ta = np.tan(al)
    k = 1.0 / (1.0 - ta * H / L)
    vc = ve * k  # v_c = v_e / (1 - tan(alpha) H / L): rear-left encoder speed moved to the axle centre
    w = vc * ta / L  # heading rate of the bicycle model, v_c tan(alpha) / L
    c, s = np.cos(th), np.sin(th)
    ps = a * s + b * c  # lever arm of the laser, rotated: a sin + b cos
    pc = a * c - b * s  # a cos - b sin
    shape = np.broadcast_shapes(th.shape, ve.shape)
    x_next = np.empty(shape + (3,))
    # laser velocity = axle-centre velocity + omega x (laser offset), Euler over dt
    x_next[..., 0] = x[..., 0] + dt * (vc * c - w * ps)
    x_next[..., 1] = x[..., 1] + dt * (vc * s + w * pc)
    x_next[..., 2] = _wrap(th + dt * w)
    if not jacobians:
        return x_next
    sec2 = 1.0 + ta * ta
    G = np.zeros(shape + (3, 3))
    G[..., 0, 0] = G[..., 1, 1] = G[..., 2, 2] = 1.0
    G[..., 0, 2] = dt * (-vc * s - w * pc)  # d x' / d theta
    G[..., 1, 2] = dt * (vc * c - w * ps)  # d y' / d theta
    dvc = np.stack(np.broadcast_arrays(k, ve * k * k * (H / L) * sec2), axis=-1)  # d v_c / d [v_e, alpha]
    dw = np.stack(np.broadcast_arrays(k * ta / L, (dvc[..., 1] * ta + vc * sec2) / L), axis=-1)  # d omega / d u
    V = np.empty(shape + (3, 2))
    V[..., 0, :] = dt * (dvc * c[..., None] - dw * ps[..., None])
    V[..., 1, :] = dt * (dvc * s[..., None] + dw * pc[..., None])
    V[..., 2, :] = dt * dw
    return x_next, G, V


def _ackermann1(x, u, dt, a, b, H, L):
    """One pose with Python floats: the scalar path of :func:`_ackermann` (same equations, tested against it)."""
    th, ve, al = float(x[2]), float(u[0]), float(u[1])
    ta = math.tan(al)
    sec2 = 1.0 + ta * ta
    k = 1.0 / (1.0 - ta * H / L)
    vc = ve * k  # v_c = v_e / (1 - tan(alpha) H / L)
    w = vc * ta / L  # omega = v_c tan(alpha) / L
    c, s = math.cos(th), math.sin(th)
    ps, pc = a * s + b * c, a * c - b * s
    x_next = np.array([x[0] + dt * (vc * c - w * ps), x[1] + dt * (vc * s + w * pc), _wrap1(th + dt * w)])
    G = np.array([[1.0, 0.0, dt * (-vc * s - w * pc)], [0.0, 1.0, dt * (vc * c - w * ps)], [0.0, 0.0, 1.0]])
    dv0, dv1 = k, ve * k * k * (H / L) * sec2  # d v_c / d [v_e, alpha]
    dw0, dw1 = k * ta / L, (dv1 * ta + vc * sec2) / L  # d omega / d [v_e, alpha]
    V = np.array([[dt * (dv0 * c - dw0 * ps), dt * (dv1 * c - dw1 * ps)],
                  [dt * (dv0 * s + dw0 * pc), dt * (dv1 * s + dw1 * pc)],
                  [dt * dw0, dt * dw1]])
    return x_next, G, V


def ackermann_motion(x, u, dt, *, a, b, H, L):
    """Noise-free motion of a car-like vehicle (Ackermann steering) with a laser offset, and its Jacobians.

    The pose ``[x, y, theta]`` is that of the **laser** (the sensor the
    landmarks are measured from), not of the rear axle, so the range-bearing
    measurement model stays the usual one. The control ``u = [v_e, alpha]``
    is the speed measured by an encoder on the rear left wheel and the
    steering angle.

    Parameters
    ----------
    x : ndarray, shape (3,) or (..., 3)
        Laser pose(s) ``[x, y, theta]``.
    u : ndarray, shape (2,) or (..., 2)
        Control(s) ``[v_e, alpha]`` (m/s, rad); broadcasts against `x`.
    dt : float
        Duration of the control, non-negative seconds.
    a, b : float, keyword-only
        Laser position in the car frame, metres: `a` ahead of the rear axle,
        `b` to the left of the car's centre line.
    H : float, keyword-only
        Lateral distance from the encoder wheel to the centre line, metres.
    L : float, keyword-only
        Wheel base (rear to front axle), metres.

    Returns
    -------
    x_next : ndarray, shape (..., 3)
        Laser pose after ``dt``; heading wrapped to ``[-pi, pi)``.
    G : ndarray, shape (..., 3, 3)
        Jacobian ``d x_next / d x``.
    V : ndarray, shape (..., 3, 2)
        Jacobian ``d x_next / d u``.

    Notes
    -----
    With ``v_c = v_e / (1 - tan(alpha) H / L)`` the speed of the rear-axle
    centre and ``omega = v_c tan(alpha) / L`` the turn rate of the bicycle
    model, the laser at ``(a, b)`` in the car frame moves with
    ``v_c [cos, sin] + omega [-(a sin + b cos), a cos - b sin]``; one Euler
    step of length ``dt`` gives

    ``x' = x + dt (v_c cos(theta) - omega (a sin(theta) + b cos(theta)))``,
    ``y' = y + dt (v_c sin(theta) + omega (a cos(theta) - b sin(theta)))``,
    ``theta' = theta + dt omega``.

    References
    ----------
    J. Guivant, E. Nebot, "Optimization of the simultaneous localization and
    map-building algorithm for real-time implementation", IEEE T-RA 17(3),
    2001 (the vehicle model); Thrun, Burgard & Fox (2005), Table 7.2 (the
    Jacobians ``G``, ``V`` an EKF needs).
    """
    x = as_poses(x, "x", batched=True)
    u = as_vector(u, "u", 2)
    dt = as_scalar(dt, "dt", nonnegative=True)
    check_batch((x, 1, "x"), (u, 1, "u"))
    a = as_scalar(a, "a")
    b = as_scalar(b, "b")
    H = as_scalar(H, "H", nonnegative=True)
    L = as_scalar(L, "L", positive=True)
    if np.any(np.abs(np.tan(u[..., 1])) * H >= L):
        raise ValueError(f"u: steering angle too large for H={H}, L={L} (tan(alpha) H / L must stay below 1)")
    return _ackermann(x, u, dt, a, b, H, L)


class AckermannModel:
    """The car model of :func:`ackermann_motion` as a motion model the filters can take (``motion=``).

    Calling ``model(x, u, dt)`` returns ``(x_next, G, V)`` like
    :func:`velocity_motion`, for one pose or a batch (unchecked: the filters
    validate their inputs once).

    Parameters
    ----------
    a, b, H, L : float
        Car geometry, metres (see :func:`ackermann_motion`).
    """

    def __init__(self, a, b, H, L):
        self.a = as_scalar(a, "a")
        self.b = as_scalar(b, "b")
        self.H = as_scalar(H, "H", nonnegative=True)
        self.L = as_scalar(L, "L", positive=True)

    def __call__(self, x, u, dt):
        if np.ndim(x) == 1 and np.ndim(u) == 1:
            return _ackermann1(x, u, dt, self.a, self.b, self.H, self.L)
        return _ackermann(x, u, dt, self.a, self.b, self.H, self.L)

    def pose(self, x, u, dt):
        """``x_next`` of ``model(x, u, dt)`` alone, without the Jacobians (the particle filters' sampling)."""
        if np.ndim(x) == 1 and np.ndim(u) == 1:
            return _ackermann1(x, u, dt, self.a, self.b, self.H, self.L)[0]
        return _ackermann(x, u, dt, self.a, self.b, self.H, self.L, jacobians=False)

    def __repr__(self):
        return f"AckermannModel(a={self.a}, b={self.b}, H={self.H}, L={self.L})"
