"""The exercises and their test cases, one module each.

Every module defines ``EX``, an :class:`~autograder.spec.Exercise` listing the
contract functions (``../shared/EXERCISES.md``) with their signatures, and its
test cases. Expected values are always computed by ``slamlib`` at grading time.
"""

from __future__ import annotations

import importlib

__all__ = ["EXERCISES", "get_exercise", "all_exercises"]

#: Exercise name -> module, in course order.
EXERCISES = {
    "motion_sensor_models": "motion_sensor_models",
    "ekf_localization": "ekf_localization",
    "particle_filter": "particle_filter",
    "ekf_slam": "ekf_slam",
    "fastslam": "fastslam",
    "graph_slam": "graph_slam",
    "bundle_adjustment": "bundle_adjustment",
}


def get_exercise(name):
    """The :class:`~autograder.spec.Exercise` called ``name`` (KeyError if unknown)."""
    if name not in EXERCISES:
        raise KeyError(name)
    return importlib.import_module(f"{__name__}.{EXERCISES[name]}").EX


def all_exercises():
    return [get_exercise(n) for n in EXERCISES]
