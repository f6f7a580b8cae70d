"""Find numbers in a chapter's prose that nothing in the chapter's code backs.

A literate chapter's text must not drift from its code. A number in a Markdown cell is *backed* when

1. it is glued: MyST-NB's ``{glue:text}`name:fmt``` (or ``{glue}``) inserts a value computed by a
   code cell (``myst_nb.glue(name, value, display=False)``), so the text cannot drift at all;
2. it is a literal of the code beside it, the cell just before or just after the Markdown cell when
   that cell is code (a setting the reader sees set, or the value an ``assert`` checks; a code cell
   beyond another Markdown cell is not beside it); a number with a unit is
   also matched in SI (``30 cm`` by ``0.3``, ``50 ms`` by ``0.05``, ``5 %`` by ``0.05``,
   ``3 deg`` by ``np.deg2rad(3)``'s ``3``);
3. it is a numeric default of a ``slamlib`` function the chapter calls (``sl.name(...)``): the
   library's setting the text describes, read from the signature, so changing the default fails the
   check until the text follows;
4. it matches one entry of :data:`ALLOWED`, a short list of patterns for numbers that are not results
   (references to numbered tables and equations, years, names such as ``SE(2)`` or ``FastSLAM 2.0``),
   each entry with the reason it is allowed.

Everything else is a finding. What the check ignores, because it is not prose: display and inline
math that is a formula (inline math that is a bare number, ``$7598$``, is prose), inline code, code
fences and directive options, MyST roles (``{eq}``, ``{numref}``, ``{cite}``, ``{doc}``...), labels,
link targets and HTML comments.

Usage::

    python tools/prose_check.py chapters/10_graph_slam.ipynb [...]   # exit 1 on findings

or ``from tools.prose_check import check_notebook`` (a list of :class:`Finding`).
"""

from __future__ import annotations

import argparse
import ast
import inspect
import io
import math
import re
import sys
import tokenize
from dataclasses import dataclass
from pathlib import Path

import nbformat

# (pattern, why it is not a result). A number is allowed when one of these matches a span of the
# cleaned prose that contains it. Keep this list short: each entry is a kind of number, not a number.
ALLOWED: tuple[tuple[str, str], ...] = (
    (r"\b(?:Tables?|Eqs?\.|Equations?|Chapters?|Ch\.|Sections?|Sec\.|Figures?|Fig\.|Algorithms?|Parts?|"
     r"Exercises?|exercises?|[Ll]ines?|pp?\.|chapters?|questions?|Questions?|answers?|Answers?|Steps?)"
     r"\s+\d+(?:\.\d+)*(?:\s*(?:-|–|,|and|or|to)\s*\d+(?:\.\d+)*)*",
     "a reference to a numbered table, equation, chapter, section, figure, algorithm, line or "
     "derivation Step of a textbook or of this book, not a quantity"),
    (r"\b(?:1[89]|20)\d\d\b",
     "a year (of a publication or of a data set's recording)"),
    (r"\b(?:FastSLAM|GraphSLAM|iSAM|SE|SO|g2o)\s*\(?\d(?:\.\d)?\)?|\b\d-D\b|\brank-\d\b|\b[01]-based\b|[A-Za-z_]+\d+\w*",
     "part of a name: FastSLAM 1.0 and 2.0, the groups SE(2), SO(3), '2-D', 'rank-2', '0-based' indexing, data "
     "sets like M3500"),
    (r"\b(?:[Rr]obots?|[Dd]ataset|[Bb]ox(?:es)?)\s+\d+(?:\s*(?:,|and|or|-|to)\s*\d+)*",
     "the number of a robot, a data set or a box within a collection (an identifier, as in MRCLAM)"),
    (r"(?m)^\s*\d+\.\s",
     "the number of a numbered list item"),
    (r"\b\d+\s*(?:x|×)\s*\d+\b",
     "the size of a matrix block, '3 x 3'"),
    (r"(?m)^\|\s*\d+\s*\|",
     "the line number in the first column of an algorithm written as a table"),
)

# Development history has no place in the student text (it belongs in chapters/instructors.md):
# phrases that tell the story of the code rather than the method. (pattern, what it signals)
HISTORY: tuple[tuple[str, str], ...] = (
    (r"(?i)\b(?:an |the )?(?:earlier|older|previous|former|old) (?:version|default|release|implementation)s?\b",
     "a previous state of the library"),
    (r"(?i)\bthe book's (?:former|old|earlier|previous)\b", "a previous state of the book"),
    (r"(?i)\b(?:during|in) (?:the )?development\b", "how the book was written"),
    (r"(?i)\bon the loaded machine\b|\bbusy machine\b", "the circumstances of one measurement"),
    (r"(?i)\bused to (?:be|give|take|fail|diverge)\b", "a previous state of the code"),
)

_UNITS = {  # unit -> factor to SI (matched case-sensitively after the number)
    "%": 0.01, "cm": 0.01, "mm": 1e-3, "ms": 1e-3, "km": 1e3, "deg": None, "degrees": None, "degree": None,
    "°": None,
}
_NUMBER = re.compile(r"(?:(?<![\w.\-])-)?(?<![\w.])\d+(?:,\d{3})*(?:\.\d+)?(?!\d)")
_UNIT_AFTER = re.compile(r"\s*(%|cm|mm|ms|km|degrees|degree|deg|°)")


@dataclass(frozen=True)
class Finding:
    notebook: str
    cell: int
    number: str
    context: str

    def __str__(self) -> str:
        return f"{self.notebook} cell {self.cell}: '{self.number}' in \"...{self.context}...\""


def _strip_fences(text: str) -> str:
    """Drop code fences and directive options; keep the bodies of admonitions (they are prose)."""
    out, fence, keep = [], None, False
    for line in text.splitlines():
        m = re.match(r"^\s*(`{3,}|~{3,})\s*(\{[\w:-]+\})?", line)
        if fence is None and m:
            fence = m.group(1)
            directive = m.group(2) or ""
            keep = directive in ("{admonition}", "{note}", "{tip}", "{hint}", "{important}", "{warning}",
                                 "{seealso}", "{dropdown}")
            out.append("")
            continue
        if fence is not None and line.strip() == fence:
            fence = None
            out.append("")
            continue
        if fence is not None and (not keep or re.match(r"^\s*:[\w-]+:", line)):
            out.append("")
            continue
        out.append(line)
    return "\n".join(out)


def _bare_number(math_text: str) -> bool:
    core = re.sub(r"\\(?:text|mathrm)\{[^}]*\}|\\[,;!: ]|~|\s|\{|\}", "", math_text)
    return bool(re.fullmatch(r"-?\d+(?:[.,]\d+)?%?", core))


def clean_prose(text: str) -> tuple[str, int]:
    """The prose of a Markdown cell with everything that is not prose removed, and the glue count."""
    n_glue = len(re.findall(r"\{glue(?::\w+)?\}`[^`]*`", text))
    text = re.sub(r"<!--.*?-->", " ", text, flags=re.S)
    text = _strip_fences(text)
    text = re.sub(r"\$\$.*?\$\$(\s*\([\w:-]+\))?", " ", text, flags=re.S)
    text = re.sub(r"\{[\w:-]+\}`[^`]*`", " ", text)            # roles: glue, eq, numref, cite, doc, ref
    text = re.sub(r"`[^`]*`", " ", text)                          # inline code
    text = re.sub(r"^\s*\([\w:-]+\)=\s*$", " ", text, flags=re.M)  # labels
    text = re.sub(r"\]\([^)]*\)", "] ", text)                      # link targets
    text = re.sub(r"https?://\S+", " ", text)
    text = re.sub(r"(?<!\\)\$(.+?)(?<!\\)\$", lambda m: m.group(1) if _bare_number(m.group(1)) else " MATH ",
                  text, flags=re.S)
    return text, n_glue


def _code_literals(source: str) -> set[float]:
    """Every numeric literal of a code cell (magics and shell lines skipped)."""
    lines = [ln for ln in source.splitlines() if not ln.lstrip().startswith(("%", "!"))]
    values: set[float] = set()
    try:
        for tok in tokenize.generate_tokens(io.StringIO("\n".join(lines) + "\n").readline):
            if tok.type == tokenize.NUMBER:
                try:
                    values.add(float(ast.literal_eval(tok.string.replace("_", ""))))
                except (ValueError, SyntaxError, TypeError):
                    pass
    except (tokenize.TokenError, IndentationError, SyntaxError):
        pass
    return values


def _library_defaults(code: str) -> set[float]:
    """Numeric defaults of the slamlib functions the chapter calls as ``sl.name(``."""
    try:
        import slamlib as sl
    except ImportError:  # pragma: no cover - the checker runs in the project's environment
        return set()
    values: set[float] = set()
    for name in set(re.findall(r"\bsl\.(\w+)\s*\(", code)):
        obj = getattr(sl, name, None)
        try:
            sig = inspect.signature(obj)
        except (TypeError, ValueError):
            continue
        for p in sig.parameters.values():
            d = p.default
            if isinstance(d, (int, float)) and not isinstance(d, bool):
                values.add(float(d))
            elif isinstance(d, tuple):
                values.update(float(v) for v in d if isinstance(v, (int, float)) and not isinstance(v, bool))
    return values


def _matches(value: float, unit: str | None, literals: set[float]) -> bool:
    candidates = {value}
    if unit in _UNITS and _UNITS[unit] is not None:
        candidates.add(value * _UNITS[unit])
    if unit in ("deg", "degrees", "degree", "°"):
        candidates.add(math.radians(value))
    # code writes a negative number as unary minus and a literal, so signs are not compared
    return any(math.isclose(abs(c), v, rel_tol=1e-9, abs_tol=1e-12) for c in candidates for v in literals)


def _allowed_spans(text: str) -> list[tuple[int, int]]:
    spans = []
    for pattern, _why in ALLOWED:
        spans += [m.span() for m in re.finditer(pattern, text)]
    return spans


def _glue_names(code: str) -> tuple[set[str], list[re.Pattern]]:
    """Names glued by ``glue("name", ...)``; f-string names become patterns."""
    names, patterns = set(), []
    for m in re.finditer(r"\bglue\(\s*(f?)([\"'])(.*?)\2", code):
        if m.group(1):
            patterns.append(re.compile("^" + re.sub(r"\\\{[^}]*\\\}", ".+", re.escape(m.group(3))) + "$"))
        else:
            names.add(m.group(3))
    return names, patterns


def check_notebook(path: str | Path) -> list[Finding]:
    """The numbers in the prose of one notebook that no glue, code literal, default or rule backs.

    Also reported: a ``{glue}`` role whose name no code cell glues, and development history
    (:data:`HISTORY`) in the prose.
    """
    path = Path(path)
    nb = nbformat.read(path, as_version=4)
    cells = nb.cells
    all_code = "\n".join(c.source for c in cells if c.cell_type == "code")
    defaults = _library_defaults(all_code)
    glued, glued_patterns = _glue_names(all_code)
    findings = []
    for k, cell in enumerate(cells):
        if cell.cell_type != "markdown":
            continue
        # the cells beside this one, when they are code: a literal further away, across other prose, backs nothing
        prev_code = cells[k - 1].source if k > 0 and cells[k - 1].cell_type == "code" else ""
        next_code = cells[k + 1].source if k + 1 < len(cells) and cells[k + 1].cell_type == "code" else ""
        literals = _code_literals(prev_code) | _code_literals(next_code) | defaults
        for m in re.finditer(r"\{glue(?::\w+)?\}`([^`:]+)", cell.source):
            name = m.group(1).strip()
            if name not in glued and not any(p.match(name) for p in glued_patterns):
                findings.append(Finding(path.name, k, name, "a glue role whose name no code cell glues"))
        for pattern, why in HISTORY:
            for m in re.finditer(pattern, cell.source):
                findings.append(Finding(path.name, k, m.group(0), f"development history ({why})"))
        text, _ = clean_prose(cell.source)
        spans = _allowed_spans(text)
        for m in _NUMBER.finditer(text):
            if any(a <= m.start() and m.end() <= b for a, b in spans):
                continue
            raw = m.group(0)
            value = float(raw.replace(",", ""))
            unit_m = _UNIT_AFTER.match(text, m.end())
            unit = unit_m.group(1) if unit_m else None
            if _matches(value, unit, literals):
                continue
            a, b = max(0, m.start() - 50), min(len(text), m.end() + 50)
            context = re.sub(r"\s+", " ", text[a:b]).strip()
            findings.append(Finding(path.name, k, raw, context))
    return findings


def _notebook(text):
    """An argparse type: the path of an existing notebook."""
    path = Path(text)
    if path.suffix != ".ipynb" or not path.is_file():
        raise argparse.ArgumentTypeError(f"{text!r} is not a notebook file (.ipynb)")
    return path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("paths", nargs="+", type=_notebook, metavar="NOTEBOOK", help="chapter notebooks (.ipynb) to check")
    paths = ap.parse_args(argv).paths
    total = 0
    for p in paths:
        found = check_notebook(p)
        total += len(found)
        for f in found:
            print(f)
    print(f"{total} unbacked number(s) in {len(paths)} notebook(s)")
    return 1 if total else 0


if __name__ == "__main__":
    sys.exit(main())
