"""Attacks and awkward inputs that used to earn unearned points or lose earned ones.

One test (or more) per way a submission could beat or break the grader: switching
off the audit hook from inside, reading the reference through a directory
descriptor, running a classmate's file in a batch, harvesting scenarios across
gradings, writing outside the scratch space, unbounded time, orphaned batch
workers, valid Python that was not read, a wrong signature, a hanging notebook
cell. Each is written as a submission and graded for real; each fails on a grader
without the sandbox root, the derived seeds, the budgets, the zygote and the
batch clean-up.

The protections that need namespaces (a minimal root) are skipped with a reason
where the machine does not allow them.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import nbformat
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent / "autograder_fixtures"))

from agtest import gradescope_json_ok, replace_function, solution_text  # noqa: E402

import autograder  # noqa: E402
import slamlib  # noqa: E402
from autograder.engine import grade  # noqa: E402
from autograder.sandbox import Limits, isolation_report  # noqa: E402

TARGET = "normalize_log_weights"
OTHER = "effective_sample_size"
SLAMLIB_DIR = str(Path(slamlib.__file__).resolve().parent)
PROJECT_DIR = str(Path(slamlib.__file__).resolve().parents[1])
AG_ROOT = Path(autograder.__file__).resolve().parents[1]  # the checkout whose grader is under test


@pytest.fixture(autouse=True)
def _secret(tmp_path_factory, monkeypatch):
    """Grading secrets of the test run live in a temporary folder, not in the user's config."""
    monkeypatch.setenv("AUTOGRADER_SECRET_FILE", str(tmp_path_factory.getbasetemp() / "grading_secret"))


def limits(**kw):
    """Short limits for the tests (fields a grader does not know are left out)."""
    base = {"call_timeout": 2.5, "import_timeout": 20.0}
    base.update(kw)
    names = {f.name for f in dataclasses.fields(Limits)}
    return Limits(**{k: v for k, v in base.items() if k in names})


def _grade_variant(tmp_path, body=None, *, top="", name="sub.py", function=TARGET, lim=None, **kw):
    text = solution_text("particle_filter")
    if body is not None:
        text = replace_function(text, function, body)
    path = tmp_path / name
    path.write_text("import os\nimport sys\nimport numpy as np\n" + top + "\n" + text)
    result = grade(path, "particle_filter", limits=lim or limits(), functions=[TARGET, OTHER], **kw)
    gradescope_json_ok(result.to_gradescope())
    outputs = "\n".join(t.output for t in result.tests if t.function == function)
    return result.by_function(), outputs, result


def _needs_sandbox_root():
    iso = isolation_report(Limits())
    if iso.get("fs") is False or "error" in iso:
        pytest.skip("no mount namespace on this machine (the minimal root needs namespaces: "
                    f"{iso.get('fs_error') or iso.get('mountns_error') or iso.get('error')})")
    return iso


# --------------------------------------------------------------------------- 1. the audit hook undone from inside
GC_WALK = f"""
def normalize_log_weights(log_w):
    import gc, importlib
    for obj in gc.get_objects():
        if type(obj).__name__ == "function" and obj.__name__ == "hook" and obj.__closure__:
            for cell in obj.__closure__:
                try:
                    value = cell.cell_contents
                except ValueError:
                    continue
                if isinstance(value, list) and value == [False]:
                    value[0] = True
    sys.meta_path[:] = [f for f in sys.meta_path if "Blocked" not in getattr(f, "__name__", "")]
    sys.path.insert(0, {PROJECT_DIR!r})
    ref = importlib.import_module("slam" + "lib")
    return ref.normalize_log_weights(log_w)
"""


def test_gc_walk_that_disables_the_audit_hook_finds_no_reference(tmp_path):
    _needs_sandbox_root()
    scores, out, _ = _grade_variant(tmp_path, GC_WALK)
    assert scores[TARGET][0] == 0, out
    assert "No module named" in out
    assert scores[OTHER] == (15.0, 15.0)


# --------------------------------------------------------------------------- 2. the reference read through a directory descriptor
DIR_FD = f"""
def normalize_log_weights(log_w):
    import ast
    from scipy.special import logsumexp
    top = os.open({str(Path(SLAMLIB_DIR).parent)!r}, os.O_RDONLY)
    d = os.open({Path(SLAMLIB_DIR).name[:4]!r} + {Path(SLAMLIB_DIR).name[4:]!r}, os.O_RDONLY, dir_fd=top)
    fd = os.open("particle.py", os.O_RDONLY, dir_fd=d)
    src = os.read(fd, 10**7).decode()
    tree = ast.parse(src)
    core = [n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "_normalized"]
    ns = {{"np": np, "logsumexp": logsumexp}}
    exec(compile(ast.Module(body=core, type_ignores=[]), "ref", "exec"), ns)
    return np.exp(ns["_normalized"](np.asarray(log_w, float)))
"""


def test_reference_and_tests_are_not_in_the_sandbox(tmp_path):
    _needs_sandbox_root()
    scores, out, _ = _grade_variant(tmp_path, DIR_FD)
    assert scores[TARGET][0] == 0, out
    assert "No such file or directory" in out
    # nothing of the project, the tests or site-packages is visible; the private /tmp is empty
    probe = f"""
def effective_sample_size(w):
    seen = [p for p in ({SLAMLIB_DIR!r}, {PROJECT_DIR!r} + "/autograder", {PROJECT_DIR!r} + "/tests",
                        "/autograder") if os.path.exists(p)]
    for top, dirs, files in os.walk("/"):
        if top == "/":
            dirs[:] = [d for d in dirs if d not in ("proc", "sys", "dev")]
        seen += [os.path.join(top, n) for n in dirs + files if n.startswith(("slam" + "lib", "auto" + "grader"))]
    try:
        seen += os.listdir("/tmp")
    except PermissionError:  # a worker may not even list it (Landlock): its own scratch folder is elsewhere
        pass
    if seen:
        raise RuntimeError("visible: " + ", ".join(seen))
    w = np.asarray(w, float)
    return float(w.sum() ** 2 / (w ** 2).sum())
"""
    scores, out, _ = _grade_variant(tmp_path, probe, function=OTHER, lim=limits(call_timeout=30.0))
    assert scores[OTHER] == (15.0, 15.0), out


# --------------------------------------------------------------------------- 3. a classmate's file in a batch
THIEF = """
import os
for _d in os.listdir("/proc"):
    try:
        _args = open(f"/proc/{_d}/cmdline", "rb").read().split(b"\\0")
    except Exception:
        continue
    for _a in _args:
        _a = _a.decode(errors="replace")
        if _a.startswith("/") and os.path.isdir(_a) and "thief" not in _a:
            for _name in sorted(os.listdir(_a)):
                _f = os.path.join(_a, _name)
                try:
                    if _name.endswith(".py") and "thief" not in _name and "def normalize_log_weights" in open(_f).read():
                        exec(open(_f).read(), globals())
                except Exception:
                    pass
"""


def _run_batch(subs, out, *extra, **kw):
    env = {**os.environ, "PYTHONPATH": str(AG_ROOT)}
    return subprocess.run([sys.executable, "-m", "autograder", "batch", str(subs), "--exercise", "particle_filter",
                           "--out", str(out), "--quiet", *extra], capture_output=True, text=True, cwd=str(AG_ROOT),
                          env=env, **kw)


@pytest.mark.slow
def test_batch_submission_cannot_run_a_classmates_file(tmp_path):
    _needs_sandbox_root()
    import shutil
    import tempfile

    # a folder anyone may read, as a TA's grading folder usually is
    work = Path(tempfile.mkdtemp(prefix="ag-batch-"))
    try:
        os.chmod(work, 0o755)
        subs = work / "subs"
        subs.mkdir(mode=0o755)
        (subs / "alice.py").write_text(solution_text("particle_filter"))
        (subs / "zz_thief.py").write_text(THIEF)
        for f in subs.iterdir():
            os.chmod(f, 0o644)
        out = tmp_path / "grades.csv"
        p = _run_batch(subs, out, "--jobs", "2", timeout=300)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    assert p.returncode == 0, p.stderr
    rows = {r["submission"]: r for r in csv.DictReader(out.open())}
    assert float(rows["alice"]["score"]) == 100
    assert float(rows["zz_thief"]["score"]) == 0


# --------------------------------------------------------------------------- 4. harvested scenarios
def test_answers_harvested_in_one_grading_do_not_fit_the_next(tmp_path):
    tag = uuid.uuid4().hex
    store = f"/tmp/harvest_{tag}.json"
    # the worker's scratch folder (TMPDIR) where there is one, else /tmp: either way the first grading's table is
    # where the second grading would look if anything passed between gradings
    logger = f"""
def normalize_log_weights(log_w):
    import json, tempfile
    STORE = os.path.join(tempfile.gettempdir(), {os.path.basename(store)!r})
    x = np.asarray(log_w, float)
    w = np.exp(x - x.max())
    w = w / w.sum()
    try:
        table = json.load(open(STORE))
    except (OSError, ValueError):
        table = []
    table.append([x.tolist(), w.tolist()])
    fd = os.open(STORE, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o666)
    os.write(fd, json.dumps(table).encode())
    os.close(fd)
    return w
"""
    lookup = f"""
def normalize_log_weights(log_w):
    import glob, json, tempfile
    x = np.asarray(log_w, float)
    table = []
    for STORE in [os.path.join(tempfile.gettempdir(), {os.path.basename(store)!r})] + glob.glob(
            "/tmp/**/" + {os.path.basename(store)!r}, recursive=True):
        try:
            table += json.load(open(STORE))
        except (OSError, ValueError):
            pass
    for inp, out in table:
        if len(inp) == len(x) and np.array_equal(np.array(inp), x):
            return np.array(out)
    return np.zeros(len(x))
"""
    try:
        honest, _, first = _grade_variant(tmp_path, logger, name="honest.py")
        assert honest[TARGET] == (20.0, 20.0)
        copied, out, second = _grade_variant(tmp_path, lookup, name="copier.py")
        assert copied[TARGET][0] == 0, out
        # the scenarios follow the submission's content; the seed is recorded and reproduces the grade
        assert first.seed is not None and second.seed is not None and first.seed != second.seed
        again = grade(tmp_path / "copier.py", "particle_filter", limits=limits(), functions=[TARGET, OTHER],
                      seed=second.seed)
        assert [t.output for t in again.tests] == [t.output for t in second.tests]
        assert again.to_gradescope()["extra_data"]["seed"] == second.seed
    finally:
        if os.path.exists(store):
            os.remove(store)


# --------------------------------------------------------------------------- 5. writes outside the scratch space
def test_writes_stay_in_the_sandbox_and_are_capped(tmp_path):
    _needs_sandbox_root()
    tag = uuid.uuid4().hex
    marks = [f"/tmp/ag_mark_{tag}", f"/dev/shm/ag_mark_{tag}", os.path.join(os.getcwd(), f"ag_mark_{tag}")]
    body = f"""
def normalize_log_weights(log_w):
    for p in {marks!r}:
        try:
            with open(p, "w") as fh:
                fh.write("x")
        except OSError:
            pass
    capped = False
    chunk = b"\\0" * (4 << 20)
    for k in range(12):
        try:
            with open(f"/tmp/ag_fill_{tag}_{{k}}", "wb") as fh:
                fh.write(chunk)
        except OSError:
            capped = True
            break
    x = np.asarray(log_w, float)
    w = np.exp(x - x.max())
    return w / w.sum() if capped else np.zeros(len(x))
"""
    try:
        scores, out, _ = _grade_variant(tmp_path, body, lim=limits(tmp_size="16m"))
        left = [p for p in marks if os.path.exists(p)] + [str(p) for p in Path("/tmp").glob(f"ag_fill_{tag}_*")]
        assert left == []
        assert scores[TARGET] == (20.0, 20.0), out  # the private /tmp filled up at 16 MB
    finally:
        for p in marks + [str(p) for p in Path("/tmp").glob(f"ag_fill_{tag}_*")]:
            if os.path.exists(p):
                os.remove(p)


# --------------------------------------------------------------------------- 6. time budgets, and loading once
def test_slow_function_is_bounded_by_its_budgets(tmp_path):
    body = """
def normalize_log_weights(log_w):
    import time
    time.sleep(0.4)
    x = np.asarray(log_w, float)
    w = np.exp(x - x.max())
    return w / w.sum()
"""
    scores, out, result = _grade_variant(tmp_path, body, lim=limits(test_budget=1.0, submission_budget=20.0))
    assert scores[TARGET][0] == 0 and "time budget of 1 s was used up" in out, out
    assert scores[OTHER] == (15.0, 15.0)
    # the whole submission's budget: the remaining tests score 0 with a message
    _, out, _ = _grade_variant(tmp_path, body, lim=limits(test_budget=5.0, submission_budget=1.5))
    assert "the submission's time budget of 1.5 s was used up" in out, out


def test_slow_top_level_code_runs_once(tmp_path):
    top = "import time\ntime.sleep(1.5)\n"
    text = "import os\nimport sys\nimport numpy as np\n" + top + solution_text("particle_filter")
    path = tmp_path / "slow_top.py"
    path.write_text(text)
    result = grade(path, "particle_filter", limits=limits(), workers=1)
    assert result.score == 100
    # loaded once for the four functions (the load time is not asserted: wall time depends on the machine)
    assert getattr(result, "loads", None) == 1


# --------------------------------------------------------------------------- 7. killing batch ends every worker and child
def _descendants(pid):
    children = {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        children.setdefault(ppid, []).append(int(d.name))
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        for c in children.get(p, []):
            out.append(c)
            todo.append(c)
    return out


def _alive(pid):
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _cmdline(pid):
    """The command line of process ``pid`` (empty once it has exited: listing and reading /proc race)."""
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except (FileNotFoundError, ProcessLookupError):
        return b""


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT, signal.SIGKILL])
def test_killing_batch_leaves_no_process_behind(tmp_path, sig):
    subs = tmp_path / "subs"
    subs.mkdir()
    slow = replace_function(solution_text("particle_filter"), TARGET, """
def normalize_log_weights(log_w):
    import time
    time.sleep(0.3)
    x = np.asarray(log_w, float)
    w = np.exp(x - x.max())
    return w / w.sum()
""")
    for i in range(4):
        (subs / f"s{i}.py").write_text(f"# {i}\n" + slow)
    out = tmp_path / "grades.csv"
    env = {**os.environ, "PYTHONPATH": str(AG_ROOT)}
    proc = subprocess.Popen([sys.executable, "-m", "autograder", "batch", str(subs), "--exercise", "particle_filter",
                             "--out", str(out), "--quiet", "--jobs", "2"], cwd=str(AG_ROOT), env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    seen = set()
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            desc = _descendants(proc.pid)
            seen.update(desc)
            runners = [p for p in desc if b"_runner.py" in _cmdline(p)] if desc else []
            if len(runners) >= 2:
                break
            time.sleep(0.2)
        else:
            pytest.fail("the batch never started its sandboxes")
        time.sleep(1.0)
        seen.update(_descendants(proc.pid))
        os.kill(proc.pid, sig)
        proc.wait(timeout=30)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and any(_alive(p) for p in seen):
            time.sleep(0.2)
        survivors = [p for p in seen if _alive(p)]
        assert survivors == [], [_cmdline(p)[:200] for p in survivors]
    finally:
        if proc.poll() is None:
            proc.kill()
        for p in seen:
            if _alive(p):
                try:
                    os.kill(p, signal.SIGKILL)
                except OSError:
                    pass
    assert not any(p.name.endswith(".tmp") for p in tmp_path.rglob("*"))
    # a rerun finishes the job: every submission graded, the CSV complete
    p = _run_batch(subs, out, "--jobs", "2", timeout=300)
    assert p.returncode == 0, p.stderr
    rows = list(csv.DictReader(out.open()))
    assert sorted(r["submission"] for r in rows) == [f"s{i}" for i in range(4)]
    assert all(float(r["effective_sample_size"]) == 15 for r in rows)


# --------------------------------------------------------------------------- 8. inputs a student really submits
def _latin1_source():
    return ("# -*- coding: latin-1 -*-\n# Auteur : Ren\u00e9e Caf\u00e9\n" + solution_text("particle_filter")
            ).encode("latin-1")


@pytest.mark.parametrize("kind", ["bom", "latin1-cookie", "crlf", "nbformat3"])
def test_real_world_encodings_and_formats_grade_normally(tmp_path, kind):
    sol = solution_text("particle_filter")
    if kind == "bom":
        path = tmp_path / "bom.py"
        path.write_bytes(b"\xef\xbb\xbf" + sol.encode("utf-8"))
    elif kind == "latin1-cookie":
        path = tmp_path / "latin.py"
        path.write_bytes(_latin1_source())
    elif kind == "crlf":
        path = tmp_path / "crlf.py"
        path.write_bytes(sol.replace("\n", "\r\n").encode("utf-8"))
    else:
        v3 = nbformat.v3
        nb = v3.new_notebook(worksheets=[v3.new_worksheet(cells=[v3.new_code_cell(input=sol)])])
        path = tmp_path / "old.ipynb"
        path.write_text(v3.writes_json(nb))
        assert json.loads(path.read_text())["nbformat"] == 3
    result = grade(path, "particle_filter", limits=limits(), functions=[TARGET, OTHER])
    assert result.score == 35, result.text_report()


# --------------------------------------------------------------------------- 9. a wrong signature
def test_wrong_signature_reports_the_students_type_error(tmp_path):
    scores, out, _ = _grade_variant(tmp_path, "def normalize_log_weights():\n    return np.ones(3) / 3\n")
    assert scores[TARGET][0] == 0
    assert "TypeError" in out and "takes 0 positional arguments but 1 was given" in out, out
    assert "IndexError" not in out


# --------------------------------------------------------------------------- 10. a hanging notebook cell
def test_hanging_cell_is_skipped_and_the_other_cells_count(tmp_path):
    sol = solution_text("particle_filter")
    head, _, tail = sol.partition("def effective_sample_size")
    nb = nbformat.v4.new_notebook(cells=[
        nbformat.v4.new_code_cell(head),
        nbformat.v4.new_code_cell("import time\nwhile True:\n    time.sleep(0.01)"),
        nbformat.v4.new_code_cell("def effective_sample_size" + tail),
        nbformat.v4.new_code_cell("while True:\n    pass"),
    ])
    path = tmp_path / "hang.ipynb"
    nbformat.write(nb, path)
    result = grade(path, "particle_filter", limits=limits(statement_timeout=1.5), functions=[TARGET, OTHER])
    assert result.score == 35, result.text_report()
    notes = "\n".join(result.notes)
    assert "code cell 2, line 2: did not finish within 1.5 s" in notes
    assert "code cell 4, line 1: did not finish within 1.5 s" in notes


# each-over: three skips of 1 s each use the whole 3 s of loading by themselves, whatever a loading costs on this
# machine (with 4 s, a fast machine skipped all three and reloaded in time: no cut, and nothing of what is tested)
@pytest.mark.parametrize("sleep,n,lim", [(2.5, 3, dict(statement_timeout=1.0, import_timeout=3.0)),
                                         (0.8, 4, dict(statement_timeout=1.5, import_timeout=2.5))],
                         ids=["each-over-the-statement-limit", "together-over-the-loading-limit"])
def test_slow_experiment_cells_after_the_functions_cost_nothing(tmp_path, sleep, n, lim, monkeypatch):
    """Cells that each ran over the statement limit (each skip cost a loading again), or that together ran over the
    loading limit, once scored 0 ("loading the submission took longer than ..."): the statement under way when
    the loading runs out of time is left out with the rest, as in an interrupted kernel, and the functions
    defined before are graded."""
    # the limits as an idle machine keeps them: on a loaded one they stretch by the time the loading waited for a
    # processor (test_autograder_grader_process), and the loading might then not run out of time at all
    monkeypatch.setattr("autograder.sandbox._delays", lambda pids: {})
    nb = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(solution_text("particle_filter"))] + [
        nbformat.v4.new_code_cell(f"import time\ntime.sleep({sleep})") for _ in range(n)])
    path = tmp_path / "slow_cells.ipynb"
    nbformat.write(nb, path)
    result = grade(path, "particle_filter", limits=limits(**lim), functions=[TARGET, OTHER])
    assert result.score == result.max_score == 35, result.text_report()
    notes = "\n".join(result.notes)
    assert f"reached its {lim['import_timeout']:g} s limit; this statement and every one after it were not run" in notes


# --------------------------------------------------------------------------- 9. files a student controls
def test_a_symbolic_link_is_never_graded_as_a_submission(tmp_path):
    """A link would make the grader (often root) read another student's work or its own secret as the submission,
    and echo it in a load note: links to files and to folders are refused in every way in."""
    from autograder.batch import _LINK_REASON, find_submissions, pick_submission_file
    from autograder.submission import SubmissionError, load_submission

    secret = tmp_path / "grading_secret"
    secret.write_text("a2c4864d9b54d97\n")
    subs = tmp_path / "subs"
    (subs / "alice").mkdir(parents=True)
    (subs / "alice" / "my_solution.py").write_text(solution_text("particle_filter"))
    (subs / "mallory").mkdir()
    (subs / "mallory" / "mine.py").symlink_to(subs / "alice" / "my_solution.py")
    (subs / "carol.py").symlink_to(secret)
    (subs / "dave").symlink_to(subs / "alice", target_is_directory=True)
    (subs / "erin").mkdir()
    (subs / "erin" / "work").symlink_to(subs / "alice", target_is_directory=True)
    got = {sid: (path, why) for sid, path, why in find_submissions(subs)}
    assert got["alice"] == (subs / "alice" / "my_solution.py", None)
    for sid in ("mallory", "carol", "dave", "erin"):
        assert got[sid][0] is None and "symbolic link" in got[sid][1], (sid, got[sid])
    assert pick_submission_file(subs / "mallory")[0] is None
    assert pick_submission_file(subs / "dave") == (None, f"the submission folder dave is {_LINK_REASON}")
    with pytest.raises(SubmissionError, match="symbolic link"):
        load_submission(subs / "carol.py")
    root = tmp_path / "gs"  # a Gradescope root whose submission is a link to the grader's own secret
    (root / "submission").mkdir(parents=True)
    (root / "submission" / "solution.py").symlink_to(secret)
    env = {**os.environ, "PYTHONPATH": str(AG_ROOT)}
    p = subprocess.run([sys.executable, "-m", "autograder", "gradescope", "--root", str(root), "-e", "particle_filter"],
                       capture_output=True, text=True, cwd=str(AG_ROOT), env=env, timeout=300)
    out = (root / "results" / "results.json").read_text()
    assert "a2c4864d9b54d97" not in out + p.stdout + p.stderr and "symbolic link" in out, out


def test_two_entries_with_one_id_are_one_row_and_not_graded(tmp_path):
    from autograder.batch import find_submissions

    (tmp_path / "dave.py").write_text(solution_text("particle_filter"))
    (tmp_path / "dave.ipynb").write_text("{}")
    (tmp_path / "erin").mkdir()
    (tmp_path / "erin" / "a.py").write_text("x = 1\n")
    (tmp_path / "erin.py").write_text("x = 2\n")
    got = find_submissions(tmp_path)
    assert [sid for sid, _, _ in got] == ["dave", "erin"]
    assert all(path is None and "have the id" in why for _, path, why in got), got


def test_csv_cells_a_student_names_are_not_spreadsheet_formulas():
    from autograder.batch import _cell

    assert _cell('=HYPERLINK("http://x","y")') == '\'=HYPERLINK("http://x","y")'
    assert [_cell(v) for v in ("+1", "-rf", "@sum", "\tx", "alice", 100.0, "")] == \
        ["'+1", "'-rf", "'@sum", "'\tx", "alice", 100.0, ""]


@pytest.mark.parametrize("meta", [{"tags": 5}, {"tags": "skip-grading"}, {"tags": [5, None]}, [], "x", None])
def test_any_cell_metadata_reads_as_no_tags(tmp_path, meta):
    """The cell's metadata is the student's JSON: a value of another type is no tag (and never a grader error)."""
    from autograder.submission import load_submission

    cell = {"cell_type": "code", "execution_count": None, "metadata": meta, "outputs": [],
            "source": solution_text("particle_filter")}
    nb = {"cells": [cell], "metadata": {}, "nbformat": 4, "nbformat_minor": 5}
    path = tmp_path / "nb.ipynb"
    path.write_text(json.dumps(nb))
    try:
        sub = load_submission(path)
    except Exception as exc:  # noqa: BLE001 - the reader may refuse it, as a SubmissionError only
        from autograder.submission import SubmissionError

        assert isinstance(exc, SubmissionError), type(exc)
        return
    assert len(sub.units) == 1


def test_a_file_name_too_long_for_a_results_file_is_graded_like_any_other(tmp_path):
    """The results file of an id of 237 characters would need a temporary name over 255 bytes: the batch once
    stopped there, on every rerun, without writing grades.csv."""
    from autograder.batch import results_file

    subs = tmp_path / "subs"
    subs.mkdir()
    long_id = "0" * 237
    (subs / f"{long_id}.py").write_text(solution_text("particle_filter"))
    out = tmp_path / "grades.csv"
    for _ in range(2):  # a rerun reads the results file back
        p = _run_batch(subs, out, "--jobs", "1", timeout=300)
        assert p.returncode == 0, p.stderr[-2000:]
        rows = {r["submission"]: r for r in csv.DictReader(out.open())}
        assert float(rows[long_id]["score"]) == 100, rows
    name = results_file(tmp_path, long_id).name
    assert len(name.encode()) <= 205 and results_file(tmp_path, long_id) != results_file(tmp_path, "0" * 238)
    assert results_file(tmp_path, "alice").name == "alice.json"


def test_code_nested_too_deeply_for_the_parser_is_a_cell_that_cannot_be_read(tmp_path):
    from autograder.submission import load_submission

    deep = "_x = " + "+".join(["1"] * 5000) + "\n"
    nb = {"cells": [{"cell_type": "code", "execution_count": None, "metadata": {}, "outputs": [],
                     "source": solution_text("particle_filter")},
                    {"cell_type": "code", "execution_count": None, "metadata": {}, "outputs": [], "source": deep}],
          "metadata": {}, "nbformat": 4, "nbformat_minor": 5}
    path = tmp_path / "deep.ipynb"
    path.write_text(json.dumps(nb))
    sub = load_submission(path)
    assert list(sub.syntax_errors.values()) == ["too deeply nested for Python's parser"], sub.syntax_errors
    result = grade(path, "particle_filter")
    assert result.score == result.max_score, result.text_report()


def test_a_folder_nested_deeper_than_python_recurses_is_its_own_row(tmp_path):
    """An upload 1100 folders deep once stopped the batch (and was a grader error on Gradescope)."""
    from autograder.batch import MAX_DEPTH, find_submissions, pick_submission_file

    subs = tmp_path / "subs"
    levels = [os.path.join(subs, "bob", *["d"] * k) for k in range(1, 1101)]
    (subs / "bob").mkdir(parents=True)
    try:
        for d in levels:  # one level at a time: os.makedirs and shutil.rmtree recurse
            os.mkdir(d)
        Path(levels[-1], "x.py").write_text("x = 1\n")
        carl = subs / "carl" / os.path.join(*["d"] * (MAX_DEPTH - 2))
        carl.mkdir(parents=True)
        (carl / "a.py").write_text("x = 1\n")
        got = {sid: (path, why) for sid, path, why in find_submissions(subs)}
        assert got["bob"] == (None, f"the submission folder is nested more than {MAX_DEPTH} levels deep"), got["bob"]
        assert got["carl"][0] is not None and got["carl"][0].name == "a.py"
        assert pick_submission_file(subs / "bob")[0] is None
    finally:  # pytest's own clean-up of tmp_path recurses too
        Path(levels[-1], "x.py").unlink(missing_ok=True)
        for d in reversed(levels):
            if os.path.isdir(d):
                os.rmdir(d)


def test_a_file_name_that_is_not_utf8_is_its_own_row(tmp_path):
    """A Latin-1 name (caf\\xe9.py) once stopped the batch, on every rerun: its id could not be written."""
    from autograder.batch import _write_csv, find_submissions, results_file
    from autograder.exercises import get_exercise

    fd = os.open(os.path.join(os.fsencode(tmp_path), b"caf\xe9.py"), os.O_WRONLY | os.O_CREAT, 0o644)
    os.write(fd, b"x = 1\n")
    os.close(fd)
    (tmp_path / "alice.py").write_text("x = 1\n")
    got = find_submissions(tmp_path)
    assert got[0][0] == "alice" and got[1][:2] == ("caf\\xe9", None) and "not UTF-8" in got[1][2], got
    ex = get_exercise("particle_filter")
    rows = [{"submission": sid, "file": "", "score": 0.0, "max_score": ex.max_score(), "status": "error",
             "message": why or "", **{fn: 0.0 for fn in ex.functions}} for sid, _, why in got]
    _write_csv(tmp_path / "out" / "grades.csv", rows, ex)
    results_file(tmp_path, got[1][0]).write_text("{}")


def test_two_ids_never_share_a_results_file(tmp_path):
    import hashlib

    from autograder.batch import results_file

    long_id = "alice_" + "x" * 210
    looks_cut = long_id[:100] + "-" + hashlib.sha256(long_id.encode()).hexdigest()[:16]
    assert results_file(tmp_path, long_id) != results_file(tmp_path, looks_cut)
    assert results_file(tmp_path, "bob").name == "bob.json"


def test_a_line_that_starts_with_an_operator_inside_brackets_is_python_not_a_magic(tmp_path):
    """Code formatters break a long expression before its operator: a line starting with % or != inside brackets
    is Python (the notebook once scored 0 where the same .py file scored full marks)."""
    from autograder.submission import _strip_magics, load_submission

    notes = []
    src = "%matplotlib inline\nx = (7\n     % 2)\n!ls\ny = [1\n     != 2]\n%time z = 1\n"
    out = _strip_magics(src, "c", notes)
    assert out.splitlines()[1:3] == ["x = (7", "     % 2)"] and out.splitlines()[4:6] == ["y = [1", "     != 2]"]
    assert sum("IPython line left out" in line for line in out.splitlines()) == 3, out
    text = solution_text("particle_filter").replace("nu[:, 1] = (nu[:, 1] + np.pi) % (2 * np.pi) - np.pi",
                                                     "nu[:, 1] = ((nu[:, 1] + np.pi)\n    % (2 * np.pi)) - np.pi")
    assert "\n    % (2 * np.pi)" in text
    nb = {"cells": [{"cell_type": "code", "execution_count": None, "metadata": {}, "outputs": [], "source": text}],
          "metadata": {}, "nbformat": 4, "nbformat_minor": 5}
    path = tmp_path / "formatted.ipynb"
    path.write_text(json.dumps(nb))
    assert not load_submission(path).syntax_errors
    result = grade(path, "particle_filter", functions=["landmark_likelihood"])
    assert result.score == result.max_score, result.text_report()


def test_cell_magics_that_run_python_and_help_lines_keep_their_functions(tmp_path):
    """``%%time``/``%%capture`` cells run their body as Python in Jupyter, and ``obj?`` is a help line: the notebook
    once scored 30/100 (both cells left out, the help line a syntax error) where IPython defined every function."""
    from autograder.submission import _strip_magics

    head, *defs = solution_text("particle_filter").split("\ndef ")
    cells = [head + "\ndef " + defs[0], "def " + defs[1], "def " + defs[2], "def " + defs[3]]
    nb = nbformat.v4.new_notebook(cells=[
        nbformat.v4.new_code_cell("%%time\n" + cells[0]),
        nbformat.v4.new_code_cell("%%capture out\n" + cells[1]),
        nbformat.v4.new_code_cell("np.random.default_rng?\n" + cells[2] + "\n??np.linalg\n"),
        nbformat.v4.new_code_cell("%%bash\necho def landmark_likelihood\n"),
        nbformat.v4.new_code_cell("np.linalg.inv??\n" + cells[3]),
    ])
    path = tmp_path / "ipython.ipynb"
    nbformat.write(nb, path)
    result = grade(path, "particle_filter")
    assert result.score == result.max_score == 100, result.text_report()
    notes = "\n".join(result.notes)
    assert "code cell 1: cell magic %%time -- its first line left out" in notes, notes
    assert "code cell 2: cell magic %%capture -- its first line left out" in notes, notes
    assert "code cell 3: 2 IPython magic/shell lines left out" in notes, notes
    assert "code cell 4: cell magic %%bash -- the whole cell is left out" in notes, notes
    # only where it is IPython syntax: not in a string, inside brackets, or after an operator
    src = 's = """\nx?\n"""\nf(a,\n  b?\n  )\ny = a?\n'
    assert _strip_magics(src, "c", []) == src
    # a magic or a shell escape assigned to a name is IPython too (and never Python)
    notes = []
    kept = _strip_magics("files = !ls\nt = %timeit -o f()\ndef f():\n    return 1\nx = (1 %\n     2)\n", "c", notes)
    assert kept.splitlines()[2:] == ["def f():", "    return 1", "x = (1 %", "     2)"], kept
    assert "!ls" not in kept and "%timeit" not in kept and notes == ["c: 2 IPython magic/shell lines left out"], notes


def test_a_function_that_calls_jupyters_display_runs_as_in_jupyter(tmp_path):
    """Jupyter gives every notebook ``display``: a correct function that displayed an intermediate value (a
    debugging leftover) raised NameError in every test of the grader. A submission's own ``display`` still wins."""
    text = solution_text("particle_filter")
    body = ("def normalize_log_weights(logw):\n    display(logw)\n    return _own_nlw(logw)\n")
    text = text.replace("def normalize_log_weights(", "def _own_nlw(") + "\n\n" + body
    nb = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(text)])
    path = tmp_path / "display.ipynb"
    nbformat.write(nb, path)
    result = grade(path, "particle_filter", functions=["normalize_log_weights"])
    assert result.score == result.max_score, result.text_report()
    own = text + "\n\ndef display(x):\n    raise RuntimeError('own display')\n"
    path = tmp_path / "own.py"
    path.write_text(own)
    result = grade(path, "particle_filter", functions=["normalize_log_weights"])
    assert result.score == 0 and "own display" in result.text_report(), result.text_report()


def test_no_public_test_runs_after_a_hidden_one(tmp_path):
    """One worker serves a function's tests in order: a submission counted the calls of the hidden test declared
    between two public ones of ekf_predict and told the count in the later public test's error (shown before the
    due date). Every public test now runs before any hidden one."""
    text = solution_text("ekf_localization").replace("def ekf_predict(", "def _own_ekf_predict(")
    text += '''

_seen = []


def ekf_predict(mu, Sigma, u, dt, M):
    if float(u[1]) in (2e-6, -3e-5, 1.5e-3, -9e-3):  # the turn rates of the hidden test "small turn rates"
        _seen.append(1)
    elif _seen:
        raise RuntimeError(f"ORACLE: the hidden test made {len(_seen)} calls before this one")
    return _own_ekf_predict(mu, Sigma, u, dt, M)
'''
    path = tmp_path / "oracle.py"
    path.write_text(text)
    result = grade(path, "ekf_localization", limits=limits(), functions=["ekf_predict"])
    data = gradescope_json_ok(result.to_gradescope())
    shown = [t for t in data["tests"] if t["visibility"] == "visible"]
    assert shown and all(t["status"] == "passed" for t in shown), result.text_report()
    assert "ORACLE" not in json.dumps(shown)


def test_the_always_visible_summary_counts_no_hidden_test():
    """Gradescope shows the top-level ``output`` before the due date: it once said which function lost points in a
    hidden test, and how many."""
    from autograder.results import GradeResult, TestResult

    tests = [TestResult("f: a", "f", 3.0, 3.0, "passed", "visible"),
             TestResult("f: b", "f", 0.0, 2.0, "FAILED\nsecret inputs", "after_due_date"),
             TestResult("g: a", "g", 0.0, 4.0, "FAILED", "visible")]
    data = GradeResult("s.py", "ex", tests).to_gradescope()
    assert data["output"].splitlines()[:2] == [
        "Exercise ex: 3 / 7 points on the tests shown now; hidden tests worth 2 more points count in the score shown "
        "after the due date", "Functions that lost points: g (0/4)"], data["output"]
    data = GradeResult("s.py", "ex", tests[:2]).to_gradescope()
    assert "Every test shown now passed." in data["output"] and "f (3/5)" not in data["output"]
    # the staff's report still counts every test
    assert GradeResult("s.py", "ex", tests[:2]).text_report().startswith("Exercise ex: 3 / 5 points\n")


# --------------------------------------------------------------------------- 11. the static check for slamlib
LIK = "landmark_likelihood"
OWN_WRAP = ('def wrap_angle(a):\n    """My own wrap."""\n'
            '    return (np.asarray(a, dtype=float) + np.pi) % (2.0 * np.pi) - np.pi\n\n\n')
WRAPPED = solution_text("particle_filter").replace("nu[:, 1] = (nu[:, 1] + np.pi) % (2 * np.pi) - np.pi",
                                                   "nu[:, 1] = wrap_angle(nu[:, 1])")


def _static(src, functions=("f",)):
    from autograder.submission import forbidden_usage

    return forbidden_usage([{"source": src, "filename": "s.py", "label": "s.py"}], list(functions))


def _grade_lik(path):
    result = grade(path, "particle_filter", limits=limits(), functions=[LIK])
    gradescope_json_ok(result.to_gradescope())
    return result.by_function()[LIK], "\n".join(t.output for t in result.tests)


def test_an_import_of_the_reference_the_submission_replaces_or_never_runs_costs_nothing(tmp_path):
    """Any ``from slamlib import wrap_angle`` anywhere tainted the name: a correct landmark_likelihood calling the
    student's own wrap_angle, defined after a try/except import of the reference's, or compared with it under
    ``if __name__ == "__main__":``, scored 0 ("uses `wrap_angle` (from slamlib import wrap_angle ...)"). The
    binding in force when the functions are called counts; an import still in force at the end costs it."""
    assert "def wrap_angle" not in WRAPPED and "wrap_angle(nu[:, 1])" in WRAPPED
    head, _, body = WRAPPED.partition("\n\n\n")
    try_import = "try:\n    from slamlib import wrap_angle\n    print(wrap_angle(4.0))\nexcept ImportError:\n    pass\n"
    main = ('\n\nif __name__ == "__main__":\n    from slamlib import wrap_angle, landmark_likelihood as ref\n'
            '    print(wrap_angle(4.0))\n')
    path = tmp_path / "own_wrap.py"
    path.write_text(head + "\n\n" + try_import + "\n\n" + OWN_WRAP + body + main)
    (score, max_score), out = _grade_lik(path)
    assert score == max_score > 0, out
    # the same import in force at the end: landmark_likelihood calls the reference's wrap_angle
    path.write_text(head + "\n\n" + OWN_WRAP + body + "\n\nfrom slamlib import wrap_angle\n")
    (score, _), out = _grade_lik(path)
    assert score == 0 and "No credit" in out and "`wrap_angle` (from slamlib import wrap_angle" in out, out


def test_a_notebook_that_imports_the_reference_before_the_template_defines_the_name_keeps_its_points(tmp_path):
    """Notebooks 02 and 03 define wrap_angle in a template cell: an earlier cell of the student's importing the
    reference's wrap_angle to compare zeroed the correct landmark_likelihood. A cell after it that imports it
    again still does."""
    cells = ["from slamlib import wrap_angle\nprint(wrap_angle(4.0))", OWN_WRAP, WRAPPED]
    path = tmp_path / "compare_first.ipynb"
    nbformat.write(nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(c) for c in cells]), path)
    (score, max_score), out = _grade_lik(path)
    assert score == max_score > 0, out
    path = tmp_path / "compare_last.ipynb"
    nbformat.write(nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(c) for c in cells[1:] + cells[:1]]),
                   path)
    (score, _), out = _grade_lik(path)
    assert score == 0 and "No credit" in out and "code cell 3" in out, out


BINDINGS = [
    # a parameter of a lambda or def inside the function is no module-level name (round 7: 70/100)
    ("def f(x):\n    return (lambda w: w + 1)(x)\nfrom slamlib import w\n", None),
    ("def f(x):\n    def g(a, w=2):\n        return w * a\n    return g(x)\nfrom slamlib import w\n", None),
    # ... but a default or a decorator is evaluated outside that scope, and the function's own use still counts
    ("from slamlib import w\ndef f(x):\n    def g(a, w=w):\n        return w(a)\n    return g(x)\n", "w"),
    ("from slamlib import w\ndef f(x):\n    g = lambda w: w\n    return w(g(x))\n", "w"),
    # ... and so does a name a nested def declares global, whatever the parameters around it (round 8)
    ("from slamlib import w\ndef f(x, w=None):\n    def g(a):\n        global w\n        return w(a)\n"
     "    return g(x)\n", "w"),
    # replaced by a later binding, unbound, or never run: harmless
    ("from slamlib import w\ndef w(a): return a\ndef f(x): return w(x)\n", None),
    ("try:\n    from slamlib import w\nexcept ImportError:\n    pass\ndef w(a): return a\ndef f(x): return w(x)\n",
     None),
    ("def w(a): return a\nif __name__ == '__main__':\n    from slamlib import w\ndef f(x): return w(x)\n", None),
    ("from slamlib import w\nif c:\n    def w(a): return a\nelse:\n    w = abs\ndef f(x): return w(x)\n", None),
    ("from slamlib import w\ndel w\ndef f(x): return w(x)\n", None),
    ("import slamlib as sl\nsl = None\ndef f(x): return sl.w(x)\n", None),
    ("from slamlib import *\ndef w(a): return a\ndef f(x): return w(x)\n", None),
    ("from slamlib import f\ndef f(x): return x\n", None),
    ("from slamlib import w\nW = lambda a: w(a)\ndef w(a): return a\ndef f(x): return W(x)\n", None),
    # the reference's code may be what runs: no credit
    ("def w(a): return a\nfrom slamlib import w\ndef f(x): return w(x)\n",
     "uses `w` (from slamlib import w, s.py line 2)"),
    ("try:\n    from slamlib import w\nexcept ImportError:\n    def w(a): return a\ndef f(x): return w(x)\n",
     "uses `w` (from slamlib"),
    ("def w(a): return a\nif c:\n    from slamlib import w\ndef f(x): return w(x)\n", "uses `w` (from slamlib"),
    ("def w(a): return a\nif __name__ == '__main__':\n    pass\nelse:\n    from slamlib import w\n"
     "def f(x): return w(x)\n", "uses `w` (from slamlib"),
    ("from slamlib import w\nW = w\ndef w(a): return a\ndef f(x): return W(x)\n", "calls `W`, which uses `w`"),
    ("import slamlib as sl\nsl.x = 1\ndef f(x): return sl.w(x)\n", "uses `sl` (import slamlib"),
    ("def w(a): return a\ndef load():\n    global w\n    from slamlib import w\nload()\ndef f(x): return w(x)\n",
     "calls `w`, which imports slamlib"),
    ("from slamlib import *\ndef f(x): return w(x)\n", "can only come from from slamlib import *"),
    ("def f(x): return x\nfrom slamlib import f\n", "f is `f` (from slamlib import f, s.py line 2)"),
]


def test_the_binding_in_force_when_the_functions_run_decides():
    """The static check tainted a name any statement bound from slamlib, wherever it stood: a later def, a
    ``del``, an ``if __name__ == "__main__":`` block did not count. The bindings are followed in execution order;
    one that may be in force (in either branch, in a try body or its handler) still counts."""
    wrong = []
    for src, why in BINDINGS:
        found = _static(src).get("f")
        if (found is None) != (why is None) or (why is not None and why not in found):
            wrong.append(f"{src!r}: expected {why!r}, found {found!r}")
    assert not wrong, "\n".join(wrong)


W = "from slamlib import w\n"
SCOPES = [
    # a name bound in a scope inside the function is not the function's: its own load of `w` is the module's
    # (round 9: each hid a real use of the reference)
    ("comprehension-variable", W + "def f(x):\n    _ = [w for w in ()]\n    return w(x)\n", "uses `w` (from slamlib"),
    ("nested-def-local", W + "def f(x):\n    def inner():\n        w = 1\n    return w(x)\n", "uses `w` (from slamlib"),
    ("nested-class-body", W + "def f(x):\n    class C:\n        w = 1\n    return w(x)\n", "uses `w` (from slamlib"),
    ("walrus-in-nested-def", W + "def f(x):\n    def g():\n        return (w := 1)\n    return w(x)\n",
     "uses `w` (from slamlib"),
    ("walrus-in-lambdas-comprehension", W + "def f(x):\n    g = lambda: [(w := v) for v in x]\n    return w(x)\n",
     "uses `w` (from slamlib"),
    # a comprehension in a class body does not see the class's names
    ("comprehension-in-class-body", W + "def f(x):\n    class A:\n        w = abs\n        y = [w(v) for v in x]\n"
     "    return A.y\n", "uses `w` (from slamlib"),
    # a name bound in the function by except-as, a match capture or a walrus is the function's own
    ("except-as", W + "def f(x):\n    try:\n        return x\n    except ValueError as w:\n        return w\n", None),
    ("match-capture", W + "def f(x):\n    match x:\n        case w:\n            return w\n", None),
    ("match-sequence", W + "def f(x):\n    match x:\n        case [w]:\n            return w\n    return x\n", None),
    ("match-star", W + "def f(x):\n    match x:\n        case [1, *w]:\n            return w\n    return x\n", None),
    ("match-mapping-rest", W + "def f(x):\n    match x:\n        case {'k': 1, **w}:\n            return w\n"
     "    return x\n", None),
    ("walrus", W + "def f(x):\n    if (w := x):\n        return w\n    return x\n", None),
    ("walrus-in-comprehension", W + "def f(x):\n    _ = [(w := v) for v in x]\n    return w\n", None),
    # a comprehension's variable at module level is not the module's name
    ("module-level-comprehension", W + "W = [w for w in range(3)]\ndef f(x):\n    return W[x]\n", None),
    # module-level bindings a walrus or a match capture makes are followed like the others
    ("module-level-walrus", "import slamlib\n_ = (w := slamlib.wrap_angle)\ndef f(x):\n    return w(x)\n",
     "calls `w`, which uses `slamlib` (import slamlib"),
    ("module-level-match-capture", "import slamlib\nmatch slamlib.wrap_angle:\n    case w:\n        pass\n"
     "def f(x):\n    return w(x)\n", "calls `w`, which uses `slamlib` (import slamlib"),
    # a walrus the statement always evaluates replaces the binding before it; one it may skip does not
    ("module-level-walrus-replaces", "from slamlib import wrap_angle as w\n_ = print((w := abs))\n"
     "def f(x):\n    return w(x)\n", None),
    ("module-level-walrus-in-if-test-and-default", "from slamlib import wrap_angle as w\nif (w := abs):\n"
     "    pass\nfrom slamlib import wrap_angle as v\ndef g(a=(v := abs)):\n    pass\n"
     "def f(x):\n    return w(v(x))\n", None),
    ("module-level-walrus-maybe-skipped", "from slamlib import wrap_angle as w\n_ = 0 or (w := abs)\n"
     "def f(x):\n    return w(x)\n", "uses `w` (from slamlib"),
    ("module-level-walrus-in-branch", "from slamlib import wrap_angle as w\n_ = (w := abs) if len('') else 0\n"
     "def f(x):\n    return w(x)\n", "uses `w` (from slamlib"),
    ("module-level-walrus-in-assert-message", "from slamlib import wrap_angle as w\nassert 1, (w := abs)\n"
     "def f(x):\n    return w(x)\n", "uses `w` (from slamlib"),
    ("module-level-walrus-in-failed-guard", "from slamlib import wrap_angle as w\nmatch 1:\n"
     "    case 2 if (w := abs):\n        pass\ndef f(x):\n    return w(x)\n", "uses `w` (from slamlib"),
    ("module-level-walrus-after-a-raise", "from slamlib import wrap_angle as w\ntry:\n"
     "    _ = (1 // 0, (w := abs))\nexcept ZeroDivisionError:\n    pass\ndef f(x):\n    return w(x)\n",
     "uses `w` (from slamlib"),
    ("module-level-walrus-in-an-elif-test", "import slamlib\nif len(''):\n    pass\n"
     "elif (w := slamlib.wrap_angle):\n    pass\ndef f(x):\n    return w(x)\n", "calls `w`, which uses `slamlib`"),
    # a decorator runs when the def does: the binding then counts, not the last one
    ("decorator-at-def-time", "from slamlib import wrap_angle as d\n@d\ndef f(x):\n    return x\nd = abs\n",
     "uses `d` (from slamlib"),
    # a generator expression runs as it is iterated: when the function calls next() on it
    ("generator-run-later", "def w(a):\n    return a\ng = (w(v) for v in [1])\nfrom slamlib import w\n"
     "def f(x):\n    return next(g)\n", "calls `g`, which uses `w` (from slamlib"),
    # the name of an except clause is unbound when it ends: the star import is what the function may find
    ("except-as-unbound-after", "from slamlib import *\ntry:\n    pass\nexcept Exception as w:\n    pass\n"
     "def f(x):\n    return w(x)\n", "can only come from from slamlib import *"),
]


@pytest.mark.parametrize("src, why", [s[1:] for s in SCOPES], ids=[s[0] for s in SCOPES])
def test_a_name_is_the_modules_exactly_where_python_finds_it_there(src, why):
    """A name bound anywhere in a function counted as local to all of it (a comprehension's variable, a nested
    def's local, a class body's name hid a real use of the module's `w`), and the names of ``except ... as`` and
    of ``match`` captures were taken for the module's (a correct function scored 0). Names are now resolved by
    Python's scoping rules."""
    compile(src, "s.py", "exec")  # valid Python
    found = _static(src).get("f")
    assert (found is None) == (why is None) and (why is None or why in found), found


#: code whose module-level names, as symtable resolves them, the static check must find (each a scope shape)
RESOLVED = [
    "def f(x):\n    w = 1\n    class A:\n        y = w\n        w = 2\n        def m(self):\n            return w + z\n"
    "        z = 3\n    return A\n",
    "def f(x):\n    w = 1\n    class A:\n        global w\n        y = w\n        def m(self):\n            return w\n"
    "    return A\n",
    "def f(x):\n    w = 1\n    class A:\n        nonlocal w\n        y = w\n    return A\n",
    "def f(x):\n    global w\n    def g():\n        return w\n    def h():\n        w = 2\n        def k():\n"
    "            return w\n        return k\n    return g, h\n",
    "def f(x):\n    global w\n    _ = [(w := v) for v in x]\n    return w\n",
    "def f(x):\n    _ = [[(w := v) for v in u] for u in x]\n    return w\n",
    "def f(x, w=w, *a, k: w = w, **kw) -> w:\n    return x\n",
    "@w\ndef f(x):\n    return (lambda w=w: w)(x)\n",
    "def f(x):\n    (w): int\n    return w\n",
    "def f(x):\n    w: int\n    return w\n",
    "def f(x):\n    del w\n    return w\n",
    "def f(x):\n    import w.v\n    from u import a as w2\n    return w, w2, v\n",
    "def f(x):\n    w += 1\n    return x\n",
    "def f(x):\n    return {w: v for w, v in x}, {w for w in w}, (w for w in w), w\n",
    "class A(w, metaclass=m):\n    def g(self, a=w):\n        return w\n    w = 1\n    v = [w for _ in w]\n",
    "def f(x):\n    async def g():\n        return [w async for w in x]\n    return w\n",
    "def f(x):\n    try:\n        pass\n    except* E as w:\n        pass\n    return w\n",
    "def f(x):\n    def g():\n        global w\n        w = 1\n    return w\n",
    "def f(x):\n    return [lambda: w for w in x], [lambda w=w: w for q in x]\n",
    "def f(x):\n    class A:\n        class B:\n            w = 1\n            def m(self):\n                return w\n"
    "        w = 2\n        y = w\n    return A\n",
]


def test_the_static_check_finds_the_module_level_names_symtable_finds():
    """The names a def loads from the module, as the static check finds them, are those Python's own symtable
    resolves to the module (in a class body, also those the body binds: looked up in the module when unbound)."""
    import ast
    import symtable

    from autograder.submission import _Facts

    wrong = []
    for src in [s[1] for s in SCOPES if s[1].startswith(W)] + RESOLVED:
        src = src.removeprefix(W)
        top = symtable.symtable(src, "s.py", "exec")
        expected = {s.get_name() for s in top.get_symbols() if s.is_referenced()}
        tables = list(top.get_children())
        while tables:
            t = tables.pop()
            tables.extend(t.get_children())
            expected |= {s.get_name() for s in t.get_symbols() if s.is_referenced() and (
                s.is_global() or (t.get_type() == "class" and s.is_local() and not s.is_free()))}
        found = set()
        for stmt in ast.parse(src).body:
            facts = _Facts(stmt)
            found |= facts.now | facts.later
        if found != expected:
            wrong.append(f"{src!r}: symtable {sorted(expected)}, found {sorted(found)}")
    assert not wrong, "\n".join(wrong)


@pytest.mark.parametrize("src", [
    "class C:\n    global helper\n    from slamlib import wrap_angle as helper\nmy_wrap = helper\n"
    "def f(x):\n    return my_wrap(x)\n",
    "def g():\n    global helper\n    from slamlib import wrap_angle as helper\ng()\nmy_wrap = helper\n"
    "def f(x):\n    return my_wrap(x)\n",
    "def g():\n    global helper\n    import slamlib as helper\ng()\ndef f(x, w=helper.wrap_angle):\n    return w(x)\n",
], ids=["class-body", "def-called", "default-value"])
def test_a_name_bound_through_global_while_the_module_loads_is_seen_by_what_loads_after(src):
    """A class body (which runs), or a def called at load, binding a module-level name through ``global`` was seen
    only by the functions' bodies, not by what the module looked up while loading after it (an assigned value, a
    default): the reference passed through ``my_wrap = helper`` got credit (round 10)."""
    found = _static(src).get("f")
    assert found is not None and "slamlib" in found, found


def test_the_static_check_costs_each_binding_once_over_a_grading(monkeypatch):
    """Every possible binding of a graded name walked the whole chain of helpers again: n bindings of it that lead
    to one chain of m helpers cost n * m steps (170 KB of code: 370 s in the grader's own process, before any
    budget). A walk that finds nothing proves what it met clean for every later walk."""
    from autograder import submission

    n = m = 300
    src = "def h0(x):\n    return x\n" + "".join(f"def h{i}(x):\n    return h{i - 1}(x)\n" for i in range(1, m))
    src += f"def f(x):\n    return x\n" + f"if 0:\n    f = h{m - 1}\n" * n
    steps = []
    real = submission._Execution.direct
    monkeypatch.setattr(submission._Execution, "direct", lambda self, b: (steps.append(1), real(self, b))[1])
    assert _static(src) == {}
    assert len(steps) <= 2 * (n + m + 1), len(steps)  # n * m = 90 000 before


@pytest.mark.parametrize("kind", ["elif", "match"])
def test_long_elif_chains_and_match_statements_are_walked_in_linear_time(kind, monkeypatch):
    """A module-level chain of 400 elifs made the static check recurse once per elif (RecursionError: a correct
    submission scored 0, "the autograder failed internally"); and merging the branches of a match of n cases that
    each bind a name of their own looked every name up in every case (n * n)."""
    from autograder import submission

    n = 900 if kind == "elif" else 3000  # Python itself compiles no more than about 1000 elifs
    if kind == "elif":
        src = "if c:\n    x0 = 0\n" + "".join(f"elif c:\n    x{i} = {i}\n" for i in range(1, n))
    else:
        src = "match c:\n" + "".join(f"    case [x{i}]:\n        pass\n" for i in range(n))
    src += "from slamlib import wrap_angle as x7\nx8 = x7\ndef f(x):\n    return x + x5 + x8(x)\n"
    looks = []
    real = submission._Scope.get
    monkeypatch.setattr(submission._Scope, "get", lambda self, name: (looks.append(1), real(self, name))[1])
    found = _static(src).get("f")
    assert found is not None and "x7" in found, found
    assert len(looks) <= 20 * n, len(looks)


def test_a_docstring_that_names_the_reference_is_not_a_dynamic_import(tmp_path):
    """Any string starting with "slamlib." was taken for a dynamic import: the docstring "slamlib.effective_sample_size,
    written again with NumPy only." zeroed a correct function. Docstrings never count, and other strings only when
    they are a dotted module name of slamlib or the autograder; a real dynamic import by name still costs it."""
    doc = '    """slamlib.effective_sample_size, written again with NumPy only."""\n'
    text = solution_text("particle_filter").replace("def effective_sample_size(w):\n",
                                                    "def effective_sample_size(w):\n" + doc)
    assert doc in text
    path = tmp_path / "docstring.py"
    path.write_text(text)
    result = grade(path, "particle_filter", limits=limits(), functions=[OTHER])
    assert result.by_function()[OTHER] == (15.0, 15.0), result.text_report()
    # a string that is the name of a module of slamlib is a dynamic import, wherever it is used
    body = (f"def {OTHER}(w):\n    import importlib\n    ref = importlib.import_module('slamlib.particle')\n"
            f"    return ref.{OTHER}(w)\n")
    scores, out, _ = _grade_variant(tmp_path, body, function=OTHER, name="dynamic.py")
    assert scores[OTHER][0] == 0 and "No credit" in out and "a dynamic import" in out, out
    code = "def f(w, n='x'):\n    import importlib, sys\n    return {}\n"
    for call in ("importlib.import_module('slamlib')", "__import__(' slamlib.fastslam ')", "sys.modules['autograder']",
                 "getattr(importlib.import_module('slamlib'), n)", "importlib.import_module('slamlib.' + n)"):
        assert "a dynamic import" in _static(code.format(call)).get("f", ""), call
    # a docstring, or prose that mentions one, is not
    assert _static('def f(w):\n    """slamlib.particle"""\n    return w\n') == {}
    for prose in ("see slamlib.particle, the reference", "slamlib is the reference", "slamlib.f, again"):
        assert _static(f"def f(w):\n    x = {prose!r}\n    return w\n") == {}, prose
