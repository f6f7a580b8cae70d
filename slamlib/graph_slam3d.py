"""Pose-graph SLAM in 3-D: poses on SE(3), solved by the sparse machinery of :mod:`slamlib.graph_slam`.

A pose is ``T_i = [[R_i, t_i], [0, 1]] (4, 4)``; an edge ``k = (i, j)`` measures pose ``j``
seen from pose ``i`` as ``Z_k (4, 4)`` with information ``Omega_k (6, 6)`` over
``[translation, rotation]`` (the order of g2o and TORO files). Its error is the twist that
takes the measurement to the prediction,

``e_k = log(Z_k^-1 T_i^-1 T_j)  (6,)``, ``[rho, phi]`` (:func:`slamlib.lie.se3_log`),

zero when the poses agree with the measurement; this is GTSAM's ``BetweenFactor<Pose3>``
error (with its rotation-first order swapped), so both libraries minimise the same ``chi2``.

On-manifold Gauss-Newton: poses are not vectors, so a step ``dx`` (6 numbers per pose) is
applied by the perturbation ``T (+) delta = (R Exp(phi), t + R rho)``, and the Jacobians are
taken with respect to ``delta`` at ``delta = 0``. With ``J_r^-1`` the inverse right Jacobian
of SE(3) and ``Ad`` the adjoint,

``B = de/d delta_j = J_r^-1(e)``, ``A = de/d delta_i = -J_r^-1(e) Ad(T_j^-1 T_i)``.

Everything else is the 2-D back end unchanged: the same sparse assembly (``6 x 6`` blocks),
fill-reducing ordering, sparse factorisation, Gauss-Newton and Levenberg-Marquardt loop and
robust kernels, the first pose fixed for the gauge.

References
----------
G. Grisetti, R. Kuemmerle, C. Stachniss, W. Burgard, "A tutorial on graph-based SLAM", IEEE
ITS Magazine 2(4), 2010 (Sec. V, non-Euclidean spaces). F. Dellaert, M. Kaess, "Factor graphs
for robot perception", Foundations and Trends in Robotics 6(1-2), 2017 (Sec. 6, on-manifold
optimisation). J. Sola, J. Deray, D. Atchuthan, "A micro Lie theory for state estimation in
robotics", arXiv:1812.01537, 2018 (Sec. IV, Jacobians of compositions and of the logarithm).
L. Carlone, R. Tron, K. Daniilidis, F. Dellaert, "Initialization techniques for 3D SLAM",
ICRA 2015 (the sphere2500 benchmark).
"""

from __future__ import annotations

import time

import numpy as np

from ._checks import (as_count, as_edges, as_index, as_index_set, as_pose_graph3d, as_rigid_motions, as_scalar)
from .graph_slam import (_GAUGE, _chi2_terms, _compose_along_tree, _method_args, _require_connected, _robust_args,
                         _solve_pose_graph, PoseGraphResult)
from .lie import _se3_adjoint, _se3_exp, _se3_inverse, _se3_jr_inv, _se3_log, _so3_log

__all__ = [
    "se3_edge_error",
    "pose_graph3d_errors",
    "pose_graph3d_chi2",
    "pose_graph3d_initial_guess",
    "optimize_pose_graph3d",
    "trajectory_errors3d",
]


def _se3_edges(Ti, Tj, Z):
    """Errors ``log(Z^-1 T_i^-1 T_j)`` and Jacobians of all edges at once (``(E, 6)``, ``(E, 6, 6)`` twice)."""
    Tij = _se3_inverse(Ti) @ Tj
    e = _se3_log(_se3_inverse(Z) @ Tij)
    B = _se3_jr_inv(e)  # d e / d delta_j
    A = -B @ _se3_adjoint(_se3_inverse(Tij))  # d e / d delta_i = -J_r^-1(e) Ad(T_j^-1 T_i)
    return e, A, B


def _update_poses3d(T, dx):
    # T exp(delta): equal to T (+) delta to first order (the same Jacobians), and along the screw motion
    return T @ _se3_exp(dx.reshape(-1, 6))


def se3_edge_error(Ti, Tj, Z):
    """Error and Jacobians of one 3-D relative-pose edge.

    Parameters
    ----------
    Ti, Tj : array_like, shape (4, 4)
        The poses the edge joins.
    Z : array_like, shape (4, 4)
        The measurement: pose ``j`` seen from pose ``i``.

    Returns
    -------
    e : ndarray, shape (6,)
        ``log(Z^-1 T_i^-1 T_j) = [rho, phi]``.
    A, B : ndarray, shape (6, 6)
        ``de/d delta_i`` and ``de/d delta_j`` for the perturbation ``T (+) delta = (R Exp(phi), t + R rho)``.

    References
    ----------
    Sola et al. (2018), Eqs. 79-83 and 179 (Jacobians of ``log`` and of the inverse composition).
    """
    Ti = as_rigid_motions(Ti, "Ti")
    Tj = as_rigid_motions(Tj, "Tj")
    Z = as_rigid_motions(Z, "Z")
    for name, v in (("Ti", Ti), ("Tj", Tj), ("Z", Z)):
        if v.shape != (4, 4):
            raise ValueError(f"{name} must have shape (4, 4), got {v.shape}")
    e, A, B = _se3_edges(Ti[None], Tj[None], Z[None])
    return e[0], A[0], B[0]


def pose_graph3d_errors(T, edges, Z):
    """Errors and Jacobians of all edges of a 3-D pose graph, computed at once.

    Parameters
    ----------
    T : ndarray, shape (n, 4, 4)
        Poses.
    edges : int ndarray, shape (E, 2)
        Index pairs.
    Z : ndarray, shape (E, 4, 4)
        Measurements.

    Returns
    -------
    e : ndarray, shape (E, 6)
    A, B : ndarray, shape (E, 6, 6)
        Row ``k`` equals :func:`se3_edge_error` ``(T[i], T[j], Z[k])`` for ``(i, j) = edges[k]``.
    """
    T = as_rigid_motions(T, "T")
    if T.ndim != 3:
        raise ValueError(f"T must have shape (n, 4, 4), got {T.shape}")
    edges = as_edges(edges, "edges", T.shape[0])
    Z = as_rigid_motions(Z, "Z")
    if Z.shape != (edges.shape[0], 4, 4):
        raise ValueError(f"Z must have shape ({edges.shape[0]}, 4, 4) (to match edges), got {Z.shape}")
    return _se3_edges(T[edges[:, 0]], T[edges[:, 1]], Z)


def pose_graph3d_chi2(T, edges, Z, Omega):
    """``chi2 = sum_k e_k^T Omega_k e_k`` of a 3-D pose graph (twice GTSAM's graph error).

    Parameters
    ----------
    T : ndarray, shape (n, 4, 4)
    edges : int ndarray, shape (E, 2)
    Z : ndarray, shape (E, 4, 4)
    Omega : ndarray, shape (E, 6, 6)
        Information matrices over ``[translation, rotation]``.

    Returns
    -------
    float
    """
    T, edges, Z, Omega = as_pose_graph3d(T, edges, Z, Omega)
    e, _, _ = _se3_edges(T[edges[:, 0]], T[edges[:, 1]], Z)
    return float(_chi2_terms(e, Omega).sum())


def pose_graph3d_initial_guess(n, edges, Z, *, root=0, T_root=None):
    """Initial guess by composing the measurements along a spanning tree (the odometry guess in 3-D).

    The same tree as :func:`slamlib.graph_slam.pose_graph_initial_guess` (the minimum spanning
    tree with weights ``|i - j|``: the odometry chain where there is one), each pose the product
    of the measurements along its path.

    Parameters
    ----------
    n : int
        Number of poses.
    edges : int ndarray, shape (E, 2)
    Z : ndarray, shape (E, 4, 4)
    root : int, keyword-only
        The pose the tree grows from.
    T_root : ndarray, shape (4, 4), optional, keyword-only
        Pose given to `root` (default the identity).

    Returns
    -------
    ndarray, shape (n, 4, 4)
    """
    n = as_count(n, "n", minimum=1)
    edges = as_edges(edges, "edges", n)
    Z = as_rigid_motions(Z, "Z")
    if Z.shape != (edges.shape[0], 4, 4):
        raise ValueError(f"Z must have shape ({edges.shape[0]}, 4, 4) (to match edges), got {Z.shape}")
    root = as_index(root, "root", n)
    T_root = np.eye(4) if T_root is None else as_rigid_motions(T_root, "T_root")
    if T_root.shape != (4, 4):
        raise ValueError(f"T_root must have shape (4, 4), got {T_root.shape}")
    _require_connected(n, edges, (root,))
    return _compose_along_tree(n, edges, Z, _se3_inverse(Z), root, T_root, np.matmul)


def optimize_pose_graph3d(T0, edges, Z, Omega, *, method="lm", max_iter=100, rtol=1e-9, robust=None,
                          robust_scale=None, fixed=(0,), lm_lambda=1e-7):
    """Maximum a posteriori poses of a 3-D pose graph by on-manifold Gauss-Newton or Levenberg-Marquardt.

    Minimises ``sum_k rho(e_k^T Omega_k e_k)``, ``e_k = log(Z_k^-1 T_i^-1 T_j)``, over the
    poses; each step ``dx (6 n)`` is applied as ``T (+) delta``. The solver, damping, stopping
    rule and robust kernels are those of :func:`slamlib.graph_slam.optimize_pose_graph`.

    Parameters
    ----------
    T0 : ndarray, shape (n, 4, 4)
        Initial guess (e.g. :func:`pose_graph3d_initial_guess`).
    edges : int ndarray, shape (E, 2)
    Z : ndarray, shape (E, 4, 4)
        Relative-pose measurements: pose ``j`` seen from pose ``i``.
    Omega : ndarray, shape (E, 6, 6)
        Information matrices over ``[translation, rotation]``, symmetric positive definite.
    method, max_iter, rtol, robust, fixed, lm_lambda : keyword-only
        As in :func:`slamlib.graph_slam.optimize_pose_graph`.
    robust_scale : float, optional, keyword-only
        Kernel width on ``sqrt(e^T Omega e)``; default ``sqrt(chi2_6(0.95)) = 3.55``.

    Returns
    -------
    PoseGraphResult
        ``X`` holds the optimised poses ``(n, 4, 4)``.

    References
    ----------
    Grisetti et al. (2010), Sec. V; Dellaert & Kaess (2017), Sec. 6.
    """
    start = time.perf_counter()
    T0, edges, Z, Omega = as_pose_graph3d(T0, edges, Z, Omega, ("T0", "edges", "Z", "Omega"))
    max_iter, rtol = _method_args(method, max_iter, rtol)
    robust, k = _robust_args(robust, robust_scale, 6)
    fixed = as_index_set(fixed, "fixed", T0.shape[0], what="pose", why=_GAUGE)
    _require_connected(T0.shape[0], edges, fixed)
    return _solve_pose_graph(T0, edges, Z, Omega, 6, _se3_edges, _update_poses3d, start=start, method=method,
                             max_iter=max_iter, rtol=rtol, robust=robust, k=k, fixed=fixed,
                             lm_lambda=as_scalar(lm_lambda, "lm_lambda", positive=True))


def trajectory_errors3d(T, T_true):
    """Per-pose translation and rotation errors of 3-D poses against the truth (no alignment).

    Both trajectories are compared as given: with the first pose fixed at its true value (the
    gauge of :func:`optimize_pose_graph3d` when the guess starts there) no alignment is needed.

    Parameters
    ----------
    T, T_true : ndarray, shape (n, 4, 4)

    Returns
    -------
    trans : ndarray, shape (n,)
        ``|t_i - t_i^true|``.
    rot : ndarray, shape (n,)
        The angle of ``R_i^true^T R_i`` (radians).
    """
    T = as_rigid_motions(T, "T")
    T_true = as_rigid_motions(T_true, "T_true")
    if T.ndim != 3 or T.shape != T_true.shape:
        raise ValueError(f"T and T_true must have the same shape (n, 4, 4), got {T.shape} and {T_true.shape}")
    trans = np.linalg.norm(T[:, :3, 3] - T_true[:, :3, 3], axis=1)
    rot = np.linalg.norm(_so3_log(np.swapaxes(T_true[:, :3, :3], 1, 2) @ T[:, :3, :3]), axis=1)
    return trans, rot
