"""Speed of the autograder: one submission, and a batch of 50 with two jobs.

Run ``python benchmarks/bench_autograder.py [--exercise NAME] [--n 50] [--jobs 2]``.
Figures, all measured in this process and its children:

* grading one correct submission of every exercise (one sandbox per submission,
  loaded once, a worker forked per function; functions graded in parallel on the
  available cores), against a baseline measured here: the same tests run
  in-process on the same functions, without any child process (the student's
  self-check path); target: at most 3 s per exercise in one process;
* the same from a fresh ``python -m autograder grade`` process (imports included);
* a batch of ``n`` generated submissions of one exercise graded with
  ``run_batch(..., jobs=2)`` (a third correct notebooks, a third with one bug in
  one function, a third unimplemented stubs); target: 50 submissions in at most
  60 s with two jobs.

Seeds come from a throw-away secret in a temporary folder.

The generated submissions come from the independent solutions in
``tests/autograder_fixtures/solutions`` and the exercise notebooks.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import nbformat

ROOT = Path(__file__).resolve().parents[1]
SOLUTIONS = ROOT / "tests" / "autograder_fixtures" / "solutions"
sys.path.insert(0, str(ROOT))
from autograder.exercises import EXERCISES, get_exercise  # noqa: E402

#: every registered exercise and its student notebook (the registry's, so a new exercise is timed too)
NOTEBOOKS = {name: get_exercise(name).notebook for name in EXERCISES}
# one textual bug per exercise, in one function (as in tests/test_autograder_buggy.py)
BUGS = {
    "motion_sensor_models": ("_normal(z - z_star, sigma_hit**2) / eta", "_normal(z - z_star, sigma_hit**2)"),
    "ekf_localization": ("K = Sigma_bar @ H.T @ np.linalg.inv(S)", "K = Sigma_bar @ H.T @ np.linalg.inv(Q)"),
    "particle_filter": ("U = r + m / M", "U = r + (m + 1) / M"),
    "ekf_slam": ("K = Sigma_bar @ H.T @ np.linalg.inv(S)", "K = Sigma_bar @ H.T @ np.linalg.inv(Q)"),
    "fastslam": ("Hi = np.linalg.inv(H)", "Hi = H"),
    "graph_slam": ("H[si, sj] += A.T @ W @ B", "H[si, sj] = A.T @ W @ B"),
    "bundle_adjustment": ("s -= W @ b[sl_]", "s += W @ b[sl_]"),
}
if set(BUGS) != set(NOTEBOOKS):
    raise RuntimeError(f"BUGS needs one bug for every exercise: missing {sorted(set(NOTEBOOKS) - set(BUGS))}")


def _notebook_with(code, exercise):
    nb = nbformat.read(ROOT / "exercises" / NOTEBOOKS[exercise], as_version=4)
    cells = [c for c in nb.cells if not (c.cell_type == "code" and "raise NotImplementedError" in c.source)]
    cells.insert(3, nbformat.v4.new_code_cell(code))
    nb.cells = cells
    return nbformat.writes(nb)


def make_submissions(folder, exercise, n):
    """Write ``n`` submissions of ``exercise`` into ``folder``: correct, buggy, stub (in turn)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    good = (SOLUTIONS / f"{exercise}.py").read_text()
    old, new = BUGS[exercise]
    buggy = good.replace(old, new)
    stub = (ROOT / "exercises" / NOTEBOOKS[exercise]).read_text()
    for i in range(n):
        kind = ("good", "buggy", "stub")[i % 3]
        text = {"good": _notebook_with(good, exercise), "buggy": _notebook_with(buggy, exercise), "stub": stub}[kind]
        (folder / f"student{i:03d}_{kind}.ipynb").write_text(text)
    return folder


def cold(exercise):
    """Wall seconds of ``python -m autograder grade`` in a fresh process (imports and reference runs included)."""
    import subprocess

    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "autograder", "grade", str(SOLUTIONS / f"{exercise}.py"), "-e", exercise],
                   check=True, capture_output=True, cwd=ROOT)
    return time.perf_counter() - t0


def single(exercise):
    """(wall seconds with sandboxed children, in-process baseline seconds, score)."""
    from autograder.engine import grade, run_tests
    from autograder.exercises import get_exercise
    from autograder.selfcheck import InProcessCaller

    ex = get_exercise(exercise)
    grade(SOLUTIONS / f"{exercise}.py", exercise)  # warm the per-process caches (reference runs)
    t0 = time.perf_counter()
    result = grade(SOLUTIONS / f"{exercise}.py", exercise)
    wall = time.perf_counter() - t0
    ns = {}
    exec(compile((SOLUTIONS / f"{exercise}.py").read_text(), "solution", "exec"), ns)
    t0 = time.perf_counter()
    for fn in ex.functions:
        run_tests(ex, fn, InProcessCaller(ns))
    base = time.perf_counter() - t0
    return wall, base, result.score


def batch(exercise, n, jobs):
    from autograder.batch import run_batch

    tmp = Path(tempfile.mkdtemp(prefix="bench-ag-"))
    try:
        subs = make_submissions(tmp / "subs", exercise, n)
        t0 = time.perf_counter()
        rows = run_batch(subs, exercise, out_csv=tmp / "grades.csv", jobs=jobs, progress=False, restart=True)
        wall = time.perf_counter() - t0
        return wall, rows
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def main():
    secret_dir = tempfile.mkdtemp(prefix="bench-ag-secret-")
    os.environ.setdefault("AUTOGRADER_SECRET_FILE", os.path.join(secret_dir, "secret"))
    try:
        _main()
    finally:
        shutil.rmtree(secret_dir, ignore_errors=True)


def _main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--exercise", default="ekf_localization", choices=list(NOTEBOOKS),
                    help="the exercise of the batch (default: %(default)s)")
    ap.add_argument("--n", type=int, default=50)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--skip-single", action="store_true")
    args = ap.parse_args()
    for name, low in {'n': 1, 'jobs': 1}.items():  # counts at least 1, seeds at least 0
        value = getattr(args, name)
        if value is not None and min(value if isinstance(value, list) else [value]) < low:
            ap.error(f"--{name.replace('_', '-')} must be at least {low}, got {value}")
    print(f"cores: {os.cpu_count()}, load average: {os.getloadavg()[0]:.1f}")
    if not args.skip_single:
        print("\none correct submission per exercise (target <= 3 s):")
        for ex in NOTEBOOKS:
            wall, base, score = single(ex)
            print(f"  {ex:22s} {wall:6.2f} s   in-process baseline {base:5.2f} s   ratio {wall / base:5.1f}x   "
                  f"score {score:g}   command line, fresh process: {cold(ex):5.2f} s")
    wall, rows = batch(args.exercise, args.n, args.jobs)
    scores = sorted({r["score"] for r in rows})
    print(f"\nbatch of {args.n} {args.exercise} submissions, --jobs {args.jobs} (target <= 60 s): {wall:.1f} s "
          f"({wall / args.n:.2f} s per submission); scores seen: {scores}")


if __name__ == "__main__":
    main()
