"""Hold-out evaluation of global MCL: trials that no tuning has seen, judged like ``mcl_study.py``.

``benchmarks/mcl_study.py`` is where MCL's mechanisms and defaults are chosen. Its simulated drives
use the filter's own models calibrated to the robot (the beam model of ``MCLParams`` with the Wean
Hall laser's range bias, ``cmu.CMU_RANGE_BIAS``; the odometry model with the robot's noise, a third of
the filter's ``alpha`` in standard deviation), and its log trials start at ten fixed offsets. This script is the data the tuning never
saw, with the study's criteria (``judge`` and ``summarize`` are imported from it):

* **sim** (model mismatch): drives in the Wean Hall map from a reactive wander controller (follows
  the most open direction, with a drifting turn preference, turns in place now and then), started
  anywhere in free space with 0.35 m clearance, at a speed of 0.15-0.7 m/s with 0.05-0.4 m between
  scans (the filter picks its own updates). Per trial, drawn independently of the study's generator
  from a different base seed:

  - unmodelled obstacles: 0-8 discs of radius 0.15-0.4 m (people, boxes) near the start that the
    map lacks, and passers-by (a block of 5-20 beams cut short in 20 % of the scans);
  - beam noise other than the filter's mixture: Gaussian hit noise 1-2x the filter's ``sigma_hit``
    plus a noise correlated across neighbouring beams (a misregistered map), 5-20 % short readings,
    2-6 % random readings, 2-10 % max-range dropouts in runs of 3-12 beams, a laser mounted up to
    1 degree off;
  - odometry with systematic error (translation scale off by 2-5 %, rotation scale by up to 3 %, a
    rotational drift of 0.2-1 degree per metre) and random-walk noise with 1.5-3x the variance of the
    filter's ``alpha`` over an update (0.2 m or 0.2 rad).

* **logs**: the two shipped logs, started between the study's start offsets (midway between two of
  them, then a random number of scans further, so even the update grid differs) and run for
  horizons of 20-120 updates instead of the study's 40; the truth is the reference track of
  ``mcl_success.py``, computed once and kept in a file beside the cache, so every configuration
  (and every library version) is judged against the same truth.

* **control** (a diagnostic, ``--sets ... control``): the sim set's drives (the same true poses)
  sensed with the filter's own models: scans of the map without the obstacles with the beam mixture,
  odometry without bias with the filter's ``alpha``. Its gap to **sim** is the mismatch's share of the
  failures; its gap to the study's simulated set is the drives' share.

``--tracking-check`` runs plain MCL started at the truth on every simulated trial (computed once, by
the first tree evaluated, and read from a file after): the trials it tracks are those a global
localizer can solve at all, and strict success is also printed on that subset.

Success and confidently-wrong are the study's: strict success = the estimate within 0.5 m at every
update of the second half; confidently wrong = more than 0.5 m off while ``mode_mass`` > 0.9. Rates
come with Wilson 95 % intervals (log trials of one log overlap: their interval is optimistic).

Configurations: ``defaults`` (``MCLParams()`` with ``run_mcl``'s default variant), ``plain MCL``
(Table 8.2 as printed, as in ``mcl_study.py``: ``variant="mcl"``, a uniform start and the estimate at the
mode's mean, ``init_candidates=0, estimate_radius=0``; a tree without these parameters refuses them) and ``overrides`` (``--set KEY=VALUE`` and ``--variant``,
as ``mcl_success.py`` takes them). ``--slamlib DIR`` evaluates the ``slamlib`` of another tree (the
trials and references are the cached ones, so the trees are judged on identical data); every run is
cached under its configuration and a hash of the ``slamlib`` source that ran it, so an interrupted
evaluation resumes and two library versions never share a cached run.

    nice -n 10 python benchmarks/mcl_holdout.py                          # defaults and plain MCL
    nice -n 10 python benchmarks/mcl_holdout.py --sets sim logs control --tracking-check --json chapters/data/mcl_holdout.json   # chapter 5's data
    nice -n 10 python benchmarks/mcl_holdout.py --slamlib ../other-tree  # another tree's defaults
    nice -n 10 python benchmarks/mcl_holdout.py --configs overrides --set likelihood_exponent=0.1
    python benchmarks/mcl_holdout.py --compare a.json b.json               # their tables side by side

This evaluates; it must never be used to choose a parameter.
"""

from __future__ import annotations

import argparse
import gzip
import hashlib
import json
import os
import pickle
import subprocess
import sys
import tempfile
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

_HERE = os.path.dirname(os.path.abspath(__file__))
_ROOT = os.path.dirname(_HERE)


def _slamlib_dir(argv):
    """The tree whose ``slamlib`` is evaluated (``--slamlib DIR``; this tree by default)."""
    for i, a in enumerate(argv):
        if a == "--slamlib" and i + 1 < len(argv):
            return os.path.abspath(argv[i + 1])
        if a.startswith("--slamlib="):
            return os.path.abspath(a.split("=", 1)[1])
    return _ROOT


_LIB = _slamlib_dir(sys.argv[1:] if __name__ == "__main__" else [])
sys.path.insert(0, _LIB)

import numpy as np  # noqa: E402

import slamlib as sl  # noqa: E402
from slamlib.datasets import cmu  # noqa: E402

sys.path.insert(1, _HERE)  # the judging code of this tree's study (slamlib is already imported above)
from mcl_study import (CONFIDENT, RADIUS, TRUTH_SPREAD, judge, resumable_runs, summarize,  # noqa: E402,F401
                       truth_at, wilson)
from mcl_success import make_params as _success_params  # noqa: E402
from mcl_success import reference_track  # noqa: E402

BASE_SEED = 1717  # the study's is 2026
STUDY_SEED, STUDY_OFFSETS, STUDY_UPDATES = 2026, 10, 40  # mcl_study.py's defaults: its log offsets are avoided
HORIZONS = (120, 90, 60, 30, 20)  # updates per log trial, longest first (assigned to the earliest starts)

# the generator's reference noise: the library's defaults when this file was written, fixed here so the
# trials do not move when a library changes its defaults
REF_SIGMA_HIT = 0.3
REF_LAMBDA_SHORT = 0.1
REF_ALPHA = np.array([0.05, 0.005, 0.05, 0.005])
OCCUPIED, FREE = 0.9, 0.1
START_CLEARANCE = 0.35  # [m] from the nearest wall at the start
ROBOT_RADIUS = 0.25  # [m] the drive keeps this far from walls and obstacles
SUB = 0.05  # [m] (or rad / 1 for turns) per control sub-step of the drive
SPIN_RATE = 0.05  # [rad] per sub-step of a turn in place
WANDER_RAYS = np.deg2rad(np.arange(-90, 91, 10))

_WORK = {}


# --------------------------------------------------------------------------- simulated trials
def draw_mismatch(rng):
    """One trial's deviations from the filter's models."""
    sign = lambda: float(rng.choice([-1.0, 1.0]))  # noqa: E731
    return dict(
        speed=float(rng.uniform(0.15, 0.7)),  # [m/s]
        scan_step=float(SUB * rng.integers(1, 9)),  # [m] between scans: 0.05 .. 0.4
        n_obstacles=int(rng.integers(0, 9)),
        obstacle_radius=(0.15, 0.4),
        passer_by=0.2,  # share of scans with a block of beams cut short
        sigma_factor=float(rng.uniform(1.0, 2.0)),
        correlated_sigma=float(rng.uniform(0.02, 0.1)),  # [m], smooth over ~15 beams
        p_short=float(rng.uniform(0.05, 0.2)),
        p_rand=float(rng.uniform(0.02, 0.06)),
        p_dropout=float(rng.uniform(0.02, 0.1)),
        p_max=0.0,  # single max-range readings (the filter's mixture; the control set only)
        laser_yaw=float(np.deg2rad(rng.uniform(-1.0, 1.0))),
        trans_scale=sign() * float(rng.uniform(0.02, 0.05)),
        rot_scale=sign() * float(rng.uniform(0.0, 0.03)),
        rot_drift=sign() * float(np.deg2rad(rng.uniform(0.2, 1.0))),  # [rad/m]
        noise_factor=float(rng.uniform(1.5, 3.0)),  # variance over 0.2 m or 0.2 rad, times the filter's
        wander_bias=float(rng.uniform(0.4, 1.2)),  # how strongly the drive keeps its turn preference
    )


def holdout_world(grid=None):
    """Map, its likelihood field and the places a drive may start."""
    grid = cmu.load_cmu_map() if grid is None else grid
    field = sl.likelihood_field(grid, max_dist=2.0, threshold=OCCUPIED)
    free = grid.free_mask(FREE)
    rows, cols = np.nonzero(free)
    xy = np.column_stack([grid.origin[0] + (cols + 0.5) * grid.resolution,
                          grid.origin[1] + (rows + 0.5) * grid.resolution])
    ok = field.distance_at(xy) >= START_CLEARANCE
    return dict(grid=grid, field=field, starts=xy[ok])


def _with_obstacles(grid, discs):
    occ = np.array(grid.occupancy, dtype=float)
    if discs.size:
        H, W = occ.shape
        yy = grid.origin[1] + (np.arange(H) + 0.5) * grid.resolution
        xx = grid.origin[0] + (np.arange(W) + 0.5) * grid.resolution
        for cx, cy, r in discs:
            r0, r1 = np.searchsorted(yy, [cy - r - 0.1, cy + r + 0.1])
            c0, c1 = np.searchsorted(xx, [cx - r - 0.1, cx + r + 0.1])
            sub = (xx[None, c0:c1] - cx) ** 2 + (yy[r0:r1, None] - cy) ** 2 <= r * r
            occ[r0:r1, c0:c1][sub] = 1.0
    return sl.OccupancyGrid(occ, grid.resolution, grid.origin)


def _clearance(world, discs, xy):
    d = float(world["field"].distance_at(xy))
    if discs.size:
        d = min(d, float(np.min(np.hypot(discs[:, 0] - xy[0], discs[:, 1] - xy[1]) - discs[:, 2])))
    return d


def _place_obstacles(world, start, mm, rng):
    starts = world["starts"]
    near = starts[np.hypot(*(starts - start[:2]).T) < 10.0]
    discs = []
    for _ in range(200):
        if len(discs) == mm["n_obstacles"] or near.shape[0] == 0:
            break
        c = near[rng.integers(near.shape[0])] + rng.uniform(-0.05, 0.05, 2)
        r = rng.uniform(*mm["obstacle_radius"])
        if np.hypot(*(c - start[:2])) < r + ROBOT_RADIUS + 0.5:
            continue
        discs.append((c[0], c[1], r))
    return np.array(discs).reshape(-1, 3)


def _drive(world, obs_grid, discs, start, n_updates, every, mm, rng):
    """Sub-steps of a reactive wander drive (a scan every `every`): poses, and which were turns in place."""
    pose = np.array(start, dtype=float)
    poses, spins = [pose.copy()], [False]
    pref, spin = 0.0, 0.0
    max_turn = SUB / 0.5  # curvature radius >= 0.5 m
    for it in range(40 * n_updates * 20):
        if it % 50 == 49:
            idx, _ = sl.odometry_steps(np.array(poses[::every]))
            if idx.size >= n_updates + 5:
                return np.array(poses), np.array(spins)
        if spin != 0.0:
            d = np.sign(spin) * min(abs(spin), SPIN_RATE)
            spin -= d
            pose = pose + [0.0, 0.0, d]
            pose[2] = sl.wrap_angle(pose[2])
            poses.append(pose.copy()), spins.append(True)
            continue
        if rng.random() < SUB / 25.0:  # about one turn in place per 25 m
            spin = float(rng.choice([-1, 1]) * rng.uniform(0.8, 3.1))
            continue
        pref = float(np.clip(pref + rng.normal(0.0, 0.08), -1.2, 1.2))
        ranges = sl.ray_cast(obs_grid, pose, WANDER_RAYS, 4.0, threshold=OCCUPIED)
        score = ranges - mm["wander_bias"] * np.abs(WANDER_RAYS - pref)
        target = WANDER_RAYS[int(np.argmax(score))]
        heading = pose[2] + float(np.clip(target, -max_turn, max_turn))
        nxt = np.array([pose[0] + SUB * np.cos(heading), pose[1] + SUB * np.sin(heading), sl.wrap_angle(heading)])
        if ranges.max() < 0.6 or _clearance(world, discs, nxt[:2]) < ROBOT_RADIUS:
            spin = float(rng.choice([-1, 1]) * rng.uniform(1.5, 3.1))  # dead end: turn around
            pref = 0.0
            continue
        pose = nxt
        poses.append(pose.copy()), spins.append(False)
    raise RuntimeError("the drive did not reach its length")


def _scans(obs_grid, truth, angles, mm, rng, z_max, sensor_offset):
    """Ranges with obstacles, passers-by, non-mixture noise, dropouts and a mounting error."""
    P, K = truth.shape[0], angles.size
    laser = truth + [0.0, 0.0, mm["laser_yaw"]]
    z_star = sl.ray_cast(obs_grid, laser, angles, z_max, sensor_offset=sensor_offset, threshold=OCCUPIED)
    win = np.hanning(17)
    win /= np.sqrt(np.sum(win ** 2))
    corr = np.array([np.convolve(rng.standard_normal(K + 16), win, "valid") for _ in range(P)]) * mm["correlated_sigma"]
    hit = z_star + REF_SIGMA_HIT * mm["sigma_factor"] * rng.standard_normal((P, K)) + corr
    e = rng.uniform(size=(P, K))
    short = -np.log1p(-e * (1.0 - np.exp(-REF_LAMBDA_SHORT * z_star))) / REF_LAMBDA_SHORT
    u = rng.uniform(size=(P, K))
    z = np.where(u < mm["p_short"], short, hit)
    z = np.where((u >= mm["p_short"]) & (u < mm["p_short"] + mm["p_rand"]), rng.uniform(0.0, z_max, (P, K)), z)
    z = np.where((u >= mm["p_short"] + mm["p_rand"]) & (u < mm["p_short"] + mm["p_rand"] + mm["p_max"]), z_max, z)
    for p in range(P):
        if rng.random() < mm["passer_by"]:  # a person walking by: a block of beams cut short
            k0, n = int(rng.integers(K)), int(rng.integers(5, 21))
            sl_ = slice(k0, min(K, k0 + n))
            z[p, sl_] = np.minimum(z[p, sl_], rng.uniform(0.5, 3.0) + 0.03 * rng.standard_normal(z[p, sl_].shape))
        starts = np.flatnonzero(rng.uniform(size=K) < mm["p_dropout"] / 7.5)
        for k0 in starts:  # max-range dropouts in runs (glass, black surfaces)
            z[p, k0:k0 + int(rng.integers(3, 13))] = z_max
    return np.clip(z, 0.0, z_max)


def _odometry(truth, mm, rng):
    """Odometry with systematic scale and drift errors and heavier noise than the filter's.

    The noise is a random walk: its variance grows linearly with the distance and the turn of each
    scan's increment, and equals ``noise_factor`` times the filter's (Table 5.6 with ``alpha``) over
    an update of 0.2 m or 0.2 rad, whatever the spacing of the scans.
    """
    u = sl.odometry_from_poses(truth[:-1], truth[1:])
    odom = np.zeros_like(truth)
    odom[0] = truth[0] + [3.0, -2.0, 0.7]  # the odometry's own frame
    odom[0, 2] = sl.wrap_angle(odom[0, 2])
    a, k, d0 = REF_ALPHA, mm["noise_factor"], 0.2
    for t in range(1, truth.shape[0]):
        rot1, trans, rot2 = u[t - 1]
        drift = mm["rot_drift"] * trans / 2
        v = np.array([rot1 * (1 + mm["rot_scale"]) + drift, trans * (1 + mm["trans_scale"]),
                      rot2 * (1 + mm["rot_scale"]) + drift])
        var = k * d0 * np.array([a[0] * abs(rot1) + a[1] * trans, a[2] * trans + a[3] * (abs(rot1) + abs(rot2)),
                                 a[0] * abs(rot2) + a[1] * trans])
        odom[t] = sl.odometry_motion(odom[t - 1], v + np.sqrt(var) * rng.standard_normal(3))
    return odom


def filter_models(mm):
    """`mm` with the filter's own models: no obstacles in the scans, the beam mixture, unbiased odometry."""
    return dict(mm, passer_by=0.0, sigma_factor=1.0, correlated_sigma=0.0, p_short=0.05, p_rand=0.05, p_dropout=0.0,
                p_max=0.05, laser_yaw=0.0, trans_scale=0.0, rot_scale=0.0, rot_drift=0.0, noise_factor=1.0)


def simulate_holdout_trial(world, angles, n_updates, rng, *, control=False, z_max=cmu.CMU_MAX_RANGE,
                           sensor_offset=cmu.CMU_SENSOR_OFFSET):
    """One hold-out drive: truth, odometry, ranges and times at every scan, and its mismatch draw.

    With `control`, the same drive (same truth) is sensed with the filter's own models
    (:func:`filter_models`, scans of the map without the obstacles): the control set that tells the
    mismatch's share of the failures from the drives'.
    """
    mm = draw_mismatch(rng)
    every = int(round(mm["scan_step"] / SUB))
    for _ in range(50):
        starts = world["starts"]
        s = starts[rng.integers(starts.shape[0])] + rng.uniform(-0.05, 0.05, 2)
        start = np.array([s[0], s[1], rng.uniform(-np.pi, np.pi)])
        discs = _place_obstacles(world, start, mm, rng)
        obs_grid = _with_obstacles(world["grid"], discs)
        try:
            sub, spins = _drive(world, obs_grid, discs, start, n_updates, every, mm, rng)
        except RuntimeError:
            continue
        if spins.mean() > 0.5:  # mostly turning on the spot: a trapped start
            continue
        pick = np.arange(0, sub.shape[0], every)
        truth = sub[pick]
        odom = _odometry(truth, mm, rng)
        if sl.odometry_steps(odom)[0].size < n_updates:  # the noisy odometry triggers fewer updates
            continue
        break
    else:
        raise RuntimeError("no drive found")
    step_t = np.where(spins, SPIN_RATE / 0.5, SUB / mm["speed"])  # turns in place at 0.5 rad/s
    times = np.cumsum(step_t)[pick] - step_t[0]
    ranges = _scans(obs_grid, truth, angles, mm, rng, z_max, sensor_offset)
    if control:
        crng = np.random.default_rng(int(rng.integers(2 ** 62)))
        mm = filter_models(mm)
        ranges = _scans(world["grid"], truth, angles, mm, crng, z_max, sensor_offset)
        odom = _odometry(truth, mm, crng)
    mm = dict(mm, obstacle_radius=list(mm["obstacle_radius"]), discs=discs.round(3).tolist(),
              turn_in_place_share=float(spins.mean()), length=float(np.sum(np.hypot(*np.diff(truth[:, :2], axis=0).T))))
    return dict(truth=truth, odom=odom, ranges=ranges, times=times, mismatch=mm)


def trial_digest(trial):
    h = hashlib.sha1()
    for k in ("truth", "odom", "ranges", "times"):
        h.update(np.ascontiguousarray(trial[k]).tobytes())
    return h.hexdigest()[:12]


def make_sim_trials(world, angles, n, n_updates, seed, *, control=False):
    ss = np.random.SeedSequence([seed, 0])
    return [simulate_holdout_trial(world, angles, n_updates, np.random.default_rng(s), control=control)
            for s in ss.spawn(n)]


# --------------------------------------------------------------------------- log trials
def study_offsets(n_ref, updates=STUDY_UPDATES, offsets=STUDY_OFFSETS):
    """The start updates ``mcl_study.py`` uses on a log with `n_ref` reference updates."""
    return np.linspace(0, n_ref - updates - 1, offsets).round().astype(int)


def log_starts(refs, per_log, seed):
    """Hold-out log trials ``(log, update j, scan shift, horizon)``: midway between the study's offsets."""
    rng = np.random.default_rng([seed, 1])
    keys = []
    for n in sorted(refs):
        ref = refs[n]
        L = len(ref["scan_index"])
        so = study_offsets(L)
        mids = (so[:-1] + so[1:]) // 2
        pick = mids[np.linspace(0, mids.size - 1, min(per_log, mids.size)).round().astype(int)]
        for i, j in enumerate(pick):
            gap = int(ref["scan_index"][j + 1] - ref["scan_index"][j])
            shift = int(rng.integers(1, gap)) if gap > 1 else 0
            h = min(HORIZONS[i % len(HORIZONS)], L - int(j) - 2)
            keys.append((int(n), int(j), shift, int(h)))
    return keys


def load_refs(path, grid, logs):
    """The reference tracks (truth of the log trials), computed once and then read from `path`."""
    if os.path.exists(path):
        with np.load(path) as f:
            return {n: dict(scan_index=f[f"scan_index_{n}"], mean=f[f"mean_{n}"]) for n in logs}, False
    refs = {}
    for n, lg in logs.items():
        ref = reference_track(grid, lg, n)[0]
        refs[n] = dict(scan_index=np.asarray(ref.scan_index), mean=np.asarray(ref.mean))
    np.savez_compressed(path, **{f"{k}_{n}": v for n, r in refs.items() for k, v in r.items()})
    return refs, True


# --------------------------------------------------------------------------- running
class _Ref:
    def __init__(self, d):
        self.scan_index, self.mean = d["scan_index"], d["mean"]


def _row(t):
    """One summary row's columns (strict success, share, confidently-wrong updates and trials, CPU), as both
    tables print them."""
    lo, hi = wilson(t["confidently_wrong_trials"], t["trials"])
    return (f"{t['strict']:4d}/{t['trials']:<3d} = {t['strict_rate']:4.0%} "
            f"[{t['strict_ci'][0]:4.0%}, {t['strict_ci'][1]:4.0%}] {t['share_within']:12.0%} "
            f"{t['confidently_wrong_updates']:9d}/{t['updates']:<9d} "
            f"{t['confidently_wrong_trials']:9d}/{t['trials']:<3d} [{lo:4.0%}, {hi:4.0%}]     "
            f"{t['cpu_s']:8.0f}")


def configs_from(args):
    out = {}
    for c in args.configs:
        if c == "defaults":
            out[c] = (None, [])
        elif c == "plain MCL":  # Table 8.2 as printed, as in mcl_study.py: a uniform start, the mode's mean
            out[c] = ("mcl", ["init_candidates=0", "estimate_radius=0"])
        elif c == "overrides":
            out[c] = (args.variant, list(args.overrides))
        else:
            raise SystemExit(f"unknown configuration {c!r}: defaults, 'plain MCL' or overrides")
    return out


def _init(data):
    _WORK.update(data)
    _WORK["grid"] = cmu.load_cmu_map()


def _run(job):
    config, kind, key, seed = job
    variant, overrides = _WORK["configs"][config]
    kw = {} if variant is None else {"variant": variant}
    grid = _WORK["grid"]
    rng = np.random.default_rng(seed)
    if kind != "logs":
        trial = _WORK["sims"][kind][key]
        params = _success_params(_Geom(), overrides)
        res = sl.run_mcl(sl.prepare_mcl(grid, params), trial["odom"], trial["ranges"], _WORK["angles"], rng=rng,
                         times=trial["times"], max_steps=_WORK["updates"], **kw)
        truth = trial["truth"][res.scan_index]
    else:
        n, j, shift, h = key
        log, ref = _WORK["logs"][n], _Ref(_WORK["refs"][n])
        params = _success_params(log, overrides)
        a = int(ref.scan_index[j]) + shift
        res = sl.run_mcl(sl.prepare_mcl(grid, params), log.laser_pose[a:], log.ranges[a:], log.angles, rng=rng,
                         times=log.laser_t[a:], max_steps=h, **kw)
        truth = truth_at(ref, log.laser_pose, res.scan_index + a)
    out = judge(res, truth)
    if getattr(res, "confidence", None) is not None:  # a library that reports mass near its estimate as well
        err = np.hypot(*(res.estimate[:, :2] - truth[:, :2]).T)
        out["confidently_wrong_conf"] = int(np.sum((err > RADIUS) & (np.asarray(res.confidence) > CONFIDENT)))
    out.update(config=config, set=kind, trial=key if kind != "logs" else list(key), seed=seed,
               duration=float(res.t[-1] - res.t[0]))
    return out


class _Geom:
    """The sensor geometry of the simulated laser (the CMU robot's), for ``mcl_success.make_params``."""
    sensor_offset = cmu.CMU_SENSOR_OFFSET
    max_range = cmu.CMU_MAX_RANGE


def _lib_tag():
    h = hashlib.sha1()
    base = os.path.dirname(sl.__file__)
    for dirpath, _, files in sorted(os.walk(base)):
        for f in sorted(files):
            if f.endswith(".py"):
                with open(os.path.join(dirpath, f), "rb") as fh:
                    h.update(f.encode() + fh.read())
    try:
        commit = subprocess.run(["git", "-C", base, "log", "-1", "--format=%h %cI %s"], capture_output=True,
                                text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        commit = "?"
    return h.hexdigest()[:10], commit


def _by_factor(runs, sims):
    """Strict success in the trials below and above the median of each mismatch factor."""
    rows = []
    for f in ("speed", "scan_step", "n_obstacles", "sigma_factor", "p_short", "p_dropout", "noise_factor",
              "turn_in_place_share"):
        vals = np.array([sims[r["trial"]]["mismatch"][f] for r in runs])
        ok = np.array([r["strict"] for r in runs])
        med = np.median(vals)
        lo, hi = vals <= med, vals > med
        rows.append((f, med, int(ok[lo].sum()), int(lo.sum()), int(ok[hi].sum()), int(hi.sum())))
    return rows


def tracking_check(sims, angles, updates, seed):
    """How many trials are solvable at all: plain MCL started at the truth (2000 particles, 10 cm, 2 deg)
    with ``MCLParams()``, judged by the strict criterion (an upper bound for global localization)."""
    grid = cmu.load_cmu_map()
    model = sl.prepare_mcl(grid, _success_params(_Geom(), []))
    ok = []
    for i, t in enumerate(sims):
        rng = np.random.default_rng([seed, 3, i])
        init = t["truth"][0] + rng.normal(size=(2000, 3)) * TRUTH_SPREAD  # the study's ceiling's spread
        res = sl.run_mcl(model, t["odom"], t["ranges"], angles, rng=rng, variant="mcl", init=init,
                         times=t["times"], max_steps=updates)
        err = np.hypot(*(res.estimate[:, :2] - t["truth"][res.scan_index, :2]).T)
        ok.append(bool(np.all(err[len(err) // 2:] < RADIUS)))
    return ok


def compare(paths):
    """Side by side: the tables of several ``--json`` outputs (e.g. two library versions)."""
    print(f"{'slamlib':10s} {'configuration':14s} {'set':5s} {'strict success (95 % CI)':>27s} {'share within':>12s} "
          f"{'conf. wrong updates':>19s} {'conf. wrong trials (95 % CI)':>30s} {'CPU [s]':>8s} {'data':>13s}")
    for p in paths:
        with open(p) as f:
            d = json.load(f)
        for c, row in d["table"].items():
            for s, t in row.items():
                print(f"{d['slamlib']['hash']:10s} {c:14s} {s:5s} {_row(t)} "
                      f"{d['settings'].get('digests', {}).get(s, s):>13s}")
        print(f"{'':10s} ({d['slamlib']['path']}; {d['slamlib']['commit']})")


def _existing_file(text):
    """An argparse type: the path of an existing file."""
    if not os.path.isfile(text):
        raise argparse.ArgumentTypeError(f"no file {text!r}")
    return text


def _slamlib_tree(text):
    """An argparse type: a source tree holding a slamlib package."""
    if not os.path.isfile(os.path.join(text, "slamlib", "__init__.py")):
        raise argparse.ArgumentTypeError(f"{text!r} holds no slamlib package (slamlib/__init__.py)")
    return text


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--compare", nargs="+", type=_existing_file, metavar="JSON", help="print the tables of these --json outputs, run nothing")
    ap.add_argument("--configs", nargs="+", default=["defaults", "plain MCL"],
                    help="defaults, 'plain MCL' and/or overrides (the latter from --set / --variant)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                    help="override an MCLParams field for the 'overrides' configuration (augmented.x, kld.x nested)")
    ap.add_argument("--variant", default=None, help="run_mcl variant of the 'overrides' configuration")
    ap.add_argument("--slamlib", default=_ROOT, type=_slamlib_tree, help="the tree whose slamlib is evaluated (default: this one)")
    ap.add_argument("--trials", type=int, default=48, help="simulated trials")
    ap.add_argument("--log-starts", type=int, default=5, choices=range(1, 10), help="start points per log (at most 9)")
    ap.add_argument("--sets", nargs="+", default=["sim", "logs"], choices=["sim", "logs", "control"],
                    help="control: the sim set's drives sensed with the filter's own models (a diagnostic)")
    ap.add_argument("--updates", type=int, default=40, help="filter updates per simulated trial")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=BASE_SEED)
    ap.add_argument("--cache", default=os.path.join(tempfile.gettempdir(), "mcl_holdout"),
                    help="prefix of the cache files (runs, simulated trials, reference tracks)")
    ap.add_argument("--json", help="write the summary and every run to this file")
    ap.add_argument("--tracking-check", action="store_true",
                    help="also report how many simulated trials plain MCL tracks when started at the truth")
    args = ap.parse_args(argv)
    for name, low in {'trials': 1, 'updates': 2, 'jobs': 1, 'seed': 0}.items():  # counts at least 1, seeds at least 0
        value = getattr(args, name)
        if value is not None and min(value if isinstance(value, list) else [value]) < low:
            ap.error(f"--{name.replace('_', '-')} must be at least {low}, got {value}")
    if args.compare:
        return compare(args.compare)
    if args.seed == STUDY_SEED:
        raise SystemExit(f"--seed {STUDY_SEED} is the study's: a hold-out needs another")
    if args.jobs > 2:
        raise SystemExit("--jobs: at most 2 worker processes on this machine")
    configs = configs_from(args)
    tag, commit = _lib_tag()
    print(f"slamlib: {os.path.dirname(sl.__file__)} (source hash {tag}; {commit})")
    if os.path.abspath(os.path.dirname(os.path.dirname(sl.__file__))) != os.path.abspath(args.slamlib):
        raise SystemExit(f"asked for the slamlib of {args.slamlib}, imported {sl.__file__}")

    t0 = time.perf_counter()
    os.makedirs(os.path.dirname(os.path.abspath(args.cache)), exist_ok=True)
    grid = cmu.load_cmu_map()
    logs = {n: cmu.load_cmu_log(log=n) for n in (1, 2)}
    angles = logs[1].angles
    refs, fresh = load_refs(args.cache + "_refs.npz", grid, logs)
    if fresh and os.path.abspath(args.slamlib) != _ROOT:
        print("warning: the reference tracks were computed with this slamlib; run the default tree first "
              "so that every tree is judged against the same truth")
    all_sims = {}
    for kind in ("sim", "control"):
        if kind not in args.sets:
            continue
        path = args.cache + f"_{kind}s_s{args.seed}_u{args.updates}_n{args.trials}.pkl.gz"
        if os.path.exists(path):
            with gzip.open(path, "rb") as f:
                all_sims[kind] = pickle.load(f)
        else:
            all_sims[kind] = make_sim_trials(holdout_world(grid), angles, args.trials, args.updates, args.seed,
                                             control=kind == "control")
            with gzip.open(path, "wb") as f:
                pickle.dump(all_sims[kind], f)
    sims = all_sims.get("sim") or all_sims.get("control") or []
    digests = {k: hashlib.sha1("".join(trial_digest(t) for t in v).encode()).hexdigest()[:12] for k, v in all_sims.items()}
    digest = digests.get("sim", "")
    keys = log_starts(refs, args.log_starts, args.seed) if "logs" in args.sets else []
    run_ss = np.random.SeedSequence([args.seed, 2])
    seeds = [int(s.generate_state(1)[0]) for s in run_ss.spawn(len(sims) + len(keys))]
    trials = [(kind, i, seeds[i]) for kind in all_sims for i in range(len(sims))] + \
             [("logs", k, seeds[len(sims) + i]) for i, k in enumerate(keys)]
    if sims:
        upd = [sl.odometry_steps(t["odom"])[0].size for t in sims]
        print(f"{len(sims)} simulated hold-out trials per set (data digests {digests}): {min(args.updates, min(upd))}-"
              f"{args.updates} updates, {np.median([t['mismatch']['length'] for t in sims]):.1f} m median drive, "
              f"{np.median([t['times'][-1] for t in sims]):.0f} s median duration")
    if keys:
        print(f"{len(keys)} log trials (log, start update, scan shift, horizon): {keys}")
        print(f"  the study's start updates: " + "; ".join(f"log {n}: {study_offsets(len(refs[n]['scan_index'])).tolist()}"
                                                          for n in sorted(refs)))
    print(f"set-up {time.perf_counter() - t0:.0f} s", flush=True)
    tracking = {}
    if args.tracking_check:
        for kind, trial_list in all_sims.items():
            path = args.cache + f"_tracking_{kind}_s{args.seed}_u{args.updates}_n{args.trials}.json"
            if os.path.exists(path):  # computed once (by the first tree run), so every tree gets the same subset
                with open(path) as f:
                    ok = json.load(f)
            else:
                ok = tracking_check(trial_list, angles, args.updates, args.seed)
                with open(path, "w") as f:
                    json.dump(ok, f)
            lo, hi = wilson(sum(ok), len(ok))
            tracking[kind] = dict(strict=sum(ok), trials=len(ok), ci=[lo, hi], ok=ok)
            print(f"{kind}: plain MCL started at the truth is strictly right in {sum(ok)}/{len(ok)} trials "
                  f"[{lo:.0%}, {hi:.0%}] (how many are solvable at all)", flush=True)

    def label(c):
        variant, overrides = configs[c]
        return json.dumps([c, variant, sorted(overrides), tag])

    def ckey(c, kind, key, seed):
        return json.dumps([label(c), kind, key if kind != "logs" else list(key), seed])

    jobs = [(c, kind, key, seed) for c in configs for kind, key, seed in trials]
    data = dict(sims=all_sims, logs=logs, refs=refs, angles=angles, updates=args.updates, configs=configs)
    done, n_new, wall = resumable_runs(jobs, lambda j: ckey(*j), _run,
                                   args.cache + f"_runs_s{args.seed}_u{args.updates}_n{args.trials}.jsonl",
                                   processes=args.jobs, initializer=_init, initargs=(data,), every=10)
    runs = [done[ckey(*j)] for j in jobs]

    table = {c: {s: summarize([r for r in runs if r["config"] == c and r["set"] == s]) for s in args.sets}
             for c in configs}
    print(f"\nhold-out evaluation, slamlib {tag} ({commit})")
    print(f"{'configuration':14s} {'set':5s} {'strict success (95 % CI)':>27s} {'share within':>12s} "
          f"{'conf. wrong updates':>19s} {'conf. wrong trials (95 % CI)':>30s} {'CPU [s]':>8s} {'x real time':>11s}")
    for c, row in table.items():
        for s, t in row.items():
            print(f"{c:14s} {s:5s} {_row(t)} {t['real_time_factor']:10.1f}x")
            t["confidently_wrong_trials_ci"] = list(wilson(t["confidently_wrong_trials"], t["trials"]))
            mine = [r for r in runs if r["config"] == c and r["set"] == s]
            if s in tracking:  # the trials that plain MCL tracks from the truth: what global localization can reach
                sub = [r for r in mine if tracking[s]["ok"][r["trial"]]]
                k = sum(r["strict"] for r in sub)
                lo2, hi2 = wilson(k, len(sub))
                t["strict_solvable"] = [k, len(sub), lo2, hi2]
                print(f"{'':20s} of the {len(sub)} trials tracked from the truth: strict {k}/{len(sub)} "
                      f"[{lo2:.0%}, {hi2:.0%}], confidently wrong in {sum(r['confidently_wrong'] > 0 for r in sub)}")
            if mine and all("confidently_wrong_conf" in r for r in mine):
                t["confidently_wrong_conf_updates"] = sum(r["confidently_wrong_conf"] for r in mine)
                t["confidently_wrong_conf_trials"] = sum(r["confidently_wrong_conf"] > 0 for r in mine)
                print(f"{'':20s} confidently wrong by MCLResult.confidence (mass within 0.5 m of the estimate) > 0.9: "
                      f"{t['confidently_wrong_conf_updates']} updates in {t['confidently_wrong_conf_trials']} trials")
    if "sim" in all_sims:
        for c in configs:
            mine = [r for r in runs if r["config"] == c and r["set"] == "sim"]
            print(f"\n{c}, sim: strict success below / above the median of each mismatch factor")
            for f, med, k1, n1, k2, n2 in _by_factor(mine, all_sims["sim"]):
                print(f"  {f:20s} median {med:7.3f}: {k1:3d}/{n1:<3d} vs {k2:3d}/{n2:<3d}")
    if keys:
        for c in configs:
            print(f"\n{c}, logs: (log, start update, shift, horizon) -> strict, share within, conf. wrong updates")
            for r in runs:
                if r["config"] == c and r["set"] == "logs":
                    print(f"  {tuple(r['trial'])}: {'ok  ' if r['strict'] else 'FAIL'} {r['share']:4.0%} "
                          f"{r['confidently_wrong']:4d}  final error {r['final_error']:.2f} m")
    print(f"\nwall time {wall:.0f} s with {args.jobs} process(es), {n_new} new runs; "
          f"CPU in the filters (all {len(runs)} runs) {sum(r['runtime'] for r in runs):.0f} s")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(dict(slamlib=dict(path=os.path.dirname(sl.__file__), hash=tag, commit=commit),
                           settings=dict(seed=args.seed, trials=len(sims), updates=args.updates, log_trials=keys,
                                         sim_digest=digest, digests=digests, radius=RADIUS, confident=CONFIDENT),
                           configs={c: dict(variant=v, overrides=o) for c, (v, o) in configs.items()},
                           table=table, tracking=tracking, runs=runs), f)
    return table, runs


if __name__ == "__main__":
    main()
