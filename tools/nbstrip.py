"""Strip notebook outputs except the text outputs of cells that the notebook tests check.

Usage: ``python tools/nbstrip.py [NOTEBOOK ...]`` (default: every notebook under
``chapters/`` and ``exercises/``). Cells whose source contains
``# NBVAL_CHECK_OUTPUT`` keep their ``stream`` and ``text/plain`` outputs (what
the notebook test in chapters/conftest.py compares); every other output, every execution count and the per-cell
execution metadata are dropped, so the repository holds no build products.
Run with ``--check`` to only report notebooks that would change (exit 1).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MARK = "NBVAL_CHECK_OUTPUT"


def _keep(output):
    if output.get("output_type") == "stream":
        return {k: output[k] for k in ("output_type", "name", "text")}
    if output.get("output_type") in ("execute_result", "display_data") and "text/plain" in output.get("data", {}):
        return {"output_type": "execute_result", "data": {"text/plain": output["data"]["text/plain"]},
                "metadata": {}, "execution_count": None}
    return None


def strip(nb: dict) -> dict:
    for cell in nb.get("cells", []):
        cell.get("metadata", {}).pop("execution", None)
        cell.get("metadata", {}).pop("collapsed", None)
        if cell.get("cell_type") != "code":
            continue
        src = "".join(cell.get("source", []))
        if MARK in src:
            outs = [o for o in map(_keep, cell.get("outputs", [])) if o is not None]
            for o in outs:
                if o["output_type"] == "execute_result":
                    o["execution_count"] = 1
            cell["outputs"] = outs
            cell["execution_count"] = 1 if outs else None
        else:
            cell["outputs"] = []
            cell["execution_count"] = None
    nb.get("metadata", {}).pop("widgets", None)
    return nb


def _notebook(text):
    """An argparse type: the path of an existing notebook."""
    path = Path(text)
    if path.suffix != ".ipynb" or not path.is_file():
        raise argparse.ArgumentTypeError(f"{text!r} is not a notebook file (.ipynb)")
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("notebooks", nargs="*", type=_notebook, metavar="NOTEBOOK",
                    help="notebooks to strip (default: every chapter and exercise)")
    ap.add_argument("--check", action="store_true", help="report, do not write; exit 1 if any would change")
    args = ap.parse_args(argv)
    paths = args.notebooks or sorted([*ROOT.glob("chapters/*.ipynb"), *ROOT.glob("exercises/*.ipynb")])
    changed = []
    for path in paths:
        text = path.read_text(encoding="utf-8")
        new = json.dumps(strip(json.loads(text)), indent=1, ensure_ascii=False) + "\n"
        if new != text:
            changed.append(path)
            if not args.check:
                path.write_text(new, encoding="utf-8")
    for path in changed:
        print(("would strip " if args.check else "stripped ") + str(path))
    return 1 if (args.check and changed) else 0


if __name__ == "__main__":
    sys.exit(main())
