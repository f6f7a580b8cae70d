"""Every command-line script of the project (``benchmarks/``, ``tools/``) reads its arguments before it works.

``--help`` prints the usage and exits at once; an argument the script does not know is refused with exit
status 2 and its name. Neither starts a measurement or writes a file: a script that ignored its arguments
would run a whole benchmark for ``--help``, or rewrite a chapter's data file. Every script and option the text
quotes (the README, the pages, the chapters, the scripts' docstrings) is one that exists.
"""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
from test_prose import _quoted_commands

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted(p for folder in ("benchmarks", "tools") for p in (ROOT / folder).glob("*.py")
                 if '__name__ == "__main__"' in p.read_text())


def _quoted_options():
    """``{script: options}``: the options of every command the README, the pages, the chapters and the
    scripts' docstrings quote, by script (``benchmarks/mcl_study.py``)."""
    options = {}
    for _, cmd in _quoted_commands():
        words = shlex.split(cmd)
        options.setdefault(words[1], set()).update(w.split("=")[0] for w in words[2:] if w.startswith("--"))
    return options


QUOTED = _quoted_options()
#: valid positional arguments for the scripts that need them ("x" for the others: refused as well); a
#: script that writes is pointed away from the repository, should it ever run
OUT = str(Path(tempfile.gettempdir()) / "slam-course-test-scripts")
POSITIONAL = {"prose_check.py": ["chapters/00_intro.ipynb"], "nbstrip.py": ["--check", "chapters/00_intro.ipynb"],
              "mrclam_subset.py": ["slamlib/data/mrclam", "--out", OUT]}


def _run(script, *args):
    data = {p: p.stat().st_mtime_ns for p in (ROOT / "chapters" / "data").iterdir()}
    proc = subprocess.run([sys.executable, str(script), *args], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert {p: p.stat().st_mtime_ns for p in (ROOT / "chapters" / "data").iterdir()} == data, "a data file was written"
    return proc


def test_the_scripts_are_found():
    names = {p.name for p in SCRIPTS}
    assert {"mcl_study.py", "bench_slam.py", "prose_check.py", "lidar_slam_robustness.py"} <= names
    # every script the text quotes exists, and the quoted options are read
    assert set(QUOTED) <= {f"{p.parent.name}/{p.name}" for p in SCRIPTS}, set(QUOTED)
    assert {"--json", "--configs", "--updates"} <= QUOTED["benchmarks/mcl_study.py"]


@pytest.mark.parametrize("script, args", [("bench_3d.py", ["M3500", "Intel"]), ("bench_3d.py", []),
                                          ("bench_graph_slam.py", ["edges"]), ("bench_graph_slam.py", [])])
def test_sections_are_chosen_by_name(script, args, monkeypatch, capsys):
    # the scripts that measure sections run only the named ones (all by default) and refuse other names
    import importlib.util

    spec = importlib.util.spec_from_file_location(script[:-3], ROOT / "benchmarks" / script)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    ran = []
    for name in ("sphere_figures", "figures2d", "incremental_figures", "bundle_adjustment_figures",
                 "solve_figures", "edge_figures", "solver_figures"):
        if hasattr(mod, name):
            monkeypatch.setattr(mod, name, lambda *a, name=name: ran.append((name, a)))
    mod.main(args)
    assert ran and (len(ran) < 3) == bool(args)
    if script == "bench_3d.py" and args:
        assert ran == [("figures2d", (["M3500", "Intel"],))]
    with pytest.raises(SystemExit) as exit_:
        mod.main(["M3050"])
    assert exit_.value.code == 2 and "M3050" in capsys.readouterr().err


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_help_prints_the_usage_and_does_nothing_else(script):
    proc = _run(script, "--help")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.startswith("usage:"), proc.stdout[:500]
    # an option the text quotes for this script is one it has
    missing = [o for o in QUOTED.get(f"{script.parent.name}/{script.name}", ())
               if not re.search(rf"{re.escape(o)}(?![\w-])", proc.stdout)]
    assert not missing, f"quoted but not an option of {script.name}: {missing}"


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_an_unknown_argument_is_refused_by_name(script):
    proc = _run(script, "--no-such-option", *POSITIONAL.get(script.name, ["x"]))
    assert proc.returncode == 2, (proc.returncode, proc.stdout[-1000:], proc.stderr[-1000:])
    assert "--no-such-option" in proc.stderr


@pytest.mark.parametrize("script, args, named", [
    ("tools/prose_check.py", ["chapters/no_such_chapter.ipynb"], "argument NOTEBOOK"),
    ("tools/prose_check.py", ["README.md"], "argument NOTEBOOK"),
    ("tools/nbstrip.py", ["--check", "chapters/no_such_chapter.ipynb"], "argument NOTEBOOK"),
    ("tools/mrclam_subset.py", ["/no/such/folder"], "argument original"),
    ("tools/mrclam_subset.py", ["slamlib/data/mrclam", "--out", OUT, "--robots", "6"], "argument --robots"),
    ("benchmarks/mcl_holdout.py", ["--compare", "no_such_output.json"], "argument --compare"),
    ("benchmarks/mcl_holdout.py", ["--slamlib", "/no/such/tree"], "argument --slamlib"),
])
def test_a_path_that_is_not_there_is_refused_by_its_argument(script, args, named):
    proc = _run(ROOT / script, *args)
    assert proc.returncode == 2 and named in proc.stderr, (proc.returncode, proc.stderr[-1500:])
    assert "Traceback" not in proc.stderr


def _numeric_options():
    """``(script, option)`` for every ``add_argument("--option", type=int or float)`` of the scripts."""
    import ast

    found = []
    for script in SCRIPTS:
        for node in ast.walk(ast.parse(script.read_text())):
            if (isinstance(node, ast.Call) and getattr(node.func, "attr", None) == "add_argument"
                    and any(k.arg == "type" and getattr(k.value, "id", None) in ("int", "float") for k in node.keywords)):
                names = [a.value for a in node.args if isinstance(a, ast.Constant) and str(a.value).startswith("--")]
                found += [(script, names[0])] if names else []
    return found


NUMERIC = _numeric_options()


def test_the_numeric_options_are_found():
    assert len(NUMERIC) >= 30
    assert (ROOT / "benchmarks" / "mcl_study.py", "--jobs") in NUMERIC
    assert (ROOT / "tools" / "victoria_park_graph.py", "--t-max") in NUMERIC


@pytest.mark.parametrize("script, option", NUMERIC, ids=lambda v: v.name if isinstance(v, Path) else v)
def test_a_negative_count_seed_or_duration_is_refused_by_its_option(script, option):
    # every numeric option of the scripts is a count (at least 1), a seed (at least 0), a robot, a log or a
    # duration (positive): -1 is none of them
    proc = _run(script, *POSITIONAL.get(script.name, []), option, "-1")
    assert proc.returncode == 2 and (f"argument {option}" in proc.stderr or f"{option} must be" in proc.stderr), \
        (proc.returncode, proc.stderr[-1500:])
    assert "Traceback" not in proc.stderr
