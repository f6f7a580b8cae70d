"""The benchmarks' verdicts: a goal is "met" only when every figure it covers was measured and meets it."""
import importlib.util
import math
from pathlib import Path

import pytest

from autograder.exercises import EXERCISES

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def _script(name):
    """``benchmarks/<name>.py`` as a module (the scripts are not a package)."""
    spec = importlib.util.spec_from_file_location(f"{name}_under_test", BENCH / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def small_calls():
    return _script("bench_small_calls")


def test_small_calls_goal_is_met_only_when_every_ratio_is_measured_and_meets_it(small_calls):
    goal = small_calls.GOAL_FILTERPY
    assert small_calls.goal_verdict([1.0, goal], True).endswith("(met)")
    assert small_calls.goal_verdict([1.0, goal * 1.01], True).endswith("(MISSED)")
    # a ratio against a contestant that was not timed is NaN: never a pass, whatever its position
    assert small_calls.goal_verdict([math.nan, 1.0], True).endswith("(MISSED)")
    assert small_calls.goal_verdict([1.0, math.nan], True).endswith("(MISSED)")
    assert "met" not in small_calls.goal_verdict([math.nan] * 3, False)
    assert small_calls.goal_verdict([math.nan] * 3, False).startswith("not measured")


def test_fastslam_size_goal_compares_the_time_per_observation():
    mod = _script("bench_fastslam")
    small, big = mod.UNKNOWN_SIZES[0], mod.UNKNOWN_SIZES[-1]
    # twice the time per step for twice the observations per step: the same time per observation
    assert mod.unknown_ratio({(small, 2): (1.5, small, 4.0), (big, 2): (3.0, big, 8.0)}, 2) == pytest.approx(1.0)
    assert mod.unknown_ratio({(small, 1): (1.0, small, 5.0), (big, 1): (3.0, big, 5.0)}, 1) == pytest.approx(3.0)


@pytest.fixture(scope="module")
def bench_autograder():
    return _script("bench_autograder")


def test_autograder_benchmark_times_every_registered_exercise(bench_autograder):
    assert list(bench_autograder.NOTEBOOKS) == list(EXERCISES)
    assert set(bench_autograder.BUGS) == set(EXERCISES)


@pytest.mark.slow
@pytest.mark.parametrize("exercise", list(EXERCISES))
def test_autograder_benchmark_submissions_grade_as_their_names_say(bench_autograder, exercise, tmp_path):
    """The batch the benchmark times holds what it claims: a correct notebook (full marks), one with one bug
    (some points lost, not all), an unimplemented one (0)."""
    from autograder.engine import grade

    folder = bench_autograder.make_submissions(tmp_path / "subs", exercise, 3)
    res = {p.stem.rsplit("_", 1)[1]: grade(p, exercise) for p in sorted(folder.glob("*.ipynb"))}
    assert set(res) == {"good", "buggy", "stub"}
    assert res["good"].score == res["good"].max_score > 0, res["good"].text_report()
    assert 0 < res["buggy"].score < res["good"].score, res["buggy"].text_report()
    assert res["stub"].score == 0
