"""Build a standalone submission from slamlib's own source, as a student could hand it in.

The generated ``.py`` embeds the source text of the slamlib modules the
exercise needs (read with :func:`inspect.getsource`) and executes each in its own
module object of a private package ``_reference``, so relative imports and
private helpers work exactly as in slamlib. It imports only NumPy and SciPy:
nothing from slamlib is imported while it loads or runs. The contract functions
are then bound at module level.
"""

from __future__ import annotations

import inspect
import re
from pathlib import Path

_IMPORT = re.compile(r"^from \.(\w*) import", re.M)

TEMPLATE = '''"""Reference implementation of exercise {exercise!r}, generated from slamlib's source."""

import sys
import types

_SOURCES = {sources!r}
_ORDER = {order!r}

_pkg = types.ModuleType("_reference")
_pkg.__path__ = []
sys.modules["_reference"] = _pkg
_mods = {{}}
for _name in _ORDER:
    _mod = types.ModuleType("_reference." + _name)
    _mod.__package__ = "_reference"
    sys.modules["_reference." + _name] = _mod
    exec(compile(_SOURCES[_name], "<reference " + _name + ">", "exec"), _mod.__dict__)
    setattr(_pkg, _name, _mod)
    _mods[_name] = _mod

{bindings}
'''


def _deps(source):
    return [m for m in _IMPORT.findall(source) if m]


def reference_source(exercise_functions):
    """Text of a standalone module defining ``exercise_functions`` (name -> slamlib module name)."""
    import importlib

    sources = {}
    order = []

    def visit(name):
        if name in sources:
            return
        mod = importlib.import_module(f"slamlib.{name}")
        src = inspect.getsource(mod)
        sources[name] = src
        for dep in _deps(src):
            visit(dep)
        order.append(name)

    for mod_name in dict.fromkeys(exercise_functions.values()):
        visit(mod_name)
    bindings = "\n".join(f"{fn} = _mods[{mod!r}].{fn}" for fn, mod in exercise_functions.items())
    return TEMPLATE.format(exercise="", sources=sources, order=order, bindings=bindings)


def write_reference_submission(exercise, path):
    """Write the reference submission of ``exercise`` (an autograder Exercise) to ``path``."""
    import slamlib

    functions = {fn: getattr(slamlib, fn).__module__.split(".")[-1] for fn in exercise.functions}
    text = reference_source(functions).replace("exercise ''", f"exercise {exercise.name!r}", 1)
    Path(path).write_text(text, encoding="utf-8")
    return Path(path)
