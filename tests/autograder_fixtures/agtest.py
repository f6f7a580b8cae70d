"""Helpers shared by the autograder tests: solution files, variants, score summaries."""

from __future__ import annotations

import json
import re
from pathlib import Path

FIXTURES = Path(__file__).resolve().parent
SOLUTIONS = FIXTURES / "solutions"
ROOT = FIXTURES.parents[1]
EXERCISE_NAMES = ["motion_sensor_models", "ekf_localization", "particle_filter", "ekf_slam", "fastslam", "graph_slam",
                  "bundle_adjustment"]
NOTEBOOKS = {
    "motion_sensor_models": "01_motion_sensor_models.ipynb",
    "ekf_localization": "02_ekf_localization.ipynb",
    "particle_filter": "03_particle_filter.ipynb",
    "ekf_slam": "04_ekf_slam.ipynb",
    "fastslam": "05_fastslam.ipynb",
    "graph_slam": "06_graph_slam.ipynb",
    "bundle_adjustment": "07_bundle_adjustment.ipynb",
}


def solution(exercise):
    """Path of the independent solution of ``exercise``."""
    return SOLUTIONS / f"{exercise}.py"


def solution_text(exercise):
    return solution(exercise).read_text(encoding="utf-8")


def replace_function(text, name, new_def):
    """Replace the top-level ``def name(...)`` block of ``text`` by ``new_def``."""
    m = re.search(rf"^def {name}\(.*?(?=^\S|\Z)", text, flags=re.S | re.M)
    assert m, f"no function {name}"
    return text[: m.start()] + new_def.strip("\n") + "\n\n\n" + text[m.end():]


def variant(exercise, replacements, dest):
    """Write the solution of ``exercise`` with textual ``(old, new)`` replacements applied once each."""
    text = solution_text(exercise)
    for old, new in replacements:
        assert text.count(old) == 1, f"{old!r} occurs {text.count(old)} times in the {exercise} solution"
        text = text.replace(old, new)
    Path(dest).write_text(text, encoding="utf-8")
    return Path(dest)


def by_function(result):
    """``{function: (score, max_score)}`` of a GradeResult."""
    return result.by_function()


def gradescope_json_ok(data):
    """Assert ``data`` is a well-formed Gradescope results.json payload."""
    assert isinstance(data["score"], (int, float))
    assert isinstance(data["execution_time"], int)
    assert isinstance(data["output"], str)
    json.dumps(data, allow_nan=False)
    for t in data["tests"]:
        assert set(t) >= {"name", "score", "max_score", "status", "output", "visibility"}
        assert t["status"] in ("passed", "failed")
        assert t["visibility"] in ("visible", "hidden", "after_due_date", "after_published")
        assert 0 <= t["score"] <= t["max_score"]
    assert abs(sum(t["score"] for t in data["tests"]) - data["score"]) < 1e-6
    return data
