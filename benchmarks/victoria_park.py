"""Victoria Park end to end: EKF SLAM and FastSLAM over the whole run, timed and scored against GPS.

Run ``python benchmarks/victoria_park.py`` (a few minutes on 2 cores; the
targets are EKF SLAM <= 30 s and FastSLAM 2.0 with 100 particles <= 60 s for
the whole 1549 s run). Options: ``--t-max S`` for a shorter window,
``--seeds K`` FastSLAM seeds (default 3), ``--particles M`` (default 100),
``--skip-fastslam1`` (also ``--skip-fastslam``, ``--skip-ekf``, ``--skip-jcbb``), ``--out FILE`` to write the cached results chapter 12
reads (default ``chapters/data/victoria_park_full.npz``; ``--out ''``
writes nothing).

Every filter uses the loader's noise (``VICTORIA_M``, ``VICTORIA_Q``: chosen,
not tuned), unknown correspondences and the car model of ``info.txt``:

* EKF SLAM: nearest-neighbour association (Algorithm 2) with the validation
  gate and the provisional landmark list (``confirm=2`` sightings within 10
  steps), ``association="jcbb"`` as a second row;
* FastSLAM 1.0 and 2.0 (per-particle maximum-likelihood association), several
  seeds, failures included.

Printed: the machine's load average at the start and with the targets, wall
and CPU time of each full run (on a shared machine the CPU time is the figure
to compare with the targets; a loaded machine still slows it), a closing
table of each CPU time against its target (the slowest FastSLAM seed; only for
the whole run with 100 particles), ATE against the GPS fixes after a rigid
alignment (the GPS's own error, metres with jumps, is part of it), landmarks
in the map, and the time of one EKF SLAM step (prediction, association and
updates of one real laser scan's detections) from the full run's final
state cut to ``N`` landmarks, against the bare-numpy floor of the same
step (``K`` rank-2 updates ``Sigma -= A @ B.T`` of the ``(3+2N)^2``
covariance). BLAS runs single-threaded, as in ``bench_slam.py``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # before numpy loads BLAS

import numpy as np  # noqa: E402

import slamlib as sl  # noqa: E402
from slamlib.datasets.victoria import load_victoria_park, victoria_gps_ate  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = ROOT / "chapters" / "data" / "victoria_park_full.npz"
#: EKF SLAM settings of the book on this log (chapter 12 explains them).
EKF_OPTIONS = dict(known=False, confirm=2, window=10)
#: CPU-time targets (s) of the whole run: EKF SLAM with nearest-neighbour association and with JCBB, FastSLAM 2.0
#: with 100 particles (per seed).
TARGETS = {"EKF SLAM (nn)": 30.0, "EKF SLAM (jcbb)": 30.0, "FastSLAM 2.0": 60.0}


def load_line():
    """The machine's load (1-minute average) against its cores: CPU times on a loaded machine run long."""
    return f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"


def dead_reckoning(run):
    """The car model integrated with the logged controls, no noise."""
    x = np.zeros((run.n_steps + 1, 3))
    x[0] = run.x0
    for k in range(run.n_steps):
        x[k + 1] = run.motion(x[k], run.u[k], run.dt)[0]
    return x


def step_time(res, run, N, repeats=20):
    """Median ms of one real scan's EKF SLAM step from the final state cut to N landmarks, and the numpy floor."""
    n = 3 + 2 * N
    steps = [k for k in range(run.n_steps) if len(run.z[k])][-200:]
    times, floors = [], []
    rng = np.random.default_rng(0)
    K = int(round(np.mean([len(run.z[k]) for k in steps])))
    for k in steps[:repeats]:
        filt = sl.EKFSLAM.from_state(res.mu[:n], res.Sigma[:n, :n])
        filt._motion = run.motion
        t0 = time.process_time()  # CPU time: the machine may be shared
        filt._predict(run.u[k], run.dt, run.M)
        for z in run.z[k]:
            j = filt._associate(z, run.Q, sl.ekf_slam.DEFAULT_ALPHA)
            if j == filt.n_landmarks:
                j = filt._add_landmark(z)
            filt._update(z, j, run.Q)
        filt.Sigma  # bring the covariance up to date
        times.append(time.process_time() - t0)
        S = res.Sigma[:n, :n].copy()
        A, B = rng.standard_normal((2, n, 2))
        t0 = time.process_time()
        for _ in range(K):
            S -= A @ B.T  # the floor: one dense rank-2 update per detection
        floors.append(time.process_time() - t0)
    return 1e3 * statistics.median(times), 1e3 * statistics.median(floors), K


def victoria_figures(t_max=300.0, sizes=(25, 50, 100, 200)):
    """Lines for ``bench_slam.py``: EKF SLAM on the first `t_max` s, then the step time against N and the floor."""
    run = load_victoria_park(t_max=t_max)
    c0 = time.process_time()
    res = sl.run_ekf_slam(run, motion=run.motion, **EKF_OPTIONS)
    cpu = time.process_time() - c0
    L = int(res.n_landmarks[-1])
    lines = [f"EKF SLAM, first {t_max:g} s ({run.n_steps} steps, {L} landmarks at the end): {cpu:.1f} s CPU"]
    for N in [s for s in sizes if s < L] + [L]:
        ms, floor, K = step_time(res, run, N)
        lines.append(f"  one scan's step at N = {N:4d}: {ms:7.3f} ms, bare numpy ({K} rank-2 updates) {floor:7.3f} ms, "
                     f"ratio {ms / floor:5.1f}x")
    lines.append("  (the whole run, targets EKF <= 30 s and FastSLAM 2.0 M=100 <= 60 s: "
                 "python benchmarks/victoria_park.py)")
    return lines


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t-max", type=float, default=None)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--particles", type=int, default=100)
    ap.add_argument("--skip-fastslam1", action="store_true")
    ap.add_argument("--skip-fastslam", action="store_true")
    ap.add_argument("--skip-jcbb", action="store_true")
    ap.add_argument("--skip-ekf", action="store_true")
    ap.add_argument("--versions", default="1,2", help="FastSLAM versions to run, e.g. '2'")
    ap.add_argument("--out", default=str(DEFAULT_OUT))
    args = ap.parse_args(argv)
    for name, low in {'seeds': 1, 'particles': 1}.items():  # counts at least 1, seeds at least 0
        value = getattr(args, name)
        if value is not None and min(value if isinstance(value, list) else [value]) < low:
            ap.error(f"--{name.replace('_', '-')} must be at least {low}, got {value}")
    if args.t_max is not None and not args.t_max > 0:
        ap.error(f"--t-max must be a positive number of seconds, got {args.t_max}")

    print(load_line())
    verdicts = []
    t0 = time.perf_counter()
    run = load_victoria_park(t_max=args.t_max)
    print(f"loaded {run.n_steps} steps of {run.dt} s, {run.n_sightings} detections, {run.gps.shape[0]} GPS fixes "
          f"in {time.perf_counter() - t0:.2f} s")
    out = {"t": run.t, "gps": np.asarray(run.gps)}
    dr = dead_reckoning(run)
    ate, aligned, _, _ = victoria_gps_ate(run, dr)
    print(f"dead reckoning: ATE vs GPS {ate:.2f} m")
    out["dr_xy"], out["dr_ate"] = aligned, ate

    rows = [("nn", {})] + ([] if args.skip_jcbb else [("jcbb", {"association": "jcbb"})])
    if args.skip_ekf:
        rows = []
    for name, extra in rows:
        t0, c0 = time.perf_counter(), time.process_time()
        res = sl.run_ekf_slam(run, motion=run.motion, **EKF_OPTIONS, **extra)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        ate, aligned, _, (R, tr) = victoria_gps_ate(run, res.x)
        print(f"EKF SLAM ({name}): {wall:.1f} s wall, {cpu:.1f} s CPU, ATE vs GPS {ate:.2f} m, {res.n_landmarks[-1]} landmarks, "
              f"{res.n_rejected} detections kept out by the provisional list")
        verdicts.append((f"EKF SLAM ({name})", cpu))
        out[f"ekf_{name}_xy"], out[f"ekf_{name}_ate"], out[f"ekf_{name}_time"] = aligned, ate, wall
        out[f"ekf_{name}_map"] = res.landmarks @ R.T + tr
        out[f"ekf_{name}_n_landmarks"] = res.n_landmarks
        if name == "nn":
            L = int(res.n_landmarks[-1])
            sizes = [s for s in (25, 50, 100, 200, 300, 400, 600) if s < L] + [L]
            print("  per-step time (one laser scan: predict, associate, update) vs landmarks:")
            table = []
            for N in sizes:
                ms, floor, K = step_time(res, run, N)
                table.append((N, ms, floor))
                print(f"    N = {N:4d}: {ms:7.3f} ms   bare numpy ({K} rank-2 updates) {floor:7.3f} ms   "
                      f"ratio {ms / floor:5.1f}x")
            out["step_table"] = np.array(table)

    versions = [int(v) for v in args.versions.split(",") if v.strip()]
    versions = [] if args.skip_fastslam else ([v for v in versions if v != 1] if args.skip_fastslam1 else versions)
    for version in versions:
        ates, walls, lms, cpus = [], [], [], []
        for seed in range(args.seeds):
            t0, c0 = time.perf_counter(), time.process_time()
            res = sl.run_fastslam(run, n_particles=args.particles, rng=np.random.default_rng(seed), known=False,
                                  version=version, motion=run.motion)
            walls.append(time.perf_counter() - t0)
            cpu = time.process_time() - c0
            cpus.append(cpu)
            ate, aligned, _, (R, tr) = victoria_gps_ate(run, res.path_best)  # the most likely particle's path
            ates.append(ate)
            lms.append(int(res.seen.sum()))
            print(f"FastSLAM {version}.0 (M={args.particles}, seed {seed}): {walls[-1]:.1f} s wall, {cpu:.1f} s CPU, ATE vs GPS {ate:.2f} m, "
                  f"{lms[-1]} landmarks")
            if seed == 0:
                out[f"fs{version}_xy"] = aligned
                out[f"fs{version}_map"] = res.landmarks[res.seen] @ R.T + tr
        out[f"fs{version}_ate"], out[f"fs{version}_time"], out[f"fs{version}_landmarks"] = (
            np.array(ates), np.array(walls), np.array(lms))
        print(f"FastSLAM {version}.0: ATE {np.mean(ates):.2f} m (min {min(ates):.2f}, max {max(ates):.2f}) "
              f"over {args.seeds} seeds, median time {statistics.median(walls):.1f} s")
        verdicts.append((f"FastSLAM {version}.0", max(cpus)))

    if verdicts:
        print(f"targets (CPU time of the whole run; the slowest seed; {load_line()}):")
        for name, cpu in verdicts:
            goal = TARGETS.get(name) if args.t_max is None and args.particles == 100 else None
            verdict = "no target" if goal is None else f"target {goal:g} s: {'met' if cpu <= goal else 'MISSED'}"
            print(f"  {name:<18} {cpu:7.1f} s CPU  ({verdict})")

    if args.out:
        # the chapter plots every 10th pose: enough for a 2 km path, and small to ship
        small = {k: (v[::10] if k.endswith("_xy") or k == "t" or k.endswith("_n_landmarks") else v)
                 for k, v in out.items()}
        np.savez_compressed(args.out, **small)
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
