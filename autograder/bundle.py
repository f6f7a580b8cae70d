"""The Gradescope autograder bundle, and what it runs on Gradescope.

``python -m autograder bundle --exercise NAME -o autograder.zip`` writes a zip with

* ``setup.sh`` -- run once by Gradescope when the image is built: finds (or
  installs) Python >= 3.11, creates ``/autograder/venv``, installs the pinned
  requirements (binary wheels only) and the project's wheel from the zip, installs
  the grading secret readable by root only, and takes read permission on the
  reference and the grader away from other users (the fallback protection where
  the sandbox cannot use namespaces);
* ``run_autograder`` -- run for every submission: grades
  ``$AUTOGRADER_ROOT/submission/*`` (``AUTOGRADER_ROOT`` defaults to
  ``/autograder``) and writes ``$AUTOGRADER_ROOT/results/results.json``; if the
  grader cannot even start it still leaves a valid results.json;
* ``requirements.txt`` -- exactly the versions of the runtime dependencies this
  bundle was built (and tested) with: NumPy, SciPy, nbformat and what they need,
  nothing else (no matplotlib, ipywidgets or tqdm: grading does not use them);
* ``grading_secret`` -- a fresh secret per bundle: each submission's scenarios are
  drawn from a seed derived from it and from the submission's content;
* ``wheels/slamlib-<version>-py3-none-any.whl`` -- this project (``slamlib`` and
  ``autograder``), built from the source tree by :func:`build_wheel`.
"""

from __future__ import annotations

import base64
import hashlib
import io
import os
import stat
import zipfile
from pathlib import Path

from .results import fallback_results, safe_print, write_json_atomic
from .spec import VISIBILITY

__all__ = ["build_bundle", "build_wheel", "run_gradescope", "project_root"]

PROJECT_ROOT = Path(__file__).resolve().parents[1]

SETUP_SH = r"""#!/usr/bin/env bash
# Gradescope setup: Python >= 3.11, a virtual environment, the requirements and this project's wheel.
set -euo pipefail
cd "$(dirname "$0")"
ROOT="${AUTOGRADER_ROOT:-/autograder}"
pick_python() {
  for py in python3.13 python3.12 python3.11 python3; do
    if command -v "$py" >/dev/null 2>&1 && "$py" -c 'import sys; sys.exit(sys.version_info < (3, 11))'; then
      echo "$py"; return 0
    fi
  done
  return 1
}
PY=$(pick_python || true)
if [ -z "$PY" ]; then
  apt-get update
  apt-get install -y python3.11 python3.11-venv
  PY=python3.11
fi
if ! "$PY" -m venv --help >/dev/null 2>&1; then
  apt-get update && apt-get install -y python3-venv
fi
"$PY" -m venv "$ROOT/venv"
export PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_NO_INPUT=1
"$ROOT/venv/bin/python" -m pip install --quiet --no-cache-dir --only-binary=:all: -r requirements.txt
"$ROOT/venv/bin/python" -m pip install --quiet --no-cache-dir --no-deps wheels/*.whl
# the secret: root only (and outside the sandbox's root anyway)
install -m 600 grading_secret "$ROOT/grading_secret"
rm -f grading_secret
# fallback protection where namespaces are unavailable: the submission runs as another
# uid, which must not read the reference, the tests or this bundle
SITE=$("$ROOT/venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
chmod -R go-rwx "$SITE/slamlib" "$SITE/autograder" "$SITE"/slamlib-*.dist-info "$(pwd)"
"$ROOT/venv/bin/python" -m autograder list >/dev/null
"""

RUN_AUTOGRADER = r"""#!/usr/bin/env bash
# Gradescope entry point: grade $AUTOGRADER_ROOT/submission into $AUTOGRADER_ROOT/results/results.json.
# When the grader writes no results.json (its self-check failed, or Python could not start it), none is made up
# here: Gradescope then reports that the autograder failed, which is the staff's to fix, not a student's zero.
ROOT="$(cd "${AUTOGRADER_ROOT:-/autograder}" && pwd)" || exit 1
PY="${AUTOGRADER_PYTHON:-$ROOT/venv/bin/python}"
case "$PY" in /*) ;; */*) PY="$(cd "$(dirname "$PY")" && pwd)/$(basename "$PY")" ;; esac
if [ ! -x "$PY" ]; then PY=python3; fi
mkdir -p "$ROOT/results"
cd "$ROOT" || exit 1
AUTOGRADER_SECRET_FILE="${AUTOGRADER_SECRET_FILE:-$ROOT/grading_secret}" \
  "$PY" -P -m autograder gradescope --root "$ROOT" --exercise "@EXERCISE@"
"""


def project_root():
    """The source checkout this package lives in (it must hold pyproject.toml)."""
    if not (PROJECT_ROOT / "pyproject.toml").is_file():
        raise RuntimeError("building a bundle needs the project's source tree (pyproject.toml not found next to the "
                           "autograder package)")
    return PROJECT_ROOT


def _project_meta(root):
    import tomllib

    data = tomllib.loads((root / "pyproject.toml").read_text(encoding="utf-8"))
    return data["project"]


def _package_files(root):
    for pkg in ("slamlib", "autograder"):
        for path in sorted((root / pkg).rglob("*")):
            rel = path.relative_to(root)
            if path.is_file() and "__pycache__" not in rel.parts and path.suffix not in (".pyc", ".pyo"):
                yield rel.as_posix(), path.read_bytes()


def _record_line(name, data):
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
    return f"{name},sha256={digest},{len(data)}"


def build_wheel(root=None):
    """A pure-Python wheel of the project (``slamlib`` + ``autograder``): ``(filename, bytes)``."""
    root = Path(root) if root else project_root()
    meta = _project_meta(root)
    name, version = meta["name"], meta["version"]
    dist = f"{name}-{version}.dist-info"
    metadata = [
        "Metadata-Version: 2.1",
        f"Name: {name}",
        f"Version: {version}",
        f"Summary: {meta.get('description', '')}",
        f"Requires-Python: {meta.get('requires-python', '>=3.11')}",
    ]
    metadata += [f"Requires-Dist: {d}" for d in meta.get("dependencies", [])]
    files = list(_package_files(root))
    extra = {
        f"{dist}/METADATA": ("\n".join(metadata) + "\n").encode(),
        f"{dist}/WHEEL": b"Wheel-Version: 1.0\nGenerator: autograder.bundle\nRoot-Is-Purelib: true\nTag: py3-none-any\n",
        f"{dist}/top_level.txt": b"autograder\nslamlib\n",
        f"{dist}/entry_points.txt": ("[console_scripts]\n" + "".join(
            f"{k} = {v}\n" for k, v in meta.get("scripts", {}).items())).encode(),
    }
    buf = io.BytesIO()
    record = []
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for arcname, data in files + list(extra.items()):
            info = zipfile.ZipInfo(arcname, date_time=(2020, 1, 1, 0, 0, 0))
            info.external_attr = 0o644 << 16
            info.compress_type = zipfile.ZIP_DEFLATED
            zf.writestr(info, data)
            record.append(_record_line(arcname, data))
        record.append(f"{dist}/RECORD,,")
        info = zipfile.ZipInfo(f"{dist}/RECORD", date_time=(2020, 1, 1, 0, 0, 0))
        info.external_attr = 0o644 << 16
        zf.writestr(info, "\n".join(record) + "\n")
    return f"{name}-{version}-py3-none-any.whl", buf.getvalue()


#: What grading imports (the grader's process); everything else in the project's dependencies is left out.
GRADING_REQUIREMENTS = ("numpy", "scipy", "nbformat")


def pinned_requirements(names=GRADING_REQUIREMENTS):
    """``name==version`` of ``names`` and of everything they require, as installed here.

    The versions are those of the environment that builds the bundle (and runs the
    test suite), so Gradescope grades with exactly what was tested.
    """
    import re
    from importlib import metadata

    def canon(n):
        return re.sub(r"[-_.]+", "-", n).lower()

    seen, todo = {}, [canon(n) for n in names]
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        try:
            dist = metadata.distribution(name)
        except metadata.PackageNotFoundError:
            raise RuntimeError(f"{name} is not installed: cannot pin it for the bundle") from None
        seen[name] = (dist.metadata["Name"], dist.version)
        for req in dist.requires or []:
            spec, _, marker = req.partition(";")
            if "extra" in marker:
                continue
            if marker.strip():
                try:
                    from packaging.markers import Marker

                    if not Marker(marker.strip()).evaluate():
                        continue
                except ImportError:
                    pass
            m = re.match(r"\s*([A-Za-z0-9][A-Za-z0-9._-]*)", spec)
            if m:
                todo.append(canon(m.group(1)))
    return [f"{n}=={v}" for n, v in sorted(seen.values(), key=lambda t: t[0].lower())]


def build_bundle(exercise, output="autograder.zip"):
    """Write the Gradescope autograder zip for ``exercise``; returns its path."""
    from .exercises import get_exercise
    from .seeds import new_secret

    ex = get_exercise(exercise)
    root = project_root()
    wheel_name, wheel = build_wheel(root)
    reqs = "\n".join(pinned_requirements()) + "\n"
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    entries = {
        "setup.sh": (SETUP_SH.encode(), 0o755),
        "run_autograder": (RUN_AUTOGRADER.replace("@EXERCISE@", ex.name).encode(), 0o755),
        "requirements.txt": (reqs.encode(), 0o644),
        f"wheels/{wheel_name}": (wheel, 0o644),
        "grading_secret": ((new_secret() + "\n").encode(), 0o600),
        "README.txt": (f"Gradescope autograder for exercise {ex.name} ({ex.notebook}).\n"
                       "Upload this zip as the autograder of a programming assignment; students submit "
                       f"{ex.notebook}.\n".encode(), 0o644),
    }
    tmp = output.with_name(f".{output.name}.tmp")
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, (data, mode) in entries.items():
            info = zipfile.ZipInfo(name, date_time=(2020, 1, 1, 0, 0, 0))
            info.external_attr = (stat.S_IFREG | mode) << 16
            info.compress_type = zipfile.ZIP_DEFLATED
            zf.writestr(info, data)
    os.replace(tmp, output)
    return output


def _gradescope_secret(root, secret=None):
    from .seeds import SECRET_ENV

    if secret or os.environ.get(SECRET_ENV):
        return secret or os.environ[SECRET_ENV]
    for p in (root / "grading_secret", root / "source" / "grading_secret"):
        if p.is_file():
            return str(p)
    return None


def run_gradescope(root, exercise, *, limits=None, secret=None):
    """Grade ``root/submission`` into ``root/results/results.json``.

    Written whenever grading ran (a grader error included); not written when the
    sandbox's self-check fails before grading (exit status 3), so that no student
    gets a score from a broken installation.
    """
    from .batch import pick_submission_file
    from .engine import grade
    from .exercises import get_exercise

    from .sandbox import SandboxBroken, require_sandbox

    root = Path(root)
    results = root / "results" / "results.json"
    try:
        require_sandbox(limits)
    except SandboxBroken as exc:  # the grader's fault: no results.json, so Gradescope reports an autograder failure
        safe_print(str(exc))
        return 3
    try:
        ex = get_exercise(exercise)
        path, why = pick_submission_file(root / "submission", ex.notebook)
        if path is None:
            msg = f"Nothing to grade: {why}. Submit {ex.notebook}."
            tests = [{"name": t.name, "score": 0.0, "max_score": t.weight, "status": "failed", "output": msg,
                      "visibility": VISIBILITY[t.visibility]} for t in ex.tests]
            write_json_atomic(results, {**fallback_results(msg), "tests": tests})
            safe_print(msg)
            return 0
        result = grade(path, ex.name, limits=limits, secret=_gradescope_secret(root, secret))
        write_json_atomic(results, result.to_gradescope())
    except Exception:  # noqa: BLE001 - always leave a valid results.json
        import traceback

        msg = "The autograder failed internally; please tell the course staff.\n" + traceback.format_exc(limit=5)
        write_json_atomic(results, fallback_results(msg))
        safe_print(msg)
        return 1
    safe_print(result.text_report())  # after the results are written: a log that cannot be printed changes nothing
    return 0
