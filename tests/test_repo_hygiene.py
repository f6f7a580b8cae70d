"""The repository stays what it claims: stripped notebooks, a complete toc, documented API."""

from __future__ import annotations

import inspect
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

import slamlib as sl

ROOT = Path(__file__).resolve().parents[1]
CHAPTERS = sorted((ROOT / "chapters").glob("*.ipynb"))


def _toc_files():
    text = (ROOT / "_toc.yml").read_text(encoding="utf-8")
    return re.findall(r"^\s*(?:root|- file):\s*(\S+)", text, flags=re.M)


def test_every_toc_entry_exists():
    missing = [f for f in _toc_files() if not any((ROOT / (f + ext)).is_file() for ext in ("", ".md", ".ipynb"))]
    assert not missing, f"_toc.yml lists files that do not exist: {missing}"


def test_every_chapter_is_in_the_toc():
    toc = set(_toc_files())
    orphans = [p.relative_to(ROOT).with_suffix("").as_posix() for p in CHAPTERS
               if p.relative_to(ROOT).with_suffix("").as_posix() not in toc]
    assert not orphans, f"chapters missing from _toc.yml: {orphans}"


def test_notebooks_are_stripped():
    res = subprocess.run([sys.executable, str(ROOT / "tools" / "nbstrip.py"), "--check"],
                         capture_output=True, text=True, cwd=ROOT)
    assert res.returncode == 0, "notebooks carry outputs: run python tools/nbstrip.py\n" + res.stdout


@pytest.mark.parametrize("path", CHAPTERS, ids=lambda p: p.name)
def test_chapter_has_checked_output(path):
    nb = json.loads(path.read_text(encoding="utf-8"))
    checked = [c for c in nb["cells"] if c["cell_type"] == "code" and "NBVAL_CHECK_OUTPUT" in "".join(c["source"])]
    if path.stem in ("00_intro",):
        return
    assert checked, f"{path.name} has no '# NBVAL_CHECK_OUTPUT' cell"
    assert all(c["outputs"] for c in checked), f"{path.name}: a checked cell has no stored output to compare"


def _public_functions():
    for name in sl.__all__:
        obj = getattr(sl, name)
        if inspect.isfunction(obj):
            yield name, obj


@pytest.mark.parametrize("name", [n for n, _ in _public_functions()])
def test_public_function_has_numpydoc(name):
    doc = inspect.getdoc(getattr(sl, name)) or ""
    assert "Parameters\n----------" in doc, f"sl.{name}: docstring lacks a numpydoc Parameters section"
    assert "Returns\n-------" in doc or "Yields\n------" in doc, f"sl.{name}: docstring lacks a Returns section"


def test_no_module_is_a_placeholder():
    import importlib
    import pkgutil

    empty = []
    for info in pkgutil.walk_packages(sl.__path__, "slamlib."):
        mod = importlib.import_module(info.name)
        if info.name.rsplit(".", 1)[-1].startswith("_") and info.name != "slamlib.viz._core":
            if not info.name.startswith("slamlib.viz."):
                continue
        if hasattr(mod, "__all__") and not mod.__all__ and not info.ispkg:
            empty.append(info.name)
    assert not empty, f"modules that export nothing: {empty}"


def test_tracked_files_are_small_and_data_compressed():
    files = subprocess.run(["git", "ls-files"], capture_output=True, text=True, cwd=ROOT).stdout.split()
    if not files:
        pytest.skip("not a git checkout")
    big = [f for f in files if (ROOT / f).is_file() and (ROOT / f).stat().st_size > 2 * 1024 * 1024]
    assert not big, f"tracked files over 2 MiB: {big}"
    raw = [f for f in files if f.startswith("slamlib/data/") and not f.endswith((".gz", ".npz", ".md"))]
    assert not raw, f"uncompressed data files: {raw}"


def test_every_data_folder_has_attribution():
    data = ROOT / "slamlib" / "data"
    folders = [p for p in data.iterdir() if p.is_dir()]
    missing = [p.name for p in folders if not (p / "ATTRIBUTION.md").is_file()]
    assert not missing, f"data folders without ATTRIBUTION.md: {missing}"
