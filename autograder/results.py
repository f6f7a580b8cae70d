"""The grader's results: per-test and per-submission types, reports, and writing ``results.json`` atomically.

:class:`GradeResult` is what :func:`autograder.engine.grade` returns. Its text report
and Gradescope's ``results.json`` put what a student needs first (the score, what
failed, with the call, the expected and received values and a hint); the sandbox in
force, the scenario seed and the submission's hash go to the end of the printed
report and to ``extra_data``, which Gradescope stores for the course staff.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["TestResult", "GradeResult", "write_json_atomic", "write_text_atomic", "fallback_results", "read_results"]


@dataclass
class TestResult:
    name: str
    function: str
    score: float
    max_score: float
    output: str
    visibility: str

    @property
    def status(self):
        return "passed" if self.score >= self.max_score - 1e-9 else "failed"


@dataclass
class GradeResult:
    """The outcome of grading one submission.

    ``seed`` (the base seed of the scenarios), ``submission_sha256`` and
    ``isolation`` are for the course staff: they go to ``extra_data`` in
    ``results.json`` and to the end of the printed report. ``loads`` counts
    the times the submission was loaded into a sandbox, over both gradings
    when a fault of the grader made it grade a second time.
    """

    submission: str
    exercise: str | None
    tests: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    isolation: dict = field(default_factory=dict)
    error: str | None = None
    execution_time: float = 0.0
    seed: int | None = None
    submission_sha256: str | None = None
    loads: int = 0

    @property
    def score(self):
        return round(sum(t.score for t in self.tests), 6)

    @property
    def max_score(self):
        return round(sum(t.max_score for t in self.tests), 6)

    def by_function(self):
        out = {}
        for t in self.tests:
            s, m = out.get(t.function, (0.0, 0.0))
            out[t.function] = (round(s + t.score, 6), round(m + t.max_score, 6))
        return out

    def _headline(self, visible_only=False):
        if visible_only:  # what a student may see before the due date: nothing counted from hidden tests
            shown = [t for t in self.tests if t.visibility == "visible"]
            later = round(sum(t.max_score for t in self.tests if t.visibility != "visible"), 6)
            view = GradeResult(self.submission, self.exercise, shown, error=self.error)
            lines = view._headline()
            if later and lines and self.exercise:
                lines[0] = (f"Exercise {self.exercise}: {view.score:g} / {view.max_score:g} points on the tests shown "
                            f"now; hidden tests worth {later:g} more points count in the score shown after the due "
                            "date")
            if later and shown and lines[-1] == "Every test passed.":
                lines[-1] = "Every test shown now passed."
            return lines
        lines = []
        if self.exercise:
            lines.append(f"Exercise {self.exercise}: {self.score:g} / {self.max_score:g} points")
        if self.error:
            lines.append(self.error)
        failed = [f"{fn} ({s:g}/{m:g})" for fn, (s, m) in self.by_function().items() if s < m - 1e-9]
        if self.tests:
            lines.append("Functions that lost points: " + ", ".join(failed) if failed else "Every test passed.")
        return lines

    def summary_text(self, visible_only=False):
        """What a student reads first: the score, what lost points, then notes about loading. ``visible_only``:
        counting the always visible tests only (Gradescope's top-level ``output``, shown before the due date)."""
        lines = self._headline(visible_only)
        for n in self.notes:
            lines.append(f"Note: {n}")
        return "\n".join(lines)

    def staff_lines(self):
        """Seed, hash and sandbox: for the course staff (end of the report, ``extra_data``)."""
        from .sandbox import describe_isolation

        lines = []
        if self.seed is not None:
            lines.append(f"scenario seed: {self.seed} (regrade with --seed {self.seed})")
        if self.submission_sha256:
            lines.append(f"submission sha256: {self.submission_sha256}")
        if self.isolation:
            lines.append("isolation of the submission's code:")
            lines.extend(f"  - {s}" for s in describe_isolation(self.isolation))
        return lines

    def extra_data(self):
        from .sandbox import protection_level

        return {"exercise": self.exercise, "seed": self.seed, "submission_sha256": self.submission_sha256,
                "protection": protection_level(self.isolation) if self.isolation else None,
                "isolation": self.isolation, "loads": self.loads}

    def to_gradescope(self):
        """Gradescope's ``results.json`` content (``extra_data`` is for the course staff only).

        The top-level ``output`` is always shown, so it counts the visible tests only; Gradescope itself hides the
        total ``score`` from students while tests whose visibility is ``after_due_date`` are not shown yet."""
        return {
            "score": self.score,
            "execution_time": int(round(self.execution_time)),
            "output": self.summary_text(visible_only=True),  # always shown: hidden tests' results are not in it
            "tests": [
                {"name": t.name, "score": round(t.score, 6), "max_score": round(t.max_score, 6), "status": t.status,
                 "output": t.output, "visibility": t.visibility}
                for t in self.tests
            ],
            "extra_data": self.extra_data(),
        }

    def text_report(self, *, verbose=False, staff=True):
        """Readable report: score and failures first, then one block per function, staff details last."""
        lines = self._headline()
        current = None
        per_fn = self.by_function()
        for t in self.tests:
            if t.function != current:
                current = t.function
                s, m = per_fn[current]
                lines.append("")
                lines.append(f"{current}  {s:g}/{m:g}")
            mark = "PASS" if t.status == "passed" else "FAIL"
            lines.append(f"  [{mark}] {t.name}  ({t.score:g}/{t.max_score:g})")
            if t.status != "passed" or verbose or "note:" in t.output.lower():
                body = t.output if t.status != "passed" else "\n".join(
                    ln for ln in t.output.splitlines() if ln.lower().startswith("note:"))
                for ln in body.splitlines():
                    lines.append(f"         {ln}")
        if self.notes:
            lines.append("")
            lines.extend(f"Note: {n}" for n in self.notes)
        lines.append("")
        lines.append(f"Total: {self.score:g} / {self.max_score:g}")
        if staff:
            extra = self.staff_lines()
            if extra:
                lines.append("")
                lines.append("For the course staff:")
                lines.extend(f"  {ln}" for ln in extra)
        return "\n".join(lines)


def safe_print(text, file=None):
    """Print ``text`` whatever the stream: its control characters escaped (:func:`autograder.wire.clean_text`),
    characters the stream's encoding lacks written as escapes (``LC_ALL=C``, ``PYTHONIOENCODING=ascii``), and a
    closed or broken stream ignored (``grade ... | head -1``). The grading is done when this runs: a log that
    cannot be printed must not turn it into a failure.
    """
    from .wire import clean_text

    stream = sys.stdout if file is None else file
    if stream is None:  # Python's stream for a descriptor that was closed when it started
        return
    text = clean_text(text) + "\n"
    try:
        try:
            stream.write(text)
        except UnicodeEncodeError:
            enc = getattr(stream, "encoding", None) or "ascii"
            stream.write(text.encode(enc, "backslashreplace").decode(enc, "replace"))
        stream.flush()
    except (OSError, ValueError):  # a closed stream, a broken pipe
        try:  # nothing more reaches it; and the interpreter's own flush at exit must not fail either
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, stream.fileno())
            os.close(devnull)
        except (OSError, ValueError, AttributeError):
            pass


def write_json_atomic(path, data):
    """Write ``data`` as JSON to ``path`` through a temporary file and ``os.replace``.

    A reader never sees a partial file: either the old content or the new one.
    """
    write_text_atomic(path, json.dumps(data, indent=2, allow_nan=False, ensure_ascii=False) + "\n")


def write_text_atomic(path, text):
    """Write ``text`` (UTF-8) to ``path`` through a temporary ``.NAME.*.tmp`` beside it and ``os.replace``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=str(path.parent))
    try:
        # backslashreplace: a lone surrogate that reached a message is written as its escape, never a failed write
        with os.fdopen(fd, "w", encoding="utf-8", errors="backslashreplace", newline="") as fh:
            fh.write(text)
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


def read_results(path):
    """A results JSON written by :func:`write_json_atomic`, or None if missing or unreadable."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) and isinstance(data.get("tests"), list) else None


def fallback_results(message, tests=None):
    """A valid results.json payload scoring 0 with an explanation."""
    return {"score": 0.0, "execution_time": 0, "output": message, "tests": tests or []}
