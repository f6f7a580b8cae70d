"""Victoria Park: the car's Ackermann model, the loader and its bad-input checks, SLAM on a short window."""

from __future__ import annotations

import gzip
import shutil

import numpy as np
import pytest

import slamlib as sl
from slamlib.datasets import data_path
from slamlib.datasets.victoria import (VICTORIA_DT, car_model, load_victoria_park, read_car_geometry,
                                       victoria_gps_ate)
from slamlib.motion import _ackermann, _ackermann1

CAR = dict(a=3.78, b=0.5, H=0.76, L=2.83)


# --------------------------------------------------------------------------- the model
def _central(f, x, eps=1e-6):
    cols = []
    for i in range(x.size):
        e = np.zeros_like(x)
        e[i] = eps
        cols.append((f(x + e) - f(x - e)) / (2 * eps))
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize("seed", range(5))
def test_ackermann_jacobians_against_central_differences(seed):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=3) * [10, 10, 2]
    u = np.array([rng.uniform(-1, 7), rng.uniform(-0.55, 0.55)])
    dt = 0.05
    _, G, V = sl.ackermann_motion(x, u, dt, **CAR)
    G_num = _central(lambda p: sl.ackermann_motion(p, u, dt, **CAR)[0], x)
    V_num = _central(lambda q: sl.ackermann_motion(x, q, dt, **CAR)[0], u)
    np.testing.assert_allclose(G, G_num, rtol=0, atol=1e-8)
    np.testing.assert_allclose(V, V_num, rtol=0, atol=1e-8)


def test_ackermann_is_vectorised_and_the_scalar_path_agrees():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(50, 3))
    u = np.column_stack([rng.uniform(0, 6, 50), rng.uniform(-0.5, 0.5, 50)])
    xn, G, V = sl.ackermann_motion(x, u, 0.1, **CAR)
    assert xn.shape == (50, 3) and G.shape == (50, 3, 3) and V.shape == (50, 3, 2)
    for k in (0, 17, 49):
        for a, b in zip((xn[k], G[k], V[k]), _ackermann1(x[k], u[k], 0.1, *CAR.values())):
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
    model = sl.AckermannModel(**CAR)
    np.testing.assert_allclose(model(x, u, 0.1)[0], xn, atol=0)
    # the pose alone (what the particle filters sample with) is the same pose, bit for bit
    np.testing.assert_array_equal(model.pose(x, u, 0.1), xn)
    np.testing.assert_array_equal(model.pose(x[3], u[3], 0.1), model(x[3], u[3], 0.1)[0])


def test_ackermann_straight_and_the_laser_lever_arm():
    # straight ahead: every point of the car moves with v_e along the heading
    xn, _, _ = sl.ackermann_motion(np.array([1.0, 2.0, np.pi / 2]), np.array([4.0, 0.0]), 0.5, **CAR)
    np.testing.assert_allclose(xn, [1.0, 4.0, np.pi / 2], atol=1e-12)
    # turning: the laser point moves like the rear-axle centre plus omega x (a, b), to first order
    x = np.array([0.0, 0.0, 0.3])
    u = np.array([2.0, 0.2])
    dt = 1e-4
    xn = _ackermann(x, u, dt, *CAR.values())[0]
    vc = u[0] / (1 - np.tan(u[1]) * CAR["H"] / CAR["L"])
    w = vc * np.tan(u[1]) / CAR["L"]
    c, s = np.cos(x[2]), np.sin(x[2])
    lever = np.array([CAR["a"] * c - CAR["b"] * s, CAR["a"] * s + CAR["b"] * c])
    v_laser = vc * np.array([c, s]) + w * np.array([-lever[1], lever[0]])
    np.testing.assert_allclose((xn[:2] - x[:2]) / dt, v_laser, rtol=1e-9)
    np.testing.assert_allclose((xn[2] - x[2]) / dt, w, rtol=1e-9)


def test_ackermann_rejects_bad_input():
    with pytest.raises(ValueError, match="steering"):
        sl.ackermann_motion(np.zeros(3), np.array([1.0, 1.4]), 0.1, **CAR)
    with pytest.raises(ValueError, match="L"):
        sl.ackermann_motion(np.zeros(3), np.array([1.0, 0.1]), 0.1, a=1, b=0, H=0.5, L=0)


def test_pluggable_motion_leaves_the_velocity_default_unchanged():
    rng = np.random.default_rng(3)
    landmarks = rng.uniform(-10, 10, (8, 2))
    u = np.tile([1.0, 0.2], (60, 1))
    M, Q = np.diag([0.01, 0.001]), np.diag([0.05, 0.002])
    run = sl.simulate_landmark_run(landmarks, u, 0.1, x0=np.zeros(3), M=M, Q=Q, rng=rng)
    res0 = sl.run_ekf_slam(run)
    res1 = sl.run_ekf_slam(run, motion=sl.velocity_motion)
    np.testing.assert_allclose(res1.x, res0.x, rtol=0, atol=1e-10)
    f0 = sl.run_fastslam(run, n_particles=20, rng=np.random.default_rng(0), version=2)
    f1 = sl.run_fastslam(run, n_particles=20, rng=np.random.default_rng(0), version=2, motion=sl.velocity_motion)
    np.testing.assert_allclose(f1.x_est, f0.x_est, rtol=0, atol=1e-10)
    # a car model drives differently: the same controls read as [v_e, alpha] give another path
    res2 = sl.run_ekf_slam(run, motion=sl.AckermannModel(**CAR))
    assert np.abs(res2.x - res0.x).max() > 0.1


# --------------------------------------------------------------------------- the loader
@pytest.fixture(scope="module")
def window():
    return load_victoria_park(t_max=60.0)


def test_loader_shapes_and_conventions(window):
    T = window.n_steps
    assert window.dt == VICTORIA_DT and T == 1200
    assert window.u.shape == (T, 2) and len(window.z) == len(window.ids) == len(window.diameters) == T
    z = np.concatenate([z for z in window.z if len(z)])
    assert z.shape[0] == window.n_sightings > 1000
    # raw bearings span [0, pi] with pi/2 ahead; the book's are raw - pi/2
    assert -np.pi / 2 <= z[:, 1].min() < -1.0 and 1.0 < z[:, 1].max() <= np.pi / 2
    assert np.all(np.concatenate(window.ids) == -1)
    assert window.car == {"a": 0.95, "b": 0.5, "H": 0.76, "L": 2.83}
    assert window.motion.a == pytest.approx(3.78) and window.motion.b == 0.5
    assert np.all(np.diff(window.gps[:, 0]) >= 0) and 0 <= window.gps[0, 0] and window.gps[-1, 0] <= 60.0


def test_first_detection_is_the_file_first_line_converted(window):
    # measurements.dat line 1: 0.852 20.46202 0.88575 0.35404 (before the first input, 0.973 s: dropped);
    # the first kept detection is the first row at or after the first input
    with gzip.open(data_path("victoria_park", "measurements.dat.gz"), "rt") as fh:
        rows = np.loadtxt(fh, max_rows=200)
    first = rows[rows[:, 0] >= 0.973][0]
    k = next(k for k in range(window.n_steps) if len(window.z[k]))
    np.testing.assert_allclose(window.z[k][0], [first[1], first[2] - np.pi / 2], rtol=0, atol=1e-12)
    assert window.diameters[k][0] == first[3]


def _write_set(tmp_path, *, inputs=None, measurements=None, gps=None, info=None, gz=True):
    src = data_path("victoria_park")
    default = {
        "inputs.dat": "1.000 2.0 0.01\n1.025 2.0 0.01\n1.050 2.1 0.02\n1.075 2.1 0.02\n1.100 2.1 0.02\n",
        "measurements.dat": "1.030 10.0 1.57 0.3\n1.030 12.0 1.00 0.4\n1.080 10.1 1.56 0.3\n",
        "gps.dat": "1.00 0.0 0.0\n1.10 0.2 0.0\n",
    }
    given = {"inputs.dat": inputs, "measurements.dat": measurements, "gps.dat": gps}
    for name, text in default.items():
        text = given[name] if given[name] is not None else text
        path = tmp_path / (name + (".gz" if gz else ""))
        if gz:
            with gzip.open(path, "wt") as fh:
                fh.write(text)
        else:
            path.write_text(text)
    if info is None:
        shutil.copy(src / "info.txt.gz", tmp_path / "info.txt.gz")
    else:
        (tmp_path / "info.txt").write_text(info)
    return tmp_path


def test_loader_reads_a_small_synthetic_set(tmp_path):
    run = load_victoria_park(data_dir=_write_set(tmp_path, gz=False), dt=0.025)
    assert run.n_steps == 4 and run.n_sightings == 3
    np.testing.assert_allclose(run.z[0], [[10.0, 1.57 - np.pi / 2], [12.0, 1.00 - np.pi / 2]])
    np.testing.assert_allclose(run.u[0], [2.0, 0.01])
    assert run.counts == {"inputs": 5, "detections": 3, "outside": 0, "gps": 2}


@pytest.mark.parametrize("kwargs, match", [
    (dict(inputs="1.000 2.0 0.01\n1.025 2.0\n1.050 2.1 0.02\n"), r"inputs\.dat\.gz, line 2: expected 3 numbers"),
    (dict(inputs="1.000 2.0 0.01\n1.025 2.0 abc\n"), r"inputs\.dat\.gz, line 2: expected 3 numbers"),
    (dict(inputs="1.000 2.0 0.01\n1.025 nan 0.01\n1.05 1 0\n"), r"inputs\.dat\.gz, line 2: NaN or inf"),
    (dict(inputs="1.000 2.0 0.01\n1.050 2.0 0.01\n1.025 2.0 0.01\n"), r"inputs\.dat\.gz, line 3: time goes backwards"),
    (dict(inputs="1.000 2.0 0.01\n1.025 2.0 1.4\n1.05 1 0\n"), r"inputs\.dat\.gz, line 2: steering"),
    (dict(measurements="1.03 10 1.5 0.3\n1.03 -1 1.5 0.3\n"), r"measurements\.dat\.gz, line 2: non-positive range"),
    (dict(measurements="1.03 10 1.5 0.3\n\n1.04 10 3.5 0.3\n"), r"measurements\.dat\.gz, line 3: bearing outside"),
    (dict(measurements="1.03 10 1.5 0.3\n1.04 10 1.5 -0.3\n"), r"measurements\.dat\.gz, line 2: negative trunk"),
    (dict(measurements="1.04 10 1.5 0.3\n1.03 10 1.5 0.3\n"), r"measurements\.dat\.gz, line 2: time goes backwards"),
    (dict(gps="1.0 0 0\n1.2 0 inf\n"), r"gps\.dat\.gz, line 2: NaN or inf"),
    (dict(gps=""), r"gps\.dat\.gz: no data rows"),
    (dict(info="CAR parameters\na : 0.95 m\nb : 0.5 m\nH : 0.76 m\n"), r"info\.txt: no line 'L"),
])
def test_bad_input_names_the_file_and_line(tmp_path, kwargs, match):
    with pytest.raises(ValueError, match=match):
        load_victoria_park(data_dir=_write_set(tmp_path, **kwargs), dt=0.025)


def test_truncated_gzip_names_the_file(tmp_path):
    _write_set(tmp_path)
    data = (data_path("victoria_park") / "inputs.dat.gz").read_bytes()
    (tmp_path / "inputs.dat.gz").write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=r"inputs\.dat\.gz: corrupt or truncated"):
        load_victoria_park(data_dir=tmp_path)
    (tmp_path / "inputs.dat.gz").write_bytes(b"not a gzip file at all")
    with pytest.raises(ValueError, match=r"inputs\.dat\.gz: corrupt or truncated"):
        load_victoria_park(data_dir=tmp_path)


def test_missing_file_and_geometry(tmp_path):
    _write_set(tmp_path)
    (tmp_path / "gps.dat.gz").unlink()
    with pytest.raises(FileNotFoundError, match="gps.dat"):
        load_victoria_park(data_dir=tmp_path)
    assert read_car_geometry(data_path("victoria_park", "info.txt.gz")) == {"a": 0.95, "b": 0.5, "H": 0.76, "L": 2.83}
    assert car_model({"a": 0.95, "b": 0.5, "H": 0.76, "L": 2.83}).a == pytest.approx(3.78)


# --------------------------------------------------------------------------- SLAM on a window
def _dead_reckoning(run):
    x = np.zeros((run.n_steps + 1, 3))
    for k in range(run.n_steps):
        x[k + 1] = run.motion(x[k], run.u[k], run.dt)[0]
    return x


def test_gps_ate_of_a_rotated_copy_is_zero(window):
    x = np.zeros((window.n_steps + 1, 3))
    x[:, 0] = np.interp(window.t, window.gps[:, 0], window.gps[:, 1])
    x[:, 1] = np.interp(window.t, window.gps[:, 0], window.gps[:, 2])
    c, s = np.cos(0.7), np.sin(0.7)
    ate0 = victoria_gps_ate(window, x)[0]
    assert ate0 < 0.05  # only the interpolation onto the step times and back
    x[:, :2] = x[:, :2] @ np.array([[c, -s], [s, c]]).T + [5.0, -3.0]
    ate, aligned, res, (R, t) = victoria_gps_ate(window, x)
    assert ate == pytest.approx(ate0, abs=1e-9) and res.shape == (window.gps.shape[0],)
    np.testing.assert_allclose(R, [[c, s], [-s, c]], atol=1e-4)


@pytest.mark.slow
def test_ekf_slam_on_a_window_beats_dead_reckoning_against_gps():
    run = load_victoria_park(t_max=150.0)
    dr = victoria_gps_ate(run, _dead_reckoning(run))[0]
    res = sl.run_ekf_slam(run, known=False, confirm=2, motion=run.motion)
    ekf = victoria_gps_ate(run, res.x)[0]
    assert ekf < 0.8 * dr, (ekf, dr)
    assert 50 < res.n_landmarks[-1] < 300


@pytest.mark.slow
@pytest.mark.parametrize("version", [1, 2])
def test_fastslam_per_measurement_candidates_equal_scoring_every_candidate_on_the_log(version, monkeypatch):
    # the real log's scans (a dozen trees in view, hundreds in the map): the run with each measurement
    # scoring only the landmarks within reach of it is bit for bit the run scoring every candidate
    from slamlib import fastslam as fs

    run = load_victoria_park(t_max=60.0)
    kw = dict(n_particles=30, known=False, version=version, motion=run.motion)
    res = sl.run_fastslam(run, rng=np.random.default_rng(5), **kw)
    monkeypatch.setattr(fs, "_PREFILTER", False)
    every = sl.run_fastslam(run, rng=np.random.default_rng(5), **kw)
    assert res.seen.sum() > 30
    for a, b in zip(res.state, every.state):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(res.path_best, every.path_best)
