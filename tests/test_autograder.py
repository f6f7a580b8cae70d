"""The autograder end to end: reference and independent solutions, stubs, results.json, CLI, batch, bundle."""

from __future__ import annotations

import ast
import csv
import json
import os
import subprocess
import sys
import zipfile
from functools import lru_cache
from pathlib import Path

import nbformat
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent / "autograder_fixtures"))

from agtest import EXERCISE_NAMES, NOTEBOOKS, ROOT, gradescope_json_ok, solution, solution_text  # noqa: E402
from reference_submission import write_reference_submission  # noqa: E402

from autograder.engine import grade  # noqa: E402
from autograder.exercises import all_exercises, get_exercise  # noqa: E402
from autograder.sandbox import Limits  # noqa: E402

PY = sys.executable
EXERCISES_DIR = ROOT / "exercises"


@pytest.fixture(autouse=True)
def _secret(tmp_path_factory, monkeypatch):
    """Grading secrets of the test run live in a temporary folder, not in the user's config."""
    monkeypatch.setenv("AUTOGRADER_SECRET_FILE", str(tmp_path_factory.getbasetemp() / "grading_secret"))


@lru_cache(maxsize=None)
def _graded_solution(exercise):
    return grade(solution(exercise), exercise)


# --------------------------------------------------------------------------- exercise declarations
def test_exercises_are_well_formed():
    for ex in all_exercises():
        assert ex.max_score() == pytest.approx(100.0), ex.name
        names = [t.name for t in ex.tests]
        assert len(names) == len(set(names))
        for fn in ex.functions:
            tests = ex.tests_for(fn)
            assert tests, f"{fn} has no tests"
            assert any(t.visibility == "public" for t in tests), f"{fn} has no public test"
            assert all(t.name.startswith(f"{fn}: ") for t in tests)
            assert all(t.hint and t.timeout > 0 and t.weight > 0 for t in tests)
        assert ex.notebook == NOTEBOOKS[ex.name]


# --------------------------------------------------------------------------- full marks and zero
@pytest.mark.slow
@pytest.mark.parametrize("exercise", EXERCISE_NAMES)
def test_slamlib_as_a_submission_scores_full_marks(exercise, tmp_path):
    path = write_reference_submission(get_exercise(exercise), tmp_path / f"{exercise}.py")
    tree = ast.parse(path.read_text())
    imported = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    imported |= {n.module.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
    assert imported <= {"sys", "types"}  # the embedded slamlib sources import only numpy and scipy
    result = grade(path, exercise)
    failed = {t.name: t.output for t in result.tests if t.status != "passed"}
    assert not failed, failed
    assert result.score == result.max_score == 100.0


@pytest.mark.slow
@pytest.mark.parametrize("exercise", EXERCISE_NAMES)
def test_independent_solution_scores_full_marks(exercise):
    result = _graded_solution(exercise)
    failed = {t.name: t.output for t in result.tests if t.status != "passed"}
    assert not failed, failed
    assert result.score == 100.0
    gradescope_json_ok(result.to_gradescope())


@pytest.mark.slow
@pytest.mark.parametrize("exercise", EXERCISE_NAMES)
def test_stub_notebook_scores_zero_without_grader_error(exercise):
    result = grade(EXERCISES_DIR / NOTEBOOKS[exercise])  # the exercise comes from the notebook's metadata
    assert result.exercise == exercise
    assert result.score == 0.0
    assert result.max_score == 100.0
    assert result.error is None
    for t in result.tests:
        assert "grader could not complete" not in t.output, t.output
        assert "NotImplementedError" in t.output or "not run" in t.output, t.output
    gradescope_json_ok(result.to_gradescope())


def test_results_are_deterministic():
    first = _graded_solution("particle_filter").to_gradescope()
    second = grade(solution("particle_filter"), "particle_filter").to_gradescope()
    first.pop("execution_time")
    second.pop("execution_time")
    # the sandbox's uid differs between gradings; the scenarios (seed) and every result do not
    assert first.pop("extra_data")["seed"] == second.pop("extra_data")["seed"]
    assert first == second


def test_every_test_keeps_its_max_score(tmp_path):
    """Whatever happens to a submission, the list of tests and their max_score stay the same."""
    ex = get_exercise("ekf_localization")
    want = [(t.name, t.weight) for t in ex.tests]
    broken = tmp_path / "broken.py"
    broken.write_text("def ekf_predict(mu, Sigma, u, dt, M):\n    return 'garbage'\n")
    garbage = tmp_path / "garbage.ipynb"
    garbage.write_text("this is not a notebook")
    syntax = tmp_path / "syntax.py"
    syntax.write_text("def ekf_predict(:\n")
    for path in (broken, garbage, syntax, solution("ekf_localization")):
        result = grade(path, "ekf_localization", limits=Limits(call_timeout=3.0))
        assert [(t.name, t.max_score) for t in result.tests] == want
        gradescope_json_ok(result.to_gradescope())


# --------------------------------------------------------------------------- malformed submissions
def _one_message(result):
    msgs = {t.output for t in result.tests}
    assert len(msgs) == 1
    return msgs.pop()


def test_malformed_submissions_get_zero_and_a_clear_message(tmp_path):
    cases = {
        "not_a_notebook.ipynb": ("{not json", "not a Jupyter notebook"),
        "no_cells.ipynb": (json.dumps({"metadata": {}}), "not a Jupyter notebook"),
        "empty.py": ("", "contains no code"),
        "answer.txt": ("def f(): pass", "unsupported file type"),
    }
    for name, (content, message) in cases.items():
        path = tmp_path / name
        path.write_text(content)
        result = grade(path, "particle_filter")
        assert result.score == 0 and len(result.tests) == len(get_exercise("particle_filter").tests)
        assert message in _one_message(result), name
        gradescope_json_ok(result.to_gradescope())


def test_syntax_error_and_missing_functions(tmp_path):
    path = tmp_path / "s.py"
    path.write_text("import numpy as np\n\ndef normalize_log_weights(log_w)\n    return log_w\n")
    result = grade(path, "particle_filter")
    assert result.score == 0
    assert any("syntax error at line 3" in n for n in result.notes)
    assert all("is not defined in your submission" in t.output for t in result.tests)
    # a notebook: only the broken cell is lost
    nb = nbformat.v4.new_notebook(cells=[
        nbformat.v4.new_code_cell(solution_text("particle_filter")),
        nbformat.v4.new_code_cell("def broken(:\n    pass"),
    ])
    nbp = tmp_path / "n.ipynb"
    nbformat.write(nb, nbp)
    result = grade(nbp, "particle_filter")
    assert result.score == 100
    assert any("code cell 2: syntax error" in n for n in result.notes)


def test_wrong_exercise_notebook(tmp_path):
    result = grade(EXERCISES_DIR / NOTEBOOKS["fastslam"], "particle_filter")
    assert result.score == 0
    assert "exercise 'fastslam'" in result.error and "03_particle_filter.ipynb" in result.error
    assert len(result.tests) == len(get_exercise("particle_filter").tests)


def test_unknown_exercise_without_metadata(tmp_path):
    path = tmp_path / "x.py"
    path.write_text("x = 1\n")
    result = grade(path)
    assert result.exercise is None and "Cannot tell which exercise" in result.error
    gradescope_json_ok(result.to_gradescope())


def test_magics_skip_tags_and_main_guard(tmp_path):
    sol = solution_text("particle_filter")
    nb = nbformat.v4.new_notebook(cells=[
        nbformat.v4.new_code_cell("%matplotlib inline\n!pip install nothing\nimport numpy as np"),
        nbformat.v4.new_code_cell("%%time\nraise SystemExit"),
        nbformat.v4.new_code_cell(sol),
        nbformat.v4.new_code_cell("def normalize_log_weights(log_w):\n    return None", metadata={"tags": ["skip-grading"]}),
        nbformat.v4.new_code_cell("if __name__ == '__main__':\n    def effective_sample_size(w):\n        return None"),
        nbformat.v4.new_code_cell("for i in range(3):\n    if True:\n        %time x = 1"),
    ])
    nb.metadata["slam_course"] = {"exercise": "particle_filter"}
    path = tmp_path / "magic.ipynb"
    nbformat.write(nb, path)
    result = grade(path)
    assert result.score == 100, result.text_report()
    notes = "\n".join(result.notes)
    assert "code cell 1: 2 IPython magic/shell lines left out" in notes
    assert "code cell 2: cell magic %%time" in notes
    assert "code cell 6: 1 IPython magic/shell line left out" in notes


# --------------------------------------------------------------------------- command line
def _run(args, **kw):
    return subprocess.run([PY, "-m", "autograder", *args], capture_output=True, text=True, cwd=ROOT, **kw)


@pytest.mark.slow
def test_cli_grade(tmp_path):
    res = tmp_path / "out" / "results.json"
    p = _run(["grade", str(EXERCISES_DIR / NOTEBOOKS["fastslam"]), "--results", str(res)])
    assert p.returncode == 0, p.stderr
    data = gradescope_json_ok(json.loads(res.read_text()))
    assert data["score"] == 0 and len(data["tests"]) == len(get_exercise("fastslam").tests)
    assert all(t["name"].split(":")[0] in get_exercise("fastslam").functions for t in data["tests"])
    assert "fastslam_update_landmark: updated means" in p.stdout and "Total: 0 / 100" in p.stdout
    # grading completed with a low score: still exit 0; an unknown exercise: exit 2 and a valid results.json
    p = _run(["grade", str(solution("fastslam")), "--exercise", "nope", "--results", str(res)])
    assert p.returncode == 2
    gradescope_json_ok(json.loads(res.read_text()))


def test_cli_list():
    p = _run(["list"])
    assert p.returncode == 0
    for name in EXERCISE_NAMES:
        assert name in p.stdout


# --------------------------------------------------------------------------- batch and bundle
@pytest.mark.slow
def test_batch(tmp_path):
    subs = tmp_path / "subs"
    subs.mkdir()
    (subs / "alice.py").write_text(solution_text("particle_filter"))
    (subs / "bob.ipynb").write_bytes((EXERCISES_DIR / NOTEBOOKS["particle_filter"]).read_bytes())
    (subs / "carol").mkdir()
    (subs / "carol" / NOTEBOOKS["particle_filter"]).write_text(
        nbformat.writes(nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(solution_text("particle_filter"))])))
    (subs / "dave").mkdir()
    (subs / "dave" / "notes.txt").write_text("forgot the notebook")
    out = tmp_path / "grades.csv"
    p = _run(["batch", str(subs), "--exercise", "particle_filter", "--out", str(out), "--jobs", "2"])
    assert p.returncode == 0, p.stderr
    assert "grading particle_filter" in p.stderr  # the progress bar
    rows = {r["submission"]: r for r in csv.DictReader(out.open())}
    assert set(rows) == {"alice", "bob", "carol", "dave"}
    assert float(rows["alice"]["score"]) == 100 and float(rows["carol"]["score"]) == 100
    assert float(rows["bob"]["score"]) == 0 and float(rows["dave"]["score"]) == 0
    assert rows["dave"]["status"] == "error" and "no .ipynb or .py" in rows["dave"]["message"]
    for fn in get_exercise("particle_filter").functions:
        assert fn in rows["alice"]
    assert float(rows["alice"]["low_variance_resample"]) == 35
    for sid in rows:
        gradescope_json_ok(json.loads((tmp_path / "grades_results" / f"{sid}.json").read_text()))


@pytest.mark.slow
def test_batch_rerun_keeps_graded_rows_and_grades_the_graders_failures_again(tmp_path):
    """A rerun skips a submission whose results JSON matches its content, except where the grader itself failed on
    it ("grader-error"): that was no grade, so it is graded again."""
    from autograder.batch import _fingerprint, _settings
    from autograder.results import fallback_results, write_json_atomic
    from autograder.seeds import derive_seed, load_secret

    subs = tmp_path / "subs"
    subs.mkdir()
    ex = get_exercise("particle_filter")
    results = tmp_path / "grades_results"
    results.mkdir()
    for sid, status, score in (("alice", "grader-error", 0.0), ("bob", "ok", 42.0)):
        path = subs / f"{sid}.py"
        path.write_text(solution_text("particle_filter"))
        row = {"submission": sid, "file": str(path), "score": score, "max_score": ex.max_score(), "status": status,
               "message": "OSError: [Errno 9] Bad file descriptor" if status != "ok" else ""}
        fp = _fingerprint(path, None)  # what a grading with this run's secret and default limits records
        write_json_atomic(results / f"{sid}.json", {**fallback_results("earlier run"), "extra_data": {
            "exercise": "particle_filter", "submission_sha256": fp, "batch_row": row,
            "seed": derive_seed(load_secret(), "particle_filter", fp), "batch_settings": _settings(None)}})
    out = tmp_path / "grades.csv"
    p = _run(["batch", str(subs), "--exercise", "particle_filter", "--out", str(out), "--jobs", "1", "--quiet"])
    assert p.returncode == 0, p.stderr
    rows = {r["submission"]: r for r in csv.DictReader(out.open())}
    assert float(rows["alice"]["score"]) == 100 and rows["alice"]["status"] == "ok", rows["alice"]
    assert float(rows["bob"]["score"]) == 42, rows["bob"]  # kept: graded before, same content


@pytest.mark.slow
def test_gradescope_bundle_runs(tmp_path):
    zpath = tmp_path / "autograder.zip"
    p = _run(["bundle", "--exercise", "ekf_localization", "-o", str(zpath)])
    assert p.returncode == 0, p.stderr
    with zipfile.ZipFile(zpath) as zf:
        names = zf.namelist()
        assert {"setup.sh", "run_autograder", "requirements.txt", "grading_secret"} <= set(names)
        reqs = zf.read("requirements.txt").decode().split()
        assert all("==" in r for r in reqs) and not any(r.startswith(("matplotlib", "ipywidgets")) for r in reqs)
        assert "--only-binary=:all:" in zf.read("setup.sh").decode()
        assert len(zf.read("grading_secret").strip()) == 64
        wheel = [n for n in names if n.startswith("wheels/") and n.endswith(".whl")]
        assert len(wheel) == 1
        assert (zf.getinfo("run_autograder").external_attr >> 16) & 0o111
        root = tmp_path / "gs"
        (root / "source").mkdir(parents=True)
        zf.extractall(root / "source")
        with zipfile.ZipFile(root / "source" / wheel[0]) as whl:
            wn = whl.namelist()
            assert "autograder/_runner.py" in wn and "slamlib/gaussian.py" in wn
            assert "autograder/wire.py" in wn  # the child's script loads it from its own folder
            assert any(n.endswith(".dist-info/RECORD") for n in wn)
    (root / "submission").mkdir()
    (root / "results").mkdir()
    env = {**os.environ, "AUTOGRADER_ROOT": str(root), "AUTOGRADER_PYTHON": PY}
    # nothing submitted: a valid results.json with every test at 0
    p = subprocess.run(["bash", str(root / "source" / "run_autograder")], env=env, capture_output=True, text=True)
    assert p.returncode == 0
    data = gradescope_json_ok(json.loads((root / "results" / "results.json").read_text()))
    assert data["score"] == 0 and len(data["tests"]) == len(get_exercise("ekf_localization").tests)
    # a real submission, in a sub-folder as uploaded
    (root / "submission" / "hw").mkdir()
    (root / "submission" / "hw" / NOTEBOOKS["ekf_localization"]).write_text(
        nbformat.writes(nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(solution_text("ekf_localization"))])))
    p = subprocess.run(["bash", str(root / "source" / "run_autograder")], env=env, capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    data = gradescope_json_ok(json.loads((root / "results" / "results.json").read_text()))
    assert data["score"] == 100
    # the grader cannot start at all: no results.json is made up (Gradescope reports the autograder's failure, which
    # is the staff's to fix, not a score of 0 for the student)
    os.remove(root / "results" / "results.json")
    env["AUTOGRADER_PYTHON"] = "/bin/false"
    p = subprocess.run(["bash", str(root / "source" / "run_autograder")], env=env, capture_output=True, text=True)
    assert p.returncode != 0 and not (root / "results" / "results.json").exists()


# --------------------------------------------------------------------------- the student's self-check
def test_selfcheck_runs_public_tests_in_process(capsys):
    from autograder.selfcheck import run_public_tests

    ns = {}
    exec(compile(solution_text("ekf_slam"), "solution", "exec"), ns)
    report = run_public_tests("ekf_slam", ns)
    assert report.all_passed and report.results
    assert all(r.visibility == "visible" for r in report.results)
    out = capsys.readouterr().out
    assert "PASS  ekf_slam_update: mean and covariance on random beliefs" in out
    nb = nbformat.read(EXERCISES_DIR / NOTEBOOKS["ekf_slam"], as_version=4)
    stub_ns = {}
    for cell in nb.cells:
        if cell.cell_type == "code" and "skip-grading" not in cell.metadata.get("tags", []):
            exec(cell.source, stub_ns)
    report = run_public_tests("ekf_slam", stub_ns)
    assert report.score == 0 and "not implemented yet" in capsys.readouterr().out
