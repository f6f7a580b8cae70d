"""Input validation shared by every public ``slamlib`` function.

Each helper raises ``ValueError`` (or ``TypeError``) whose message names the
argument and says what was expected, so that a wrong call fails loudly instead
of being coerced into a wrong answer.

* arrays: :func:`as_array`, :func:`as_vector` (``(..., n)``), :func:`as_matrix`
  (``(..., r, c)``), :func:`as_rows` (``(K, c)``, e.g. measurements; empty
  allowed), :func:`as_mask`, :func:`as_scan` (a range scan), :func:`as_range_bearing`
  (one measurement ``[r, phi]``, ``r > 0``);
* covariances: :func:`as_covariance` (symmetric, PSD or PD, batched or not),
  :func:`as_invertible_covariance` (PD with a representable determinant);
* poses and states: :func:`as_pose`, :func:`as_poses`, :func:`as_slam_mean` and
  :func:`as_slam_state` (``[x, y, theta, m0x, m0y, ...]`` and its covariance),
  :func:`as_rigid_transform` (``R``, ``t``); in 3-D :func:`as_rotations` (``(..., 3, 3)``) and
  :func:`as_rigid_motions` (homogeneous ``(..., 4, 4)``);
* graphs: :func:`as_edges` (index pairs), :func:`as_information` (a stack of
  PD information matrices), :func:`as_pose_graph`, :func:`as_pose_graph3d`;
* weights and probabilities: :func:`as_weights`, :func:`as_log_weights`
  (:func:`check_log_weights`), :func:`as_probability`, :func:`as_probabilities`,
  :func:`as_kernel` (a motion kernel centred on zero);
* numbers: :func:`as_scalar`, :func:`as_threshold` (gates; ``None`` for none),
  :func:`as_count`, :func:`as_index`, :func:`as_indices`, :func:`as_index_set`;
* others: :func:`check_rng`, :func:`check_type`, :func:`check_field_shapes` (a
  record's array fields), :func:`check_choice` (an option among named strings);
* functions a caller plugs into a driver: :func:`check_callable` (the argument),
  :func:`as_returned` (what it returned);
* arguments whose shapes must agree: :func:`check_batch`, :func:`check_rows`,
  :func:`check_broadcast` (the message names both sides); the ``ref`` keyword
  of the array helpers names the argument a required size comes from;
* :func:`small_ok`: every small argument of one filter step checked at once.

Small float64 arrays take a fast path (no conversion, a Python pass over a few
numbers, no eigendecomposition for a clearly positive definite covariance up to
8x8: Sylvester's criterion for 2x2 and 3x3, LAPACK's Cholesky from 4x4), so
checking one filter step costs microseconds; nothing is built for a message
unless a check fails.
"""

from __future__ import annotations

import math
import numbers

import numpy as np
from scipy.linalg.lapack import dpotrf as _dpotrf  # LAPACK's Cholesky: reports failure, warns nothing

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


def as_mask(value, name, *, ndim=None, shape=None, ref=None):
    """A boolean array from booleans or 0/1 numbers (of `shape`, the shape of argument `ref`, when given)."""
    arr = as_array(value, name, shape, ndim=ndim, ref=ref)
    if not np.all((arr == 0) | (arr == 1)):
        raise ValueError(f"{name} must hold booleans (or 0/1)")
    return arr.astype(bool)


def check_type(value, cls, name, hint=None):
    """Require an instance of `cls` (a class or a tuple of classes); `hint` says where one comes from."""
    if not isinstance(value, cls):
        want = " or ".join(c.__name__ for c in cls) if isinstance(cls, tuple) else cls.__name__
        raise TypeError(f"{name} must be a {want}{'' if hint is None else f' ({hint})'}, got {type(value).__name__}")
    return value


def check_field_shapes(value, name, shapes):
    """The array fields of record `value` (e.g. a filter's state) must have ``shapes`` (a dict field -> shape)."""
    for field, shape in shapes.items():
        got = getattr(value, field).shape
        if got != shape:
            raise ValueError(f"{name}.{field} must have shape {shape}, got {got}")
    return value


def check_choice(value, name, choices, *, removed=None):
    """One of the strings `choices` (a dict: choice -> what it means, said in the message).

    `removed` maps a choice that is gone to the message that says what took its place.
    """
    if isinstance(value, str) and value in choices:
        return value
    if removed and isinstance(value, str) and value in removed:
        raise ValueError(f"{name}={value!r} is gone: {removed[value]}")
    want = " or ".join(f"{c!r} ({what})" for c, what in choices.items())
    raise ValueError(f"{name} must be {want}, got {value!r}")


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


def as_threshold(value, name, *, optional=False, none=None, positive=False, finite=False):
    """A threshold (a gate on a squared Mahalanobis distance, a chi-square bound) as a Python float.

    Non-negative (positive with `positive`); ``inf`` (never fires) is allowed
    unless `finite`. With `optional`, ``None`` means "no threshold" and gives
    `none` (e.g. ``math.inf``); otherwise ``None`` is refused.
    """
    if value is None and optional:
        return none
    return as_scalar(value, name, positive=positive, nonnegative=not positive, finite=finite)


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
    criterion), a 4x4 to 8x8 one whose Cholesky pivots are clearly positive, or
    a 2x2 one whose closed-form eigenvalues are clearly non-negative (when
    semi-definite is enough), is accepted without an eigendecomposition, so
    checking one small covariance costs a microsecond or two; anything else
    goes through ``numpy.linalg.eigvalsh``.
    """
    if type(value) is np.ndarray and value.dtype is _F64 and value.ndim == 2:
        k = value.shape[0]
        if 2 <= k <= SMALL_COV and value.shape[1] == k and (n is None or n == k):
            a = value.tolist()
            if _small_pd(a, k, value) or (k == 2 and not definite and _small_psd2(a)):
                return value.copy() if copy else value  # finite, symmetric and clearly positive (semi-)definite
    arr = as_matrix(value, name, n, n, copy=copy, ref=ref)
    if arr.shape[-1] != arr.shape[-2]:
        raise ValueError(f"{name} must be square, got shape {arr.shape}")
    if arr.ndim > 2 and not batched:
        raise ValueError(f"{name} must have shape {_mat_str(n, n)}{_ref(ref)}, got {arr.shape}")
    k = arr.shape[-1]
    if arr.ndim == 2 and 2 <= k <= SMALL_COV and _small_pd(arr.tolist(), k, arr):
        return arr
    scale = np.maximum(1.0, np.abs(arr).max(axis=(-2, -1), initial=0.0))
    asym = np.abs(arr - np.swapaxes(arr, -1, -2)).max(axis=(-2, -1), initial=0.0)
    if np.any(asym > SYM_RTOL * scale):
        raise ValueError(f"{name} must be symmetric (largest |{name} - {name}^T| is {float(np.max(asym)):.3g})")
    if psd and k > 0 and arr.size:  # (an empty batch has nothing to check)
        eig = np.linalg.eigvalsh(arr)
        low = float(eig.min())
        if definite and np.any(eig.min(axis=-1) <= 0.0):
            raise ValueError(f"{name} must be positive definite (smallest eigenvalue {low:.3g})")
        tol = PSD_RTOL * np.maximum(1.0, np.abs(eig).max(axis=-1))
        if np.any(eig.min(axis=-1) < -tol):
            raise ValueError(f"{name} must be positive semi-definite (smallest eigenvalue {low:.3g})")
    return arr


def as_invertible_covariance(value, name, n=None, *, max_log_det):
    """A positive definite ``(n, n)`` covariance whose determinant and its inverse are ordinary floats.

    ``|log det value| < max_log_det``, so that a Gaussian density's
    normaliser ``|2 pi value|^-1/2`` and ``value^-1`` stay far from overflow
    and underflow (e.g. a noise covariance written in standard deviations
    instead of variances is refused, with a hint).
    """
    arr = as_covariance(value, name, n, definite=True)
    if arr.shape == (2, 2):
        (a, b), (c, d) = arr.tolist()
        det = a * d - b * c
        log_det = math.log(det) if 0.0 < det < math.inf else float(np.linalg.slogdet(arr)[1])
    else:
        log_det = float(np.linalg.slogdet(arr)[1])
    if not abs(log_det) < max_log_det:
        raise ValueError(f"{name} is out of the representable range: log det {name} = {log_det:.4g} (its entries are "
                         "squared standard deviations, e.g. diag([0.1, 0.02])**2; the weights need det "
                         f"{name} and its inverse as floats, |log det {name}| < {max_log_det})")
    return arr


def small_ok(vectors=(), matrices=(), covariances=()):
    """True when a call's small arguments pass every check at once (the fast path of one filter step).

    Every argument must be a float64 ndarray: `vectors` 1-D with at most 16
    finite entries, `matrices` 2-D with at most 64 finite entries, and
    `covariances` from 2x2 to 8x8, symmetric and clearly positive definite (see
    :func:`as_covariance`; a covariance with the same values as one accepted in a
    recent call, such as a filter's noise covariance, is accepted without a second
    factorisation). The caller still compares the shapes. ``False``
    decides nothing: the caller then runs the full checks, which name what is
    wrong.
    """
    values = []
    for v in vectors:
        if type(v) is not np.ndarray or v.dtype is not _F64 or v.ndim != 1 or v.size > 16:
            return False
        values += v.tolist()
    new = []
    for m in matrices:
        if type(m) is not np.ndarray or m.dtype is not _F64 or m.ndim != 2 or m.size > 64:
            return False
        key = m.tobytes()  # a matrix found finite before (a filter's F or H) is finite again
        if key not in _FINITE:
            values += m.ravel().tolist()
            new.append(key)
    if not math.isfinite(sum(values)) and not all(map(math.isfinite, values)):
        return False
    if new:
        _remember(_FINITE, new)
    for c in covariances:
        if type(c) is not np.ndarray or c.dtype is not _F64 or c.ndim != 2:
            return False
        k = c.shape[0]
        if not (2 <= k <= SMALL_COV and c.shape[1] == k):
            return False
        key = c.tobytes()  # the values decide the check: a matrix accepted before is accepted again
        if key in _ACCEPTED:
            continue
        if not (_small_pd_chol(c, None, k, key) if k > 3 else _small_pd(c.tolist(), k)):
            return False
        _remember(_ACCEPTED, (key,))
    return True


#: The float64 contents (``tobytes``) of the last square covariances :func:`small_ok` accepted, and of the
#: last matrices it found finite: a filter's noise covariances and model matrices come back call after call,
#: and the same values pass the same check. Only what passed is kept (never a verdict against), at most
#: ``_N_ACCEPTED`` of each.
_ACCEPTED = set()
_FINITE = set()
_N_ACCEPTED = 32


def _remember(memory, keys):
    if len(memory) + len(keys) > _N_ACCEPTED:
        memory.clear()
    memory.update(keys)


#: Largest covariance the small-matrix fast path checks (by Cholesky from 4 rows up).
SMALL_COV = 8

def _small_pd_chol(value, a, k, key=None):
    """True if the float64 ``(k, k)`` array `value` (nested list `a`, or None) is finite, symmetric and clearly
    positive definite: LAPACK's Cholesky succeeds with every pivot ``U_ii^2 > 1e-12 max(1, max a_ii)``.

    A successful Cholesky factorisation is backward stable (it factors ``A + E``
    with ``|E|`` a few rounding errors of ``|A|``), so the smallest eigenvalue is
    far above the full check's tolerance ``-1e-9``; the pivots' margin plays the
    role of Sylvester's criterion for the 2x2 and 3x3 forms. False decides
    nothing (the caller then runs the full check).

    An exactly symmetric matrix (its bytes equal its transpose's; `key` is
    ``value.tobytes()`` when the caller has it) needs no separate finiteness
    test: the factorisation reads one triangle, which then holds every entry,
    and a NaN or infinity there leaves a pivot that is not a finite positive
    number (or makes LAPACK report failure).
    """
    if (value.tobytes() if key is None else key) != value.T.tobytes():  # not exactly symmetric
        a = value.tolist() if a is None else a
        if not math.isfinite(sum(map(sum, a))):
            return False
        tol = SYM_RTOL * max(1.0, *value.diagonal().tolist())  # within the tolerance?
        for i in range(1, k):
            ai = a[i]
            for j in range(i):
                if abs(ai[j] - a[j][i]) > tol:
                    return False
    U, info = _dpotrf(value.T, 0, 0)  # A = U^T U (lower=0, clean=0; A^T = A, read in Fortran order, no copy)
    if info:
        return False  # not positive definite (or not numerically)
    pivots = U.diagonal().tolist()
    low = min(pivots)
    # pivots U_ii^2 clearly positive; NaN or infinity in a pivot: not finite
    return math.isfinite(sum(pivots)) and low * low > 1e-12 * max(1.0, *value.diagonal().tolist())


def _small_pd(a, k, value=None):
    """True if the nested list `a` (k = 2 or 3) is finite, symmetric and clearly positive definite.

    From ``k = 4`` up to :data:`SMALL_COV` (with the array `value`), a
    Cholesky factorisation decides (:func:`_small_pd_chol`).

    False for anything else (the caller then runs the full check). The scale of
    the tolerances is the largest diagonal entry: for a positive definite matrix
    every ``|a_ij| <= max a_ii``, and a matrix with a larger entry is not
    accepted here, so this test is never looser than the full one.
    """
    if k > 3:
        return value is not None and k <= SMALL_COV and _small_pd_chol(value, a, k)
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


def _small_psd2(a):
    """True if the 2x2 nested list `a` is finite, symmetric and positive semi-definite by a clear margin.

    The eigenvalues in closed form (of the lower triangle, as ``eigvalsh``
    reads it); the smallest must lie above half the tolerance of the full
    check, far above the rounding of either computation, so this test is never
    looser than the full one. False decides nothing (e.g. a singular matrix
    asked to be definite goes the long way).
    """
    (a00, a01), (a10, a11) = a
    if not math.isfinite(a00 + a01 + a10 + a11):
        return False
    if abs(a01 - a10) > SYM_RTOL * max(1.0, abs(a00), abs(a01), abs(a10), abs(a11)):
        return False
    mid, rad = 0.5 * (a00 + a11), math.hypot(0.5 * (a00 - a11), a10)
    low, high = mid - rad, mid + rad
    return low >= -0.5 * PSD_RTOL * max(1.0, abs(low), abs(high))


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


def as_slam_mean(value, name="mu"):
    """A landmark-SLAM mean ``[x, y, theta, m0x, m0y, ...]``, shape ``(3+2N,)``, finite."""
    mu = as_array(value, name, ndim=1)
    if mu.shape[0] < 3 or (mu.shape[0] - 3) % 2:
        raise ValueError(f"{name} must have shape (3+2N,) = [x, y, theta, m0x, m0y, ...], got {mu.shape}")
    return mu


def as_slam_state(mu, Sigma, mu_name="mu", sigma_name="Sigma"):
    """A landmark-SLAM Gaussian: :func:`as_slam_mean` and its ``(3+2N, 3+2N)`` covariance (symmetric, PSD).

    The semi-definiteness test costs an eigendecomposition, ``O(N^3)``: no more
    than a teaching version's dense algebra; a fast filter checks once, when it
    takes the state.
    """
    mu = as_slam_mean(mu, mu_name)
    return mu, as_covariance(Sigma, sigma_name, mu.shape[0], ref=mu_name)


def as_rigid_transform(R, t, names=("R", "t")):
    """A 2-D rigid transform ``p -> R p + t``: a rotation matrix ``R (2, 2)`` (orthonormal, det +1) and ``t (2,)``."""
    R = as_array(R, names[0], (2, 2))
    t = as_array(t, names[1], (2,))
    if not np.allclose(R.T @ R, np.eye(2), atol=1e-9) or np.linalg.det(R) < 0:
        raise ValueError(f"{names[0]} must be a rotation matrix (orthonormal, det +1)")
    return R, t


#: Tolerance of the 3-D rotation checks: ``|R^T R - I|`` and ``|det R - 1|`` (data files store
#: rotations as rounded quaternions or angles, so exact orthonormality is not required).
ROTATION_ATOL = 1e-6


def as_rotations(value, name, *, copy=True):
    """3-D rotation matrices ``(3, 3)`` or ``(..., 3, 3)``: orthonormal with ``det +1`` up to :data:`ROTATION_ATOL`."""
    R = as_matrix(value, name, 3, 3, copy=copy)
    err = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max(initial=0.0)
    if err > ROTATION_ATOL or (R.size and np.abs(np.linalg.det(R) - 1.0).max() > ROTATION_ATOL):
        raise ValueError(f"{name} must be a rotation matrix (orthonormal, det +1) or a batch of them")
    return R


def as_rigid_motions(value, name, *, copy=True):
    """Homogeneous 3-D poses ``[[R, t], [0, 0, 0, 1]]``, ``(4, 4)`` or ``(..., 4, 4)``, ``R`` a rotation."""
    T = as_matrix(value, name, 4, 4, copy=copy)
    if T.size and np.abs(T[..., 3, :] - [0.0, 0.0, 0.0, 1.0]).max() > 0.0:
        raise ValueError(f"{name} must be a homogeneous pose [[R, t], [0, 0, 0, 1]]: its last row must be [0, 0, 0, 1]")
    as_rotations(T[..., :3, :3], f"{name}[..., :3, :3]", copy=False)
    return T


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


def as_kernel(value, name, ndim, *, tol=1e-6):
    """A motion kernel: a distribution over displacements centred on zero (odd length along every axis)."""
    arr = as_probabilities(value, name, ndim=ndim, sums_to_one=True, tol=tol)
    if any(s % 2 == 0 for s in arr.shape):
        raise ValueError(f"{name} must have an odd length along every axis (centred on zero displacement), "
                         f"got shape {arr.shape}")
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
    if type(value) is np.ndarray and value.dtype.kind in "iu" and 0 < value.size <= 16 and value.ndim == 1 \
            and (shape is None or value.shape == tuple(shape)):
        lst = value.tolist()  # the common case, a few indices of one step: no ufunc reductions
        if min(lst) >= 0 and max(lst) < upper:
            return value.astype(np.intp)
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


def as_range_bearing(value, name="z"):
    """One range-bearing measurement ``[r, phi]``, shape ``(2,)``, finite, with a positive range
    (the inverse measurement model and its Jacobian are undefined at ``r = 0``)."""
    z = as_array(value, name, (2,))
    if z[0] <= 0:
        raise ValueError(f"{name} must have a positive range {name}[0], got {z[0]}")
    return z


def as_index_set(value, name, upper, *, what="index", why=None):
    """A sorted tuple of distinct Python ints in ``[0, upper)`` from a non-empty sequence of integers.

    Bools and floats are refused; `what` names an index in the messages
    (e.g. ``"pose"``), `why` says why an empty set is refused.
    """
    try:
        raw = list(value)
    except TypeError:
        raise TypeError(f"{name} must be a sequence of {what} indices, got {type(value).__name__}") from None
    for f in raw:
        if isinstance(f, bool) or not isinstance(f, (numbers.Integral, np.integer)):
            raise TypeError(f"{name} must hold integer {what} indices, got {f!r}")
        if not 0 <= f < upper:
            raise ValueError(f"{name} holds {what} {int(f)}, outside 0..{upper - 1}")
    if not raw:
        raise ValueError(f"{name} must hold at least one {what}" + ("" if why is None else f": {why}"))
    return tuple(sorted({int(f) for f in raw}))


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


def as_edges(value, name, n, m=None, *, what=("pose", "landmark")):
    """Index pairs ``(E, 2)`` as a new int64 array (``E`` may be 0).

    Without `m`: edges ``[i, j]`` between `n` nodes (``what[0]`` names one),
    ``0 <= i, j < n`` and ``i != j``. With `m`: pairs ``[i, k]`` of a node
    ``i < n`` and a ``what[1]`` ``k < m``. Integer arrays; floats holding whole
    numbers are taken as the integers they hold.
    """
    arr = np.asarray(value)
    if arr.dtype.kind not in "iu":
        if arr.dtype.kind == "f" and arr.size and np.all(np.isfinite(arr)) and np.all(arr == np.round(arr)):
            arr = arr.astype(np.int64)
        elif arr.size == 0:
            arr = arr.astype(np.int64)
        else:
            raise TypeError(f"{name} must be an integer array of index pairs, got dtype {arr.dtype}")
    arr = arr.astype(np.int64, copy=True)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"{name} must have shape (E, 2), got {arr.shape}")
    hi = n if m is None else m
    bad = np.flatnonzero((arr < 0).any(axis=1) | (arr[:, 0] >= n) | (arr[:, 1] >= hi))
    if bad.size:
        where = f"a {what[0]} outside 0..{n - 1}" + ("" if m is None else f" or a {what[1]} outside 0..{m - 1}")
        raise ValueError(f"{name}[{bad[0]}] = {arr[bad[0]].tolist()} refers to {where}")
    if m is None:
        loop = np.flatnonzero(arr[:, 0] == arr[:, 1])
        if loop.size:
            raise ValueError(f"{name}[{loop[0]}] joins {what[0]} {arr[loop[0], 0]} to itself (i == j)")
    return arr


def as_information(value, name, E, d):
    """`E` information matrices ``(E, d, d)``, each symmetric and positive definite; the message names the first bad one.

    Positive definite means a smallest eigenvalue above ``1e-15`` times the largest.
    """
    W = as_array(value, name, (E, d, d))
    scale = np.maximum(1.0, np.abs(W).max(axis=(1, 2), initial=0.0))
    asym = np.flatnonzero(np.abs(W - np.swapaxes(W, 1, 2)).max(axis=(1, 2), initial=0.0) > SYM_RTOL * scale)
    if asym.size:
        raise ValueError(f"{name}[{asym[0]}] must be symmetric")
    if E:
        eig = np.linalg.eigvalsh(W)
        bad = np.flatnonzero(eig[:, 0] <= 1e-15 * eig[:, -1].clip(min=0))
        if bad.size:
            raise ValueError(f"{name}[{bad[0]}] must be positive definite (smallest eigenvalue {eig[bad[0], 0]:.3g})")
    return W


def as_pose_graph(X, edges, Z, Omega, names=("X", "edges", "Z", "Omega")):
    """A pose graph: poses ``X (n, 3)`` (at least one), edges ``(E, 2)`` between them, relative poses
    ``Z (E, 3)`` and information matrices ``Omega (E, 3, 3)``; see :func:`as_edges`, :func:`as_information`."""
    X = as_poses(X, names[0], allow_empty=False)
    edges = as_edges(edges, names[1], X.shape[0])
    E = edges.shape[0]
    Z = as_array(Z, names[2], (E, 3))
    Omega = as_information(Omega, names[3], E, 3)
    return X, edges, Z, Omega


def as_pose_graph3d(T, edges, Z, Omega, names=("T", "edges", "Z", "Omega")):
    """A 3-D pose graph: poses ``T (n, 4, 4)`` (at least one), edges ``(E, 2)`` between them, relative
    poses ``Z (E, 4, 4)`` and information matrices ``Omega (E, 6, 6)`` (``[translation, rotation]`` order)."""
    T = as_rigid_motions(T, names[0])
    if T.ndim != 3 or T.shape[0] == 0:
        raise ValueError(f"{names[0]} must have shape (n, 4, 4) with n >= 1, got {T.shape}")
    edges = as_edges(edges, names[1], T.shape[0])
    E = edges.shape[0]
    Z = as_rigid_motions(Z, names[2])
    if Z.shape != (E, 4, 4):
        raise ValueError(f"{names[2]} must have shape ({E}, 4, 4) (to match {names[1]}), got {Z.shape}")
    Omega = as_information(Omega, names[3], E, 6)
    return T, edges, Z, Omega
