"""Tests of slamlib.sim: the simulated landmark run follows its models."""

import numpy as np
import pytest
from scipy import stats

import slamlib as sl


def ro(a):
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


def make_run(seed=0, T=200, **kw):
    rng = np.random.default_rng(seed)
    lm = sl.make_landmark_world(12, extent=12.0, min_separation=1.5, rng=rng)
    u = sl.loop_controls(T, v=1.0, omega=0.25)
    args = dict(x0=np.array([0.0, -3.0, 0.0]), M=np.diag([0.02, 0.01]), Q=np.diag([0.04, 0.003]),
                max_range=6.0, fov=np.deg2rad(180), rng=rng)
    args.update(kw)
    return sl.simulate_landmark_run(lm, u, 0.1, **args)


def test_run_shapes_and_fields():
    run = make_run()
    T = 200
    assert run.n_steps == T
    assert run.x_true.shape == (T + 1, 3) and run.u.shape == (T, 2) and run.u_true.shape == (T, 2)
    np.testing.assert_array_equal(run.x_true[0], [0.0, -3.0, 0.0])
    assert len(run.z) == T and len(run.ids) == T
    for z, ids in zip(run.z, run.ids):
        assert z.shape == (len(ids), 2) and ids.dtype.kind == "i"
        assert np.all((z[:, 1] >= -np.pi) & (z[:, 1] < np.pi))
    assert sum(len(i) for i in run.ids) > T  # landmarks are seen
    assert run.M.shape == (2, 2) and run.Q.shape == (2, 2) and run.max_range == 6.0
    with pytest.raises(ValueError):
        run.x_true[0, 0] = 1.0  # read-only


def test_truth_follows_executed_controls():
    run = make_run(1)
    for t in range(run.n_steps):
        nxt, _, _ = sl.velocity_motion(run.x_true[t], run.u_true[t], run.dt)
        np.testing.assert_allclose(run.x_true[t + 1], nxt, atol=1e-12)


def test_control_noise_has_covariance_M():
    run = make_run(2, T=3000)
    d = run.u_true - run.u
    np.testing.assert_allclose(np.cov(d.T), run.M, atol=0.003)
    assert np.all(np.abs(d.mean(axis=0)) < 4 * np.sqrt(np.diag(run.M) / 3000))


def test_measurement_noise_and_visibility():
    run = make_run(3, T=1500)
    res = []
    for t in range(run.n_steps):
        x = run.x_true[t + 1]
        zh, _, _ = sl.landmark_measurement(x, run.landmarks)
        visible = np.flatnonzero((zh[:, 0] <= run.max_range) & (np.abs(zh[:, 1]) <= run.fov / 2))
        np.testing.assert_array_equal(run.ids[t], visible)
        e = run.z[t] - zh[run.ids[t]]
        e[:, 1] = sl.wrap_angle(e[:, 1])
        res.append(e)
    e = np.concatenate(res)
    np.testing.assert_allclose(np.cov(e.T), run.Q, rtol=0.06, atol=2e-4)
    # standardised bearing residuals are normal (KS on wrapped angles)
    assert stats.kstest(e[:, 1] / np.sqrt(run.Q[1, 1]), "norm").pvalue > 0.01
    assert stats.kstest(e[:, 0] / np.sqrt(run.Q[0, 0]), "norm").pvalue > 0.01


def test_noise_free_run_is_exact_and_reproducible():
    a = make_run(4, M=np.zeros((2, 2)), Q=np.zeros((2, 2)))
    np.testing.assert_array_equal(a.u, a.u_true)
    t = 17
    zh, _, _ = sl.landmark_measurement(a.x_true[t + 1], a.landmarks[a.ids[t]])
    np.testing.assert_allclose(a.z[t], zh, atol=1e-12)
    b = make_run(4, M=np.zeros((2, 2)), Q=np.zeros((2, 2)))
    np.testing.assert_array_equal(a.x_true, b.x_true)


def test_loop_closes_and_figure_eight():
    n = 100
    u = sl.loop_controls(n, v=0.5, omega=2 * np.pi / (n * 0.1))
    x = np.zeros(3)
    for k in range(n):
        x, _, _ = sl.velocity_motion(x, u[k], 0.1)
    np.testing.assert_allclose(x, 0, atol=1e-10)
    u8 = sl.figure_eight_controls(2 * n, v=0.5, omega=2 * np.pi / (n * 0.1))
    assert u8.shape == (2 * n, 2) and np.all(u8[:n, 1] > 0) and np.all(u8[n:, 1] < 0)
    xs = [np.zeros(3)]
    for k in range(2 * n):
        xs.append(sl.velocity_motion(xs[-1], u8[k], 0.1)[0])
    xs = np.array(xs)
    np.testing.assert_allclose(xs[-1], 0, atol=1e-9)
    assert xs[:, 1].max() > 1.0 and xs[:, 1].min() < -1.0  # two lobes


def test_bad_inputs():
    lm = np.zeros((3, 2)) + [[1, 1], [2, 2], [3, 3]]
    u = np.ones((5, 2))
    good = dict(x0=np.zeros(3), M=np.eye(2) * 0.01, Q=np.eye(2) * 0.01, rng=np.random.default_rng(0))
    for kw, name in [({"M": -np.eye(2)}, "M"), ({"Q": np.ones((3, 3))}, "Q"), ({"x0": np.zeros(2)}, "x0"),
                     ({"rng": 3}, "rng"), ({"max_range": -1.0}, "max_range"), ({"fov": 0.0}, "fov")]:
        with pytest.raises((ValueError, TypeError), match=name):
            sl.simulate_landmark_run(lm, u, 0.1, **{**good, **kw})
    with pytest.raises(ValueError, match="landmarks"):
        sl.simulate_landmark_run(np.zeros((3, 3)), u, 0.1, **good)
    with pytest.raises(ValueError, match="dt"):
        sl.simulate_landmark_run(lm, u, 0.0, **good)
    with pytest.raises(TypeError, match="n_steps"):
        sl.loop_controls(2.5, v=1.0, omega=0.1)


def test_inputs_not_modified():
    lm, u, x0 = ro([[1.0, 1.0], [3.0, -1.0]]), ro(np.ones((4, 2))), ro([0.0, 0.0, 4.0])
    run = sl.simulate_landmark_run(lm, u, 0.1, x0=x0, M=ro(np.eye(2) * 0.01), Q=ro(np.eye(2) * 0.01),
                                   rng=np.random.default_rng(0))
    assert x0[2] == 4.0 and run.x_true[0, 2] == pytest.approx(sl.wrap_angle(4.0))
