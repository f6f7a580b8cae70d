"""Incremental smoothing: odometry composes, loop closures re-solve a window, periodic full solves keep
the estimate near the batch optimum; arrival-order checks; gtsam.ISAM2 as the reference on City10000."""

from __future__ import annotations

import numpy as np
import pytest

import slamlib as sl
from slamlib.datasets import load_city10000, load_m3500
from slamlib.incremental import incremental_pose_graph


def _arrival_order(g, n):
    """The edges of the first n poses of a graph in arrival order: by the newest pose they touch, odometry first."""
    keep = (g.edges < n).all(axis=1)
    edges, Z, W = g.edges[keep], g.Z[keep], g.Omega[keep]
    odo = edges[:, 1] == edges[:, 0] + 1
    order = np.lexsort((~odo, edges.max(axis=1)))
    return edges[order], Z[order], W[order]


def test_odometry_only_is_dead_reckoning_and_costs_no_solve():
    rng = np.random.default_rng(0)
    n = 50
    edges = np.column_stack([np.arange(n - 1), np.arange(1, n)])
    Z = np.column_stack([rng.uniform(0.5, 1.0, n - 1), rng.normal(0, 0.1, n - 1), rng.normal(0, 0.2, n - 1)])
    W = np.broadcast_to(np.eye(3) * 100, (n - 1, 3, 3)).copy()
    res = incremental_pose_graph(edges, Z, W, growth=1e9)
    np.testing.assert_allclose(res.X, sl.pose_graph_initial_guess(n, edges, Z), atol=1e-12)
    assert res.chi2 < 1e-20 and res.batch_steps.size == 0 and res.step_time.shape == (n - 1,)


def test_m3500_incremental_ends_near_the_batch_optimum():
    edges, Z, W = _arrival_order(load_m3500(), 1200)
    res = incremental_pose_graph(edges, Z, W, snapshot_steps=(100, len(edges) - 1))
    batch = sl.optimize_pose_graph(sl.pose_graph_initial_guess(1200, edges, Z), edges, Z, W)
    assert res.chi2 <= 1.05 * batch.chi2[-1]
    np.testing.assert_allclose(res.snapshots[len(edges) - 1], res.X, atol=0)
    assert res.snapshots[100].shape[0] == edges[:101].max() + 1
    # the full solves are spaced geometrically: each after the graph grew by the fraction `growth`
    b = res.batch_steps + 1
    assert np.all(b[1:] >= 1.1 * b[:-1] - 1)


def test_window_solves_improve_on_odometry_between_full_solves():
    edges, Z, W = _arrival_order(load_m3500(), 600)
    no_window = incremental_pose_graph(edges, Z, W, window=1, growth=1e9)
    window = incremental_pose_graph(edges, Z, W, window=80, growth=1e9)
    assert window.chi2 < 0.5 * no_window.chi2


def test_an_edge_to_a_pose_not_yet_introduced_is_refused():
    edges = np.array([[0, 1], [1, 3], [1, 2]])
    with pytest.raises(ValueError, match=r"edges\[1\] = \[1, 3\] uses pose 3 before the odometry edge \(1, 2\)"):
        incremental_pose_graph(edges, np.zeros((3, 3)), np.broadcast_to(np.eye(3), (3, 3, 3)))
    with pytest.raises(ValueError, match="window"):
        incremental_pose_graph(edges[:1], np.zeros((1, 3)), np.eye(3)[None], window=0)


def test_city10000_loader_arrival_order_and_truth():
    c = load_city10000()
    g = c.graph
    assert (g.n_poses, g.n_edges) == (10000, 20687) and c.truth.shape == (10000, 3)
    assert int((c.n_hypotheses == 2).sum()) == 200
    odo = g.edges[:, 1] == g.edges[:, 0] + 1
    assert odo.sum() == 9999
    np.testing.assert_allclose(np.diag(g.Omega[0]), [900.0, 900.0, 10000.0])
