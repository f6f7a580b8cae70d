"""Exercise 7 (bundle_adjustment): the grader's guarantees, run for its functions only.

The same checks as :mod:`test_autograder_mutation` (garbage scores 0, slamlib and an
independent solution score full marks for several seeds, a stub gives one traceback
per function, at least 95 % of the non-equivalent mutants are killed), restricted to
exercise 7, plus the end-to-end drivers the grader plugs the functions into.
"""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

import mutation  # noqa: E402
from mutation_table import EQUIVALENT, NOT_KILLED  # noqa: E402
from test_autograder_mutation import GARBAGE, KILL_RATE, garbage_namespace  # noqa: E402

import slamlib as sl  # noqa: E402
from autograder.engine import run_tests  # noqa: E402
from autograder.exercises import get_exercise  # noqa: E402
from autograder.selfcheck import InProcessCaller  # noqa: E402

EX = get_exercise("bundle_adjustment")
FUNCTIONS = list(EX.functions)
SOLUTION = Path(__file__).resolve().parent / "autograder_fixtures" / "solutions" / "bundle_adjustment.py"


def test_registered_with_every_contract_function():
    assert FUNCTIONS == ["so3_exp", "so3_log", "project", "triangulate", "eight_point", "schur_complement",
                         "back_substitute"]
    assert mutation.exercise_of("schur_complement") == "bundle_adjustment"
    for fn in FUNCTIONS:
        assert any(t.visibility == "hidden" for t in EX.tests_for(fn)) or fn in ("so3_log",), fn


@pytest.mark.parametrize("kind", GARBAGE)
@pytest.mark.parametrize("fn", FUNCTIONS)
def test_garbage_scores_zero(fn, kind):
    for seed in (0, 3):
        rows = mutation.grade_namespace(fn, garbage_namespace(fn, kind, seed), stop_at_first=False,
                                        seed=mutation.SEED if seed == 0 else seed * 7919)
        paid = [(name, score) for name, score, _, _ in rows if score > 0]
        assert not paid, (fn, kind, paid)


@pytest.mark.parametrize("seed", [mutation.SEED, 7919, 5 * 7919])
def test_slamlib_and_an_independent_solution_score_full_marks(seed):
    ref = mutation.load(mutation.submission_source("so3_exp"))
    indep = runpy.run_path(str(SOLUTION))
    for fn in FUNCTIONS:
        for ns in (mutation.load(mutation.submission_source(fn)), indep):
            rows = mutation.grade_namespace(fn, ns, stop_at_first=False, seed=seed)
            lost = [(name, out) for name, score, top, out in rows if score < top]
            assert not lost, (fn, seed, lost)
    assert "import slamlib" not in mutation.submission_source("schur_complement")
    del ref


def test_stub_scores_zero_with_one_traceback_per_function():
    def stub(*args, **kwargs):
        raise NotImplementedError("replace this line with your implementation")

    ns = {fn: stub for fn in FUNCTIONS}
    for fn in FUNCTIONS:
        results, _ = run_tests(EX, fn, InProcessCaller(ns))
        assert all(r.score == 0 for r in results)
        raised = [r for r in results if "NotImplementedError" in r.output and not r.output.startswith("not run")]
        assert len(raised) == 1, [r.output for r in results]


@pytest.mark.parametrize("fn", FUNCTIONS)
def test_grader_kills_the_mutants(fn):
    rows = mutation.summarize(mutation.run([fn], every=2), EQUIVALENT, NOT_KILLED)
    for name, total, eq, non_eq, killed, rate, unexplained in rows:
        assert rate >= KILL_RATE and not unexplained, (name, rate, [m.label for m in unexplained])


def test_a_planted_bug_costs_points_and_names_the_function():
    """A Jacobian with the wrong sign of the rotation block fails the value and finite-difference tests."""
    def bad_project(K, T_wc, P):
        uv, Jp, Jx = sl.project(K, T_wc, P)
        Jp = Jp.copy()
        Jp[..., 3:] *= -1.0
        return uv, Jp, Jx

    results, _ = run_tests(EX, "project", InProcessCaller({"project": bad_project}))
    assert results[0].score == 0 and "J_pose" in results[0].output and "called project(" in results[0].output


def test_drivers_with_slamlib_hooks_equal_the_plain_drivers():
    rng = np.random.default_rng(0)
    from autograder.exercises import bundle_adjustment as B

    T0, P0, K, cam, point, uv = B._ba_problem(rng, 3, 10)
    a = sl.bundle_adjust(T0, P0, K, cam, point, uv, max_iter=5, rtol=0.0)
    b = sl.bundle_adjust(T0, P0, K, cam, point, uv, max_iter=5, rtol=0.0, project=sl.project, so3_exp=sl.so3_exp,
                         schur_complement=sl.schur_complement, back_substitute=sl.back_substitute)
    np.testing.assert_allclose(a.cost, b.cost, rtol=1e-9)
    np.testing.assert_allclose(a.points, b.points, atol=1e-9)
