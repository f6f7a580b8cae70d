"""Grading a folder of submissions in parallel: one CSV row and one results JSON each.

A submission is a ``.ipynb`` or ``.py`` file directly in the folder, or a
sub-folder holding one (as in a Gradescope or LMS export: the exercise's notebook
by name, else the only notebook, else the only Python file). Submissions are
graded in ``jobs`` worker processes; within a worker the functions of a
submission are graded one after another, each in a worker forked from the
submission's sandbox.

Stopping and resuming: the worker processes die with the batch (a parent-death
signal; SIGTERM and SIGINT stop them explicitly), and every sandbox dies with its
worker, so killing ``batch`` by any means leaves no process behind. Each
submission's results JSON is written atomically as soon as it is graded and
records the submission's hash; a rerun skips every submission whose JSON matches
its current content, unless the grader itself failed on it (``--restart`` grades
everything again). The CSV is rewritten atomically after each submission.
"""

from __future__ import annotations

import csv
import io
import multiprocessing
import os
import re
import signal
import sys
import traceback
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path

from .results import fallback_results, read_results, write_json_atomic, write_text_atomic
from .spec import VISIBILITY
from .wire import clean_text, shorten

__all__ = ["find_submissions", "run_batch", "pick_submission_file"]

_SUFFIXES = (".ipynb", ".py")


def _linked(path, folder):
    """True when ``path`` or a folder between ``folder`` and it is a symbolic link."""
    p = Path(path)
    while True:
        if p.is_symlink():
            return True
        if p == Path(folder) or p.parent == p:
            return False
        p = p.parent


#: why a symbolic link is never graded: it may point at another student's work or at the grader's own files
_LINK_REASON = "a symbolic link (links are not followed: they may point at another student's work or the grader's files)"


#: how far and how wide a submission folder is searched (an upload nested 1100 levels deep stopped the batch)
MAX_DEPTH, MAX_ENTRIES = 16, 10_000


class _TooMuch(Exception):
    """A submission folder deeper or larger than the caps above."""


def _walk(folder):
    """Every entry under ``folder`` (hidden ones and ``__MACOSX`` left out), links not followed, within the caps."""
    out, stack = [], [(folder, 0)]
    while stack:
        d, depth = stack.pop()
        with os.scandir(d) as it:
            for e in it:
                if e.name.startswith((".", "__MACOSX")):
                    continue
                p = Path(e.path)
                out.append(p)
                if len(out) > MAX_ENTRIES:
                    raise _TooMuch(f"the submission folder holds more than {MAX_ENTRIES} files and folders")
                if e.is_dir(follow_symlinks=False):
                    if depth + 1 >= MAX_DEPTH:
                        raise _TooMuch(f"the submission folder is nested more than {MAX_DEPTH} levels deep")
                    stack.append((p, depth + 1))
    return out


def _utf8(name):
    """True when a file name (as the file system gave it) is valid UTF-8 on disk.

    The name's bytes are checked, not the string: under a locale whose file-system encoding is not UTF-8
    (``LC_ALL=C`` with ``PYTHONUTF8=0``), Python hands ``josé.py`` over as ``jos\\udcc3\\udca9.py``.
    """
    try:
        os.fsencode(name).decode("utf-8")
        return True
    except UnicodeError:
        return False


def _printable(name):
    """A file name as text: its bytes read as UTF-8, any that are not written as escapes (``caf\\xe9``).

    The id of a row and the names in its message, whatever the grader's locale (see :func:`_fs_name`).
    """
    return os.fsencode(name).decode("utf-8", "backslashreplace")


def _fs_name(text):
    """The file name whose bytes on disk are ``text`` in UTF-8, as this interpreter's ``os`` functions take it.

    The inverse of :func:`_printable`: under a file-system encoding that is not UTF-8, ``josé.json`` is passed as
    ``jos\\udcc3\\udca9.json`` (the same bytes), where the plain string cannot be encoded and the write fails.
    """
    return os.fsdecode(text.encode("utf-8", "surrogateescape"))


def pick_submission_file(folder, notebook_name=None):
    """The file to grade in a submission folder, or ``(None, reason)``.

    Symbolic links (to files or folders, the folder itself included) are never followed: a submission is
    the files in its folder.
    """
    if Path(folder).is_symlink():
        return None, f"the submission folder {_printable(Path(folder).name)} is {_LINK_REASON}"
    try:
        found = _walk(Path(folder))
    except _TooMuch as exc:
        return None, str(exc)
    except OSError as exc:
        return None, f"the submission folder cannot be read ({exc.strerror or exc})"
    odd = sorted(p for p in found if not _utf8(str(p.relative_to(folder))) and p.suffix.lower() in _SUFFIXES)
    found = [p for p in found if _utf8(str(p.relative_to(folder)))]
    files = sorted(p for p in found if p.suffix.lower() in _SUFFIXES and not _linked(p, folder) and p.is_file())
    links = sorted(p for p in found if p.is_symlink() and (p.suffix.lower() in _SUFFIXES or p.is_dir()))
    if not files and odd:
        return None, f"{_printable(str(odd[0].relative_to(folder)))}: a file name that is not UTF-8 (rename it)"
    if notebook_name:
        named = [p for p in files if p.name == notebook_name]
        if named:
            return named[0], None
    for suffix in _SUFFIXES:
        cand = [p for p in files if p.suffix.lower() == suffix]
        if len(cand) == 1:
            return cand[0], None
        if len(cand) > 1:
            names = ", ".join(_printable(p.name) for p in cand)
            return None, f"several {suffix} files ({names}); submit only the exercise notebook"
    if links:
        return None, (f"{_printable(str(links[0].relative_to(folder)))} is {_LINK_REASON}; no other .ipynb or .py "
                      "file in the submission")
    special = sorted(p for p in found if p.suffix.lower() in _SUFFIXES and not p.is_symlink() and not p.is_file()
                     and not p.is_dir())
    if special:  # a FIFO, a socket, a device named like a submission: never opened
        return None, (f"{_printable(str(special[0].relative_to(folder)))}: not a regular file; no other .ipynb or .py "
                      "file in the submission")
    return None, "no .ipynb or .py file in the submission"


def find_submissions(folder, notebook_name=None):
    """``[(id, path or None, problem or None)]`` for every submission under ``folder``, sorted by id.

    An entry that is a symbolic link is listed with a problem and not graded. Two entries with the same id
    (``ann.py`` and ``ann.ipynb``, or a folder ``ann`` and ``ann.py``) are one entry with a problem: one
    id has one row and one results file.
    """
    out = []
    for entry in sorted(Path(folder).iterdir()):
        if entry.name.startswith("."):
            continue
        if not _utf8(entry.name):
            if entry.is_dir() or entry.suffix.lower() in _SUFFIXES:
                name = _printable(entry.name)
                out.append((name.rsplit(".", 1)[0] if entry.suffix.lower() in _SUFFIXES else name, None,
                            f"{name}: a file name that is not UTF-8 (rename it)"))
            continue
        if entry.is_symlink():
            if entry.is_dir() or entry.suffix.lower() in _SUFFIXES:
                out.append((_printable(entry.stem if entry.suffix.lower() in _SUFFIXES else entry.name), None,
                            f"{_printable(entry.name)} is {_LINK_REASON}"))
            continue
        if entry.is_file() and entry.suffix.lower() in _SUFFIXES:
            out.append((_printable(entry.stem), entry, None))
        elif entry.suffix.lower() in _SUFFIXES and not entry.is_dir():  # a FIFO, a socket, a device: never opened
            out.append((_printable(entry.stem), None, f"{_printable(entry.name)}: not a regular file"))
        elif entry.is_dir():
            try:
                path, why = pick_submission_file(entry, notebook_name)
            except Exception as exc:  # noqa: BLE001 - a student's folder: its own row, never the batch's end
                path, why = None, f"the submission folder cannot be read ({type(exc).__name__}: {exc})"[:300]
            out.append((_printable(entry.name), path, why))
    names = {}
    for sid, path, _ in out:
        names.setdefault(sid, []).append(path)
    listed, unique = set(), []
    for sid, path, why in out:  # one row per id: a clash is one row with the problem, never graded
        if sid in listed:
            continue
        listed.add(sid)
        if len(names[sid]) > 1:
            path, why = None, (f"{len(names[sid])} submissions have the id {sid!r} (a file and a folder, or a notebook "
                               "and a Python file, of the same name): rename all but one")
        unique.append((sid, path, why))
    return unique


def _settings(limits):
    """The limits a batch grades with, as its results record them (``extra_data.batch_settings``)."""
    import dataclasses

    from .sandbox import Limits

    return dataclasses.asdict(limits or Limits())


def _fingerprint(path, problem):
    from .seeds import content_hash

    if path is None:
        return "missing:" + str(problem)
    try:
        return content_hash(path)
    except OSError as exc:
        return f"unreadable:{exc}"


def _worker_init(parent):
    """In each pool worker: die with the batch (SIGKILL when the parent ends), leave SIGINT to the batch."""
    try:
        import ctypes
        import ctypes.util

        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGKILL, 0, 0, 0)  # PR_SET_PDEATHSIG
    except OSError:
        pass
    if os.getppid() != parent:  # the batch ended before the line above
        os._exit(1)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _grade_one(sid, path, problem, exercise, results_path, limits, fingerprint, seed=None):
    from .engine import grade
    from .exercises import get_exercise

    ex = get_exercise(exercise)
    row = {"submission": sid, "file": _printable(str(path)) if path else "", "score": 0.0,
           "max_score": ex.max_score(), "status": "ok", "message": ""}
    for fn in ex.functions:
        row[fn] = 0.0
    extra = {"exercise": exercise, "submission_sha256": fingerprint, "batch_settings": _settings(limits)}
    try:
        if path is None:
            row["status"] = "error"
            row["message"] = problem
            tests = [{"name": t.name, "score": 0.0, "max_score": t.weight, "status": "failed", "output": problem,
                      "visibility": VISIBILITY[t.visibility]} for t in ex.tests]
            write_json_atomic(results_path, {**fallback_results(problem), "tests": tests,
                                             "extra_data": {**extra, "batch_row": row}})
            return row
        result = grade(path, exercise, limits=limits, workers=1, seed=seed)
        row["score"] = result.score
        for fn, (s, _) in result.by_function().items():
            row[fn] = s
        if result.error:
            row["status"] = "error"
            row["message"] = result.error.splitlines()[0]
        data = result.to_gradescope()
        data["extra_data"] = {**data.get("extra_data", {}), **extra, "batch_row": row}
        write_json_atomic(results_path, data)
    except Exception as exc:  # noqa: BLE001 - one bad submission must not stop the batch
        # the grader's failure is no grade: the row has no score (never a zero, nor a score its JSON does not hold)
        row.update({"score": "", **{fn: "" for fn in ex.functions}})
        row["status"] = "grader-error"
        row["message"] = f"{type(exc).__name__}: {exc}"
        write_json_atomic(results_path, {**fallback_results("The autograder failed internally:\n"
                                                            + traceback.format_exc()),
                                         "extra_data": {**extra, "batch_row": row}})
    return row


def _write_csv(out_csv, rows, ex):
    rows = sorted(rows, key=lambda r: r["submission"])
    fields = ["submission", "file", "score", "max_score", "percent", *ex.functions, "status", "message"]
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=fields, extrasaction="ignore")
    writer.writeheader()
    for r in rows:
        if r["score"] == "":  # the grader failed on it: no score, no percentage
            r["percent"] = ""
        else:
            r["percent"] = round(100.0 * float(r["score"]) / float(r["max_score"]), 2) if float(r["max_score"]) else 0.0
        writer.writerow({k: _cell(v) for k, v in r.items()})
    write_text_atomic(out_csv, buf.getvalue())
    return rows


def results_file(results_dir, sid):
    """``results_dir / "<id>.json"``, with an id too long for a file name (255 bytes, and the atomic write's
    temporary name around it) cut to its first 100 characters and a hash of the whole, so that it still fits."""
    name = sid
    # an id that merely looks like a cut one is cut as well, so that two ids never share a file
    if len(sid.encode("utf-8", "surrogateescape")) > 200 or _CUT_NAME.search(sid):
        import hashlib

        name = sid[:100]
        while len(name.encode("utf-8", "surrogateescape")) > 180:
            name = name[:-1]
        name = f"{name}-{hashlib.sha256(sid.encode('utf-8', 'surrogateescape')).hexdigest()[:16]}"
    return Path(results_dir) / _fs_name(f"{name}.json")


_CUT_NAME = re.compile(r"-[0-9a-f]{16}$")


def _cell(value):
    """A CSV cell that a spreadsheet shows as text: a string a student chose (a file name, a message quoting it) that
    starts like a formula (``=``, ``+``, ``-``, ``@``, a tab or carriage return) gets a leading apostrophe; its
    control characters are written as escapes (as in the printed report) and it is cut at 1000 characters."""
    if not isinstance(value, str):
        return value
    value = shorten(clean_text(value), 1000)
    if value[:1] in ("=", "+", "-", "@", "\t", "\r"):
        return "'" + value
    return value


def _remove_stale_temporaries(*folders):
    for folder in folders:
        for p in Path(folder).glob(".*.tmp"):
            try:
                p.unlink()
            except OSError:
                pass


class _Stop(Exception):
    """SIGTERM or SIGINT arrived."""


def run_batch(folder, exercise, *, out_csv="grades.csv", jobs=2, results_dir=None, limits=None, progress=True,
              restart=False, seed=None):
    """Grade every submission under ``folder``; write the CSV and one results JSON per submission.

    Parameters
    ----------
    restart : bool
        Grade every submission again. By default a submission whose results JSON
        records the same content hash (from an interrupted or earlier run) is
        not graded again.
    seed : int, optional
        One base seed for every submission (default: each derived from the
        deployment's secret and its own content).

    Returns
    -------
    list of dict
        The CSV rows, sorted by submission id.
    """
    from .exercises import get_exercise
    from .sandbox import require_sandbox
    from .seeds import derive_seed, load_secret

    from .engine import check_integer

    check_integer(jobs, "jobs", 1, optional=False)
    check_integer(seed, "seed", 0)
    ex = get_exercise(exercise)
    require_sandbox(limits)  # a broken grader stops here, before any submission is charged
    out_csv = Path(out_csv)
    out_csv.parent.mkdir(parents=True, exist_ok=True)
    results_dir = Path(results_dir) if results_dir else out_csv.with_name(out_csv.stem + "_results")
    results_dir.mkdir(parents=True, exist_ok=True)
    _remove_stale_temporaries(results_dir, out_csv.parent)
    secret = load_secret() if seed is None else None  # created here once, not by two workers at the same time
    settings = _settings(limits)
    subs = find_submissions(folder, ex.notebook)
    rows, todo = [], []
    for sid, path, why in subs:
        fp = _fingerprint(path, why)
        old = None if restart else read_results(results_file(results_dir, sid))
        extra = (old or {}).get("extra_data") or {}
        # a result is kept only when this run would grade the same way: same file, exercise, seed (a new secret
        # changes every derived seed) and limits (--timeout, the budgets)
        same_seed = extra.get("seed") == (seed if seed is not None else derive_seed(secret, exercise, fp))
        if (old and extra.get("submission_sha256") == fp and extra.get("exercise") == exercise
                and isinstance(extra.get("batch_row"), dict) and extra["batch_row"].get("submission") == sid
                and (same_seed or path is None) and extra.get("batch_settings") == settings
                and extra["batch_row"].get("status") != "grader-error"):  # the grader's failure is graded again
            rows.append(extra["batch_row"])
        else:
            todo.append((sid, path, why, fp))
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(subs), initial=len(rows), desc=f"grading {exercise}", unit="submission")
    ctx = multiprocessing.get_context("spawn")
    old_handlers = {}

    def stop(signum, frame):
        raise _Stop(signum)

    if todo and threading_main():
        for sig in (signal.SIGTERM, signal.SIGINT):
            old_handlers[sig] = signal.signal(sig, stop)
    pool = None
    # the pool's workers are new interpreters (`python -c`), which put the working directory first on sys.path before
    # they import anything: started in a folder of students' files, they imported a student's threading.py
    safe_path = os.environ.get("PYTHONSAFEPATH")
    os.environ["PYTHONSAFEPATH"] = "1"
    try:
        if todo:
            pool = ProcessPoolExecutor(max_workers=max(1, int(jobs)), mp_context=ctx, initializer=_worker_init,
                                       initargs=(os.getpid(),))
            futures = {pool.submit(_grade_one, sid, path, why, exercise, results_file(results_dir, sid), limits, fp,
                                   seed): sid for sid, path, why, fp in todo}
            pending = set(futures)
            while pending:
                done, pending = wait(pending, timeout=1.0, return_when=FIRST_COMPLETED)
                for fut in done:
                    sid = futures[fut]
                    try:
                        rows.append(fut.result())
                    except Exception as exc:  # noqa: BLE001 - a worker that died
                        row = {"submission": sid, "file": "", "score": "", "max_score": ex.max_score(),
                               "status": "grader-error", "message": f"{type(exc).__name__}: {exc}"}
                        row.update({fn: "" for fn in ex.functions})  # no grade: no score
                        rows.append(row)
                        try:  # the row above is what counts: a file that cannot be written does not stop the batch
                            write_json_atomic(results_file(results_dir, sid),
                                              fallback_results(f"grading failed: {exc}"))
                        except OSError:
                            pass
                    if bar is not None:
                        bar.update(1)
                if done:
                    _write_csv(out_csv, rows, ex)
        rows = _write_csv(out_csv, rows, ex)
    except (_Stop, KeyboardInterrupt) as exc:
        _kill_pool(pool)
        pool = None
        if bar is not None:
            bar.close()
            bar = None
        signum = exc.args[0] if isinstance(exc, _Stop) else signal.SIGINT
        print(f"\nbatch stopped ({signal.Signals(signum).name}): {len(rows)} of {len(subs)} submissions graded; "
              "run the same command again to grade the rest", file=sys.stderr)
        raise SystemExit(128 + int(signum)) from None
    finally:
        if pool is not None:
            pool.shutdown(wait=True)
        if safe_path is None:
            os.environ.pop("PYTHONSAFEPATH", None)
        else:
            os.environ["PYTHONSAFEPATH"] = safe_path
        for sig, h in old_handlers.items():
            signal.signal(sig, h)
        if bar is not None:
            bar.close()
    return rows


def threading_main():
    import threading

    return threading.current_thread() is threading.main_thread()


def _kill_pool(pool):
    """SIGKILL every worker of ``pool`` (their sandboxes die with them)."""
    if pool is None:
        return
    procs = list(getattr(pool, "_processes", {}).values())
    for p in procs:
        try:
            p.kill()
        except (OSError, AttributeError):
            pass
    for p in procs:
        try:
            p.join(timeout=5)
        except (OSError, AssertionError):
            pass
    try:
        pool.shutdown(wait=False, cancel_futures=True)
    except Exception:  # noqa: BLE001 - a broken pool
        pass
