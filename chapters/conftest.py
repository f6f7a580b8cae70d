"""Every chapter notebook is a test: it must run from top to bottom without an error, and the text
outputs of the cells marked ``NBVAL_CHECK_OUTPUT`` must equal the ones stored in the notebook.

Each notebook runs once per test session, in a fresh kernel whose working directory is the
notebook's folder, exactly as the book build runs it (``jupyter-book build .`` with
``execute_notebooks: cache``). When it passes, its executed copy is stored in the book's execution
cache (``_build/.jupyter_cache``, the cache of jupyter-cache that MyST-NB reads), so a book built
after the tests reuses these executions instead of running every chapter a second time. The tests
themselves never read that cache: a notebook is always executed against the library as it is now.
"""

from __future__ import annotations

import fcntl
import os
from contextlib import contextmanager
from pathlib import Path

import nbformat
import pytest

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
CACHE = ROOT / "_build" / ".jupyter_cache"  # jupyter-book's default: <build dir>/.jupyter_cache
CHECK = "NBVAL_CHECK_OUTPUT"
TIMEOUT = 300  # seconds per cell, as _config.yml's execute.timeout


def pytest_collect_file(file_path, parent):
    if file_path.suffix == ".ipynb" and file_path.parent == HERE:
        return NotebookFile.from_parent(parent, path=file_path)
    return None


class NotebookFile(pytest.File):
    def collect(self):
        yield NotebookRun.from_parent(self, name="runs")


class NotebookFailed(Exception):
    pass


def _text_outputs(outputs) -> list[tuple[str, str]]:
    """The text a reader sees, output by output: streams and ``text/plain`` results (no images,
    no execution counts)."""
    seen = []
    for out in outputs:
        if out.output_type == "stream":
            seen.append((out.name, out.text))
        elif out.output_type in ("execute_result", "display_data") and "text/plain" in out.get("data", {}):
            seen.append(("result", out.data["text/plain"]))
        elif out.output_type == "error":
            seen.append(("error", f"{out.ename}: {out.evalue}"))
    # consecutive pieces of one stream are one text (the kernel may split it anywhere)
    merged: list[tuple[str, str]] = []
    for kind, text in seen:
        if merged and merged[-1][0] == kind and kind in ("stdout", "stderr"):
            merged[-1] = (kind, merged[-1][1] + text)
        else:
            merged.append((kind, text))
    return merged


@contextmanager
def _inline_matplotlib():
    """The kernel draws figures as the book shows them, whatever backend the test process uses."""
    old = os.environ.get("MPLBACKEND")
    os.environ["MPLBACKEND"] = "module://matplotlib_inline.backend_inline"
    try:
        yield
    finally:
        if old is None:
            os.environ.pop("MPLBACKEND", None)
        else:
            os.environ["MPLBACKEND"] = old


def _store_in_book_cache(nb, path: Path, seconds: float, cache_dir: Path) -> None:
    """Put the executed notebook into the book's execution cache (one writer at a time)."""
    from jupyter_cache import get_cache
    from jupyter_cache.base import CacheBundleIn

    cache_dir.parent.mkdir(parents=True, exist_ok=True)
    with open(cache_dir.parent / ".jupyter_cache.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        cache = get_cache(str(cache_dir))
        record = cache.add_nb_to_project(str(path))
        cache.cache_notebook_bundle(CacheBundleIn(nb, record.uri, data={"execution_seconds": seconds}),
                                    check_validity=False, overwrite=True)


def run_notebook(path: Path, *, cache: Path | None = CACHE) -> float:
    """Execute the notebook at ``path``, check its marked outputs, store it in ``cache`` (``None``:
    nowhere); returns the execution time in seconds. Raises :class:`NotebookFailed`."""
    from jupyter_cache.executors.utils import single_nb_execution

    nb = nbformat.read(path, as_version=4)
    expected = {k: _text_outputs(c.outputs) for k, c in enumerate(nb.cells)
                if c.cell_type == "code" and CHECK in c.source}
    with _inline_matplotlib():
        result = single_nb_execution(nb, cwd=str(path.parent), timeout=TIMEOUT,
                                     allow_errors=False, meta_override=True)
    if result.err is not None:
        raise NotebookFailed(result.exc_string)
    for k, want in expected.items():
        got = _text_outputs(nb.cells[k].outputs)
        if got != want:
            first = nb.cells[k].source.strip().splitlines()[:2]
            raise NotebookFailed(f"cell {k} ({' / '.join(first)}): its output changed\n"
                                 f"stored: {want}\nnow:    {got}")
    if cache is not None:
        _store_in_book_cache(nb, path, result.time, cache)
    return result.time


class NotebookRun(pytest.Item):
    def runtest(self):
        store = os.environ.get("SLAM_NB_NO_BOOK_CACHE") != "1"
        run_notebook(self.path, cache=CACHE if store else None)

    def repr_failure(self, excinfo, style=None):
        if isinstance(excinfo.value, NotebookFailed):
            return f"{self.path.name}: {excinfo.value}"
        return super().repr_failure(excinfo, style=style)

    def reportinfo(self):
        return self.path, 0, f"notebook {self.path.name}"
