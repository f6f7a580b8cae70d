"""The course's autograder: grades the exercise notebooks against slamlib.

Command line: ``python -m autograder {grade,batch,bundle,gradescope,calibrate,list}``
(see :mod:`autograder.__main__`). From Python: :func:`autograder.engine.grade` for one
submission, :func:`autograder.selfcheck.run_public_tests` for the students' self-check
in a notebook. The instructors' chapter of the book describes grading, Gradescope,
test cases and the isolation model.

Layout: ``submission`` (reading notebooks statically), ``sandbox`` and ``_runner``
(the child processes that run student code), ``context`` and ``spec`` (test cases and
checks), ``exercises/`` (one module of test cases per exercise), ``loops`` (end-to-end
filters), ``stats`` and ``calibrate`` (statistical tests), ``engine`` (grading),
``batch``, ``bundle`` and ``results`` (outputs).
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
