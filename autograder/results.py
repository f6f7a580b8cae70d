"""Writing ``results.json`` atomically, including when grading itself fails."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

__all__ = ["write_json_atomic", "fallback_results"]


def write_json_atomic(path, data):
    """Write ``data`` as JSON to ``path`` through a temporary file and ``os.replace``.

    A reader never sees a partial file: either the old content or the new one.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps(data, indent=2, allow_nan=False, ensure_ascii=False)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=str(path.parent))
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.write("\n")
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def fallback_results(message, tests=None):
    """A valid results.json payload scoring 0 with an explanation."""
    return {"score": 0.0, "execution_time": 0, "output": message, "tests": tests or []}
