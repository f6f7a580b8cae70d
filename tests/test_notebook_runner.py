"""The chapter-notebook test (chapters/conftest.py) fails when it should, and fills the book's cache."""

import importlib.util
from pathlib import Path

import nbformat
import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("chapter_notebooks", ROOT / "chapters" / "conftest.py")
runner = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(runner)


def _notebook(tmp_path, *cells, stored=None):
    nb = nbformat.v4.new_notebook()
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    nb.cells = [nbformat.v4.new_code_cell(src) for src in cells]
    if stored is not None:
        nb.cells[-1].outputs = [nbformat.v4.new_output("stream", name="stdout", text=stored)]
    path = tmp_path / "nb.ipynb"
    nbformat.write(nb, path)
    return path


def test_passing_notebook_is_stored_where_the_book_build_finds_it(tmp_path):
    path = _notebook(tmp_path, "x = 2", "# NBVAL_CHECK_OUTPUT\nprint(x + 1)", stored="3\n")
    cache = tmp_path / "_build" / ".jupyter_cache"
    runner.run_notebook(path, cache=cache)
    from jupyter_cache import get_cache

    record = get_cache(str(cache)).match_cache_notebook(nbformat.read(path, as_version=4))
    assert record is not None


def test_changed_checked_output_fails(tmp_path):
    path = _notebook(tmp_path, "x = 2", "# NBVAL_CHECK_OUTPUT\nprint(x + 1)", stored="4\n")
    with pytest.raises(runner.NotebookFailed, match="output changed"):
        runner.run_notebook(path, cache=None)


def test_error_in_a_cell_fails_and_is_not_stored(tmp_path):
    path = _notebook(tmp_path, "x = 2", "raise ValueError('boom')")
    cache = tmp_path / "_build" / ".jupyter_cache"
    with pytest.raises(runner.NotebookFailed, match="boom"):
        runner.run_notebook(path, cache=cache)
    assert not cache.exists()
