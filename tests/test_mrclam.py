"""MRCLAM Dataset 6 loader, scoring up to a rigid transform, and SLAM on the real log."""

from __future__ import annotations

import gzip
import json
from pathlib import Path

import numpy as np
import pytest

import slamlib as sl
from slamlib.datasets.mrclam import MRCLAM_DT, MRCLAM_M, MRCLAM_Q, MRCLAM_ROBOTS, load_mrclam

ROOT = Path(__file__).resolve().parents[1]

#: The full recording the shipped subset was cut from, when a checkout of the course's data sits
#: beside the repository (as in the development setup); the comparison is skipped elsewhere.
ORIGINAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "mrclam" / "MRCLAM_Dataset6"
#: Landmark sightings of robot 1 per landmark index 0..14 (subjects 6..20) over its whole log.
ROBOT1_PER_LANDMARK = [73, 131, 84, 48, 50, 32, 88, 169, 140, 91, 140, 158, 115, 85, 130]


@pytest.fixture(scope="module")
def run1():
    return load_mrclam(1)


def _rot(a):
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


# --------------------------------------------------------------------------- loader
def test_shapes_and_time_grid(run1):
    T = run1.n_steps
    assert run1.dt == MRCLAM_DT
    assert run1.x_true.shape == (T + 1, 3) and run1.u.shape == (T, 2) and run1.t.shape == (T + 1,)
    assert len(run1.z) == len(run1.ids) == T
    np.testing.assert_allclose(np.diff(run1.t), run1.dt, rtol=0, atol=1e-9)
    assert run1.t[0] == 0.0
    np.testing.assert_array_equal(run1.x0, run1.x_true[0])
    assert run1.landmarks.shape == (15, 2) and run1.landmark_std.shape == (15, 2)
    # robot 1's Vicon track ends first (772 s after the Vicon start); its commands start 12.2 s in
    assert 755.0 < run1.t[-1] <= 760.0
    for z, i in zip(run1.z, run1.ids):
        assert z.shape == (i.shape[0], 2) and i.dtype.kind == "i"


def test_units_and_ranges(run1):
    Z = np.concatenate(run1.z)
    assert 0.9 < Z[:, 0].min() and Z[:, 0].max() < 9.0  # metres
    assert np.all(np.abs(Z[:, 1]) < 0.65)  # radians: the camera sees about +-35 degrees
    assert np.all(np.abs(run1.u[:, 0]) <= 0.1) and np.all(np.abs(run1.u[:, 1]) <= 0.45)  # m/s, rad/s
    assert np.all((run1.x_true[:, 2] >= -np.pi) & (run1.x_true[:, 2] < np.pi))
    lo, hi = run1.x_true[:, :2].min(axis=0), run1.x_true[:, :2].max(axis=0)
    assert np.all(lo > [-1.0, -5.5]) and np.all(hi < [5.0, 6.5])  # inside the hall
    # subject 6 (index 0) and 20 (index 14) from Landmark_Groundtruth.dat
    np.testing.assert_allclose(run1.landmarks[0], [0.58831396, -4.28264845], atol=1e-8)
    np.testing.assert_allclose(run1.landmarks[14], [1.24712229, 4.46500471], atol=1e-8)


def test_barcode_mapping_counts():
    run = load_mrclam(1)
    # Robot1_Measurement.dat: 1942 records = 1534 landmarks + 407 robots (barcodes 14, 23, 32, 41)
    # + 1 of barcode 43, which belongs to no subject
    assert run.counts == {"landmark": 1534, "robot": 407, "unknown": 1, "outside": 0}
    assert run.n_sightings == 1534
    np.testing.assert_array_equal(np.bincount(np.concatenate(run.ids), minlength=15), ROBOT1_PER_LANDMARK)
    run2 = load_mrclam(2)
    assert run2.counts == {"landmark": 3239, "robot": 792, "unknown": 0, "outside": 0}


def test_sightings_agree_with_vicon(run1):
    # a wrong barcode -> landmark mapping or a wrong step assignment gives metre-scale residuals
    res = sl.measurement_residuals(run1.x_true, run1.z, run1.ids, run1.landmarks)
    assert res.shape == (1534, 2)
    assert np.median(np.abs(res[:, 0])) < 0.10
    assert np.median(np.abs(res[:, 1])) < 0.015
    assert abs(np.mean(res[:, 1])) < 0.005


def test_controls_agree_with_vicon(run1):
    # averaged over 1 s, the commands match the Vicon motion to a few cm/s and rad/s
    res = sl.control_residuals(run1.x_true, run1.u, run1.dt, window=10)
    assert np.all(np.abs(res.mean(axis=0)) < [0.01, 0.01])
    assert np.all(res.std(axis=0) < [0.03, 0.08])


def test_t_max_and_dt_scale_M():
    run = load_mrclam(1, dt=0.05, t_max=30.0)
    assert run.n_steps == 600
    np.testing.assert_allclose(run.M, MRCLAM_M * 2.0)
    np.testing.assert_allclose(run.Q, MRCLAM_Q)
    full = load_mrclam(1, dt=0.05)
    np.testing.assert_array_equal(run.u, full.u[:600])
    np.testing.assert_array_equal(run.x_true, full.x_true[:601])
    M = np.diag([0.01, 0.02])
    np.testing.assert_array_equal(load_mrclam(1, t_max=5.0, M=M).M, M)


def test_run_is_read_only(run1):
    with pytest.raises(ValueError):
        run1.u[0, 0] = 1.0


@pytest.mark.parametrize(
    "kwargs, exc, match",
    [
        ({"robot": 6}, ValueError, "robot"),
        ({"robot": 0}, ValueError, "robot"),
        ({"robot": "1"}, TypeError, "robot"),
        ({"robot": True}, TypeError, "robot"),
        ({"dt": 0.0}, ValueError, "dt"),
        ({"dt": 2.0}, ValueError, "dt"),
        ({"t_max": 0.01}, ValueError, "t_max"),
        ({"t_max": -1.0}, ValueError, "t_max"),
        ({"M": np.eye(3)}, ValueError, "M"),
        ({"Q": np.array([[1.0, 2.0], [2.0, 1.0]])}, ValueError, "Q"),
        ({"data_dir": "/nonexistent/mrclam"}, FileNotFoundError, "data_dir"),
        ({"gate": -1.0}, ValueError, "gate"),
    ],
)
def test_bad_arguments(kwargs, exc, match):
    with pytest.raises(exc, match=match):
        load_mrclam(**kwargs)


def _write(path, rows, header="# a header line\n"):
    with gzip.open(path, "wt") as f:
        f.write(header + "".join("\t".join(str(v) for v in r) + "\n" for r in rows))


@pytest.fixture
def tiny(tmp_path):
    """A hand-made log: known controls, two landmarks, sightings of robots and unknown barcodes."""
    _write(tmp_path / "Barcodes.dat.gz", [(1, 5), (2, 14)] + [(s, 100 + s) for s in range(6, 21)])
    _write(tmp_path / "Landmark_Groundtruth.dat.gz",
           [(s, float(s), 1.0, 1e-4, 1e-4) for s in range(20, 5, -1)])  # reversed order on purpose
    # commands: 0.1 m/s from t=100.0, 0.3 m/s from t=100.25, stop at t=101.0
    _write(tmp_path / "Robot1_Odometry.dat.gz", [(100.0, 0.1, 0.0), (100.25, 0.3, 0.0), (101.0, 0.0, 0.0)])
    _write(tmp_path / "Robot1_Groundtruth.dat.gz",
           [(99.9 + 0.1 * k, 0.01 * k, 0.0, 0.0) for k in range(15)])
    _write(tmp_path / "Robot1_Measurement.dat.gz", [
        (99.0, 107, 7.0, 0.0),     # before the start: outside
        (100.26, 120, 14.0, 3.5),  # landmark 14, step 2 (after 0.3 s); bearing 3.5 is wrapped
        (100.31, 5, 1.0, 0.0),     # robot 1's own barcode: skipped as a robot
        (100.40, 77, 2.0, 0.0),    # barcode of no subject: skipped
        (100.52, 106, 6.0, 0.1),   # landmark 0, nearest step end t=0.5 -> step 4
    ])
    return tmp_path


def test_tiny_log(tiny):
    run = load_mrclam(1, dt=0.1, data_dir=tiny)
    assert run.n_steps == 10
    assert run.t_start == pytest.approx(100.0)
    np.testing.assert_allclose(run.landmarks[:, 0], np.arange(6, 21))
    # zero-order hold averaged per step: step 2 covers [0.2, 0.3): half at 0.1, half at 0.3
    np.testing.assert_allclose(run.u[:, 0], [0.1, 0.1, 0.2, 0.3, 0.3, 0.3, 0.3, 0.3, 0.3, 0.3], atol=1e-12)
    assert run.counts == {"landmark": 2, "robot": 1, "unknown": 1, "outside": 1}
    assert [k for k, i in enumerate(run.ids) if i.size] == [2, 4]
    np.testing.assert_array_equal(run.ids[2], [14])
    np.testing.assert_array_equal(run.ids[4], [0])
    np.testing.assert_allclose(run.z[2], [[14.0, 3.5 - 2 * np.pi]])
    np.testing.assert_allclose(run.x_true[:, 0], 0.01 + 0.1 * np.arange(11) * 0.1, atol=1e-12)


def test_malformed_file(tiny):
    _write(tiny / "Robot1_Odometry.dat.gz", [(100.0, 0.1), (101.0, 0.2)])
    with pytest.raises(ValueError, match="Robot1_Odometry.*3 columns"):
        load_mrclam(1, data_dir=tiny)
    (tiny / "Robot1_Odometry.dat.gz").unlink()
    with pytest.raises(FileNotFoundError, match="Robot1_Odometry"):
        load_mrclam(1, data_dir=tiny)


def _lines(path):
    with gzip.open(path, "rt") as f:
        return f.read().splitlines(keepends=True)


def _edit_line(path, line, text):
    """Replace 1-based `line` of a gzip text file."""
    lines = _lines(path)
    lines[line - 1] = text + "\n"
    with gzip.open(path, "wt") as f:
        f.write("".join(lines))


@pytest.mark.parametrize("name, line, text, match", [
    ("Robot1_Measurement.dat.gz", 3, "100.26\t120\tfourteen\t3.5", r"Robot1_Measurement.dat.gz, line 3: field 'fourteen' is not a number"),
    ("Robot1_Measurement.dat.gz", 3, "100.26\t120\tnan\t3.5", r"Robot1_Measurement.dat.gz, line 3: NaN or infinity"),
    ("Robot1_Measurement.dat.gz", 6, "100.52\t106\t-6.0\t0.1", r"Robot1_Measurement.dat.gz, line 6: non-positive range"),
    ("Robot1_Measurement.dat.gz", 6, "100.52\t106\t0\t0.1", r"Robot1_Measurement.dat.gz, line 6: non-positive range"),
    ("Robot1_Measurement.dat.gz", 6, "100.52\t106.5\t6.0\t0.1", r"Robot1_Measurement.dat.gz, line 6: barcode is not an integer"),
    ("Robot1_Measurement.dat.gz", 4, "100.20\t5\t1.0\t0.0", r"Robot1_Measurement.dat.gz, line 4: time runs backwards"),
    ("Robot1_Odometry.dat.gz", 3, "101.5\t0.3\t0.0", r"Robot1_Odometry.dat.gz, line 4: time runs backwards"),
    ("Robot1_Odometry.dat.gz", 3, "100.25\t0.3", r"Robot1_Odometry.dat.gz, line 3: expected 3 columns, got 2"),
    ("Robot1_Groundtruth.dat.gz", 5, "100.2\t0.03\tinf\t0.0", r"Robot1_Groundtruth.dat.gz, line 5: NaN or infinity"),
    ("Robot1_Groundtruth.dat.gz", 5, "99.0\t0.03\t0.0\t0.0", r"Robot1_Groundtruth.dat.gz, line 5: time runs backwards"),
    ("Barcodes.dat.gz", 4, "6\t14", r"Barcodes.dat.gz, line 4: duplicate barcode 14 \(subject 6; line 3 gives it to subject 2\)"),
    ("Barcodes.dat.gz", 4, "1\t106", r"Barcodes.dat.gz, line 4: duplicate subject 1 \(first on line 2\)"),
    ("Landmark_Groundtruth.dat.gz", 2, "7\t20.0\t1.0\t0.0001\t0.0001", r"Landmark_Groundtruth.dat.gz: expected subjects 6..20 once each"),
])
def test_bad_file_content_is_an_error_naming_file_and_line(tiny, name, line, text, match):
    load_mrclam(1, data_dir=tiny)  # the intact log loads
    _edit_line(tiny / name, line, text)
    with pytest.raises(ValueError, match=match):
        load_mrclam(1, data_dir=tiny)


def test_equal_times_are_allowed(tiny):
    _edit_line(tiny / "Robot1_Odometry.dat.gz", 3, "100.0\t0.3\t0.0")  # same time as line 2: it overrides
    run = load_mrclam(1, data_dir=tiny)
    np.testing.assert_allclose(run.u[:, 0], 0.3, atol=1e-12)


@pytest.mark.parametrize("damage", ["truncate", "corrupt"])
def test_truncated_or_corrupt_gzip_is_an_error_naming_the_file(tiny, damage):
    path = tiny / "Robot1_Groundtruth.dat.gz"
    raw = path.read_bytes()
    if damage == "truncate":
        raw = raw[: len(raw) // 2]
    else:
        raw = raw[:12] + bytes(b ^ 0xFF for b in raw[12:40]) + raw[40:]
    path.write_bytes(raw)
    with pytest.raises(ValueError, match=r"Robot1_Groundtruth.dat.gz: truncated or corrupt gzip file"):
        load_mrclam(1, data_dir=tiny)


def test_all_five_robots_ship_and_carry_the_gate():
    from slamlib.datasets.mrclam import MRCLAM_GATE, MRCLAM_ROBOTS

    assert MRCLAM_ROBOTS == (1, 2, 3, 4, 5)
    np.testing.assert_allclose(MRCLAM_GATE, -2 * np.log(1e-5))
    for r in MRCLAM_ROBOTS:
        run = load_mrclam(r, t_max=20.0)
        assert run.robot == r and run.n_steps == 200 and run.gate == MRCLAM_GATE
    assert load_mrclam(1, t_max=5.0, gate=np.inf).gate == np.inf


@pytest.mark.skipif(not ORIGINAL.is_dir(), reason="the original MRCLAM Dataset 6 folder is not on this machine")
@pytest.mark.parametrize("robot", [1, 2, 3, 4, 5])
def test_every_shipped_robot_matches_the_original(robot):
    ours, orig = load_mrclam(robot), load_mrclam(robot, data_dir=ORIGINAL)
    T = ours.n_steps
    assert T > 7000 and orig.n_steps - T < 3
    np.testing.assert_allclose(ours.u, orig.u[:T], atol=1e-12)
    assert all(np.array_equal(a, b) for a, b in zip(ours.ids, orig.ids[:T]))
    assert all(np.array_equal(a, b) for a, b in zip(ours.z, orig.z[:T]))
    # robot 4's Vicon track has a 2 s gap, where the 60 Hz and the 10 Hz interpolations differ most
    assert np.abs(ours.x_true[:, :2] - orig.x_true[:T + 1, :2]).max() < (0.03 if robot == 4 else 0.01)


@pytest.mark.skipif(not ORIGINAL.is_dir(), reason="the original MRCLAM Dataset 6 folder is not on this machine")
def test_subset_tool_reproduces_the_shipped_files(tmp_path):
    import importlib.util

    spec = importlib.util.spec_from_file_location("mrclam_subset", Path(__file__).resolve().parents[1] / "tools" / "mrclam_subset.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    tool.main([str(ORIGINAL), "--out", str(tmp_path), "--robots", "3"])
    shipped = Path(sl.datasets.data_path("mrclam"))
    for name in ("Robot3_Odometry.dat.gz", "Robot3_Groundtruth.dat.gz", "Robot3_Measurement.dat.gz", "Barcodes.dat.gz"):
        assert _lines(tmp_path / name) == _lines(shipped / name)


@pytest.mark.skipif(not ORIGINAL.is_dir(), reason="the original MRCLAM Dataset 6 folder is not on this machine")
def test_shipped_subset_matches_original():
    ours, orig = load_mrclam(1), load_mrclam(1, data_dir=ORIGINAL)
    T = ours.n_steps
    np.testing.assert_allclose(ours.u, orig.u[:T], atol=1e-12)  # change points only: lossless
    assert all(np.array_equal(a, b) for a, b in zip(ours.ids, orig.ids[:T]))
    # ground truth thinned to 10 Hz: within 1 cm and 0.05 rad of the 60 Hz track
    assert np.abs(ours.x_true[:, :2] - orig.x_true[:T + 1, :2]).max() < 0.01
    assert np.abs(sl.angle_diff(ours.x_true[:, 2], orig.x_true[:T + 1, 2])).max() < 0.05


# --------------------------------------------------------------------------- alignment and scores
def test_align_recovers_rigid_transform():
    rng = np.random.default_rng(0)
    P = rng.uniform(-5, 5, size=(50, 2))
    R, t = _rot(2.5), np.array([1.5, -3.0])
    R_hat, t_hat = sl.align_se2(P, P @ R.T + t)
    np.testing.assert_allclose(R_hat, R, atol=1e-12)
    np.testing.assert_allclose(t_hat, t, atol=1e-12)
    # with noise the fit is close and the residual is what the noise leaves
    noisy = P @ R.T + t + rng.normal(0, 0.01, P.shape)
    R_hat, t_hat = sl.align_se2(P, noisy)
    np.testing.assert_allclose(R_hat, R, atol=5e-3)
    np.testing.assert_allclose(t_hat, t, atol=5e-3)


def test_align_excludes_reflections():
    rng = np.random.default_rng(1)
    P = rng.uniform(-1, 1, size=(20, 2))
    R, _ = sl.align_se2(P, P * [1.0, -1.0])  # a mirror image: best proper rotation instead
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(R.T @ R, np.eye(2), atol=1e-12)


def test_align_rejects_degenerate_input():
    with pytest.raises(ValueError, match="coincide"):
        sl.align_se2(np.ones((5, 2)), np.zeros((5, 2)))
    with pytest.raises(ValueError, match="at least 2"):
        sl.align_se2(np.ones((1, 2)), np.zeros((1, 2)))
    with pytest.raises(ValueError, match="true_xy"):
        sl.align_se2(np.ones((3, 2)), np.zeros((4, 2)))


def test_apply_se2_poses_and_points():
    R, t = _rot(np.pi / 2), np.array([1.0, 0.0])
    np.testing.assert_allclose(sl.apply_se2(R, t, [[1.0, 0.0, 3.0]]), [[1.0, 1.0, 3.0 + np.pi / 2 - 2 * np.pi]])
    np.testing.assert_allclose(sl.apply_se2(R, t, [2.0, 0.0]), [1.0, 2.0], atol=1e-15)
    with pytest.raises(ValueError, match="R"):
        sl.apply_se2(np.diag([1.0, -1.0]), t, [0.0, 0.0])
    with pytest.raises(ValueError, match="x"):
        sl.apply_se2(R, t, np.zeros((3, 4)))


def _wiggly_path(seed=0, T=300):
    rng = np.random.default_rng(seed)
    u = np.column_stack([np.full(T, 0.5), rng.normal(0, 0.3, T)])
    return sl.dead_reckoning([0.0, 0.0, 0.0], u, 0.1)


def test_ate_zero_and_invariant_to_rigid_transform():
    true = _wiggly_path()
    s0 = sl.score_trajectory(true, true)
    assert s0.ate == pytest.approx(0.0, abs=1e-12) and s0.heading_rmse == pytest.approx(0.0, abs=1e-12)
    est = true + np.random.default_rng(2).normal(0, [0.05, 0.05, 0.02], true.shape)
    ref = sl.score_trajectory(est, true)
    moved = sl.apply_se2(_rot(-1.2), np.array([4.0, 7.0]), est)
    again = sl.score_trajectory(moved, true)
    assert again.ate == pytest.approx(ref.ate, rel=1e-9)
    assert again.heading_rmse == pytest.approx(ref.heading_rmse, rel=1e-9)
    assert 0.03 < ref.ate < 0.1
    # without alignment the moved estimate is metres off
    assert sl.score_trajectory(moved, true, align=False).ate > 3.0
    # the returned transform undoes the motion
    np.testing.assert_allclose(sl.apply_se2(again.R, again.t, moved)[:, :2],
                               sl.apply_se2(ref.R, ref.t, est)[:, :2], atol=1e-9)


def test_landmarks_scored_in_the_trajectory_frame():
    true = _wiggly_path(3)
    lm = np.random.default_rng(4).uniform(-5, 5, size=(8, 2))
    R, t = _rot(0.4), np.array([-2.0, 1.0])
    # path and map moved together: both perfect after the trajectory's alignment
    row = sl.score_run("moved", sl.apply_se2(R, t, true), true, landmarks_est=sl.apply_se2(R, t, lm), landmarks_true=lm)
    assert row.ate == pytest.approx(0.0, abs=1e-9) and row.landmark_rmse == pytest.approx(0.0, abs=1e-9)
    assert (row.n_landmarks, row.n_matched) == (8, 8)
    # a map rotated relative to its own path is wrong, even though a fit on the map alone would hide it
    rot_map = sl.apply_se2(R, t, lm)
    row = sl.score_run("map off", true, true, landmarks_est=rot_map, landmarks_true=lm)
    assert row.landmark_rmse > 1.0
    Rm, tm = sl.align_se2(rot_map, lm)
    assert sl.score_landmarks(rot_map, lm, transform=(Rm, tm)) == pytest.approx(0.0, abs=1e-9)
    # seen selects rows; None means no alignment
    seen = np.arange(8) < 3
    est = lm + 0.1
    assert sl.score_landmarks(est, lm, transform=None, seen=seen) == pytest.approx(np.sqrt(0.02))
    with pytest.raises(ValueError, match="seen"):
        sl.score_landmarks(est, lm, transform=None, seen=np.ones(3, dtype=bool))
    with pytest.raises(TypeError, match="transform"):
        sl.score_landmarks(est, lm, transform="identity")


def test_match_landmarks_unknown_order():
    lm = np.random.default_rng(5).uniform(-5, 5, size=(6, 2))
    perm = np.array([3, 0, 5, 1, 4, 2])
    est = np.vstack([lm[perm] + 0.01, [[50.0, 50.0]]])  # plus one spurious landmark far away
    ei, ti = sl.match_landmarks(est, lm, max_dist=1.0)
    np.testing.assert_array_equal(ti, np.arange(6))
    np.testing.assert_array_equal(perm[ei], ti)
    row = sl.score_run("unknown", _wiggly_path(), _wiggly_path(), landmarks_est=est, landmarks_true=lm,
                       match=True, max_dist=1.0)
    assert (row.n_landmarks, row.n_matched) == (7, 6)
    assert row.landmark_rmse == pytest.approx(0.01 * np.sqrt(2), rel=1e-9)


def test_format_score_table():
    rows = [sl.RunScore("dead reckoning", 2.1234, 0.5, float("nan"), 0, 0),
            sl.RunScore("EKF", 0.2049, np.radians(6.04), 0.1251, 15, 15)]
    text = sl.format_score_table(rows).splitlines()
    assert len(text) == 3
    assert text[1].split() == ["dead", "reckoning", "2.12", "28.6", "-", "-"]
    assert text[2].split() == ["EKF", "0.20", "6.0", "0.13", "15/15"]
    with pytest.raises(TypeError, match="RunScore"):
        sl.format_score_table([(1, 2)])


def test_dead_reckoning_equals_step_by_step():
    rng = np.random.default_rng(6)
    u = np.column_stack([rng.uniform(-0.2, 0.5, 400), rng.normal(0, 1.0, 400)])
    u[::7, 1] = 0.0  # straight-line steps too
    x0 = np.array([1.0, -2.0, 3.0])
    x = x0.copy()
    loop = [x]
    for uk in u:
        x = sl.velocity_motion(x, uk, 0.1)[0]
        loop.append(x)
    loop = np.array(loop)
    out = sl.dead_reckoning(x0, u, 0.1)
    assert out.shape == (401, 3)
    np.testing.assert_allclose(out[:, :2], loop[:, :2], atol=1e-10)
    np.testing.assert_allclose(sl.angle_diff(out[:, 2], loop[:, 2]), 0.0, atol=1e-10)
    assert np.all((out[:, 2] >= -np.pi) & (out[:, 2] < np.pi))
    np.testing.assert_array_equal(sl.dead_reckoning(x0, np.zeros((0, 2)), 0.1), x0[None])
    with pytest.raises(ValueError, match="u"):
        sl.dead_reckoning(x0, np.zeros((5, 3)), 0.1)
    with pytest.raises(ValueError, match="dt"):
        sl.dead_reckoning(x0, u, -0.1)


def test_residuals_vanish_on_exact_data():
    run = sl.simulate_landmark_run(np.array([[3.0, 1.0], [-1.0, 4.0]]), sl.loop_controls(50, v=1.0, omega=0.3), 0.1,
                                   x0=np.zeros(3), M=np.zeros((2, 2)), Q=np.zeros((2, 2)),
                                   rng=np.random.default_rng(7))
    res = sl.measurement_residuals(run.x_true, run.z, run.ids, run.landmarks)
    assert res.shape == (sum(len(i) for i in run.ids), 2) and res.shape[0] > 50
    np.testing.assert_allclose(res, 0.0, atol=1e-12)
    np.testing.assert_allclose(sl.control_residuals(run.x_true, run.u, run.dt), 0.0, atol=1e-9)
    with pytest.raises(ValueError, match="window"):
        sl.control_residuals(run.x_true, run.u, run.dt, window=0)


# --------------------------------------------------------------------------- SLAM on the real log
@pytest.fixture(scope="module")
def window():
    """Robot 1, first 400 s: dead reckoning drifts to an aligned ATE of about 1 m."""
    run = load_mrclam(1, t_max=400.0)
    dr = sl.score_trajectory(sl.dead_reckoning(run.x0, run.u, run.dt), run.x_true)
    assert dr.ate > 0.8
    return run, dr


@pytest.mark.slow
def test_ekf_slam_beats_dead_reckoning(window):
    run, dr = window
    res = sl.run_ekf_slam(run, known=True)
    assert res.x.shape == run.x_true.shape
    score = sl.score_trajectory(res.x, run.x_true)
    assert score.ate < 0.5 * dr.ate
    lm = np.zeros((15, 2))
    lm[res.landmark_ids] = res.landmarks
    seen = np.zeros(15, dtype=bool)
    seen[res.landmark_ids] = True
    assert seen.sum() >= 12
    assert sl.score_landmarks(lm, run.landmarks, transform=score, seen=seen) < 0.5


@pytest.mark.slow
def test_fastslam_beats_dead_reckoning(window):
    """FastSLAM 1.0 on the real log varies from seed to seed (a particle set that commits to a
    slightly wrong early map keeps it), so it is judged over five seeds: every run beats dead
    reckoning, the typical (median) run by a factor of two, and its map (landmark RMSE after the
    same alignment) is well inside the drift of dead reckoning."""
    run, dr = window
    ate, rmse = [], []
    for seed in range(5):
        res = sl.run_fastslam(run, n_particles=20, rng=np.random.default_rng(seed), known=True)
        score = sl.score_trajectory(res.x_est, run.x_true)
        ate.append(score.ate)
        rmse.append(sl.score_landmarks(res.landmarks, run.landmarks, transform=score, seen=res.seen))
    assert max(ate) < 0.7 * dr.ate, ate
    assert np.median(ate) < 0.5 * dr.ate, ate
    assert np.median(rmse) < 0.6 * dr.ate, rmse


# --------------------------------------------------------------------------- noise calibration and association scoring
def test_calibrate_noise_recovers_white_noise_of_a_simulated_run():
    rng = np.random.default_rng(50)
    landmarks = sl.make_landmark_world(20, extent=20.0, min_separation=2.0, rng=rng)
    M = np.diag([0.08**2, 0.12**2])
    Q = np.diag([0.2**2, 0.03**2])
    run = sl.simulate_landmark_run(landmarks, sl.loop_controls(3000, v=0.8, omega=0.1), 0.1, x0=[0.0, -8.0, 0.0],
                                   M=M, Q=Q, max_range=8.0, fov=np.pi, rng=rng)
    cal = sl.calibrate_noise(run, windows=(10, 30))  # long enough runs of blocks for a 7 % standard error
    assert np.all(np.abs(cal.rho) < 0.1)  # white: consecutive sightings uncorrelated
    np.testing.assert_allclose(np.sqrt(np.diag(cal.Q)), [0.2, 0.03], rtol=0.12)
    np.testing.assert_allclose(np.sqrt(np.diag(cal.M)), [0.08, 0.12], rtol=0.15)
    assert cal.n_outliers == 0 and cal.control_std.shape == (2, 2)


def test_sighting_correlation_of_an_ar1_sequence():
    rng = np.random.default_rng(51)
    n, rho = 4000, 0.8
    e = np.empty((n, 2))
    e[0] = rng.standard_normal(2)
    for k in range(1, n):
        e[k] = rho * e[k - 1] + np.sqrt(1 - rho**2) * rng.standard_normal(2)
    ids = tuple(np.array([0]) for _ in range(n))  # one landmark, one sighting per step
    np.testing.assert_allclose(sl.sighting_correlation(e, ids), rho, atol=0.03)
    # sightings further apart than max_gap are not paired: every other step empty, max_gap=1 leaves nothing
    sparse = tuple(np.array([0]) if k % 2 == 0 else np.array([], dtype=int) for k in range(2 * n))
    with pytest.raises(ValueError, match="fewer than 3 pairs"):
        sl.sighting_correlation(e, sparse, max_gap=1)


def test_calibrated_noise_of_the_shipped_constants():
    cal = sl.calibrate_noise(load_mrclam(1))
    # the loader's constants are robot 1's calibration, rounded
    np.testing.assert_allclose(np.sqrt(np.diag(cal.M)), np.sqrt(np.diag(MRCLAM_M)), rtol=0.05)
    np.testing.assert_allclose(np.sqrt(np.diag(cal.Q)), np.sqrt(np.diag(MRCLAM_Q)), rtol=0.08)
    assert cal.rho[0] > 0.9  # range errors persist over a pass


def test_association_errors_counts_against_majority_labels():
    assoc = (np.array([0, 1]), np.array([0, -1]), np.array([1, 1, 2]))
    truth = (np.array([5, 6]), np.array([5, 7]), np.array([6, 7, 5]))
    # slot 0: labels 5, 5 -> 5; slot 1: 6, 6, 7 -> 6 (one wrong); slot 2: 5 -> 5 (a second copy of 5)
    assert sl.association_errors(assoc, np.arange(3), truth) == (1, 6, 1)
    with pytest.raises(ValueError, match="one entry per measurement"):
        sl.association_errors(assoc, np.arange(3), truth[:2])


def test_gate_rescues_known_correspondences_on_robot_3():
    run = load_mrclam(3)
    gated = sl.run_ekf_slam(run, known=True)  # the run's gate
    plain = sl.run_ekf_slam(run, known=True, gate=np.inf)
    assert gated.n_gated == 4 and plain.n_gated == 0
    ate_g, ate_p = (sl.score_trajectory(r.x, run.x_true).ate for r in (gated, plain))
    assert ate_g < 0.3 < ate_p


def test_gate_rescues_ekf_localization_on_robot_3():
    run = load_mrclam(3, t_max=300.0)  # its four gross outliers come 255 s in
    gated = sl.ekf_localization_run(run)  # known correspondences, the run's gate
    plain = sl.ekf_localization_run(run, gate=np.inf)
    assert gated.n_gated == 4 and plain.n_gated == 0
    after = slice(2600, None)  # after the outliers
    err_g = sl.ate_rmse(gated.mu[after], run.x_true[after])
    err_p = sl.ate_rmse(plain.mu[after], run.x_true[after])
    assert err_g < 0.25 and err_p > 2 * err_g


# --------------------------------------------------------------------------- generalisation study and table
def _tool(name):
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, ROOT / "tools" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_misread_relabels_the_share_asked_and_keeps_the_measurements(run1):
    study = _tool("mrclam_assoc_study")
    bad = study.misread(run1, 0.1, np.random.default_rng(0))
    changed = np.concatenate([b != a for b, a in zip(bad.ids, run1.ids)])
    assert changed.sum() == round(0.1 * run1.n_sightings)
    assert all(b.min(initial=0) >= 0 and b.max(initial=0) < 15 for b in bad.ids)
    assert bad.z is run1.z  # ranges and bearings are those of the landmark actually seen
    assert all(np.array_equal(a, b) for a, b in zip(run1.ids, load_mrclam(1).ids))  # the input is untouched


def test_ambiguity_counts_sightings_nearer_another_landmark(run1):
    study = _tool("mrclam_assoc_study")
    amb, nearer = study.ambiguity(run1, np.diag([0.12**2, 0.02**2]), sl.DEFAULT_ALPHA)
    assert 0 <= nearer <= amb <= 1 and amb > 0.5  # tubes 0.2 m apart: most sightings fit a neighbour
    # a sensor 100 times more precise resolves the tubes
    amb_fine, nearer_fine = study.ambiguity(run1, np.diag([0.0012**2, 0.0002**2]), sl.DEFAULT_ALPHA)
    assert amb_fine < 0.05
    assert nearer_fine == nearer  # which landmark is nearer does not depend on the scale of the noise


def test_fastslam_counter_keeps_landmarks_that_misread_barcodes_would_lose():
    # robot 3's first four minutes with a tenth of the sightings relabelled: with the gate alone a misread
    # first sighting places a landmark for good and every true sighting of it is rejected from then on;
    # the existence counter discards such a landmark and the next sighting re-creates it
    study = _tool("mrclam_assoc_study")
    run = load_mrclam(3, t_max=240.0)
    bad = study.misread(run, 0.1, np.random.default_rng(1003))
    ate, rejected = {}, {}
    for reinit in (False, True):
        fs = [sl.run_fastslam(bad, n_particles=20, rng=np.random.default_rng(s), reinit_lost=reinit) for s in range(3)]
        ate[reinit] = np.median([sl.score_trajectory(f.x_est, run.x_true).ate for f in fs])
        rejected[reinit] = np.median([f.rejected.sum() for f in fs])
    # without the counter: true sightings rejected. Over 19 draws of the misreadings (seeds 1003-1021, filter
    # seeds shifted alike) the ratio was 0.14-0.26. The path's error is no per-draw criterion: the counter's
    # median was the lower in 15 of the 19 (ratios 0.25-1.43), so it is only reported here
    assert rejected[True] < 0.5 * rejected[False], (rejected, ate)


def test_table_and_study_files_report_fastslam_over_ten_seeds_with_failures_counted():
    table = json.loads((ROOT / "chapters" / "data" / "mrclam_table.json").read_text())
    assert table["seeds"] == 10 and set(table["robots"]) == {str(k) for k in MRCLAM_ROBOTS}
    for d in table["robots"].values():
        for v in (1, 2):
            r = d["rows"][f"FastSLAM {v}.0, known"]
            ate = np.array(r["per_seed_ate"])
            assert r["n_seeds"] == ate.size == 10
            assert r["n_failed"] == int(np.sum(ate > table["fail_ate"]))
            assert r["ate"] == pytest.approx(np.median(ate)) and r["ate_min"] == ate.min() and r["ate_max"] == ate.max()
    study = json.loads((ROOT / "chapters" / "data" / "mrclam_assoc_study.json").read_text())
    assert set(study["association"]) == {str(k) for k in MRCLAM_ROBOTS}
    for case in study["fastslam"]["cases"].values():
        for name, r in case.items():
            if isinstance(r, dict):
                assert r["n_failed"] == int(np.sum(np.array(r["per_seed_ate"]) > study["fail_ate"]))
