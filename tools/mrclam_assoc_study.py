"""Does data association, and FastSLAM's defence against wrong sightings, hold on robots it was not set on?

Usage: ``python tools/mrclam_assoc_study.py [--seeds 10] [--out chapters/data/mrclam_assoc_study.json]``

Chapter 9 sets its noise on robot 1 and reads the five-robot table of ``tools/mrclam_table.py``.
This study asks what carries over, with the five robots of MRCLAM Dataset 6 only, in three parts.

1. **Association gates from pooled calibration, leave one robot out.** For each robot, the spread of
   one sighting is measured on the *other four* (RMS of the residuals against Vicon, the gross ones
   beyond the loader's gate under ``MRCLAM_Q`` left out), and EKF SLAM with unknown correspondences
   (Algorithm 2's nearest neighbour, and JCBB) runs on the held-out robot with that
   ``Q_association`` and the chi-square thresholds of the library (``DEFAULT_ALPHA``, the 99.999 %
   point; JCBB's 99 % individual test), next to the robot-1 spread the chapter uses and to the
   inflated ``Q`` of the update (``Q_association=None``), whose gates merge each group of tubes.
2. **Why the association cannot be made reliable here**: for every sighting, from the true pose, the
   squared Mahalanobis distance (under the held-out robot's pooled ``Q_association``) to its own
   landmark and to the nearest *other* landmark. A sighting within the new-landmark threshold of
   another landmark is ambiguous by position, whatever the search.
3. **FastSLAM with many wrong sightings.** On the two robots with the most gross sightings, a share
   of the sightings (``RATES``) is relabelled to another, random landmark (a misread barcode;
   range and bearing stay those of the landmark actually seen), and FastSLAM with known
   correspondences runs over ``--seeds`` seeds (FastSLAM 2.0, the slower: ``--seeds-v2``) with the existence counter of ``run_fastslam``
   (``reinit_lost=True``, the default) and without it; EKF SLAM with known correspondences runs once
   for reference. A run whose aligned ATE exceeds 1 m counts as a failure.

It prints a summary and writes ``chapters/data/mrclam_assoc_study.json``, which chapters 8 and 9 read.
It takes about ten minutes of CPU, most of it FastSLAM; on a loaded machine split it between
processes (``--skip-fastslam``; ``--fastslam-robots 3``; ``--fastslam-robots 5``) and ``--merge``
the outputs.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

import slamlib as sl
from slamlib.datasets.mrclam import MRCLAM_GATE, MRCLAM_Q, MRCLAM_Q_SIGHTING, MRCLAM_ROBOTS, load_mrclam

ROOT = Path(__file__).resolve().parents[1]
FAIL_ATE = 1.0  # metres, as tools/mrclam_table.py
RATES = (0.10,)  # share of sightings relabelled to another landmark


def residuals(run):
    """Sighting residuals against Vicon and the mask of the gross ones (beyond the gate under MRCLAM_Q)."""
    res = sl.measurement_residuals(run.x_true, run.z, run.ids, run.landmarks)
    d = np.einsum("ni,ij,nj->n", res, np.linalg.inv(MRCLAM_Q), res)
    return res, d > MRCLAM_GATE


def pooled_spread(res_by_robot, robots):
    """diag of the RMS range and bearing residuals pooled over `robots`, gross sightings left out."""
    r = np.concatenate([res_by_robot[k][0][~res_by_robot[k][1]] for k in robots])
    return np.diag(np.mean(r**2, axis=0))


def ambiguity(run, Qa, alpha):
    """Shares of sightings, from the true pose and map (no state error): within `alpha` of another landmark,
    and nearer (squared Mahalanobis distance) to another landmark than to their own."""
    Qi = np.linalg.inv(Qa)
    n = amb = closer = 0
    for k, (zk, ik) in enumerate(zip(run.z, run.ids)):
        if len(ik) == 0:
            continue
        x = run.x_true[k + 1]
        zhat = sl.landmark_measurement(np.broadcast_to(x, (len(run.landmarks), 3)), run.landmarks)[0]  # (N, 2)
        nu = zk[:, None, :] - zhat[None]  # (K, N, 2)
        nu[..., 1] = sl.wrap_angle(nu[..., 1])
        d = np.einsum("kni,ij,knj->kn", nu, Qi, nu)
        own = d[np.arange(len(ik)), ik].copy()
        d[np.arange(len(ik)), ik] = np.inf
        amb += int(np.sum(d.min(axis=1) < alpha))
        closer += int(np.sum(d.min(axis=1) < own))
        n += len(ik)
    return amb / n, closer / n


def misread(run, rate, rng):
    """The run with a share `rate` of its sightings relabelled to another landmark, drawn at random."""
    ids = [np.array(i, copy=True) for i in run.ids]
    where = [(t, m) for t, i in enumerate(ids) for m in range(len(i))]
    N = len(run.landmarks)
    for p in rng.choice(len(where), size=int(round(rate * len(where))), replace=False):
        t, m = where[p]
        ids[t][m] = (ids[t][m] + rng.integers(1, N)) % N
    return dataclasses.replace(run, ids=tuple(ids))


def association_part(runs, res):
    out = {}
    for k, run in runs.items():
        others = [r for r in runs if r != k]
        Qk = pooled_spread(res, others)
        amb, closer = ambiguity(run, Qk, sl.DEFAULT_ALPHA)
        row = {"Q_association_std": np.sqrt(np.diag(Qk)).tolist(), "ambiguous_share": amb,
               "nearer_other_share": closer, "methods": {}}
        for assoc in ("nn", "jcbb"):
            for name, Qa in (("robot 1", MRCLAM_Q_SIGHTING), ("other four", Qk), ("update Q", None)):
                t0 = time.perf_counter()
                e = sl.run_ekf_slam(run, known=False, association=assoc, Q_association=Qa)
                secs = time.perf_counter() - t0
                wrong, used, _ = sl.association_errors(e.associations, e.landmark_ids, run.ids)
                sc = sl.score_run("u", e.x, run.x_true, landmarks_est=e.landmarks, landmarks_true=run.landmarks,
                                  match=True, max_dist=1.0)
                row["methods"][f"{assoc} / {name}"] = {"ate": sc.ate, "n_landmarks": sc.n_landmarks,
                                                       "n_wrong": wrong, "n_used": used, "seconds": secs}
        out[str(k)] = row
        print(f"robot {k}: pooled sighting std {np.sqrt(np.diag(Qk)).round(3)}, ambiguous "
              f"{amb:.0%}, nearer another {closer:.0%}; " + ", ".join(f"{m} {v['ate']:.2f}" for m, v in row["methods"].items()),
              flush=True)
    return out


def fastslam_part(runs, res, seeds, seeds_v2, only=None):
    gross = {k: int(res[k][1].sum()) for k in runs}
    worst = sorted(runs, key=lambda k: (-gross[k], k))[:2]
    if only is not None:  # one share of the work (--fastslam-robots), merged later with --merge
        worst = [k for k in worst if k in only]
    out = {"gross_sightings": {str(k): g for k, g in gross.items()}, "robots": [int(k) for k in worst],
           "rates": list(RATES), "cases": {}}
    for k in worst:
        run = runs[k]
        for rate in RATES:
            bad = misread(run, rate, np.random.default_rng(1000 + k))
            e = sl.run_ekf_slam(bad, known=True)
            case = {"ekf_known_ate": sl.score_trajectory(e.x, run.x_true).ate, "ekf_known_gated": e.n_gated}
            for version, reinit in ((1, False), (1, True)) + (((2, False), (2, True)) if seeds_v2 else ()):
                ates = []
                for s in range(seeds if version == 1 else seeds_v2):
                    f = sl.run_fastslam(bad, n_particles=50, rng=np.random.default_rng(s), version=version,
                                        reinit_lost=reinit)
                    ates.append(sl.score_trajectory(f.x_est, run.x_true).ate)
                a = np.array(ates)
                case[f"FastSLAM {version}.0, " + ("counter" if reinit else "gate only")] = {
                    "ate": float(np.median(a)), "ate_min": float(a.min()), "ate_max": float(a.max()),
                    "n_failed": int(np.sum(a > FAIL_ATE)), "n_seeds": a.size, "per_seed_ate": a.tolist()}
            out["cases"][f"{k}/{rate}"] = case
            print(f"robot {k}, {rate:.0%} misread: EKF known {case['ekf_known_ate']:.2f}; " + "; ".join(
                f"{m} {v['ate']:.2f} ({v['n_failed']}/{v['n_seeds']} failed)" for m, v in case.items() if isinstance(v, dict)),
                flush=True)
    return out


def merge(paths, out):
    parts = [json.loads(Path(p).read_text()) for p in paths]
    data = next(p for p in parts if p["association"] is not None)
    fs = [p["fastslam"] for p in parts if p["fastslam"] is not None]
    data["fastslam"] = dict(fs[0], robots=sorted({k for f in fs for k in f["robots"]}),
                            cases={c: v for f in fs for c, v in f["cases"].items()})
    data["command"] = " + ".join(p["command"] for p in parts)
    out.write_text(json.dumps(data, indent=1) + "\n")
    print(f"merged {len(parts)} files into {out}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--seeds-v2", type=int, default=3)
    ap.add_argument("--skip-fastslam", action="store_true", help="parts 1 and 2 only")
    ap.add_argument("--fastslam-robots", type=int, nargs="+", default=None, choices=list(MRCLAM_ROBOTS),
                    help="part 3 only, on these of the two robots (to split the work between processes)")
    ap.add_argument("--merge", type=Path, nargs="+", default=None,
                    help="combine the outputs of split runs (parts 1-2 from the one that has them, part 3's cases "
                         "from all) into --out, and do nothing else")
    ap.add_argument("--fastslam-from", type=Path, default=None,
                    help="copy part 3 (FastSLAM) from this earlier output instead of recomputing it")
    ap.add_argument("--out", type=Path, default=ROOT / "chapters" / "data" / "mrclam_assoc_study.json")
    args = ap.parse_args(argv)
    for name, low in {'seeds': 1, 'seeds_v2': 1}.items():  # counts at least 1, seeds at least 0
        value = getattr(args, name)
        if value is not None and min(value if isinstance(value, list) else [value]) < low:
            ap.error(f"--{name.replace('_', '-')} must be at least {low}, got {value}")
    if args.merge:
        return merge(args.merge, args.out)
    t0 = time.perf_counter()
    runs = {k: load_mrclam(k) for k in MRCLAM_ROBOTS}
    res = {k: residuals(r) for k, r in runs.items()}
    given = [a for a in (sys.argv[1:] if argv is None else argv)]
    if "--out" in given:  # the command that reproduces the numbers, wherever they were written
        del given[given.index("--out"):given.index("--out") + 2]
    data = {"command": " ".join(["python tools/mrclam_assoc_study.py", *given]),
            "fail_ate": FAIL_ATE, "alpha": sl.DEFAULT_ALPHA,
            "association": None if args.fastslam_robots else association_part(runs, res)}
    if args.fastslam_from is not None:
        data["fastslam"] = json.loads(args.fastslam_from.read_text())["fastslam"]
    elif args.skip_fastslam:
        data["fastslam"] = None
    else:
        data["fastslam"] = fastslam_part(runs, res, args.seeds, args.seeds_v2, args.fastslam_robots)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(data, indent=1) + "\n")
    print(f"wrote {args.out} after {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
