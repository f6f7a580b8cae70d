"""3-D pose graphs: the SE(3) edge error and its Jacobians, the solver on a synthetic graph and on
sphere2500 (against its truth and against GTSAM), the g2o/TORO loaders (3-D and TORO 2-D), and the
Levenberg-Marquardt damping on the large 2-D graphs."""

from __future__ import annotations

import numpy as np
import pytest

import slamlib as sl
from slamlib import graph_slam as gs
from slamlib import graph_slam3d as g3
from slamlib import lie
from slamlib.datasets import load_g2o, load_g2o3d, load_sphere2500

try:
    import gtsam
except ImportError:  # the GTSAM comparisons skip without it
    gtsam = None

needs_gtsam = pytest.mark.skipif(gtsam is None, reason="gtsam not installed (the dev extra installs it)")

#: sphere2500 from the odometry guess: the optimum chi2 (GTSAM's LM reaches the same, to 1e-12 relative,
#: in benchmarks/bench_3d.py).
SPHERE_CHI2 = 728.989737181782


def _random_T(rng, n, scale=1.0):
    return lie.se3_exp(np.concatenate([scale * rng.normal(size=(n, 3)), rng.normal(size=(n, 3))], 1))


def _num_jac(f, x0, plus, eps=1e-6):
    cols = []
    for k in range(6):
        d = np.zeros(6)
        d[k] = eps
        cols.append((f(plus(x0, d)) - f(plus(x0, -d))) / (2 * eps))
    return np.stack(cols, 1)


# --------------------------------------------------------------------------- the edge
@pytest.mark.parametrize("seed", range(4))
def test_edge_jacobians_match_finite_differences_of_the_contract_perturbation(seed):
    rng = np.random.default_rng(seed)
    Ti, Tj = _random_T(rng, 2, 3.0)
    Z = lie.se3_inverse(Ti) @ Tj @ lie.se3_exp(0.3 * rng.normal(size=6))
    e, A, B = g3.se3_edge_error(Ti, Tj, Z)
    np.testing.assert_allclose(e, lie.se3_log(lie.se3_inverse(Z) @ lie.se3_inverse(Ti) @ Tj), atol=1e-13)
    np.testing.assert_allclose(A, _num_jac(lambda T: g3.se3_edge_error(T, Tj, Z)[0], Ti, lie.se3_plus), atol=1e-7)
    np.testing.assert_allclose(B, _num_jac(lambda T: g3.se3_edge_error(Ti, T, Z)[0], Tj, lie.se3_plus), atol=1e-7)


def test_edge_error_is_zero_for_a_consistent_measurement_and_batched_equals_single():
    rng = np.random.default_rng(5)
    T = _random_T(rng, 6)
    edges = np.array([[0, 1], [2, 5], [4, 3]])
    Z = lie.se3_inverse(T[edges[:, 0]]) @ T[edges[:, 1]]
    e, A, B = g3.pose_graph3d_errors(T, edges, Z)
    np.testing.assert_allclose(e, 0.0, atol=1e-12)
    Zn = Z @ lie.se3_exp(0.1 * rng.normal(size=(3, 6)))
    e, A, B = g3.pose_graph3d_errors(T, edges, Zn)
    for k, (i, j) in enumerate(edges):
        ek, Ak, Bk = g3.se3_edge_error(T[i], T[j], Zn[k])
        np.testing.assert_allclose(e[k], ek, atol=1e-14)
        np.testing.assert_allclose(A[k], Ak, atol=1e-13)
        np.testing.assert_allclose(B[k], Bk, atol=1e-13)


@needs_gtsam
def test_edge_error_and_chi2_equal_gtsam_between_factor():
    rng = np.random.default_rng(6)
    T = _random_T(rng, 2, 2.0)
    Z = lie.se3_exp(rng.normal(size=6))
    L = rng.normal(size=(6, 6))
    Omega = L @ L.T + 6 * np.eye(6)
    e, _, _ = g3.se3_edge_error(T[0], T[1], Z)
    P = np.block([[Omega[3:, 3:], Omega[3:, :3]], [Omega[:3, 3:], Omega[:3, :3]]])  # GTSAM: rotation first
    f = gtsam.BetweenFactorPose3(0, 1, gtsam.Pose3(Z), gtsam.noiseModel.Gaussian.Information(P))
    v = gtsam.Values()
    v.insert(0, gtsam.Pose3(T[0]))
    v.insert(1, gtsam.Pose3(T[1]))
    np.testing.assert_allclose(2 * f.error(v), e @ Omega @ e, rtol=1e-10)
    np.testing.assert_allclose(g3.pose_graph3d_chi2(T, [[0, 1]], Z[None], Omega[None]), e @ Omega @ e, rtol=1e-14)


# --------------------------------------------------------------------------- the solver
def _noisy_graph(rng, n=40, closures=((0, 20), (5, 30), (10, 39))):
    """A helix with odometry and loop closures; noise sigma 0.01 on every coordinate."""
    s = np.arange(n)
    xi = np.stack([3 * np.cos(0.3 * s), 3 * np.sin(0.3 * s), 0.1 * s, 0.05 * s, 0.02 * s, 0.3 * s], 1)
    T_true = lie.se3_exp(np.zeros(6)) @ np.stack([lie.se3(lie.so3_exp(x[3:]), x[:3]) for x in xi])
    edges = np.array([[k, k + 1] for k in range(n - 1)] + list(closures))
    Z = lie.se3_inverse(T_true[edges[:, 0]]) @ T_true[edges[:, 1]] @ lie.se3_exp(0.01 * rng.normal(size=(len(edges), 6)))
    Omega = np.broadcast_to(np.eye(6) / 0.01 ** 2, (len(edges), 6, 6)).copy()
    return T_true, edges, Z, Omega


@pytest.mark.parametrize("method", ["gn", "lm"])
def test_solver_reaches_a_minimum_with_zero_gradient_and_beats_odometry(method):
    rng = np.random.default_rng(7)
    T_true, edges, Z, Omega = _noisy_graph(rng)
    T0 = g3.pose_graph3d_initial_guess(len(T_true), edges, Z, T_root=T_true[0])
    res = g3.optimize_pose_graph3d(T0, edges, Z, Omega, method=method)
    assert res.converged and res.X.shape == T0.shape
    # chi2 of a least-squares optimum with E edges of dimension 6 and 6(n-1) unknowns: about 6E - 6(n-1)
    dof = 6 * len(edges) - 6 * (len(T_true) - 1)
    assert 0.3 * dof < res.chi2[-1] < 3 * dof
    # zero gradient: the linearised system at the solution has b ~ 0
    layout = gs._pose_layout(len(T_true), edges, 6, (0,))
    e, A, B = g3.pose_graph3d_errors(res.X, edges, Z)
    _, b = layout.values([(A, B, e, Omega)])
    assert np.abs(b).max() < 1e-6 * np.abs(Omega).max()
    assert np.allclose(res.X[0], T_true[0])
    err_opt = g3.trajectory_errors3d(res.X, T_true)[0].mean()
    err_odo = g3.trajectory_errors3d(T0, T_true)[0].mean()
    assert err_opt < err_odo


def test_robust_kernel_downweights_a_wrong_loop_closure():
    rng = np.random.default_rng(8)
    T_true, edges, Z, Omega = _noisy_graph(rng)
    Z = Z.copy()
    Z[-1] = Z[-1] @ lie.se3_exp([2.0, -1.0, 0.5, 0.3, 0.0, 0.2])  # an outlier closure
    T0 = g3.pose_graph3d_initial_guess(len(T_true), edges, Z, T_root=T_true[0])
    plain = g3.optimize_pose_graph3d(T0, edges, Z, Omega)
    robust = g3.optimize_pose_graph3d(T0, edges, Z, Omega, robust="cauchy")
    assert robust.weights[-1] < 1e-3 < robust.weights[:-1].min()
    assert g3.trajectory_errors3d(robust.X, T_true)[0].max() < 0.5 * g3.trajectory_errors3d(plain.X, T_true)[0].max()


def test_initial_guess_composes_the_chain():
    rng = np.random.default_rng(9)
    T = _random_T(rng, 5)
    T[0] = np.eye(4)
    edges = np.array([[0, 1], [2, 1], [2, 3], [3, 4]])  # one edge read backwards
    Z = lie.se3_inverse(T[edges[:, 0]]) @ T[edges[:, 1]]
    np.testing.assert_allclose(g3.pose_graph3d_initial_guess(5, edges, Z), T, atol=1e-12)


def test_bad_inputs_name_the_argument():
    T = np.broadcast_to(np.eye(4), (3, 4, 4)).copy()
    Z = np.broadcast_to(np.eye(4), (2, 4, 4)).copy()
    Om = np.broadcast_to(np.eye(6), (2, 6, 6)).copy()
    edges = np.array([[0, 1], [1, 2]])
    with pytest.raises(ValueError, match="T0 must"):
        g3.optimize_pose_graph3d(T[:, :3], edges, Z, Om)
    bad = T.copy()
    bad[1, :3, :3] *= 2
    with pytest.raises(ValueError, match=r"T0\[..., :3, :3\] must be a rotation"):
        g3.optimize_pose_graph3d(bad, edges, Z, Om)
    with pytest.raises(ValueError, match="Z must have shape"):
        g3.optimize_pose_graph3d(T, edges, Z[:1], Om)
    with pytest.raises(ValueError, match=r"Omega\[1\] must be positive definite"):
        g3.optimize_pose_graph3d(T, edges, Z, np.stack([np.eye(6), -np.eye(6)]))
    with pytest.raises(ValueError, match="disconnected"):
        g3.optimize_pose_graph3d(T, edges[:1], Z[:1], Om[:1])
    with pytest.raises(ValueError, match="method"):
        g3.optimize_pose_graph3d(T, edges, Z, Om, method="newton")


# --------------------------------------------------------------------------- loaders
G2O3D = """# a tiny 3-D graph
VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1
VERTEX_SE3:QUAT 1 1 0 0 0 0 0.0998334 0.995004
EDGE_SE3:QUAT 0 1 1 0 0 0 0 0.0998334 0.995004 1 0 0 0 0 0 2 0 0 0 0 3 0 0 0 4 0 0 5 0 6
"""
TORO3D = """VERTEX3 0 0 0 0 0 0 0
VERTEX3 1 1 0 0 0 0 0.2
EDGE3 0 1 1 0 0 0.1 -0.2 0.2 1 0 0 0 0 0 2 0 0 0 0 3 0 0 0 4 0 0 5 0 6
"""


def test_g2o3d_reads_quaternions_and_toro_angles(tmp_path):
    p = tmp_path / "a.g2o"
    p.write_text(G2O3D)
    g = load_g2o3d(p)
    assert (g.n_poses, g.n_edges) == (2, 1)
    np.testing.assert_allclose(g.T[1], lie.se3(lie.so3_exp([0, 0, 0.2]), [1, 0, 0]), atol=1e-6)
    np.testing.assert_allclose(np.diag(g.Omega[0]), [1, 2, 3, 4, 5, 6])
    p = tmp_path / "b.graph"
    p.write_text(TORO3D)
    g = load_g2o3d(p)
    np.testing.assert_allclose(g.Z[0, :3, :3], lie.euler_to_so3([0.1, -0.2, 0.2]), atol=1e-15)
    np.testing.assert_allclose(g.T[1, :3, :3], lie.so3_exp([0, 0, 0.2]), atol=1e-15)


def test_g2o3d_without_vertices_composes_the_odometry_guess(tmp_path):
    p = tmp_path / "c.graph"
    p.write_text("EDGE3 0 1 1 0 0 0 0 0.5 " + " ".join(map(str, np.eye(6)[np.triu_indices(6)])) + "\n"
                 "EDGE3 1 2 1 0 0 0 0 0.5 " + " ".join(map(str, np.eye(6)[np.triu_indices(6)])) + "\n")
    g = load_g2o3d(p)
    np.testing.assert_allclose(g.T[2], g.Z[0] @ g.Z[1], atol=1e-15)
    np.testing.assert_allclose(g.T[2, :3, 3], [1 + np.cos(0.5), np.sin(0.5), 0.0], atol=1e-6)


@pytest.mark.parametrize("line, match", [
    ("EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1", r"EDGE_SE3:QUAT needs 30 fields"),
    ("EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1", r"unsupported record 'EDGE_SE2' \(a 3-D pose graph reads"),
    ("VERTEX_SE3:QUAT 5 0 0 0 0 0 0 0", r"VERTEX_SE3:QUAT has a zero quaternion"),
    ("EDGE3 0 7 1 0 0 0 0 0 " + " ".join(["1"] * 21), r"refers to vertex 7"),
    ("EDGE3 0 1 1 0 0 0 0 0 " + " ".join(["0"] * 21), r"not positive definite"),
])
def test_g2o3d_errors_name_file_and_line(tmp_path, line, match):
    p = tmp_path / "bad.g2o"
    p.write_text(G2O3D + line + "\n")
    with pytest.raises(ValueError, match=match) as info:
        load_g2o3d(p)
    assert f"{p}:5:" in str(info.value)


def test_toro_2d_information_order_and_equiv(tmp_path):
    p = tmp_path / "w.graph"
    # TORO order: I11 I12 I22 I33 I13 I23
    p.write_text("VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\nEDGE2 1 0 -1 0 0 10 1 20 30 2 3\nEQUIV 1 0\n")
    g = load_g2o(p)
    np.testing.assert_allclose(g.Omega[0], [[10, 1, 2], [1, 20, 3], [2, 3, 30]])
    np.testing.assert_array_equal(g.equivalences, [[1, 0]])
    # a file tagged EDGE2 with g2o's order (TORO's would be indefinite) is read in g2o's order
    p.write_text("EDGE2 0 1 1 0 0 3 0 0 3 0 5\nEDGE2 1 2 1 0 0 3 0 0 3 0 5\n")
    g = load_g2o(p)
    np.testing.assert_allclose(g.Omega[0], np.diag([3.0, 3.0, 5.0]))
    np.testing.assert_allclose(g.X[2], [2.0, 0.0, 0.0])  # no vertices: the odometry guess
    assert g.equivalences is None


# --------------------------------------------------------------------------- sphere2500
def test_sphere2500_converges_to_the_optimum_and_beats_odometry_against_the_truth():
    g, truth = load_sphere2500()
    assert (g.n_poses, g.n_edges) == (2500, 4949)
    res = g3.optimize_pose_graph3d(g.T, g.edges, g.Z, g.Omega)
    assert res.converged and res.iterations <= 10
    np.testing.assert_allclose(res.chi2[-1], SPHERE_CHI2, rtol=1e-9)
    opt = np.sqrt(np.mean(g3.trajectory_errors3d(res.X, truth)[0] ** 2))
    odo = np.sqrt(np.mean(g3.trajectory_errors3d(g.T, truth)[0] ** 2))
    assert opt < 0.2 * odo


@needs_gtsam
def test_sphere2500_chi2_equals_gtsam_levenberg_marquardt():
    g, _ = load_sphere2500()
    graph = gtsam.NonlinearFactorGraph()
    for (i, j), z, W in zip(g.edges, g.Z, g.Omega):
        P = np.block([[W[3:, 3:], W[3:, :3]], [W[:3, 3:], W[:3, :3]]])
        graph.add(gtsam.BetweenFactorPose3(int(i), int(j), gtsam.Pose3(z), gtsam.noiseModel.Gaussian.Information(P)))
    graph.add(gtsam.NonlinearEqualityPose3(0, gtsam.Pose3(g.T[0])))
    init = gtsam.Values()
    for k, t in enumerate(g.T):
        init.insert(k, gtsam.Pose3(t))
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-9)
    params.setAbsoluteErrorTol(0.0)
    vals = gtsam.LevenbergMarquardtOptimizer(graph, init, params).optimize()
    np.testing.assert_allclose(2 * graph.error(vals), SPHERE_CHI2, rtol=1e-9)


# --------------------------------------------------------------------------- LM damping on a large 2-D graph
@needs_gtsam
def test_w10000_levenberg_marquardt_converges_in_as_few_iterations_as_gtsam():
    """w10000 (TORO, 10 000 poses, 64 311 edges; shipped with GTSAM): Nielsen's damping with a shrink of at
    most 1/3 per step crawled for 28 iterations; Marquardt's factor 10 with poses moved in their own frame
    needs 9, as GTSAM's LM (benchmarks/bench_3d.py), at the same optimum."""
    g = load_g2o(gtsam.findExampleDataFile("w10000.graph"))
    assert (g.n_poses, g.n_edges) == (10000, 64311) and g.equivalences.shape == (5875, 2)
    X0 = sl.pose_graph_initial_guess(g.n_poses, g.edges, g.Z)
    res = sl.optimize_pose_graph(X0, g.edges, g.Z, g.Omega)
    assert res.converged and res.iterations <= 10
    np.testing.assert_allclose(res.chi2[-1], 289.725891182, rtol=1e-9)
