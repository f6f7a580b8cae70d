"""Input validation shared by every public ``slamlib`` function.

Each helper raises ``ValueError`` (or ``TypeError``) whose message names the
argument and says what was expected, so that a wrong call fails loudly instead
of being coerced into a wrong answer.

* arrays: :func:`as_array`, :func:`as_vector` (``(..., n)``), :func:`as_matrix`
  (``(..., r, c)``), :func:`as_rows` (``(K, c)``, empty allowed), :func:`as_mask`;
* covariances: :func:`as_covariance` (symmetric, PSD or PD, batched or not);
* poses: :func:`as_pose`, :func:`as_poses`;
* weights and probabilities: :func:`as_weights`, :func:`as_log_weights`
  (:func:`check_log_weights`), :func:`as_probability`, :func:`as_probabilities`;
* numbers: :func:`as_scalar`, :func:`as_count`, :func:`as_index`, :func:`as_indices`;
* others: :func:`check_rng`, :func:`check_type`;
* functions a caller plugs into a driver: :func:`check_callable` (the argument),
  :func:`as_returned` (what it returned);
* arguments whose shapes must agree: :func:`check_batch`, :func:`check_rows`,
  :func:`check_broadcast` (the message names both sides); the ``ref`` keyword
  of the array helpers names the argument a required size comes from;
* :func:`small_ok`: every small argument of one filter step checked at once.

Small float64 arrays take a fast path (no conversion, a Python pass over a few
numbers, no eigendecomposition for a clearly positive definite 2x2 or 3x3), so
checking one filter step costs microseconds; nothing is built for a message
unless a check fails.
"""

from __future__ import annotations

import math
import numbers

import numpy as np

__all__: list[str] = []

_F64 = np.dtype(np.float64)


def _shape_str(shape):
    return "(" + ", ".join("*" if s is None else str(s) for s in shape) + (",)" if len(shape) == 1 else ")")


def as_array(value, name, shape=None, *, ndim=None, finite=True, dtype=np.float64, nonnegative=False, ref=None,
             bools=True):
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
    nonnegative : bool
        Reject negative entries.
    ref : str, optional
        The argument(s) the expected shape comes from, named in the message
        (``"... (to match x)"``).
    bools : bool
        Accept booleans (as 0 and 1); ``False`` refuses them with a TypeError.
    """
    if type(value) is np.ndarray and value.dtype is _F64 and dtype is np.float64:
        arr = value.copy()  # the common case: no dtype inspection or conversion
    else:
        arr = _convert(value, name, dtype, bools)
    if shape is not None:
        ok = arr.ndim == len(shape) and all(s is None or s == a for s, a in zip(shape, arr.shape))
        if not ok:
            raise ValueError(f"{name} must have shape {_shape_str(shape)}{_ref(ref)}, got {arr.shape}")
    elif ndim is not None:
        allowed = (ndim,) if isinstance(ndim, int) else tuple(ndim)
        if arr.ndim not in allowed:
            raise ValueError(f"{name} must have {' or '.join(map(str, allowed))} dimensions, got shape {arr.shape}")
    if finite and not _all_finite(arr):
        raise ValueError(f"{name} must be finite (no NaN or inf)")
    if nonnegative and arr.size and not arr.min() >= 0:
        raise ValueError(f"{name} must be non-negative, got minimum {arr.min():.6g}")
    return arr


def as_rows(value, name, cols):
    """A float64 ``(K, cols)`` array of rows (e.g. measurements ``(K, 2)``); an empty list gives ``(0, cols)``."""
    arr = as_array(value, name, ndim=(1, 2))
    if arr.ndim == 1 and arr.size == 0:
        arr = arr.reshape(0, cols)
    if arr.ndim != 2 or arr.shape[1] != cols:
        raise ValueError(f"{name} must have shape (K, {cols}), got {arr.shape}")
    return arr


def as_mask(value, name, *, ndim=None):
    """A boolean array from booleans or 0/1 numbers."""
    arr = as_array(value, name, ndim=ndim)
    if not np.all((arr == 0) | (arr == 1)):
        raise ValueError(f"{name} must hold booleans (or 0/1)")
    return arr.astype(bool)


def check_type(value, cls, name):
    """Require an instance of `cls` (a class or a tuple of classes)."""
    if not isinstance(value, cls):
        want = " or ".join(c.__name__ for c in cls) if isinstance(cls, tuple) else cls.__name__
        raise TypeError(f"{name} must be a {want}, got {type(value).__name__}")
    return value


def _ref(ref):
    return "" if ref is None else f" (to match {ref})"


def _convert(value, name, dtype=np.float64, bools=True):
    """A new array of `dtype` from any real array_like; bools count as 0/1, strings are refused."""
    if isinstance(value, (str, bytes)) or value is None:
        raise TypeError(f"{name} must be a numeric array, got {type(value).__name__}")
    try:
        arr = np.array(value, dtype=None, copy=True)
    except Exception as exc:  # ragged lists and the like
        raise ValueError(f"{name} must be a numeric array: {exc}") from None
    if arr.dtype.kind not in ("biuf" if bools else "iuf"):
        raise TypeError(f"{name} must hold real numbers, got dtype {arr.dtype}")
    return np.asarray(arr, dtype=dtype)


def _all_finite(arr):
    if arr.size <= 16:  # a Python pass over a few numbers beats a ufunc and a reduction
        values = arr.ravel().tolist()
        # a finite sum proves every term finite; an overflowing sum of finite terms is looked at one by one
        return math.isfinite(sum(values)) or all(map(math.isfinite, values))
    return bool(np.isfinite(arr).all())


def as_scalar(value, name, *, positive=False, nonnegative=False, finite=True):
    """Return ``value`` as a Python float after checking sign and finiteness."""
    if type(value) is float:  # the common case, without the ABC and array checks
        out = float(value)
    else:
        out = _real_scalar(value, name)
    if finite and not math.isfinite(out):
        raise ValueError(f"{name} must be finite, got {out}")
    if positive and not out > 0:
        raise ValueError(f"{name} must be positive, got {out}")
    if nonnegative and not out >= 0:
        raise ValueError(f"{name} must be non-negative, got {out}")
    return out


def _real_scalar(value, name):
    if isinstance(value, bool) or not isinstance(value, (numbers.Real, np.ndarray)):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__}")
    arr = np.asarray(value)
    if arr.ndim != 0 or arr.dtype.kind not in "iuf":
        raise ValueError(f"{name} must be a real scalar, got shape {arr.shape} dtype {arr.dtype}")
    return float(arr)


def as_vector(value, name, n=None, *, copy=True, ref=None):
    """A float64 array of shape ``(n,)`` or ``(..., n)`` (a batch of vectors), finite.

    With ``copy=False`` it returns `value` itself when it already is a finite
    float64 array (for cores that never write into their inputs), so the check
    of one small vector costs a few attribute lookups.
    """
    if type(value) is np.ndarray and value.dtype is _F64 and value.ndim >= 1:
        arr = value.copy() if copy else value
    else:
        arr = as_array(value, name, finite=False)
        if arr.ndim == 0:
            raise ValueError(f"{name} must have shape ({'n' if n is None else n},) or (..., {'n' if n is None else n}), "
                             f"got a scalar")
    if n is not None and arr.shape[-1] != n:
        raise ValueError(f"{name} must have shape ({n},) or (..., {n}){_ref(ref)}, got {arr.shape}")
    if not _all_finite(arr):
        raise ValueError(f"{name} must be finite (no NaN or inf)")
    return arr


def as_matrix(value, name, rows=None, cols=None, *, copy=True, ref=None):
    """A float64 array of shape ``(rows, cols)`` or ``(..., rows, cols)``, finite (see :func:`as_vector`)."""
    if type(value) is np.ndarray and value.dtype is _F64 and value.ndim >= 2:
        arr = value.copy() if copy else value
    else:
        arr = as_array(value, name, finite=False)
        if arr.ndim < 2:
            raise ValueError(f"{name} must be a matrix {_mat_str(rows, cols)} or a batch (..., {_mat_str(rows, cols)[1:-1]}), "
                             f"got shape {arr.shape}")
    r, c = arr.shape[-2:]
    if (rows is not None and r != rows) or (cols is not None and c != cols):
        want = _mat_str(rows, cols)
        raise ValueError(f"{name} must have shape {want} or (..., {want[1:-1]}){_ref(ref)}, got {arr.shape}")
    if not _all_finite(arr):
        raise ValueError(f"{name} must be finite (no NaN or inf)")
    return arr


def _mat_str(rows, cols):
    return f"({'n' if rows is None else rows}, {'n' if cols is None else cols})"


#: Relative tolerances of the covariance checks: asymmetry ``|A - A^T|`` and a
#: negative eigenvalue are tolerated up to this fraction of ``max(1, |A|)``.
SYM_RTOL = 1e-9
PSD_RTOL = 1e-9


def as_covariance(value, name, n=None, *, definite=False, batched=False, psd=True, copy=True, ref=None):
    """A (batch of) symmetric positive semi-definite (or definite) ``(n, n)`` matrices.

    Parameters
    ----------
    value : array_like, shape (n, n) or (..., n, n)
        The argument to check; a batch is checked matrix by matrix.
    name : str
        Argument name used in error messages.
    n : int, optional
        Required size; any square size if omitted.
    definite : bool, keyword-only
        Require positive definiteness (every eigenvalue ``> 0``), e.g. for a
        matrix that is inverted.
    batched : bool, keyword-only
        Accept leading batch axes.
    psd : bool, keyword-only
        Check (semi-)definiteness at all; ``False`` checks symmetry only.
    copy : bool, keyword-only
        ``False`` returns `value` itself when it already is a float64 array
        (for cores that never write into it).

    Returns
    -------
    ndarray
        `value` as a float64 array.

    Notes
    -----
    Symmetric means ``max |A - A^T| <= 1e-9 max(1, max |A|)``; semi-definite
    means the smallest eigenvalue is ``>= -1e-9 max(1, max |eig|)``. A 2x2 or
    3x3 matrix whose leading principal minors are clearly positive (Sylvester's
    criterion) is accepted without an eigendecomposition, so checking one small
    covariance costs about a microsecond; anything else goes through
    ``numpy.linalg.eigvalsh``.
    """
    if type(value) is np.ndarray and value.dtype is _F64 and value.ndim == 2:
        k = value.shape[0]
        if 2 <= k <= 3 and value.shape[1] == k and (n is None or n == k) and _small_pd(value.tolist(), k):
            return value.copy() if copy else value  # finite, symmetric and clearly positive definite
    arr = as_matrix(value, name, n, n, copy=copy, ref=ref)
    if arr.shape[-1] != arr.shape[-2]:
        raise ValueError(f"{name} must be square, got shape {arr.shape}")
    if arr.ndim > 2 and not batched:
        raise ValueError(f"{name} must have shape {_mat_str(n, n)}{_ref(ref)}, got {arr.shape}")
    k = arr.shape[-1]
    if arr.ndim == 2 and 2 <= k <= 3 and _small_pd(arr.tolist(), k):
        return arr
    scale = np.maximum(1.0, np.abs(arr).max(axis=(-2, -1), initial=0.0))
    asym = np.abs(arr - np.swapaxes(arr, -1, -2)).max(axis=(-2, -1), initial=0.0)
    if np.any(asym > SYM_RTOL * scale):
        raise ValueError(f"{name} must be symmetric (largest |{name} - {name}^T| is {float(np.max(asym)):.3g})")
    if psd and k > 0:
        eig = np.linalg.eigvalsh(arr)
        low = float(eig.min())
        if definite and np.any(eig.min(axis=-1) <= 0.0):
            raise ValueError(f"{name} must be positive definite (smallest eigenvalue {low:.3g})")
        tol = PSD_RTOL * np.maximum(1.0, np.abs(eig).max(axis=-1))
        if np.any(eig.min(axis=-1) < -tol):
            raise ValueError(f"{name} must be positive semi-definite (smallest eigenvalue {low:.3g})")
    return arr


def small_ok(vectors=(), matrices=(), covariances=()):
    """True when a call's small arguments pass every check at once (the fast path of one filter step).

    Every argument must be a float64 ndarray: `vectors` 1-D with at most 16
    finite entries, `matrices` 2-D with at most 16 finite entries, and
    `covariances` 2x2 or 3x3, symmetric and clearly positive definite (see
    :func:`as_covariance`). The caller still compares the shapes. ``False``
    decides nothing: the caller then runs the full checks, which name what is
    wrong.
    """
    values = []
    for v in vectors:
        if type(v) is not np.ndarray or v.dtype is not _F64 or v.ndim != 1 or v.size > 16:
            return False
        values += v.tolist()
    for m in matrices:
        if type(m) is not np.ndarray or m.dtype is not _F64 or m.ndim != 2 or m.size > 16:
            return False
        values += m.ravel().tolist()
    if not math.isfinite(sum(values)) and not all(map(math.isfinite, values)):
        return False
    for c in covariances:
        if type(c) is not np.ndarray or c.dtype is not _F64 or c.ndim != 2:
            return False
        k = c.shape[0]
        if not (2 <= k <= 3 and c.shape[1] == k and _small_pd(c.tolist(), k)):
            return False
    return True


def _small_pd(a, k):
    """True if the nested list `a` (k = 2 or 3) is finite, symmetric and clearly positive definite.

    False for anything else (the caller then runs the full check). The scale of
    the tolerances is the largest diagonal entry: for a positive definite matrix
    every ``|a_ij| <= max a_ii``, and a matrix with a larger entry is not
    accepted here, so this test is never looser than the full one.
    """
    if k == 2:
        (a00, a01), (a10, a11) = a
        if not math.isfinite(a00 + a01 + a10 + a11):
            return False
        scale = max(1.0, a00, a11)
        if abs(a01 - a10) > SYM_RTOL * scale:
            return False
        # Sylvester: a00 > 0 and det > 0, with a margin far above rounding
        eps = 1e-12 * scale
        return a00 > eps and a00 * a11 - a01 * a10 > eps * scale
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = a
    if not math.isfinite(a00 + a01 + a02 + a10 + a11 + a12 + a20 + a21 + a22):
        return False
    scale = max(1.0, a00, a11, a22)
    tol = SYM_RTOL * scale
    if abs(a01 - a10) > tol or abs(a02 - a20) > tol or abs(a12 - a21) > tol:
        return False
    eps = 1e-12 * scale
    if not (a00 > eps and a00 * a11 - a01 * a10 > eps * scale):
        return False
    det = a00 * (a11 * a22 - a12 * a21) - a01 * (a10 * a22 - a12 * a20) + a02 * (a10 * a21 - a11 * a20)
    return det > eps * scale * scale


def check_rows(*named):
    """Arrays ``(array, name)`` must have the same number of rows (first axis); returns it."""
    first, first_name = named[0]
    n = np.shape(first)[0]
    for arr, nm in named[1:]:
        if np.shape(arr)[0] != n:
            raise ValueError(f"{nm} must have one row per row of {first_name} ({n}), got {np.shape(arr)[0]} "
                             f"({first_name} {np.shape(first)}, {nm} {np.shape(arr)})")
    return n


def check_batch(*named):
    """Leading (batch) axes of ``(array, core ndim, name)`` triples must broadcast; returns their shape.

    The message names every argument with its shape, instead of numpy's
    broadcast error deep inside a computation.
    """
    for a, k, _ in named:
        if a.ndim != k:
            break
    else:
        return ()  # nothing batched
    shapes = [a.shape[: a.ndim - k] for a, k, _ in named]
    try:
        return np.broadcast_shapes(*shapes)
    except ValueError:
        desc = ", ".join(f"{name} {a.shape}" for a, _, name in named)
        raise ValueError(f"leading (batch) axes do not broadcast: {desc}") from None


def check_broadcast(*named):
    """Arrays ``(array, name)`` must broadcast against each other (whole shapes); returns the shape."""
    try:
        return np.broadcast_shapes(*(np.shape(a) for a, _ in named))
    except ValueError:
        desc = ", ".join(f"{name} {np.shape(a)}" for a, name in named)
        raise ValueError(f"shapes do not broadcast: {desc}") from None


def as_pose(value, name="pose"):
    """One pose ``[x, y, theta]``, shape ``(3,)``, finite."""
    if type(value) is np.ndarray and value.dtype is _F64 and value.shape == (3,):
        if not all(map(math.isfinite, value.tolist())):
            raise ValueError(f"{name} must be finite (no NaN or inf)")
        return value.copy()
    return as_array(value, name, (3,))


def as_poses(value, name="poses", *, batched=False, ndim=None, allow_empty=True):
    """Poses ``[x, y, theta]``, finite: shape ``(M, 3)``; ``(..., 3)`` when `batched`;
    any of the numbers of dimensions `ndim` (e.g. ``(1, 2)`` for ``(3,)`` or ``(M, 3)``) when given."""
    if batched or ndim is not None:
        arr = as_array(value, name, ndim=range(1, 33) if ndim is None else ndim)
        if arr.shape[-1] != 3:
            want = "(3,) or (..., 3)" if ndim is None else "(3,) or (M, 3)"
            raise ValueError(f"{name} must have shape {want}, got {arr.shape}")
    else:
        arr = as_array(value, name, (None, 3))
    if not allow_empty and arr.size == 0:
        raise ValueError(f"{name} must hold at least one pose")
    return arr


def as_weights(value, name="w", n=None, *, normalize=True, ref=None):
    """Non-negative weights ``(n,)``, not all zero, finite sum; normalised to sum 1 unless told not to."""
    w = as_array(value, name, (None,) if n is None else (n,), ref=ref)
    if w.size == 0:
        raise ValueError(f"{name} must hold at least one weight")
    if np.any(w < 0):
        raise ValueError(f"{name} must be non-negative, got minimum {w.min():.3g}")
    with np.errstate(over="ignore"):
        total = w.sum()
    if not total > 0:
        raise ValueError(f"{name} must have a positive sum (all weights are zero)")
    if not np.isfinite(total):
        raise ValueError(f"{name} sums to infinity; rescale the weights (or use log-weights)")
    return w / total if normalize else w


def as_log_weights(value, name="log_w", n=None, *, ref=None):
    """Log-weights ``(n,)``: no NaN or ``+inf``, ``-inf`` allowed for some but not all entries."""
    lw = as_array(value, name, (None,) if n is None else (n,), finite=False, ref=ref)
    check_log_weights(lw, name)
    return lw


def check_log_weights(lw, name="log_w"):
    """Raise unless the float array `lw` can be normalised (see :func:`as_log_weights`)."""
    if lw.size == 0:
        raise ValueError(f"{name} must hold at least one log-weight")
    if np.any(np.isnan(lw)):
        raise ValueError(f"{name} contains NaN")
    if np.any(lw == np.inf):
        raise ValueError(f"{name} contains +inf (an infinite weight cannot be normalised)")
    if not np.any(np.isfinite(lw)):
        raise ValueError(f"{name}: every log-weight is -inf (all particles have zero weight), nothing to normalise")


def as_probability(value, name):
    """A Python float in ``[0, 1]``."""
    p = as_scalar(value, name)
    if not 0.0 <= p <= 1.0:
        raise ValueError(f"{name} must be a probability in [0, 1], got {p}")
    return p


def as_probabilities(value, name, shape=None, *, ndim=None, sums_to_one=False, tol=1e-6):
    """An array of probabilities in ``[0, 1]`` (a distribution summing to 1 within `tol` when `sums_to_one`)."""
    arr = as_array(value, name, shape, ndim=ndim)
    if arr.size == 0:
        raise ValueError(f"{name} must not be empty")
    if np.any(arr < 0):
        raise ValueError(f"{name} must be non-negative (it is a probability distribution)")
    if sums_to_one:
        total = float(arr.sum())
        if abs(total - 1.0) > tol:
            raise ValueError(f"{name} must sum to 1 (it is a probability distribution), got sum {total:.6g}")
    elif np.any(arr > 1):
        raise ValueError(f"{name} must hold probabilities in [0, 1], got maximum {arr.max():.6g}")
    return arr


def as_count(value, name, *, minimum=0, maximum=None):
    """A Python int count ``>= minimum`` (and ``<= maximum``); bools and floats are refused."""
    if isinstance(value, bool) or not isinstance(value, (numbers.Integral, np.integer)):
        raise TypeError(f"{name} must be an integer count, got {type(value).__name__}")
    out = int(value)
    if out < minimum or (maximum is not None and out > maximum):
        want = f">= {minimum}" if maximum is None else f"in [{minimum}, {maximum}]"
        raise ValueError(f"{name} must be {want}, got {out}")
    return out


def as_indices(value, name, upper, shape=None, *, ref=None):
    """An integer array (intp) of indices in ``[0, upper)``; an empty list is fine; bools are refused."""
    arr = np.asarray(value)
    if arr.size == 0 and arr.dtype.kind not in "iu":
        arr = arr.astype(np.intp)
    if arr.dtype.kind not in "iu":
        raise TypeError(f"{name} must be an integer array, got dtype {arr.dtype}")
    if shape is not None and arr.shape != tuple(shape):
        raise ValueError(f"{name} must have shape {_shape_str(tuple(shape))}{_ref(ref)}, got {arr.shape}")
    if arr.size and (arr.min() < 0 or arr.max() >= upper):
        raise ValueError(f"{name} must hold indices in [0, {upper}), got range [{arr.min()}, {arr.max()}]")
    return arr.astype(np.intp)


def check_callable(value, name, signature):
    """``value`` if it is None or callable; the message shows the call `signature` expected."""
    if value is not None and not callable(value):
        raise TypeError(f"{name} must be a callable {name}{signature} or None, got {type(value).__name__}")
    return value


def as_returned(value, name, *shapes, nonnegative=()):
    """What a caller's function `name` returned, as new float64 arrays of the given `shapes`.

    One shape: the returned value itself; several: a tuple (or list) of that many
    arrays. Every array must be finite; the items whose positions are in
    `nonnegative` must have no negative entry. Messages name the function and the
    item (``"ekf_predict(...)[1] must have shape (3, 3), got (3,)"``).
    """
    if len(shapes) == 1:
        return as_array(value, f"{name}(...)", shapes[0], nonnegative=0 in nonnegative)
    if not isinstance(value, (tuple, list)) or len(value) != len(shapes):
        got = f"{len(value)} items" if isinstance(value, (tuple, list)) else f"a {type(value).__name__}"
        raise ValueError(f"{name} must return a tuple of {len(shapes)} arrays, got {got}")
    return tuple(as_array(v, f"{name}(...)[{i}]", s, nonnegative=i in nonnegative)
                 for i, (v, s) in enumerate(zip(value, shapes)))


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
