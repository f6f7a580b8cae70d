"""FastSLAM 1.0 against 2.0 at the same particle budget: particle diversity and error, over many seeds.

Not a speed benchmark: an accuracy study, too long for the book (a few minutes on 2 cores), whose output
chapter 8 summarises. Run ``python benchmarks/study_fastslam_versions.py [--seeds N] [--real-only]``.

For every run it prints, then summarises as mean (min-max) over the seeds, failures included:

* ``ATE``: RMSE of the filter's weighted-mean positions (after the rigid alignment of
  :func:`slamlib.score_trajectory` on real data; the simulated runs share the true start frame);
* ``map``: landmark RMSE of the final most likely particle's map (in the trajectory's frame);
* ``ESS/M``: median effective sample size after the updates that had measurements, before
  resampling;
* ``resampled``: fraction of steps that resampled (ESS < M/2);
* ``anc(T/2)``, ``anc(T-10s)``: distinct ancestors, among the final particles, of the poses
  half way through and 10 s before the end (1 means the whole set shares one path there);
* ``rejected``: sightings the per-particle gate rejected (``run_fastslam`` applies the run's ``gate``,
  ``MRCLAM_GATE`` on the real logs).

Worlds: the simulated loop of chapter 8 (25 landmarks, 330 steps of 0.2 s), once with its sensor and once
with a sensor 10x more precise in range and bearing than that one (where the proposal matters most), and
MRCLAM Dataset 6 robots 1 and 2 (known correspondences, 50 particles as in chapter 9, the loader's calibrated
``MRCLAM_M``, ``MRCLAM_Q`` and gate).

References
----------
Thrun, Burgard & Fox (2005), Tables 13.1 and 13.3. Montemerlo et al. (2003), FastSLAM 2.0.
"""

from __future__ import annotations

import argparse
import os
import time

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

import slamlib as sl  # noqa: E402


def chapter_world(seed, precise=False):
    """The simulated loop of chapter 8 (optionally with a 10x more precise sensor)."""
    rng = np.random.default_rng(seed)
    landmarks = rng.uniform(-12, 12, size=(25, 2))
    M = np.diag([0.1, 0.05]) ** 2
    Q = np.diag([0.2, np.deg2rad(2.0)]) ** 2 / (100.0 if precise else 1.0)
    u = sl.loop_controls(330, v=1.0, omega=0.12)
    return sl.simulate_landmark_run(landmarks, u, 0.2, x0=np.array([0.0, -1.0 / 0.12, 0.0]), M=M, Q=Q,
                                    max_range=8.0, fov=np.pi, rng=rng)


def measure(run, version, n_particles, seed, real):
    t0 = time.perf_counter()
    res = sl.run_fastslam(run, n_particles=n_particles, version=version, rng=np.random.default_rng(1000 + seed))
    seconds = time.perf_counter() - t0
    T = run.u.shape[0]
    has = np.array([len(z) > 0 for z in run.z])
    if real:
        score = sl.score_trajectory(res.x_est, run.x_true)
        ate = score.ate
        lm = sl.score_landmarks(res.landmarks, run.landmarks, transform=score, seen=res.seen)
    else:
        ate = sl.ate_rmse(res.x_est, run.x_true)
        ids = np.flatnonzero(res.seen)
        lm = sl.landmark_rmse(res.landmarks[ids], run.landmarks[ids])
    back = int(round(10.0 / run.dt))
    return {
        "ATE": ate, "map": lm, "ESS/M": float(np.median(res.ess[has])) / n_particles,
        "resampled": float(res.resampled.mean()),
        "anc(T/2)": res.n_ancestors[T // 2] / n_particles, "anc(T-10s)": res.n_ancestors[T - back] / n_particles,
        "rejected": float(res.rejected.sum()), "ms/step": 1e3 * seconds / T,
    }


def summarise(name, rows):
    keys = list(rows[0])
    parts = []
    for k in keys:
        v = np.array([r[k] for r in rows])
        parts.append(f"{k} {v.mean():.3g} ({v.min():.3g}-{v.max():.3g})")
    print(f"{name}: " + ", ".join(parts), flush=True)


def outliers(seeds):
    """The per-particle gate on and off (robot 1: `seeds` seeds, robot 3: 3), and Q x 4 on robot 1 (3 seeds).

    Seed ``s`` is ``numpy.random.default_rng(1000 + s)`` as in the main study, whose gated robot-1 runs these
    repeat; ATE after the rigid alignment, per seed.
    """
    from slamlib.datasets.mrclam import load_mrclam

    def ate(run, version, s, **kw):
        res = sl.run_fastslam(run, n_particles=50, version=version, rng=np.random.default_rng(1000 + s), **kw)
        return sl.score_trajectory(res.x_est, run.x_true).ate, float(res.rejected.sum())

    for robot, n in ((1, seeds), (3, 3)):
        run = load_mrclam(robot)
        for version in (1, 2):
            for gate in (np.inf, None):
                out = np.array([ate(run, version, s, gate=gate) for s in range(n)])
                print(f"MRCLAM robot {robot}, FastSLAM {version}.0, gate {'off' if gate else 'on '}: ATE mean "
                      f"{out[:, 0].mean():.3f} ({out[:, 0].min():.3f}-{out[:, 0].max():.3f}), per seed "
                      f"{np.array2string(out[:, 0], precision=3)}, rejected {np.array2string(out[:, 1], precision=1)}",
                      flush=True)
    run = load_mrclam(1)
    for version in (1, 2):
        out = np.array([ate(run, version, s, Q=4.0 * run.Q) for s in range(3)])
        print(f"MRCLAM robot 1, FastSLAM {version}.0, Q x 4: ATE mean {out[:, 0].mean():.3f} "
              f"({out[:, 0].min():.3f}-{out[:, 0].max():.3f})", flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10, help="seeds per case (default 10)")
    ap.add_argument("--real-seeds", type=int, default=5, help="seeds per MRCLAM case (default 5; 0: no MRCLAM)")
    ap.add_argument("--real-only", action="store_true",
                    help="only the MRCLAM cases (the same seeds as the full study)")
    ap.add_argument("--outliers", action="store_true",
                    help="instead: the gate's effect (robots 1 and 3, gate off and on, per seed) and Q x 4 on robot 1")
    args = ap.parse_args(argv)
    for name, low in {'seeds': 1, 'real_seeds': 0}.items():  # counts at least 1, seeds at least 0
        value = getattr(args, name)
        if value is not None and min(value if isinstance(value, list) else [value]) < low:
            ap.error(f"--{name.replace('_', '-')} must be at least {low}, got {value}")
    if args.outliers:
        return outliers(args.real_seeds)
    for precise in (() if args.real_only else (False, True)):
        for n in (20, 100):
            for version in (1, 2):
                rows = [measure(chapter_world(s, precise), version, n, s, False) for s in range(args.seeds)]
                summarise(f"sim {'precise sensor' if precise else 'chapter sensor'}, M = {n}, "
                          f"FastSLAM {version}.0", rows)
    from slamlib.datasets.mrclam import load_mrclam

    for robot in ((1, 2) if args.real_seeds else ()):
        run = load_mrclam(robot)
        for version in (1, 2):
            rows = [measure(run, version, 50, s, True) for s in range(args.real_seeds)]
            summarise(f"MRCLAM robot {robot}, M = 50, FastSLAM {version}.0", rows)


if __name__ == "__main__":
    main()
