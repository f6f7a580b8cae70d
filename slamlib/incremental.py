"""Incremental smoothing: a pose graph solved as each measurement arrives.

A robot does not get its pose graph at the end: odometry and loop closures arrive one by one,
and it needs its best estimate of the whole path *now*, after every one. Re-solving the whole
graph after every measurement costs a sparse factorisation of a growing system each time.
Incremental smoothing spends work only where the new measurement changes the solution
{Kaess et al. 2008 (iSAM), 2012 (iSAM2)}. This module does it with three rules, each a use of the
batch solver of :mod:`slamlib.graph_slam` on a part of the graph:

1. **Odometry** (``j = i + 1``, a new pose ``j``): the new pose is composed,
   ``x_j = x_i (+) z``. Nothing else moves: the new edge fits exactly and touches no other
   pose, so the optimum of the old poses is unchanged. This costs microseconds.
2. **Loop closure** (an edge between two existing poses): the newest ``window`` poses are
   relinearised and re-solved (Gauss-Newton) with every edge that touches them; the older poses
   those edges reach are held fixed, as anchors. The correction of a closure spreads first over
   the recent part of the path, where it matters most.
3. **Periodic batch**: when the number of edges has grown by the fraction ``growth`` since the
   last full solve, the whole graph is relinearised and re-solved from the current estimate
   (warm start, a few Gauss-Newton iterations). The full solves are spaced geometrically, so
   their total cost is about ``1 + 1/growth`` times that of one full solve of the final graph,
   and the estimate of the old part never lags by more than that fraction of the data.

The first pose is fixed (the gauge). Every step's wall time is recorded.

References
----------
M. Kaess, A. Ranganathan, F. Dellaert, "iSAM: Incremental smoothing and mapping", IEEE T-RO
24(6), 2008 (incremental factorisation with periodic batch relinearisation and reordering).
M. Kaess, H. Johannsson, R. Roberts, V. Ila, J. Leonard, F. Dellaert, "iSAM2: Incremental
smoothing and mapping using the Bayes tree", IJRR 31(2), 2012 (relinearising only the variables
that changed: fluid relinearisation).
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from ._checks import as_array, as_count, as_edges, as_information, as_scalar
from .graph_slam import _chi2_terms, _compose, _se2_edges, _solve_pose_graph, _update_poses

__all__ = ["IncrementalResult", "incremental_pose_graph"]


class IncrementalResult(NamedTuple):
    """Result of :func:`incremental_pose_graph`.

    Attributes
    ----------
    X : ndarray, shape (n, 3)
        The estimate after the last measurement.
    step_time : ndarray, shape (E,)
        Wall-clock seconds spent on each measurement (its update of the estimate).
    batch_steps : int ndarray, shape (B,)
        The measurements after which the whole graph was re-solved.
    chi2 : float
        ``sum e^T Omega e`` of `X` over all edges.
    snapshots : dict of int -> ndarray
        The estimate after the measurements asked for (``snapshot_steps``), poses so far.
    """

    X: np.ndarray
    step_time: np.ndarray
    batch_steps: np.ndarray
    chi2: float
    snapshots: dict


def _solve(X, edges, Z, Omega, fixed, max_iter, rtol):
    res = _solve_pose_graph(X, edges, Z, Omega, 3, _se2_edges, _update_poses, start=0.0, method="gn",
                            max_iter=max_iter, rtol=rtol, robust=None, k=1.0, fixed=fixed, lm_lambda=1e-7)
    return res.X


def incremental_pose_graph(edges, Z, Omega, *, window=60, growth=0.1, local_iter=1, batch_iter=3,
                           rtol=1e-6, snapshot_steps=()):
    """Solve a 2-D pose graph incrementally, one measurement at a time, in the given order.

    Parameters
    ----------
    edges : int ndarray, shape (E, 2)
        Index pairs in arrival order. An edge ``(i, i + 1)`` whose ``i + 1`` is the next new
        pose introduces it (odometry); every other edge must join poses already introduced.
        Pose 0 exists from the start, at the origin, and stays fixed.
    Z : ndarray, shape (E, 3)
        Relative-pose measurements.
    Omega : ndarray, shape (E, 3, 3)
        Information matrices.
    window : int, keyword-only
        Poses relinearised and re-solved after a loop closure (the newest ones).
    growth : float, keyword-only
        Fraction by which the number of edges grows between two full solves.
    local_iter, batch_iter : int, keyword-only
        Gauss-Newton iterations of a window solve and of a full solve.
    rtol : float, keyword-only
        Relative chi2 change that ends a full solve early.
    snapshot_steps : sequence of int, keyword-only
        Measurements after which to keep a copy of the estimate.

    Returns
    -------
    IncrementalResult

    Raises
    ------
    ValueError
        If an edge refers to a pose not yet introduced (naming the edge), or on malformed inputs.

    References
    ----------
    Kaess, Ranganathan & Dellaert (2008); Kaess et al. (2012).
    """
    edges = as_edges(edges, "edges", np.iinfo(np.int64).max)
    E = edges.shape[0]
    Z = as_array(Z, "Z", (E, 3))
    Omega = as_information(Omega, "Omega", E, 3)
    window = as_count(window, "window", minimum=1)
    growth = as_scalar(growth, "growth", positive=True)
    local_iter = as_count(local_iter, "local_iter", minimum=1)
    batch_iter = as_count(batch_iter, "batch_iter", minimum=1)
    rtol = as_scalar(rtol, "rtol", nonnegative=True)
    snaps = {int(s) for s in snapshot_steps}
    n_total = int(edges.max()) + 1 if E else 1
    # the pose each edge introduces (-1: none); every pose is introduced before it is used
    introduces = np.where(edges[:, 1] == edges[:, 0] + 1, edges[:, 1], -1)
    intro_at = np.full(n_total, -1, dtype=np.int64)
    seen = 1
    for k in range(E):  # validation only: a cheap pass over integers
        if introduces[k] == seen:
            intro_at[seen] = k
            seen += 1
        elif edges[k].max() >= seen:
            raise ValueError(f"edges[{k}] = {edges[k].tolist()} uses pose {int(edges[k].max())} before the odometry "
                             f"edge ({seen - 1}, {seen}) introduces it")
    X = np.zeros((n_total, 3))
    step_time = np.zeros(E)
    batch_steps = []
    snapshots = {}
    n = 1
    next_batch = max(10, int(np.ceil(window * 1.5)))
    hi_end = edges.max(axis=1)
    for k in range(E):
        t0 = time.perf_counter()
        i, j = int(edges[k, 0]), int(edges[k, 1])
        if j == n and introduces[k] == n:
            X[n] = _compose(X[i], Z[k])  # odometry: x_j = x_i (+) z, the optimum of the rest unchanged
            n += 1
        elif k + 1 >= next_batch:
            pass  # the full solve below takes this closure into account
        else:
            # loop closure: re-solve the newest `window` poses with every edge that touches them
            lo = max(1, n - window)
            first = intro_at[lo]
            sel = first + np.flatnonzero(hi_end[first:k + 1] >= lo)
            sub = edges[sel]
            ids = np.unique(sub)
            local = np.searchsorted(ids, sub)
            fixed = tuple(np.flatnonzero(ids < lo).tolist())
            X[ids] = _solve(X[ids], local, Z[sel], Omega[sel], fixed, local_iter, 0.0)
        if k + 1 >= next_batch:
            X[:n] = _solve(X[:n], edges[:k + 1], Z[:k + 1], Omega[:k + 1], (0,), batch_iter, rtol)
            batch_steps.append(k)
            next_batch = int(np.ceil((k + 1) * (1.0 + growth)))
        step_time[k] = time.perf_counter() - t0
        if k in snaps:
            snapshots[k] = X[:n].copy()
    e, _, _ = _se2_edges(X[edges[:, 0]], X[edges[:, 1]], Z)
    return IncrementalResult(X=X, step_time=step_time, batch_steps=np.array(batch_steps, dtype=np.int64),
                             chi2=float(_chi2_terms(e, Omega).sum()), snapshots=snapshots)
