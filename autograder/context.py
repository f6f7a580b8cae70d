"""What a test case sees: calling the student's function and checking results.

:class:`Ctx` is handed to every test's ``run(ctx)``. ``ctx.call(...)`` sends the
arguments to the child process running the submission (or, in the student's own
self-check, calls the function in-process) and returns the decoded result;
``ctx.expect`` checks the contract's output rules (tuple arity, exact shape,
real float or integer dtype, finiteness) and the other helpers compare values
with explicit tolerances. Every failed check raises :class:`Fail` with a message
that names the call that produced the bad value.

All comparisons happen here, in the grader's process, on plain float64 arrays of
identical shape (never broadcasting).
"""

from __future__ import annotations

import numpy as np

from .wire import Returned, RngSeed, describe_value

__all__ = ["Ctx", "Fail", "CallError", "Out", "RngSeed", "fmt_array", "wrap"]


class Fail(Exception):
    """A check failed; the message is shown to the student."""


class CallError(Exception):
    """The student's function did not return (raised, crashed, timed out ...)."""

    def __init__(self, outcome, call_text, fatal=False):
        super().__init__(outcome.error)
        self.outcome = outcome
        self.call_text = call_text
        self.fatal = fatal


class SkipRest(Exception):
    """Stop running this function's tests (after a timeout)."""


def wrap(a):
    """Wrap angles to ``[-pi, pi)`` (the grader's own helper, float64)."""
    a = np.asarray(a, dtype=float)
    out = np.mod(a + np.pi, 2 * np.pi) - np.pi
    return np.where(out >= np.pi, out - 2 * np.pi, out)


def fmt_array(a, max_items=24):
    """Compact one-line text of a small array (or a summary of a large one)."""
    a = np.asarray(a)
    if a.size > max_items:
        return f"<array of shape {a.shape}>"
    if a.ndim == 0:
        return np.format_float_positional(float(a), precision=8, trim="-") if a.dtype.kind == "f" else str(a)
    return np.array2string(a, precision=6, separator=", ", max_line_width=10**6, suppress_small=False,
                           floatmode="maxprec").replace("\n", "")


def _fmt_arg(v):
    if isinstance(v, RngSeed):
        return repr(v)
    if isinstance(v, np.ndarray):
        return fmt_array(v)
    if isinstance(v, float):
        return np.format_float_positional(v, precision=8, trim="-")
    return repr(v)


class Out:
    """Expected form of one returned value.

    Parameters
    ----------
    name : str
        Name used in messages (``"x_next"``, ``"G"`` ...).
    shape : tuple of int, or callable
        Exact shape (``()`` for a scalar).
    kind : str
        ``"float"`` (real floating dtype), ``"int"`` (an integer array) or
        ``"index"`` (a Python int or NumPy integer scalar).
    """

    def __init__(self, name, shape, kind="float"):
        self.name = name
        self.shape = tuple(shape)
        self.kind = kind


class Ctx:
    """The grading context of one test.

    Parameters
    ----------
    caller : object
        Has ``call(fn, args, kwargs, timeout=, names=, global_seed=)`` returning a
        :class:`~autograder.sandbox.CallOutcome` (a child process or in-process).
    function : str
        The contract function under test.
    params : list of str
        Its contract parameter names (for messages and mutation reports).
    timeout : float
        Per-call wall-clock limit.
    rng : numpy.random.Generator
        The test's seeded generator for inputs.
    """

    def __init__(self, caller, function, params, timeout, rng, seed):
        self.caller = caller
        self.function = function
        self.params = params
        self.timeout = timeout
        self.rng = rng
        self.seed = seed
        self.calls = 0
        self.last_call = None
        self.mutated = set()
        self.blocked = []
        self.notes = []

    # ------------------------------------------------------------------ calling
    def describe_call(self, fn, args, kwargs):
        names = self.params if fn == self.function else []
        parts = []
        for i, a in enumerate(args):
            label = names[i] if i < len(names) else None
            parts.append(f"{label}={_fmt_arg(a)}" if label else _fmt_arg(a))
        parts.extend(f"{k}={_fmt_arg(v)}" for k, v in kwargs.items())
        return f"{fn}({', '.join(parts)})"

    def call(self, *args, **kwargs):
        """Call the function under test with these arguments; returns a :class:`Returned`."""
        return self.call_fn(self.function, args, kwargs)

    def call_fn(self, fn, args, kwargs=None, *, global_seed=None):
        kwargs = dict(kwargs or {})
        args = tuple(np.array(a, dtype=float) if isinstance(a, list) else a for a in args)
        text = self.describe_call(fn, args, kwargs)
        self.last_call = text
        self.calls += 1
        names = self.params if fn == self.function else []
        names = names + [k for k in kwargs]
        outcome = self.caller.call(fn, list(args), kwargs, timeout=self.timeout, names=names[: len(args)],
                                   global_seed=global_seed)
        if outcome.mutated:
            self.mutated.update(outcome.mutated)
        if outcome.blocked:
            self.blocked.extend(outcome.blocked)
        if outcome.status != "ok":
            raise CallError(outcome, text)
        return outcome.returned

    # ------------------------------------------------------------------ failures
    def fail(self, message):
        where = f"called {self.last_call}\n" if self.last_call else ""
        raise Fail(where + message)

    # ------------------------------------------------------------------ output rules
    def expect(self, ret, *outs):
        """Check a returned value against the contract's output rules.

        With one :class:`Out`, the result itself must match; with several, the
        result must be a tuple (or list) of exactly that many items. Returns the
        values as float64 arrays (``kind="float"``), int64 arrays (``"int"``) or
        Python ints (``"index"``); a single value is returned bare.
        """
        if not isinstance(ret, Returned):
            self.fail("internal: no result")
        fname = self.function
        if len(outs) == 1:
            out = outs[0]
            if ret.seq_kind is not None:
                if out.kind == "index":
                    self.fail(f"{fname} must return a single integer ({out.name}), got {ret.describe()}")
                value = ret.whole
            else:
                value = ret.value
            return self._value(value, out)
        names = ", ".join(o.name for o in outs)
        if ret.seq_kind is None:
            self.fail(f"{fname} must return a tuple ({names}); got {ret.describe()}")
        if ret.n != len(outs):
            self.fail(f"{fname} must return a tuple of {len(outs)} items ({names}); got {ret.describe()}")
        return tuple(self._value(v, o) for v, o in zip(ret.items, outs))

    def _value(self, v, out):
        if v.array is None:
            self.fail(f"{out.name}: {v.problem}; expected {self._want(out)}")
        a = v.array
        if v.subclass:
            self.notes.append(f"{out.name} was an ndarray subclass ({v.subclass}); it was judged as a plain array")
        kind = a.dtype.kind
        if out.kind == "index":
            if a.shape != () or kind not in "iu" or not v.int_like:
                self.fail(f"{out.name} must be a Python int or NumPy integer; got {describe_value(v)}")
            return int(a)
        if out.kind == "int":
            if kind not in "iu":
                self.fail(f"{out.name} must have an integer dtype; got {describe_value(v)}")
            if a.shape != out.shape:
                self.fail(f"{out.name} must have shape {out.shape}; got shape {a.shape}")
            return a.astype(np.int64)
        if kind == "c":
            self.fail(f"{out.name} must be real; got a complex dtype ({a.dtype})")
        if kind != "f":
            self.fail(f"{out.name} must have a real floating dtype; got {describe_value(v)}")
        if a.shape != out.shape:
            self.fail(f"{out.name} must have shape {out.shape}; got shape {a.shape}")
        a = a.astype(np.float64)
        if not np.all(np.isfinite(a)):
            bad = np.argwhere(~np.isfinite(a))
            self.fail(f"{out.name} contains NaN or inf (first at index {tuple(int(i) for i in bad[0])}): {fmt_array(a)}")
        return a

    @staticmethod
    def _want(out):
        if out.kind == "index":
            return "an int"
        return f"an array of shape {out.shape} and dtype {'float64' if out.kind == 'float' else 'int'}"

    # ------------------------------------------------------------------ comparisons
    def close(self, name, got, expected, *, atol=1e-8, rtol=1e-6, angles=None, note=""):
        """``|got - expected| <= atol + rtol |expected|`` elementwise, same shape.

        ``angles``: indices along the last axis (or ``True`` for all entries)
        compared through their wrapped difference.
        """
        got = np.asarray(got, dtype=float)
        expected = np.asarray(expected, dtype=float)
        if got.shape != expected.shape:
            self.fail(f"{name} must have shape {expected.shape}; got shape {got.shape}")
        diff = got - expected
        if angles is True:
            diff = wrap(diff)
        elif angles:
            diff = diff.copy()
            diff[..., list(angles)] = wrap(diff[..., list(angles)])
        err = np.abs(diff)
        allowed = atol + rtol * np.abs(expected)
        bad = err > allowed
        if np.any(bad) or not np.all(np.isfinite(err)):
            idx = np.unravel_index(int(np.argmax(np.where(bad, err - allowed, -np.inf))), err.shape) if err.ndim else ()
            where = f" at index {tuple(int(i) for i in idx)}" if err.ndim else ""
            msg = (f"{name} is wrong: error {err[idx]:.3g}{where} (allowed {atol:g} + {rtol:g} |expected|)"
                   + (f" {note}" if note else "") + f"\n  expected {fmt_array(expected)}\n  got      {fmt_array(got)}")
            if expected.size > 24 and err.ndim:
                at = "[" + ", ".join(str(int(i)) for i in idx) + "]"
                msg += (f"\n  expected {name}{at} = {fmt_array(expected[idx])}, got {name}{at} = "
                        f"{fmt_array(got[idx])}")
            self.fail(msg)

    def wrapped(self, name, angles):
        """Angles must lie in ``[-pi, pi)``."""
        a = np.asarray(angles, dtype=float)
        bad = (a < -np.pi) | (a >= np.pi)
        if np.any(bad):
            v = a[bad].ravel()[0]
            self.fail(f"{name} must be wrapped to [-pi, pi); got {v:.6f}")

    def symmetric(self, name, S, *, tol=1e-9):
        S = np.asarray(S, dtype=float)
        scale = max(1.0, float(np.abs(S).max(initial=0.0)))
        asym = float(np.abs(S - np.swapaxes(S, -1, -2)).max(initial=0.0))
        if asym > tol * scale:
            self.fail(f"{name} must be symmetric: |{name} - {name}^T| reaches {asym:.3g}")

    def equal(self, name, got, expected):
        got = np.asarray(got)
        expected = np.asarray(expected)
        if got.shape != expected.shape:
            self.fail(f"{name} must have shape {expected.shape}; got shape {got.shape}")
        if not np.array_equal(got, expected):
            idx = np.argwhere(got != expected)
            first = tuple(int(i) for i in idx[0]) if idx.size else ()
            self.fail(f"{name} differs from the expected value (first difference at index {first})"
                      f"\n  expected {fmt_array(expected)}\n  got      {fmt_array(got)}")
