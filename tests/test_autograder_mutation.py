"""The grader's tests catch wrong code: garbage scores 0 everywhere, mutants of slamlib lose points.

* Garbage: for every contract function, a submission returning zeros of the right
  shape, random values of the right shape, or its own inputs scores 0 on *every*
  test of that function (property and end-to-end tests included).
* Mutants: :mod:`mutation` derives wrong versions of each contract function from
  slamlib's own source; the grader must take points from at least 95 % of the
  mutants that are not equivalent (those are listed with their reason in
  :mod:`mutation_table`). A deterministic sample runs here; every mutant runs in the
  ``slow`` test. ``python -m tests.mutation`` prints the kill rate per function.
* Reports: a failed test shows the call, the expected and received values and a hint;
  an untouched stub gives one traceback per function.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

import mutation  # noqa: E402
from mutation_table import EQUIVALENT, NOT_KILLED  # noqa: E402

import slamlib  # noqa: E402
from autograder.engine import run_tests  # noqa: E402
from autograder.exercises import get_exercise  # noqa: E402
from autograder.selfcheck import InProcessCaller  # noqa: E402

FUNCTIONS = [fn for fns in mutation.CONTRACT.values() for fn in fns]
GARBAGE = ("zeros", "random", "inputs")
#: Every K-th mutant of each function in the default suite (the slow test grades them all).
FAST_EVERY = 12
KILL_RATE = 0.95


# =========================================================================== garbage
def _garble(value, args, kind, rng):
    """A value of the same form as ``value`` (the right answer) filled with garbage."""
    if isinstance(value, tuple):
        return tuple(_garble(v, args, kind, rng) for v in value)
    if hasattr(value, "toarray"):  # a scipy.sparse matrix (build_linear_system's H): garbage of its dense form
        value = value.toarray()
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        if kind == "zeros":
            return 0
        if kind == "random":
            return int(rng.integers(-1, 6))
        ints = [a for a in args if isinstance(a, (int, np.integer))]
        return int(ints[0]) if ints else 0
    a = np.asarray(value)
    if kind == "zeros":
        return np.zeros_like(a)
    if kind == "random":
        if a.dtype.kind in "iu":
            return rng.integers(0, max(a.size, 1), size=a.shape).astype(a.dtype)
        out = rng.random(a.shape)
        return float(out) if a.ndim == 0 and isinstance(value, float) else out
    for arg in args:  # the first input of the same shape, returned as it came
        if isinstance(arg, np.ndarray) and arg.shape == a.shape:
            return arg.astype(a.dtype) if a.dtype.kind in "iu" else arg
    return np.zeros_like(a)


def garbage_namespace(fn, kind, seed=0):
    """A submission whose ``fn`` returns garbage of the form of slamlib's answer."""
    ref = getattr(slamlib, fn)
    rng = np.random.default_rng(seed)

    def f(*args, **kwargs):
        return _garble(ref(*args, **kwargs), args, kind, rng)

    return {fn: f}


@pytest.mark.parametrize("kind", GARBAGE)
@pytest.mark.parametrize("fn", FUNCTIONS)
def test_garbage_scores_zero_on_every_test(fn, kind):
    rows = mutation.grade_namespace(fn, garbage_namespace(fn, kind), stop_at_first=False)
    paid = [(name, score, out) for name, score, _, out in rows if score > 0]
    assert not paid, f"{fn} returning {kind} earned points: {paid}"


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_garbage_scores_zero_for_other_grading_seeds(seed):
    """The tests hold for any seed, not only the default one."""
    for fn in FUNCTIONS:
        for kind in GARBAGE:
            rows = mutation.grade_namespace(fn, garbage_namespace(fn, kind, seed), stop_at_first=False,
                                            seed=seed * 7919)
            assert all(score == 0 for _, score, _, _ in rows), (fn, kind, seed, rows)


@pytest.mark.parametrize("seed", [mutation.SEED, 1])
def test_reference_scores_full_marks_for_any_seed(seed):
    for fn in FUNCTIONS:
        ns = mutation.load(mutation.submission_source(fn))
        rows = mutation.grade_namespace(fn, ns, stop_at_first=False, seed=seed * 7919 if seed != mutation.SEED
                                        else seed)
        lost = [(name, out) for name, score, top, out in rows if score < top]
        assert not lost, (fn, seed, lost)


# =========================================================================== reports
@pytest.mark.parametrize("fn", FUNCTIONS)
def test_failure_shows_call_expected_received_and_hint(fn):
    rows = mutation.grade_namespace(fn, garbage_namespace(fn, "random"), stop_at_first=False)
    for name, score, _, out in rows:
        assert score == 0
        if out.startswith("not run"):
            continue
        assert f"called {fn}(" in out, (name, out)
        assert "expected" in out, (name, out)
        assert "Hint:" in out, (name, out)


@pytest.mark.parametrize("exercise", list(mutation.CONTRACT))
def test_stub_report_has_one_traceback_per_function(exercise):
    ex = get_exercise(exercise)

    def stub(*args, **kwargs):
        raise NotImplementedError("replace this line with your implementation")

    ns = {fn: stub for fn in ex.functions}
    for fn in ex.functions:
        results, _ = run_tests(ex, fn, InProcessCaller(ns))
        assert all(r.score == 0 for r in results)
        raised = [r for r in results if "NotImplementedError" in r.output and not r.output.startswith("not run")]
        assert len(raised) == 1, [r.output for r in results]
        rest = [r for r in results if r is not raised[0]]
        assert all(r.output.startswith("not run") and len(r.output.splitlines()) == 1 for r in rest), \
            [r.output for r in rest]
        lines = sum(len(r.output.splitlines()) + 1 for r in results)
        assert lines <= 30, "\n".join(r.output for r in results)


# =========================================================================== mutants
def test_mutants_cover_every_contract_function_and_operator():
    for fn in FUNCTIONS:
        ms = mutation.mutants(fn)
        assert len(ms) >= 10, fn
        assert fn in {m.host for m in ms}, f"{fn} itself is not mutated"
    labels = [m.key for m in mutation.mutants("ekf_update")]
    for marker in ("wrap_angle(", " -> Q", "_T(", "np.swapaxes"):
        assert any(marker in k for k in labels), marker


def test_reference_submission_is_slamlib_and_scores_full_marks():
    ns = mutation.load(mutation.submission_source("ekf_slam_update"))
    for fn in FUNCTIONS:
        src = mutation.submission_source(fn)
        assert "import slamlib" not in src and "from slamlib" not in src and "from ." not in src, fn
    rows = mutation.grade_namespace("ekf_slam_update", ns, stop_at_first=False)
    assert all(score == top for _, score, top, _ in rows)


def test_every_table_entry_names_a_mutant():
    """The tables name real mutants (a stale entry would hide nothing but mislead)."""
    for table in (EQUIVALENT, NOT_KILLED):
        for fn, entries in table.items():
            ms = mutation.mutants(fn)
            stale = [k for k in entries if not any(mutation.reason({fn: {k: "x"}}, m) for m in ms)]
            assert not stale, (fn, stale)


def _check_rates(report):
    rows = mutation.summarize(report, EQUIVALENT, NOT_KILLED)
    bad = [(fn, rate, [m.label for m in unexplained]) for fn, total, eq, non_eq, killed, rate, unexplained in rows
           if rate < KILL_RATE or unexplained]
    assert not bad, bad


@pytest.mark.parametrize("fn", FUNCTIONS)
def test_grader_kills_a_sample_of_mutants(fn):
    _check_rates(mutation.run([fn], every=FAST_EVERY))


@pytest.mark.slow
@pytest.mark.parametrize("fn", FUNCTIONS)
def test_grader_kills_every_nonequivalent_mutant(fn):
    _check_rates(mutation.run([fn]))
