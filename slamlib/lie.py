"""Rotations and rigid motions in 3-D: SO(3) and SE(3), their exponential and logarithm.

A rotation is a matrix ``R (3, 3)`` (orthonormal, ``det R = +1``); a rigid motion (a
pose) is a homogeneous matrix ``T = [[R, t], [0, 0, 0, 1]] (4, 4)``. Every function takes
a batch over leading axes (``(..., 3)``, ``(..., 3, 3)``, ``(..., 4, 4)``) and broadcasts.

Tangent vectors:

* a rotation vector ``w (3,)``, ``[w]x`` the skew matrix with ``[w]x v = w x v``
  (:func:`skew`, alias :func:`hat`; :func:`vee` is its inverse), and Rodrigues' formula
  ``Exp(w) = I + sin(a)/a [w]x + (1 - cos a)/a^2 [w]x^2``, ``a = |w|`` (:func:`so3_exp`);
* a twist ``xi = [rho (3), phi (3)]`` (**translation first**), whose exponential is
  ``exp(xi) = [[Exp(phi), J_l(phi) rho], [0, 1]]`` (:func:`se3_exp`).

Perturbation of a pose (the convention of the course's homework contract, section 7):
``T (+) delta = (R Exp(phi), t + R rho)`` for ``delta = [rho, phi]`` (:func:`se3_plus`);
its inverse is :func:`se3_minus`. To first order in ``delta`` it equals ``T exp(delta)``.
Jacobians are taken at ``delta = 0``.

Near the singular angles the formulas switch to forms without cancellation: series or
``sinc`` near ``a = 0``, and near ``a = pi`` the logarithm reads the axis from the
symmetric part of ``R`` and its sign from ``R - R^T`` (the angle is
``atan2(|vee(R - R^T)|/2, (tr R - 1)/2)``, accurate at every angle).

References
----------
J. Sola, J. Deray, D. Atchuthan, "A micro Lie theory for state estimation in robotics",
arXiv:1812.01537, 2018 (Eqs. 143-146 so3, 172-180 se3). T. D. Barfoot, *State Estimation
for Robotics* (2017), Sec. 7.1 (Eqs. 7.83-7.86, the ``Q`` block of the SE(3) Jacobian).
"""

from __future__ import annotations

import numpy as np

from ._checks import ROTATION_ATOL, as_matrix, as_rigid_motions, as_rotations, as_vector  # noqa: F401 (re-exported tolerance)

__all__ = [
    "skew",
    "hat",
    "vee",
    "so3_exp",
    "so3_log",
    "so3_right_jacobian",
    "so3_right_jacobian_inv",
    "so3_left_jacobian",
    "so3_left_jacobian_inv",
    "quat_to_so3",
    "so3_to_quat",
    "euler_to_so3",
    "so3_to_euler",
    "se3",
    "se3_exp",
    "se3_log",
    "se3_compose",
    "se3_inverse",
    "se3_adjoint",
    "se3_right_jacobian_inv",
    "se3_plus",
    "se3_minus",
]

#: Below this angle the Jacobian coefficients use their Taylor series (the direct forms
#: lose digits to cancellation there).
_SMALL = 1e-3


def _rotations(R, name):
    return as_rotations(R, name, copy=False)


def _poses(T, name):
    return as_rigid_motions(T, name, copy=False)


# --------------------------------------------------------------------------- cores


def _skew(w):
    z = np.zeros(w.shape[:-1])
    x, y, c = w[..., 0], w[..., 1], w[..., 2]
    return np.stack([np.stack([z, -c, y], -1), np.stack([c, z, -x], -1), np.stack([-y, x, z], -1)], -2)


def _vee(M):
    return 0.5 * np.stack([M[..., 2, 1] - M[..., 1, 2], M[..., 0, 2] - M[..., 2, 0], M[..., 1, 0] - M[..., 0, 1]], -1)


def _sinc(a):
    return np.sinc(a / np.pi)  # sin(a)/a, exact 1 at 0


def _rodrigues_coefficients(a):
    """``A = sin(a)/a`` and ``B = (1 - cos a)/a^2``, accurate down to ``a = 0``."""
    return _sinc(a), 0.5 * _sinc(0.5 * a) ** 2  # (1 - cos a)/a^2 = 2 sin^2(a/2)/a^2: no cancellation


def _coefficients(a):
    """``A``, ``B`` (:func:`_rodrigues_coefficients`) and ``C = (a - sin a)/a^3``, accurate down to ``a = 0``."""
    A, B = _rodrigues_coefficients(a)
    small = a < _SMALL
    a2 = a * a
    with np.errstate(divide="ignore", invalid="ignore"):
        C = np.where(small, 1.0 / 6.0 - a2 / 120.0 + a2 * a2 / 5040.0, (a - np.sin(a)) / (a2 * a))
    return A, B, C


def _so3_exp(w):
    a = np.linalg.norm(w, axis=-1)
    A, B = _rodrigues_coefficients(a)
    K = _skew(w)
    return np.eye(3) + A[..., None, None] * K + B[..., None, None] * (K @ K)  # Rodrigues


def _so3_log(R):
    s = _vee(R)  # sin(a) n
    sn = np.linalg.norm(s, axis=-1)
    c = 0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0)  # cos(a)
    a = np.arctan2(sn, c)
    with np.errstate(divide="ignore", invalid="ignore"):
        return _so3_log_branches(R, s, c, a)


def _so3_log_branches(R, s, c, a):
    # away from pi: w = a / sin(a) * s
    w_small = s / _sinc(a)[..., None]
    # near pi: n n^T = ((R + R^T)/2 - c I) / (1 - c); the column with the largest diagonal
    S = 0.5 * (R + np.swapaxes(R, -1, -2)) - c[..., None, None] * np.eye(3)
    d = np.diagonal(S, axis1=-2, axis2=-1)
    k = np.argmax(d, axis=-1)
    col = np.take_along_axis(S, k[..., None, None], axis=-1)[..., 0]
    n = col / np.linalg.norm(col, axis=-1, keepdims=True)
    sign = np.where(np.sum(n * s, axis=-1) < 0.0, -1.0, 1.0)
    w_pi = (sign * a)[..., None] * n
    return np.where((c < -0.5)[..., None], w_pi, w_small)


def _so3_jr(w, sign=1.0):
    """Right Jacobian ``J_r(w) = I - B [w]x + C [w]x^2``; ``sign=-1`` gives the left one ``J_l(w) = J_r(-w)``."""
    a = np.linalg.norm(w, axis=-1)
    _, B, C = _coefficients(a)
    K = _skew(w)
    return np.eye(3) - sign * B[..., None, None] * K + C[..., None, None] * (K @ K)


def _so3_jr_inv(w, sign=1.0):
    """``J_r(w)^-1 = I + [w]x / 2 + D [w]x^2``, ``D = 1/a^2 - cos(a/2) / (2 a sin(a/2))`` (finite at pi)."""
    a = np.linalg.norm(w, axis=-1)
    a2 = a * a
    with np.errstate(divide="ignore", invalid="ignore"):
        D = np.where(a < _SMALL, 1.0 / 12.0 + a2 / 720.0 + a2 * a2 / 30240.0,
                     1.0 / a2 - np.cos(0.5 * a) / (2.0 * a * np.sin(0.5 * a)))
    K = _skew(w)
    return np.eye(3) + sign * 0.5 * K + D[..., None, None] * (K @ K)


def _se3(R, t):
    T = np.zeros(R.shape[:-2] + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def _se3_exp(xi):
    rho, phi = xi[..., :3], xi[..., 3:]
    return _se3(_so3_exp(phi), (_so3_jr(phi, -1.0) @ rho[..., None])[..., 0])


def _se3_log(T):
    phi = _so3_log(T[..., :3, :3])
    rho = (_so3_jr_inv(phi, -1.0) @ T[..., :3, 3, None])[..., 0]
    return np.concatenate([rho, phi], -1)


def _se3_inverse(T):
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return _se3(Rt, -(Rt @ T[..., :3, 3, None])[..., 0])


def _se3_adjoint(T):
    R, t = T[..., :3, :3], T[..., :3, 3]
    Ad = np.zeros(T.shape[:-2] + (6, 6))
    Ad[..., :3, :3] = R
    Ad[..., :3, 3:] = _skew(t) @ R
    Ad[..., 3:, 3:] = R
    return Ad


def _q_block(rho, phi):
    """Barfoot's ``Q(rho, phi)``: the upper-right block of the left SE(3) Jacobian (Eq. 7.86; signs as in Sola et al. Eq. 180)."""
    a = np.linalg.norm(phi, axis=-1)
    a2 = a * a
    small = a < _SMALL
    safe = np.where(small, 1.0, a)
    s2 = safe * safe
    c1 = np.where(small, 1.0 / 6.0 - a2 / 120.0, (safe - np.sin(safe)) / (s2 * safe))
    c2 = np.where(small, 1.0 / 24.0 - a2 / 720.0, (0.5 * s2 + np.cos(safe) - 1.0) / (s2 * s2))
    c3 = np.where(small, 1.0 / 120.0 - a2 / 2520.0,
                  -0.5 * ((1.0 - 0.5 * s2 - np.cos(safe)) / (s2 * s2)
                         - 3.0 * (safe - np.sin(safe) - s2 * safe / 6.0) / (s2 * s2 * safe)))
    P, V = _skew(phi), _skew(rho)
    PV, VP = P @ V, V @ P
    PVP = PV @ P
    e = lambda c: c[..., None, None]  # noqa: E731
    return (0.5 * V + e(c1) * (PV + VP + PVP) + e(c2) * (P @ PV + VP @ P - 3.0 * PVP)
            + e(c3) * (PVP @ P + P @ PVP))


def _se3_jr_inv(xi):
    """Inverse right Jacobian of SE(3) (``[rho, phi]`` order): ``J_r(xi)^-1 = J_l(-xi)^-1``."""
    rho, phi = -xi[..., :3], -xi[..., 3:]
    Jli = _so3_jr_inv(phi, -1.0)
    Q = _q_block(rho, phi)
    out = np.zeros(xi.shape[:-1] + (6, 6))
    out[..., :3, :3] = Jli
    out[..., 3:, 3:] = Jli
    out[..., :3, 3:] = -Jli @ Q @ Jli
    return out


def _se3_plus(T, delta):
    R, t = T[..., :3, :3], T[..., :3, 3]
    return _se3(R @ _so3_exp(delta[..., 3:]), t + (R @ delta[..., :3, None])[..., 0])


def _se3_minus(T1, T0):
    R0t = np.swapaxes(T0[..., :3, :3], -1, -2)
    rho = (R0t @ (T1[..., :3, 3] - T0[..., :3, 3])[..., None])[..., 0]
    return np.concatenate([rho, _so3_log(R0t @ T1[..., :3, :3])], -1)


def _quat_to_so3(q):
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], -2)


def _euler_to_so3(rpy):
    r, p, y = rpy[..., 0], rpy[..., 1], rpy[..., 2]
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.stack([
        np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
        np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
        np.stack([-sp, cp * sr, cp * cr], -1)], -2)


# --------------------------------------------------------------------------- public faces


def skew(w):
    """The skew-symmetric matrix ``[w]x`` with ``[w]x v = w x v``.

    Parameters
    ----------
    w : array_like, shape (3,) or (..., 3)

    Returns
    -------
    ndarray, shape (3, 3) or (..., 3, 3)
    """
    return _skew(as_vector(w, "w", 3, copy=False))


hat = skew


def vee(M):
    """The vector ``w`` with ``[w]x = (M - M^T)/2``: the inverse of :func:`skew` on skew matrices.

    Parameters
    ----------
    M : array_like, shape (3, 3) or (..., 3, 3)
        A skew-symmetric matrix (any square matrix: its skew part is read).

    Returns
    -------
    ndarray, shape (3,) or (..., 3)
    """
    return _vee(as_matrix(M, "M", 3, 3, copy=False))


def so3_exp(w):
    """The rotation ``Exp(w)`` of a rotation vector (Rodrigues' formula), accurate down to ``w = 0``.

    Parameters
    ----------
    w : array_like, shape (3,) or (..., 3)
        Rotation vector: axis times angle (radians).

    Returns
    -------
    R : ndarray, shape (3, 3) or (..., 3, 3)

    References
    ----------
    Sola et al. (2018), Eq. 143; ``(1 - cos a)/a^2`` computed as ``2 sin^2(a/2)/a^2``.
    """
    return _so3_exp(as_vector(w, "w", 3, copy=False))


def so3_log(R):
    """The rotation vector ``w`` with ``Exp(w) = R`` and ``|w| <= pi``, accurate at every angle.

    The angle is ``atan2(|vee(R - R^T)|/2, (tr R - 1)/2)``. For angles below ``2 pi / 3``
    the axis is ``vee(R - R^T)/2`` divided by ``sin(a)``; above, it is read from the
    symmetric part ``(R + R^T)/2 - cos(a) I = (1 - cos a) n n^T`` and its sign from
    ``R - R^T`` (either sign where ``R`` is symmetric, at ``a = pi``).

    Parameters
    ----------
    R : array_like, shape (3, 3) or (..., 3, 3)
        Rotation matrices (orthonormal, det +1, up to ``ROTATION_ATOL``).

    Returns
    -------
    w : ndarray, shape (3,) or (..., 3)
    """
    return _so3_log(_rotations(R, "R"))


def so3_right_jacobian(w):
    """The right Jacobian of SO(3): ``Exp(w + dw) ~ Exp(w) Exp(J_r(w) dw)``.

    ``J_r(w) = I - (1 - cos a)/a^2 [w]x + (a - sin a)/a^3 [w]x^2`` (Sola et al. Eq. 143).

    Parameters
    ----------
    w : array_like, shape (3,) or (..., 3)

    Returns
    -------
    ndarray, shape (3, 3) or (..., 3, 3)
    """
    return _so3_jr(as_vector(w, "w", 3, copy=False))


def so3_right_jacobian_inv(w):
    """The inverse right Jacobian: ``Log(Exp(w) Exp(dw)) ~ w + J_r(w)^-1 dw`` (finite for ``|w| <= pi``).

    ``J_r(w)^-1 = I + [w]x / 2 + (1/a^2 - (1 + cos a)/(2 a sin a)) [w]x^2`` (Sola et al. Eq. 144).

    Parameters
    ----------
    w : array_like, shape (3,) or (..., 3)

    Returns
    -------
    ndarray, shape (3, 3) or (..., 3, 3)
    """
    return _so3_jr_inv(as_vector(w, "w", 3, copy=False))


def so3_left_jacobian(w):
    """The left Jacobian ``J_l(w) = J_r(-w)``: ``Exp(w + dw) ~ Exp(J_l(w) dw) Exp(w)``; also the ``V`` of :func:`se3_exp`."""
    return _so3_jr(as_vector(w, "w", 3, copy=False), -1.0)


def so3_left_jacobian_inv(w):
    """The inverse left Jacobian ``J_l(w)^-1 = J_r(-w)^-1``."""
    return _so3_jr_inv(as_vector(w, "w", 3, copy=False), -1.0)


def quat_to_so3(q):
    """The rotation of a quaternion ``q = [qx, qy, qz, qw]`` (g2o's order; normalised here).

    Parameters
    ----------
    q : array_like, shape (4,) or (..., 4)
        Non-zero quaternions, scalar part last.

    Returns
    -------
    R : ndarray, shape (3, 3) or (..., 3, 3)
    """
    q = as_vector(q, "q", 4, copy=False)
    if q.size and np.linalg.norm(q, axis=-1).min() < 1e-12:
        raise ValueError("q must be non-zero quaternions [qx, qy, qz, qw]")
    return _quat_to_so3(q)


def so3_to_quat(R):
    """The unit quaternion ``[qx, qy, qz, qw]`` of a rotation, with ``qw >= 0``.

    Parameters
    ----------
    R : array_like, shape (3, 3) or (..., 3, 3)

    Returns
    -------
    q : ndarray, shape (4,) or (..., 4)
    """
    w = _so3_log(_rotations(R, "R"))
    a = np.linalg.norm(w, axis=-1)
    q = np.concatenate([0.5 * _sinc(0.5 * a)[..., None] * w, np.cos(0.5 * a)[..., None]], -1)  # sin(a/2) n
    return q


def euler_to_so3(rpy):
    """The rotation ``R = R_z(yaw) R_y(pitch) R_x(roll)`` of roll-pitch-yaw angles (TORO's and ROS's convention).

    Parameters
    ----------
    rpy : array_like, shape (3,) or (..., 3)
        ``[roll, pitch, yaw]`` in radians.

    Returns
    -------
    R : ndarray, shape (3, 3) or (..., 3, 3)
    """
    return _euler_to_so3(as_vector(rpy, "rpy", 3, copy=False))


def so3_to_euler(R):
    """Roll, pitch, yaw of a rotation (inverse of :func:`euler_to_so3`, pitch in ``[-pi/2, pi/2]``).

    At ``pitch = +-pi/2`` (gimbal lock) only ``yaw - roll`` (or ``yaw + roll``) is determined;
    roll is then returned as 0.

    Parameters
    ----------
    R : array_like, shape (3, 3) or (..., 3, 3)

    Returns
    -------
    rpy : ndarray, shape (3,) or (..., 3)
    """
    R = _rotations(R, "R")
    pitch = np.arctan2(-R[..., 2, 0], np.hypot(R[..., 0, 0], R[..., 1, 0]))
    locked = np.hypot(R[..., 2, 1], R[..., 2, 2]) < 1e-12
    roll = np.where(locked, 0.0, np.arctan2(R[..., 2, 1], R[..., 2, 2]))
    yaw = np.where(locked, np.arctan2(-R[..., 0, 1], R[..., 1, 1]), np.arctan2(R[..., 1, 0], R[..., 0, 0]))
    return np.stack([roll, pitch, yaw], -1)


def se3(R, t):
    """The homogeneous pose ``[[R, t], [0, 0, 0, 1]]``.

    Parameters
    ----------
    R : array_like, shape (3, 3) or (..., 3, 3)
        Rotation(s).
    t : array_like, shape (3,) or (..., 3)
        Translation(s); broadcast against `R`'s batch.

    Returns
    -------
    T : ndarray, shape (4, 4) or (..., 4, 4)
    """
    R = _rotations(R, "R")
    t = as_vector(t, "t", 3, copy=False)
    batch = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    return _se3(np.broadcast_to(R, batch + (3, 3)), np.broadcast_to(t, batch + (3,)))


def se3_exp(xi):
    """The pose ``exp(xi) = [[Exp(phi), J_l(phi) rho], [0, 1]]`` of a twist ``xi = [rho, phi]``.

    Parameters
    ----------
    xi : array_like, shape (6,) or (..., 6)
        Translation part first, rotation vector last.

    Returns
    -------
    T : ndarray, shape (4, 4) or (..., 4, 4)
    """
    return _se3_exp(as_vector(xi, "xi", 6, copy=False))


def se3_log(T):
    """The twist ``xi = [rho, phi]`` with ``exp(xi) = T`` and ``|phi| <= pi`` (inverse of :func:`se3_exp`).

    Parameters
    ----------
    T : array_like, shape (4, 4) or (..., 4, 4)

    Returns
    -------
    xi : ndarray, shape (6,) or (..., 6)
    """
    return _se3_log(_poses(T, "T"))


def se3_compose(T1, T2):
    """The product ``T1 T2`` (pose ``T2`` expressed in frame ``T1``), broadcast over leading axes."""
    return _poses(T1, "T1") @ _poses(T2, "T2")


def se3_inverse(T):
    """The inverse pose ``[[R^T, -R^T t], [0, 1]]``."""
    return _se3_inverse(_poses(T, "T"))


def se3_adjoint(T):
    """The adjoint ``Ad_T (6, 6) = [[R, [t]x R], [0, R]]`` (``[rho, phi]`` order): ``T exp(xi) T^-1 = exp(Ad_T xi)``.

    Parameters
    ----------
    T : array_like, shape (4, 4) or (..., 4, 4)

    Returns
    -------
    ndarray, shape (6, 6) or (..., 6, 6)
    """
    return _se3_adjoint(_poses(T, "T"))


def se3_right_jacobian_inv(xi):
    """The inverse right Jacobian of SE(3): ``log(exp(xi) exp(d)) ~ xi + J_r(xi)^-1 d`` (``[rho, phi]`` order).

    Parameters
    ----------
    xi : array_like, shape (6,) or (..., 6)

    Returns
    -------
    ndarray, shape (6, 6) or (..., 6, 6)

    References
    ----------
    Barfoot (2017), Eqs. 7.85-7.86 (the left Jacobian; ``J_r(xi) = J_l(-xi)``).
    """
    return _se3_jr_inv(as_vector(xi, "xi", 6, copy=False))


def se3_plus(T, delta):
    """The perturbed pose ``T (+) delta = (R Exp(phi), t + R rho)`` for ``delta = [rho, phi]``.

    Parameters
    ----------
    T : array_like, shape (4, 4) or (..., 4, 4)
    delta : array_like, shape (6,) or (..., 6)

    Returns
    -------
    ndarray, shape (4, 4) or (..., 4, 4)
    """
    return _se3_plus(_poses(T, "T"), as_vector(delta, "delta", 6, copy=False))


def se3_minus(T1, T0):
    """The perturbation ``delta = [R0^T (t1 - t0), Log(R0^T R1)]`` with ``T0 (+) delta = T1``.

    Parameters
    ----------
    T1, T0 : array_like, shape (4, 4) or (..., 4, 4)

    Returns
    -------
    delta : ndarray, shape (6,) or (..., 6)
    """
    return _se3_minus(_poses(T1, "T1"), _poses(T0, "T0"))
