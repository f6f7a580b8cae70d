"""Accessible pages: repair, after every HTML build, the few places where the theme's and docutils'
markup fails axe-core's serious or critical rules (the browser test runs axe-core on every page).

- the search button's ``aria-label="Search"`` hides its visible text ("Search Ctrl+K"), and the
  colour-mode button's icons carry titles that are not its name (label-content-name-mismatch): the
  search button is named by its text, the icons are hidden from assistive technology;
- the navigation's ``<summary>`` toggles hold only an icon (summary-name): they get a label; the
  toggles of hidden code cells are labelled "Toggle hidden content" while they show "Show code cell
  source" (label-content-name-mismatch): they are named by their text;
- the bibliography is a ``role="list"`` whose entries carry ``role="doc-biblioentry"``, which ARIA
  1.2 deprecates and which is not a list item (aria-required-children): they become list items.

Each repair must find what it repairs in at least one page of a build: if a theme update changes the
markup, the build warns (``-W`` makes that an error) instead of silently leaving the fix undone.
"""

from __future__ import annotations

import re
from pathlib import Path

from sphinx.util import logging

logger = logging.getLogger(__name__)

# (name, pattern, replacement)
_REPAIRS = [
    ("search button named by its visible text",
     re.compile(r'(<button class="btn search-button-field search-button__button[^"]*" title="Search") aria-label="Search"'),
     r"\1"),
    ("colour-mode icons hidden from assistive technology",
     re.compile(r'<i class="theme-switch (fa-solid [^"]*)" data-mode="(\w+)" title="[^"]*"></i>'),
     r'<i class="theme-switch \1" data-mode="\2" aria-hidden="true"></i>'),
    ("hidden-cell toggles named by their visible text",
     re.compile(r'<summary aria-label="Toggle hidden content">'),
     "<summary>"),
    ("navigation toggles labelled",
     re.compile(r"<summary>(<span class=\"toctree-toggle\" role=\"presentation\">)"),
     r'<summary aria-label="Show or hide the sections">\1'),
    ("bibliography entries as list items",
     re.compile(r'(<div class="citation" id="[^"]*") role="doc-biblioentry"'),
     r'\1 role="listitem"'),
]


def repair(html: str) -> tuple[str, dict[str, int]]:
    """The page with every repair applied, and how often each applied."""
    counts = {}
    for name, pattern, replacement in _REPAIRS:
        html, counts[name] = pattern.subn(replacement, html)
    return html, counts


def _build_finished(app, exception):
    if exception is not None or app.builder.format != "html":
        return
    totals = dict.fromkeys((name for name, _, _ in _REPAIRS), 0)
    for page in Path(app.outdir).rglob("*.html"):
        text = page.read_text(encoding="utf-8")
        fixed, counts = repair(text)
        if fixed != text:
            page.write_text(fixed, encoding="utf-8")
        for name, n in counts.items():
            totals[name] += n
    if app.builder.name != "html":  # the single page has no navigation toggles
        return
    for name, n in totals.items():
        if n == 0:
            logger.warning(f"accessibility repair '{name}' found nothing to repair: the theme's markup "
                           "changed; update _ext/accessibility.py")


def setup(app):
    app.connect("build-finished", _build_finished)
    return {"version": "1.0", "parallel_read_safe": True, "parallel_write_safe": True}
