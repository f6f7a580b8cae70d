"""Angles: wrapping, differences and circular means.

Every angle ``slamlib`` returns (headings, bearings, bearing innovations) goes
through :func:`wrap_angle`, so it lies in ``[-pi, pi)``.
"""

from __future__ import annotations

import math

import numpy as np

from ._checks import as_array, as_index, check_broadcast

__all__ = ["wrap_angle", "angle_diff", "circular_mean"]

_TWO_PI = 2.0 * np.pi


def wrap_angle(a):
    """Wrap angles to ``[-pi, pi)``.

    Parameters
    ----------
    a : float or ndarray, any shape
        Angles in radians.

    Returns
    -------
    float or ndarray, same shape as `a`
        ``(a + pi) mod 2 pi - pi``; ``pi`` itself maps to ``-pi``.
    """
    arr = np.asarray(a)
    if arr.dtype.kind not in "biuf":
        raise TypeError(f"a must hold real angles in radians, got dtype {arr.dtype}")
    arr = arr.astype(np.float64, copy=False)
    if not np.isfinite(arr).all():
        raise ValueError("a must be finite (no NaN or inf)")
    out = _wrap(arr)
    return float(out) if out.ndim == 0 else out


def _wrap(arr):
    """``wrap_angle`` of a float64 array, without the checks (the array hot path of the filters)."""
    # a - 2 pi floor((a + pi) / 2 pi): a new array, never a view of the input
    out = np.add(arr, np.pi, out=np.empty_like(arr))
    out *= 1.0 / _TWO_PI
    np.floor(out, out=out)
    out *= -_TWO_PI
    out += arr
    # rounding near odd multiples of pi can land a hair outside [-pi, pi): fold it back (rare: one check first)
    if (np.abs(out) >= np.pi).any():
        np.subtract(out, _TWO_PI, out=out, where=out >= np.pi)
        np.add(out, _TWO_PI, out=out, where=out < -np.pi)
    return out


def _wrap1(a):
    """``wrap_angle`` of one Python float, without the array checks (the scalar hot path of the filters)."""
    w = (float(a) + math.pi) % _TWO_PI - math.pi
    return w - _TWO_PI if w >= math.pi else w


def angle_diff(a, b):
    """Wrapped difference ``wrap(a - b)`` in ``[-pi, pi)``.

    Parameters
    ----------
    a, b : float or ndarray
        Angles in radians; they broadcast against each other.

    Returns
    -------
    float or ndarray
        The signed smallest rotation taking `b` to `a`.
    """
    a = as_array(a, "a", ndim=range(0, 33))
    b = as_array(b, "b", ndim=range(0, 33))
    check_broadcast((a, "a"), (b, "b"))
    return wrap_angle(a - b)


def circular_mean(angles, weights=None, axis=0):
    """Weighted circular mean ``atan2(sum w sin a, sum w cos a)``.

    Parameters
    ----------
    angles : ndarray
        Angles in radians.
    weights : ndarray, optional
        Non-negative weights of the same shape as `angles`, not all zero along
        `axis`; uniform if omitted.
    axis : int
        Axis to average over.

    Raises
    ------
    ValueError
        If `angles` is empty along `axis` or every weight along it is zero
        (the mean direction is undefined).

    Returns
    -------
    float or ndarray
        The mean direction, wrapped to ``[-pi, pi)``.
    """
    a = as_array(angles, "angles", ndim=range(1, 33))
    axis = as_index(axis, "axis", a.ndim, lower=-a.ndim)
    if a.shape[axis] == 0:
        raise ValueError(f"angles must hold at least one angle along axis {axis}, got shape {a.shape}")
    if weights is None:
        w = np.ones_like(a)
    else:
        w = as_array(weights, "weights", a.shape, ref="angles")
        if np.any(w < 0):
            raise ValueError(f"weights must be non-negative, got minimum {w.min():.3g}")
        total = np.sum(w, axis=axis)
        if not np.all(total > 0):
            raise ValueError("weights must not all be zero (along the averaged axis): the mean direction is undefined")
        if not np.all(np.isfinite(total)):
            raise ValueError("weights sum to infinity; rescale them")
    return _circular_mean(a, w, axis)


def _circular_mean(a, w, axis=0):
    """Unchecked core of :func:`circular_mean`: ``wrap(atan2(sum w sin a, sum w cos a))``."""
    s = np.sum(w * np.sin(a), axis=axis)
    c = np.sum(w * np.cos(a), axis=axis)
    m = np.arctan2(s, c)
    if isinstance(m, np.float64) and math.isfinite(m):  # a finite scalar (the filters' per-step mean):
        return float(_wrap(np.asarray(m)))  # what wrap_angle returns, without its checks
    return wrap_angle(m)
