"""Parts of the autograder tested in isolation: wire format, output rules, static checks, statistics, loops."""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path

import numpy as np
import pytest

import slamlib as sl
from autograder import loops, wire
from autograder.wire import ProtocolError, decode_result, encode_args, encode_result, pack_frame, parse_frame
from autograder.calibrate import calibrate, summarize
from autograder.context import Ctx, Fail, Out
from autograder.results import write_json_atomic
from autograder.sandbox import Limits, describe_isolation, isolation_report
from autograder.stats import P_THRESHOLD, wrapped_normal_cdf
from autograder.submission import forbidden_usage


# --------------------------------------------------------------------------- wire format
def test_the_childs_side_imports_only_the_standard_library_numpy_and_the_wire_format():
    """``_runner.py`` runs in the sandbox, where neither slamlib nor the rest of the autograder exists."""
    import ast
    import sys

    folder = Path(wire.__file__).parent
    for name in ("_runner.py", "wire.py"):
        tree = ast.parse((folder / name).read_text(encoding="utf-8"))
        absolute = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
        absolute |= {n.module.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and not n.level}
        relative = {a.name for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.level for a in n.names}
        assert absolute <= set(sys.stdlib_module_names) | {"numpy"}, (name, absolute)
        assert relative <= ({"wire"} if name == "_runner.py" else set()), (name, relative)
    assert "wire.py" in (folder / "_runner.py").read_text(encoding="utf-8")  # loaded by its path in the child


def _roundtrip(obj):
    desc, payload = encode_result(obj, np)
    header, body, used = parse_frame(pack_frame({"result": desc}, payload))
    return decode_result(header["result"], body, np)


def test_frames_roundtrip_and_reject_garbage():
    frame = pack_frame({"a": 1}, b"xyz")
    assert parse_frame(frame) == ({"a": 1}, b"xyz", len(frame))
    assert parse_frame(frame[:-1]) is None
    with pytest.raises(ProtocolError):
        parse_frame(b"EVIL" + frame[4:])
    with pytest.raises(ProtocolError):
        parse_frame(struct.pack("<4sII", b"AGW1", 1 << 30, 0))
    with pytest.raises(ProtocolError):
        parse_frame(struct.pack("<4sII", b"AGW1", 3, 0) + b"[1]")


@pytest.mark.parametrize("desc", [
    {"t": "item", "value": {"t": "arr", "dtype": "|O8", "shape": [1], "off": 0, "len": 8}},
    {"t": "item", "value": {"t": "arr", "dtype": "<f8", "shape": [2], "off": 0, "len": 8}},
    {"t": "item", "value": {"t": "arr", "dtype": "<f8", "shape": [1], "off": 4, "len": 8}},
    {"t": "item", "value": {"t": "arr", "dtype": "<f8", "shape": [-1], "off": 0, "len": 8}},
    {"t": "item", "value": {"t": "arr", "dtype": "V8", "shape": [1], "off": 0, "len": 8}},
    {"t": "item", "value": {"t": "pickle"}},
    {"t": "seq", "kind": "tuple", "n": 1, "items": "x", "whole": None},
    {"t": "nope"},
    ["not", "a", "dict"],
])
def test_decoder_rejects_malformed_descriptors(desc):
    with pytest.raises(ProtocolError):
        decode_result(desc, b"\0" * 8, np)


def test_results_become_plain_arrays():
    class Sub(np.ndarray):
        pass

    r = _roundtrip(np.arange(3.0).view(Sub))
    assert type(r.value.array) is np.ndarray and r.value.subclass == "Sub"
    r = _roundtrip((np.zeros(2), 3, [1.0, 2.0]))
    assert r.seq_kind == "tuple" and r.n == 3 and r.items[1].int_like and r.items[2].array.shape == (2,)
    r = _roundtrip([1.0, 2.0])
    assert r.seq_kind == "list" and r.whole.array.shape == (2,)
    assert _roundtrip(object()).value.problem.startswith("numpy.asarray() of the result has dtype object")
    big_endian = np.arange(3, dtype=">f8")
    assert np.array_equal(_roundtrip(big_endian).value.array, np.arange(3.0))


def test_args_encoding():
    header, payload = encode_args((np.eye(2), 3, 0.5, None, True), {"rng": wire.RngSeed(7)}, np)
    args, kwargs = wire.decode_args(header, payload, np)
    assert np.array_equal(args[0], np.eye(2)) and args[1:] == [3, 0.5, None, True]
    assert kwargs["rng"].random() == np.random.default_rng(7).random()


# --------------------------------------------------------------------------- output rules
class _Fake:
    def __init__(self, value):
        self.value = value

    def call(self, fn, args, kwargs, **kw):
        from autograder.sandbox import CallOutcome

        return CallOutcome("ok", returned=_roundtrip(self.value))


def _expect(value, *outs):
    ctx = Ctx(_Fake(value), "f", ["x"], 1.0, np.random.default_rng(0), 0)
    return ctx.expect(ctx.call(np.zeros(1)), *outs)


def test_output_rules():
    A, B = Out("a", (2,)), Out("b", (2, 2))
    a, b = _expect((np.ones(2), np.eye(2)), A, B)
    assert a.dtype == np.float64 and b.shape == (2, 2)
    _expect([np.ones(2), np.eye(2)], A, B)  # a list is accepted
    _expect([1.0, 2.0], A)  # a list for one array result: numpy.asarray(result)
    assert _expect(np.int64(3), Out("j", (), "index")) == 3
    assert _expect(np.float32(2.5), Out("e", ())) == 2.5
    for bad, outs, msg in [
        (np.ones(2), (A, B), "must return a tuple"),
        ((np.ones(2),), (A, B), "tuple of 2 items"),
        ((np.ones(2), np.eye(2), 1), (A, B), "tuple of 2 items"),
        (np.ones((1, 2)), (A,), "must have shape (2,)"),
        (np.ones(1), (A,), "must have shape (2,)"),
        (np.array([1, 2]), (A,), "real floating dtype"),
        (np.array([True, False]), (A,), "real floating dtype"),
        (np.array([1j, 2]), (A,), "complex"),
        (np.array([np.inf, 0.0]), (A,), "NaN or inf"),
        (3.0, (Out("j", (), "index"),), "Python int or NumPy integer"),
        (True, (Out("j", (), "index"),), "Python int or NumPy integer"),
        (np.array(3), (Out("j", (), "index"),), "Python int or NumPy integer"),
        ((3,), (Out("j", (), "index"),), "single integer"),
        (np.ones(3, dtype=np.float64), (Out("i", (3,), "int"),), "integer dtype"),
    ]:
        with pytest.raises(Fail, match=msg.replace("(", r"\(").replace(")", r"\)")):
            _expect(bad, *outs)


def test_comparisons_never_broadcast_and_wrap_angles():
    ctx = Ctx(_Fake(0.0), "f", [], 1.0, np.random.default_rng(0), 0)
    with pytest.raises(Fail, match="shape"):
        ctx.close("v", np.ones(3), np.ones((1, 3)))
    ctx.close("angle", np.array([np.pi - 1e-12]), np.array([-np.pi]), atol=1e-9, angles=True)
    with pytest.raises(Fail):
        ctx.close("angle", np.array([np.pi - 1e-12]), np.array([-np.pi]), atol=1e-9)
    with pytest.raises(Fail, match="wrapped"):
        ctx.wrapped("h", np.array([np.pi]))
    with pytest.raises(Fail, match="symmetric"):
        ctx.symmetric("S", np.array([[1.0, 0.1], [0.0, 1.0]]))


# --------------------------------------------------------------------------- static checks
def test_forbidden_usage_follows_helpers_and_aliases():
    src = """
import numpy as np
import slamlib as sl
from slamlib.particle import normalize_log_weights as nlw
try:
    import autograder.selfcheck as ag
except ImportError:
    pass
def helper(x):
    return sl.wrap_angle(x)
alias = nlw
def a(x): return helper(x)
def b(x): return alias(x)
def c(x):
    import importlib
    return importlib.import_module("slamlib").f(x)
def d(x, sl=None): return sl
def e(x): return np.sin(x)
def f(x): return ag.run_public_tests
def g(x):
    from autograder import engine
"""
    found = forbidden_usage([{"source": src, "filename": "s.py", "label": "s.py"}], list("abcdefg") + ["nlw"])
    assert set(found) == {"a", "b", "c", "f", "g", "nlw"}
    assert "calls `helper`, which uses `sl` (import slamlib" in found["a"]


# --------------------------------------------------------------------------- statistics
def test_wrapped_normal_cdf():
    rng = np.random.default_rng(1)
    for sigma in (0.1, 1.0, 3.0):
        e = np.mod(rng.normal(0, sigma, 200000) + np.pi, 2 * np.pi) - np.pi
        q = np.linspace(-np.pi, np.pi, 9)
        emp = np.array([np.mean(e <= v) for v in q])
        np.testing.assert_allclose(wrapped_normal_cdf(q, sigma), emp, atol=5e-3)
    assert wrapped_normal_cdf(np.array([-np.pi]), 1.0)[0] == pytest.approx(0.0, abs=1e-12)
    assert wrapped_normal_cdf(np.array([np.pi]), 1.0)[0] == pytest.approx(1.0, abs=1e-12)


def test_correlation_bound_of_the_odometry_noises():
    """The bound on each pair's correlation is the exact MOMENT_P quantile (t law), and it catches shared draws."""
    from scipy import stats as sstats

    from autograder.stats import (MOMENT_P, correlation_bound, odometry_correlations,
                                  odometry_independence_problem)

    n = 20000
    r = correlation_bound(n)
    t = r * np.sqrt((n - 2) / (1 - r * r))
    assert 2 * sstats.t.sf(t, n - 2) == pytest.approx(MOMENT_P, rel=1e-6)
    assert r == pytest.approx(7.13 / np.sqrt(n), rel=0.01)
    u, alpha = np.array([2.5, 0.5, 3.0]), np.array([0.2, 0.1, 0.004, 0.0002])  # rotations wrap
    x = np.tile([1.0, -2.0, 3.0], (n, 1))
    good = sl.sample_motion_model_odometry(x, u, alpha, rng=np.random.default_rng(5))
    assert odometry_independence_problem(x, good, u, alpha) is None
    assert [(a, b) for a, b, *_ in odometry_correlations(x, good, u, alpha)] == [
        ("rot1", "trans"), ("rot1", "rot2"), ("trans", "rot2")]
    # rot2's noise a multiple of rot1's: right marginals, correlated (below 1 once both wrap)
    e = np.random.default_rng(6).standard_normal((n, 2))
    sd = np.sqrt([0.2 * 2.5**2 + 0.1 * 0.5**2, 0.004 * 0.5**2 + 0.0002 * (2.5**2 + 3.0**2),
                  0.2 * 3.0**2 + 0.1 * 0.5**2])
    r1, tr, r2 = 2.5 - sd[0] * e[:, 0], 0.5 - sd[1] * e[:, 1], 3.0 - sd[2] * e[:, 0]
    bad = np.column_stack([x[:, 0] + tr * np.cos(x[:, 2] + r1), x[:, 1] + tr * np.sin(x[:, 2] + r1),
                           np.mod(x[:, 2] + r1 + r2 + np.pi, 2 * np.pi) - np.pi])
    msg = odometry_independence_problem(x, bad, u, alpha)
    assert msg.startswith("the rot1 and rot2 noises recovered from your samples are correlated"), msg
    assert odometry_correlations(x, bad, u, alpha)[1][2] > 0.5
    # a zero-variance noise has no pair
    assert len(odometry_correlations(x, x, np.array([0.0, 0.0, 0.0]), np.zeros(4))) == 0


def test_the_repeated_noise_checks_false_alarm_is_bounded_by_its_formula():
    """``repeated_noise_false_alarm`` is the expected number of matching pairs (same or opposite scores) among a
    correct sampler's poses, counted over all pairs here; the check itself (one sort, neighbours only) raises no
    more alarms than that on the reference sampler, at a tolerance where both are measurable."""
    from scipy import stats as sstats

    from autograder.stats import odometry_repeated_noise_problem, repeated_noise_false_alarm

    M, tol, trials = 200, 0.02, 600
    expected = repeated_noise_false_alarm(M, tol)
    rng = np.random.default_rng(11)
    iu = np.triu_indices(M, 1)
    pairs = 0
    for _ in range(trials):
        z = rng.standard_normal((M, 3))
        same = np.abs(z[:, None, :] - z[None, :, :]).max(-1)[iu] <= tol
        opposite = np.abs(z[:, None, :] + z[None, :, :]).max(-1)[iu] <= tol
        pairs += int(same.sum() + opposite.sum())
    # a Poisson count: 34 expected, within 1e-6 two-sided
    lo, hi = sstats.poisson.ppf([5e-7, 1 - 5e-7], expected * trials)
    assert lo <= pairs <= hi, (pairs, expected * trials)
    u, alpha = np.array([-0.6, 0.8, 0.9]), np.array([0.03, 0.02, 0.02, 0.005])
    alarms = 0
    for _ in range(trials):
        x = np.column_stack([rng.uniform(-5, 5, M), rng.uniform(-5, 5, M), rng.uniform(-np.pi, np.pi, M)])
        out = sl.sample_motion_model_odometry(x, u, alpha, rng=rng)
        alarms += odometry_repeated_noise_problem(x, out, u, alpha, tol=tol) is not None
    assert alarms <= sstats.binom.ppf(1 - 1e-6, trials, min(expected, 1.0)), alarms


@pytest.mark.slow
def test_statistical_checks_calibrated_on_the_reference():
    """Reduced calibration (the full one: python -m autograder calibrate --seeds 2000)."""
    res = calibrate(40, first_seed=1000)
    for name, p in res.items():
        s = summarize(p)
        assert s["below_threshold"] == 0, name
        assert all(r["ok"] for r in s["levels"]), (name, s)
        assert p.min() > P_THRESHOLD
    # the KS p-values are uniform under the null; the chi-square one is conservative
    ks = np.concatenate([res[n] for n in res if "KS" in n])
    assert summarize(ks)["ks_uniform_p"] > 1e-3


# --------------------------------------------------------------------------- end-to-end loops: slamlib's own drivers
def test_loops_reproduce_slamlib_runners():
    """The reference loops are the drivers' own runs (slamlib's functions plugged in change nothing)."""
    sc = loops.scenario("localization", np.random.default_rng(3))
    run = sc.run
    traj = loops.reference("ekf_known", sc)
    np.testing.assert_allclose(traj, sl.ekf_localization_run(run, known=True).mu, atol=1e-9)
    traj, ids = loops.reference("ekf_unknown", sc)
    ref = sl.ekf_localization_run(run, known=False, gate=loops.GATE)
    np.testing.assert_allclose(traj, ref.mu, atol=1e-9)
    assert list(ids) == [int(i) for step in ref.ids for i in step]
    ssc = loops.scenario("slam", np.random.default_rng(4))
    srun = ssc.run
    traj, lm = loops.reference("ekf_slam", ssc)
    ref = sl.run_ekf_slam(srun, known=True, fast=False, prior_var=1e4)
    np.testing.assert_allclose(traj, ref.x, atol=1e-9)
    np.testing.assert_allclose(lm[ref.landmark_ids], ref.landmarks, atol=1e-9)
    assert np.isnan(lm).sum() == 2 * (srun.landmarks.shape[0] - ref.landmark_ids.size)
    fs = sl.run_fastslam(srun, n_particles=60, rng=np.random.default_rng(ssc.filter_seed), known=True)
    np.testing.assert_allclose(loops.reference("fastslam", ssc), fs.x_est, atol=1e-9)
    assert loops.ate(loops.reference("pf", sc), run) < 0.5
    assert loops.ate(loops.reference("fastslam", ssc), srun) < 0.5


class _Calls:
    """A student's function for a loop: slamlib's, recording the step of every call."""

    def __init__(self, fn):
        self.fn, self.steps = fn, []

    def __call__(self, t, *args, **kwargs):
        self.steps.append(t)
        return self.fn(*args, **kwargs)


def test_loops_plug_the_student_function_into_the_driver():
    """Every loop calls the student's function at every step that needs it and, given slamlib's, matches the reference."""
    sc, ssc = loops.scenario("localization", np.random.default_rng(5)), loops.scenario("slam", np.random.default_rng(6))
    run, srun = sc.run, ssc.run
    predict = _Calls(sl.ekf_predict)
    np.testing.assert_array_equal(loops.ekf_localization_loop(sc, predict=predict)[0], loops.reference("ekf_known", sc))
    assert predict.steps == list(range(run.n_steps))
    associate = _Calls(sl.associate_ml)
    traj, ids = loops.ekf_localization_loop(sc, known=False, associate=associate)
    assert tuple(ids) == loops.reference("ekf_unknown", sc)[1] and len(associate.steps) == len(ids)
    assert associate.steps == [t for t in range(run.n_steps) for _ in run.z[t]]
    lik = _Calls(sl.landmark_likelihood)
    np.testing.assert_array_equal(loops.particle_filter_loop(sc, likelihood=lik), loops.reference("pf", sc))
    assert lik.steps == [t for t in range(run.n_steps) for _ in run.z[t]]
    draws = _Calls(lambda w, seed: sl.low_variance_resample(w, rng=np.random.default_rng(seed)))
    np.testing.assert_array_equal(loops.particle_filter_loop(sc, resample=draws), loops.reference("pf", sc))
    assert 0 < len(draws.steps) < run.n_steps
    init = _Calls(sl.ekf_slam_init_landmark)
    traj, lm = loops.ekf_slam_loop(ssc, init=init)
    np.testing.assert_array_equal(traj, loops.reference("ekf_slam", ssc)[0])
    assert len(init.steps) == int(np.sum(~np.isnan(lm[:, 0])))
    update = _Calls(sl.fastslam_update_landmark)
    np.testing.assert_array_equal(loops.fastslam_loop(ssc, update=update), loops.reference("fastslam", ssc))
    assert update.steps == sorted(update.steps) and len(update.steps) > srun.n_steps


def test_loops_report_a_value_the_reference_rejects_at_its_step():
    run = loops.scenario("localization", np.random.default_rng(7))

    def predict(t, mu, Sigma, u, dt, M):
        mu_bar, S = sl.ekf_predict(mu, Sigma, u, dt, M)
        if t == 7:
            S = S.copy()
            S[0, 1] += 1.0  # not symmetric: the reference ekf_update refuses it
        return mu_bar, S

    with pytest.raises(loops.LoopError, match=r"^step 7: the reference EKF update could not use your result"):
        loops.ekf_localization_loop(run, predict=predict)

    def update(t, mu, Sigma, z, m, Q):
        return sl.ekf_update(mu, Sigma, z, m, Q)[0], np.eye(2)  # a covariance of the wrong shape

    with pytest.raises(loops.LoopError, match=r"^step 0: the filter could not use your result .*ekf_update"):
        loops.ekf_localization_loop(run, update=update)

    def likelihood(t, particles, z, m, Q):
        return np.zeros(particles.shape[0]) if t == 3 else sl.landmark_likelihood(particles, z, m, Q)

    with pytest.raises(loops.LoopError, match=r"^step 3: the filter could not use your result .*-inf"):
        loops.particle_filter_loop(run, likelihood=likelihood)


# --------------------------------------------------------------------------- isolation and results files
def test_isolation_report_lists_every_mechanism():
    iso = isolation_report(Limits())
    text = "\n".join(describe_isolation(iso))
    assert "rlimits: CPU=" in text and "NPROC=0" in text and "AS=2147483648" in text
    assert "audit hook (second line): imports of slamlib" in text
    if iso.get("root"):
        assert iso.get("uid", 0) != 0 and "dropped from root" in text


def test_results_json_written_atomically(tmp_path):
    path = tmp_path / "r" / "results.json"
    write_json_atomic(path, {"score": 1.0, "tests": []})
    assert json.loads(path.read_text())["score"] == 1.0
    with pytest.raises(ValueError):
        write_json_atomic(path, {"score": float("nan")})
    assert json.loads(path.read_text())["score"] == 1.0  # the old file is intact
    assert [p.name for p in path.parent.iterdir()] == ["results.json"]


# --------------------------------------------------------------------------- seeds, inputs, bundle requirements, protection
def test_seeds_follow_secret_exercise_and_content(tmp_path):
    from autograder.seeds import content_hash, derive_seed, load_secret

    path = tmp_path / "cfg" / "secret"
    secret = load_secret(path)
    assert path.stat().st_mode & 0o777 == 0o600 and load_secret(path) == secret
    h1, h2 = content_hash(b"def f(): pass\n"), content_hash(b"def f(): pass \n")
    s = derive_seed(secret, "particle_filter", h1)
    assert s == derive_seed(secret, "particle_filter", h1) and 0 <= s < 2**63
    assert len({s, derive_seed(secret, "particle_filter", h2), derive_seed(secret, "fastslam", h1),
                derive_seed(b"another secret of enough length", "particle_filter", h1)}) == 4


def test_graders_that_create_the_secret_at_once_agree_and_never_read_it_empty(tmp_path, monkeypatch):
    """Two graders creating the default secret at once: the loser read the file the winner had made but not yet
    written, and graded with the empty key (every seed computable by anyone). The secret is now linked into place
    whole, and a secret read from the file is checked for its length on every path."""
    import subprocess
    import sys

    from autograder import seeds

    # a grader whose file appears between our write and our link, still empty (made by an older grader)
    path = tmp_path / "race" / "secret"
    real_link = os.link

    def late(src, dst, *a, **k):
        Path(dst).touch()
        return real_link(src, dst, *a, **k)

    monkeypatch.setattr(os, "link", late)
    with pytest.raises(ValueError, match="too short"):
        seeds.load_secret(path)
    monkeypatch.setattr(os, "link", real_link)
    # ... and written: its secret is ours
    path = tmp_path / "race2" / "secret"
    monkeypatch.setattr(os, "link", lambda src, dst, *a, **k: (Path(dst).write_text("w" * 64 + "\n"),
                                                                 real_link(src, dst, *a, **k)))
    assert seeds.load_secret(path) == b"w" * 64
    monkeypatch.setattr(os, "link", real_link)
    assert [p.name for p in path.parent.iterdir()] == ["secret"]  # no file of ours left behind
    # real graders started at once: one secret, never empty
    code = "import sys; from autograder.seeds import load_secret; print(load_secret(sys.argv[1]).decode())"
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    for k in range(5):
        target = tmp_path / f"at_once{k}" / "secret"
        procs = [subprocess.Popen([sys.executable, "-c", code, str(target)], stdout=subprocess.PIPE, text=True,
                                  env=env) for _ in range(6)]
        outs = {proc.communicate(timeout=60)[0].strip() for proc in procs}
        assert len(outs) == 1 and len(outs.pop()) == 64, outs
        assert target.read_text().strip() and len(list(target.parent.iterdir())) == 1


def test_a_secret_that_cannot_be_kept_is_said_so(tmp_path, monkeypatch):
    """A dangling link (or a read-only home) at the default secret's path made the grader use a secret of its own
    process without a word: the seeds changed on every run (round 10, O2). It warns, once, naming the path."""
    from autograder import seeds

    config = tmp_path / "cfg"
    (config / "slam-autograder").mkdir(parents=True)
    (config / "slam-autograder" / "secret").symlink_to(tmp_path / "nowhere")
    monkeypatch.setenv("XDG_CONFIG_HOME", str(config))
    monkeypatch.delenv(seeds.SECRET_ENV, raising=False)
    monkeypatch.setattr(seeds, "_EPHEMERAL", [])
    with pytest.warns(RuntimeWarning, match="cannot be kept at .*slam-autograder/secret"):
        first = seeds.load_secret()
    assert len(first) == 64 and seeds.load_secret() == first  # one for the process


def test_python_sources_are_read_as_python_reads_them():
    from autograder.submission import SubmissionError, decode_python_source

    text = "x = 'caf\u00e9'\r\ny = 1\r\n"
    assert decode_python_source(b"\xef\xbb\xbf" + text.encode()) == "x = 'caf\u00e9'\ny = 1\n"
    latin = ("# -*- coding: latin-1 -*-\n" + text).encode("latin-1")
    assert "caf\u00e9" in decode_python_source(latin)
    with pytest.raises(SubmissionError, match="not a readable Python text file"):
        decode_python_source(text.encode("latin-1"))


def test_bundle_requirements_are_pinned_and_minimal():
    from autograder.bundle import pinned_requirements

    reqs = pinned_requirements()
    names = {r.split("==")[0].lower() for r in reqs}
    assert all("==" in r for r in reqs)
    assert {"numpy", "scipy", "nbformat"} <= names
    assert not names & {"matplotlib", "ipywidgets", "tqdm", "jupyter-book", "pytest"}


def test_protection_level_says_which_line_held():
    from autograder.sandbox import protection_level

    assert protection_level({"fs": True, "root": True, "uid": 123}) == "namespaces"
    assert protection_level({"fs": False, "root": True, "uid": 123, "reference_readable": []}) == "separate-user"
    iso = {"fs": False, "root": False, "uid": 1000, "reference_readable": ["/x/slamlib"], "rlimits": {}}
    assert protection_level(iso) == "audit-hook-only"
    assert "audit hook ONLY" in describe_isolation(iso)[0] and "/x/slamlib" in describe_isolation(iso)[0]


def test_without_a_mount_namespace_the_report_says_what_protects_the_reference():
    from autograder.sandbox import BLOCKED_PATHS, protection_level

    iso = isolation_report(Limits(filesystem=False))
    assert iso.get("fs") is False
    level = protection_level(iso)
    text = "\n".join(describe_isolation(iso))
    readable = [p for p in BLOCKED_PATHS if all(os.stat(q).st_mode & 0o005 for q in [p, *map(str, Path(p).parents)])]
    if iso.get("root") and "uid_error" not in iso and not readable:
        assert level == "separate-user" and "separate unprivileged user" in text
    elif iso.get("reference_readable"):
        assert level == "audit-hook-only" and "audit hook ONLY" in text


def test_ekf_update_wrapping_cases_cross_the_cut_for_every_seed():
    """The 'bearing innovation wrapped' test must catch a missing wrap whatever the scenario seed."""
    from autograder.exercises import ekf_localization as ex

    for seed in range(200):
        rng = np.random.default_rng(seed)
        for th in (0.3, np.pi - 0.01, -np.pi + 0.02):
            mu_bar = np.array([rng.uniform(-5, 5), rng.uniform(-5, 5), th])
            z, m = ex._meas_case(rng, mu_bar, behind=True)
            z_hat = sl.landmark_measurement(mu_bar, m)[0]
            assert abs(z[1] - z_hat[1]) > np.pi, (seed, th, z, z_hat)


def test_gauss_newton_wrapping_cases_cross_the_cut_for_every_seed():
    """The 'first pose unchanged and headings wrapped' test: the step takes a heading beyond +-pi whatever the seed."""
    from autograder.context import wrap
    from autograder.exercises import graph_slam as ex

    for seed in range(100):
        rng = np.random.default_rng(seed)
        for th in (np.pi - 0.02, -np.pi + 0.02):
            X0, edges, Z, Omega = ex._graph_across_cut(rng, th)
            assert np.all((X0[:, 2] >= -np.pi) & (X0[:, 2] < np.pi)) and np.array_equal(X0[0], [3.0, -2.0, th])
            ref = sl.gauss_newton_step(X0, edges, Z, Omega)
            unwrapped = X0[:, 2] + wrap(ref[:, 2] - X0[:, 2])
            assert np.abs(unwrapped[1:]).max() > np.pi + 0.05, (seed, th, unwrapped)


def test_measurement_wrapping_cases_need_the_wrap_for_every_seed():
    """The z_hat tests of landmark_measurement and ekf_slam_measurement catch a missing bearing wrap whatever the seed."""
    from autograder.exercises import ekf_slam, motion_sensor_models

    def unwrapped(x, m):
        return np.arctan2(m[1] - x[1], m[0] - x[0]) - x[2]

    for seed in range(200):
        rng = np.random.default_rng(seed)
        raw = [unwrapped(x, m) for x, m in motion_sensor_models._across_cases(rng)]
        for s in (1.0, -1.0):
            mu, j = ekf_slam._across(rng, s)
            raw.append(unwrapped(mu[:3], mu[3 + 2 * j:5 + 2 * j]))
        raw = np.array(raw)
        assert np.all(np.abs(raw) > np.pi + 0.5) and np.all(np.abs(raw) < 2 * np.pi - 0.2), (seed, raw)
        assert np.all(np.sign(raw) == [-1, 1, -1, 1]), (seed, raw)


def test_odometry_density_wrapping_cases_need_the_wrap_for_every_seed():
    """'angle differences wrapped' (motion_model_odometry): u - rot_hat leaves [-pi, pi) for likely hypotheses."""
    from autograder.context import wrap
    from autograder.exercises import motion_sensor_models as ex

    u = np.array([3.05, 1.0, -3.05])
    alpha = np.array([0.05, 0.02, 0.05, 0.01])
    for seed in range(200):
        x, x_next = ex._hypotheses(np.random.default_rng(seed), 40, u, 0.1, beyond=8)
        rot1 = wrap(np.arctan2(x_next[:, 1] - x[:, 1], x_next[:, 0] - x[:, 0]) - x[:, 2])
        rot2 = wrap(x_next[:, 2] - x[:, 2] - rot1)
        p = sl.motion_model_odometry(x_next, u, x, alpha)
        likely = p > 1e-3 * p.max()
        for d in (u[0] - rot1, u[2] - rot2):
            assert np.any(likely & (np.abs(d) > np.pi + 1.0)), (seed, d, p)


def test_prediction_sharp_turns_go_both_ways_for_every_seed():
    """The V and Sigma_bar tests turn sharply left and right whatever the seed (beyond the small-turn series of V)."""
    from autograder.exercises import ekf_localization, ekf_slam, motion_sensor_models

    def series_error(a):  # relative error of d sinc(a) / da's small-turn series -a/3 + a^3/30
        exact = (a * np.cos(a) - np.sin(a)) / a**2
        return abs(-a / 3 + a**3 / 30 - exact) / abs(exact)

    for seed in range(200):
        rng = np.random.default_rng(seed)
        controls = [(u, dt) for _, u, dt in motion_sensor_models._sharp_turns(rng)]
        controls += ekf_localization._sharp_controls(rng) + ekf_slam._sharp_controls(rng)
        for k, (u, dt) in enumerate(controls):
            turn = u[1] * dt * (1 if k % 2 == 0 else -1)  # left (> 0) then right (< 0) in each pair
            assert turn >= 1.2 and u[0] >= 0.5 and series_error(0.5 * u[1] * dt) > 1e-4, (seed, k, u, dt)


def test_ekf_updates_near_the_cut_cross_it_for_every_seed():
    """The 'bearing innovation wrapped' tests of ekf_update and ekf_slam_update move a heading across +-pi."""
    from autograder.context import wrap
    from autograder.exercises import ekf_localization, ekf_slam

    Q = np.diag([0.05, 0.02])
    for seed in range(200):
        rng = np.random.default_rng(seed)
        mu_bar, Sigma_bar, m = ekf_localization._near_cut(rng)
        mu, Sigma, j = ekf_slam._near_cut(rng)
        for db in (-0.3, 0.3):
            z = sl.landmark_measurement(mu_bar, m)[0] + [0.0, db]
            z[1] = sl.wrap_angle(z[1])
            th = sl.ekf_update(mu_bar, Sigma_bar, z, m, Q)[0][2]
            z = sl.ekf_slam_measurement(mu, j)[0] + [0.0, db]
            z[1] = sl.wrap_angle(z[1])
            th_slam = sl.ekf_slam_update(mu, Sigma, z, j, Q)[0][2]
            for before, after in ((mu_bar[2], th), (mu[2], th_slam)):
                unwrapped = before + wrap(after - before)
                if db < 0:  # the heading rises past +pi
                    assert unwrapped > np.pi + 0.1, (seed, db, unwrapped)
                else:
                    assert unwrapped < np.pi - 0.1, (seed, db, unwrapped)
