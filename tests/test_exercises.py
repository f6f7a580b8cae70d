"""The exercise notebooks: metadata, stubs that match the contract and slamlib, cells that run."""

from __future__ import annotations

import inspect
import re
import sys
from pathlib import Path

import matplotlib
import nbformat
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent / "autograder_fixtures"))

from agtest import NOTEBOOKS, ROOT, solution_text  # noqa: E402

import slamlib  # noqa: E402
from autograder.exercises import get_exercise  # noqa: E402
from autograder.submission import SKIP_TAG  # noqa: E402

matplotlib.use("Agg")
EXERCISES = list(NOTEBOOKS)


def _nb(exercise):
    return nbformat.read(ROOT / "exercises" / NOTEBOOKS[exercise], as_version=4)


def _graded_namespace(nb):
    ns = {"__name__": "submission"}
    for cell in nb.cells:
        if cell.cell_type == "code" and SKIP_TAG not in cell.metadata.get("tags", []):
            exec(compile(cell.source, "cell", "exec"), ns)
    return ns


def _contract_view(sig):
    """A signature without keyword-only parameters that have defaults (slamlib's extra options)."""
    params = [p for p in sig.parameters.values() if not (p.kind is p.KEYWORD_ONLY and p.default is not p.empty)]
    return sig.replace(parameters=params)


@pytest.mark.parametrize("exercise", EXERCISES)
def test_notebook_metadata_and_no_outputs(exercise):
    nb = _nb(exercise)
    nbformat.validate(nb)
    assert nb.metadata["slam_course"]["exercise"] == exercise
    assert nb.metadata["kernelspec"]["name"] == "python3"
    for cell in nb.cells:
        if cell.cell_type == "code":
            assert cell.outputs == [] and cell.execution_count is None
    assert nb.cells[0].cell_type == "markdown" and nb.cells[0].source.startswith("# Exercise ")
    headings = [ln for c in nb.cells if c.cell_type == "markdown" for ln in c.source.splitlines() if ln.startswith("# ")]
    assert len(headings) == 1


@pytest.mark.parametrize("exercise", EXERCISES)
def test_stubs_match_the_contract_and_slamlib(exercise):
    ex = get_exercise(exercise)
    ns = _graded_namespace(_nb(exercise))
    for fn in ex.functions:
        stub = ns[fn]
        sig = inspect.signature(stub)
        assert sig == ex.signature(fn), fn
        assert _contract_view(inspect.signature(getattr(slamlib, fn))) == sig, fn
        doc = inspect.getdoc(stub)
        assert doc and "Parameters" in doc and "Returns" in doc, fn
        args = [None] * sum(p.kind is p.POSITIONAL_OR_KEYWORD for p in sig.parameters.values())
        kwargs = {p.name: None for p in sig.parameters.values() if p.kind is p.KEYWORD_ONLY}
        with pytest.raises(NotImplementedError):
            stub(*args, **kwargs)


@pytest.mark.parametrize("exercise", EXERCISES)
def test_links_point_into_the_book(exercise):
    toc = (ROOT / "_toc.yml").read_text()
    nb = _nb(exercise)
    text = "\n".join(c.source for c in nb.cells if c.cell_type == "markdown")
    links = re.findall(r"\]\(([^)#]+)\)", text)
    assert any(link.startswith("../chapters/") for link in links)
    for link in links:
        target = (ROOT / "exercises" / link).resolve().relative_to(ROOT)
        assert f"file: {target.with_suffix('').as_posix()}" in toc, link


def _run_all_cells(nb, replace=None):
    """Execute every code cell in order in one namespace (no kernel); ``replace`` swaps the stubs."""
    import matplotlib.pyplot as plt

    ns = {"__name__": "__main__"}
    for cell in nb.cells:
        if cell.cell_type != "code":
            continue
        src = cell.source
        if replace is not None and "raise NotImplementedError" in src:
            src = replace
            replace = ""  # the solution defines every function once
        exec(compile(src, "cell", "exec"), ns)
        plt.close("all")
    return ns


@pytest.mark.slow
@pytest.mark.parametrize("exercise", EXERCISES)
def test_every_cell_runs_with_stubs_and_with_a_solution(exercise, capsys):
    nb = _nb(exercise)
    ns = _run_all_cells(nb)
    out = capsys.readouterr().out
    assert "not implemented yet" in out
    assert ns["report"].score == 0
    ns = _run_all_cells(nb, replace=solution_text(exercise))
    out = capsys.readouterr().out
    assert "not implemented yet" not in out
    assert ns["report"].all_passed, out


def test_student_and_instructor_pages():
    index = (ROOT / "exercises" / "index.md").read_text()
    for name in NOTEBOOKS.values():
        assert name in index
    assert "run_public_tests" in index and "Gradescope" in index
    instructors = (ROOT / "chapters" / "instructors.md").read_text()
    for needle in ("python -m autograder grade", "python -m autograder batch", "python -m autograder bundle",
                   "run_autograder", "AUTOGRADER_ROOT", "autograder/exercises", "RLIMIT_NPROC", "calibrate"):
        assert needle in instructors, needle


def test_equation_references_exist_in_the_chapters():
    """Every {eq} label an exercise cites is defined by a labelled equation of a chapter."""
    labels = set()
    for path in (ROOT / "chapters").glob("*.ipynb"):
        src = "\n".join(c.source for c in nbformat.read(path, as_version=4).cells if c.cell_type == "markdown")
        labels |= set(re.findall(r"\$\$\s*\(([\w-]+)\)", src))
    cited = set()
    for exercise in EXERCISES:
        text = "\n".join(c.source for c in _nb(exercise).cells if c.cell_type == "markdown")
        cited |= set(re.findall(r"\{eq\}`([\w-]+)`", text))
    assert cited, "the exercises cite no chapter equation"
    assert cited <= labels, f"undefined equation labels: {sorted(cited - labels)}"
