"""Zero-size inputs across the library: the valid ones work, the others are refused with a message that names
the argument (never an error from inside NumPy)."""
import numpy as np
import pytest

import slamlib as sl


def test_nees_of_an_empty_batch_is_empty():
    np.testing.assert_array_equal(sl.nees(np.zeros((0, 3)), np.zeros((0, 3, 3))), np.zeros(0))


def test_a_run_of_no_control_has_no_measurement_step():
    L = sl.make_landmark_world(6, extent=10.0, min_separation=2.0, rng=np.random.default_rng(0))
    M, Q = np.diag([0.01, np.deg2rad(3) ** 2]), np.diag([0.01, np.deg2rad(2) ** 2])
    run = sl.simulate_landmark_run(L, np.zeros((0, 2)), 0.1, x0=[0.0, -6.7, 0.0], M=M, Q=Q,
                                   rng=np.random.default_rng(0))
    assert len(run.u) == len(run.z) == len(run.ids) == 0 and run.x_true.shape == (1, 3)
    assert len(sl.add_clutter(run, 0.5, rng=np.random.default_rng(0), max_range=5.0).z) == 0
    res = sl.ekf_localization_run(run)  # and what consumes it runs (no step)
    assert res is not None


def test_kf_update_with_no_measurement_leaves_the_belief():
    g = sl.kf_update(np.array([1.0, 2.0]), np.diag([2.0, 3.0]), np.zeros(0), np.zeros((0, 2)), np.zeros((0, 0)))
    np.testing.assert_array_equal(g.mean, [1.0, 2.0])
    np.testing.assert_array_equal(g.cov, np.diag([2.0, 3.0]))


def test_a_fastslam_set_of_no_particle_is_refused_naming_the_state():
    st = sl.FastSLAMState(np.zeros((0, 3)), np.zeros((0, 4, 2)), np.zeros((0, 4, 2, 2)), np.zeros((0, 4), bool),
                          np.zeros((0, 4), np.int64), np.zeros(0))
    Q = np.diag([0.01, 0.001])
    for call in (lambda: sl.fastslam_update_known(st, np.array([[2.0, 0.1]]), np.array([0]), Q),
                 lambda: sl.fastslam_update_unknown(st, np.array([[2.0, 0.1]]), Q),
                 lambda: sl.fastslam_resample(st, rng=np.random.default_rng(0)),
                 lambda: sl.fastslam_estimate(st)):
        with pytest.raises(ValueError, match="state must hold at least one particle"):
            call()


def test_an_empty_scan_leaves_every_cell_at_the_prior():
    out = sl.inverse_range_sensor_model(np.array([[20.0, 20.0], [2.5, 2.0]]), np.array([2.0, 2.0, 0.0]), np.zeros(0),
                                        np.zeros(0), z_max=5.0)
    np.testing.assert_array_equal(out, np.full(2, sl.OccupancyParams().l0))


def test_poses_at_scans_needs_a_keyframe_only_when_scans_are_asked_for():
    odo = np.c_[np.linspace(1, 3, 5), np.full(5, 2.0), np.zeros(5)]
    with pytest.raises(ValueError, match="key_index must hold at least one keyframe"):
        sl.poses_at_scans(np.zeros(0, int), np.zeros((0, 3)), odo, np.arange(5))
    assert sl.poses_at_scans(np.zeros(0, int), np.zeros((0, 3)), odo, np.zeros(0, int)).shape == (0, 3)


def test_a_map_of_no_scan_needs_its_grid():
    angles = np.linspace(-1.5, 1.5, 30)
    with pytest.raises(ValueError, match="poses must hold at least one pose to size the map, or give spec"):
        sl.occupancy_grid_mapping(np.zeros((0, 3)), np.zeros((0, 30)), angles, z_max=5.0)


def test_noise_calibration_of_a_run_without_sightings_is_refused_naming_the_run():
    L = sl.make_landmark_world(6, extent=10.0, min_separation=2.0, rng=np.random.default_rng(0))
    M, Q = np.diag([0.01, np.deg2rad(3) ** 2]), np.diag([0.01, np.deg2rad(2) ** 2])
    for u in (np.zeros((0, 2)), np.tile([0.5, 0.0], (20, 1))):
        run = sl.simulate_landmark_run(L, u, 0.1, x0=[0.0, -6.7, 0.0], M=M, Q=Q, max_range=1e-3,
                                       rng=np.random.default_rng(0))
        with pytest.raises(ValueError, match="run must hold at least 3 landmark sightings"):
            sl.calibrate_noise(run)


def test_a_pose_graph_of_no_edge_has_the_empty_sum_as_its_system():
    """H and b are sums over the edges: with none they are zero (and a single pose needs no step); with more poses
    than one the graph is refused as disconnected, naming what is missing."""
    empty = (np.zeros((0, 2), np.int64), np.zeros((0, 3)), np.zeros((0, 3, 3)))
    for n in (1, 4):
        H, b = sl.build_linear_system(np.zeros((n, 3)), *empty)
        np.testing.assert_array_equal(H.toarray(), np.zeros((3 * n, 3 * n)))
        np.testing.assert_array_equal(b, np.zeros(3 * n))
    X = np.array([[1.0, 2.0, 0.5]])
    np.testing.assert_array_equal(sl.gauss_newton_step(X, *empty), X)
    with pytest.raises(ValueError, match="disconnected"):
        sl.gauss_newton_step(np.zeros((4, 3)), *empty)


def test_a_lidar_log_of_fewer_than_two_scans_is_refused_naming_the_poses():
    angles = np.linspace(-1.5, 1.5, 30)
    for n in (0, 1):
        with pytest.raises(ValueError, match="odom_poses must hold at least two poses.*got %d" % n):
            sl.run_lidar_slam(np.zeros((n, 3)), np.ones((n, 30)), angles, z_max=8.0)
