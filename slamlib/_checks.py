"""Input validation shared by every public ``slamlib`` function.

Each helper raises ``ValueError`` (or ``TypeError``) whose message names the
argument and says what was expected, so that a wrong call fails loudly instead
of being coerced into a wrong answer.
"""

from __future__ import annotations

import numbers

import numpy as np

__all__: list[str] = []


def _shape_str(shape):
    return "(" + ", ".join("*" if s is None else str(s) for s in shape) + (",)" if len(shape) == 1 else ")")


def as_array(value, name, shape=None, *, ndim=None, finite=True, dtype=np.float64):
    """Return ``value`` as a new float64 array after checking it.

    Parameters
    ----------
    value : array_like
        The argument to check.
    name : str
        Argument name used in error messages.
    shape : tuple of (int or None), optional
        Expected shape; ``None`` entries match any length.
    ndim : int or tuple of int, optional
        Accepted numbers of dimensions (when ``shape`` is not given).
    finite : bool
        Reject NaN and infinities.
    """
    if isinstance(value, (str, bytes)) or value is None:
        raise TypeError(f"{name} must be a numeric array, got {type(value).__name__}")
    try:
        arr = np.array(value, dtype=None, copy=True)
    except Exception as exc:  # ragged lists and the like
        raise ValueError(f"{name} must be a numeric array: {exc}") from None
    if arr.dtype.kind not in "biuf":
        raise TypeError(f"{name} must hold real numbers, got dtype {arr.dtype}")
    arr = np.asarray(arr, dtype=dtype)
    if shape is not None:
        ok = arr.ndim == len(shape) and all(s is None or s == a for s, a in zip(shape, arr.shape))
        if not ok:
            raise ValueError(f"{name} must have shape {_shape_str(shape)}, got {arr.shape}")
    elif ndim is not None:
        allowed = (ndim,) if isinstance(ndim, int) else tuple(ndim)
        if arr.ndim not in allowed:
            raise ValueError(f"{name} must have {' or '.join(map(str, allowed))} dimensions, got shape {arr.shape}")
    if finite and not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite (no NaN or inf)")
    return arr


def as_scalar(value, name, *, positive=False, nonnegative=False, finite=True):
    """Return ``value`` as a Python float after checking sign and finiteness."""
    if isinstance(value, bool) or not isinstance(value, (numbers.Real, np.ndarray)):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__}")
    arr = np.asarray(value)
    if arr.ndim != 0 or arr.dtype.kind not in "iuf":
        raise ValueError(f"{name} must be a real scalar, got shape {arr.shape} dtype {arr.dtype}")
    out = float(arr)
    if finite and not np.isfinite(out):
        raise ValueError(f"{name} must be finite, got {out}")
    if positive and not out > 0:
        raise ValueError(f"{name} must be positive, got {out}")
    if nonnegative and not out >= 0:
        raise ValueError(f"{name} must be non-negative, got {out}")
    return out


def as_covariance(value, name, n, *, psd=True):
    """Return a float64 ``(n, n)`` symmetric positive semi-definite matrix."""
    arr = as_array(value, name, (n, n))
    if not np.allclose(arr, arr.T, rtol=1e-9, atol=1e-12 * max(1.0, float(np.abs(arr).max(initial=0.0)))):
        raise ValueError(f"{name} must be symmetric")
    if psd:
        eig = np.linalg.eigvalsh(arr)
        if eig.min() < -1e-9 * max(1.0, abs(eig).max()):
            raise ValueError(f"{name} must be positive semi-definite (smallest eigenvalue {eig.min():.3g})")
    return arr


def check_rng(rng, name="rng"):
    """Require a ``numpy.random.Generator`` (no global random state anywhere)."""
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"{name} must be a numpy.random.Generator (np.random.default_rng(seed)), got {type(rng).__name__}")
    return rng


def as_index(value, name, upper=None, *, lower=0):
    """Return ``value`` as a Python int in ``[lower, upper)``."""
    if isinstance(value, bool) or not isinstance(value, (numbers.Integral, np.integer)):
        raise TypeError(f"{name} must be an integer, got {type(value).__name__}")
    out = int(value)
    if out < lower or (upper is not None and out >= upper):
        want = f">= {lower}" if upper is None else f"in [{lower}, {upper})"
        raise ValueError(f"{name} must be {want}, got {out}")
    return out


def as_scan(ranges, angles):
    """Return a range scan ``(ranges (K,), angles (K,))`` as new float64 arrays after checking it.

    Ranges must be finite (no NaN) and non-negative, one angle per beam; the
    errors name the argument.
    """
    ranges = as_array(ranges, "ranges", ndim=1)
    angles = as_array(angles, "angles", ndim=1)
    if ranges.shape != angles.shape:
        raise ValueError(f"ranges {ranges.shape} and angles {angles.shape} must have the same length: one angle per beam")
    if np.any(ranges < 0):
        raise ValueError("ranges must be non-negative")
    return ranges, angles
