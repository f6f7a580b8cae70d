"""The book's text against its code: numbers in prose, the reference pages, citations and seeds.

* Every chapter's prose passes ``tools/prose_check.py``: each number is glued, a literal of the code
  beside it, a default of a library function the chapter calls, or one of the checker's few allowed
  kinds; no development history; every glue role names a glued value.
* The checker itself is tested on small notebooks built here, so that it can fail.
* The reference pages: the introduction lists every chapter; every citation key exists in
  ``references.bib`` and every entry there is well formed; the notation table has one row per
  symbol; the seed policy stated in the notation page holds in every chapter.
* The data files: every file of ``chapters/data`` is listed on the instructors' page with the commands that
  made it and the chapters that read it, and every command quoted for one of them, anywhere, is a listed one.
* Every library name the text cites (``sl.name``, ``slamlib.module.name`` in code spans and the ``{func}``-like
  roles) exists.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import nbformat
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tools.prose_check import ALLOWED, HISTORY, check_notebook, clean_prose  # noqa: E402

CHAPTERS = sorted((ROOT / "chapters").glob("[0-9][0-9]_*.ipynb"))
PAGES = sorted((ROOT / "chapters").glob("*.md"))

@pytest.mark.parametrize("path", CHAPTERS, ids=lambda p: p.name)
def test_chapter_prose_is_backed_by_code(path):
    findings = check_notebook(path)
    assert not findings, "unbacked prose:\n" + "\n".join(map(str, findings))


# ----------------------------------------------------------------------------- the checker itself
def _nb(*cells, path):
    nb = nbformat.v4.new_notebook()
    for kind, src in cells:
        nb.cells.append(nbformat.v4.new_markdown_cell(src) if kind == "md" else nbformat.v4.new_code_cell(src))
    nbformat.write(nb, path)
    return path


def _numbers(findings):
    return sorted(f.number for f in findings)


def test_checker_flags_a_typed_result(tmp_path):
    p = _nb(("code", "x = run()"), ("md", "The filter ends 0.63 m from the truth, 4.5 times better; "
                                          "the loop closes at step 470 (Step 2 of the derivation)."),
            path=tmp_path / "a.ipynb")
    assert _numbers(check_notebook(p)) == ["0.63", "4.5", "470"]


def test_checker_accepts_glue_literals_beside_and_allowed_kinds(tmp_path):
    p = _nb(("code", "from myst_nb import glue\nglue('ate', 0.63, display=False)\nn = 50\ngate = 0.3"),
            ("md", "It ends {glue:text}`ate:.2f` m off with 50 particles and a 30 cm gate (Table 8.3, "
                   "Eq. 11.17, FastSLAM 2.0 in SE(2), robots 3 and 5, data of 2011).\n\n1. a list item"),
            path=tmp_path / "b.ipynb")
    assert check_notebook(p) == []


def test_checker_needs_the_literal_beside_the_prose_not_anywhere(tmp_path):
    p = _nb(("code", "n = 50"), ("md", "text"), ("code", "x = 1"), ("md", "With 50 particles."),
            ("code", "y = 2"), path=tmp_path / "c.ipynb")
    assert _numbers(check_notebook(p)) == ["50"]


def test_checker_needs_the_code_cell_right_beside_the_prose(tmp_path):
    # a literal across a heading or another paragraph is not beside the number it would back
    p = _nb(("code", "n = 50"), ("md", "## A section"), ("md", "With 50 particles."), ("md", "Then 7 more."),
            ("code", "k = 7"), path=tmp_path / "c2.ipynb")
    assert _numbers(check_notebook(p)) == ["50"]


def test_checker_ignores_formulas_but_not_bare_numbers_in_math(tmp_path):
    p = _nb(("code", "x = 1"), ("md", "With $k^2 = 7.81$ and $$\\chi^2 = 3$$ but $7598$ poses."),
            path=tmp_path / "d.ipynb")
    assert _numbers(check_notebook(p)) == ["7598"]


def test_checker_reports_unknown_glue_names_and_history(tmp_path):
    p = _nb(("code", "from myst_nb import glue\nglue(f'ate_{r}', 1.0)"),
            ("md", "{glue:text}`ate_3:.2f` and {glue:text}`missing:.1f`; the previous default was worse."),
            path=tmp_path / "e.ipynb")
    found = check_notebook(p)
    assert [f.number for f in found] == ["missing", "the previous default"]


def test_checker_matches_units_and_library_defaults(tmp_path):
    # sl.icp's defaults: max_dist=0.3, trim=0.8
    p = _nb(("code", "r = sl.icp(a, b, c)"), ("md", "Pairs beyond 30 cm are dropped and 80 % are kept; 45 cm is typed."),
            path=tmp_path / "f.ipynb")
    assert _numbers(check_notebook(p)) == ["45"]


def test_allow_list_is_short_and_explained():
    assert len(ALLOWED) <= 8 and len(HISTORY) <= 8
    for pattern, why in ALLOWED + HISTORY:
        re.compile(pattern)
        assert len(why.split()) >= 4, f"allow-list entry {pattern!r} needs a reason"


def test_clean_prose_drops_roles_code_and_fences():
    text, n_glue = clean_prose("A {cite}`x2001` `code 5` {glue:text}`k:.1f`\n```{literalinclude} f.py\n:lines: 3-9\n```\n")
    assert n_glue == 1 and not re.search(r"\d", text)


# ----------------------------------------------------------------------------- reference pages
def _markdown(path):
    if path.suffix == ".md":
        return path.read_text(encoding="utf-8")
    nb = nbformat.read(path, as_version=4)
    return "\n".join(c.source for c in nb.cells if c.cell_type == "markdown")


def test_intro_lists_every_chapter():
    intro = _markdown(ROOT / "chapters" / "00_intro.ipynb")
    missing = [p.stem for p in CHAPTERS if p.stem != "00_intro" and f"{{doc}}`{p.stem}`" not in intro]
    assert not missing, f"chapters/00_intro does not list {missing}"


def _bib_entries():
    text = (ROOT / "references.bib").read_text(encoding="utf-8")
    entries = {}
    for m in re.finditer(r"@(\w+)\{([^,]+),(.*?)\n\}", text, flags=re.S):
        fields = dict((k.lower(), v.strip()) for k, v in re.findall(r"^\s*(\w+)\s*=\s*(.+?),?\s*$", m.group(3), re.M))
        entries[m.group(2).strip()] = (m.group(1).lower(), fields)
    return entries


def test_every_cited_key_exists():
    keys = set(_bib_entries())
    used = set()
    for path in [*CHAPTERS, *PAGES]:
        for roles in re.findall(r"\{cite(?::\w+)?\}`([^`]+)`", _markdown(path)):
            used.update(k.strip() for k in roles.split(","))
    assert used, "no citations found: the pattern is wrong"
    assert not used - keys, f"cited but not in references.bib: {sorted(used - keys)}"


def test_bibliography_entries_are_well_formed():
    entries = _bib_entries()
    assert len(entries) >= 30
    for key, (kind, fields) in entries.items():
        assert "year" in fields, f"{key}: no year"
        assert "title" in fields and ("author" in fields), f"{key}: no title or author"
        if kind == "article":
            journal = fields.get("journal", "")
            assert journal and not journal.strip("{").startswith("Proceedings"), \
                f"{key}: an @article needs a journal (proceedings are @inproceedings)"
            assert "publisher" not in fields, f"{key}: an @article with a publisher is a book or a chapter"
        if kind == "inproceedings":
            assert "booktitle" in fields, f"{key}: @inproceedings needs a booktitle"
        if kind in ("book", "incollection"):
            assert "publisher" in fields, f"{key}: a book needs a publisher"


def _notation_rows():
    text = (ROOT / "chapters" / "notation.md").read_text(encoding="utf-8")
    table = text.split("## Symbols", 1)[1].split("\n## ", 1)[0]
    rows = [ln for ln in table.splitlines() if ln.startswith("| $")]
    return [ln.split("|")[1].strip() for ln in rows]


def _letters(symbol_cell):
    """The base letters a notation row defines: '$\\mu_t$, $\\Sigma_t$' -> {'mu', 'Sigma'}."""
    out = set()
    for math in re.findall(r"\$([^$]+)\$", symbol_cell):
        m = re.match(r"\s*(?:\\(?:overline|hat|bar|mathbf)\{)?\\?([A-Za-z]+)", math)
        if m and m.group(1) not in ("p", "bel", "text", "operatorname"):
            out.add(m.group(1))
    return out


def test_notation_has_one_row_per_symbol():
    seen = {}
    for cell in _notation_rows():
        for letter in _letters(cell):
            assert letter not in seen, (f"the symbol {letter} has two rows ({seen[letter]!r} and {cell!r}): "
                                        "give each symbol one row that lists all its meanings")
            seen[letter] = cell
    # the symbols every part of the book leans on, chapter 5's included
    for letter in ("x", "u", "z", "m", "mu", "Sigma", "M", "Q", "R", "alpha", "H", "rho", "nu", "w", "chi"):
        assert letter in seen, f"notation.md has no row for {letter}"


def test_notation_symbols_appear_in_the_chapters():
    book = "\n".join(_markdown(p) for p in CHAPTERS)
    for cell in _notation_rows():
        for math in re.findall(r"\$([^$]+)\$", cell):
            first = re.split(r"[,_^ ({]", math.strip(), maxsplit=1)[0]
            if first and first not in ("\\overline", "\\hat", "p", "bel"):
                assert first in book, f"notation.md lists {math!r}, which no chapter uses"


@pytest.mark.parametrize("path", CHAPTERS, ids=lambda p: p.name)
def test_one_seed_policy(path):
    """notation.md states it: each chapter sets SEED = its number once, every generator derives from it."""
    policy = (ROOT / "chapters" / "notation.md").read_text(encoding="utf-8")
    assert "(notation-seeds)=" in policy
    nb = nbformat.read(path, as_version=4)
    code = "\n".join(c.source for c in nb.cells if c.cell_type == "code")
    number = int(path.name[:2])
    if "default_rng" not in code:
        return  # draws no random numbers
    assert re.findall(r"^SEED = (\d+)$", code, re.M) == [str(number)], f"{path.name}: SEED must be {number}"
    literal = re.findall(r"default_rng\((\d+)\)", code)
    assert not literal, f"{path.name}: default_rng({literal[0]}): derive every generator from SEED"


@pytest.mark.parametrize("path", [p for p in CHAPTERS if p.name != "00_intro.ipynb"], ids=lambda p: p.name)
def test_every_question_has_an_answer(path):
    text = _markdown(path)
    assert "## Questions" in text, f"{path.name} has no questions"
    questions = text.split("## Questions", 1)[1].split("{admonition} Answers", 1)
    assert len(questions) == 2, f"{path.name}: the questions have no Answers admonition"
    n_q = len(re.findall(r"(?m)^\d+\. ", questions[0]))
    n_a = len(re.findall(r"(?m)^\d+\. ", questions[1].split("```", 1)[0]))
    assert n_q == n_a > 0, f"{path.name}: {n_q} questions, {n_a} answers"


# ----------------------------------------------------------------------------- the data files and their commands
DATA = ROOT / "chapters" / "data"
_COMMAND = re.compile(r"`(python (?:benchmarks|tools)/[^`]+)`")
#: a command line in a script's docstring that writes a data file (usage templates with [options] are not)
_SCRIPT_COMMAND = re.compile(r"(python (?:benchmarks|tools)/\S+\.py [^`#\n\[]*?chapters/data/[^\s`]+)")


def _data_table():
    """``{file: (commands, chapters)}`` from the instructors' page's table of the files the chapters read."""
    rows = {}
    for line in (ROOT / "chapters" / "instructors.md").read_text().splitlines():
        m = re.match(r"\| `chapters/data/([^`]+)` \| (.*) \| chapters? ([0-9, and]+) \|$", line)
        if m:
            rows[m[1]] = (_COMMAND.findall(m[2]), sorted(int(n) for n in re.findall(r"\d+", m[3])))
    return rows


def _quoted_commands():
    """Every ``python benchmarks/...`` or ``python tools/...`` command quoted in the README, a page, a chapter's
    prose or a script's docstring, with where it is quoted."""
    texts = [("README.md", (ROOT / "README.md").read_text())]
    texts += [(p.name, (p.read_text())) for p in PAGES]
    texts += [(p.name, c.source) for p in CHAPTERS for c in nbformat.read(p, as_version=4).cells if c.cell_type == "markdown"]
    quoted = [(name, cmd) for name, text in texts for cmd in _COMMAND.findall(text)]
    for p in sorted((ROOT / "benchmarks").glob("*.py")) + sorted((ROOT / "tools").glob("*.py")):  # their docstrings
        quoted += [(p.name, cmd) for cmd in _SCRIPT_COMMAND.findall(p.read_text())]
    return quoted


def test_every_data_file_has_its_commands_and_readers_listed():
    table = _data_table()
    assert sorted(table) == sorted(p.name for p in DATA.iterdir()), "chapters/instructors.md's table of data files"
    for name, (commands, readers) in table.items():
        assert commands, f"{name}: no command"
        read = [int(p.name[:2]) for p in CHAPTERS
                if any(c.cell_type == "code" and name in c.source for c in nbformat.read(p, as_version=4).cells)]
        assert read == readers, f"{name} is read by chapters {read}, the table says {readers}"
        if name.endswith(".json"):  # a file that records its own command was made by the listed ones
            recorded = json.loads((DATA / name).read_text()).get("command")
            assert recorded in (None, " + ".join(commands)), f"{name} records {recorded!r}, the table says {commands}"


def _stale(quoted, table):
    """The quoted commands that name a data file but are not among the commands listed for it."""
    return [f"{where}: `{cmd}` (listed: {table[f][0]})" for where, cmd in quoted for f in table
            if f"chapters/data/{f}" in cmd and cmd not in table[f][0]]


def test_a_command_quoted_for_a_data_file_is_the_listed_one():
    table, quoted = _data_table(), _quoted_commands()
    for where in ("README.md", "mcl_study.py", "mcl_holdout.py", "vo_study.py"):  # the README and the docstrings are read
        assert any(w == where and "chapters/data/" in cmd for w, cmd in quoted), where
    wrong = _stale(quoted, table)
    assert not wrong, "\n".join(wrong)


def test_the_command_checks_can_fail():
    table = _data_table()
    text = ("the study: `python benchmarks/mcl_study.py --updates 150 --configs defaults "
            "--json chapters/data/mcl_study_long.json`; the table: `python tools/mrclam_table.py` (no file named)")
    quoted = [("a chapter", cmd) for cmd in _COMMAND.findall(text)]
    assert len(quoted) == 2 and len(_stale(quoted, table)) == 1  # a stale copy is found, a bare mention is not
    listed = [("a chapter", table["mcl_study_long.json"][0][0])]
    assert _stale(listed, table) == []


# ----------------------------------------------------------------------------- the library names the text cites
_NAME = re.compile(r"`((?:sl|slamlib|autograder)(?:\.[A-Za-z_]\w*)+)(?:\(|`)")
_ROLE = re.compile(r"\{(?:func|class|meth|attr|mod)\}`~?([A-Za-z_][\w.]*)`")


def _resolves(name):
    """Whether a dotted name (``sl.`` for ``slamlib.``; a role's name may omit ``slamlib.``) is an object."""
    import importlib

    parts = name.split(".")
    parts[0] = "slamlib" if parts[0] == "sl" else parts[0]
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for attr in parts[i:]:
            if not hasattr(obj, attr):
                return False
            obj = getattr(obj, attr)
        return True
    return False


def _cited_names(texts):
    return [(where, m[1]) for where, text in texts for rx in (_NAME, _ROLE) for m in rx.finditer(text)]


def test_every_library_name_the_text_cites_exists():
    notebooks = CHAPTERS + sorted((ROOT / "exercises").glob("*.ipynb"))
    texts = [(p.name, c.source) for p in notebooks for c in nbformat.read(p, as_version=4).cells
             if c.cell_type == "markdown"]
    texts += [(p.name, p.read_text()) for p in PAGES + sorted((ROOT / "exercises").glob("*.md")) + [ROOT / "README.md"]]
    cited = _cited_names(texts)
    assert len(cited) > 100  # the text is read
    missing = [f"{where}: {name}" for where, name in cited if not (_resolves(name) or _resolves(f"slamlib.{name}"))]
    assert not missing, "\n".join(missing)


def test_a_name_the_library_lacks_is_found():
    cited = _cited_names([("a chapter", "Call `sl.run_mcl(model, ...)`, {func}`slamlib.mcl.prepare_mcl`, "
                                        "`sl.run_mcll` and {func}`~slamlib.sensors.no_such_model`.")])
    found = {n: _resolves(n) for _, n in cited}
    assert found == {"sl.run_mcl": True, "sl.run_mcll": False, "slamlib.mcl.prepare_mcl": True,
                     "slamlib.sensors.no_such_model": False}
