"""What the grader does in its own process with a submission's data.

The sandbox bounds what a submission's code can do; these tests bound what the grader itself does
with what the submission gives it, outside every sandbox limit: the text the submission chose (an
exception's message, a file name it set on its code) printed and written, the static check of its
code, the size of the code the grader parses, the notes it keeps, the files a batch folder holds,
and the modules the grader imports when it is started in a folder of students' files.
"""

from __future__ import annotations

import ast
import dataclasses
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent / "autograder_fixtures"))

from agtest import gradescope_json_ok, replace_function, solution_text  # noqa: E402

import autograder  # noqa: E402
from autograder.engine import grade  # noqa: E402
from autograder.results import write_json_atomic  # noqa: E402
from autograder.sandbox import Limits  # noqa: E402

TARGET = "normalize_log_weights"
OTHER = "effective_sample_size"
AG_ROOT = Path(autograder.__file__).resolve().parents[1]  # the checkout whose grader is under test


@pytest.fixture(autouse=True)
def _secret(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("AUTOGRADER_SECRET_FILE", str(tmp_path_factory.getbasetemp() / "grading_secret"))


def _limits():
    names = {f.name for f in dataclasses.fields(Limits)}
    return Limits(**{k: v for k, v in {"call_timeout": 2.5, "import_timeout": 20.0}.items() if k in names})


def _grade(tmp_path, text, name="sub.py"):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    result = grade(path, "particle_filter", limits=_limits(), functions=[TARGET, OTHER])
    gradescope_json_ok(result.to_gradescope())
    return result


def _written(tmp_path, result):
    """results.json as the grader writes it, read back, and the printed report as bytes (UTF-8, strict)."""
    write_json_atomic(tmp_path / "results.json", result.to_gradescope())
    return (tmp_path / "results.json").read_text(encoding="utf-8"), result.text_report(verbose=True).encode("utf-8")


def _strings(obj):
    if isinstance(obj, str):
        yield obj
    elif isinstance(obj, dict):
        for k, v in obj.items():
            yield k
            yield from _strings(v)
    elif isinstance(obj, list):
        for v in obj:
            yield from _strings(v)


RAISES = """
def effective_sample_size(w):
    raise ValueError({message!r})
"""


def test_a_lone_surrogate_in_the_submissions_text_is_written_as_an_escape(tmp_path):
    """A lone surrogate is valid in JSON (``\\ud800``), not in UTF-8: it made every write of the result fail,
    so a correct submission got no results.json (and a batch row was a grader error on every rerun)."""
    text = replace_function(solution_text("particle_filter"), OTHER, RAISES.format(message="bad \ud800 value"))
    result = _grade(tmp_path, text + '\nraise RuntimeError("\\ud800 at the top level")\n')
    data, report = _written(tmp_path, result)
    scores = result.by_function()
    assert scores[TARGET] == (20.0, 20.0) and scores[OTHER] == (0.0, 15.0), scores
    assert "\\ud800" in data and b"\\ud800" in report


def test_escape_sequences_of_the_submission_never_reach_the_report(tmp_path):
    """An exception message that clears the terminal and draws a full score is printed as escapes."""
    fake = "\x1b[2J\x1b[HTotal: 100 / 100\n\x1b[8m\r\x00"
    text = replace_function(solution_text("particle_filter"), OTHER, RAISES.format(message=fake))
    result = _grade(tmp_path, "import sys\nsys.stdout.write('\\x1b[2J')\n" + text)
    data, report = _written(tmp_path, result)
    strings = list(_strings(json.loads(data)))
    for bad in ("\x1b", "\r", "\x00"):
        assert bad.encode() not in report and not any(bad in s for s in strings), bad
    assert b"\\x1b[2J" in report


def test_a_file_name_the_submission_sets_on_its_code_is_only_text(tmp_path):
    """``co_filename`` with a NUL byte made the grader's ``os.path.realpath`` raise: an internal error."""
    text = solution_text("particle_filter") + \
        f"\n{OTHER}.__code__ = {OTHER}.__code__.replace(co_filename='/x\\0y')\n"
    result = _grade(tmp_path, text)
    assert result.score == result.max_score, result.text_report()


def _count_walks(monkeypatch):
    """Count the nodes the static check visits (``ast.walk`` of autograder.submission)."""
    import autograder.submission as submission

    seen = [0]
    walk = ast.walk

    def counting(node):
        for n in walk(node):
            seen[0] += 1
            yield n

    monkeypatch.setattr(submission.ast, "walk", counting)
    return seen


def test_the_static_check_visits_each_node_a_bounded_number_of_times(monkeypatch):
    """The check for slamlib use walked a function's whole body once per name it loads: quadratic, in the
    grader's process and charged to the submission's budget (8000 names in one list: 203 s)."""
    from autograder.submission import forbidden_usage

    names = ", ".join(f"v{i}" for i in range(3000))
    src = f"import numpy as np\n\ndef {OTHER}(w):\n    if False:\n        return [{names}]\n    return 1.0\n"
    nodes = sum(1 for _ in ast.walk(ast.parse(src)))
    seen = _count_walks(monkeypatch)
    assert forbidden_usage([{"source": src, "filename": "sub.py", "label": "sub.py"}], [OTHER]) == {}
    assert seen[0] <= 4 * nodes, (seen[0], nodes)


def test_a_long_chain_of_helpers_is_followed_without_recursion():
    """A chain of a thousand module-level names made the check recurse past Python's limit (an internal error);
    followed iteratively, the chain is clean, or it names the import at its end."""
    from autograder.submission import forbidden_usage

    chain = "\n".join(f"K{i} = K{i - 1}" for i in range(1, 1500))
    fn = f"def {OTHER}(w):\n    return K1499\n"
    clean = f"K0 = 1.0\n{chain}\n{fn}"
    tainted = f"import slamlib\nK0 = slamlib.effective_sample_size\n{chain}\n{fn}"
    unit = {"filename": "sub.py", "label": "sub.py"}
    assert forbidden_usage([{**unit, "source": clean}], [OTHER]) == {}
    why = forbidden_usage([{**unit, "source": tainted}], [OTHER])[OTHER]
    assert why.startswith(f"{OTHER} calls `K1499`, which calls `K1498`") and "import slamlib" in why, why[-200:]
    # a message, not a trace: the chain of 1500 names is told in its first and last steps (it was 30 KB in every
    # test's output of the function)
    assert len(why) < 400 and "more)" in why, why


def test_code_beyond_the_size_the_grader_parses_is_refused_by_name(tmp_path):
    """Python's parser holds hundreds of bytes per character of some code, in the grader's own process (a 3 MB
    file took 2.2 GB): code above MAX_CODE is refused before it is parsed."""
    from autograder.submission import MAX_CODE, SubmissionError, load_submission

    path = tmp_path / "big.py"
    path.write_text("if False:\n    _ = [" + "a," * (MAX_CODE // 2) + "]\n")
    with pytest.raises(SubmissionError, match="KB of code"):
        load_submission(path)
    result = grade(path, "particle_filter", limits=_limits(), functions=[TARGET])
    assert result.score == 0 and "KB of code" in result.error


def test_notes_on_broken_cells_are_capped(tmp_path):
    """A notebook of many unreadable cells made every test's message repeat the whole list: results.json of 20 MB
    from a notebook of 1.7 MB."""
    import nbformat

    from autograder.engine import MAX_NOTES

    cells = [nbformat.v4.new_code_cell("(") for _ in range(300)] + [nbformat.v4.new_code_cell("import numpy as np")]
    nb = nbformat.v4.new_notebook(cells=cells)
    path = tmp_path / "nb.ipynb"
    nbformat.write(nb, str(path))
    result = grade(path, "particle_filter", limits=_limits(), functions=[TARGET, OTHER])
    assert len(result.notes) <= 2 * (MAX_NOTES + 1), len(result.notes)
    assert all(len(t.output) < 2000 for t in result.tests), max(len(t.output) for t in result.tests)
    assert len(json.dumps(result.to_gradescope())) < 50_000


def test_an_entry_that_is_not_a_regular_file_is_its_own_row(tmp_path):
    """A FIFO named like a submission got no row at all; inside a folder, a misleading "no file" message."""
    from autograder.batch import find_submissions

    (tmp_path / "alice.py").write_text(solution_text("particle_filter"))
    os.mkfifo(tmp_path / "bob.py")
    (tmp_path / "carol").mkdir()
    os.mkfifo(tmp_path / "carol" / "03_particle_filter.ipynb")
    got = {sid: (path, why) for sid, path, why in find_submissions(tmp_path)}
    assert set(got) == {"alice", "bob", "carol"}, got
    assert got["alice"][1] is None
    for sid in ("bob", "carol"):
        assert got[sid][0] is None and "not a regular file" in got[sid][1], got[sid]


def test_the_grader_never_imports_from_a_folder_of_students_files(tmp_path):
    """``python -m`` puts the working directory first on ``sys.path``: started in a folder holding a student's
    ``numpy.py``, the grader imported it in its own process (and a forged score with it)."""
    marker = tmp_path / "imported"
    (tmp_path / "numpy.py").write_text(f"open({str(marker)!r}, 'w').close()\nraise ImportError('a student file')\n")
    env = {**os.environ, "PYTHONPATH": str(AG_ROOT)}
    p = subprocess.run([sys.executable, "-m", "autograder", "list"], capture_output=True, text=True, cwd=str(tmp_path),
                       env=env, timeout=120)
    assert not marker.exists(), p.stderr[-2000:]
    assert p.returncode == 0 and "particle_filter" in p.stdout, p.stderr[-2000:]


def test_the_grader_still_runs_from_its_own_checkout():
    """The working directory stays on the path when it is the folder that holds the grader (no install)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    p = subprocess.run([sys.executable, "-m", "autograder", "list"], capture_output=True, text=True,
                       cwd=str(AG_ROOT), env=env, timeout=120)
    assert p.returncode == 0 and "particle_filter" in p.stdout, p.stderr[-2000:]


def test_the_instructors_page_states_the_caps():
    """The page's figures are the grader's constants."""
    from autograder.engine import MAX_NOTES
    from autograder.submission import MAX_CODE

    page = " ".join((AG_ROOT / "chapters" / "instructors.md").read_text().split())
    assert f"reads at most {MAX_CODE // 1024} KB of code" in page
    assert f"At most {MAX_NOTES} notes on the submission's cells, and {MAX_NOTES} from loading" in page
    from autograder.submission import MAX_JSON_CONTAINERS

    assert f"more than {MAX_JSON_CONTAINERS:,} JSON objects".replace(",", " ") in page


def test_the_instructors_page_states_the_waiting_and_the_own_noise_figures():
    """The page's figures for a loaded machine's waiting and for the hidden own-noise test are the grader's."""
    from autograder.exercises.motion_sensor_models import OWN_NOISE_POSES
    from autograder.sandbox import LATE, MAX_STRETCH
    from autograder.stats import REPEATED_NOISE_TOL, repeated_noise_false_alarm

    words = {2: "two", 3: "three", 4: "four", 5: "five"}
    page = " ".join((AG_ROOT / "chapters" / "instructors.md").read_text().split())
    assert MAX_STRETCH == int(MAX_STRETCH)
    times = words[int(MAX_STRETCH)]
    assert f"stretch by that waiting, up to {times} times the limit more" in page
    assert f"at most {times} times the submission's budget over a grading" in page
    assert f"takes at most {words[int(MAX_STRETCH) + 1]} times its budget" in page
    assert f"the grader comes back to a clock more than {LATE:g} s later than it asked to" in page
    assert "the loadings' as the calls'" in page
    assert f"up to {times} times the limit of the call under way, {times} times the submission's budget" in page
    exponent = round(math.log10(REPEATED_NOISE_TOL))
    assert REPEATED_NOISE_TOL == 10.0**exponent
    bound = repeated_noise_false_alarm(OWN_NOISE_POSES, REPEATED_NOISE_TOL)
    assert bound < 1e-13
    assert (f"a correct sampler's {OWN_NOISE_POSES:,} poses hold such a pair, to $10^{{{exponent}}}$, with "
            f"probability below $10^{{-13}}$").replace(",", " ", 1) in page


# --------------------------------------------------------------------------- the environment's failures are the grader's
def test_mapped_files_with_non_ascii_names_and_spaces_in_the_c_locale(tmp_path):
    """``/proc/self/maps`` was read as text in the locale's encoding: a grader installed under ``/opt/pé th`` and
    started with ``LC_ALL=C PYTHONUTF8=0`` stopped every command, the self-check included (UnicodeDecodeError);
    and a mapped path with a space was cut at it. The files are read as bytes and named as the file system does."""
    lib = tmp_path / "pé th" / "libpython3-fake.so"
    lib.parent.mkdir()
    lib.write_bytes(b"\0" * 4096)
    code = (
        "import mmap, os, sys\n"
        "from autograder import sandbox\n"
        "path = os.fsdecode(sys.argv[1].encode('utf-8', 'surrogateescape'))\n"
        "fd = os.open(path, os.O_RDONLY); m = mmap.mmap(fd, 4096, prot=mmap.PROT_READ)\n"
        "assert path in sandbox._mapped_files(), sandbox._mapped_files()\n"
        "spec = dict(sandbox.fs_spec(sandbox.Limits()))\n"
        "assert os.path.realpath(path) in spec['python'], spec['python']\n"
        "print(sys.getfilesystemencoding())\n")
    env = {**os.environ, "LC_ALL": "C", "LANG": "C", "PYTHONUTF8": "0", "PYTHONPATH": str(AG_ROOT)}
    out = subprocess.run([sys.executable, "-c", code, str(lib)], env=env, capture_output=True, text=True,
                         errors="replace", timeout=60)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "ascii"  # the locale the failure needs


def _run_autograder_script(tmp_path, python_body, root="gs"):
    """Gradescope's ``run_autograder`` of a bundle, with a stand-in for the grader's Python (``python_body``)."""
    from autograder.bundle import RUN_AUTOGRADER

    script = tmp_path / "run_autograder"
    script.write_text(RUN_AUTOGRADER.replace("@EXERCISE@", "particle_filter"))
    fake = tmp_path / "fakepython"
    fake.write_text("#!/bin/sh\n" + python_body)
    fake.chmod(0o755)
    (tmp_path / root / "submission").mkdir(parents=True)  # root: relative to tmp_path, or absolute
    env = {**os.environ, "AUTOGRADER_ROOT": root, "AUTOGRADER_PYTHON": str(fake)}
    subprocess.run(["bash", str(script)], cwd=str(tmp_path), env=env, timeout=60)
    return tmp_path / root / "results" / "results.json"


def test_a_grader_that_declines_leaves_no_score_on_gradescope(tmp_path):
    """The grader's self-check failed (exit 3, "nobody is charged"), and the bundle's script then wrote a results
    file scoring 0: the machine's fault became every student's zero."""
    results = _run_autograder_script(tmp_path, "exit 3\n", root=str(tmp_path / "gs"))
    assert not results.exists(), results.read_text()


def test_a_relative_gradescope_root_is_the_same_folder_after_the_script_enters_it(tmp_path):
    """The script entered the root and passed the relative root on: the grader looked for ROOT/ROOT/submission and
    told the student to submit the notebook."""
    results = _run_autograder_script(
        tmp_path, 'for a; do [ "$prev" = --root ] && root="$a"; prev="$a"; done\n'
                  'test -d "$root/submission" && echo "{}" > "$root/results/results.json"\n', root="gs root")
    assert results.exists()


def test_the_report_of_a_finished_grading_never_replaces_its_results(tmp_path):
    """Printing the report failed (a closed pipe, an ASCII-only stream) after results.json was written, and the
    fallback of a failed grading overwrote a score of 100 with 0."""
    import io

    from autograder.results import safe_print

    raw = io.BytesIO()
    ascii_out = io.TextIOWrapper(raw, encoding="ascii")
    safe_print("caf\u00e9 \x1b[2J done", file=ascii_out)
    assert raw.getvalue() == b"caf\\xe9 \\x1b[2J done\n"
    closed = io.StringIO()
    closed.close()
    safe_print("anything", file=closed)  # no exception

    root = tmp_path / "gs"
    (root / "submission").mkdir(parents=True)
    (root / "submission" / "particle_filter.py").write_text(
        solution_text("particle_filter") + "\nprint('caf\u00e9')\nraise RuntimeError('\u00e9t\u00e9')\n")
    env = {**os.environ, "PYTHONPATH": str(AG_ROOT), "PYTHONIOENCODING": "ascii"}
    p = subprocess.run([sys.executable, "-m", "autograder", "gradescope", "--root", str(root), "-e", "particle_filter"],
                       capture_output=True, cwd=str(tmp_path), env=env, timeout=300)
    data = json.loads((root / "results" / "results.json").read_text())
    assert p.returncode == 0 and data["score"] == 100, (p.stderr[-2000:], data.get("output"))


def test_limits_the_sandbox_cannot_set_stop_the_grading_before_anyone_is_graded(tmp_path):
    """Started under a lower hard limit (``ulimit -v``), the sandbox could not raise RLIMIT_AS to its 2 GiB: a correct
    submission that needs 1.5 GB scored 80, with the MemoryError shown as the student's."""
    from autograder.sandbox import failed_limits

    assert failed_limits({"rlimits": {"RLIMIT_AS": "failed: not allowed to raise maximum limit", "RLIMIT_CPU": 600}}) \
        == ["RLIMIT_AS: failed: not allowed to raise maximum limit"]
    code = ("import resource, runpy, sys\n"
            "resource.setrlimit(resource.RLIMIT_AS, (1536 << 20, 1536 << 20))\n"
            "sys.argv = ['autograder', 'selfcheck']\n"
            "runpy.run_module('autograder', run_name='__main__')\n")
    env = {**os.environ, "PYTHONPATH": str(AG_ROOT)}
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=str(tmp_path), env=env,
                       timeout=300)
    assert p.returncode == 3 and "could not set its resource limits" in p.stdout + p.stderr, p.stdout[-2000:]


def test_the_minimal_root_is_readable_whatever_the_graders_umask(tmp_path):
    """With umask 027 (or 077) the minimal root's folders were made unreadable for the sandbox's uid: every grading
    stopped at the self-check."""
    code = ("import os, runpy, sys\nos.umask(0o077)\nsys.argv = ['autograder', 'selfcheck']\n"
            "runpy.run_module('autograder', run_name='__main__')\n")
    env = {**os.environ, "PYTHONPATH": str(AG_ROOT)}
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=str(tmp_path), env=env,
                       timeout=300)
    assert p.returncode == 0 and "sandbox self-check: ok" in p.stdout, (p.stdout + p.stderr)[-2000:]


# --------------------------------------------------------------------------- the notebook reader's own costs
def _notebook(tmp_path, cells, **top):
    nb = {"cells": cells, "metadata": {}, "nbformat": 4, "nbformat_minor": 5, **top}
    path = tmp_path / "nb.ipynb"
    path.write_text(json.dumps(nb))
    return path


def _code(source, **extra):
    return {"cell_type": "code", "execution_count": None, "metadata": {}, "outputs": [], "source": source, **extra}


def test_outputs_never_reach_the_notebook_validator(tmp_path, monkeypatch):
    """nbformat validated every output in the grader's process: 33 000 invalid outputs in a 100 KB notebook took
    1.6 GB and 36 s. Outputs are not graded; they are dropped before nbformat reads the notebook."""
    import nbformat

    from autograder.submission import load_submission

    seen = []
    reads = nbformat.reads
    monkeypatch.setattr(nbformat, "reads", lambda text, *a, **k: (seen.append(text), reads(text, *a, **k))[1])
    path = _notebook(tmp_path, [_code(solution_text("particle_filter"), outputs=[{}] * 5000,
                                      attachments={"a.png": {"image/png": "x" * 100}})])
    sub = load_submission(path)
    assert len(sub.units) == 1 and len(seen) == 1
    cell = json.loads(seen[0])["cells"][0]
    assert cell["outputs"] == [] and "attachments" not in cell


def test_the_code_cap_comes_before_any_parse(tmp_path, monkeypatch):
    """A cell with one magic-looking line is parsed to find it: 3 MB of code in a notebook took 4.3 GB before the
    cap refused it."""
    import autograder.submission as submission

    calls = []
    parse = ast.parse
    monkeypatch.setattr(submission.ast, "parse", lambda *a, **k: (calls.append(1), parse(*a, **k))[1])
    big = "if False:\n    _ = [" + "a," * (submission.MAX_CODE // 2) + "]\n%time 1\n"
    with pytest.raises(submission.SubmissionError, match="KB of code"):
        submission.load_submission(_notebook(tmp_path, [_code(big)]))
    assert calls == []


def test_a_notebook_of_too_many_json_objects_is_refused_before_it_is_parsed(tmp_path):
    """Millions of tiny objects (``{}``) in metadata or outputs cost the grader ~190 bytes of memory per byte."""
    from autograder.submission import MAX_JSON_CONTAINERS, SubmissionError, load_submission

    path = _notebook(tmp_path, [_code(solution_text("particle_filter"))],
                     metadata={"pad": [{}] * (MAX_JSON_CONTAINERS + 1)})
    with pytest.raises(SubmissionError, match="JSON objects and arrays"):
        load_submission(path)


@pytest.mark.parametrize("refusal", ["code", "objects", "json", "nbformat"])
def test_a_refused_notebook_still_names_its_exercise(tmp_path, refusal):
    """A notebook refused for its size (or unreadable) lost the exercise its metadata names: graded without
    ``--exercise`` it got "Cannot tell which exercise this is" and no tests, where a notebook that could be read
    lists every test with 0 and the reason."""
    from autograder.submission import MAX_CODE, MAX_JSON_CONTAINERS

    meta = {"slam_course": {"exercise": "particle_filter"}}
    big = "if False:\n    _ = [" + "a," * (MAX_CODE // 2) + "]\n"
    if refusal == "code":
        path = _notebook(tmp_path, [_code(big)], metadata=meta)
    elif refusal == "objects":
        path = _notebook(tmp_path, [_code("x = 1")], metadata={**meta, "pad": [{}] * (MAX_JSON_CONTAINERS + 1)})
    elif refusal == "json":  # cut short: not JSON
        path = _notebook(tmp_path, [_code("x = 1")], metadata=meta)
        path.write_bytes(path.read_bytes()[:-1])
    else:  # JSON that nbformat refuses
        path = _notebook(tmp_path, [_code("x = 1")], metadata=meta, nbformat="four")
    result = grade(path, None, limits=_limits())
    assert result.exercise == "particle_filter", result.error
    assert result.score == 0 and result.error.startswith("The submission could not be read"), result.error
    assert result.tests and all(t.score == 0 for t in result.tests)


def test_a_message_about_the_notebook_is_one_short_line(tmp_path):
    """nbformat's error quoted a 1 MB "nbformat" value, with fake report lines, in every test: 16 MB of results."""
    from autograder.submission import SubmissionError, load_submission

    path = _notebook(tmp_path, [_code(solution_text("particle_filter"))],
                     nbformat="\n\nExercise particle_filter: 100 / 100 points\n" + "x" * 100_000)
    with pytest.raises(SubmissionError) as err:
        load_submission(path)
    assert len(str(err.value)) < 400 and "\n" not in str(err.value), str(err.value)[:500]


def test_names_an_import_binds_are_not_blamed_on_a_star_import():
    """``from autograder.selfcheck import *`` (a self-check cell written with a star) made every use of ``np`` "come
    from" the star: correct code scored 0. A name no import binds still does."""
    from autograder.submission import forbidden_usage

    unit = {"filename": "sub.py", "label": "sub.py"}
    ok = "import numpy as np\nfrom autograder.selfcheck import *\ndef f(w):\n    return float(np.sum(w))\n"
    assert forbidden_usage([{**unit, "source": ok}], ["f"]) == {}
    bad = "from slamlib import *\ndef f(w):\n    return particle_summary(w)\n"
    assert "can only come from from slamlib import *" in forbidden_usage([{**unit, "source": bad}], ["f"])["f"]


def test_csv_cells_carry_no_control_characters_and_are_cut_short():
    from autograder.batch import _cell

    got = _cell("eve\x1b[2J\x1b[H\rTotal: 100" + "x" * 5000)
    assert "\x1b" not in got and "\r" not in got and len(got) <= 1000 and got.startswith("eve\\x1b[2J")
    assert _cell("\rx").startswith("\\x0d") and _cell(42.0) == 42.0


def test_the_grader_starts_in_a_working_directory_that_was_removed(tmp_path):
    """Started from a folder removed meanwhile (a terminal left in it), with a relative entry on ``sys.path`` (an
    editable install's path hook), the grader stopped at import: ``abspath`` of the entry needs the working
    directory. It starts, with the working directory ("") off the path and the other entries kept."""
    gone = tmp_path / "gone"
    gone.mkdir()
    code = ("import os, sys\n"
            "os.rmdir(os.getcwd())\n"
            "sys.path.insert(1, '__editable__.hook__path_hook__')\n"
            "import autograder\n"
            "assert '' not in sys.path and '__editable__.hook__path_hook__' in sys.path, sys.path\n"
            "print('started')\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=gone, capture_output=True, text=True, timeout=60,
                         env={**os.environ, "PYTHONPATH": str(AG_ROOT)})
    assert out.returncode == 0 and out.stdout.strip() == "started", out.stderr[-2000:]


def test_the_batch_fingerprints_a_huge_submission_in_bounded_memory(tmp_path):
    """The batch read every submission whole to fingerprint it, before grading: a 3 GB upload made the batch hold
    3.2 GB, and a larger one would have stopped the batch with a MemoryError. The hash is read in blocks."""
    from autograder.seeds import content_hash

    big = tmp_path / "bob.py"
    with open(big, "wb") as fh:  # sparse: no disk
        fh.truncate(600 << 20)
    code = ("import resource, sys\n"
            "from autograder.batch import _fingerprint\n"
            "resource.setrlimit(resource.RLIMIT_AS, (400 << 20, resource.RLIM_INFINITY))\n"
            "print(_fingerprint(sys.argv[1], None))\n")
    import hashlib

    out = subprocess.run([sys.executable, "-c", code, str(big)], capture_output=True, text=True, timeout=120,
                         env={**os.environ, "PYTHONPATH": str(AG_ROOT)})
    assert out.returncode == 0, out.stderr[-2000:]
    h = hashlib.sha256()
    block = bytes(1 << 20)
    for _ in range(600):
        h.update(block)
    assert out.stdout.strip() == h.hexdigest() == content_hash(big)
    assert content_hash(b"abc") == hashlib.sha256(b"abc").hexdigest()


@pytest.mark.parametrize("closed", ["1", "0 1", "0 1 2"])
def test_the_grader_runs_with_its_standard_descriptors_closed(tmp_path, closed):
    """Started with ``>&-`` (a cron line): the report's print raised after results.json was written (exit 1 for a
    grading that scored 100); with ``<&- >&-`` the sandbox's control socket got descriptor 1 and the child's output
    pipe was set over it (exit 3: nothing could be graded). The grader opens /dev/null on closed descriptors."""
    path = tmp_path / "alice.py"
    path.write_text(solution_text("particle_filter"))
    out = tmp_path / "out.json"
    redirect = " ".join(f"{fd}>&-" if fd != "0" else "<&-" for fd in closed.split())
    cmd = (f'exec "{sys.executable}" -P -m autograder grade "{path}" -e particle_filter '
           f'-r "{out}" {redirect}')
    proc = subprocess.run(["sh", "-c", cmd], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONPATH": str(AG_ROOT)})
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert json.loads(out.read_text())["score"] > 0


def test_batch_workers_never_import_from_the_working_directory(tmp_path):
    """The batch's pool workers are new interpreters, which put the working directory first on sys.path: started
    in the submissions folder, they imported a student's ``threading.py`` (and rewrote every score to 100)."""
    subs = tmp_path / "subs"
    subs.mkdir()
    marker = tmp_path / "imported"
    (subs / "threading.py").write_text(f"open({str(marker)!r}, 'w').close()\nraise ImportError('a student file')\n")
    (subs / "alice.py").write_text(solution_text("particle_filter"))
    env = {**os.environ, "PYTHONPATH": str(AG_ROOT)}
    p = subprocess.run([sys.executable, "-m", "autograder", "batch", ".", "--exercise", "particle_filter",
                        "--out", str(tmp_path / "g.csv"), "--quiet", "--jobs", "1"], capture_output=True, text=True,
                       cwd=str(subs), env=env, timeout=600)
    assert not marker.exists(), p.stderr[-2000:]
    rows = {r.split(",")[0]: r for r in (tmp_path / "g.csv").read_text().splitlines()[1:]}
    assert rows["alice"].split(",")[2] == "100.0", rows


FORGED_EVENTS = '''
import os, stat, time


def _forge(event):
    for fd in range(3, 256):  # the loader's control socket: the only socket among its descriptors
        try:
            if stat.S_ISSOCK(os.fstat(fd).st_mode):
                os.write(fd, event)
        except OSError:
            pass


_forge(b'{"ev":"stmt","unit":0,"stmt":%d,"line":1}')
time.sleep(%s)
'''


@pytest.mark.parametrize("stmt", [9999, 0])
def test_a_forged_statement_event_is_the_submissions_malformed_message(tmp_path, stmt):
    """Top-level code that told the sandbox "statement 9999 (or an earlier one) is running" restarted the statement's
    clock: a statement over the statement limit ran in full, in the loader and in every worker."""
    text = solution_text("particle_filter") + FORGED_EVENTS % (stmt, 0.1)
    path = tmp_path / "sub.py"
    path.write_text(text)
    result = grade(path, "particle_filter", limits=_limits(), functions=[TARGET])
    assert result.score == 0 and "statement event out of order or for no statement" in result.tests[0].output, \
        result.tests[0].output


def test_a_grader_error_row_holds_no_score(tmp_path, monkeypatch):
    """When writing a graded submission's results failed, its row said "grader-error" with the score the grading
    had reached (100 in the CSV, 0 in the fallback JSON): the grader's failure is no grade, so the row has none."""
    import csv

    import autograder.batch as batch
    from autograder.exercises import get_exercise

    writes = []

    def failing_once(path, data):
        writes.append(path)
        if len(writes) == 1:
            raise OSError(28, "No space left on device")
        return write_json_atomic(path, data)

    monkeypatch.setattr(batch, "write_json_atomic", failing_once)
    path = tmp_path / "alice.py"
    path.write_text(solution_text("particle_filter"))
    row = batch._grade_one("alice", path, None, "particle_filter", tmp_path / "alice.json", _limits(), "fp")
    ex = get_exercise("particle_filter")
    assert row["status"] == "grader-error" and row["score"] == "" and all(row[fn] == "" for fn in ex.functions), row
    batch._write_csv(tmp_path / "g.csv", [row], ex)
    got = next(csv.DictReader((tmp_path / "g.csv").open()))
    assert got["score"] == got["percent"] == "" and got["status"] == "grader-error", got


def test_a_batch_under_a_locale_that_is_not_utf8_grades_non_ascii_names(tmp_path):
    """Under ``LC_ALL=C`` with ``PYTHONUTF8=0`` (file names decoded as ASCII), ``josé.py`` was called "not UTF-8"
    and not graded, and writing another name's results stopped the whole batch (UnicodeEncodeError)."""
    subs = tmp_path / "subs"
    (subs / "zoë").mkdir(parents=True)
    (subs / "josé.py").write_text(solution_text("particle_filter"))
    (subs / "zoë" / "answer.py").write_text(solution_text("particle_filter"))
    (subs / "ann.py").write_text(solution_text("particle_filter"))
    env = {**os.environ, "PYTHONPATH": str(AG_ROOT), "LC_ALL": "C", "LANG": "C", "PYTHONUTF8": "0",
           "PYTHONIOENCODING": ""}
    check = subprocess.run([sys.executable, "-c", "import sys; print(sys.getfilesystemencoding())"], env=env,
                           capture_output=True, text=True)
    assert check.stdout.strip() == "ascii", check.stdout  # the locale the test is about
    p = subprocess.run([sys.executable, "-P", "-m", "autograder", "batch", str(subs), "--exercise", "particle_filter",
                        "--out", str(tmp_path / "g.csv"), "--quiet", "--jobs", "1"], capture_output=True,
                       env=env, timeout=600)
    assert p.returncode == 0, p.stderr[-2000:]
    rows = {r.split(",")[0]: r.split(",") for r in (tmp_path / "g.csv").read_text(encoding="utf-8").splitlines()[1:]}
    assert set(rows) == {"ann", "josé", "zoë"}, rows
    assert all(r[2] == "100.0" and r[-2] == "ok" for r in rows.values()), rows
    assert rows["josé"][1].endswith("josé.py"), rows
    assert sorted(os.listdir(tmp_path / "g_results")) == ["ann.json", "josé.json", "zoë.json"]


ROOT_ONLY = pytest.mark.skipif(os.geteuid() != 0, reason="the zygote's process limit is its own only under a fresh uid")


@ROOT_ONLY
def test_a_worker_the_machine_cannot_start_is_the_graders_fault_not_a_crash():
    """A fork the zygote was refused (a non-root grader under ``ulimit -u 11``) closed the worker's pipes: the
    function's tests failed with "ended while loading the submission" and a correct submission scored 70."""
    from autograder.sandbox import Sandbox, WorkerNotStarted

    box = Sandbox([{"source": "def f():\n    return 1.0\n", "filename": "p.py", "label": "p"}], ["f"], Limits())
    box.max_workers = 1  # the zygote's RLIMIT_NPROC: itself and one worker
    try:
        box.start()
        first = box.fork_worker()
        assert first.call("f", [], timeout=10).status == "ok"
        second = box.fork_worker()
        with pytest.raises(WorkerNotStarted, match="could not start a process"):
            second.call("f", [], timeout=10)
        first.close()
        second.close()
        third = box.fork_worker()  # the sandbox itself is fine: a worker starts once there is room
        assert third.call("f", [], timeout=10).status == "ok"
        third.close()
    finally:
        box.close()


@ROOT_ONLY
def test_a_grading_the_machine_cannot_give_processes_to_is_no_score(tmp_path, monkeypatch):
    from autograder.engine import GraderFault
    from autograder.sandbox import Sandbox

    monkeypatch.setattr(Sandbox, "max_workers", 1)
    path = tmp_path / "sub.py"
    path.write_text(solution_text("particle_filter"))
    with pytest.raises(GraderFault, match="WorkerNotStarted"):
        grade(path, "particle_filter", limits=_limits(), workers=2)


def test_a_grader_under_a_small_address_space_stops_at_its_self_check(tmp_path):
    """Under ``ulimit -v 200000`` the self-check spun forever in OpenBLAS's start-up (the grader's own
    ``import scipy.linalg``), and with that fixed it ended in a MemoryError traceback: exit 3 and a message."""
    import resource

    def small():
        resource.setrlimit(resource.RLIMIT_AS, (200_000 * 1024, 200_000 * 1024))

    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    env["PYTHONPATH"] = str(AG_ROOT)
    try:
        p = subprocess.run([sys.executable, "-P", "-m", "autograder", "selfcheck"], capture_output=True, text=True,
                           env=env, cwd=str(tmp_path), timeout=120, preexec_fn=small)
    except subprocess.TimeoutExpired:
        pytest.fail("the self-check did not end within 120 s under a 200 MB address space")
    assert p.returncode == 3, (p.returncode, p.stdout[-1500:], p.stderr[-1500:])
    assert "FAILED" in p.stdout and "Traceback" not in p.stderr, p.stdout[-1500:]


def test_printing_a_lot_while_loading_costs_nothing(tmp_path):
    """Top-level code that printed more than the 1 MB output cap (a check loop at the end of a file, a cell showing a
    large array) failed the whole loading: a correct submission scored 0 on every test."""
    result = _grade(tmp_path, solution_text("particle_filter") + '\nprint("x" * 1_100_000)\n')
    assert result.score == result.max_score, result.text_report(verbose=True)[-2000:]
    assert any("printed 1100001 bytes while loading" in n for n in result.notes), result.notes


def test_the_notebook_validators_warnings_are_not_the_graders_output(tmp_path):
    import warnings

    from autograder.submission import load_submission

    cell = {"cell_type": "code", "metadata": {}, "execution_count": None, "outputs": [],
            "source": solution_text("particle_filter")}
    nb = {"nbformat": 4, "nbformat_minor": 5, "metadata": {}, "cells": [cell]}  # 4.5 without cell ids
    path = tmp_path / "sub.ipynb"
    path.write_text(json.dumps(nb))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load_submission(path)
    assert not caught, [str(w.message)[:200] for w in caught]


def _numeric_options():
    """(command, option) for every option of the command line that takes a number."""
    from autograder.__main__ import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    for cmd, p in sub.choices.items():
        for action in p._actions:
            if action.type is not None and action.option_strings:
                yield cmd, max(action.option_strings, key=len)


@pytest.mark.parametrize("value", ["-1", "0", "nan", "inf", "x"])
def test_every_numeric_option_refuses_what_it_cannot_mean(value, capsys):
    """``grade --seed -1`` was taken, then failed inside the grading: an internal error and a results.json scoring 0
    (``batch --seed -1`` made every row a grader error); ``--timeout 0`` was silently ignored."""
    from autograder.__main__ import main

    options = list(_numeric_options())
    assert {("grade", "--seed"), ("batch", "--jobs"), ("grade", "--timeout"), ("calibrate", "--seeds")} <= set(options)
    for cmd, option in options:
        if value == "0" and option == "--seed":
            continue  # 0 is a seed
        required = {"grade": ["sub.py"], "batch": ["folder", "-e", "particle_filter"], "gradescope": ["-e", "x"]}
        with pytest.raises(SystemExit) as stop:
            main([cmd, *required.get(cmd, []), option, value])
        assert stop.value.code == 2, (cmd, option, value)
        assert f"argument {option}" in capsys.readouterr().err, (cmd, option)


def test_the_python_interface_refuses_what_it_cannot_mean(tmp_path):
    from autograder.batch import run_batch

    path = tmp_path / "sub.py"
    path.write_text(solution_text("particle_filter"))
    for kw, name in ((dict(seed=-1), "seed"), (dict(seed=1.5), "seed"), (dict(workers=0), "workers"),
                     (dict(workers=True), "workers")):
        with pytest.raises(ValueError, match=f"^{name}:"):
            grade(path, "particle_filter", **kw)
    with pytest.raises(TypeError, match="^limits:"):
        grade(path, "particle_filter", limits={"call_timeout": 1.0})
    for kw, name in ((dict(jobs=0), "jobs"), (dict(seed=-3), "seed")):
        with pytest.raises(ValueError, match=f"^{name}:"):
            run_batch(tmp_path, "particle_filter", out_csv=tmp_path / "g.csv", **kw)
    for field, value in (("call_timeout", 0.0), ("import_timeout", float("nan")), ("statement_timeout", -1),
                         ("test_budget", float("inf")), ("memory", 0), ("output", 1.5), ("code", True)):
        with pytest.raises(ValueError, match=f"^Limits.{field}:"):
            Limits(**{field: value})


def test_a_results_file_that_cannot_be_written_is_said_so_before_or_after_grading(tmp_path, monkeypatch, capsys):
    """``grade -r`` into a folder that cannot be made, or onto a full disk, ended in a raw traceback."""
    import errno

    from autograder import __main__ as cli

    sub = tmp_path / "sub.py"
    sub.write_text(solution_text("particle_filter"))
    (tmp_path / "file").write_text("")
    assert cli.main(["grade", str(sub), "-e", "particle_filter", "-r", str(tmp_path / "file" / "r.json")]) == 2
    err = capsys.readouterr().err
    assert "argument --results" in err and "Traceback" not in err, err

    def full(path, data):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr("autograder.results.write_json_atomic", full)
    assert cli.main(["grade", str(sub), "-e", "particle_filter", "-r", str(tmp_path / "r.json"),
                     "--timeout", "2.5"]) == 1
    out, err = capsys.readouterr()
    assert "100 / 100" in out, out[:500]  # the grade is shown; the machine's failure is no score
    assert "could not write the results" in err and "No space left" in err and "Traceback" not in err, err


def test_a_grades_file_that_cannot_be_written_ends_the_batch_with_a_message(tmp_path, monkeypatch, capsys):
    import errno

    from autograder import __main__ as cli

    subs = tmp_path / "subs"
    subs.mkdir()
    (subs / "ann.py").write_text(solution_text("particle_filter"))

    def full(path, text):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr("autograder.batch.write_text_atomic", full)
    assert cli.main(["batch", str(subs), "-e", "particle_filter", "-o", str(tmp_path / "g.csv"), "-q",
                     "--timeout", "2.5"]) == 1
    err = capsys.readouterr().err
    assert "No space left on device" in err and "g.csv" in err and "Traceback" not in err, err
    assert (tmp_path / "g_results" / "ann.json").exists()  # what was graded is kept for the next run


def test_a_batch_run_again_keeps_only_results_graded_the_same_way(tmp_path, monkeypatch):
    """A rerun kept every earlier result whose file had not changed, even when it was asked to grade with another
    --timeout or budget, or under a new secret (every derived seed changes): the CSV mixed two gradings."""
    from autograder.batch import run_batch

    subs = tmp_path / "subs"
    subs.mkdir()
    (subs / "ann.py").write_text(solution_text("particle_filter"))
    out, res = tmp_path / "g.csv", tmp_path / "g_results" / "ann.json"

    def run(limits):
        run_batch(subs, "particle_filter", out_csv=out, jobs=1, limits=limits, progress=False)
        data = json.loads(res.read_text())
        return res.stat().st_mtime_ns, data["extra_data"]["seed"], data["extra_data"]["batch_settings"]

    first = run(Limits(call_timeout=2.5))
    assert first[2]["call_timeout"] == 2.5
    assert run(Limits(call_timeout=2.5)) == first  # the same settings: kept, not graded again
    other = run(Limits(call_timeout=3.0))
    assert other[0] != first[0] and other[2]["call_timeout"] == 3.0 and other[1] == first[1]
    monkeypatch.setenv("AUTOGRADER_SECRET_FILE", str(tmp_path / "another_secret"))
    renewed = run(Limits(call_timeout=3.0))
    assert renewed[0] != other[0] and renewed[1] != other[1]


SLEEPER = "import time\n\ndef f(s):\n    time.sleep(s)\n    return 1.0\n"


def _fake_waiting(monkeypatch, share):
    """The kernel's accounting replaced by a machine that keeps the worker waiting ``share`` of the wall time."""
    import time as _time

    from autograder import sandbox

    t0 = _time.monotonic()
    monkeypatch.setattr(sandbox, "_delays", lambda pids: {p: share * (_time.monotonic() - t0) for p in pids},
                        raising=False)


def test_a_call_is_not_charged_the_time_the_machine_kept_it_waiting(monkeypatch):
    """On a loaded machine (6 busy processes on 2 cores) a correct submission whose calls take 2 s of processor
    lost a test's budget (95/100): the call's deadline counted the time its worker waited for a processor."""
    from autograder.sandbox import Sandbox

    box = Sandbox([{"source": SLEEPER, "filename": "p.py", "label": "p"}], ["f"], Limits())
    try:
        box.start()
        _fake_waiting(monkeypatch, 0.8)
        worker = box.fork_worker()
        out = worker.call("f", [1.5], timeout=1.0)
        assert out.status == "ok", out.error
        assert out.waited >= 0.8, out.waited  # handed to the budgets, which stretch by it too
        worker.close()
    finally:
        box.close()


def test_the_stretch_of_a_call_is_capped(monkeypatch):
    from autograder.sandbox import MAX_STRETCH, Sandbox

    box = Sandbox([{"source": SLEEPER, "filename": "p.py", "label": "p"}], ["f"], Limits())
    try:
        box.start()
        _fake_waiting(monkeypatch, 100.0)  # a lie no kernel tells: the cap still ends the call
        worker = box.fork_worker()
        import time as _time

        t0 = _time.monotonic()
        out = worker.call("f", [60.0], timeout=0.5)
        assert out.status == "timeout" and "waiting for a processor" in out.error, out.error
        assert _time.monotonic() - t0 < 30.0  # (1 + MAX_STRETCH) x 0.5 s, not the minute the call sleeps
        assert MAX_STRETCH <= 5
    finally:
        box.close()


def test_the_kernel_says_how_long_a_process_waited_for_a_processor():
    from autograder.sandbox import run_delay

    got = run_delay([os.getpid()])
    if not os.path.exists(f"/proc/{os.getpid()}/schedstat"):
        assert got is None
    else:
        assert isinstance(got, float) and got >= 0.0
    assert run_delay([]) is None and run_delay([2 ** 30]) is None


def test_loading_is_not_charged_the_time_the_machine_kept_it_waiting(monkeypatch):
    """The same for the top-level code: on a loaded machine a statement within --statement-timeout on an idle one
    was skipped (and a long loading cut), with the functions after it."""
    from autograder.sandbox import Sandbox

    src = "import time\ntime.sleep(1.5)\nX = 2.0\n\ndef f():\n    return X\n"
    box = Sandbox([{"source": src, "filename": "p.py", "label": "p"}], ["f"],
                  Limits(statement_timeout=1.0, import_timeout=20.0))
    try:
        _fake_waiting(monkeypatch, 0.8)
        ready = box.start()
        assert not ready.get("notes"), ready.get("notes")  # the sleeping statement was not skipped
        worker = box.fork_worker()
        out = worker.call("f", [], timeout=5.0)
        assert out.status == "ok", (out.status, out.error)
        worker.close()
    finally:
        box.close()


def test_scratch_folders_in_the_hosts_tmp_are_removed_with_the_sandbox():
    """Without a mount namespace each worker's private /tmp and /dev/shm folders are the host's: every grading left
    about seven of them behind (with whatever the submission wrote there)."""
    from autograder.sandbox import Sandbox

    src = "import os, tempfile\n\ndef f():\n    open(os.path.join(tempfile.gettempdir(), 'left'), 'w').write('x')\n" \
          "    return 1.0\n"
    box = Sandbox([{"source": src, "filename": "p.py", "label": "p"}], ["f"], Limits(filesystem=False))

    def left():
        return [n for top in ("/tmp", "/dev/shm") if os.path.isdir(top) for n in os.listdir(top)
                if n.startswith(box._scratch_prefix + "-")]

    try:
        box.start()
        worker = box.fork_worker()
        assert worker.call("f", [], timeout=10).status == "ok"
        assert left(), "the worker's scratch folders carry the sandbox's prefix"
    finally:
        box.close()
    assert not left()


FORGED_FORK_FAILURE = '''
import fcntl, json, os, stat, struct


def _forge():
    head = json.dumps({"status": "fork-failed", "error": "forged"}).encode()
    frame = b"AGW1" + struct.pack("<II", len(head), 0) + head
    pipes = [fd for fd in range(3, 256) if _fifo(fd)]
    for fd in pipes:  # the request pipe first (no one reads it then), as a zygote that could not fork would
        if fcntl.fcntl(fd, fcntl.F_GETFL) & os.O_ACCMODE == os.O_RDONLY:
            os.close(fd)
    for fd in pipes:  # then the word, on the result pipe: the one pipe it writes to beyond stdout and stderr
        try:
            if fcntl.fcntl(fd, fcntl.F_GETFL) & os.O_ACCMODE == os.O_WRONLY:
                os.write(fd, frame)
        except OSError:
            pass


def _fifo(fd):
    try:
        return stat.S_ISFIFO(os.fstat(fd).st_mode)
    except OSError:
        return False


_forge()
'''


def test_a_worker_cannot_pass_for_the_sandbox_that_could_not_start_it(tmp_path):
    """A zygote that could not fork a worker said so on the worker's result pipe (the grader's fault: graded again,
    then an internal error); a worker shares that pipe, and its forged word (after closing its request pipe, as the
    zygote did) turned the submission's grading into the grader's error at will: one bit per grading, visible
    before the deadline. The zygote now closes the pipes empty, which no worker can do."""
    path = tmp_path / "sub.py"
    path.write_text(solution_text("particle_filter") + FORGED_FORK_FAILURE)
    result = grade(path, "particle_filter", limits=_limits(), functions=[TARGET])
    assert not any("graded a second time" in n for n in result.notes), result.notes
    assert result.score == 0 and "a result arrived before the request was sent" in result.tests[0].output, \
        result.tests[0].output


def test_a_deep_scratch_tree_is_removed_without_failing_the_grading():
    """Python 3.11's shutil.rmtree recurses once per folder level: 5000 nested folders in a worker's scratch folder
    raised RecursionError out of the sandbox's end, and so out of grade() (an internal error, the folders left)."""
    from autograder.sandbox import Sandbox

    src = ("import os\n\ndef f():\n    for _ in range(3000):\n        os.mkdir('d')\n        os.chdir('d')\n"
           "    return 1.0\n")
    box = Sandbox([{"source": src, "filename": "p.py", "label": "p"}], ["f"], Limits(filesystem=False))
    try:
        box.start()
        worker = box.fork_worker()
        assert worker.call("f", [], timeout=30).status == "ok"
    finally:
        box.close()
    assert not [n for top in ("/tmp", "/dev/shm") if os.path.isdir(top) for n in os.listdir(top)
                if n.startswith(box._scratch_prefix + "-")]


def test_a_worker_cannot_make_itself_wait_for_a_processor():
    """Round 7: a worker that lowered its own priority (os.nice(19)) or pinned itself to one processor waited on
    purpose, and the grader gave that waiting back as the machine's (a hanging call ran twice as long, and the
    budgets had no cap on it). Seccomp refuses the calls; where there is no seccomp, such a process's waiting is
    not counted; and the budgets get back at most MAX_STRETCH times the submission's budget."""
    from autograder.engine import Budget
    from autograder.sandbox import MAX_STRETCH, Sandbox, _delays

    src = ("import os\n\ndef nice():\n    os.nice(19)\n    return 1.0\n\n"
           "def pin():\n    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})\n    return 1.0\n")
    box = Sandbox([{"source": src, "filename": "p.py", "label": "p"}], ["nice", "pin"], Limits())
    try:
        ready = box.start()
        if (ready.get("isolation") or {}).get("seccomp"):
            for fn in ("nice", "pin"):
                worker = box.fork_worker()
                out = worker.call(fn, [], timeout=10)
                assert out.status == "error" and "PermissionError" in out.error, (fn, out.status, out.error)
                worker.close()
    finally:
        box.close()
    slow = subprocess.Popen([sys.executable, "-c", "import os, time; os.nice(5); time.sleep(30)"])
    try:
        import time

        time.sleep(1.0)
        assert slow.pid not in _delays([slow.pid])  # a process that lowered its priority: its waiting is its own
        assert os.getpid() in _delays([os.getpid()]) or not os.path.exists("/proc/self/schedstat")
    finally:
        slow.kill()
        slow.wait()
    budget = Budget(30.0, 100.0, start=0.0)
    budget.give_back_waiting(10 * MAX_STRETCH * 100.0)
    assert budget.deadline == 100.0 + MAX_STRETCH * 100.0


def test_without_seccomp_no_waiting_is_given_back(monkeypatch):
    """Round 8: without seccomp a worker may change its own scheduling between two of the grader's readings (pin
    itself to one processor, spin, widen again) and be given its own waiting back; there, none is."""
    from autograder.sandbox import Sandbox

    box = Sandbox([{"source": SLEEPER, "filename": "p.py", "label": "p"}], ["f"], Limits(seccomp=False))
    try:
        box.start()
        _fake_waiting(monkeypatch, 0.8)
        worker = box.fork_worker()
        out = worker.call("f", [1.5], timeout=1.0)
        assert out.status == "timeout" and out.waited == 0.0, (out.status, out.waited)
    finally:
        box.close()
