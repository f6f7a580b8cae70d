"""Speed of bundle adjustment: the Schur complement against the same LM without it, SciPy and GTSAM.

Run ``python benchmarks/bench_ba.py`` (about a minute on an idle core). Figures, all measured in this
process, on three problems from the same initial guess (first camera fixed, intrinsics fixed):

* ``dubrovnik-3-7`` (BAL, 3 cameras, 7 points) and ``Balbianello`` (Bundler, 5 cameras, 544
  points, 1417 observations), real data shipped in ``slamlib/data/sfm``, radial distortion removed
  from the observations at load time;
* ``synthetic``: 30 cameras on a circle around 1500 points, each point seen by the 6 to 9 cameras
  nearest to it (about 11 000 observations), 0.5 px noise, cameras and points perturbed.

For each: :func:`slamlib.bundle_adjust` with ``linear_solver="schur"`` (the reduced camera system),
``"dense"`` (the same Levenberg-Marquardt solving the whole normal equations by a dense Cholesky
factorisation: the structure ignored; target: Schur >= 10x faster) and ``"sparse"`` (the whole
system by a sparse LU with a minimum-degree order, as the pose graphs); ``scipy.optimize.least_squares``
(trust-region reflective with the sparsity pattern of the Jacobian and finite differences, the
SciPy cookbook's bundle adjustment; rotation vectors as parameters; target: Schur >= 5x faster at
the same cost); and GTSAM's Levenberg-Marquardt (``GenericProjectionFactorCal3_S2``, first pose
held by a ``NonlinearEquality``; ``pip install gtsam``, skipped when absent). Costs are
``1/2 sum |e|^2`` in pixels squared (GTSAM's error with unit sigma). Each solver runs until its own
relative-decrease test (1e-10) or 100 iterations; the table gives each one's final cost and
time, and says which ones end more than 1e-6 (relative) above the best final cost.

Timings are medians over repeats (``time.perf_counter``); BLAS runs single-threaded.

References
----------
B. Triggs et al., "Bundle adjustment - a modern synthesis", 1999 (Sec. 6.1, the Schur complement);
S. Agarwal, N. Snavely, S. M. Seitz, R. Szeliski, "Bundle adjustment in the large", ECCV 2010;
SciPy cookbook, "Large-scale bundle adjustment in scipy".
"""

from __future__ import annotations

import argparse
import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import time  # noqa: E402

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402
from scipy.optimize import least_squares  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

import slamlib as sl  # noqa: E402
from slamlib.datasets import SfmProblem, load_balbianello, load_dubrovnik  # noqa: E402

RTOL = 1e-10


def synthetic(seed=0, n_cam=30, n_pt=1500):
    rng = np.random.default_rng(seed)
    K = sl.calibration_matrix(700.0, 700.0, 320.0, 240.0)
    ang = np.linspace(0, 2 * np.pi, n_cam, endpoint=False)
    centres = np.column_stack([12 * np.cos(ang), rng.normal(0, 0.5, n_cam), 12 * np.sin(ang)])
    T = []
    for c in centres:
        z = -c / np.linalg.norm(c)
        x = np.cross([0.0, 1.0, 0.0], z)
        x /= np.linalg.norm(x)
        T.append(sl.pose_matrix(np.column_stack([x, np.cross(z, x), z]), c))
    T = np.stack(T)
    P = rng.uniform(-3, 3, (n_pt, 3))
    cam, point = [], []
    for j in range(n_pt):
        near = np.argsort(np.linalg.norm(centres - P[j], axis=1))[: rng.integers(6, 10)]
        cam += list(near)
        point += [j] * len(near)
    cam, point = np.array(cam), np.array(point)
    uv = np.empty((len(cam), 2))
    for c in range(n_cam):
        s = cam == c
        uv[s] = sl.project(K, T[c], P[point[s]])[0]
    uv += rng.normal(0, 0.5, uv.shape)
    T0 = T.copy()
    T0[1:, :3, 3] += rng.normal(0, 0.05, (n_cam - 1, 3))
    P0 = P + rng.normal(0, 0.05, P.shape)
    return SfmProblem(T0, np.repeat(K[None], n_cam, 0), P0, cam, point, uv, np.zeros((n_cam, 2)), -np.ones(len(cam), int))


def timed(fn, repeat=3):
    ts, out = [], None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts)), out


def run_slamlib(pb, solver, max_iter=100):
    return sl.bundle_adjust(pb.T_wc, pb.points, pb.K, pb.cam, pb.point, pb.uv, linear_solver=solver,
                            max_iter=max_iter, rtol=RTOL)


# --------------------------------------------------------------------------- scipy
def scipy_problem(pb):
    """Residuals over x = [rotvec, t] of cameras 1.. (world-to-camera) and the points."""
    C = len(pb.T_wc)
    R_cw = np.swapaxes(pb.T_wc[:, :3, :3], 1, 2)
    t_cw = -np.einsum("cij,cj->ci", R_cw, pb.T_wc[:, :3, 3])
    x0 = np.concatenate([np.column_stack([Rotation.from_matrix(R_cw[1:]).as_rotvec(), t_cw[1:]]).ravel(),
                         pb.points.ravel()])
    f = pb.K[:, 0, 0][pb.cam]
    cxy = pb.K[:, :2, 2][pb.cam]

    def fun(x):
        cams = np.vstack([np.r_[Rotation.from_matrix(R_cw[0]).as_rotvec(), t_cw[0]], x[: 6 * (C - 1)].reshape(-1, 6)])
        P = x[6 * (C - 1):].reshape(-1, 3)
        pc = Rotation.from_rotvec(cams[pb.cam, :3]).apply(P[pb.point]) + cams[pb.cam, 3:]
        return (f[:, None] * pc[:, :2] / pc[:, 2:] + cxy - pb.uv).ravel()

    O = len(pb.cam)
    rows, cols = [], []
    for k in range(2):
        r = 2 * np.arange(O) + k
        live = pb.cam > 0
        for i in range(6):
            rows.append(r[live])
            cols.append(6 * (pb.cam[live] - 1) + i)
        for i in range(3):
            rows.append(r)
            cols.append(6 * (C - 1) + 3 * pb.point + i)
    A = sp.coo_matrix((np.ones(sum(len(r) for r in rows)), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(2 * O, x0.size)).tocsr()
    return fun, x0, A


def run_scipy(pb, max_nfev=None):
    fun, x0, A = scipy_problem(pb)
    return least_squares(fun, x0, jac_sparsity=A, method="trf", x_scale="jac", ftol=RTOL, xtol=1e-12, gtol=1e-12,
                         max_nfev=max_nfev)


# --------------------------------------------------------------------------- GTSAM
def run_gtsam(pb, max_iter=100):
    import gtsam
    from gtsam.symbol_shorthand import L, X

    g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
    noise = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    for c in range(len(pb.T_wc)):
        v.insert(X(c), gtsam.Pose3(pb.T_wc[c]))
    for j, P in enumerate(pb.points):
        v.insert(L(j), gtsam.Point3(*P))
    cal = [gtsam.Cal3_S2(K[0, 0], K[1, 1], 0.0, K[0, 2], K[1, 2]) for K in pb.K]
    for c, j, uv in zip(pb.cam, pb.point, pb.uv):
        g.add(gtsam.GenericProjectionFactorCal3_S2(gtsam.Point2(*uv), noise, X(int(c)), L(int(j)), cal[int(c)]))
    g.add(gtsam.NonlinearEqualityPose3(X(0), gtsam.Pose3(pb.T_wc[0])))
    p = gtsam.LevenbergMarquardtParams()
    p.setMaxIterations(max_iter)
    p.setRelativeErrorTol(RTOL)
    p.setAbsoluteErrorTol(0.0)
    opt = gtsam.LevenbergMarquardtOptimizer(g, v, p)
    res = opt.optimize()
    return g.error(res), opt.iterations()


def main(argv=None):
    argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter).parse_args(argv)
    problems = [("dubrovnik-3-7", load_dubrovnik()), ("Balbianello", load_balbianello()), ("synthetic", synthetic())]
    try:
        import gtsam  # noqa: F401
        have_gtsam = True
    except ImportError:
        have_gtsam = False
    print(f"{'problem':14s} {'solver':22s} {'cost start':>12s} {'cost final':>14s} {'iter':>5s} {'time s':>8s} "
          f"{'vs schur':>9s}")
    for name, pb in problems:
        print(f"# {name}: {len(pb.T_wc)} cameras, {len(pb.points)} points, {len(pb.cam)} observations")
        repeat = 1 if name == "synthetic" else 3
        rows = {}
        for solver in ("schur", "sparse", "dense"):
            t, r = timed(lambda: run_slamlib(pb, solver), repeat)
            rows[f"slamlib {solver}"] = (0.5 * r.cost[0], 0.5 * r.cost[-1], r.iterations, t)
        t, r = timed(lambda: run_scipy(pb), 1)  # slow: one run
        fun, x0, _ = scipy_problem(pb)
        rows["scipy least_squares"] = (0.5 * float(fun(x0) @ fun(x0)), float(r.cost), int(r.nfev), t)
        if have_gtsam:
            t, (e, it) = timed(lambda: run_gtsam(pb), repeat)
            rows["GTSAM LM"] = (rows["slamlib schur"][0], e, it, t)
        base = rows["slamlib schur"][3]
        for label, (c0, c1, it, t) in rows.items():
            print(f"{name:14s} {label:22s} {c0:12.6g} {c1:14.10g} {it:5d} {t:8.3f} {t / base:8.1f}x")
        best = min(r[1] for r in rows.values())
        for label, (_, c1, _, _) in rows.items():
            if abs(c1 - best) > 1e-6 * best:
                print(f"{name:14s} {label:22s} ends {100 * (c1 - best) / best:.2g} % above the best cost")
    print("scipy's 'iter' column counts function evaluations (finite-difference Jacobians included).")


if __name__ == "__main__":
    main()
