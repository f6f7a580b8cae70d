"""The course's autograder: grades the exercise notebooks against slamlib.

Command line: ``python -m autograder {grade,batch,bundle,gradescope,calibrate,list}``
(see :mod:`autograder.__main__`). From Python: :func:`autograder.engine.grade` for one
submission, :func:`autograder.selfcheck.run_public_tests` for the students' self-check
in a notebook. The instructors' chapter of the book describes grading, Gradescope,
test cases and the isolation model.

Layout: ``submission`` (reading notebooks statically), ``sandbox`` and ``_runner``
(the isolated process that loads a submission once and forks a worker per
function), ``wire`` (the format of what passes between them), ``seeds`` (scenario seeds from a deployment secret and the submission's
content), ``context`` and ``spec`` (test cases, checks, time budgets),
``exercises/`` (one module of test cases per exercise), ``loops`` (end-to-end
filters), ``stats`` and ``calibrate`` (statistical tests), ``engine`` (grading),
``results`` (result types, reports, results.json), ``batch`` and ``bundle``.
"""

__all__ = ["grade", "run_public_tests"]


def __getattr__(name):
    # imported lazily: the child runner and `python -m autograder list` stay light
    if name == "grade":
        from .engine import grade

        return grade
    if name == "run_public_tests":
        from .selfcheck import run_public_tests

        return run_public_tests
    raise AttributeError(f"module 'autograder' has no attribute {name!r}")
