"""Speed of scan matching and mapping, each figure against a baseline timed in this run.

Run ``python benchmarks/bench_scan_matching.py``. It prints

(a) ICP (``slamlib.icp``, point-to-line and point-to-point) aligning two
    consecutive 180-beam scans of the CMU Wean Hall log (target <= 2 ms per
    call), against the textbook ICP of the same number of rounds with the
    nearest neighbours found from the dense distance matrix (a bare NumPy
    expression) and the closed-form step;
(b) scan-matching odometry over the whole log (135 s): point-to-line ICP
    between consecutive keyframes from the odometry increment, as the front end
    of ``slamlib.run_lidar_slam`` does, and between every pair of consecutive
    scans, as multiples of real time (target >= 20x), against the same loop with
    the dense-matrix ICP of (a);
(c) the occupancy-grid update of one scan at 10 cm resolution (cells of all
    180 beams found, classified and added to the log odds of an 800 x 800 grid;
    target <= 1 ms), against a per-beam Python loop (the Amanatides-Woo walk,
    one beam and one cell at a time) computing the same cells.

Times are medians over repeats (``time.perf_counter``); the machine's load
shows in the absolute figures, less in the ratios. The whole run takes about a
minute.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

import slamlib as sl  # noqa: E402
from slamlib import mapping as mp  # noqa: E402
from slamlib.datasets import cmu  # noqa: E402
from bench_localization import median_time  # noqa: E402  (the same timer as the other benchmarks)


# --------------------------------------------------------------------------- baselines
def dense_icp(src, tgt, init, rounds, max_dist=0.3):
    """Textbook point-to-point ICP: dense (N, M) distance matrix for the neighbours, closed-form step."""
    pose = init.copy()
    for _ in range(rounds):
        c, s = np.cos(pose[2]), np.sin(pose[2])
        moved = src @ np.array([[c, s], [-s, c]]) + pose[:2]
        d2 = ((moved[:, None, :] - tgt[None, :, :]) ** 2).sum(-1)
        j = d2.argmin(axis=1)
        keep = d2[np.arange(j.size), j] <= max_dist**2
        R, t = sl.icp_align(src[keep], tgt[j[keep]])
        pose = np.array([t[0], t[1], np.arctan2(R[1, 0], R[0, 0])])
    return pose


def loop_scan_cells(spec, pose, ranges, angles, z_max, params, off):
    """The cells of one scan, one beam and one cell at a time (Amanatides-Woo in plain Python)."""
    H, W = spec.shape
    res = spec.resolution
    ox, oy = spec.origin
    sx, sy = pose[0] + off * np.cos(pose[2]), pose[1] + off * np.sin(pose[2])
    occ, free = set(), set()
    for z, a in zip(ranges, angles):
        hit = z < min(z_max, params.range_limit)
        zz = z if hit else min(z_max, params.range_limit)
        reach = zz + params.alpha / 2 if hit else zz
        ex, ey = sx + reach * np.cos(pose[2] + a), sy + reach * np.sin(pose[2] + a)
        gx, gy, hx, hy = (sx - ox) / res, (sy - oy) / res, (ex - ox) / res, (ey - oy) / res
        cx, cy = int(np.floor(gx)), int(np.floor(gy))
        endx, endy = int(np.floor(hx)), int(np.floor(hy))
        dx, dy = hx - gx, hy - gy
        stx, sty = (1 if dx > 0 else -1), (1 if dy > 0 else -1)
        tmx = ((cx + (stx > 0)) - gx) / dx if dx != 0 else np.inf
        tmy = ((cy + (sty > 0)) - gy) / dy if dy != 0 else np.inf
        tdx = abs(1 / dx) if dx != 0 else np.inf
        tdy = abs(1 / dy) if dy != 0 else np.inf
        while True:
            if 0 <= cx < W and 0 <= cy < H:
                r = np.hypot(ox + (cx + 0.5) * res - sx, oy + (cy + 0.5) * res - sy)
                if hit and abs(r - zz) < params.alpha / 2:
                    occ.add(cy * W + cx)
                elif r <= zz:
                    free.add(cy * W + cx)
            if cx == endx and cy == endy:
                break
            if tmx < tmy:
                cx += stx
                tmx += tdx
            else:
                cy += sty
                tmy += tdy
    return occ, free - occ


def main(argv=None):
    argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter).parse_args(argv)
    log = cmu.load_cmu_log()
    duration = float(log.laser_t[-1] - log.laser_t[0])
    index, _ = sl.odometry_steps(log.laser_pose)
    pts = [sl.scan_to_points(r, log.angles, max_range=40.0, sensor_offset=log.sensor_offset) for r in log.ranges]
    print(f"CMU Wean Hall log: {log.n_scans} scans of 180 beams in {duration:.1f} s, {index.size} keyframes\n")

    # (a) one ICP call
    a, b = index[50], index[51]
    init = sl.relative(log.laser_pose[a], log.laser_pose[b])
    print("(a) ICP on two consecutive 180-beam scans (per call)")
    for method in ("point_to_line", "point_to_point"):
        res = sl.icp(pts[b], pts[a], init, method=method)
        t_icp = median_time(lambda: sl.icp(pts[b], pts[a], init, method=method), 200, warmup=5)
        t_dense = median_time(lambda: dense_icp(pts[b], pts[a], init, res.iterations), 50, warmup=2)
        print(f"    {method:15s} {1e3 * t_icp:6.2f} ms ({res.iterations:2d} rounds; target <= 2 ms)   "
              f"dense-matrix ICP, same rounds: {1e3 * t_dense:6.2f} ms   ratio {t_dense / t_icp:5.1f}x")

    # (b) scan-matching odometry over the whole log
    print("\n(b) scan-matching odometry over the whole log (multiples of real time; target >= 20x)")

    def odometry(pairs, matcher):
        x = log.laser_pose[pairs[0][0]].copy()
        for i, j in pairs:
            x = sl.compose(x, matcher(i, j))
        return x

    def slam_icp(i, j):
        return sl.icp(pts[j], pts[i], sl.relative(log.laser_pose[i], log.laser_pose[j])).pose

    def textbook(i, j):
        return dense_icp(pts[j], pts[i], sl.relative(log.laser_pose[i], log.laser_pose[j]), 10)

    for name, pairs in (("keyframes", list(zip(index[:-1], index[1:]))),
                        ("every scan", list(zip(range(log.n_scans - 1), range(1, log.n_scans))))):
        t_fast = median_time(lambda: odometry(pairs, slam_icp), 3, warmup=0)
        t_base = median_time(lambda: odometry(pairs, textbook), 1, warmup=0)
        print(f"    {name:10s} ({len(pairs):3d} matches): slamlib ICP {t_fast:5.2f} s = {duration / t_fast:6.1f}x real time"
              f"   dense-matrix ICP (10 rounds) {t_base:5.2f} s = {duration / t_base:5.1f}x   ratio {t_base / t_fast:4.1f}x")

    # (c) occupancy-grid update of one scan
    print("\n(c) occupancy-grid update of one scan, 10 cm cells, 800 x 800 grid (target <= 1 ms)")
    params = mp.OccupancyParams()
    spec = mp.GridSpec((-40.0, -40.0), 0.1, (800, 800))
    logodds = np.zeros(spec.shape)
    seen = np.zeros(spec.shape, dtype=bool)
    ks = index[::10]

    def update_all():
        for k in ks:
            occ, free = mp._scan_cells(spec, log.laser_pose[k], log.ranges[k], log.angles, log.max_range, params,
                                       log.sensor_offset)
            mp._apply(logodds, seen, occ, free, params)

    def loop_all():
        for k in ks[:5]:
            loop_scan_cells(spec, log.laser_pose[k], log.ranges[k], log.angles, log.max_range, params,
                            log.sensor_offset)

    # the two compute the same cells
    k = ks[3]
    occ, free = mp._scan_cells(spec, log.laser_pose[k], log.ranges[k], log.angles, log.max_range, params,
                               log.sensor_offset)
    occ_l, free_l = loop_scan_cells(spec, log.laser_pose[k], log.ranges[k], log.angles, log.max_range, params,
                                    log.sensor_offset)
    same = set(occ.tolist()) == occ_l and set(free.tolist()) == free_l
    t_up = median_time(update_all, 5) / len(ks)
    t_loop = median_time(loop_all, 1) / 5
    print(f"    vectorised {1e3 * t_up:6.3f} ms per scan   per-beam Python loop {1e3 * t_loop:7.2f} ms   "
          f"ratio {t_loop / t_up:5.0f}x   (same cells: {same})")


if __name__ == "__main__":
    main()
