"""Lidar SLAM on the CMU Wean Hall log over several settings and seeds, failures included.

Runs :func:`slamlib.lidar_slam.run_lidar_slam` with the default settings and with one change at a
time (beam subsampling, keyframe spacing, start of the log, loop-closure radius, noise on every ICP
initial guess over several seeds) and prints, per run, the ATE against the MCL reference track and
the agreement of the map with the shipped Wean Hall map for raw odometry, ICP odometry and ICP with
loop closures. Usage: ``python tools/lidar_slam_robustness.py`` (about a minute on 2 cores). It writes
every run to ``chapters/data/lidar_slam_robustness.json``, which chapter 11 reads.
"""

import argparse
import json
import time
from pathlib import Path

import numpy as np

import slamlib as sl
from slamlib import lidar_slam as ls
from slamlib.datasets import cmu

MAP_THRESHOLD = 0.80  # occupied-cell agreement a run must reach (see tests/test_lidar_slam.py)
OUT = Path(__file__).resolve().parents[1] / "chapters" / "data" / "lidar_slam_robustness.json"


def main(argv=None):
    argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter).parse_args(argv)
    grid, log = cmu.load_cmu_map(), cmu.load_cmu_log()
    ref = ls.cmu_reference_track(grid, log, rng=np.random.default_rng(99))
    base = ls.LidarSlamParams()
    runs = [("default", {}, {})]
    runs += [(f"one beam in {k}", {"beam_step": k}, {}) for k in (2, 3)]
    runs += [(f"keyframes {d} m", {"min_translation": d}, {}) for d in (0.1, 0.4)]
    runs += [(f"start at scan {s}", {}, {"start": s}) for s in (40, 120)]
    runs += [(f"loop radius {r} m", {"loop_radius": r}, {}) for r in (1.0, 3.0)]
    runs += [(f"guess noise 3 cm/1 deg seed {s}", {}, {"rng": np.random.default_rng(s),
                                                      "init_noise": (0.03, np.deg2rad(1.0))}) for s in range(5)]
    runs += [(f"guess noise 10 cm/3 deg seed {s}", {}, {"rng": np.random.default_rng(s),
                                                       "init_noise": (0.1, np.deg2rad(3.0))}) for s in range(2)]
    print(f"{'run':32s} {'odometry':>15s} {'ICP odometry':>15s} {'ICP + loops':>15s} {'loops':>7s} {'time':>6s}  verdict")
    print(f"{'':32s} {'ATE m / map':>15s} {'ATE m / map':>15s} {'ATE m / map':>15s}")
    records = []
    for name, change, kw in runs:
        params = sl.lidar_slam.LidarSlamParams(**{**base.__dict__, **change})
        t0 = time.perf_counter()
        try:
            res = ls.run_lidar_slam(log.laser_pose, log.ranges, log.angles, z_max=log.max_range,
                                    sensor_offset=log.sensor_offset, params=params, **kw)
        except Exception as exc:  # a failure is a result too
            print(f"{name:32s} FAILED: {type(exc).__name__}: {exc}")
            records.append({"name": name, "error": f"{type(exc).__name__}: {exc}"})
            continue
        dt = time.perf_counter() - t0
        rows = ls.score_lidar_slam(res, ref.scan_index, ref.mean, log.laser_pose, log.ranges, log.angles, grid,
                                   z_max=log.max_range, sensor_offset=log.sensor_offset)
        cells = " ".join(f"{r.ate:5.2f} / {r.occupied:.3f}" for r in rows)
        n_loops = len(res.edges) - res.n_sequential
        slam = rows[2]
        ok = slam.occupied >= MAP_THRESHOLD and slam.ate <= rows[0].ate
        print(f"{name:32s} {cells} {n_loops:4d}/{res.loop_tried:<3d} {dt:5.1f}s  {'ok' if ok else 'FAIL'}")
        records.append({"name": name, "ate": {r.name: float(r.ate) for r in rows},
                        "occupied": {r.name: float(r.occupied) for r in rows}, "loops": int(n_loops),
                        "loop_tried": int(res.loop_tried), "ok": bool(ok)})
    OUT.write_text(json.dumps({"command": "python tools/lidar_slam_robustness.py", "threshold": MAP_THRESHOLD,
                               "runs": records}, indent=1) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
