"""Chapter 9's five-robot table: every method on every robot of MRCLAM Dataset 6.

Usage: ``python tools/mrclam_table.py [--seeds 10] [--particles 50] [--out chapters/data/mrclam_table.json]``

For each robot (the shipped logs, ``dt = 0.1`` s, the loader's calibrated ``M``, ``Q`` and gate)
it runs dead reckoning, EKF SLAM with known correspondences, EKF SLAM with unknown
correspondences (Algorithm 2's nearest neighbour and JCBB, both with the provisional list off, as
in the chapter, and association gates of the width of one sighting, ``MRCLAM_Q_SIGHTING``), FastSLAM 1.0 and 2.0 with known correspondences over ``--seeds`` seeds
(seed ``s`` is ``numpy.random.default_rng(s)``; both apply the run's gate), and landmark graph SLAM with
known correspondences (chapter 10's :func:`slamlib.landmark_graph_slam_row`: least squares, and the Cauchy
kernel on every edge), and scores them as the chapter does: ATE after the
rigid alignment of the trajectory, landmark RMSE in that frame (unknown correspondences: the
estimated landmarks matched to the true ones within 1 m), landmarks in the map, and for unknown
correspondences the sightings that updated a landmark of another barcode
(:func:`slamlib.association_errors`). It also records the mean NEES of the robot pose of EKF SLAM
with known correspondences with a hand-set noise (``M`` 0.05 m/s, 0.15 rad/s; ``Q`` 0.3 m,
0.03 rad; no gate) and with the calibrated noise and the gate, and the sightings the gate rejected.
FastSLAM runs with its defaults, among them the per-particle gate and the landmark counter
(``reinit_lost``); a seed whose ATE exceeds ``FAIL_ATE`` counts as a failure (``n_failed``).

It prints the table and writes the numbers to a JSON file that chapters 8 and 9 read. It takes
about ten minutes of CPU (most of it FastSLAM); ``--fastslam-from`` copies the FastSLAM rows of an
earlier output with the same seeds and particles and recomputes the rest in a few minutes.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import slamlib as sl
from slamlib.datasets.mrclam import MRCLAM_Q_SIGHTING, MRCLAM_ROBOTS, load_mrclam

ROOT = Path(__file__).resolve().parents[1]
OLD_M = np.diag([0.05**2, 0.15**2])  # a hand-set noise: commands rounded up, Q near the 95th percentile
OLD_Q = np.diag([0.3**2, 0.03**2])
FAIL_ATE = 1.0  # metres: a run whose aligned ATE exceeds this counts as a failure


def mean_nees(result_x, result_S, x_true):
    # skip the first second: the pose covariance starts singular (x0 is given exactly)
    return float(sl.nees(sl.pose_error(result_x[10:], x_true[10:]), result_S[10:]).mean())


def known_map(result, n):
    m, seen = np.zeros((n, 2)), np.zeros(n, dtype=bool)
    m[result.landmark_ids] = result.landmarks
    seen[result.landmark_ids] = True
    return m, seen


def row(score, **extra):
    out = {"ate": score.ate, "landmark_rmse": score.landmark_rmse, "n_landmarks": score.n_landmarks,
           "n_matched": score.n_matched}
    out.update(extra)
    return out


def robot_rows(robot, seeds, particles, fastslam_rows=None):
    run = load_mrclam(robot)
    L = run.landmarks
    rows = {}
    x_dr = sl.dead_reckoning(run.x0, run.u, run.dt)
    rows["dead reckoning"] = row(sl.score_run("dr", x_dr, run.x_true))

    old = sl.run_ekf_slam(run, known=True, M=OLD_M, Q=OLD_Q, gate=np.inf)
    ekf = sl.run_ekf_slam(run, known=True)
    m, seen = known_map(ekf, len(L))
    rows["EKF SLAM, known"] = row(sl.score_run("k", ekf.x, run.x_true, landmarks_est=m, landmarks_true=L, seen=seen),
                                  n_gated=ekf.n_gated)
    m_old, seen_old = known_map(old, len(L))
    old_score = sl.score_run("k", old.x, run.x_true, landmarks_est=m_old, landmarks_true=L, seen=seen_old)
    nees = {"before": mean_nees(old.x, old.Sigma_x, run.x_true), "after": mean_nees(ekf.x, ekf.Sigma_x, run.x_true),
            "before_ate": old_score.ate, "before_landmark_rmse": old_score.landmark_rmse,
            "n_gated": ekf.n_gated}

    for assoc, name in (("nn", "EKF SLAM, unknown (NN)"), ("jcbb", "EKF SLAM, unknown (JCBB)")):
        t0 = time.perf_counter()
        res = sl.run_ekf_slam(run, known=False, association=assoc, Q_association=MRCLAM_Q_SIGHTING)
        elapsed = time.perf_counter() - t0
        wrong, used, split = sl.association_errors(res.associations, res.landmark_ids, run.ids)
        rows[name] = row(sl.score_run(name, res.x, run.x_true, landmarks_est=res.landmarks, landmarks_true=L,
                                      match=True, max_dist=1.0),
                         n_wrong=wrong, n_used=used, n_split=split, n_gated=res.n_gated, seconds=elapsed)

    for version in (1, 2):
        if fastslam_rows is not None:
            rows[f"FastSLAM {version}.0, known"] = fastslam_rows[f"FastSLAM {version}.0, known"]
            continue
        runs = []
        for s in range(seeds):
            f = sl.run_fastslam(run, n_particles=particles, rng=np.random.default_rng(s), known=True, version=version)
            sc = sl.score_run("f", f.x_est, run.x_true, landmarks_est=f.landmarks, landmarks_true=L, seen=f.seen)
            runs.append(row(sc))
        ate = np.array([r["ate"] for r in runs])
        lm = np.array([r["landmark_rmse"] for r in runs])
        rows[f"FastSLAM {version}.0, known"] = {
            "ate": float(np.median(ate)), "ate_min": float(ate.min()), "ate_max": float(ate.max()),
            "landmark_rmse": float(np.median(lm)), "landmark_rmse_min": float(lm.min()),
            "landmark_rmse_max": float(lm.max()), "n_landmarks": int(np.median([r["n_landmarks"] for r in runs])),
            "n_failed": int(np.sum(ate > FAIL_ATE)), "n_seeds": seeds, "per_seed_ate": ate.tolist()}

    # full SLAM (chapter 10): least squares, then the Cauchy kernel on every edge
    for name, kw in (("graph SLAM, known", {}), ("graph SLAM, known, Cauchy", {"robust": "cauchy"})):
        t0 = time.perf_counter()
        sc = sl.landmark_graph_slam_row(run, name=name, **kw)
        rows[name] = row(sc, seconds=time.perf_counter() - t0)
    return {"n_steps": run.n_steps, "duration": float(run.t[-1]), "n_sightings": run.n_sightings,
            "rows": rows, "nees": nees}


def fmt(value, lo=None, hi=None):
    if lo is None:
        return f"{value:5.2f}"
    return f"{value:5.2f} ({lo:.2f}-{hi:.2f})"


def print_table(data):
    for robot, d in data["robots"].items():
        print(f"robot {robot}: {d['duration']:.0f} s, {d['n_sightings']} sightings")
        print(f"  {'method':28s} {'ATE [m]':>20s} {'landmark RMSE [m]':>20s} {'map':>4s} {'wrong':>6s}")
        for name, r in d["rows"].items():
            ate = fmt(r["ate"], r.get("ate_min"), r.get("ate_max"))
            lm = "" if np.isnan(r["landmark_rmse"]) else fmt(r["landmark_rmse"], r.get("landmark_rmse_min"),
                                                               r.get("landmark_rmse_max"))
            wrong = f"{r['n_wrong']:6d}" if "n_wrong" in r else ""
            size = f"{r['n_landmarks']:4d}" if name != "dead reckoning" else ""
            fail = f"  failed {r['n_failed']}/{r['n_seeds']}" if "n_failed" in r else ""
            print(f"  {name:28s} {ate:>20s} {lm:>20s} {size:>4s} {wrong:>6s}{fail}")
        n = d["nees"]
        print(f"  NEES of the pose, EKF SLAM known: {n['before']:.1f} before, {n['after']:.1f} after; "
              f"gated {n['n_gated']}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--particles", type=int, default=50)
    ap.add_argument("--robots", type=int, nargs="+", default=list(MRCLAM_ROBOTS), choices=list(MRCLAM_ROBOTS))
    ap.add_argument("--out", type=Path, default=ROOT / "chapters" / "data" / "mrclam_table.json")
    ap.add_argument("--fastslam-from", type=Path, default=None,
                    help="copy the FastSLAM rows from this earlier output (same seeds and particles) instead of "
                         "recomputing them")
    args = ap.parse_args(argv)
    for name, low in {'seeds': 1, 'particles': 1}.items():  # counts at least 1, seeds at least 0
        value = getattr(args, name)
        if value is not None and min(value if isinstance(value, list) else [value]) < low:
            ap.error(f"--{name.replace('_', '-')} must be at least {low}, got {value}")
    t0 = time.perf_counter()
    data = {"command": "python tools/mrclam_table.py " + f"--seeds {args.seeds} --particles {args.particles}",
            "seeds": args.seeds, "particles": args.particles, "fail_ate": FAIL_ATE, "robots": {}}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    earlier = json.loads(args.fastslam_from.read_text()) if args.fastslam_from else None
    if earlier and (earlier["seeds"], earlier["particles"]) != (args.seeds, args.particles):
        raise SystemExit(f"{args.fastslam_from} has {earlier['seeds']} seeds and {earlier['particles']} particles")
    for r in args.robots:
        fs = earlier["robots"][str(r)]["rows"] if earlier else None
        data["robots"][str(r)] = robot_rows(r, args.seeds, args.particles, fs)
        print(f"robot {r} done after {time.perf_counter() - t0:.0f} s", flush=True)
        args.out.write_text(json.dumps(data, indent=1, sort_keys=False) + "\n")  # after each robot
    print_table(data)
    print(f"wrote {args.out.relative_to(ROOT) if args.out.is_relative_to(ROOT) else args.out}")


if __name__ == "__main__":
    main()
