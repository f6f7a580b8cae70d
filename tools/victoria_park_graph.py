"""Graph SLAM on the whole Victoria Park run, beside the filters: writes the file chapter 12 reads.

The trees carry no identities, so the graph needs a front end's associations: EKF SLAM (nearest
neighbour behind the validation gate, the provisional list, the chapter's settings) runs over the
whole log, and its ``associations`` (the map slot each detection updated, ``-1`` for those it left
out) and its path and map become the graph's edges and initial guess
(:func:`slamlib.landmark_graph_from_run` with ``motion=`` the car model and ``associations=``).
Levenberg-Marquardt then solves the full-SLAM problem, with least squares and with the Cauchy
kernel, and each solution is scored against the GPS like the filters.

Usage: ``python tools/victoria_park_graph.py [--t-max S] [--out FILE]`` (about a minute on one core
for the whole run). Writes ``chapters/data/victoria_park_graph.npz``: every 10th pose of each path
in the GPS frame (``*_xy``, aligned as scored), the ATEs, the sizes of the graph, the solve times and the iteration counts.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

import slamlib as sl  # noqa: E402
from slamlib.datasets.victoria import load_victoria_park, victoria_gps_ate  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = ROOT / "chapters" / "data" / "victoria_park_graph.npz"
EKF_OPTIONS = dict(known=False, confirm=2, window=10)  # the chapter's (and benchmarks/victoria_park.py's)
#: Heading noise (rad) added to every odometry edge: the car model has none while the car stands still.
HEADING_FLOOR = 1e-3


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t-max", type=float, default=None, help="seconds of the log (default: all)")
    ap.add_argument("--out", default=str(DEFAULT_OUT))
    args = ap.parse_args(argv)
    if args.t_max is not None and not args.t_max > 0:
        ap.error(f"--t-max must be a positive number of seconds, got {args.t_max}")
    run = load_victoria_park(t_max=args.t_max)
    t0 = time.process_time()
    ekf = sl.run_ekf_slam(run, motion=run.motion, **EKF_OPTIONS)
    t_ekf = time.process_time() - t0
    graph = sl.landmark_graph_from_run(run, motion=run.motion, associations=ekf.associations,
                                       heading_floor=HEADING_FLOOR)
    warm = graph._replace(X0=ekf.x, L0=ekf.landmarks[graph.landmark_ids])
    ekf_ate, ekf_aligned, _, _ = victoria_gps_ate(run, ekf.x)
    out = {"t_max": float(run.t[-1]), "n_poses": graph.X0.shape[0], "n_landmarks": graph.L0.shape[0],
           "n_sightings": graph.obs_edges.shape[0], "n_detections": int(sum(len(z) for z in run.z)),
           "ekf_ate": ekf_ate, "ekf_cpu": t_ekf, "ekf_xy": ekf_aligned[::10]}
    print(f"{run.t[-1]:.0f} s: {out['n_poses']} poses, {out['n_landmarks']} landmarks, {out['n_sightings']} "
          f"sightings of {out['n_detections']} detections; EKF SLAM ATE {out['ekf_ate']:.2f} m ({t_ekf:.1f} s CPU)")
    for key, robust in (("graph", None), ("graph_cauchy", "cauchy")):
        t0 = time.process_time()
        res = sl.optimize_landmark_graph(warm, robust=robust)
        cpu = time.process_time() - t0
        ate, aligned, _, _ = victoria_gps_ate(run, res.X)
        out.update({f"{key}_ate": ate, f"{key}_cpu": cpu, f"{key}_iterations": res.iterations,
                    f"{key}_converged": bool(res.converged), f"{key}_chi2": res.chi2[-1], f"{key}_xy": aligned[::10]})
        print(f"graph SLAM ({robust or 'least squares'}): ATE {ate:.2f} m, {res.iterations} iterations "
              f"({'converged' if res.converged else 'stopped at the cap'}), "
              f"{cpu:.1f} s CPU, chi2 {res.chi2[0]:.0f} -> {res.chi2[-1]:.0f}")
    if args.out:
        np.savez_compressed(args.out, **{k: np.asarray(v) for k, v in out.items()})
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
