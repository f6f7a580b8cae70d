"""Mutation testing of the autograder: wrong versions of slamlib's contract functions must lose points.

For every contract function of exercises 1-5 this module

1. builds a standalone submission module from slamlib's own source: the public
   function, every slamlib function, class and constant it reaches (its private
   cores, ``velocity_motion`` inside ``ekf_predict`` ...), and the imports they
   use (:func:`submission_source`);
2. generates mutants of it with the :mod:`ast` module (:func:`mutants`). What is
   mutated is the algorithm: the public function's body and the private cores it
   calls. Input validation is not: the grader sends only valid inputs, so a mutant
   that merely weakens a check computes the same values on them (it is equivalent by
   construction). The rule: every definition of :data:`FROZEN_MODULES`
   (:mod:`slamlib._checks`, the validation helpers, and :mod:`slamlib.angles`, the
   angle utilities), every name in :data:`FROZEN` and every name beginning with
   ``_check``, ``_as_``, ``as_`` or ``check_`` is copied verbatim and never mutated;
   inside a mutated function, door checks (an ``if`` that only raises, ``raise``,
   ``assert``, ``try``, a statement calling a checking helper) are left alone as well.
   The mutation operators: swapped and
   negated arithmetic and comparison operators, dropped ``wrap_angle`` (and its unchecked core ``_wrap``) / ``sqrt`` /
   transposes, square vs square root, added transposes, swapped call arguments,
   confusable variables swapped (``Q`` for ``S``, ``dx`` for ``dy`` ...), another
   parameter used in place of one, off-by-one index constants, changed constants,
   deleted in-place assignments and a parameter returned. Also left alone is
   the shape bookkeeping of batched inputs (``x.shape[:-1]``, ``np.broadcast_shapes``:
   the contract gives each input one shape). No mutant adds a transpose to a
   covariance (:data:`SYMMETRIC`), which would change nothing;
3. grades each mutant with the autograder's in-process caller (the student's
   self-check path; the sandbox is not what is under test) and the grader's own
   :func:`autograder.engine.run_tests`, one test at a time, stopping at the first
   test that takes points (:func:`grade_mutant`).

A mutant is *killed* when the grader takes points from it. Mutants that survive
are listed in :mod:`mutation_table` with the reason they are equivalent (they
compute the same values within the contract's tolerances, or differ only on
inputs the contract excludes).

Run ``python -m tests.mutation`` (from the repository root, ``PYTHONPATH`` set) for
the kill rate per function and the survivors; ``--function NAME`` for one
function, ``--every K`` for every K-th mutant only, ``--list`` to print mutants.
"""

from __future__ import annotations

import argparse
import ast
import builtins
import copy
import functools
import importlib
import inspect
import re
import signal
import sys
import textwrap
import time
import types
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import slamlib  # noqa: E402
from autograder.exercises import EXERCISES, get_exercise  # noqa: E402

__all__ = ["CONTRACT", "Mutant", "submission_source", "mutants", "grade_mutant", "run", "SEED"]

#: Exercise -> its contract functions, for every registered exercise (a new exercise is covered as soon as it
#: is registered in :data:`autograder.exercises.EXERCISES`; its reference functions are slamlib's of the same name).
CONTRACT = {name: list(get_exercise(name).functions) for name in EXERCISES}
#: Base seed of the test inputs while grading mutants (fixed, so runs are reproducible).
SEED = 20240

#: slamlib functions copied into a submission but never mutated: input checks and the
#: small angle/array utilities (their call sites in the mutated functions are still mutated).
FROZEN = {
    "as_array", "as_scalar", "as_covariance", "check_rng", "as_index", "_shape_str",
    "_as_vec", "_as_mat", "_as_cov", "_as_pd", "_check_batch", "_as_alpha", "_as_weights", "_as_poses",
    "_check_log_weights", "_last_axis", "_broadcast", "_beam_params", "_beam_inputs", "_check_state",
    "_check_index", "_as_state", "_as_particles", "_as_landmarks", "_check_fs", "_as_meas",
    "_z_arg", "_poses_arg", "wrap_angle", "angle_diff", "circular_mean", "_T", "_mv", "_sym",
    # the checks' own helpers (slamlib/_checks.py) and the pose graph's connectivity check (an input check)
    "_all_finite", "_convert", "_ref", "_require_connected", "_components",
}


#: Modules whose definitions are copied into a submission but never mutated: input validation
#: (:mod:`slamlib._checks`) and the angle utilities (:mod:`slamlib.angles`).
FROZEN_MODULES = ("slamlib._checks", "slamlib.angles")


def _frozen(name, obj=None):
    """Whether definition ``name`` (object ``obj``) is copied verbatim (see the module docstring's rule)."""
    if obj is not None and getattr(obj, "__module__", "") in FROZEN_MODULES:
        return True
    return name in FROZEN or name.startswith(("_check", "_as_", "as_", "check_"))
#: Calls whose statements are input checks (left unmutated inside a mutated function).
_CHECK_CALL_PREFIXES = ("as_", "_as_", "check_", "_check")
_VALIDATORS = {"_last_axis", "_broadcast", "_beam_params", "_beam_inputs", "_z_arg", "_poses_arg"} | {
    name for name, obj in vars(importlib.import_module("slamlib._checks")).items()
    if inspect.isfunction(obj) and obj.__module__ == "slamlib._checks"}

#: Variables a student confuses (each load of the key may become one of the values).
CONFUSABLE = {
    "Q": ["S"], "S": ["Q"], "Sigma": ["Sigma_bar"], "Sigma_bar": ["Sigma"], "mu": ["mu_bar"], "mu_bar": ["mu"],
    "dx": ["dy"], "dy": ["dx"], "cos_c": ["sin_c"], "sin_c": ["cos_c"], "cos_t": ["sin_t"], "sin_t": ["cos_t"],
    "cx": ["cy"], "cy": ["cx"], "r": ["q"], "q": ["r"], "G": ["V"], "V": ["G"], "Hx": ["Hm"], "Hm": ["Hx"],
    "rot1": ["rot2"], "rot2": ["rot1"], "r1h": ["r2h"], "r2h": ["r1h"], "var1": ["var3"], "var3": ["var1"],
    "x_next": ["x"], "z_hat": ["z"], "z_star": ["z"], "theta": ["phi"], "phi": ["theta"], "nr": ["nb"],
    "nb": ["nr"], "H": ["Hx"], "K": ["H"], "Qi": ["Q"], "Fx": ["G"], "s": ["ds"], "ds": ["s"],
}
#: Covariances (symmetric by the contract): transposing one changes nothing, so no mutant adds a transpose to them.
SYMMETRIC = {"Sigma", "Sigma_bar", "M", "Q", "S", "R", "P", "Qi", "Sigma_new"}
#: Function names swapped for a similar one.
_NAME_SWAP = {"cos": "sin", "sin": "cos", "argmin": "argmax", "argmax": "argmin", "maximum": "minimum",
              "minimum": "maximum", "max": "min", "min": "max", "any": "all", "all": "any", "floor": "ceil",
              "ceil": "floor", "arctan2": "arctan2", "expm1": "exp", "hypot": "add"}
#: One-argument calls that may be dropped (``f(a)`` -> ``a``).
_DROPPABLE = {"wrap_angle", "_wrap", "sqrt", "abs", "exp", "log", "_T", "_sym", "inv", "expm1", "copy", "_sinc"}


# =========================================================================== building a submission
def _module_of(obj):
    return sys.modules[obj.__module__]


def _import_binding(module, name):
    """The top-level import statement of ``module`` that binds ``name`` (as source text), or None."""
    tree = ast.parse(inspect.getsource(module))
    for node in tree.body:
        if isinstance(node, ast.Import):
            for a in node.names:
                if (a.asname or a.name.split(".")[0]) == name:
                    return f"import {a.name}" + (f" as {a.asname}" if a.asname else "")
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            for a in node.names:
                if (a.asname or a.name) == name:
                    return f"from {node.module} import {a.name}" + (f" as {a.asname}" if a.asname else "")
    return None


def _loaded_names(tree):
    return {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}


@dataclass
class _Unit:
    name: str
    source: str
    kind: str  # "def", "class" or "const"


def _literal(val):
    """Whether ``repr(val)`` rebuilds ``val`` as a Python literal (a dict or list of plain constants)."""
    try:
        return ast.literal_eval(repr(val)) == val
    except (ValueError, SyntaxError, TypeError):
        return False


def _collect(fn):
    """Definitions (in dependency order of discovery) and imports a submission of ``fn`` needs."""
    units = {}
    imports = []
    work = [(getattr(slamlib, fn), fn)]
    while work:
        obj, name = work.pop()
        if name in units:
            if units[name].kind != "const" and getattr(units[name], "obj", obj) is not obj:
                raise RuntimeError(f"two slamlib objects called {name}")
            continue
        module = _module_of(obj)
        src = textwrap.dedent(inspect.getsource(obj))
        unit = _Unit(name, src, "class" if inspect.isclass(obj) else "def")
        unit.obj = obj
        units[name] = unit
        for ref in sorted(_loaded_names(ast.parse(src))):
            if ref in units or hasattr(builtins, ref) and ref not in vars(module):
                continue
            if ref not in vars(module):
                continue
            val = vars(module)[ref]
            if isinstance(val, types.ModuleType):
                stmt = _import_binding(module, ref)
                if stmt and stmt not in imports:
                    imports.append(stmt)
            elif (inspect.isfunction(val) or inspect.isclass(val)) and getattr(val, "__module__", "").startswith(
                    "slamlib"):
                work.append((val, ref))
            elif callable(val):
                stmt = _import_binding(module, ref)
                if stmt is None:
                    raise RuntimeError(f"cannot tell where {module.__name__}.{ref} comes from")
                if stmt not in imports:
                    imports.append(stmt)
            elif isinstance(val, (int, float, str, tuple, bool, frozenset)) or val is None:
                units[ref] = _Unit(ref, f"{ref} = {val!r}", "const")
            elif isinstance(val, (dict, list)) and _literal(val):  # e.g. graph_slam.SPLU_OPTIONS
                units[ref] = _Unit(ref, f"{ref} = {val!r}", "const")
            elif isinstance(val, np.dtype) and hasattr(np, val.name):  # e.g. _checks._F64 = np.dtype(np.float64)
                units[ref] = _Unit(ref, f"{ref} = np.dtype(np.{val.name})", "const")
                if "import numpy as np" not in imports:
                    imports.append("import numpy as np")
            else:
                raise RuntimeError(f"cannot copy {module.__name__}.{ref} ({type(val).__name__})")
    return units, imports


def _assemble(units, imports, replaced=None):
    """Module source: imports, constants, then every definition (``replaced``: name -> new source)."""
    replaced = replaced or {}
    parts = ["from __future__ import annotations", "from typing import NamedTuple", *sorted(imports), ""]
    parts += [u.source for u in units.values() if u.kind == "const"]
    parts.append("")
    # a class must follow the classes it derives from (functions bind late: any order will do)
    defs = [u for u in units.values() if u.kind != "const"]
    defs.sort(key=lambda u: len(u.obj.__mro__) if u.kind == "class" else 0)
    defs.sort(key=lambda u: u.kind != "class")
    for u in defs:
        parts.append(replaced.get(u.name, u.source))
        parts.append("")
    return "\n".join(parts)


def submission_source(fn):
    """Source of a standalone module defining contract function ``fn`` exactly as slamlib does."""
    units, imports = _collect(fn)
    return _assemble(units, imports)


# =========================================================================== mutation operators
@dataclass(frozen=True)
class Mutant:
    """One mutant: ``function`` (contract), ``host`` (the mutated definition), ``key`` (stable description)."""

    function: str
    host: str
    key: str
    source: str

    @property
    def label(self):
        return f"{self.host}: {self.key}"


def _call_name(node):
    f = node.func
    if isinstance(f, ast.Name):
        return f.id
    if isinstance(f, ast.Attribute):
        return f.attr
    return None


def _is_check_stmt(stmt):
    """An input check: ``if ...: raise``, ``raise``, ``assert`` or a statement calling a checking helper."""
    if isinstance(stmt, (ast.Raise, ast.Assert)):
        return True
    if isinstance(stmt, ast.If) and all(isinstance(s, ast.Raise) for s in stmt.body) and not stmt.orelse:
        return True
    if isinstance(stmt, ast.Try):
        return True
    value = getattr(stmt, "value", None)
    if isinstance(value, ast.Call):
        name = _call_name(value) or ""
        if name.startswith(_CHECK_CALL_PREFIXES) or name in _VALIDATORS:
            return True
    if isinstance(stmt, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "shape" for t in stmt.targets):
        return True  # the broadcast shape of batched inputs (the contract's inputs have one shape each)
    return False


def _swapaxes(node):
    return ast.Call(ast.Attribute(ast.Name("np", ast.Load()), "swapaxes", ast.Load()),
                    [node, ast.Constant(-1), ast.Constant(-2)], [])


def _const_mutations(node, in_index):
    v = node.value
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return []
    if isinstance(v, int):
        out = [v + 1]
        if in_index:
            out.append(v - 1)
        return [ast.Constant(x) for x in out]
    return [ast.Constant(1.0 if v == 0 else v * 2.0)]


def _candidates(node, params, names, in_index):
    """Replacement nodes for ``node`` (the operators of the module docstring)."""
    out = []
    if isinstance(node, ast.BinOp):
        swaps = {ast.Add: ast.Sub, ast.Sub: ast.Add, ast.Mult: ast.Div, ast.Div: ast.Mult, ast.FloorDiv: ast.Div,
                 ast.Pow: ast.Mult}
        for op, new in swaps.items():
            if isinstance(node.op, op):
                out.append(ast.BinOp(node.left, new(), node.right))
        if isinstance(node.op, (ast.Sub, ast.Div, ast.MatMult)):
            out.append(ast.BinOp(node.right, node.op, node.left))
        if isinstance(node.op, ast.Pow) and isinstance(node.right, ast.Constant) and node.right.value == 2:
            out.append(ast.Call(ast.Attribute(ast.Name("np", ast.Load()), "sqrt", ast.Load()), [node.left], []))
        if isinstance(node.op, ast.MatMult):
            for side in ("left", "right"):
                operand = getattr(node, side)
                if isinstance(operand, ast.Name) and operand.id[:1].isupper() and operand.id not in SYMMETRIC:
                    new = copy.copy(node)
                    setattr(new, side, _swapaxes(operand))
                    out.append(new)
    elif isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
        out.append(node.operand)
    elif isinstance(node, ast.Compare) and len(node.ops) == 1:
        swaps = {ast.Lt: [ast.LtE, ast.Gt], ast.LtE: [ast.Lt, ast.GtE], ast.Gt: [ast.GtE, ast.Lt],
                 ast.GtE: [ast.Gt, ast.LtE], ast.Eq: [ast.NotEq], ast.NotEq: [ast.Eq], ast.Is: [ast.IsNot],
                 ast.IsNot: [ast.Is]}
        for new in swaps.get(type(node.ops[0]), []):
            out.append(ast.Compare(node.left, [new()], node.comparators))
    elif isinstance(node, ast.BoolOp):
        out.append(ast.BoolOp(ast.Or() if isinstance(node.op, ast.And) else ast.And(), node.values))
    elif isinstance(node, ast.Call):
        name = _call_name(node)
        if name and name.startswith(_CHECK_CALL_PREFIXES):
            return []
        if name in _DROPPABLE and len(node.args) == 1 and not node.keywords:
            out.append(node.args[0])
        if name == "copy" and isinstance(node.func, ast.Attribute) and not node.args:
            out.append(node.func.value)
        if name == "sqrt" and len(node.args) == 1:
            out.append(ast.BinOp(node.args[0], ast.Pow(), ast.Constant(2)))
        if name in _NAME_SWAP and isinstance(node.func, ast.Attribute) and _NAME_SWAP[name] != name:
            out.append(ast.Call(ast.Attribute(node.func.value, _NAME_SWAP[name], ast.Load()), node.args,
                                node.keywords))
        if name == "angle_diff" and len(node.args) == 2:
            out.append(ast.BinOp(node.args[0], ast.Sub(), node.args[1]))
        if len(node.args) >= 2 and not any(isinstance(a, ast.Starred) for a in node.args[:2]):
            if ast.dump(node.args[0]) != ast.dump(node.args[1]):
                out.append(ast.Call(node.func, [node.args[1], node.args[0], *node.args[2:]], node.keywords))
        if name == "where" and len(node.args) == 3:
            out.append(ast.Call(node.func, [node.args[0], node.args[2], node.args[1]], node.keywords))
    elif isinstance(node, ast.Attribute) and node.attr == "T" and isinstance(node.ctx, ast.Load):
        out.append(node.value)
    elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Load):
        alts = [a for a in CONFUSABLE.get(node.id, []) if a in names]
        if node.id in params:
            alts += [p for p in params if p != node.id and p not in alts]
        out.extend(ast.Name(a, ast.Load()) for a in alts)
    elif isinstance(node, ast.Constant):
        out.extend(_const_mutations(node, in_index))
    elif isinstance(node, ast.Return) and node.value is not None:
        out.extend(ast.Return(ast.Name(p, ast.Load())) for p in params)
    elif isinstance(node, ast.AugAssign) or (isinstance(node, ast.Assign) and len(node.targets) == 1
                                             and isinstance(node.targets[0], ast.Subscript)):
        out.append(ast.Pass())
    return out


def _sites(tree):
    """(node, parent, field, index, in_index) for every mutable node of a function definition."""
    fdef = tree.body[0]
    params = [a.arg for a in fdef.args.args + fdef.args.kwonlyargs]
    names = set(params) | {t.id for n in ast.walk(fdef) for t in ast.walk(n)
                           if isinstance(n, (ast.Assign, ast.AugAssign, ast.For)) and isinstance(t, ast.Name)}
    sites = []

    def visit(node, in_index, skip, stmt=None):
        for field, value in ast.iter_fields(node):
            items = value if isinstance(value, list) else [value]
            for i, child in enumerate(items):
                if not isinstance(child, ast.AST):
                    continue
                child_skip = skip
                if isinstance(child, ast.stmt) and _is_check_stmt(child):
                    child_skip = True
                if isinstance(child, ast.Expr) and isinstance(child.value, ast.Constant):
                    child_skip = True  # docstring
                if isinstance(child, (ast.arguments, ast.keyword)) and field in ("args",) and isinstance(
                        node, ast.FunctionDef):
                    continue
                if isinstance(child, ast.arguments):
                    continue
                child_index = in_index or (isinstance(node, ast.Subscript) and field == "slice")
                if isinstance(child, ast.Call) and _call_name(child) in ("broadcast_shapes", "shape"):
                    child_skip = True  # shape bookkeeping for batched inputs
                if isinstance(child, ast.Subscript) and isinstance(child.value, ast.Attribute) and \
                        child.value.attr == "shape":
                    child_skip = True
                child_stmt = child if isinstance(child, ast.stmt) else stmt
                if not child_skip:
                    sites.append((child, node, field, i if isinstance(value, list) else None, child_index, child_stmt))
                visit(child, child_index, child_skip, child_stmt)

    visit(fdef, False, False)
    return [(s, params, names) for s in sites]


def _replace(parent, field, index, new):
    if index is None:
        setattr(parent, field, new)
    else:
        getattr(parent, field)[index] = new


@functools.lru_cache(maxsize=None)
def mutants(fn):
    """Every mutant of contract function ``fn`` (a tuple of :class:`Mutant`), in a fixed order."""
    units, imports = _collect(fn)
    out = []
    for name, unit in units.items():
        if unit.kind != "def" or _frozen(name, unit.obj):
            continue
        tree = ast.parse(unit.source)
        seen = {ast.unparse(tree)}
        counts = {}
        for (node, parent, field, index, in_index, stmt), params, names in _sites(tree):
            cands = _candidates(node, params, names, in_index)
            if not cands:
                continue
            before = (ast.unparse(node).splitlines() or [""])[0]
            where = (ast.unparse(stmt).splitlines() or [""])[0] if stmt is not None and stmt is not node else ""
            if len(where) > 90:
                where = where[:87] + "..."
            for cand in cands:
                _replace(parent, field, index, cand)
                try:
                    host = ast.unparse(ast.fix_missing_locations(tree))
                finally:
                    _replace(parent, field, index, node)
                if host in seen:
                    continue
                seen.add(host)
                try:
                    compile(host, f"<mutant of {fn}>", "exec")
                except (SyntaxError, ValueError, TypeError):
                    continue
                src = _assemble(units, imports, {name: host})
                after = (ast.unparse(cand).splitlines() or [""])[0]
                key = (f"[{where}] " if where else "") + f"{before} -> {after}"
                counts[key] = counts.get(key, 0) + 1
                if counts[key] > 1:
                    key = f"{key} #{counts[key]}"
                out.append(Mutant(fn, name, key, src))
    return tuple(out)


# =========================================================================== grading
class MutantTimeout(Exception):
    """A mutant ran longer than the harness allows (counts as a failed test, as a grader timeout would)."""


def _on_alarm(signum, frame):
    raise MutantTimeout("the mutant exceeded the harness's time limit")


def load(source, name="mutant_submission"):
    ns = {"__name__": name}
    exec(compile(source, f"<{name}>", "exec"), ns)  # noqa: S102 - our own generated source
    return ns


def exercise_of(fn):
    for ex, fns in CONTRACT.items():
        if fn in fns:
            return ex
    raise KeyError(fn)


def grade_namespace(fn, ns, *, stop_at_first=True, seed=SEED, timeout=20.0):
    """Run ``fn``'s tests on the function in ``ns``; returns ``[(test name, score, max, output)]``."""
    from autograder.engine import run_tests
    from autograder.selfcheck import InProcessCaller

    ex = get_exercise(exercise_of(fn))
    caller = InProcessCaller(ns)
    rows = []
    use_alarm = hasattr(signal, "setitimer") and importlib.import_module("threading").current_thread().name == \
        "MainThread"
    for test in ex.tests_for(fn):
        single = type(ex)(ex.name, ex.title, ex.notebook, ex.functions, ex.seed, [test])
        old = signal.signal(signal.SIGALRM, _on_alarm) if use_alarm else None
        if use_alarm:
            signal.setitimer(signal.ITIMER_REAL, timeout)
        try:
            with warnings.catch_warnings(), np.errstate(all="ignore"):
                warnings.simplefilter("ignore")
                results, _ = run_tests(single, fn, caller, seed=seed)
        except MutantTimeout as exc:
            from autograder.engine import TestResult
            results = [TestResult(test.name, fn, 0.0, test.weight, f"FAILED\n{exc}", "visible")]
        finally:
            if use_alarm:
                signal.setitimer(signal.ITIMER_REAL, 0)
                signal.signal(signal.SIGALRM, old)
        r = results[0]
        rows.append((r.name, r.score, r.max_score, r.output))
        if stop_at_first and r.score < r.max_score - 1e-9:
            break
    return rows


def grade_mutant(m, **kw):
    """``(killed, first failing test or None)`` for mutant ``m``."""
    try:
        ns = load(m.source)
    except Exception as exc:  # noqa: BLE001 - a mutant that does not even load is killed at import
        return True, f"import failed: {type(exc).__name__}"
    rows = grade_namespace(m.function, ns, **kw)
    for name, score, top, _ in rows:
        if score < top - 1e-9:
            return True, name
    return False, None


def run(functions=None, *, every=1, offset=0, progress=None):
    """Grade the mutants of ``functions`` (all contract functions by default).

    Returns ``{function: {"total": n, "killed": k, "survivors": [Mutant, ...], "seconds": s}}``.
    """
    functions = functions or [f for fns in CONTRACT.values() for f in fns]
    report = {}
    for fn in functions:
        t0 = time.perf_counter()
        ms = mutants(fn)[offset::every]
        survivors = []
        for m in ms:
            killed, _ = grade_mutant(m)
            if not killed:
                survivors.append(m)
            if progress:
                progress(fn, m, killed)
        report[fn] = {"total": len(ms), "killed": len(ms) - len(survivors), "survivors": survivors,
                      "seconds": time.perf_counter() - t0}
    return report


def reason(equivalent, m):
    """The table's reason for mutant ``m`` (exact label, else a pattern whose ``*`` matches anything), or None."""
    table = equivalent.get(m.function, {})
    if m.label in table:
        return table[m.label]
    for pattern, why in table.items():
        if "*" in pattern and re.fullmatch(".*".join(map(re.escape, pattern.split("*"))), m.label, flags=re.S):
            return why
    return None


def summarize(report, equivalent, not_killed=None):
    """Rows ``(function, total, equivalent, non-equivalent, killed, rate, unexplained survivors)``.

    Only surviving mutants are looked up in the tables: a listed mutant that a test
    kills counts as killed. Survivors listed in ``not_killed`` count against the rate;
    survivors in neither table are "unexplained".
    """
    rows = []
    not_killed = not_killed or {}
    for fn, r in report.items():
        eq = [m for m in r["survivors"] if reason(equivalent, m)]
        unexplained = [m for m in r["survivors"] if not reason(equivalent, m) and not reason(not_killed, m)]
        non_eq = r["total"] - len(eq)
        rate = r["killed"] / non_eq if non_eq else 1.0
        rows.append((fn, r["total"], len(eq), non_eq, r["killed"], rate, unexplained))
    return rows


def main(argv=None):
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from mutation_table import EQUIVALENT, NOT_KILLED

    p = argparse.ArgumentParser(prog="python -m tests.mutation", description=__doc__.splitlines()[0])
    p.add_argument("--function", action="append", help="only this contract function (repeatable)")
    p.add_argument("--every", type=int, default=1, help="grade every K-th mutant only")
    p.add_argument("--list", action="store_true", help="list the mutants instead of grading them")
    p.add_argument("--source", help="print the source of the mutant with this label")
    args = p.parse_args(argv)
    functions = args.function or [f for fns in CONTRACT.values() for f in fns]
    if args.list or args.source:
        for fn in functions:
            for m in mutants(fn)[:: args.every]:
                if args.source and m.label == args.source:
                    print(m.source)
                    return 0
                if args.list:
                    print(f"{fn}\t{m.label}")
        return 0
    def progress(fn, m, killed):
        progress.n = getattr(progress, "n", 0) + 1
        if progress.n % 100 == 0:
            print(f"  ... {progress.n} mutants graded ({fn})", file=sys.stderr, flush=True)

    report = run(functions, every=args.every, progress=progress)
    rows = summarize(report, EQUIVALENT, NOT_KILLED)
    print(f"{'function':32s} {'mutants':>7s} {'equiv.':>6s} {'killed':>6s} {'kill rate':>9s} {'seconds':>7s}")
    for fn, total, eq, non_eq, killed, rate, _ in rows:
        print(f"{fn:32s} {total:7d} {eq:6d} {killed:6d} {100 * rate:8.1f}% {report[fn]['seconds']:7.1f}")
    tot = sum(r[1] for r in rows)
    killed = sum(r[4] for r in rows)
    non_eq = sum(r[3] for r in rows)
    print(f"{'all':32s} {tot:7d} {tot - non_eq:6d} {killed:6d} {100 * killed / max(non_eq, 1):8.1f}%")
    for fn, r in report.items():
        for m in r["survivors"]:
            why = reason(EQUIVALENT, m)
            why = f"equivalent: {why}" if why else (f"NOT KILLED: {reason(NOT_KILLED, m)}" if reason(NOT_KILLED, m)
                                                    else "UNEXPLAINED")
            print(f"survivor {fn} | {m.label} | {why}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
