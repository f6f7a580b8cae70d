"""Stereo visual odometry's parameters chosen by cross-validation, and checked for robustness.

**Cross-validation on the shipped drive.** The 77 frames of ``load_kitti_vo`` are split in two
halves (frames 0-38 and 38-76, each run as a drive of its own from its first reference pose). On
one half (training) the parameters of :func:`slamlib.stereo_visual_odometry` are chosen by
coordinate descent from ``START``: each parameter in turn is set to the value of its grid
(``GRID``) with the lowest training score, the others held, until a whole sweep changes nothing;
a parameter moves only for a gain larger than ``MARGIN`` (1 %) that a block bootstrap of the
paired per-segment differences confirms. The score is the mean over RANSAC seeds of the mean
relative translation error (% of the distance travelled, segments of ``DELTA`` frames; the KITTI
benchmark ranks by it). The choice
is then reported on the other half (test), both ways, with the standard metrics: ATE after the
rigid alignment, RPE in translation (%) and rotation (deg/m); the spread is given over RANSAC
seeds and by a block bootstrap of the segments (blocks of ``DELTA`` segments, 90 % interval).
The parameters finally chosen are those of the same descent on the sum of both halves' scores.

The reference is the set of poses shipped with the measurements (not KITTI's ground truth; see
``slamlib/data/kitti_vo/ATTRIBUTION.md``), so this selects the parameters that agree best with it.

**Robustness.** The final choice on the whole drive with many RANSAC seeds; and on simulated
stereo drives with known truth (``simulate_stereo_drive``: the same rig, wrong tracks at several
rates, pixel noise at two levels, several seeded drives), against one-at-a-time changes of the
parameters that guard against wrong tracks (RANSAC threshold, kernel width and kernel).

    python benchmarks/vo_study.py --json chapters/data/vo_study.json   # the chapter's data

Finished runs are appended to a cache file (``--cache``), so an interrupted study resumes.
Run it under ``nice -n 10``; one BLAS thread is set below.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import slamlib as sl  # noqa: E402
from slamlib.datasets import load_kitti_vo, simulate_stereo_drive, stereo_vo_segment  # noqa: E402

DELTA = 10  # frames per RPE segment
MARGIN = 0.01  # a parameter moves only for an improvement of more than 1 % of the score
#: Values tried for each parameter (the library's default among them).
GRID = {
    "threshold": [0.5, 1.0, 2.0, 4.0],
    "ransac_iterations": [25, 100, 500],
    "max_depth": [20.0, 40.0, 80.0],
    "window": [3, 5, 8],
    "ba_iterations": [2, 4, 8],
    "robust": ["cauchy", "huber"],
    "robust_scale": [1.0, 2.45, 6.0],
}
START = {"threshold": 1.0, "ransac_iterations": 500, "max_depth": 40.0, "window": 5, "ba_iterations": 8,
         "robust": "cauchy", "robust_scale": 2.45}
HALVES = {"first": (0, 39), "second": (38, 77)}
CV_SEEDS = (0, 1)
SIM = {"outlier_rate": [0.0, 0.1, 0.3], "noise_px": [0.3, 1.0], "drives": (0, 1), "n_frames": 40}


def _key(*parts):
    return json.dumps(parts, sort_keys=True)


class Runs:
    """Runs of visual odometry, cached in a JSON-lines file (one finished run per line)."""

    def __init__(self, path):
        self.path, self.done = path, {}
        if path and os.path.exists(path):
            with open(path) as f:
                for line in f:
                    if line.strip():
                        rec = json.loads(line)
                        self.done[rec["key"]] = rec
        self.data = load_kitti_vo()
        self._drives = {}
        self.new = 0
        self.used = set()

    def drive(self, name):
        if name not in self._drives:
            if name in HALVES:
                self._drives[name] = stereo_vo_segment(self.data, *HALVES[name])
            elif name == "all":
                self._drives[name] = self.data
            else:  # "sim/<rate>/<noise>/<drive seed>"
                _, rate, noise, seed = name.split("/")
                self._drives[name] = simulate_stereo_drive(rng=np.random.default_rng(1000 + int(seed)),
                                                           n_frames=SIM["n_frames"], outlier_rate=float(rate),
                                                           noise_px=float(noise))
        return self._drives[name]

    def run(self, drive, params, seed):  # noqa: D102
        key = _key(drive, params, seed)
        self.used.add(key)
        if key not in self.done:
            d = self.drive(drive)
            t0 = time.process_time()
            try:
                vo = sl.stereo_visual_odometry(d, rng=np.random.default_rng(seed), **params)
                trans, rot = sl.relative_pose_errors(vo.T_wc, d.T_wc, delta=DELTA)
                ate = sl.trajectory_errors(vo.T_wc, d.T_wc, delta=DELTA, align=True)[0]
                rec = {"ok": True, "ate": ate, "trans": trans.tolist(), "rot": rot.tolist()}
            except (ValueError, np.linalg.LinAlgError) as exc:  # a failed run counts, it is not skipped
                rec = {"ok": False, "error": str(exc)}
            rec.update(key=key, cpu=time.process_time() - t0)
            self.done[key] = rec
            self.new += 1
            if self.path:
                with open(self.path, "a") as f:
                    f.write(json.dumps(rec) + "\n")
        return self.done[key]

    def segments(self, drives, params, seeds):
        """Per-segment translation RPE [%], averaged over seeds, the drives' segments end to end (inf: a run failed)."""
        out = []
        for drive in drives:
            recs = [self.run(drive, params, s) for s in seeds]
            if not all(r["ok"] for r in recs):
                return None
            out.append(np.mean([r["trans"] for r in recs], axis=0))
        return np.concatenate(out)


def descend(runs, drives, seeds, start=START, log=print):
    """Coordinate descent over ``GRID`` from ``start``; returns the choice and its path.

    A parameter moves to another value only when it is better by more than ``MARGIN`` of the
    current score and the block bootstrap of the paired per-segment differences says so too (the
    95th percentile of the mean difference below zero); among such values, the one with the
    lowest mean. Differences the segments cannot resolve leave the
    parameter where it is.
    """
    cur, path = dict(start), []
    rng = np.random.default_rng(0)
    for sweep in range(4):
        changed = False
        for name, values in GRID.items():
            here = runs.segments(drives, cur, seeds)
            row = {}
            for v in values:
                seg = runs.segments(drives, {**cur, name: v}, seeds)
                if seg is None:
                    row[json.dumps(v)] = {"score": None, "better": False}
                    continue
                diff = seg - here
                hi = _boot_upper(diff, DELTA, rng)
                row[json.dumps(v)] = {"score": float(seg.mean()), "diff": float(diff.mean()), "diff_p95": hi,
                                      "better": bool(v != cur[name] and hi < 0 and diff.mean() < -MARGIN * here.mean())}
            better = [v for v in values if row[json.dumps(v)]["better"]]
            if better:
                best = min(better, key=lambda v: row[json.dumps(v)]["score"])
                changed = True
                log(f"  sweep {sweep}: {name} {cur[name]} -> {best} "
                    f"({here.mean():.4f} -> {row[json.dumps(best)]['score']:.4f} %)")
                cur[name] = best
            path.append({"sweep": sweep, "parameter": name, "values": row, "value": cur[name]})
        if not changed:
            break
    return cur, path


def _boot_upper(diff, block, rng, n=2000):
    """95th percentile of the block-bootstrap mean of ``diff`` (serially correlated segments)."""
    if np.all(diff == 0):
        return 0.0
    lo_hi = block_bootstrap(diff, block, rng, n)
    return lo_hi[1]


def block_bootstrap(x, block, rng, n=2000):
    """90 % interval of the mean of the (serially correlated) per-segment errors ``x``."""
    x = np.asarray(x)
    nb = int(np.ceil(len(x) / block))
    starts = rng.integers(0, len(x) - block + 1, (n, nb))
    idx = (starts[:, :, None] + np.arange(block)).reshape(n, -1)[:, :len(x)]
    means = x[idx].mean(axis=1)
    return [float(np.percentile(means, 5)), float(np.percentile(means, 95))]


def summary(runs, drive, params, seeds, rng):
    recs = [runs.run(drive, params, s) for s in seeds]
    ok = [r for r in recs if r["ok"]]
    out = {"runs": len(recs), "failed": len(recs) - len(ok), "cpu_s": float(np.mean([r["cpu"] for r in recs]))}
    if not ok:
        return out
    t = np.array([np.mean(r["trans"]) for r in ok])
    rot = np.array([np.mean(r["rot"]) for r in ok])
    ate = np.array([r["ate"] for r in ok])
    med = ok[int(np.argsort(t)[len(t) // 2])]  # the median seed's segments, for the bootstrap
    out.update(
        rpe_trans=float(t.mean()), rpe_trans_seeds=[float(t.min()), float(np.median(t)), float(t.max())],
        rpe_trans_boot=block_bootstrap(med["trans"], DELTA, rng),
        rpe_trans_segments=[float(np.percentile(med["trans"], q)) for q in (10, 50, 90)],
        rpe_rot=float(rot.mean()), rpe_rot_seeds=[float(rot.min()), float(np.median(rot)), float(rot.max())],
        rpe_rot_boot=block_bootstrap(med["rot"], DELTA, rng),
        ate=float(ate.mean()), ate_seeds=[float(ate.min()), float(np.median(ate)), float(ate.max())])
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cache", default=os.path.join(os.path.dirname(__file__), "..", "_build", "vo_study_cache.jsonl"))
    ap.add_argument("--json", help="write the study's results here (the chapter reads chapters/data/vo_study.json)")
    ap.add_argument("--seeds", type=int, default=20, help="RANSAC seeds of the robustness runs on the whole drive")
    args = ap.parse_args(argv)
    for name, low in {'seeds': 1}.items():  # counts at least 1, seeds at least 0
        value = getattr(args, name)
        if value is not None and min(value if isinstance(value, list) else [value]) < low:
            ap.error(f"--{name.replace('_', '-')} must be at least {low}, got {value}")
    os.makedirs(os.path.dirname(os.path.abspath(args.cache)), exist_ok=True)
    runs = Runs(args.cache)
    rng = np.random.default_rng(16)
    t0 = time.process_time()
    out = {"grid": GRID, "start": START, "halves": HALVES, "delta": DELTA, "cv_seeds": list(CV_SEEDS),
           "segment_m": float(DELTA * np.mean(np.linalg.norm(np.diff(runs.data.T_wc[:, :3, 3], axis=0), axis=1)))}
    # cross-validation, both ways
    folds = []
    for train, test in (("first", "second"), ("second", "first")):
        print(f"choose on the {train} half:")
        choice, path = descend(runs, [train], CV_SEEDS)
        fold = {"train": train, "test": test, "choice": choice, "path": path,
                "test_choice": summary(runs, test, choice, CV_SEEDS, rng),
                "test_start": summary(runs, test, START, CV_SEEDS, rng)}
        folds.append(fold)
        print(f"  choice {choice}\n  on the {test} half: RPE {fold['test_choice']['rpe_trans']:.4f} % "
              f"(start point {fold['test_start']['rpe_trans']:.4f} %)")
    out["folds"] = folds
    print("choose on both halves:")
    final, path = descend(runs, ["first", "second"], CV_SEEDS)
    out["final"], out["final_path"] = final, path
    print(f"  final {final}")
    # robustness: RANSAC seeds on the whole drive
    seeds = list(range(100, 100 + args.seeds))
    out["seeds_all"] = {"seeds": len(seeds), "final": summary(runs, "all", final, seeds, rng),
                        "start": summary(runs, "all", START, seeds[:5], rng)}
    print(f"whole drive, {len(seeds)} seeds: RPE {out['seeds_all']['final']['rpe_trans_seeds']} %, "
          f"ATE {out['seeds_all']['final']['ate_seeds']} m")
    # robustness: simulated drives with known truth
    variants = {"final": final}
    for name in ("threshold", "robust_scale", "robust"):
        for v in GRID[name]:
            if v != final[name]:
                variants[f"{name}={v}"] = {**final, name: v}
    sim = []
    for rate in SIM["outlier_rate"]:
        for noise in SIM["noise_px"]:
            drives = [f"sim/{rate}/{noise}/{s}" for s in SIM["drives"]]
            row = {"outlier_rate": rate, "noise_px": noise, "variants": {}}
            for vname, params in variants.items():
                recs = [runs.run(d, params, 0) for d in drives]
                ok = [r for r in recs if r["ok"]]
                row["variants"][vname] = {
                    "failed": len(recs) - len(ok),
                    "rpe_trans": float(np.mean([np.mean(r["trans"]) for r in ok])) if ok else None,
                    "rpe_rot": float(np.mean([np.mean(r["rot"]) for r in ok])) if ok else None,
                    "ate": float(np.mean([r["ate"] for r in ok])) if ok else None}
            best = min((v for v in row["variants"].values() if v["rpe_trans"] is not None and not v["failed"]),
                       key=lambda v: v["rpe_trans"])
            row["final_over_best"] = row["variants"]["final"]["rpe_trans"] / best["rpe_trans"]
            sim.append(row)
            print(f"sim outliers {rate:.1f} noise {noise} px: final RPE {row['variants']['final']['rpe_trans']:.3f} %, "
                  f"ATE {row['variants']['final']['ate']:.3f} m, {row['final_over_best']:.2f}x the best variant")
    out["sim"] = {"config": SIM, "variants": list(variants), "rows": sim}
    out["margin"] = MARGIN
    out["cpu_s_this_run"] = time.process_time() - t0
    out["cpu_s_all_runs"] = float(sum(runs.done[k]["cpu"] for k in runs.used))
    out["new_runs_this_run"] = runs.new
    print(f"{runs.new} new runs, {out['cpu_s_this_run']:.0f} s CPU; the study's {len(runs.used)} runs took "
          f"{out['cpu_s_all_runs']:.0f} s CPU in all")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1, sort_keys=True)
            f.write("\n")
    return out


if __name__ == "__main__":
    main()
