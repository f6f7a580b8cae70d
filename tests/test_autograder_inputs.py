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
import json
import os
import struct
import subprocess
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
    # code: the recorded answers are a lookup table of up to a few MB of code, more than a grading reads (MAX_CODE)
    base = {"call_timeout": 2.5, "import_timeout": 20.0, "code": 16 << 20}
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


def test_the_guards_catch_a_fixed_input_test_in_bundle_adjustment(monkeypatch, tmp_path):
    """The guards can fail on exercise 7: so3_exp's tiny-angle test with fixed rotation vectors is flagged.

    With that test's inputs fixed (w = 0 and four fixed tiny vectors), the audit lists
    it, and both a recorded-answers submission and one right only on the fixed cases
    earn its points under another seed; the grader's seeded version leaves them nothing.
    """
    from autograder.exercises import bundle_adjustment as B

    ex = get_exercise("bundle_adjustment")
    name = "so3_exp: w = 0 and tiny angles"

    def fixed(ctx):
        B._check_exp(ctx, np.zeros(3))
        for a in (1e-12, 1e-8, 1e-6, 1e-4):
            B._check_exp(ctx, a * np.array([0.6, 0.0, 0.8]), small=True)

    assert name in [t.name for t in ex.tests]
    monkeypatch.setattr(ex, "tests", [dataclasses.replace(t, run=fixed) if t.name == name else t for t in ex.tests])
    assert recording.audit("bundle_adjustment", 1111, 2222) == {name: 5}
    a = recording.record("bundle_adjustment", SEED_A, functions=["so3_exp"])
    c = recording.record("bundle_adjustment", 99991, functions=["so3_exp"])
    shared = set(k for ks in a.calls.values() for k in ks) & set(k for ks in c.calls.values() for k in ks)
    table = recording.lookup_submission([a], tmp_path / "table.py")
    a.answers = {k: v for k, v in a.answers.items() if k in shared}
    special = recording.lookup_submission([a], tmp_path / "special_cases.py")
    for path in (table, special):
        result = grade(path, "bundle_adjustment", limits=limits(), functions=["so3_exp"], seed=SEED_B)
        assert [t.name for t in result.tests if t.score > 0] == [name], (path.name, [
            (t.name, t.output[:200]) for t in result.tests])


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


# =========================================================================== findings 6 and 8: untrusted bytes
from autograder import wire  # noqa: E402
from autograder.wire import ProtocolError  # noqa: E402

DEEP = b"[" * 5000 + b"]" * 5000


def _frame(header_bytes, payload=b""):
    return struct.pack("<4sII", wire.MAGIC, len(header_bytes), len(payload)) + header_bytes + payload


def test_deeply_nested_messages_are_refused_not_a_recursion_error():
    with pytest.raises(ProtocolError):
        wire.parse_frame(_frame(b'{"status": "ok", "result": ' + DEEP + b"}"))
    with pytest.raises(ProtocolError):
        wire.parse_result_frame(_frame(b'{"a": ' + DEEP + b"}"))
    with pytest.raises(ProtocolError):
        wire.control_message(b'{"ev": "ready", "notes": ' + DEEP + b"}")
    # brackets inside strings are text, not nesting
    assert wire.control_message(b'{"ev": "ready", "notes": ["' + b"[" * 5000 + b'"]}')["notes"][0] == "[" * 300


@pytest.mark.parametrize("message, why", [
    (b'{"ev": "ready", "notes": 7}', "notes"),
    (b'{"ev": "ready", "notes": [1, 2]}', "notes"),
    (b'{"ev": "ready", "isolation": {"uid": NaN}}', "non-finite"),
    (b'{"ev": "ready", "isolation": {"uid": 1e999}}', "non-finite"),
    (b'{"ev": "ready", "isolation": 3}', "isolation"),
    (b'{"ev": "ready", "functions": {"f": {"defined": "yes", "callable": true}}}', "defined"),
    (b'{"ev": "stmt", "unit": "0", "stmt": 1}', "stmt"),
    (b'{"ev": "stmt", "unit": -1, "stmt": 1}', "stmt"),
    (b'\xff\xfe', "UTF-8"),
    (b"[1, 2]", "object"),
])
def test_control_messages_are_checked_against_their_schema(message, why):
    with pytest.raises(ProtocolError, match=why):
        wire.control_message(message)


def test_a_valid_ready_message_passes_with_its_fields_cut_to_size():
    msg = wire.control_message(b'{"ev": "ready", "notes": ["' + b"x" * 1000 + b'"], "functions": {"f": {"defined": '
                               b'true, "callable": true, "module": "m", "filename": null}}, "isolation": {"uid": 5, '
                               b'"rlimits": {"RLIMIT_AS": 1}, "fs_root": {"bound": ["/usr"]}}, "extra": 1}')
    assert msg["notes"] == ["x" * 300] and msg["functions"]["f"]["defined"] is True
    assert msg["isolation"]["rlimits"] == {"RLIMIT_AS": 1} and "extra" not in msg
    assert wire.control_message(b'{"ev": "future", "x": [1]}') == {"ev": "future"}


@pytest.mark.parametrize("reply, why", [
    ({"status": "ok", "mutated": 5, "result": {"t": "item", "value": {"t": "bad"}}}, "mutated"),
    ({"status": "error", "error": 5}, "error"),
    ({"status": "ok", "elapsed": -1.0, "result": {"t": "item", "value": {"t": "bad"}}}, "elapsed"),
    ({"status": "ok", "elapsed": "1", "result": {"t": "item", "value": {"t": "bad"}}}, "elapsed"),
    ({"status": "done"}, "status"),
    ({"status": "ok", "result": {"t": "item", "value": {"t": "bad", "why": 3}}}, "why"),
])
def test_replies_are_checked_against_their_schema(reply, why):
    with pytest.raises(ProtocolError, match=why):
        wire.read_reply(reply, b"", np)


def test_nan_in_a_result_header_is_refused():
    with pytest.raises(ProtocolError, match="non-finite"):
        wire.parse_result_frame(_frame(b'{"status": "ok", "elapsed": NaN}'))


def _shared_extent_result(n_items, nbytes):
    d = {"t": "arr", "dtype": "<f8", "shape": [nbytes // 8], "off": 0, "len": nbytes}
    return {"t": "seq", "kind": "tuple", "n": n_items, "items": [dict(d) for _ in range(n_items)], "whole": dict(d)}


def test_array_extents_may_not_repeat_or_overlap():
    """Finding 8: 16 items pointing at one payload were each decoded (18 copies of it); now refused unread."""
    payload = bytes(1 << 20)
    with pytest.raises(ProtocolError, match="overlap or repeat"):
        wire.decode_result(_shared_extent_result(16, len(payload)), payload, np)
    a = {"t": "arr", "dtype": "<f8", "shape": [4], "off": 0, "len": 32}
    b = {"t": "arr", "dtype": "<f8", "shape": [4], "off": 24, "len": 32}
    with pytest.raises(ProtocolError, match="overlap or repeat"):
        wire.decode_result({"t": "seq", "kind": "tuple", "n": 1, "items": [a], "whole": b}, bytes(64), np)
    # what the child really sends (disjoint extents) decodes
    desc, data = wire.encode_result((np.arange(3.0), np.eye(3), 2), np)
    got = wire.decode_result(desc, data, np)
    np.testing.assert_array_equal(got.items[1].array, np.eye(3))


def test_decoded_bytes_are_capped_and_decoded_before_the_deadline():
    big = wire.MAX_RESULT_BYTES + 8
    with pytest.raises(ProtocolError, match="too large"):  # refused from the frame's fixed header alone
        wire.parse_result_frame(struct.pack("<4sII", wire.MAGIC, 2, big) + b"{}")
    desc, data = wire.encode_result(np.arange(10.0), np)
    with pytest.raises(ProtocolError, match="deadline"):
        wire.decode_result(desc, data, np, deadline=0.0)


# =========================================================================== finding 9: SciPy sparse subclasses
def test_sparse_results_are_recognised_by_issparse_subclasses_included():
    import scipy.sparse as sp

    class H(sp.csr_matrix):
        pass

    dense = np.array([[1.0, 0.0], [0.0, 2.0]])
    for obj in (H(dense), sp.csr_matrix(dense), sp.coo_array(dense), (H(dense), np.ones(2))):
        desc, data = wire.encode_result(obj, np)
        got = wire.decode_result(desc, data, np)
        value = got.items[0] if got.seq_kind else got.value
        assert value.array is not None, value.problem
        np.testing.assert_array_equal(value.array, dense)


# =========================================================================== forged messages, graded for real
# A submission reaches the control socket (while loading) or its worker's result pipe (while called) through the
# frames of the code that runs it, and writes what it likes there.
FIND_CTL = """
import os, sys
_f = sys._getframe()
while _f is not None and "ctl" not in _f.f_locals:
    _f = _f.f_back
if _f is not None:
    os.write(_f.f_locals["ctl"].fileno(), {message!r})
"""

FORGE_RESULT = """
def normalize_log_weights(log_w):
    import os, struct, sys
    f = sys._getframe()
    while f is not None and "res_fd" not in f.f_locals:
        f = f.f_back
    header, payload = {header!r}, {payload}
    os.write(f.f_locals["res_fd"], struct.pack("<4sII", b"AGW1", len(header), len(payload)) + header)
    view = memoryview(payload)
    while view:
        view = view[os.write(f.f_locals["res_fd"], view[: 1 << 20]):]
    import time
    time.sleep(30)
"""


@pytest.mark.parametrize("message", [
    b'{"ev": "ready", "notes": ' + DEEP + b"}",
    b'{"ev": "ready", "notes": 7, "functions": {}, "isolation": {}}',
    # (a NaN in "isolation" no longer reaches the grader: the sandbox puts its own report in every ready message)
    b'{"ev": "ready", "notes": [], "functions": {"normalize_log_weights": {"defined": NaN}}, "isolation": {}}',
], ids=["deep", "notes-int", "nan-functions"])
def test_forged_control_messages_cost_points_not_the_grading(message, tmp_path):
    """Finding 6: exit 0, results.json written, every test present at its max_score (the forger's tests at 0)."""
    path = tmp_path / "forger.py"
    path.write_text(FIND_CTL.format(message=message) + "\n" + solution_text("particle_filter"))
    out = tmp_path / "results.json"
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    proc = subprocess.run([sys.executable, "-m", "autograder", "grade", str(path), "--exercise", "particle_filter",
                           "--results", str(out), "--seed", "5"], capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0, proc.stderr[-2000:]
    data = json.loads(out.read_text())
    gradescope_json_ok(data)
    ex = get_exercise("particle_filter")
    assert [t["name"] for t in data["tests"]] == [t.name for t in ex.tests]
    assert [t["max_score"] for t in data["tests"]] == [t.weight for t in ex.tests]
    assert data["score"] == 0
    assert "malformed message" in data["tests"][0]["output"]


@pytest.mark.parametrize("header, payload", [
    (b'{"status": "ok", "result": ' + DEEP + b"}", b""),
    (b'{"status": "ok", "mutated": 5, "result": {"t": "item", "value": {"t": "bad"}}}', b""),
    (b'{"status": "ok", "elapsed": NaN, "result": {"t": "item", "value": {"t": "bad"}}}', b""),
    (json.dumps(_shared_extent_result(16, 4 << 20)).encode(), "bytes(4 << 20)"),
], ids=["deep", "mutated-int", "nan-elapsed", "repeated-extents"])
def test_forged_result_frames_cost_that_function_its_points(header, payload, tmp_path):
    """Findings 6 and 8: a forged frame scores 0 for its function, with a note; the other function keeps its points."""
    text = replace_function(solution_text("particle_filter"), "normalize_log_weights",
                            FORGE_RESULT.format(header=header, payload=payload or 'b""'))
    path = tmp_path / "forger.py"
    path.write_text("import numpy as np\n" + text)
    result = grade(path, "particle_filter", limits=limits(), functions=["normalize_log_weights",
                                                                        "effective_sample_size"], seed=5)
    scores = _scores(result)
    assert scores == {"normalize_log_weights": 0.0, "effective_sample_size": 15.0}
    first = next(t for t in result.tests if t.function == "normalize_log_weights")
    assert "could not read the function's result" in first.output, first.output


def test_a_sparse_subclass_earns_full_marks(tmp_path):
    """Finding 9: build_linear_system returning a subclass of csr_matrix is judged densely, like csr_matrix."""
    text = solution_text("graph_slam").replace("    return H, b\n", "    return _H(H), b\n", 1)
    assert "_H(H)" in text
    path = tmp_path / "sparse_subclass.py"
    path.write_text(text + "\n\nfrom scipy.sparse import csr_matrix\n\n\nclass _H(csr_matrix):\n    pass\n")
    result = grade(path, "graph_slam", limits=limits(), functions=["build_linear_system"], seed=5)
    tests = [t for t in result.tests if t.function == "build_linear_system"]
    assert tests and all(t.score == t.max_score for t in tests), [t.output for t in tests if t.score < t.max_score]
