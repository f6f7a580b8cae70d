"""Private stand-in for :mod:`slamlib.lie`'s rotation functions until that module is merged (then deleted).

Same names and conventions as ``lie``: ``skew(w) v = w x v``, ``so3_exp`` (Rodrigues),
``so3_log`` (angle in ``[0, pi]``).
"""

from __future__ import annotations

import numpy as np

from ._checks import as_matrix, as_vector

__all__ = ["skew", "so3_exp", "so3_log"]


def _skew(w):
    """``[w]x`` for ``w (..., 3)``: ``(..., 3, 3)``."""
    z = np.zeros(w.shape[:-1])
    return np.stack([np.stack([z, -w[..., 2], w[..., 1]], -1),
                     np.stack([w[..., 2], z, -w[..., 0]], -1),
                     np.stack([-w[..., 1], w[..., 0], z], -1)], -2)


def skew(w):
    """The skew-symmetric matrix ``[w]x`` with ``[w]x v = w x v``; ``w (..., 3)`` -> ``(..., 3, 3)``."""
    return _skew(as_vector(w, "w", 3))


def _so3_exp(w):
    a = np.linalg.norm(w, axis=-1)[..., None, None]
    W = _skew(w)
    # Exp(w) = I + sin(a)/a [w]x + (1 - cos a)/a^2 [w]x^2, with (1 - cos a)/a^2 = sin^2(a/2) / (a^2 / 2)
    A = np.sinc(a / np.pi)
    B = 0.5 * np.sinc(a / (2.0 * np.pi)) ** 2
    return np.eye(3) + A * W + B * (W @ W)


def so3_exp(w):
    """Rodrigues' formula: the rotation of a rotation vector.

    Parameters
    ----------
    w : ndarray, shape (..., 3)
        Rotation vectors (axis times angle).

    Returns
    -------
    ndarray, shape (..., 3, 3)
        ``I + sin(a)/a [w]x + (1 - cos a)/a^2 [w]x^2``, ``a = |w|``, exact at ``w = 0``.
    """
    return _so3_exp(as_vector(w, "w", 3))


def _so3_log(R):
    v = 0.5 * np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    s = np.linalg.norm(v, axis=-1)
    c = 0.5 * (R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2] - 1.0)  # cos(angle) = (tr R - 1) / 2
    angle = np.arctan2(s, c)
    w = v / np.sinc(angle / np.pi)[..., None]  # angle / sin(angle) v
    # near pi the axis comes from the symmetric part: (R + R^T)/2 - cos I = (1 - cos) n n^T
    far = c < 0.0
    if np.any(far):
        S = 0.5 * (R[far] + np.swapaxes(R[far], -1, -2)) - c[far][..., None, None] * np.eye(3)
        k = np.argmax(np.diagonal(S, axis1=-2, axis2=-1), axis=-1)
        col = np.take_along_axis(S, k[..., None, None], axis=-1)[..., 0]
        n = col / np.linalg.norm(col, axis=-1, keepdims=True)
        sign = np.where(np.sum(n * v[far], axis=-1) < 0.0, -1.0, 1.0)
        w[far] = (sign * angle[far])[..., None] * n
    return w


def so3_log(R):
    """The rotation vector of a rotation matrix (the inverse of :func:`so3_exp`).

    Parameters
    ----------
    R : ndarray, shape (..., 3, 3)
        Rotation matrices.

    Returns
    -------
    ndarray, shape (..., 3)
        ``w`` with ``Exp(w) = R`` and ``|w| <= pi``; the angle from
        ``atan2(|vee(R - R^T)| / 2, (tr R - 1) / 2)``, the axis near ``pi`` from the
        symmetric part of ``R``.
    """
    return _so3_log(as_matrix(R, "R", 3, 3))
