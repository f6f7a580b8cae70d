"""The algorithm index (chapters/algorithm_index.md): every name, section, exercise and test it cites exists.

The page is a table per part of the book with the columns Algorithm | Source | slamlib | Chapter
section | Exercise | Test. For every row this checks that the ``sl.`` names are attributes of
``slamlib``, that the tables and algorithms cited in Source are the ones the implementation's
docstrings and comments cite, that the chapter links point to a heading, label or document that
exists, that the exercise grades the contract functions named, and that the tests are defined.
"""

from __future__ import annotations

import ast
import inspect
import json
import re
import sys
from functools import cache
from pathlib import Path

import pytest

import slamlib as sl
from autograder.exercises import all_exercises

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "chapters" / "algorithm_index.md"
HEADER = ["Algorithm", "Source", "slamlib", "Chapter section", "Exercise", "Test"]
NONE = "—"

# The algorithms the page must list (the list): a pattern on the Algorithm cell and the
# references its Source cell must cite.
REQUIRED = [
    (r"^Bayes rule", []),
    (r"^Bayes filter", ["Table 2.1"]),
    (r"^Histogram \(discrete Bayes\) filter", ["Table 4.1"]),
    (r"^Grid localization", ["Table 8.1"]),
    (r"^Velocity motion model: noise-free arc, Jacobians", ["Table 5.3", "Table 7.2"]),
    (r"^Sampling the velocity motion model", ["Table 5.3"]),
    (r"^Velocity motion model density", ["Table 5.1"]),
    (r"^Odometry motion model density", ["Table 5.5"]),
    (r"^Sampling the odometry motion model", ["Table 5.6"]),
    (r"^Range-bearing landmark model", ["Table 7.2", "Table 10.1"]),
    (r"^Landmark measurement likelihood", ["Table 6.4"]),
    (r"^Beam model", ["Table 6.1"]),
    (r"^Likelihood field", ["Table 6.3"]),
    (r"^Kalman filter", ["Table 3.1"]),
    (r"^Extended Kalman filter", ["Table 3.3"]),
    (r"^EKF localization, known correspondences", ["Table 7.2"]),
    (r"^EKF localization, unknown correspondences", ["Table 7.3"]),
    (r"^Importance weights and effective sample size", ["Table 4.3"]),
    (r"^Particle filter$", ["Table 4.3"]),
    (r"^Low-variance \(systematic\) sampler", ["Table 4.4"]),
    (r"^Multinomial resampling", []),
    (r"^Stratified resampling", []),
    (r"^Residual resampling", []),
    (r"^Monte Carlo localization", ["Table 8.2"]),
    (r"^Augmented MCL", ["Table 8.3"]),
    (r"^KLD-sampling MCL", ["Table 8.4"]),
    (r"^EKF SLAM, known correspondences", ["Algorithm 1", "Table 10.1"]),
    (r"^EKF SLAM, unknown correspondences", ["Algorithm 2", "Table 10.2"]),
    (r"^FastSLAM 1\.0, known correspondences", ["Algorithm 3", "Table 13.1"]),
    (r"^FastSLAM 1\.0, unknown correspondences", ["Table 13.2"]),
]

CODE = re.compile(r"`([^`]+)`")
ROLE = re.compile(r"\{(doc|ref)\}`([^`]+)`")
LINK = re.compile(r"\[([^\]]+)\]\(([^)#\s]+)(?:#([^)\s]+))?\)")


# --------------------------------------------------------------------------- parsing


def _cells(line):
    return [c.strip() for c in line.strip().strip("|").split("|")]


def _parse_page():
    """(header, rows) of every table on the page; a row is a dict column -> cell text."""
    tables, lines = [], PAGE.read_text(encoding="utf-8").splitlines()
    i = 0
    while i < len(lines):
        if lines[i].startswith("|") and i + 1 < len(lines) and re.fullmatch(r"\|(\s*:?-+:?\s*\|)+", lines[i + 1].strip()):
            header, rows, i = _cells(lines[i]), [], i + 2
            while i < len(lines) and lines[i].startswith("|"):
                rows.append(_cells(lines[i]))
                i += 1
            tables.append((header, rows))
        else:
            i += 1
    return tables


TABLES = _parse_page()
ROWS = [dict(zip(HEADER, cells)) for _, rows in TABLES for cells in rows]


def _target_text(target):
    """The title text of a role ``text <target>`` or ``target``, and the target."""
    m = re.fullmatch(r"(.*?)\s*<([^>]+)>", target)
    return (m.group(1), m.group(2)) if m else (None, target)


def _doc_path(target, base=PAGE.parent):
    """The file of a document name (relative to the page, without or with its suffix), or None."""
    path = (base / target).resolve()
    for cand in (path, path.with_suffix(".md"), path.with_suffix(".ipynb")):
        if cand.suffix in (".md", ".ipynb") and cand.is_file():
            return cand
    return None


@cache
def _markdown(path):
    """The Markdown text of a page: the file itself, or a notebook's markdown cells."""
    if path.suffix == ".md":
        return path.read_text(encoding="utf-8")
    nb = json.loads(path.read_text(encoding="utf-8"))
    return "\n\n".join("".join(c["source"]) for c in nb["cells"] if c["cell_type"] == "markdown")


def _slug(title):
    """The heading anchor myst-parser makes (``myst_heading_anchors``; GitHub's rule)."""
    return re.sub(r"[^\w\u4e00-\u9fff\- ]", "", title.lower().replace(" ", "-"))


@cache
def _anchors(path):
    """Anchors of the headings of levels 1-3 (with myst's -1, -2 suffixes for repeats) and labels."""
    anchors, text = {}, _markdown(path)
    in_fence = False
    for line in text.splitlines():
        if line.lstrip().startswith(("```", "~~~")):
            in_fence = not in_fence
        if in_fence:
            continue
        m = re.match(r"^(#{1,3}) +(.+?)\s*#*\s*$", line)
        if m:
            slug, k = _slug(m.group(2)), 1
            while slug in anchors:
                slug = f"{_slug(m.group(2))}-{k}"
                k += 1
            anchors[slug] = m.group(2)
    for label in re.findall(r"^\(([^()\s]+)\)=\s*$", text, flags=re.M):
        anchors[label] = label
    return anchors


@cache
def _labels():
    """Every ``(label)=`` target in the book's pages."""
    labels = set()
    for folder in ("chapters", "exercises"):
        for path in (ROOT / folder).glob("*"):
            if path.suffix in (".md", ".ipynb"):
                labels.update(re.findall(r"^\(([^()\s]+)\)=\s*$", _markdown(path), flags=re.M))
    return labels


@cache
def _test_names(path):
    """``name`` and ``Class::name`` of the test functions defined in a test file."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    names = set()
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            names.add(node.name)
        elif isinstance(node, ast.ClassDef):
            names.update(f"{node.name}::{f.name}" for f in node.body if isinstance(f, ast.FunctionDef))
    return names


def _numbers(text, word):
    """``{"Table 5.1", "Table 5.2"}`` from ``Tables 5.1 and 5.2`` (``word``: Table or Algorithm)."""
    num = r"\d+(?:\.\d+)?" if word == "Algorithm" else r"\d+\.\d+"
    out = set()
    for m in re.finditer(rf"\b{word}s?\s+({num}(?:\s*(?:,|and|&)\s*(?:{word}s?\s+)?{num})*)", text):
        out.update(f"{word} {n}" for n in re.findall(num, m.group(1)))
    return out


def _slamlib_object(name):
    """The object ``sl.a.b`` names, or None when slamlib has no such attribute."""
    obj = sl
    for part in name.removeprefix("sl.").split("."):
        if not hasattr(obj, part):
            return None
        obj = getattr(obj, part)
    return obj


def _slamlib_objects(cell):
    return [_slamlib_object(name) for name in CODE.findall(cell)]


def _cited_by(obj):
    """The text in which ``obj``'s implementation cites its sources: source, docstring, module docstring."""
    parts = [inspect.getdoc(obj) or ""]
    try:
        parts.append(inspect.getsource(obj))
    except (TypeError, OSError):
        pass
    module = sys.modules.get(getattr(obj, "__module__", ""), None)
    parts.append(getattr(module, "__doc__", "") or "")
    return "\n".join(parts)


def _row_id(row):
    return row["Algorithm"][:60]


# --------------------------------------------------------------------------- the page as a whole


def test_page_has_tables_with_the_columns_and_no_empty_cell():
    assert TABLES, "chapters/algorithm_index.md has no table"
    for header, rows in TABLES:
        assert header == HEADER, f"a table's header is {header}, expected {HEADER}"
        assert rows, "a table has no rows"
        for cells in rows:
            assert len(cells) == len(HEADER), f"row {cells[0]!r} has {len(cells)} cells, expected {len(HEADER)}"
            empty = [h for h, c in zip(HEADER, cells) if not c]
            assert not empty, f"row {cells[0]!r} has empty cells: {empty} (write {NONE!r} for 'none')"


def test_page_is_in_the_toc():
    toc = (ROOT / "_toc.yml").read_text(encoding="utf-8")
    assert re.search(r"^\s*- file:\s*chapters/algorithm_index\s*$", toc, flags=re.M)


def test_algorithms_are_listed_once():
    names = [r["Algorithm"] for r in ROWS]
    assert len(names) == len(set(names)), "an algorithm is listed twice"


@pytest.mark.parametrize("pattern, sources", REQUIRED, ids=[p.strip("^$").replace("\\", "") for p, _ in REQUIRED])
def test_required_algorithm_is_listed_with_its_source(pattern, sources):
    rows = [r for r in ROWS if re.search(pattern, r["Algorithm"])]
    assert rows, f"no row for the algorithm {pattern!r}"
    cited = set().union(*(_numbers(r["Source"], "Table") | _numbers(r["Source"], "Algorithm") for r in rows))
    missing = [s for s in sources if s not in cited]
    assert not missing, f"row {rows[0]['Algorithm']!r} does not cite {missing}"


def test_every_contract_function_is_indexed():
    listed = set()
    for r in ROWS:
        if r["Exercise"] != NONE:
            listed.update(CODE.findall(r["Exercise"]))
    missing = [f for ex in all_exercises() for f in ex.functions if f not in listed]
    assert not missing, f"contract functions graded by an exercise but not on the index: {missing}"


# --------------------------------------------------------------------------- row by row


@pytest.mark.parametrize("row", ROWS, ids=_row_id)
def test_slamlib_names_exist(row):
    names = CODE.findall(row["slamlib"])
    assert names, f"{row['Algorithm']!r}: no `sl.name` in the slamlib column"
    for name in names:
        assert name.startswith("sl."), f"{row['Algorithm']!r}: write slamlib names as `sl.{name}`"
        assert _slamlib_object(name) is not None, f"{row['Algorithm']!r}: slamlib has no {name}"


@pytest.mark.parametrize("row", ROWS, ids=_row_id)
def test_source_agrees_with_the_implementation(row):
    """Each table (and course algorithm) in Source is cited by one of the row's slamlib objects."""
    cited = set()
    for obj in _slamlib_objects(row["slamlib"]):
        text = _cited_by(obj)
        cited |= _numbers(text, "Table") | _numbers(text, "Algorithm")
    claimed = _numbers(row["Source"], "Table") | _numbers(row["Source"], "Algorithm")
    stray = sorted(claimed - cited)
    assert not stray, (f"{row['Algorithm']!r}: Source cites {stray}, which none of "
                       f"{CODE.findall(row['slamlib'])} cites in its docstring or code")


def _chapter(row, target):
    """The chapter file a link of `row` points to; fails when it is missing or not a chapter."""
    path = _doc_path(target)
    assert path is not None, f"{row['Algorithm']!r}: {target} does not exist"
    assert path.parent == ROOT / "chapters", f"{row['Algorithm']!r}: {target} is not a chapter"
    return path


@pytest.mark.parametrize("row", ROWS, ids=_row_id)
def test_chapter_section_resolves(row):
    cell = row["Chapter section"]
    links, roles = LINK.findall(cell), ROLE.findall(cell)
    assert links or roles, f"{row['Algorithm']!r}: the chapter cell links nowhere"
    for text, target, anchor in links:
        path = _chapter(row, target)
        if anchor:
            anchors = _anchors(path)
            assert anchor in anchors, f"{row['Algorithm']!r}: {target} has no heading or label {anchor!r}"
            assert _slug(text) == anchor, f"{row['Algorithm']!r}: link text {text!r} is not the title of #{anchor}"
    for role, target in roles:
        _, target = _target_text(target)
        if role == "doc":
            _chapter(row, target)
        else:
            assert target in _labels(), f"{row['Algorithm']!r}: no label ({target})= in the book"


@pytest.mark.parametrize("row", ROWS, ids=_row_id)
def test_exercise_exists_and_grades_the_functions(row):
    cell = row["Exercise"]
    if cell == NONE:
        return
    docs = [t for role, t in ROLE.findall(cell) if role == "doc"]
    assert len(docs) == 1, f"{row['Algorithm']!r}: the exercise cell needs one {{doc}} link to an exercise, or {NONE!r}"
    path = _doc_path(_target_text(docs[0])[1])
    assert path is not None and path.parent == ROOT / "exercises" and path.suffix == ".ipynb", (
        f"{row['Algorithm']!r}: {docs[0]} is not an exercise notebook")
    by_notebook = {ex.notebook: ex for ex in all_exercises()}
    assert path.name in by_notebook, f"{row['Algorithm']!r}: no autograder exercise uses {path.name}"
    functions = [n for n in CODE.findall(cell) if "<" not in n]
    assert functions, f"{row['Algorithm']!r}: name the contract function(s) the exercise grades"
    graded = by_notebook[path.name].functions
    wrong = [f for f in functions if f not in graded]
    assert not wrong, f"{row['Algorithm']!r}: {path.name} does not grade {wrong} (it grades {list(graded)})"
    missing = [f for f in functions if not hasattr(sl, f)]
    assert not missing, f"{row['Algorithm']!r}: slamlib has no reference implementation of {missing}"


@pytest.mark.parametrize("row", ROWS, ids=_row_id)
def test_tests_exist(row):
    ids = CODE.findall(row["Test"])
    assert ids, f"{row['Algorithm']!r}: no test named"
    for node in ids:
        file, sep, name = node.partition("::")
        assert sep and file.startswith("tests/") and file.endswith(".py"), f"{row['Algorithm']!r}: {node!r} is not a node id"
        path = ROOT / file
        assert path.is_file(), f"{row['Algorithm']!r}: {file} does not exist"
        assert name in _test_names(path), f"{row['Algorithm']!r}: {file} defines no {name}"
