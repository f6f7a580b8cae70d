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
    """The file cannot be graded at all (unreadable, unsupported type ...).

    `exercise`: the exercise the notebook names in its metadata, when the grader could read it (a notebook refused
    for its size still names its exercise, so that its tests are listed with 0 and the reason)."""

    def __init__(self, message, exercise=None):
        super().__init__(message)
        self.exercise = exercise


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
        raise SubmissionError(f"{path.name}: the file is larger than 50 MB",
                              _named_exercise(raw) if suffix == ".ipynb" else None)
    if suffix == ".py":
        text = decode_python_source(raw, path.name)
        sub = Submission(path, "python", [{"source": text, "filename": path.name, "label": path.name}])
    elif suffix == ".ipynb":
        try:
            sub = _load_notebook(path, raw, max_code)
        except SubmissionError as exc:
            if exc.exercise is None:
                exc.exercise = _named_exercise(raw)
            raise
        except Exception as exc:  # noqa: BLE001 - any value of the untrusted JSON the reader did not expect
            raise SubmissionError(f"{path.name}: not a readable Jupyter notebook ({type(exc).__name__}: "
                                  f"{_quoted(exc)})", _named_exercise(raw)) from None
    else:
        raise SubmissionError(f"{path.name}: unsupported file type (submit the exercise notebook .ipynb or a .py file)")
    from .seeds import content_hash

    sub.sha256 = content_hash(raw)
    size = sum(len(unit["source"]) for unit in sub.units)
    if size > max_code:
        raise SubmissionError(_too_much_code_message(path.name, size, max_code), sub.exercise)
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


def _too_much_code_message(name, size, max_code):
    return (f"{name}: {size // 1024} KB of code, more than the {max_code // 1024} KB the grader reads "
                           "(keep data out of the code: load it from a file or generate it)")


#: a notebook's ``"slam_course": {"exercise": "NAME"}`` in its bytes (the JSON itself could not be read)
_EXERCISE_IN_BYTES = re.compile(rb'(?<!\\)"slam_course"\s*:\s*\{\s*"exercise"\s*:\s*"([A-Za-z0-9_]{1,100})"')


def _named_exercise(raw):
    """The exercise a notebook that cannot be read whole names in its metadata, or None (none, or several)."""
    names = {m.group(1).decode("ascii") for m in _EXERCISE_IN_BYTES.finditer(raw)}
    return names.pop() if len(names) == 1 else None


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
    exercise = _metadata_exercise(data.get("metadata"))
    for cell in _graded_cells(data):  # outputs are not graded: nbformat never sees (nor validates) them
        if "outputs" in cell:
            cell["outputs"] = []
        cell.pop("attachments", None)
    try:
        with warnings.catch_warnings():  # nbformat's warnings (a missing cell id) are no grader's output
            warnings.simplefilter("ignore")
            nb = nbformat.reads(json.dumps(data), as_version=4)
    except Exception as exc:  # noqa: BLE001 - nbformat raises many kinds
        raise SubmissionError(f"{path.name}: not a readable Jupyter notebook ({type(exc).__name__}: {_quoted(exc)})",
                              exercise) from None
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
            raise SubmissionError(_too_much_code_message(path.name, size, max_code), exercise)
        source = _strip_magics(source.replace("\r\n", "\n").replace("\r", "\n"), label, notes)
        if not source.strip():
            continue
        units.append({"source": source, "filename": f"{path.name}, {label}", "label": label})
    return Submission(path, "notebook", units, exercise, notes)


def _metadata_exercise(meta):
    """The exercise a notebook's metadata names (``slam_course.exercise``), or None."""
    meta = meta.get("slam_course") if isinstance(meta, dict) else None
    exercise = meta.get("exercise") if isinstance(meta, dict) else None
    if not isinstance(exercise, str):
        return None
    # no exercise has so long a name; it is quoted in messages
    return exercise[:97] + "..." if len(exercise) > 100 else exercise


# --------------------------------------------------------------------------- static dependency analysis
#: a string that names a forbidden package or a module of it, as a dynamic import would (``"slamlib"``,
#: ``"slamlib.particle"``, ``"autograder." + name``); prose that mentions one (``"slamlib.f, written again"``) does not
_FORBIDDEN_STRING = re.compile(r"(?:%s)(?:\.[A-Za-z_]\w*)*\.?" % "|".join(FORBIDDEN))


def _is_forbidden_module(name):
    return isinstance(name, str) and name.split(".")[0] in FORBIDDEN


def _bound_names(target, ctx=ast.Store):
    """Names an assignment to `target` binds (``a, *b = ...``; ``del a`` with ast.Del), not those of ``a.x = ...``."""
    return [n.id for n in ast.walk(target) if isinstance(n, ast.Name) and isinstance(n.ctx, ctx)]


def _mutated_names(target):
    """Names whose object an assignment to `target` changes: ``a`` of ``a.x = ...`` and ``a[i] = ...``."""
    out = []
    for t in ast.walk(target):
        if isinstance(t, (ast.Attribute, ast.Subscript)) and isinstance(t.ctx, ast.Store):
            base = t.value
            while isinstance(base, (ast.Attribute, ast.Subscript)):
                base = base.value
            if isinstance(base, ast.Name):
                out.append(base.id)
    return out


def _main_guard(test):
    """True for ``__name__ == "__main__"``, False for ``__name__ != "__main__"``, None for any other test.

    The grader runs the submission as the module ``submission``: such a block's body never runs."""
    if isinstance(test, ast.Compare) and len(test.ops) == 1 and isinstance(test.ops[0], (ast.Eq, ast.NotEq)):
        sides = (test.left, test.comparators[0])
        if (any(isinstance(s, ast.Name) and s.id == "__name__" for s in sides)
                and any(isinstance(s, ast.Constant) and s.value == "__main__" for s in sides)):
            return isinstance(test.ops[0], ast.Eq)
    return None


def _parameters(scope):
    args = scope.args
    names = [a.arg for a in args.args + args.posonlyargs + args.kwonlyargs]
    return names + [a.arg for a in (args.vararg, args.kwarg) if a is not None]


# Which loads of a name are of the module-level binding is decided by a walk over the ast that follows Python's
# scoping rules (those of CPython's symtable.c), not by the symtable module itself. symtable resolves scopes
# exactly, but its scopes carry no column and come in the order symtable.c visits the code (a def's defaults,
# annotations and decorators before it, a comprehension's first iterable before it, an ``IfExp``'s test before its
# body; annotation and type-parameter scopes of their own from 3.12): matching them to the ast's nodes would
# depend on that order and on the Python version. The rules are few and fixed:
#   * a def, a lambda, a class body and a comprehension are scopes; a def's decorators, defaults and annotations,
#     a class's bases and keywords, and a comprehension's first iterable are evaluated in the scope around them;
#   * a name is local to a scope when the scope binds it anywhere in it: an assignment (plain, augmented,
#     annotated: ``x: int`` too, but not ``(x): int``), a ``for``, ``with ... as``, ``except ... as``, ``import``,
#     ``del``, a def or class name, a parameter, a ``match`` capture (``case x``, ``[*x]``, ``{**x}``), a
#     comprehension's targets; ``global`` makes it the module's, ``nonlocal`` that of a def around it;
#   * a walrus binds in the nearest scope that is not a comprehension (in a def declaring the name global: the
#     module's);
#   * a name a scope neither binds nor declares is that of the nearest def, lambda or comprehension around it that
#     does (``global`` there: the module's), else the module's; a class body is never seen from scopes inside it;
#   * in a class body, a name the body binds is looked up in the class's namespace, then the module's (LOAD_NAME):
#     it may be the module's, and counts as such.
# tests/test_autograder_findings.py checks the walk's answers against symtable's on code of each shape; when it was
# written, they also agreed on 30 000 random nests of defs, classes, lambdas, comprehensions, walruses, ``global``,
# ``nonlocal``, ``except ... as`` and ``match``.
_FUNCTIONS = (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)
_COMPREHENSIONS = (ast.ListComp, ast.SetComp, ast.DictComp, ast.GeneratorExp)
_OPENERS = _FUNCTIONS + (ast.ClassDef,) + _COMPREHENSIONS
_CAPTURES = tuple(getattr(ast, k) for k in ("MatchAs", "MatchStar") if hasattr(ast, k))
#: when code runs: while the module loads, or when a function is called (a generator expression: either, as it is
#: iterated)
_NOW, _LATER = 1, 2


class _Block:
    """One scope inside a module-level node (`kind`: "module", "function" -- a def or lambda --, "class",
    "comprehension"): the names it binds, declares global, declares nonlocal; `home`, where a walrus in it binds;
    `when` its code runs."""

    __slots__ = ("kind", "parent", "home", "when", "bound", "glob", "nonlocal_")

    def __init__(self, kind, parent, when):
        self.kind, self.parent, self.when = kind, parent, when
        self.home = parent.home if kind == "comprehension" else self
        self.bound, self.glob, self.nonlocal_ = set(), set(), set()

    def visible(self):
        """The names this scope shows to the scopes inside it (a class body shows none), global or not."""
        return () if self.kind in ("module", "class") else self.glob | self.bound | self.nonlocal_


def _split(n):
    """``(kind, outside, inside)`` for a node that opens a scope (`_OPENERS`): its child nodes evaluated in the
    scope around it and those evaluated in its own (a lambda's body, a def's statements ...)."""
    if isinstance(n, _FUNCTIONS):
        a = n.args
        outside = a.defaults + [d for d in a.kw_defaults if d is not None]
        if isinstance(n, ast.Lambda):
            return "function", outside, [n.body]
        every = a.posonlyargs + a.args + a.kwonlyargs + [x for x in (a.vararg, a.kwarg) if x is not None]
        outside = (n.decorator_list + outside + [x.annotation for x in every if x.annotation is not None]
                   + ([n.returns] if n.returns is not None else []) + list(getattr(n, "type_params", ())))
        return "function", outside, n.body
    if isinstance(n, ast.ClassDef):
        return "class", n.decorator_list + n.bases + n.keywords + list(getattr(n, "type_params", ())), n.body
    first, *rest = n.generators  # a comprehension
    inside = ([n.key, n.value] if isinstance(n, ast.DictComp) else [n.elt]) + [first.target] + first.ifs
    for g in rest:
        inside += [g.target, g.iter] + g.ifs
    return "comprehension", [first.iter], inside


def _scopes(node):
    """The scopes of `node`, code at module level: ``(module, splits, walrus)``. `module`: the module's scope;
    `splits`: ``{id(n): (block, outside, inside)}`` for each node that opens a scope; `walrus`: ``(name, lazily)``
    for each walrus that binds a module-level name (``lazily``: in a generator expression).

    One walk, each node entered once (iterative: no recursion however deep the nesting)."""
    module = _Block("module", None, _NOW)
    splits, walrus = {}, []
    stack = [(node, module)]
    while stack:
        n, b = stack.pop()
        if isinstance(n, ast.Name):  # the commonest node; its only child is its ctx
            if not isinstance(n.ctx, ast.Load):
                b.bound.add(n.id)
            continue
        if isinstance(n, ast.Constant):
            continue
        if isinstance(n, _OPENERS):
            kind, outside, inside = _split(n)
            if kind == "function":
                when = _LATER
            else:
                when = b.when | (_LATER if isinstance(n, ast.GeneratorExp) else 0)
            inner = _Block(kind, b, when)
            splits[id(n)] = (inner, outside, inside)
            if kind == "function":
                inner.bound.update(_parameters(n))
            if not isinstance(n, (ast.Lambda,) + _COMPREHENSIONS):
                b.bound.add(n.name)
            stack.extend((c, b) for c in outside)
            stack.extend((c, inner) for c in inside)
            continue
        if isinstance(n, ast.NamedExpr):
            b.home.bound.add(n.target.id)
            if b.home is module:
                walrus.append((n.target.id, bool(b.when & _LATER)))
            stack.append((n.value, b))
            continue
        if isinstance(n, ast.AnnAssign) and not n.simple and n.value is None:
            stack.append((n.annotation, b))  # ``(x): int``: evaluates an annotation, binds nothing
            if not isinstance(n.target, ast.Name):
                stack.append((n.target, b))
            continue
        if isinstance(n, (ast.Import, ast.ImportFrom)):
            b.bound.update(a.asname or a.name.split(".")[0] for a in n.names if a.name != "*")
        elif isinstance(n, ast.Global):
            b.glob.update(n.names)
        elif isinstance(n, ast.Nonlocal):
            b.nonlocal_.update(n.names)
        elif isinstance(n, (ast.ExceptHandler,) + _CAPTURES):
            if n.name:
                b.bound.add(n.name)
        elif type(n).__name__ == "MatchMapping":
            if n.rest:
                b.bound.add(n.rest)
        stack.extend((c, b) for c in ast.iter_child_nodes(n))
    return module, splits, walrus


def _sure_walruses(part):
    """Names bound by the walruses that code run at module level (`part`, a part of a statement) always
    evaluates when it runs to its end: not those in a ``BoolOp``'s later operands, an ``IfExp``'s branches, a
    comprehension (but its first iterable) or the body of a def, lambda or class."""
    sure, stack = set(), [part]
    while stack:
        n = stack.pop()
        if isinstance(n, ast.NamedExpr):
            sure.add(n.target.id)
            stack.append(n.value)
        elif isinstance(n, _OPENERS):
            stack.extend(_split(n)[1])  # evaluated where it stands: decorators, defaults, bases, first iterable
        elif isinstance(n, ast.BoolOp):
            stack.append(n.values[0])
        elif isinstance(n, ast.IfExp):
            stack.append(n.test)
        else:
            stack.extend(ast.iter_child_nodes(n))
    return sure


class _Facts:
    """What one node's code does, found in two walks over it (its scopes, then its loads): linear in its size,
    whatever it holds. The node is code at module level: a def or class statement, an assigned value ..."""

    __slots__ = ("imports", "string", "now", "later", "names", "rebinds", "walrus")

    def __init__(self, node):
        self.imports = []  # (module, line) of the imports that reach a forbidden package, by line
        self.string = False  # names a forbidden package in a string (a dynamic import); a docstring never does
        module, splits, walrus = _scopes(node)
        # a module-level name loaded inside a def or lambda is looked up when it is called; one loaded elsewhere
        # (in an assigned value, a class body, a def's decorators and defaults) when the node runs
        now, later, docstrings = set(), set(), set()
        # name -> for each def, lambda or comprehension around the walk's position that binds or declares it
        # (innermost last), whether that makes it the module's (``global``)
        seen = {}
        stack = [(node, module)]
        while stack:
            n, b = stack.pop()
            if b is None:  # a marker: entering (n: the names and what they are) or leaving (n: the names) a scope
                if isinstance(n, dict):
                    for name, glob in n.items():
                        seen.setdefault(name, []).append(glob)
                else:
                    for name in n:
                        seen[name].pop()
                continue
            if isinstance(n, ast.Name):
                if isinstance(n.ctx, ast.Load) and self._module_level(n.id, b, seen):
                    if b.when & _NOW:
                        now.add(n.id)
                    if b.when & _LATER:
                        later.add(n.id)
                continue
            if isinstance(n, ast.Constant):
                self.string = self.string or (isinstance(n.value, str) and id(n) not in docstrings
                                              and _FORBIDDEN_STRING.fullmatch(n.value.strip()) is not None)
                continue
            split = splits.get(id(n)) if isinstance(n, _OPENERS) else None
            if split is not None:
                inner, outside, inside = split
                names = inner.visible()
                # popped in this order: the code outside the scope, entering it, its code, leaving it
                if names:
                    stack.append((names, None))
                stack.extend((c, inner) for c in inside)
                if names:
                    stack.append(({name: name in inner.glob for name in names}, None))
                stack.extend((c, b) for c in outside)
                if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                    first = n.body[0] if n.body else None
                    if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                        docstrings.add(id(first.value))
                continue
            if isinstance(n, ast.Import):
                self.imports += [(a.name, n.lineno) for a in n.names if _is_forbidden_module(a.name)]
            elif isinstance(n, ast.ImportFrom):
                if n.level == 0 and _is_forbidden_module(n.module):
                    self.imports.append((n.module, n.lineno))
            stack.extend((c, b) for c in ast.iter_child_nodes(n))
        self.imports.sort(key=lambda i: i[1])  # the first in the source is the one a message names
        self.now = now  # module-level names looked up when the node runs
        self.later = later  # ... and when the functions in it are called
        self.names = sorted(now | later)
        # module-level names it binds through ``global`` (whenever the code that does runs)
        self.rebinds = sorted({name for inner, _, _ in splits.values() for name in inner.bound & inner.glob})
        self.walrus = walrus  # and those it binds with a walrus outside any def or lambda

    @staticmethod
    def _module_level(name, b, seen):
        """Whether a load of `name` in the scope `b` may be of the module-level binding."""
        if b.kind == "module":
            return True
        if b.kind == "class":
            if name in b.glob:
                return True
            if name in b.nonlocal_:
                return False
            if name in b.bound:  # the class's namespace, then the module's
                return True
        around = seen.get(name)  # a def, lambda or comprehension (b itself, unless a class) that binds or declares it
        return not around or around[-1]


class _Bound:
    """One binding of a module-level name: an import (`why` describes it when it is of a forbidden package), or
    code that runs when the name is used (`node`: a def, a class, an assigned value) with, for the names that code
    loads while the module runs, the bindings they had then (`at`)."""

    __slots__ = ("why", "node", "at")

    def __init__(self, why=None, node=None, at=None):
        self.why, self.node, self.at = why, node, at


class _Either:
    """Bindings any one of which may be in force (the branches of an ``if``, a ``try`` stopped anywhere ...);
    None among them: perhaps none. `why`: that of the first forbidden import among them."""

    __slots__ = ("options", "why")

    def __init__(self, options):
        self.options = options
        self.why = next((o.why for o in options if o is not None and o.why), None)


def _either(options):
    unique = list({id(o): o for o in options}.values())
    return unique[0] if len(unique) == 1 else _Either(tuple(unique))


class _Scope:
    """The module-level names a stretch of statements binds, over those of the stretch around it.

    `history`: every binding made inside the innermost enclosing ``try`` body (its handlers may start from any)."""

    __slots__ = ("parent", "vars", "history")

    def __init__(self, parent=None, history=None):
        self.parent, self.vars = parent, {}
        self.history = history if history is not None or parent is None else parent.history

    def get(self, name):
        s = self
        while s is not None:
            if name in s.vars:
                return s.vars[name]
            s = s.parent
        return None

    def set(self, name, value):
        self.vars[name] = value
        if self.history is not None:
            self.history.setdefault(name, []).append(value)

    def changed(self, top):
        """Names bound from this scope up to `top` (excluded), in order."""
        names, s = {}, self
        while s is not top:
            names.update(dict.fromkeys(s.vars))
            s = s.parent
        return names


class _Execution:
    """The module-level bindings of a submission followed in execution order, and what each one's code uses.

    Statements run in cell (source) order. A binding replaces the one before it; ``del`` unbinds. Of the branches
    of an ``if``, a loop (its body runs zero or more times), a ``match`` or a ``try`` (a handler may start after any
    statement of the body), every possible outcome is kept. The body of ``if __name__ == "__main__":`` never runs
    (the grader loads the submission as the module ``submission``). A walrus at module level and a ``match`` capture
    bind like the other statements; the name of an ``except ... as`` is unbound when its handler ends. A function
    that binds a module-level name through ``global`` may have done so whenever it was called: it stays a possible
    binding of that name.
    """

    def __init__(self):
        self.top = _Scope()
        self.star = []  # forbidden star imports executed
        self.rebound = {}  # name -> bindings of it by defs through ``global``
        self.sticky = {}  # name -> (how many of rebound[name], their _Either): see now()
        self.facts = {}  # id(node) -> _Facts, each node walked once
        self.finals = {}
        self.clean = set()  # ids of the bindings known to reach no forbidden package (reason), over the grading

    def facts_of(self, node):
        f = self.facts.get(id(node))
        if f is None:
            f = self.facts[id(node)] = _Facts(node)
        return f

    def code(self, node, scope):
        """A binding to `node`'s code; the names it loads while the module runs are looked up now."""
        return _Bound(node=node, at={n: self.now(n, scope) for n in self.facts_of(node).now})

    def now(self, name, scope):
        """The bindings `name` may have at this point of the module's run: its binding in `scope`, or one made
        through ``global`` by a def or class run so far (a class body's runs with it; a def's whenever it is
        called, perhaps already)."""
        value, extra = scope.get(name), self.rebound.get(name)
        if not extra:
            return value
        n, made = self.sticky.get(name, (0, None))
        if n != len(extra):  # one _Either per count of them: a thousand lookups do not copy a thousand lists
            made = _either(extra)
            self.sticky[name] = (len(extra), made)
        return _either([value, made])

    def final(self, name):
        """The bindings a name may have after the whole submission ran, when the graded functions are called."""
        if name not in self.finals:
            value, extra = self.top.get(name), self.rebound.get(name)
            self.finals[name] = _either([value] + extra) if extra else value
        return self.finals[name]

    # ------------------------------------------------------------------ running the module's statements
    def run(self, stmts, scope, label):
        for stmt in stmts:
            self.statement(stmt, scope, label)

    def walrus(self, parts, scope, surely=True):
        """Bind the module-level names the walruses in `parts` (code of a statement run at module level) bind: to
        the code of the part that holds the walrus (and so its value). A walrus the statement always evaluates
        replaces the binding before it (`_sure_walruses`; `surely` False: none does, as in a ``match`` guard or
        an ``except`` clause's type, after which other cases and clauses run); one it may skip
        (``a or (w := b)``) is a possible binding; one in a generator expression may bind whenever the generator
        is iterated."""
        for part in parts:
            if isinstance(part, (ast.Name, ast.Constant)):  # no walrus in it (the commonest targets)
                continue
            facts = self.facts_of(part)
            if facts.walrus:
                value = self.code(part, scope)
                sure = _sure_walruses(part) if surely else ()
                for name, lazily in facts.walrus:
                    scope.set(name, value if name in sure else _either([scope.get(name), value]))
                    if lazily:
                        self.rebound.setdefault(name, []).append(_Bound(node=part))

    def statement(self, stmt, scope, label):
        where = f"{label} line {stmt.lineno}"
        # the code a statement runs itself, not its blocks: a walrus in it binds before the statement does
        if isinstance(stmt, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            parts = [stmt]  # its decorators, defaults, bases (a walrus in its body binds in its own scope)
        elif isinstance(stmt, (ast.With, ast.AsyncWith)):
            parts = [e for item in stmt.items for e in (item.context_expr, item.optional_vars) if e is not None]
        else:
            parts = [c for c in ast.iter_child_nodes(stmt) if isinstance(c, ast.expr)]
        if isinstance(stmt, ast.Assert):  # its message is evaluated only when the test fails
            parts, maybe = [stmt.test], [stmt.msg] if stmt.msg is not None else []
            self.walrus(maybe, scope, surely=False)
        self.walrus(parts, scope)
        if isinstance(stmt, ast.Import):
            for alias in stmt.names:
                bound = alias.asname or alias.name.split(".")[0]
                forbidden = _is_forbidden_module(alias.name)
                scope.set(bound, _Bound(f"`{bound}` (import {alias.name}, {where})" if forbidden else None))
        elif isinstance(stmt, ast.ImportFrom):
            forbidden = stmt.level == 0 and _is_forbidden_module(stmt.module)
            for alias in stmt.names:
                if alias.name == "*":
                    if forbidden:
                        self.star.append(f"from {stmt.module} import * ({where})")
                    continue
                bound = alias.asname or alias.name
                why = f"`{bound}` (from {stmt.module} import {alias.name}, {where})" if forbidden else None
                scope.set(bound, _Bound(why))
        elif isinstance(stmt, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            scope.set(stmt.name, self.code(stmt, scope))
            for name in self.facts_of(stmt).rebinds:
                self.rebound.setdefault(name, []).append(_Bound(node=stmt))
        elif isinstance(stmt, (ast.Assign, ast.AnnAssign, ast.AugAssign)):
            if stmt.value is None:  # x: int
                return
            value = self.code(stmt.value, scope)
            for target in (stmt.targets if isinstance(stmt, ast.Assign) else [stmt.target]):
                for name in _bound_names(target):  # x += v is x changed by v
                    scope.set(name, _either([scope.get(name), value]) if isinstance(stmt, ast.AugAssign) else value)
                for name in _mutated_names(target):
                    scope.set(name, _either([scope.get(name), value]))
        elif isinstance(stmt, ast.Delete):
            for target in stmt.targets:
                for name in _bound_names(target, ast.Del):
                    scope.set(name, None)
        elif isinstance(stmt, ast.If):
            # an if/elif/.../else chain is one branch of n ways, walked in a loop (an elif is an If in the orelse
            # of the one before: one recursion per elif reached Python's limit at ~340 of them)
            blocks, node = [], stmt
            while True:
                if node is not stmt:  # an elif's test runs only when the tests before it were false
                    self.walrus([node.test], scope, surely=False)
                guard = _main_guard(node.test)
                if guard is None:
                    blocks.append(node.body)
                elif guard is False:  # ``__name__ != "__main__"``: its body runs, what follows it never
                    blocks.append(node.body)
                    break
                # guard True: ``__name__ == "__main__"``, its body never runs
                if len(node.orelse) == 1 and isinstance(node.orelse[0], ast.If):
                    node = node.orelse[0]
                    continue
                blocks.append(node.orelse)
                break
            if len(blocks) == 1:
                self.run(blocks[0], scope, label)
            else:
                self.branches(scope, blocks, label, exhaustive=True)
        elif isinstance(stmt, (ast.For, ast.AsyncFor, ast.While)):
            def loop(s):
                if not isinstance(stmt, ast.While):
                    value = self.code(stmt.iter, s)
                    for name in _bound_names(stmt.target):
                        s.set(name, value)
                self.run(stmt.body, s, label)
            self.branches(scope, [loop], label, exhaustive=False)  # zero or more times
            self.branches(scope, [stmt.orelse], label, exhaustive=False)  # unless it breaks
        elif isinstance(stmt, (ast.With, ast.AsyncWith)):
            for item in stmt.items:
                if item.optional_vars is not None:
                    value = self.code(item.context_expr, scope)
                    for name in _bound_names(item.optional_vars):
                        scope.set(name, value)
            self.run(stmt.body, scope, label)
        elif isinstance(stmt, (ast.Try, getattr(ast, "TryStar", ast.Try))):
            body = _Scope(scope, history={})  # a new history: that of this try
            self.run(stmt.body, body, label)
            start = _Scope(scope)  # a handler starts before the body or after any binding in it
            for name, values in body.history.items():
                start.vars[name] = _either([scope.get(name)] + values)
                if scope.history is not None:
                    scope.history.setdefault(name, []).extend(values)
            body.history = scope.history
            self.run(stmt.orelse, body, label)
            ends = [body]
            for handler in stmt.handlers:
                h = _Scope(start)
                self.walrus([handler.type] if handler.type is not None else [], h, surely=False)
                if handler.name:
                    h.set(handler.name, _Bound())
                self.run(handler.body, h, label)
                if handler.name:  # unbound when the handler ends
                    h.set(handler.name, None)
                ends.append(h)
            self.merge(scope, ends, exhaustive=True)
            self.run(stmt.finalbody, scope, label)
        elif isinstance(stmt, getattr(ast, "Match", ())):
            subject = self.code(stmt.subject, scope)

            def case_of(case):
                def run(s):  # a case binds its captures to the subject or parts of it, then runs
                    for n in ast.walk(case.pattern):
                        name = n.name if isinstance(n, _CAPTURES) else getattr(n, "rest", None)
                        if name:
                            s.set(name, subject)
                    self.walrus([case.guard] if case.guard is not None else [], s, surely=False)
                    self.run(case.body, s, label)
                return run
            self.branches(scope, [case_of(case) for case in stmt.cases], label, exhaustive=False)

    def branches(self, scope, blocks, label, exhaustive):
        """Run each block (statements, or a function of the scope) from `scope`; keep every outcome in it."""
        ends = []
        for block in blocks:
            s = _Scope(scope)
            if callable(block):
                block(s)
            else:
                self.run(block, s, label)
            ends.append(s)
        self.merge(scope, ends, exhaustive)

    @staticmethod
    def merge(scope, ends, exhaustive):
        """Every name an end bound: either of the ends' values, or the one before (an end that did not bind it, or
        none of them ran when not `exhaustive`). Linear in the bindings the ends made: a ``match`` of n cases that
        each bind a name of their own costs n, not n * n."""
        changed = {}  # name -> [(index of the end, its value)], in the ends' order
        for k, s in enumerate(ends):
            for name in s.changed(scope):
                changed.setdefault(name, []).append((k, s.get(name)))
        for name, got in changed.items():
            values = [v for _, v in got]
            before = scope.get(name)
            # the value before stands where the first end that did not bind the name stands (as if each end were
            # asked in turn), and at the end when no end need run
            first = next((i for i, (k, _) in enumerate(got) if k != i), len(got))
            if first < len(ends):
                values.insert(first, before)
            if not exhaustive:
                values.append(before)
            scope.set(name, _either(values))

    # ------------------------------------------------------------------ what the graded functions use
    def leaves(self, value, seen, clean=()):
        """The code bindings among `value`'s options not in `seen` nor in `clean` (ids), each once."""
        stack = [value]
        while stack:
            v = stack.pop()
            if v is None or id(v) in seen or id(v) in clean:
                continue
            seen.add(id(v))
            if isinstance(v, _Either):
                stack.extend(reversed(v.options))
            elif v.node is not None:
                yield v

    def values(self, f, at, name):
        """The bindings `name` may have for code whose facts are `f`: while loading (`at`), when called."""
        out = []
        if name in f.now:
            out.append(at.get(name) if at is not None else self.final(name))
        if name in f.later:
            out.append(self.final(name))
        return out

    def direct(self, bound):
        """Why `bound`'s own code depends on a forbidden package, without following the names it uses."""
        f = self.facts_of(bound.node)
        if f.imports:
            mod, line = f.imports[0]
            return f"imports {mod} (line {line})", f
        if f.string:
            return "names the slamlib/autograder package in a string (a dynamic import)", f
        for name in f.names:
            for v in self.values(f, bound.at, name):
                if v is not None and v.why:
                    return f"uses {v.why}", f
        if self.star:
            builtin_names = set(dir(builtins))
            for name in f.names:
                if name not in builtin_names and all(v is None for v in self.values(f, bound.at, name)):
                    return f"uses `{name}`, which can only come from {self.star[0]}", f
        return None, f

    def reason(self, root):
        """Why `root` depends on a forbidden package, through the submission's names it uses (depth first).

        Iterative, with every binding followed once: a chain of a thousand helpers neither recurses past
        Python's limit nor costs more than one walk over each of them. A walk that finds nothing proves every
        binding it met clean (each of them reaches only bindings the walk met), and no later walk, for another
        binding or another function, enters them again: n bindings of a graded name that all lead to one chain of
        m helpers cost n + m steps, not n * m.
        """
        if id(root) in self.clean:
            return None
        why, f = self.direct(root)
        if why:
            return why
        seen = {id(root)}

        def children(f, at):
            for name in f.names:
                for v in self.values(f, at, name):
                    for sub in self.leaves(v, seen, self.clean):
                        yield name, sub

        chain, stack = [], [children(f, root.at)]
        while stack:
            step = next(stack[-1], None)
            if step is None:
                stack.pop()
                if chain:
                    chain.pop()
                continue
            name, sub = step
            why, f = self.direct(sub)
            if why:
                hops = chain + [name]
                if len(hops) > 6:  # a message, not a trace: the first three and the last two steps
                    hops = hops[:3] + [f"... ({len(hops) - 5} more)"] + hops[-2:]
                return "".join(f"calls `{n}`, which " if not n.startswith("...") else f"{n}, which "
                               for n in hops) + why
            chain.append(name)
            stack.append(children(f, sub.at))
        self.clean |= seen
        return None


def forbidden_usage(units, functions):
    """Which contract functions depend on ``slamlib`` or ``autograder``.

    A function depends on a forbidden package when its body imports it, holds a string that is the dotted name of
    it or of one of its modules (``importlib.import_module("slamlib.particle")``; a docstring, or prose that
    mentions one, is not), or loads a module-level name bound by such an import -- directly or through helper
    functions, classes and module-level assignments of the submission.

    Names are resolved as the submission runs (`_Execution`): a function's body sees the bindings in force after
    the last cell, an assigned value those in force when it ran. So an import of the reference that a later def
    of the same name replaces, or one under ``if __name__ == "__main__":``, is harmless; one that may be the binding
    in force (in either branch of an ``if``, in a ``try`` body or its handler) counts. A name no statement binds,
    used after ``from slamlib import *``, can only come from that import. Which loads are of a module-level name
    follows Python's scoping rules (`_scopes`): a comprehension's variable, a nested def's or class's name, a
    function's ``except ... as`` name, ``match`` capture or walrus target is not the module's.

    Returns
    -------
    dict
        Function name -> human-readable reason, for the functions that depend on one.
    """
    ex = _Execution()
    trees = []  # the nodes stay alive: bindings and facts are keyed by their ids
    for unit in units:
        try:
            tree = ast.parse(unit["source"], filename=unit["filename"])
        except (SyntaxError, ValueError, RecursionError, MemoryError):
            continue
        trees.append(tree)
        try:
            ex.run(tree.body, ex.top, unit["label"])
        except (RecursionError, MemoryError):  # no shape is known to do this; a grading must never end here
            continue
    out = {}
    for fn in functions:
        value = ex.final(fn)
        if value is not None and value.why:
            out[fn] = f"{fn} is {value.why}, not your own implementation"
            continue
        for bound in ex.leaves(value, set()):
            why = ex.reason(bound)
            if why:
                out[fn] = f"{fn} {why}"
                break
    return out
