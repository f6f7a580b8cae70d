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

import os as _os
import sys as _sys

__all__ = ["grade", "run_public_tests"]


def fill_standard_fds():
    """Open ``/dev/null`` on each of the descriptors 0-2 that is closed (a grader started with ``>&-`` or ``<&-``,
    as daemons are): else the sandbox's control socket or pipes would be given those numbers, and the child's
    standard streams would be set over them."""
    while True:
        try:
            fd = _os.open(_os.devnull, _os.O_RDWR)
        except OSError:
            return
        if fd > 2:
            _os.close(fd)
            return


def _drop_working_directory():
    """Take the working directory off ``sys.path`` unless the grader itself is there.

    ``python -m autograder`` puts the working directory first on ``sys.path``, ahead of the standard
    library and the installed packages. Started in a folder of students' files, the grader would then
    import a student's ``numpy.py`` or ``json.py`` in its own process, outside every sandbox. The package is
    loaded at this point (this module runs first), so the entry is only needed when it is the folder that
    holds the package (a checkout used without installing it).
    """
    home = _os.path.dirname(_os.path.dirname(_os.path.abspath(__file__)))
    try:
        cwd = _os.getcwd()
    except OSError:  # a working directory that was removed
        cwd = None
    if cwd is None:  # nothing can be imported from a removed folder; a relative entry cannot be made absolute
        _sys.path[:] = [entry for entry in _sys.path if entry]
        return
    keep = []
    for entry in _sys.path:
        where = _os.path.abspath(entry) if entry else cwd
        if where == cwd and _os.path.realpath(where) != _os.path.realpath(home):
            continue
        keep.append(entry)
    _sys.path[:] = keep


_drop_working_directory()


def __getattr__(name):
    # imported lazily: the child runner and `python -m autograder list` stay light
    if name == "grade":
        from .engine import grade

        return grade
    if name == "run_public_tests":
        from .selfcheck import run_public_tests

        return run_public_tests
    raise AttributeError(f"module 'autograder' has no attribute {name!r}")
