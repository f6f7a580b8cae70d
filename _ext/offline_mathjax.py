"""Serve the book's own copy of MathJax 3, so equations render without a network.

MathJax comes from the ``django-static-mathjax`` wheel on PyPI (MathJax 3.2.2,
Apache-2.0; a plain data package that does not need Django), installed with the
project's ``dev`` extra. At the end of an HTML build the parts MathJax needs for
TeX input and CommonHTML output are copied into ``_build/html/_static/mathjax``
and every page loads ``_static/mathjax/tex-chtml.js`` instead of a CDN.
"""

from __future__ import annotations

import shutil
from importlib import resources
from pathlib import Path

# what tex-chtml.js loads at run time: TeX extensions (autoload), fonts, menu, a11y
_PARTS = ["tex-chtml.js", "input/tex/extensions", "output/chtml/fonts", "ui", "a11y", "adaptors"]


def mathjax_source() -> Path:
    """Folder holding MathJax's ``es5`` build inside the installed package."""
    try:
        root = Path(str(resources.files("mathjax"))) / "static" / "mathjax" / "es5"
    except ModuleNotFoundError:
        root = None
    if root is None or not (root / "tex-chtml.js").is_file():
        raise RuntimeError(
            "MathJax is not installed: the book serves its own copy from the "
            "'django-static-mathjax' package; run  python -m pip install -e \".[dev]\""
        )
    return root


def _builder_inited(app):
    mathjax_source()  # fail early with a clear message
    app.config.mathjax_path = "mathjax/tex-chtml.js"


def _build_finished(app, exception):
    if exception is not None or app.builder.format != "html":
        return
    src = mathjax_source()
    dest = Path(app.outdir) / "_static" / "mathjax"
    for part in _PARTS:
        s = src / part
        if not s.exists():
            continue
        d = dest / part
        if s.is_dir():
            shutil.copytree(s, d, dirs_exist_ok=True)
        else:
            d.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(s, d)


def _dedupe_scripts(app, pagename, templatename, context, doctree):
    """Drop repeated ``<script>`` entries.

    sphinx-thebe registers its inline configuration (``const THEBE_JS_URL = ...``)
    once per read of the sources; a build that reads twice gets two copies, and
    the second ``const`` declaration is a JavaScript error on every page.
    """
    seen, unique = set(), []
    for script in context.get("script_files", []):
        key = (str(getattr(script, "filename", script) or ""), getattr(script, "attributes", {}).get("body", ""))
        if key in seen:
            continue
        seen.add(key)
        unique.append(script)
    context["script_files"] = unique


def setup(app):
    app.connect("builder-inited", _builder_inited)
    app.connect("html-page-context", _dedupe_scripts, priority=999)  # after every other handler
    app.connect("build-finished", _build_finished)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
