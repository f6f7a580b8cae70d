"""The student's self-check: run an exercise's public tests on functions defined in a notebook.

In the last cell of each exercise notebook::

    from autograder.selfcheck import run_public_tests
    run_public_tests("motion_sensor_models", globals())

The tests are the grader's own public tests, with the same inputs, tolerances
and messages; they run in the notebook's process (the student trusts their own
code), without time limits. The hidden tests run only when grading.
"""

from __future__ import annotations

import random
import traceback
from dataclasses import dataclass, field

import numpy as np

from .wire import decode_result, encode_result
from .context import RngSeed
from .engine import run_tests
from .exercises import get_exercise
from .sandbox import CallOutcome

__all__ = ["run_public_tests", "SelfCheckReport", "InProcessCaller"]


class InProcessCaller:
    """Calls functions from a namespace directly, with the grader's output checks."""

    def __init__(self, namespace):
        self.namespace = namespace

    def call(self, fn, args, kwargs, *, timeout=None, names=(), global_seed=None):
        f = self.namespace.get(fn)
        if f is None:
            return CallOutcome("error", error=f"NameError: {fn} is not defined (run the cell that defines it)")
        if not callable(f):
            return CallOutcome("error", error=f"TypeError: {fn} is not a function")
        conv = [np.random.default_rng(a.seed) if isinstance(a, RngSeed) else (np.array(a) if isinstance(a, np.ndarray)
                else a) for a in args]
        kw = {k: (np.random.default_rng(v.seed) if isinstance(v, RngSeed) else (np.array(v) if isinstance(v, np.ndarray)
              else v)) for k, v in kwargs.items()}
        pristine = [np.array(a) if isinstance(a, np.ndarray) else None for a in conv]
        if global_seed is not None:
            np.random.seed(global_seed % (2**32))
            random.seed(global_seed)
        try:
            out = f(*conv, **kw)
        except Exception as exc:  # noqa: BLE001 - report the student's error
            tb = traceback.extract_tb(exc.__traceback__)[1:]
            where = "\n".join(f"  line {fr.lineno}, in {fr.name}" + (f"\n    {fr.line}" if fr.line else "")
                              for fr in tb[-3:])
            if isinstance(exc, NotImplementedError):
                return CallOutcome("error", error="NotImplementedError: not implemented yet")
            return CallOutcome("error", error=f"{type(exc).__name__}: {exc}", where=where)
        desc, payload = encode_result(out, np)
        returned = decode_result(desc, payload, np)
        mutated = [names[i] if i < len(names) else f"argument {i + 1}" for i, (a, p) in enumerate(zip(conv, pristine))
                   if p is not None and not (isinstance(a, np.ndarray) and a.shape == p.shape
                                             and np.array_equal(a, p, equal_nan=True))]
        return CallOutcome("ok", returned=returned, mutated=mutated)


@dataclass
class SelfCheckReport:
    """Outcome of :func:`run_public_tests`: ``(name, passed, points, max_points, message)`` per test."""

    exercise: str
    results: list = field(default_factory=list)

    @property
    def score(self):
        return sum(r.score for r in self.results)

    @property
    def max_score(self):
        return sum(r.max_score for r in self.results)

    @property
    def all_passed(self):
        return all(r.status == "passed" for r in self.results)

    def __repr__(self):
        return f"SelfCheckReport({self.exercise!r}: {self.score:g}/{self.max_score:g})"


def run_public_tests(exercise, namespace, *, functions=None, show=True):
    """Run the public tests of ``exercise`` on the functions in ``namespace`` and print a report.

    Parameters
    ----------
    exercise : str
        Exercise name (the notebook's ``metadata["slam_course"]["exercise"]``).
    namespace : dict
        Where the functions live, usually ``globals()``.
    functions : list of str, optional
        Only these contract functions.
    show : bool
        Print the per-test report.

    Returns
    -------
    SelfCheckReport
    """
    ex = get_exercise(exercise)
    report = SelfCheckReport(ex.name)
    caller = InProcessCaller(namespace)
    public = type(ex)(ex.name, ex.title, ex.notebook, ex.functions, ex.seed,
                      [t for t in ex.tests if t.visibility == "public"])
    for fn in ex.functions:
        if functions and fn not in functions:
            continue
        results, _ = run_tests(public, fn, caller)
        report.results.extend(results)
    if show:
        _print(ex, report)
    return report


def _print(ex, report):
    lines = [f"Public tests of exercise '{ex.name}'"]
    current = None
    for r in report.results:
        if r.function != current:
            current = r.function
            got = sum(x.score for x in report.results if x.function == current)
            tot = sum(x.max_score for x in report.results if x.function == current)
            lines.append(f"\n{current}: {got:g}/{tot:g}")
        ok = r.status == "passed"
        lines.append(f"  {'PASS' if ok else 'FAIL'}  {r.name}")
        if not ok:
            lines.extend("        " + ln for ln in r.output.splitlines()[1:])
    shown = {r.function for r in report.results}
    hidden = sum(t.weight for t in ex.tests if t.visibility == "hidden" and t.function in shown)
    lines.append(f"\nPublic tests: {report.score:g}/{report.max_score:g} points. "
                 f"The grader also runs hidden tests worth {hidden:g} more points.")
    print("\n".join(lines))
