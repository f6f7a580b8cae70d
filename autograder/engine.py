"""Grading one submission: static checks, one child per function, the tests, the results.

:func:`grade` never raises on account of the submission: a file that cannot be
read, a syntax error, a missing function, a crash, a hang or garbage output all
end as failed tests with a message, and every function keeps its ``max_score``.
"""

from __future__ import annotations

import os
import time
import traceback
import zlib
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from .context import CallError, Ctx, Fail, SkipRest
from .exercises import EXERCISES, get_exercise
from .sandbox import Child, ChildFailed, Limits, describe_isolation
from .spec import VISIBILITY
from .submission import FORBIDDEN, SubmissionError, forbidden_usage, load_submission

__all__ = ["grade", "GradeResult", "TestResult", "run_tests"]

#: A child that crashed is restarted (fresh import) at most this many times per function.
MAX_RESTARTS = 3


@dataclass
class TestResult:
    name: str
    function: str
    score: float
    max_score: float
    output: str
    visibility: str

    @property
    def status(self):
        return "passed" if self.score >= self.max_score - 1e-9 else "failed"


@dataclass
class GradeResult:
    """The outcome of grading one submission."""

    submission: str
    exercise: str | None
    tests: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    isolation: dict = field(default_factory=dict)
    error: str | None = None
    execution_time: float = 0.0

    @property
    def score(self):
        return round(sum(t.score for t in self.tests), 6)

    @property
    def max_score(self):
        return round(sum(t.max_score for t in self.tests), 6)

    def by_function(self):
        out = {}
        for t in self.tests:
            s, m = out.get(t.function, (0.0, 0.0))
            out[t.function] = (round(s + t.score, 6), round(m + t.max_score, 6))
        return out

    def summary_text(self):
        lines = []
        if self.exercise:
            lines.append(f"Exercise {self.exercise}: {self.score:g} / {self.max_score:g} points")
        if self.error:
            lines.append(self.error)
        for n in self.notes:
            lines.append(f"Note: {n}")
        if self.isolation:
            lines.append("Isolation of the submission's code:")
            lines.extend(f"  - {s}" for s in describe_isolation(self.isolation))
        return "\n".join(lines)

    def to_gradescope(self):
        """Gradescope's ``results.json`` content."""
        return {
            "score": self.score,
            "execution_time": int(round(self.execution_time)),
            "output": self.summary_text(),
            "tests": [
                {"name": t.name, "score": round(t.score, 6), "max_score": round(t.max_score, 6), "status": t.status,
                 "output": t.output, "visibility": t.visibility}
                for t in self.tests
            ],
        }

    def text_report(self, *, verbose=False):
        """Readable per-function, per-test report."""
        lines = [f"Grading {self.submission}"]
        lines.append(self.summary_text())
        current = None
        per_fn = self.by_function()
        for t in self.tests:
            if t.function != current:
                current = t.function
                s, m = per_fn[current]
                lines.append("")
                lines.append(f"{current}  {s:g}/{m:g}")
            mark = "PASS" if t.status == "passed" else "FAIL"
            lines.append(f"  [{mark}] {t.name}  ({t.score:g}/{t.max_score:g})")
            if t.status != "passed" or verbose or "note:" in t.output.lower():
                body = t.output if t.status != "passed" else "\n".join(
                    ln for ln in t.output.splitlines() if ln.lower().startswith("note:"))
                for ln in body.splitlines():
                    lines.append(f"         {ln}")
        lines.append("")
        lines.append(f"Total: {self.score:g} / {self.max_score:g}")
        return "\n".join(lines)


def _test_seed(exercise, test_name, base):
    return [int(base), int(zlib.crc32(f"{exercise}/{test_name}".encode()))]


def _zero_all(ex, message):
    return [TestResult(t.name, t.function, 0.0, t.weight, message, VISIBILITY[t.visibility]) for t in ex.tests]


def _call_failure_text(err):
    o = err.outcome
    lines = [f"called {err.call_text}"]
    if o.status == "error":
        lines.append(f"it raised {o.error}")
        if o.where:
            lines.append(o.where)
    else:
        lines.append(o.error or o.status)
    if o.output and o.status in ("error", "crashed", "output", "timeout"):
        tail = o.output.strip()[-600:]
        if tail:
            lines.append("its output ended with:\n" + "\n".join("  | " + ln for ln in tail.splitlines()[-8:]))
    return "\n".join(lines)


class _GroupCaller:
    """Routes a test's calls to the function's child, restarting it after a crash."""

    def __init__(self, child, fn):
        self.child = child
        self.fn = fn
        self.restarts = 0
        self.timed_out = False
        self.broken = None

    def call(self, fn, args, kwargs, *, timeout, names=(), global_seed=None):
        from .sandbox import CallOutcome

        if self.broken:
            return CallOutcome("skipped", error=self.broken)
        if self.child.proc is None:
            if self.restarts >= MAX_RESTARTS:
                self.broken = f"not run: the process running {self.fn} died {self.restarts + 1} times"
                return CallOutcome("skipped", error=self.broken)
            self.restarts += 1
            try:
                self.child.start()
            except ChildFailed as exc:
                self.broken = f"not run: {exc.outcome.error}"
                return exc.outcome
        out = self.child.call(fn, args, kwargs, timeout=timeout, names=names, global_seed=global_seed)
        if out.status == "timeout":
            self.timed_out = True
        return out


def run_tests(ex, fn, caller, *, seed=None, limits=None):
    """Run every test of ``fn`` through ``caller``; return TestResults and blocked attempts."""
    results = []
    blocked = []
    skip_reason = None
    cap = limits.call_timeout if (limits and limits.call_timeout) else None
    for test in ex.tests_for(fn):
        vis = VISIBILITY[test.visibility]
        if skip_reason:
            results.append(TestResult(test.name, fn, 0.0, test.weight, skip_reason, vis))
            continue
        timeout = min(test.timeout, cap) if cap else test.timeout
        s = _test_seed(ex.name, test.name, ex.seed if seed is None else seed)
        ctx = Ctx(caller, fn, ex.params(fn), timeout, np.random.default_rng(s), s)
        try:
            test.run(ctx)
            score, text = test.weight, f"passed ({ctx.calls} call{'s' if ctx.calls != 1 else ''})"
        except Fail as exc:
            score, text = 0.0, "FAILED\n" + str(exc)
        except CallError as exc:
            score, text = 0.0, "FAILED\n" + _call_failure_text(exc)
            if exc.outcome.status == "timeout":
                skip_reason = (f"not run: an earlier call of {fn} timed out (a function that hangs gets no points "
                               "for the tests after it)")
            elif exc.outcome.status == "error" and str(exc.outcome.error or "").startswith("NotImplementedError"):
                skip_reason = f"not run: {fn} raised NotImplementedError in '{test.title}' (not implemented yet)"
        except SkipRest as exc:
            score, text = 0.0, str(exc)
        except Exception as exc:  # noqa: BLE001 - a bug in a test must not end grading
            score = 0.0
            text = ("FAILED\nthe grader could not complete this test "
                    f"({type(exc).__name__}: {exc}); this is likely caused by an unusual result"
                    + (f"\nlast call: {ctx.last_call}" if ctx.last_call else ""))
            if os.environ.get("AUTOGRADER_DEBUG"):
                text += "\n" + traceback.format_exc()
        if score == 0.0 and test.hint:
            text += f"\nHint: {test.hint}"
        if ctx.mutated:
            text += (f"\nNote: {fn} modified its argument{'s' if len(ctx.mutated) > 1 else ''} "
                     f"{', '.join(sorted(ctx.mutated))}; contract functions must not modify their arguments "
                     "(the values were still judged)")
        for n in dict.fromkeys(ctx.notes):
            text += f"\nNote: {n}"
        blocked.extend(ctx.blocked)
        results.append(TestResult(test.name, fn, score, test.weight, text, vis))
    return results, blocked


def _grade_function(ex, fn, sub, limits, seed, forbidden):
    tests = ex.tests_for(fn)
    vis = {t.name: VISIBILITY[t.visibility] for t in tests}

    def zero(msg):
        return [TestResult(t.name, fn, 0.0, t.weight, msg, vis[t.name]) for t in tests]

    if fn in forbidden:
        return zero(f"FAILED\nNo credit: {forbidden[fn]}. Graded functions must be your own code "
                    "(NumPy, SciPy and the standard library are fine; slamlib and the autograder are not)."), None
    child = Child(sub.units, [fn], limits, sub.display_name)
    try:
        try:
            ready = child.start()
        except ChildFailed as exc:
            return zero(f"FAILED\n{exc.outcome.error}"), None
        info = (ready.get("functions") or {}).get(fn) or {}
        if not info.get("defined"):
            msg = f"FAILED\n{fn} is not defined in your submission"
            if sub.syntax_errors:
                msg += (" (some cells could not be read: "
                        + "; ".join(f"{k}: {v}" for k, v in sub.syntax_errors.items()) + ")")
            return zero(msg), ready
        if not info.get("callable"):
            return zero(f"FAILED\n{fn} is defined but is not a function"), ready
        unit_files = {u["filename"] for u in sub.units}
        module = info.get("module") or ""
        filename = info.get("filename")
        if (isinstance(module, str) and module.split(".")[0] in FORBIDDEN) or (
                filename is not None and filename not in unit_files and _in_blocked_tree(filename)):
            return zero(f"FAILED\nNo credit: {fn} is not defined by your code (it comes from {module or filename})."), ready
        caller = _GroupCaller(child, fn)
        results, blocked = run_tests(ex, fn, caller, seed=seed, limits=limits)
        if blocked:
            what = ", ".join(dict.fromkeys(blocked))
            uses_forbidden = any(b.startswith(("import ", "open ")) for b in blocked)
            if uses_forbidden:
                msg = (f"FAILED\nNo credit: while being graded, {fn} tried to use slamlib or the autograder ({what}). "
                       "Graded functions must be your own code.")
                return zero(msg), ready
            for r in results:
                r.output += f"\nNote: refused while running {fn}: {what} (no processes, network or ctypes while grading)"
        return results, ready
    finally:
        child.close()


def _in_blocked_tree(filename):
    from .sandbox import BLOCKED_PATHS

    full = os.path.realpath(filename) if os.path.isabs(filename) else filename
    return any(full.startswith(p) for p in BLOCKED_PATHS)


def grade(path, exercise=None, *, limits=None, workers=None, seed=None, functions=None):
    """Grade one submission file.

    Parameters
    ----------
    path : str or Path
        ``.ipynb`` or ``.py``.
    exercise : str, optional
        Exercise name; defaults to the one the notebook names in its metadata.
    limits : Limits, optional
        Child resource limits.
    workers : int, optional
        Functions graded in parallel (each in its own child); default: CPU count.
    seed : int, optional
        Base seed of the test inputs (the exercise's fixed seed by default).
    functions : list of str, optional
        Grade only these contract functions (for re-grading one function; the
        results then hold only their tests).

    Returns
    -------
    GradeResult
    """
    t0 = time.perf_counter()
    limits = limits or Limits()
    name = os.path.basename(str(path))
    result = GradeResult(name, None)
    try:
        sub = load_submission(path)
    except SubmissionError as exc:
        sub = None
        load_error = str(exc)
    else:
        load_error = None
    ex_name = exercise or (sub.exercise if sub else None)
    if ex_name is None:
        result.error = ((load_error + "\n") if load_error else "") + (
            "Cannot tell which exercise this is: pass --exercise NAME (one of " + ", ".join(EXERCISES) + ")")
        result.execution_time = time.perf_counter() - t0
        return result
    try:
        ex = get_exercise(ex_name)
    except KeyError:
        result.error = f"Unknown exercise {ex_name!r}; known: {', '.join(EXERCISES)}"
        result.execution_time = time.perf_counter() - t0
        return result
    result.exercise = ex.name
    if load_error:
        result.error = f"The submission could not be read: {load_error}"
        result.tests = _zero_all(ex, f"FAILED\n{load_error}")
        result.execution_time = time.perf_counter() - t0
        return result
    result.notes.extend(sub.notes)
    if sub.exercise and sub.exercise != ex.name:
        msg = (f"This is the notebook of exercise {sub.exercise!r}, but it was submitted for {ex.name!r}: "
               f"submit {ex.notebook}.")
        result.error = msg
        result.tests = _zero_all(ex, "FAILED\n" + msg)
        result.execution_time = time.perf_counter() - t0
        return result
    if not any(u["source"].strip() for u in sub.units):
        msg = "The submission contains no code."
        result.error = msg
        result.tests = _zero_all(ex, "FAILED\n" + msg)
        result.execution_time = time.perf_counter() - t0
        return result
    forbidden = forbidden_usage(sub.units, list(ex.functions))
    if functions:
        unknown = [f for f in functions if f not in ex.functions]
        if unknown:
            raise ValueError(f"not functions of {ex.name}: {', '.join(unknown)}")
        functions = [f for f in ex.functions if f in functions]
    else:
        functions = list(ex.functions)
    workers = workers or min(len(functions), os.cpu_count() or 2)
    if workers <= 1:
        outs = [_grade_function(ex, fn, sub, limits, seed, forbidden) for fn in functions]
    else:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            outs = list(pool.map(lambda fn: _grade_function(ex, fn, sub, limits, seed, forbidden), functions))
    load_notes = None
    for results, ready in outs:
        result.tests.extend(results)
        if ready and load_notes is None:
            load_notes = ready.get("notes") or []
            result.isolation = ready.get("isolation") or {}
    for n in load_notes or []:
        result.notes.append(f"while loading: {n}")
    result.execution_time = time.perf_counter() - t0
    return result
