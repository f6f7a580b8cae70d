"""Precompute the incremental-smoothing figures of chapter 13 (slamlib against gtsam.ISAM2).

Run ``python tools/incremental_city10000.py [--graph city10000|M3500] [--measurements M]`` (minutes;
needs ``gtsam``, the dev extra), or ``--select`` for the choice of the change threshold.

A run feeds the first M (default all) measurements of the graph, in arrival order, one at a time to
:func:`slamlib.incremental.incremental_pose_graph` and to ``gtsam.ISAM2`` (as ``benchmarks/bench_3d.py``
does), solves the whole graph once by batch Levenberg-Marquardt, and writes
``chapters/data/incremental_<graph>.json``: the time per measurement of both (mean in bins of 500
measurements; median, 95th percentile and maximum), the full solves, and the final chi2 (and, on
City10000, the position RMSE against the reference poses) of the three estimates.

``--select`` runs the smoother on the first 5000 poses of City10000 only, for each threshold of
:data:`THRESHOLDS`, and writes ``chapters/data/incremental_threshold.json``: the chi2 of the estimate against
that of the batch optimum of the same measurements after every :data:`CHECK`-th measurement (a run may end
anywhere), the same for the position RMSE against the reference poses, and the mean time per measurement.
The rule: the largest threshold whose chi2 stays within :data:`SELECT_TOL` of batch's at every check; the runs above, on the whole of City10000 and on M3500, did not take
part in the choice. The chapter reads the files (it does not run the updates itself). BLAS runs
single-threaded.
"""

from __future__ import annotations

import json
import os
import platform
import sys
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

import slamlib as sl  # noqa: E402
from slamlib.incremental import arrival_order, incremental_pose_graph  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_3d import run_isam2  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / "chapters" / "data"
BIN = 500
THRESHOLDS = (0.1, 0.03, 0.01, 0.003)
SELECT_POSES = 5000
SELECT_TOL = 2e-3  # a fifth of the goal (final chi2 within 1 % of batch)
CHECK = 1000


def load(name, measurements=None, poses=None):
    """Edges, measurements, information matrices in arrival order, odometry guess, reference poses (or None)."""
    if name == "city10000":
        c = sl.datasets.load_city10000()
        g, truth = c.graph, c.truth
    elif name == "M3500":
        g, truth = sl.datasets.load_m3500(), None
    else:
        raise ValueError(f"graph must be 'city10000' or 'M3500', got {name!r}")
    o = arrival_order(g.edges)
    edges, Z, Om = g.edges[o], g.Z[o], g.Omega[o]
    m = len(edges) if measurements is None else measurements
    if poses is not None:
        m = int(np.flatnonzero(edges.max(axis=1) < poses).max()) + 1
    edges, Z, Om = edges[:m], Z[:m], Om[:m]
    n = int(edges.max()) + 1
    return edges, Z, Om, sl.pose_graph_initial_guess(n, edges, Z), None if truth is None else truth[:n]


def step_stats(t):
    ms = np.asarray(t) * 1000
    return {"mean": float(ms.mean()), "median": float(np.median(ms)), "p95": float(np.percentile(ms, 95)),
            "max": float(ms.max())}


def select():
    edges, Z, Om, X0, truth = load("city10000", poses=SELECT_POSES)
    # a run may end after any measurement: the error is checked at every CHECK-th one, not only the last
    checks = list(range(CHECK - 1, len(edges), CHECK)) + [len(edges) - 1]
    batch = {}
    for k in checks:
        e, z, w = edges[:k + 1], Z[:k + 1], Om[:k + 1]
        n = int(e.max()) + 1
        b = sl.optimize_pose_graph(X0[:n], e, z, w)
        batch[k] = (float(b.chi2[-1]), _rmse(b.X, truth[:n]))
    rows = []
    for th in THRESHOLDS:
        res = incremental_pose_graph(edges, Z, Om, threshold=th, snapshot_steps=checks)
        rel = [sl.pose_graph_chi2(res.snapshots[k], edges[:k + 1], Z[:k + 1], Om[:k + 1]) / batch[k][0] - 1
               for k in checks]
        rel_rmse = [_rmse(res.snapshots[k], truth[:res.snapshots[k].shape[0]]) / batch[k][1] - 1 for k in checks]
        rows.append({"threshold": th, "chi2_rel": rel, "rmse_rel": rel_rmse,
                     "worst": max(max(rel), max(abs(r) for r in rel_rmse)), "worst_chi2": max(rel),
                     "worst_rmse": max(abs(r) for r in rel_rmse), "final": rel[-1],
                     "mean_ms": float(res.step_time.mean() * 1000), "full_solves": int(res.batch_steps.size)})
        print({k: v for k, v in rows[-1].items() if not k.endswith("_rel")}, flush=True)
    out = {"poses": SELECT_POSES, "measurements": len(edges), "checks": checks, "rows": rows}
    choose(out)


def _rmse(X, truth):
    return float(np.sqrt(np.mean(np.sum((X[:, :2] - truth[:, :2]) ** 2, axis=1))))


def choose(out):
    """The rule applied to the rows of the study: the largest threshold whose chi2 stays within SELECT_TOL of the
    batch optimum's at every check. (The RMSE against the reference poses is recorded, not used: right after a
    closure it swings by percents for every threshold, one Gauss-Newton step not being converged.)"""
    ok = [r["threshold"] for r in out["rows"] if r["worst_chi2"] <= SELECT_TOL]
    out.update(tol=SELECT_TOL, chosen=max(ok) if ok else None)
    (DATA / "incremental_threshold.json").write_text(json.dumps(out, indent=1) + "\n")
    print(json.dumps({k: v for k, v in out.items() if k != "rows"}, indent=1))


def study(name, measurements=None):
    edges, Z, Om, X0, truth = load(name, measurements)
    res = incremental_pose_graph(edges, Z, Om)
    batch = sl.optimize_pose_graph(X0, edges, Z, Om)
    Xg, tg = run_isam2(edges, Z, Om)

    def rmse(X):
        return float(np.sqrt(np.mean(np.sum((X[:, :2] - truth[:, :2]) ** 2, axis=1))))

    def binned(t):
        k = len(t) // BIN * BIN
        return (t[:k].reshape(-1, BIN).mean(axis=1) * 1000).round(4).tolist()

    chi2 = {"incremental": res.chi2, "batch": float(batch.chi2[-1]), "isam2": sl.pose_graph_chi2(Xg, edges, Z, Om),
            "odometry": sl.pose_graph_chi2(X0, edges, Z, Om)}
    out = {
        "graph": name,
        "bin": BIN,
        "n_poses": int(X0.shape[0]),
        "n_edges": int(len(edges)),
        "slamlib_ms": binned(res.step_time),
        "isam2_ms": binned(tg),
        "slamlib_mean_ms": float(res.step_time.mean() * 1000),
        "isam2_mean_ms": float(tg.mean() * 1000),
        "slamlib_steps": step_stats(res.step_time),
        "isam2_steps": step_stats(tg),
        "batch_steps": res.batch_steps.tolist(),
        "mean_solved": float(res.solved[res.solved > 0].mean()),
        "chi2": chi2,
        "chi2_rel": {k: chi2[k] / chi2["batch"] - 1 for k in ("incremental", "isam2")},
        "batch_time_s": float(batch.time),
        "machine": platform.processor() or platform.machine(),
    }
    if truth is not None:
        out["rmse"] = {"incremental": rmse(res.X), "batch": rmse(batch.X), "isam2": rmse(Xg), "odometry": rmse(X0)}
    (DATA / f"incremental_{name.lower()}.json").write_text(json.dumps(out, indent=1) + "\n")
    print(json.dumps({k: v for k, v in out.items() if not k.endswith("_ms") and k != "batch_steps"}, indent=1))


def main(argv=None):
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--graph", default="city10000", choices=("city10000", "M3500"))
    ap.add_argument("--measurements", type=int, default=None, help="use the first M measurements (default all)")
    ap.add_argument("--select", action="store_true", help="the threshold study on the first 5000 poses of City10000")
    ap.add_argument("--choose", action="store_true", help="apply the rule again to the rows of the last --select")
    args = ap.parse_args(argv)
    for name, low in {'measurements': 1}.items():  # counts at least 1, seeds at least 0
        value = getattr(args, name)
        if value is not None and min(value if isinstance(value, list) else [value]) < low:
            ap.error(f"--{name.replace('_', '-')} must be at least {low}, got {value}")
    if args.select:
        select()
    elif args.choose:
        choose(json.loads((DATA / "incremental_threshold.json").read_text()))
    else:
        study(args.graph, args.measurements)


if __name__ == "__main__":
    main()
