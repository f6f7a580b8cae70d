"""Command line of the autograder: ``python -m autograder {grade,batch,bundle,gradescope,calibrate,list}``.

``grade``
    Grade one submission, print a per-test report, write Gradescope's
    ``results.json``. Exit status 0 whenever grading completed, whatever the score.
``batch``
    Grade a folder of submissions in parallel: one CSV row each (with per-function
    columns) and one results JSON each.
``bundle``
    Build a Gradescope autograder zip for one exercise.
``gradescope``
    What ``run_autograder`` in the bundle runs: grade ``ROOT/submission/*`` into
    ``ROOT/results/results.json``.
``calibrate``
    Run the statistical checks on the reference implementation over many seeds.
``list``
    List the exercises, their functions and test cases.
``selfcheck``
    Check the grader's own sandbox on this machine: run a known-correct function
    that imports NumPy and SciPy in it, and say which isolation held.

``grade``, ``batch`` and ``gradescope`` run the same self-check first; when it
fails they stop with exit status 3 and a message for the course staff, before
any submission is graded and without writing any results (nobody is charged
for a broken grader).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import traceback

# One BLAS thread in the grader's own process, set before NumPy loads: its linear algebra is small, a batch runs
# several graders at once, and OpenBLAS's start-up spins forever when its per-thread buffers do not fit an
# address-space limit (`ulimit -v 200000`: `import scipy.linalg` never returned). The sandbox sets the same.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
# Standard descriptors closed when the command started (a cron line's ``>&-``): /dev/null on them before any file
# is opened, so that no file, pipe or socket of the grader's gets their numbers.
from . import fill_standard_fds  # noqa: E402

fill_standard_fds()

__all__ = ["main"]


def _seconds(text):
    """An option's number of seconds: finite and positive (argparse reports anything else as a usage error)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive, finite number of seconds, got {text!r}")
    return value


def _integer(minimum):
    """An argparse type: an integer of at least ``minimum`` (counts: 1; seeds: 0, NumPy's are non-negative)."""

    def parse(text):
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or value < minimum:
            raise argparse.ArgumentTypeError(f"expected an integer of at least {minimum}, got {text!r}")
        return value

    return parse


_count, _seed = _integer(1), _integer(0)


def _limits(args):
    from .sandbox import Limits

    kw = {}
    for option, name in (("timeout", "call_timeout"), ("import_timeout", "import_timeout"),
                         ("statement_timeout", "statement_timeout"), ("test_budget", "test_budget"),
                         ("submission_budget", "submission_budget")):
        if getattr(args, option, None) is not None:
            kw[name] = float(getattr(args, option))
    return Limits(**kw)


def _secret(args):
    path = getattr(args, "secret_file", None)
    if path:
        import os

        from .seeds import SECRET_ENV

        os.environ[SECRET_ENV] = str(path)  # batch workers read it too
    return path


SANDBOX_BROKEN = 3


def _sandbox_ok(limits):
    """The grader's self-check; False (and a message on stderr) when grading must not start."""
    from .sandbox import SandboxBroken, require_sandbox

    try:
        require_sandbox(limits)
    except SandboxBroken as exc:
        from .results import safe_print

        safe_print(str(exc), file=sys.stderr)
        return False
    return True


def _cmd_grade(args):
    from .engine import grade
    from .results import fallback_results, safe_print

    if args.results:  # before the grading: a folder that cannot hold the results costs no grading
        folder = os.path.dirname(os.path.abspath(args.results))
        try:
            os.makedirs(folder, exist_ok=True)
            usable = os.access(folder, os.W_OK | os.X_OK)
        except OSError:
            usable = False
        if not usable:
            safe_print(f"python -m autograder grade: error: argument --results: cannot write to {args.results} "
                       f"(the folder {folder} cannot be made or written)", file=sys.stderr)
            return 2
    if not _sandbox_ok(_limits(args)):
        return SANDBOX_BROKEN
    try:
        result = grade(args.submission, args.exercise, limits=_limits(args), workers=args.workers, seed=args.seed,
                       secret=_secret(args))
    except Exception:  # noqa: BLE001 - a grader bug still leaves a valid results.json
        msg = "The autograder failed internally while grading this submission:\n" + traceback.format_exc(limit=5)
        if args.results:
            _write_results(args.results, fallback_results(msg))
        safe_print(msg, file=sys.stderr)
        return 1
    written = _write_results(args.results, result.to_gradescope()) if args.results else None
    safe_print(result.text_report(verbose=args.verbose))  # no escape sequence reaches the terminal
    if written:
        safe_print(f"\nresults written to {args.results}")
    elif args.results:  # the grade is printed above; the failure is the machine's (a full disk), not a score
        return 1
    return 0 if result.exercise else 2


def _write_results(path, data):
    """Write ``data`` to ``path``; on failure (a full disk, a folder gone) say so on stderr and return False."""
    from .results import safe_print, write_json_atomic

    try:
        write_json_atomic(path, data)
        return True
    except OSError as exc:
        safe_print(f"python -m autograder: could not write the results to {path} ({exc.strerror or exc}); nothing "
                   "was written there", file=sys.stderr)
        return False


def _cmd_batch(args):
    from .batch import run_batch

    _secret(args)
    if not _sandbox_ok(_limits(args)):
        return SANDBOX_BROKEN
    try:
        run_batch(args.folder, args.exercise, out_csv=args.out, jobs=args.jobs, results_dir=args.results_dir,
                  limits=_limits(args), progress=not args.quiet, restart=args.restart, seed=args.seed)
    except OSError as exc:  # the grades CSV or the results folder cannot be written (permissions, a full disk)
        from .results import safe_print

        safe_print(f"python -m autograder batch: {exc.strerror or exc}: {exc.filename or args.out} (the grades "
                   "written so far are kept: run the same command again to finish)", file=sys.stderr)
        return 1
    return 0


def _cmd_bundle(args):
    from .bundle import build_bundle

    path = build_bundle(args.exercise, args.output)
    print(f"wrote {path}")
    return 0


def _cmd_gradescope(args):
    from .bundle import run_gradescope

    if not _sandbox_ok(_limits(args)):
        return SANDBOX_BROKEN
    return run_gradescope(args.root, args.exercise, limits=_limits(args), secret=_secret(args))


def _cmd_calibrate(args):
    from .calibrate import main as cal_main

    return cal_main(n_seeds=args.seeds, out=args.out)


def _cmd_selfcheck(args):
    from .sandbox import check_sandbox, describe_isolation

    report = check_sandbox(_limits(args))
    print(f"sandbox self-check: {'ok' if report['ok'] else 'FAILED'} ({report['seconds']:.2f} s)")
    if not report["ok"]:
        print(f"  what failed: {report['problem']}")
    for line in describe_isolation(report["isolation"]):
        print(f"  - {line}")
    return 0 if report["ok"] else SANDBOX_BROKEN


def _cmd_list(args):
    from .exercises import all_exercises

    for ex in all_exercises():
        print(f"{ex.name}  ({ex.notebook}, {ex.max_score():g} points)")
        for fn in ex.functions:
            print(f"  {fn}{ex.functions[fn]}  {ex.max_score(fn):g} points")
            for t in ex.tests_for(fn):
                print(f"    [{t.visibility:6}] {t.weight:>4g}  {t.name}")
    return 0


def _budget_options(p):
    p.add_argument("--timeout", type=_seconds, help="cap on every call's wall-clock timeout (seconds)")
    p.add_argument("--import-timeout", type=_seconds, help="time allowed to load a submission (seconds, default 30)")
    p.add_argument("--statement-timeout", type=_seconds,
                   help="time allowed to one top-level statement while loading; longer ones are skipped (default 10)")
    p.add_argument("--test-budget", type=_seconds, help="wall time of one test, all its calls (default: the exercise's)")
    p.add_argument("--submission-budget", type=_seconds,
                   help="wall time of one whole grading (default: the exercise's)")
    p.add_argument("--secret-file", help="the deployment's grading secret (default: $AUTOGRADER_SECRET_FILE, else "
                                         "~/.config/slam-autograder/secret, created on first use)")


def build_parser():
    ap = argparse.ArgumentParser(prog="python -m autograder", description="Autograder of the course exercises.")
    sub = ap.add_subparsers(dest="cmd", required=True)

    g = sub.add_parser("grade", help="grade one submission")
    g.add_argument("submission", help="the student's .ipynb or .py")
    g.add_argument("--exercise", "-e", help="exercise name (default: from the notebook's metadata)")
    g.add_argument("--results", "-r", help="write Gradescope's results.json here")
    g.add_argument("--workers", type=_count, default=None, help="functions graded in parallel (default: CPU count)")
    g.add_argument("--seed", type=_seed, help="base seed of the scenarios (default: from the secret and the submission; "
                                            "the one used is in results.json, extra_data.seed)")
    _budget_options(g)
    g.add_argument("--verbose", "-v", action="store_true", help="show the output of passed tests too")
    g.set_defaults(func=_cmd_grade)

    b = sub.add_parser("batch", help="grade a folder of submissions")
    b.add_argument("folder")
    b.add_argument("--exercise", "-e", required=True)
    b.add_argument("--out", "-o", default="grades.csv", help="CSV file (default grades.csv)")
    b.add_argument("--results-dir", help="folder of per-submission results JSON (default: <out stem>_results/)")
    b.add_argument("--jobs", "-j", type=_count, default=2, help="submissions graded in parallel")
    b.add_argument("--restart", action="store_true",
                   help="grade every submission again (default: keep results whose submission did not change)")
    b.add_argument("--seed", type=_seed, help="one base seed for every submission (default: derived per submission)")
    _budget_options(b)
    b.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    b.set_defaults(func=_cmd_batch)

    z = sub.add_parser("bundle", help="build a Gradescope autograder zip")
    z.add_argument("--exercise", "-e", required=True)
    z.add_argument("--output", "-o", default="autograder.zip")
    z.set_defaults(func=_cmd_bundle)

    s = sub.add_parser("gradescope", help="grade ROOT/submission into ROOT/results/results.json")
    s.add_argument("--root", default="/autograder")
    s.add_argument("--exercise", "-e", required=True)
    _budget_options(s)
    s.set_defaults(func=_cmd_gradescope)

    c = sub.add_parser("calibrate", help="false-failure calibration of the statistical checks")
    c.add_argument("--seeds", type=_count, default=2000)
    c.add_argument("--out", help="write the p-values (CSV)")
    c.set_defaults(func=_cmd_calibrate)

    sc = sub.add_parser("selfcheck", help="check the grader's sandbox on this machine (NumPy, SciPy, isolation)")
    sc.set_defaults(func=_cmd_selfcheck)

    ls = sub.add_parser("list", help="list exercises and tests")
    ls.set_defaults(func=_cmd_list)
    return ap


def main(argv=None):
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
