"""The grader's inputs and the bytes it reads back: nothing to replay, nothing that breaks the grading.

* Seeds everywhere: every test of every exercise draws its inputs (end-to-end
  scenarios included) from its seeded generator, so a submission that returns
  answers recorded offline with ``slamlib`` (a lookup table of what a grading with
  seed A passes) scores 0 on every function when graded with seed B, and code that
  is right only on the fixed special cases scores 0 too.
* Untrusted bytes: every control message and result frame the child sends is checked
  against its schema and size (nesting depth, types, finite numbers, array extents,
  decoded bytes); a bad one costs that function its points, never the grading.
* SciPy sparse results are recognised by ``scipy.sparse.issparse``, subclasses included.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent / "autograder_fixtures"))

import recording  # noqa: E402
from agtest import gradescope_json_ok, replace_function, solution_text  # noqa: E402

from autograder import loops  # noqa: E402
from autograder.engine import grade  # noqa: E402
from autograder.exercises import EXERCISES, get_exercise  # noqa: E402
from autograder.sandbox import Limits  # noqa: E402

SEED_A, SEED_B = 1234567, 7654321


@pytest.fixture(autouse=True)
def _secret(tmp_path_factory, monkeypatch):
    """Grading secrets of the test run live in a temporary folder, not in the user's config."""
    monkeypatch.setenv("AUTOGRADER_SECRET_FILE", str(tmp_path_factory.getbasetemp() / "grading_secret"))


def limits(**kw):
    base = {"call_timeout": 2.5, "import_timeout": 20.0}
    base.update(kw)
    names = {f.name for f in dataclasses.fields(Limits)}
    return Limits(**{k: v for k, v in base.items() if k in names})


def _scores(result):
    gradescope_json_ok(result.to_gradescope())
    return {fn: got for fn, (got, _) in result.by_function().items()}


# =========================================================================== finding 2: nothing to replay
@pytest.mark.parametrize("exercise", list(EXERCISES))
def test_every_test_draws_seeded_inputs(exercise):
    """The audit: under two seeds, no test passes only inputs that the other seed's grading also passed."""
    assert recording.audit(exercise, 1111, 2222) == {}


def test_scenarios_follow_the_seed():
    """End-to-end scenarios (landmarks, circuit, noise, the filters' own draws) come from the test's generator."""
    a = loops.scenario("localization", np.random.default_rng(1))
    b = loops.scenario("localization", np.random.default_rng(2))
    assert a.seed != b.seed and a.filter_seed != b.filter_seed
    assert not np.array_equal(a.run.landmarks, b.run.landmarks)
    assert not np.array_equal(a.run.x0, b.run.x0)
    assert a == loops.scenario("localization", np.random.default_rng(1))  # reproducible from the seed
    ta, tb = loops.reference("pf", a), loops.reference("pf", b)
    assert ta.shape == tb.shape and not np.allclose(ta, tb)


@pytest.mark.parametrize("exercise", list(EXERCISES))
def test_recorded_answers_score_zero_under_another_seed(exercise, tmp_path):
    """A submission that computes nothing and returns slamlib's answers recorded for seed A earns nothing with seed B.

    With seed A it earns full marks (the recording is faithful), so the zero with seed
    B comes from the inputs alone.
    """
    rec = recording.record(exercise, SEED_A)
    path = recording.lookup_submission([rec], tmp_path / "table.py")
    same = grade(path, exercise, limits=limits(), seed=SEED_A)
    ex = get_exercise(exercise)
    assert same.score == pytest.approx(sum(t.weight for t in ex.tests)), [
        (t.name, t.output) for t in same.tests if t.score < t.max_score]
    other = grade(path, exercise, limits=limits(), seed=SEED_B)
    scores = _scores(other)
    assert set(scores) == set(ex.functions)
    assert all(v == 0 for v in scores.values()), [(t.name, t.output[:300]) for t in other.tests if t.score > 0]


@pytest.mark.parametrize("exercise", list(EXERCISES))
def test_code_right_only_on_fixed_cases_scores_zero(exercise, tmp_path):
    """For each exercise, answers right only on the inputs every grading shares (the fixed special cases) earn 0.

    The fixed inputs are those passed under two seeds alike; the submission answers
    them correctly and every other call with a wrong answer of the right form.
    """
    a, c = recording.record(exercise, SEED_A), recording.record(exercise, 99991)
    fixed = set(k for ks in a.calls.values() for k in ks) & set(k for ks in c.calls.values() for k in ks)
    a.answers = {k: v for k, v in a.answers.items() if k in fixed}
    path = recording.lookup_submission([a], tmp_path / "special_cases.py")
    result = grade(path, exercise, limits=limits(), seed=SEED_B)
    scores = _scores(result)
    assert all(v == 0 for v in scores.values()), [(t.name, t.output[:300]) for t in result.tests if t.score > 0]


TRIVIAL_PF = '''
import numpy as np


def normalize_log_weights(log_w):
    # right only when all log-weights are equal
    return np.full(len(log_w), 1.0 / len(log_w))


def effective_sample_size(w):
    # right only for uniform weights and a single non-zero weight
    return float(np.count_nonzero(w))


def low_variance_resample(w, *, rng):
    return np.zeros(len(w), dtype=int)


def landmark_likelihood(particles, z, m, Q):
    return np.ones(len(particles))
'''


def test_trivially_wrong_particle_filter_scores_zero(tmp_path):
    """Finding 3: the equal-log-weights shortcut and ESS as a count of non-zero weights earn nothing."""
    path = tmp_path / "trivial.py"
    path.write_text(TRIVIAL_PF)
    for seed in (SEED_A, SEED_B):
        result = grade(path, "particle_filter", limits=limits(), seed=seed)
        scores = _scores(result)
        assert scores == dict.fromkeys(get_exercise("particle_filter").functions, 0.0), [
            (t.name, t.output[:300]) for t in result.tests if t.score > 0]
