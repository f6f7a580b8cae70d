"""Precompute the incremental-smoothing figures of chapter 13 on City10000 (slamlib against gtsam.ISAM2).

Run ``python tools/incremental_city10000.py [--measurements M]`` (minutes; needs ``gtsam``, the dev extra).
It feeds the first M (default all 20 687) measurements of City10000 one at a time to :func:`slamlib.incremental.incremental_pose_graph` and to
``gtsam.ISAM2`` (as ``benchmarks/bench_3d.py`` does), solves the whole graph once by batch
Levenberg-Marquardt, and writes ``chapters/data/incremental_city10000.json``: the mean time per measurement
in bins of 500 measurements for both, the full-solve steps, and the final chi2 and position RMSE against the
truth of the three estimates. The chapter reads the file (it does not run the 2 x 10 000 updates itself).
BLAS runs single-threaded.
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
from slamlib.incremental import incremental_pose_graph  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_3d import run_isam2  # noqa: E402

OUT = Path(__file__).resolve().parents[1] / "chapters" / "data" / "incremental_city10000.json"
BIN = 500


def main(argv=None):
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--measurements", type=int, default=None, help="use the first M measurements (default all)")
    args = ap.parse_args(argv)
    c = sl.datasets.load_city10000()
    m = args.measurements or c.graph.n_edges
    edges, Z, Om = c.graph.edges[:m], c.graph.Z[:m], c.graph.Omega[:m]
    n = int(edges.max()) + 1
    g = sl.datasets.PoseGraph(X=sl.pose_graph_initial_guess(n, edges, Z), edges=edges, Z=Z, Omega=Om,
                              vertex_ids=np.arange(n), source=c.graph.source)
    truth = c.truth[:n]
    res = incremental_pose_graph(g.edges, g.Z, g.Omega)
    batch = sl.optimize_pose_graph(g.X, g.edges, g.Z, g.Omega)
    Xg, tg = run_isam2(g.edges, g.Z, g.Omega)

    def rmse(X):
        return float(np.sqrt(np.mean(np.sum((X[:, :2] - truth[:, :2]) ** 2, axis=1))))

    def binned(t):
        k = len(t) // BIN * BIN
        return (t[:k].reshape(-1, BIN).mean(axis=1) * 1000).round(4).tolist()

    out = {
        "bin": BIN,
        "n_poses": g.n_poses,
        "n_edges": g.n_edges,
        "slamlib_ms": binned(res.step_time),
        "isam2_ms": binned(tg),
        "slamlib_mean_ms": float(res.step_time.mean() * 1000),
        "isam2_mean_ms": float(tg.mean() * 1000),
        "batch_steps": res.batch_steps.tolist(),
        "chi2": {"incremental": res.chi2, "batch": float(batch.chi2[-1]),
                 "isam2": sl.pose_graph_chi2(Xg, g.edges, g.Z, g.Omega),
                 "odometry": sl.pose_graph_chi2(g.X, g.edges, g.Z, g.Omega)},
        "rmse": {"incremental": rmse(res.X), "batch": rmse(batch.X), "isam2": rmse(Xg), "odometry": rmse(g.X)},
        "batch_time_s": float(batch.time),
        "machine": platform.processor() or platform.machine(),
    }
    OUT.write_text(json.dumps(out, indent=1) + "\n")
    print(json.dumps({k: v for k, v in out.items() if not k.endswith("_ms") or "mean" in k}, indent=1))


if __name__ == "__main__":
    main()
