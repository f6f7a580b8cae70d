"""Incremental smoothing: a pose graph solved as each measurement arrives.

A robot does not get its pose graph at the end: odometry and loop closures arrive one by one,
and it needs its best estimate of the whole path *now*, after every one. Re-solving the whole
graph after every measurement costs a sparse factorisation of a growing system each time.
Incremental smoothing spends work only where the new measurement changes the solution
{Kaess et al. 2008 (iSAM), 2012 (iSAM2)}. This module does it with two rules:

1. **Odometry** (``j = i + 1``, a new pose ``j``): the new pose is composed,
   ``x_j = x_i (+) z``. Nothing else moves: the new edge fits exactly and touches no other
   pose, so the optimum of the old poses is unchanged. This costs microseconds.
2. **Loop closure** (an edge between two existing poses ``i < j``): the poses from
   ``min(i, n - window)`` to the newest, the part of the path the closure closes, are
   relinearised and moved by one Gauss-Newton step with every edge that touches them; the older
   poses those edges reach (the *separator*'s other side) are held. If a free pose next to a
   held one moved by more than ``threshold`` (largest of ``|dx|, |dy|, |dtheta|``), the held part
   would have moved too: the re-solved part is doubled back towards the first pose and the step
   repeated, until the poses next to the held ones move less than ``threshold`` or the whole
   graph is re-solved. This is iSAM2's rule in the language of a batch solver: re-eliminate
   the part of the graph the new measurement reaches, and carry the change further only where
   it exceeds a threshold (its "wildfire" threshold on the change of a variable).

The first pose is fixed (the gauge). Every step's wall time is recorded.

References
----------
M. Kaess, A. Ranganathan, F. Dellaert, "iSAM: Incremental smoothing and mapping", IEEE T-RO
24(6), 2008 (incremental factorisation with periodic batch relinearisation and reordering).
M. Kaess, H. Johannsson, R. Roberts, V. Ila, J. Leonard, F. Dellaert, "iSAM2: Incremental
smoothing and mapping using the Bayes tree", IJRR 31(2), 2012, Algorithms 5-7 (relinearising
and re-solving only variables whose change exceeds a threshold: fluid relinearisation, partial
state updates).
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np
from scipy.sparse.linalg import splu

from ._checks import as_array, as_count, as_edges, as_information, as_scalar
from .angles import wrap_angle
from .graph_slam import compose, pose_graph_chi2, pose_graph_system

__all__ = ["IncrementalResult", "arrival_order", "incremental_pose_graph"]


class IncrementalResult(NamedTuple):
    """Result of :func:`incremental_pose_graph`.

    Attributes
    ----------
    X : ndarray, shape (n, 3)
        The estimate after the last measurement.
    step_time : ndarray, shape (E,)
        Wall-clock seconds spent on each measurement (its update of the estimate).
    solved : int ndarray, shape (E,)
        Poses moved by each measurement's update (0 for odometry, which only adds a pose).
    batch_steps : int ndarray, shape (B,)
        The measurements whose update reached the first pose: the whole graph re-solved.
    chi2 : float
        ``sum e^T Omega e`` of `X` over all edges.
    snapshots : dict of int -> ndarray
        The estimate after the measurements asked for (``snapshot_steps``), poses so far.
    """

    X: np.ndarray
    step_time: np.ndarray
    solved: np.ndarray
    batch_steps: np.ndarray
    chi2: float
    snapshots: dict


def arrival_order(edges):
    """The order in which a robot would receive the edges of a pose graph recorded along its path.

    Each edge arrives with the newer of its two poses; among the edges of one new pose the
    odometry edge ``(j - 1, j)``, which introduces it, comes first.

    Parameters
    ----------
    edges : int ndarray, shape (E, 2)
        Index pairs, poses numbered along the path.

    Returns
    -------
    int ndarray, shape (E,)
        ``edges[order]`` is in arrival order (a stable sort: ties keep their order).
    """
    edges = as_edges(edges, "edges", np.iinfo(np.int64).max)
    odometry = edges[:, 1] == edges[:, 0] + 1
    return np.lexsort((~odometry, edges.max(axis=1)))


def _gauss_newton_part(X, edges, Z, Omega, free):
    """One Gauss-Newton step of the poses where the boolean mask `free` is true, the others held.

    ``H dx = -b`` is :func:`~slamlib.graph_slam.pose_graph_system`'s, with the held poses
    fixed: the same errors, Jacobians and assembly as the batch solver's. Returns the new poses
    of all rows of `X`.
    """
    H, b, _ = pose_graph_system(X, edges, Z, Omega, fixed=np.flatnonzero(~free))
    # H dx = -b  (Grisetti et al. 2010, Algorithm 1 line 13); H is symmetric positive definite: no pivoting
    dx = splu(H, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
              options={"SymmetricMode": True}).solve(-b).reshape(-1, 3)
    out = X.copy()
    out[free] += dx  # pose_graph_system keeps the free poses in their order
    out[free, 2] = wrap_angle(out[free, 2])
    return out


def _arrival(edges):
    """The measurement that introduces each pose; raises on an edge that uses a pose before that."""
    E = edges.shape[0]
    n_total = int(edges.max()) + 1 if E else 1
    intro_at = np.full(n_total, -1, dtype=np.int64)
    odometry = edges[:, 1] == edges[:, 0] + 1
    seen = 1
    for k in range(E):  # a cheap pass over integers
        if odometry[k] and edges[k, 1] == seen:
            intro_at[seen] = k
            seen += 1
        elif edges[k].max() >= seen:
            raise ValueError(f"edges[{k}] = {edges[k].tolist()} uses pose {int(edges[k].max())} before the odometry "
                             f"edge ({seen - 1}, {seen}) introduces it")
    return intro_at


def incremental_pose_graph(edges, Z, Omega, *, window=60, threshold=0.01, snapshot_steps=()):
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
        The newest poses re-solved after a loop closure at least (more if the closure reaches
        further back).
    threshold : float, keyword-only
        Largest change (``max |dx|, |dy|, |dtheta|``, metres and radians) of a re-solved pose next
        to a held one that leaves the held part held; a larger change doubles the re-solved part.
        The default was chosen on the first 5000 poses of City10000 (``tools/incremental_city10000.py
        --select``): the largest of 0.1, 0.03, 0.01 and 0.003 whose chi2 stays within 0.2 % of the
        batch optimum's after every 1000th measurement. It is also iSAM2's relinearisation threshold.
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
    Kaess, Ranganathan & Dellaert (2008); Kaess et al. (2012), Algorithms 5-7.
    """
    edges = as_edges(edges, "edges", np.iinfo(np.int64).max)
    E = edges.shape[0]
    Z = as_array(Z, "Z", (E, 3))
    Omega = as_information(Omega, "Omega", E, 3)
    window = as_count(window, "window", minimum=1)
    threshold = as_scalar(threshold, "threshold", positive=True)
    snaps = {int(s) for s in snapshot_steps}
    intro_at = _arrival(edges)
    n_total = intro_at.size
    X = np.zeros((n_total, 3))
    step_time = np.zeros(E)
    solved = np.zeros(E, dtype=np.int64)
    batch_steps = []
    snapshots = {}
    n = 1
    lo_end, hi_end = edges.min(axis=1), edges.max(axis=1)
    for k in range(E):
        t0 = time.perf_counter()
        i = int(edges[k, 0])
        if intro_at[min(int(edges[k, 1]), n_total - 1)] == k:
            X[n] = compose(X[i], Z[k])  # odometry: x_j = x_i (+) z, the optimum of the rest unchanged
            n += 1
        else:
            # loop closure: re-solve the poses lo..n-1 with every edge that touches them, the rest held
            lo = max(1, min(int(lo_end[k]), n - window))
            while True:
                first = intro_at[lo]  # no earlier edge touches a pose >= lo
                sel = first + np.flatnonzero(hi_end[first:k + 1] >= lo)
                sub = edges[sel]
                ids = np.unique(sub)
                free = ids >= lo
                local = np.searchsorted(ids, sub)
                new = _gauss_newton_part(X[ids], local, Z[sel], Omega[sel], free)
                change = np.abs(new - X[ids])
                change[:, 2] = np.abs(wrap_angle(new[:, 2] - X[ids, 2]))
                X[ids] = new
                if lo == 1:
                    batch_steps.append(k)
                    break
                # the separator: re-solved poses that share an edge with a held one
                cross = (sub < lo).any(axis=1)
                sep = np.searchsorted(ids, sub[cross][sub[cross] >= lo])
                if sep.size == 0 or change[sep].max() <= threshold:
                    break
                lo = max(1, lo - (n - lo))  # the change reaches the held part: double the re-solved part
            solved[k] = n - lo
        step_time[k] = time.perf_counter() - t0
        if k in snaps:
            snapshots[k] = X[:n].copy()
    return IncrementalResult(X=X, step_time=step_time, solved=solved,
                             batch_steps=np.array(batch_steps, dtype=np.int64),
                             chi2=float(pose_graph_chi2(X, edges, Z, Omega)), snapshots=snapshots)
