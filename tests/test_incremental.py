"""Incremental smoothing: odometry composes, a loop closure re-solves the part of the path it closes and carries
the change further back only where it exceeds the threshold; arrival-order checks; gtsam.ISAM2 as the reference."""

from __future__ import annotations

import numpy as np
import pytest

import slamlib as sl
from slamlib.datasets import load_city10000, load_m3500
from slamlib.incremental import arrival_order, incremental_pose_graph


def _first_poses(g, n):
    """The edges of the first n poses of a graph, in arrival order."""
    keep = (g.edges < n).all(axis=1)
    edges, Z, W = g.edges[keep], g.Z[keep], g.Omega[keep]
    o = arrival_order(edges)
    return edges[o], Z[o], W[o]


def _batch_chi2(edges, Z, W):
    n = int(edges.max()) + 1
    return sl.optimize_pose_graph(sl.pose_graph_initial_guess(n, edges, Z), edges, Z, W).chi2[-1]


def test_odometry_only_is_dead_reckoning_and_costs_no_solve():
    rng = np.random.default_rng(0)
    n = 50
    edges = np.column_stack([np.arange(n - 1), np.arange(1, n)])
    Z = np.column_stack([rng.uniform(0.5, 1.0, n - 1), rng.normal(0, 0.1, n - 1), rng.normal(0, 0.2, n - 1)])
    W = np.broadcast_to(np.eye(3) * 100, (n - 1, 3, 3)).copy()
    res = incremental_pose_graph(edges, Z, W)
    np.testing.assert_allclose(res.X, sl.pose_graph_initial_guess(n, edges, Z), atol=1e-12)
    assert res.chi2 < 1e-20 and res.batch_steps.size == 0 and res.step_time.shape == (n - 1,)
    assert not res.solved.any()


def test_arrival_order_puts_each_edge_after_the_odometry_of_its_newer_pose():
    edges = np.array([[2, 0], [1, 2], [0, 1], [3, 1], [2, 3]])
    o = arrival_order(edges)
    np.testing.assert_array_equal(edges[o], [[0, 1], [1, 2], [2, 0], [2, 3], [3, 1]])
    with pytest.raises(ValueError, match="edges"):
        arrival_order(np.array([[0, 0]]))


def test_m3500_incremental_ends_within_a_percent_of_the_batch_optimum():
    # M3500 took no part in the choice of the threshold (the first 5000 poses of City10000 did)
    edges, Z, W = _first_poses(load_m3500(), 1200)
    res = incremental_pose_graph(edges, Z, W, snapshot_steps=(100, len(edges) - 1))
    assert res.chi2 <= 1.01 * _batch_chi2(edges, Z, W)
    np.testing.assert_allclose(res.snapshots[len(edges) - 1], res.X, atol=0)
    assert res.snapshots[100].shape[0] == edges[:101].max() + 1


def test_city10000_prefix_within_a_percent_of_batch_where_holding_the_old_part_is_not():
    edges, Z, W = _first_poses(load_city10000().graph, 1500)
    batch = _batch_chi2(edges, Z, W)
    res = incremental_pose_graph(edges, Z, W)
    assert res.chi2 <= 1.01 * batch
    # holding everything older than the closure's span, however far the change reaches, leaves the old part behind
    held = incremental_pose_graph(edges, Z, W, threshold=1e9)
    assert held.chi2 > 1.005 * batch


def test_the_re_solved_part_grows_only_where_the_change_exceeds_the_threshold():
    edges, Z, W = _first_poses(load_m3500(), 600)
    closure = edges[:, 1] != edges[:, 0] + 1
    n_so_far = np.maximum.accumulate(edges.max(axis=1)) + 1
    span = n_so_far - np.maximum(1, np.minimum(edges.min(axis=1), n_so_far - 60))
    held = incremental_pose_graph(edges, Z, W, threshold=1e9)
    np.testing.assert_array_equal(held.solved[closure], span[closure])  # never more than the closure's span
    tight = incremental_pose_graph(edges, Z, W, threshold=1e-12)
    default = incremental_pose_graph(edges, Z, W)
    assert np.all(held.solved <= default.solved) and np.all(default.solved <= tight.solved)
    assert 0 < default.batch_steps.size < tight.batch_steps.size
    # a whole-graph update moves every pose but the first
    np.testing.assert_array_equal(tight.solved[tight.batch_steps], n_so_far[tight.batch_steps] - 1)


def test_an_edge_to_a_pose_not_yet_introduced_is_refused():
    edges = np.array([[0, 1], [1, 3], [1, 2]])
    with pytest.raises(ValueError, match=r"edges\[1\] = \[1, 3\] uses pose 3 before the odometry edge \(1, 2\)"):
        incremental_pose_graph(edges, np.zeros((3, 3)), np.broadcast_to(np.eye(3), (3, 3, 3)))
    with pytest.raises(ValueError, match="window"):
        incremental_pose_graph(edges[:1], np.zeros((1, 3)), np.eye(3)[None], window=0)
    with pytest.raises(ValueError, match="threshold"):
        incremental_pose_graph(edges[:1], np.zeros((1, 3)), np.eye(3)[None], threshold=0.0)


def test_city10000_loader_arrival_order_and_truth():
    c = load_city10000()
    g = c.graph
    assert (g.n_poses, g.n_edges) == (10000, 20687) and c.truth.shape == (10000, 3)
    assert int((c.n_hypotheses == 2).sum()) == 200
    odo = g.edges[:, 1] == g.edges[:, 0] + 1
    assert odo.sum() == 9999
    np.testing.assert_allclose(np.diag(g.Omega[0]), [900.0, 900.0, 10000.0])
    np.testing.assert_array_equal(arrival_order(g.edges), np.arange(g.n_edges))


def test_city10000_prefix_ends_where_gtsam_isam2_ends():
    gtsam = pytest.importorskip("gtsam")
    edges, Z, W = _first_poses(load_city10000().graph, 800)
    res = incremental_pose_graph(edges, Z, W)
    isam = gtsam.ISAM2(gtsam.ISAM2Params())
    graph, vals = gtsam.NonlinearFactorGraph(), gtsam.Values()
    graph.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(0, 0, 0), gtsam.noiseModel.Diagonal.Sigmas(np.full(3, 1e-4))))
    vals.insert(0, gtsam.Pose2(0, 0, 0))
    isam.update(graph, vals)
    for (i, j), z, w in zip(edges, Z, W):
        graph, vals = gtsam.NonlinearFactorGraph(), gtsam.Values()
        graph.add(gtsam.BetweenFactorPose2(int(i), int(j), gtsam.Pose2(*z), gtsam.noiseModel.Gaussian.Information(w)))
        if not isam.valueExists(int(j)):
            vals.insert(int(j), isam.calculateEstimate().atPose2(int(i)).compose(gtsam.Pose2(*z)))
        isam.update(graph, vals)
    est = isam.calculateEstimate()
    Xg = np.array([[est.atPose2(k).x(), est.atPose2(k).y(), est.atPose2(k).theta()] for k in range(res.X.shape[0])])
    chi2_g = sl.pose_graph_chi2(Xg, edges, Z, W)
    assert abs(res.chi2 / chi2_g - 1) < 0.01
