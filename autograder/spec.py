"""Declaring exercises and their test cases.

Each exercise module under :mod:`autograder.exercises` builds one
:class:`Exercise` and registers test cases with its :meth:`Exercise.test`
decorator::

    EX = Exercise("motion_sensor_models", "Motion and sensor models", notebook="01_motion_sensor_models.ipynb",
                  functions={"velocity_motion": "(x, u, dt)", ...})

    @EX.test("velocity_motion", "straight-line limit", weight=3, hint="For |omega| < 1e-6 ...")
    def _(ctx):
        got = ctx.call(x, u, dt)                     # runs in the child process
        x_next, G, V = ctx.expect(got, OUT_X, OUT_G, OUT_V)
        ref = sl.velocity_motion(x, u, dt)           # runs here, in the grader
        ctx.close("x_next", x_next, ref[0], angles=[2])

A test passes when ``run(ctx)`` returns; it fails when a check raises
:class:`~autograder.context.Fail` or a call of the student's function fails.

Every test pays only for right values
-------------------------------------
A function that returns garbage must score 0 on *all* of its tests, and a property
(symmetry, agreement with finite differences, an integral, a distribution) must
never pay for wrong values that happen to have it. Each exercise module therefore
follows four rules:

1. One ``_check_<function>(ctx, *args)`` helper per contract function calls the
   student's function, checks the output form (``ctx.expect``) and compares every
   returned value with ``slamlib`` on the same inputs (``ctx.close`` / ``ctx.equal``).
   Value tests call it; so does every property test, *before* checking its
   property (``ctx.symmetric``, finite differences ...), on its own scenario.
2. End-to-end runs (:mod:`autograder.loops`) plug in a step that calls the same
   helper, so a run fails at the first step whose output differs from ``slamlib``
   on that step's inputs (the message names the step and the call); the comparison
   of the final track with the reference filter's comes after.
3. Random functions are judged on what the contract fixes: the exact indices for
   the single draw of low-variance resampling, and for samplers the moments
   (:func:`~autograder.stats.odometry_moment_problem`) or the distribution (KS)
   of the sampled noise in every test, including the tests of shape and of the
   use of ``rng``, and the independence of a pose's noises
   (:func:`~autograder.stats.odometry_independence_problem`) in a test of its own.
4. Functions returning an index are asked, in every test, at least one case whose
   answer is neither 0 nor the "none" answer (``-1``, ``n_seen``), so that a
   constant cannot pass; thresholds are probed just below and just above the exact
   distance, so the distance itself must be right.

``tests/test_autograder_mutation.py`` proves the rules hold for every function of
every exercise registered in :data:`autograder.exercises.EXERCISES`: submissions
returning zeros, random values or their own inputs (in the form of the right
answer) must score 0 on every test, and mutants of slamlib's own source
(``tests/mutation.py``; ``python -m tests.mutation`` prints the kill rate per
function) must lose points, at least 95 % of the non-equivalent ones and every
survivor explained in ``tests/mutation_table.py``. A new exercise (say
``graph_slam``) is covered as soon as it is registered: write its ``_check_*``
helpers, use them in every test, then run ``python -m tests.mutation --function
NAME`` and kill or explain the survivors.
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass, field
from typing import Callable

__all__ = ["TestCase", "Exercise", "parse_signature", "VISIBILITY", "TEST_BUDGET", "SUBMISSION_BUDGET"]

#: Gradescope visibility of public and hidden tests.
VISIBILITY = {"public": "visible", "hidden": "after_due_date"}


def parse_signature(text):
    """``"(x, u, *, rng)"`` -> :class:`inspect.Signature`."""
    ns = {}
    exec(f"def _f{text}: pass", ns)  # noqa: S102 - our own constant strings
    return inspect.signature(ns["_f"])


@dataclass(frozen=True)
class TestCase:
    """One graded test of one contract function.

    Attributes
    ----------
    function : str
        The contract function it checks; the test's name begins with it.
    title : str
        What it checks (the rest of the name).
    weight : float
        Points.
    run : callable
        ``run(ctx)``; see :class:`~autograder.context.Ctx`.
    visibility : str
        ``"public"`` (self-check and Gradescope "visible") or ``"hidden"``
        (Gradescope "after_due_date"; not in the self-check).
    timeout : float
        Wall-clock limit of each call of the student's function (seconds).
    hint : str
        The message a student sees when the test fails.
    budget : float or None
        Wall time (seconds) of the whole test, all its calls together; ``None``
        takes the exercise's ``test_budget``. A test over its budget scores 0 with
        a message and the other tests still run.
    """

    function: str
    title: str
    weight: float
    run: Callable
    visibility: str = "public"
    timeout: float = 10.0
    hint: str = ""
    budget: float | None = None

    @property
    def name(self):
        return f"{self.function}: {self.title}"


#: Default wall-time budgets (seconds): one test, all its calls; one submission, all its tests.
#: A correct submission needs well under a second per test.
TEST_BUDGET = 30.0
SUBMISSION_BUDGET = 240.0


@dataclass
class Exercise:
    """An exercise: its contract functions (in grading order) and test cases.

    ``seed`` is the base seed of the public self-check (graded submissions draw
    theirs from the deployment's secret and their own content, see
    :mod:`autograder.seeds`); ``test_budget`` and ``submission_budget`` bound the
    wall time of one test and of one whole grading.
    """

    name: str
    title: str
    notebook: str
    functions: dict
    seed: int = 20240
    tests: list = field(default_factory=list)
    test_budget: float = TEST_BUDGET
    submission_budget: float = SUBMISSION_BUDGET

    def test(self, function, title, *, weight, visibility="public", timeout=10.0, hint="", budget=None):
        """Decorator registering ``run(ctx)`` as a test of ``function``."""
        if function not in self.functions:
            raise ValueError(f"{function!r} is not a function of exercise {self.name!r}")
        if visibility not in VISIBILITY:
            raise ValueError(f"visibility must be one of {sorted(VISIBILITY)}")

        def deco(run):
            case = TestCase(function, title, float(weight), run, visibility, float(timeout), hint,
                            None if budget is None else float(budget))
            if any(t.name == case.name for t in self.tests):
                raise ValueError(f"duplicate test name {case.name!r}")
            self.tests.append(case)
            return run

        return deco

    def signature(self, function):
        return parse_signature(self.functions[function])

    def params(self, function):
        """Names of the contract parameters, in order."""
        return list(self.signature(function).parameters)

    def tests_for(self, function):
        return [t for t in self.tests if t.function == function]

    def max_score(self, function=None):
        return sum(t.weight for t in self.tests if function is None or t.function == function)
