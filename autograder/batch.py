"""Grading a folder of submissions in parallel: one CSV row and one results JSON each.

A submission is a ``.ipynb`` or ``.py`` file directly in the folder, or a
sub-folder holding one (as in a Gradescope or LMS export: the exercise's notebook
by name, else the only notebook, else the only Python file). Submissions are
graded in ``jobs`` worker processes; within a worker the functions of a
submission are graded one after another, each still in its own child process.
"""

from __future__ import annotations

import csv
import io
import multiprocessing
import os
import traceback
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

from .results import fallback_results, write_json_atomic
from .spec import VISIBILITY

__all__ = ["find_submissions", "run_batch", "pick_submission_file"]

_SUFFIXES = (".ipynb", ".py")


def pick_submission_file(folder, notebook_name=None):
    """The file to grade in a submission folder, or ``(None, reason)``."""
    files = sorted(p for p in Path(folder).rglob("*")
                   if p.is_file() and p.suffix.lower() in _SUFFIXES
                   and not any(part.startswith((".", "__MACOSX")) for part in p.relative_to(folder).parts))
    if notebook_name:
        named = [p for p in files if p.name == notebook_name]
        if named:
            return named[0], None
    for suffix in _SUFFIXES:
        cand = [p for p in files if p.suffix.lower() == suffix]
        if len(cand) == 1:
            return cand[0], None
        if len(cand) > 1:
            names = ", ".join(p.name for p in cand)
            return None, f"several {suffix} files ({names}); submit only the exercise notebook"
    return None, "no .ipynb or .py file in the submission"


def find_submissions(folder, notebook_name=None):
    """``[(id, path or None, problem or None)]`` for every submission under ``folder``, sorted by id."""
    out = []
    for entry in sorted(Path(folder).iterdir()):
        if entry.name.startswith("."):
            continue
        if entry.is_file() and entry.suffix.lower() in _SUFFIXES:
            out.append((entry.stem, entry, None))
        elif entry.is_dir():
            path, why = pick_submission_file(entry, notebook_name)
            out.append((entry.name, path, why))
    return out


def _grade_one(sid, path, problem, exercise, results_path, limits):
    from .engine import grade
    from .exercises import get_exercise

    ex = get_exercise(exercise)
    row = {"submission": sid, "file": str(path) if path else "", "score": 0.0, "max_score": ex.max_score(),
           "status": "ok", "message": ""}
    for fn in ex.functions:
        row[fn] = 0.0
    try:
        if path is None:
            row["status"] = "error"
            row["message"] = problem
            tests = [{"name": t.name, "score": 0.0, "max_score": t.weight, "status": "failed", "output": problem,
                      "visibility": VISIBILITY[t.visibility]} for t in ex.tests]
            write_json_atomic(results_path, {**fallback_results(problem), "tests": tests})
            return row
        result = grade(path, exercise, limits=limits, workers=1)
        write_json_atomic(results_path, result.to_gradescope())
        row["score"] = result.score
        for fn, (s, _) in result.by_function().items():
            row[fn] = s
        if result.error:
            row["status"] = "error"
            row["message"] = result.error.splitlines()[0]
    except Exception as exc:  # noqa: BLE001 - one bad submission must not stop the batch
        row["status"] = "grader-error"
        row["message"] = f"{type(exc).__name__}: {exc}"
        write_json_atomic(results_path, fallback_results("The autograder failed internally:\n" + traceback.format_exc()))
    return row


def run_batch(folder, exercise, *, out_csv="grades.csv", jobs=2, results_dir=None, limits=None, progress=True):
    """Grade every submission under ``folder``; write the CSV and one results JSON per submission.

    Returns
    -------
    list of dict
        The CSV rows, sorted by submission id.
    """
    from .exercises import get_exercise

    ex = get_exercise(exercise)
    out_csv = Path(out_csv)
    results_dir = Path(results_dir) if results_dir else out_csv.with_name(out_csv.stem + "_results")
    results_dir.mkdir(parents=True, exist_ok=True)
    subs = find_submissions(folder, ex.notebook)
    rows = []
    ctx = multiprocessing.get_context("spawn")
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(subs), desc=f"grading {exercise}", unit="submission")
    with ProcessPoolExecutor(max_workers=max(1, int(jobs)), mp_context=ctx) as pool:
        futures = {pool.submit(_grade_one, sid, path, why, exercise, results_dir / f"{sid}.json", limits): sid
                   for sid, path, why in subs}
        for fut in as_completed(futures):
            sid = futures[fut]
            try:
                rows.append(fut.result())
            except Exception as exc:  # noqa: BLE001 - a worker that died
                row = {"submission": sid, "file": "", "score": 0.0, "max_score": ex.max_score(),
                       "status": "grader-error", "message": f"{type(exc).__name__}: {exc}"}
                row.update({fn: 0.0 for fn in ex.functions})
                rows.append(row)
                write_json_atomic(results_dir / f"{sid}.json", fallback_results(f"grading failed: {exc}"))
            if bar is not None:
                bar.update(1)
    if bar is not None:
        bar.close()
    rows.sort(key=lambda r: r["submission"])
    fields = ["submission", "file", "score", "max_score", "percent", *ex.functions, "status", "message"]
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=fields, extrasaction="ignore")
    writer.writeheader()
    for r in rows:
        r["percent"] = round(100.0 * r["score"] / r["max_score"], 2) if r["max_score"] else 0.0
        writer.writerow(r)
    tmp = out_csv.with_name(f".{out_csv.name}.tmp")
    tmp.write_text(buf.getvalue(), encoding="utf-8")
    os.replace(tmp, out_csv)
    return rows
