"""Reading a submission without running it: notebook or Python file to code units.

A notebook's code cells are read with :mod:`nbformat` (no kernel). IPython
syntax is dropped with a note: cells starting with a ``%%`` cell magic (but the
magics whose body IPython runs as Python, ``%%time``, ``%%timeit``, ``%%capture``
and ``%%prun``, lose their first line only), lines starting with ``%`` (line
magics) or ``!`` (shell escapes), and help lines (``name?``, ``name??``,
``?name``). Cells tagged
``skip-grading`` are left out. Each remaining cell becomes one *unit* that the
child executes statement by statement (a statement that raises is skipped, so a
broken plotting cell does not cost the functions defined elsewhere).

The static checks here parse every unit with :mod:`ast`: syntax errors, and which
contract functions depend on an import of ``slamlib`` or ``autograder`` (directly,
or through helper functions and module-level names of the submission).
"""

from __future__ import annotations

import ast
import builtins
import json
import os
import re
import stat
import warnings
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["Submission", "SubmissionError", "load_submission", "forbidden_usage", "decode_python_source", "SKIP_TAG"]

SKIP_TAG = "skip-grading"
FORBIDDEN = ("slamlib", "autograder")
#: a line magic, a shell escape, a help line (``obj?``, ``obj.attr??``, ``?obj``: a ``?`` is never Python
#: outside strings and comments, and the line holds nothing else), or a magic or shell escape assigned to a name
#: (``files = !ls``, ``t = %timeit -o f()``: ``= !`` and ``= %`` are never Python)
_MAGIC_LINE = re.compile(r"^\s*(?:[%!]|\?{1,2}\s*[A-Za-z_*][\w.*]*\s*$|[A-Za-z_*][\w.*]*\s*\?{1,2}\s*$"
                         r"|[A-Za-z_][\w.]*\s*=\s*[%!])")
#: cell magics whose body IPython runs as Python: the cell is graded without its first line
PYTHON_CELL_MAGICS = ("%%time", "%%timeit", "%%capture", "%%prun")
#: Most code the grader parses, summed over the cells it grades [characters]. Python's parser holds several
#: hundred bytes per character of some code (a flat list of names: ~700), in the grader's own process, where no
#: sandbox limit applies; an exercise's code is a few tens of kilobytes.
MAX_CODE = 512 * 1024
#: Most JSON objects and arrays (``{`` and ``[`` characters, strings included) of a notebook the grader parses: a
#: notebook of a thousand cells holds a few thousand; outputs are where there may be more (clear them).
MAX_JSON_CONTAINERS = 250_000


class SubmissionError(Exception):
    """The file cannot be graded at all (unreadable, unsupported type ...)."""


@dataclass
class Submission:
    """A submission's code, ready to be sent to child processes.

    Attributes
    ----------
    path : Path
        The file.
    kind : str
        ``"notebook"`` or ``"python"``.
    units : list of dict
        ``{"source", "filename", "label"}`` per code cell (notebook) or one for the file.
    exercise : str or None
        The exercise named in the notebook metadata (``metadata["slam_course"]["exercise"]``).
    notes : list of str
        What was dropped or could not be parsed.
    syntax_errors : dict
        Unit label -> message, for units that do not parse.
    """

    path: Path
    kind: str
    units: list
    exercise: str | None = None
    notes: list = field(default_factory=list)
    syntax_errors: dict = field(default_factory=dict)
    sha256: str = ""

    @property
    def display_name(self):
        # the name's bytes as UTF-8, whatever the grader's locale (``jos\udcc3\udca9.py`` is ``josé.py``)
        return os.fsencode(self.path.name).decode("utf-8", "backslashreplace")


def _statement_starts(lines):
    """For each line, whether it begins a logical line: outside brackets and strings, not after a backslash.

    One pass over the characters (a cell may hold thousands of lines, and this runs in the grader's own
    process): brackets, string quotes (short and triple, with escapes), comments and backslash continuations
    are followed; a line that begins a logical line and looks like a magic is taken as one and not scanned.
    """
    out, depth, quote, cont = [], 0, None, False
    for line in lines:
        start = depth == 0 and quote is None and not cont
        out.append(start)
        if start and _MAGIC_LINE.match(line):
            continue
        cont, i, n = False, 0, len(line)
        while i < n:
            c = line[i]
            if quote is not None:
                if c == "\\":
                    i += 2
                elif line.startswith(quote, i):
                    i += len(quote)
                    quote = None
                else:
                    i += 1
                continue
            if c == "#":
                break
            if c in "([{":
                depth += 1
            elif c in ")]}":
                depth = max(depth - 1, 0)
            elif c in "'\"":
                quote = line[i:i + 3] if line[i:i + 3] in ("'''", '"""') else c
                i += len(quote)
                continue
            elif c == "\\" and not line[i + 1:].strip():
                cont = True
            i += 1
        if quote is not None and len(quote) == 1 and not line.rstrip("\r\n").endswith("\\"):
            quote = None  # an unclosed short string ends with its line (a syntax error Python reports)
    return out


def _strip_magics(source, label, notes):
    """The cell with IPython's magic, shell and help lines (``%``, ``!``, ``name?`` at the start of a logical line)
    left out; a cell magic leaves the whole cell out, unless IPython runs its body as Python
    (:data:`PYTHON_CELL_MAGICS`: then only its first line is left out).

    A line that begins with ``%`` or ``!`` inside brackets or after a backslash is Python (an operator carried
    over from the line before, as code formatters write it), not a magic: a cell that parses as Python is left
    as it is, and otherwise a line is a magic only where the code before it is complete.
    """
    lines = source.splitlines(True)
    if lines and lines[0].lstrip().startswith("%%"):
        magic = lines[0].split()[0]
        if magic not in PYTHON_CELL_MAGICS:
            notes.append(f"{label}: cell magic {magic} -- the whole cell is left out")
            return ""
        notes.append(f"{label}: cell magic {magic} -- its first line left out, the rest graded as Python")
        lines[0] = "\n"  # line numbers unchanged
        source = "".join(lines)
    if not any(_MAGIC_LINE.match(line) for line in lines):
        return source
    try:
        ast.parse(source)
        return source  # valid Python: every such line is an operator carried over
    except (SyntaxError, ValueError, RecursionError, MemoryError):
        pass
    out = []
    dropped = 0
    for line, start in zip(lines, _statement_starts(lines)):
        if start and _MAGIC_LINE.match(line):
            dropped += 1
            # a `pass` at the same indentation keeps blocks valid and line numbers unchanged
            indent = line[: len(line) - len(line.lstrip())]
            out.append(f"{indent}pass  # IPython line left out\n")
        else:
            out.append(line)
    if dropped:
        notes.append(f"{label}: {dropped} IPython magic/shell line{'s' if dropped > 1 else ''} left out")
    return "".join(out)


def load_submission(path, *, max_code=MAX_CODE):
    """Read ``path`` (``.ipynb`` or ``.py``) into a :class:`Submission`.

    At most `max_code` characters of code (the units' sources, summed) are read.

    Raises
    ------
    SubmissionError
        If the file is missing, not a readable notebook, or of another type.
    """
    path = Path(path)
    if path.is_symlink():
        # the grader may run as root: a link could make it read (and echo) its own files or another student's
        raise SubmissionError(f"{path.name}: a symbolic link, not a file (links are not followed; grade the file "
                              "itself)")
    if not path.is_file():
        raise SubmissionError(f"{path.name}: no such file")
    suffix = path.suffix.lower()
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)  # the check above may race a new link
        with os.fdopen(fd, "rb") as fh:
            if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):
                raise SubmissionError(f"{path.name}: not a regular file")
            raw = fh.read((50 << 20) + 1)
    except OSError as exc:
        raise SubmissionError(f"{path.name}: cannot be read ({exc})") from None
    if len(raw) > 50 << 20:
        raise SubmissionError(f"{path.name}: the file is larger than 50 MB")
    if suffix == ".py":
        text = decode_python_source(raw, path.name)
        sub = Submission(path, "python", [{"source": text, "filename": path.name, "label": path.name}])
    elif suffix == ".ipynb":
        try:
            sub = _load_notebook(path, raw, max_code)
        except SubmissionError:
            raise
        except Exception as exc:  # noqa: BLE001 - any value of the untrusted JSON the reader did not expect
            raise SubmissionError(f"{path.name}: not a readable Jupyter notebook ({type(exc).__name__}: "
                                  f"{_quoted(exc)})") from None
    else:
        raise SubmissionError(f"{path.name}: unsupported file type (submit the exercise notebook .ipynb or a .py file)")
    from .seeds import content_hash

    sub.sha256 = content_hash(raw)
    size = sum(len(unit["source"]) for unit in sub.units)
    if size > max_code:
        raise _too_much_code(path.name, size, max_code)
    for unit in sub.units:
        try:
            # the number of top-level statements: the sandbox accepts the loader's "statement k is running" for these
            unit["statements"] = len(ast.parse(unit["source"], filename=unit["filename"]).body)
        except SyntaxError as exc:
            msg = f"syntax error at line {exc.lineno}: {exc.msg}"
            sub.syntax_errors[unit["label"]] = msg
            sub.notes.append(f"{unit['label']}: {msg} -- nothing in it can be graded")
        except ValueError as exc:  # null bytes
            sub.syntax_errors[unit["label"]] = str(exc)
            sub.notes.append(f"{unit['label']}: {exc}")
        except (RecursionError, MemoryError):  # an expression nested too deeply for the parser
            msg = "too deeply nested for Python's parser"
            sub.syntax_errors[unit["label"]] = msg
            sub.notes.append(f"{unit['label']}: {msg} -- nothing in it can be graded")
    return sub


def decode_python_source(raw, name="submission.py"):
    """Text of a Python file as Python reads it: a UTF-8 byte-order mark or a PEP 263
    coding cookie (``# -*- coding: latin-1 -*-``) decide the encoding; CRLF and CR line
    ends become LF.

    Raises
    ------
    SubmissionError
        If the bytes are not valid in the declared (or default UTF-8) encoding.
    """
    import io
    import tokenize

    try:
        encoding, _ = tokenize.detect_encoding(io.BytesIO(raw).readline)
        text = raw.decode(encoding)
    except (SyntaxError, LookupError, UnicodeDecodeError) as exc:
        raise SubmissionError(f"{name}: not a readable Python text file ({_quoted(exc)}); save it as UTF-8") from None
    if text.startswith("\ufeff"):
        text = text[1:]
    return text.replace("\r\n", "\n").replace("\r", "\n")


def _quoted(exc, n=200):
    """A message about the notebook's content (which may hold the content), on one line and cut short."""
    text = " ".join(str(exc).split())
    return text if len(text) <= n else text[: n - 3] + "..."


def _too_much_code(name, size, max_code):
    return SubmissionError(f"{name}: {size // 1024} KB of code, more than the {max_code // 1024} KB the grader reads "
                           "(keep data out of the code: load it from a file or generate it)")


def _graded_cells(data):
    """The cell dicts of a parsed notebook (nbformat 4: ``cells``; 3: ``worksheets[*].cells``)."""
    lists = [data.get("cells")]
    if isinstance(data.get("worksheets"), list):
        lists += [w.get("cells") for w in data["worksheets"] if isinstance(w, dict)]
    return [c for cells in lists if isinstance(cells, list) for c in cells if isinstance(c, dict)]


def _load_notebook(path, raw, max_code=MAX_CODE):
    import nbformat

    # the JSON is read in the grader's own process: a notebook of millions of tiny objects ({} {} {} ...) costs
    # about 190 bytes of memory per byte, so the number of objects is bounded before it is parsed
    containers = raw.count(b"{") + raw.count(b"[")
    if containers > MAX_JSON_CONTAINERS:
        raise SubmissionError(f"{path.name}: a notebook of {containers} JSON objects and arrays, more than the "
                              f"{MAX_JSON_CONTAINERS} the grader reads (clear the outputs and save it again)")
    try:
        data = json.loads(raw.decode("utf-8-sig"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise SubmissionError(f"{path.name}: not a Jupyter notebook (invalid JSON: {_quoted(exc)})") from None
    if not isinstance(data, dict) or not ("cells" in data or "worksheets" in data):
        raise SubmissionError(f"{path.name}: not a Jupyter notebook (no cells)")
    for cell in _graded_cells(data):  # outputs are not graded: nbformat never sees (nor validates) them
        if "outputs" in cell:
            cell["outputs"] = []
        cell.pop("attachments", None)
    try:
        with warnings.catch_warnings():  # nbformat's warnings (a missing cell id) are no grader's output
            warnings.simplefilter("ignore")
            nb = nbformat.reads(json.dumps(data), as_version=4)
    except Exception as exc:  # noqa: BLE001 - nbformat raises many kinds
        raise SubmissionError(f"{path.name}: not a readable Jupyter notebook ({type(exc).__name__}: {_quoted(exc)})") \
            from None
    notes = []
    units = []
    code_index = 0
    size = 0
    for cell in nb.cells:
        if not isinstance(cell, dict) or cell.get("cell_type") != "code":
            continue
        code_index += 1
        label = f"code cell {code_index}"
        meta = cell.get("metadata")
        tags = meta.get("tags") if isinstance(meta, dict) else None  # untrusted: any JSON value
        if isinstance(tags, list) and SKIP_TAG in [t for t in tags if isinstance(t, str)]:
            continue
        source = cell.get("source", "")
        if isinstance(source, list):
            source = "".join(source)
        if not isinstance(source, str):
            continue
        size += len(source)
        if size > max_code:  # before any parse (a cell with a magic line is parsed to find it)
            raise _too_much_code(path.name, size, max_code)
        source = _strip_magics(source.replace("\r\n", "\n").replace("\r", "\n"), label, notes)
        if not source.strip():
            continue
        units.append({"source": source, "filename": f"{path.name}, {label}", "label": label})
    meta = nb.get("metadata")
    meta = meta.get("slam_course") if isinstance(meta, dict) else None
    exercise = meta.get("exercise") if isinstance(meta, dict) else None
    if isinstance(exercise, str) and len(exercise) > 100:  # no exercise has so long a name; it is quoted in messages
        exercise = exercise[:97] + "..."
    sub = Submission(path, "notebook", units, exercise if isinstance(exercise, str) else None, notes)
    return sub


# --------------------------------------------------------------------------- static dependency analysis
def _is_forbidden_module(name):
    return isinstance(name, str) and name.split(".")[0] in FORBIDDEN


def _bound_names(target):
    return {n.id for n in ast.walk(target) if isinstance(n, ast.Name)}


class _Facts:
    """What one node's code does, found in one walk over it: linear in its size, whatever it holds."""

    __slots__ = ("imports", "string", "names")

    def __init__(self, node):
        self.imports = []  # (module, line) of the imports that reach a forbidden package, in walk order
        self.string = False  # names a forbidden package in a string (a dynamic import)
        loaded, stored, declared = set(), set(), set()
        for n in ast.walk(node):
            if isinstance(n, ast.Name):
                (loaded if isinstance(n.ctx, ast.Load) else stored).add(n.id)
            elif isinstance(n, ast.Import):
                self.imports += [(a.name, n.lineno) for a in n.names if _is_forbidden_module(a.name)]
            elif isinstance(n, ast.ImportFrom):
                if n.level == 0 and _is_forbidden_module(n.module):
                    self.imports.append((n.module, n.lineno))
            elif isinstance(n, ast.Constant):
                self.string = self.string or (isinstance(n.value, str) and _is_forbidden_module(n.value.strip()))
            elif isinstance(n, (ast.Global, ast.Nonlocal)):
                declared.update(n.names)
        local = set()
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            args = node.args
            local = {a.arg for a in args.args + args.posonlyargs + args.kwonlyargs}
            local |= {a.arg for a in (args.vararg, args.kwarg) if a is not None}
            local |= stored - declared  # a parameter or a local assignment (not one declared global)
        self.names = sorted(loaded - local)


def _module_level(stmts):
    """Statements executed at module level (descending into if/try/with/loops, not defs)."""
    for stmt in stmts:
        yield stmt
        if isinstance(stmt, (ast.If, ast.For, ast.AsyncFor, ast.While, ast.With, ast.AsyncWith, ast.Try)):
            for attr in ("body", "orelse", "finalbody"):
                yield from _module_level(getattr(stmt, attr, []) or [])
            for handler in getattr(stmt, "handlers", []) or []:
                yield from _module_level(handler.body)


def forbidden_usage(units, functions):
    """Which contract functions depend on ``slamlib`` or ``autograder``.

    A function depends on a forbidden package when its body imports it, names a
    string like ``"slamlib..."`` (``importlib.import_module``), or loads a
    module-level name bound by such an import -- directly or through helper
    functions, classes and module-level assignments of the submission.

    Returns
    -------
    dict
        Function name -> human-readable reason, for the functions that depend on one.
    """
    tainted = {}  # module-level name -> description of the import that bound it
    defs = {}  # module-level name -> nodes whose code runs when the name is used
    star = []
    imported = set()  # module-level names bound by an import (numpy's np): defined, whatever a star import brings
    for unit in units:
        try:
            tree = ast.parse(unit["source"], filename=unit["filename"])
        except (SyntaxError, ValueError, RecursionError, MemoryError):
            continue
        for stmt in _module_level(tree.body):
            where = f"{unit['label']} line {stmt.lineno}"
            if isinstance(stmt, (ast.Import, ast.ImportFrom)):  # names an import binds are defined, not a star's
                imported.update(a.asname or a.name.split(".")[0] for a in stmt.names if a.name != "*")
            if isinstance(stmt, ast.Import):
                for alias in stmt.names:
                    if _is_forbidden_module(alias.name):
                        bound = alias.asname or alias.name.split(".")[0]
                        tainted[bound] = f"`{bound}` (import {alias.name}, {where})"
            elif isinstance(stmt, ast.ImportFrom) and stmt.level == 0 and _is_forbidden_module(stmt.module):
                for alias in stmt.names:
                    if alias.name == "*":
                        star.append(f"from {stmt.module} import * ({where})")
                    else:
                        bound = alias.asname or alias.name
                        tainted[bound] = f"`{bound}` (from {stmt.module} import {alias.name}, {where})"
            for name, node in _bindings(stmt):
                defs.setdefault(name, []).append(node)
    defined = set(defs) | set(tainted) | imported
    builtin_names = set(dir(builtins))

    facts = {}  # id(node) -> _Facts, each node walked once

    def direct(node):
        """Why `node`'s own code depends on a forbidden package, without following the names it uses."""
        f = facts.get(id(node))
        if f is None:
            f = facts[id(node)] = _Facts(node)
        if f.imports:
            mod, line = f.imports[0]
            return f"imports {mod} (line {line})", f
        if f.string:
            return "names the slamlib/autograder package in a string (a dynamic import)", f
        for name in f.names:
            if name in tainted:
                return f"uses {tainted[name]}", f
        if star:
            for name in f.names:
                if name not in defined and name not in builtin_names:
                    return f"uses `{name}`, which can only come from {star[0]}", f
        return None, f

    def reason(root, seen):
        """Why `root` depends on a forbidden package, through the submission's names it uses (depth first).

        Iterative, with every name followed once (`seen`): a chain of a thousand helpers neither
        recurses past Python's limit nor costs more than one walk over each of them.
        """
        why, f = direct(root)
        if why:
            return why

        def children(f):
            for name in f.names:
                if name in defs and name not in seen:
                    seen.add(name)
                    for sub in defs[name]:
                        yield name, sub

        chain, stack = [], [children(f)]
        while stack:
            step = next(stack[-1], None)
            if step is None:
                stack.pop()
                if chain:
                    chain.pop()
                continue
            name, sub = step
            why, f = direct(sub)
            if why:
                return "".join(f"calls `{n}`, which " for n in chain + [name]) + why
            chain.append(name)
            stack.append(children(f))
        return None

    out = {}
    for fn in functions:
        if fn in tainted:
            out[fn] = f"{fn} is {tainted[fn]}, not your own implementation"
            continue
        for node in defs.get(fn, []):
            why = reason(node, {fn})
            if why:
                out[fn] = f"{fn} {why}"
                break
    return out


def _bindings(stmt):
    """(name, node) pairs a module-level statement binds, with the code that runs when the name is used."""
    if isinstance(stmt, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
        return [(stmt.name, stmt)]
    if isinstance(stmt, ast.Assign):
        return [(n, stmt.value) for t in stmt.targets for n in _bound_names(t)]
    if isinstance(stmt, (ast.AnnAssign, ast.AugAssign)) and stmt.value is not None:
        return [(n, stmt.value) for n in _bound_names(stmt.target)]
    return []
