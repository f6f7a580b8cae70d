"""Global localization over a distribution of trials: success rates with confidence intervals.

Two sets of trials, each judged against its truth:

* **logs**: the two shipped CMU Wean Hall logs, the filter started with no knowledge of its pose
  (global localization) at many start offsets (update ``j`` of the log's reference track, evenly spaced), each run for
  ``--updates`` filter updates; the truth is the reference track of ``benchmarks/mcl_success.py``
  (plain MCL started around the scan-matched start pose, checked against the map there);
* **sim**: random collision-free trajectories in the Wean Hall map (shortest paths between random
  free places with 0.5 m clearance, smoothed), scans drawn from the beam model at the true poses
  (expected ranges ray-cast and moved ``cmu.CMU_RANGE_BIAS`` beyond the map's faces, where the robot's
  laser sees the walls; ``MCLParams``' mixture: hit, short, max, random), odometry drawn from the
  odometry motion model around the true increments with the robot's noise: the filter's ``alpha``
  scaled to ``SIM_ODOMETRY_STD`` of its standard deviation. The filter's ``alpha`` is wider than the
  robot's odometry error on purpose (a filter that expects too little noise loses the robot); a
  simulator that drew with it would make every drive harder than the robot's. Both are measured and
  printed as model checks: measured ranges minus cast ones, and the odometry's error per update
  against the reference tracks divided by the motion model's standard deviation.

Per trial, over the second half of its updates: *strict* success (the estimate within 0.5 m at
every update), the share of updates within 0.5 m; over all updates: *confidently wrong* updates
(the estimate more than 0.5 m off while the heaviest mode holds more than 90 % of the mass,
``MCLResult.mode_mass``), and the same count with the filter's confidence (``MCLResult.confidence``, the
mass within 0.5 m of the estimate) in place of the mode's mass. Rates come with Wilson 95 % intervals (log trials from overlapping
windows of two logs are not independent: their interval is optimistic). A trial that ends with the estimate more
than 0.5 m off is weighed against its truth (``alias_evidence``): the wrong place's track, carried back through the
odometry, against the true track, by the scans' tempered log-likelihood ratio. The column "ends wrong" counts
these trials and, in brackets, those where the scans favour the wrong place, those too close to call and those
where they favour the truth, all by the defaults' sensor model. Too close to call is within the measure's own
spread: the largest distance from 0, over the set's trials, of the true track chained back from its end weighed
against the truth (``alias_null``). The defaults' wrong endings on the logs are weighed a second time by the beam
model (the defaults with ``model="beam"``, which also charges a beam for passing where the map has a wall; its own
band measured the same way on the log starts): printed after the table, saved per run as ``alias_evidence_beam``.

Configurations differ from the library defaults in one mechanism each (``CONFIGS``); plain MCL is
Table 8.2 as printed (uniform start, the estimate at the heaviest mode's mean). ``TRUTH_START`` is
not a mechanism but a ceiling: the defaults started around the true pose (global localization solved
by an oracle), which no global localization with the same models can be expected to beat;
``BEAM_SKIP_TRUTH`` is beam skipping (``BEAM_SKIP``, off in the defaults) started the same way, and
``BEAM_TRUTH`` the beam model (``BEAM``, the simulator's own sensor model) started the same way. The
configurations started at the truth (``TRUTH_STARTS``) take no part in the screen's ``all`` or in the
cross-validation. Cross-
validation: the configuration with the best strict success (ties: fewer confidently-wrong updates,
then fewer CPU seconds) is chosen on one set and reported on the other, both ways.

    python benchmarks/mcl_study.py                        # defaults and plain MCL on the full study
    python benchmarks/mcl_study.py --screen all           # ... and every mechanism on a development subset
    # the chapter's data (the README's command):
    python benchmarks/mcl_study.py --screen all --configs defaults "plain MCL" "tempering tau 0.2" "tempering tau 0.05" "defaults started at the truth" "beam skipping (share 0.05)" "beam skipping started at the truth" "beam model started at the truth" --json chapters/data/mcl_study.json

Finished runs are appended to a cache file (``--cache``), so an interrupted study resumes.

Run it under ``nice -n 10`` with one BLAS thread (set below).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import tempfile
import time
from multiprocessing import get_context

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from scipy import sparse  # noqa: E402
from scipy.sparse import csgraph  # noqa: E402
from scipy.stats import norm  # noqa: E402

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, os.path.dirname(__file__))

import slamlib as sl  # noqa: E402
from slamlib.datasets import cmu  # noqa: E402
from mcl_success import reference_track  # noqa: E402

RADIUS = 0.5  # [m] an update is right when the estimate is within this distance of the truth
CONFIDENT = 0.9  # an update is confidently wrong when it is wrong and the heaviest mode holds more than this
SIM_STEP = 0.3  # [m] between simulated scans (one filter update each: the filter updates every 0.2 m)
SIM_SPEED = 0.3  # [m/s] (the robot's speed on log 1: 41 m in 135 s)
CLEARANCE = 0.5  # [m] from the nearest wall, for the simulated paths
#: Standard deviation of the simulated odometry error, relative to the motion model's (MCLParams.alpha):
#: the robot's error per update against the reference tracks is 0.29 and 0.25 of it in translation, 0.18 in
#: heading (logs 1 and 2, the reference tracks' own error included; ``odometry_error_ratio``), rounded up.
SIM_ODOMETRY_STD = 1 / 3

# name -> (run_mcl variant, MCLParams overrides): the defaults, plain MCL, and one mechanism changed at a time
CONFIGS = {
    "defaults": ("augmented", {}),
    "plain MCL": ("mcl", {"init_candidates": 0, "estimate_radius": 0.0}),
    "MCL with the defaults' start and estimate": ("mcl", {}),
    "uniform start (no scan-guided start)": ("augmented", {"init_candidates": 0}),
    "estimate at the mode's mean": ("augmented", {"estimate_radius": 0.0}),
    "no mode-preserving resampling": ("augmented", {"mode_particles": 0}),
    "no sensor resetting (p_min 0)": ("augmented", {"augmented.p_min": 0.0}),
    "tempering tau 0.2": ("augmented", {"likelihood_exponent": 0.2}),
    "tempering tau 0.05": ("augmented", {"likelihood_exponent": 0.05}),
    "KLD-sampling": ("kld", {}),
    "kidnap prior p_min 1e-4": ("augmented", {"augmented.p_min": 1e-4}),
    "beam model (pre-cached ray casting)": ("augmented", {"model": "beam"}),
    "estimate hysteresis 2": ("augmented", {"estimate_hysteresis": 2.0}),
    "twice the beams, tau 0.05": ("augmented", {"beam_step": 5, "likelihood_exponent": 0.05}),
}
#: The ceiling: the defaults started around the true pose (TRUTH_SPREAD), not from the first scan.
TRUTH_START = "defaults started at the truth"
CONFIGS[TRUTH_START] = ("augmented", {})
#: Beam skipping (MCLParams.beam_skip_share, off by default), from a global start and started at the truth.
BEAM_SKIP = "beam skipping (share 0.05)"
BEAM_SKIP_TRUTH = "beam skipping started at the truth"
CONFIGS[BEAM_SKIP] = ("augmented", {"beam_skip_share": 0.05})
CONFIGS[BEAM_SKIP_TRUTH] = ("augmented", {"beam_skip_share": 0.05})
#: The beam model, the simulator's own sensor model, from a global start and started at the truth.
BEAM = "beam model (pre-cached ray casting)"
BEAM_TRUTH = "beam model started at the truth"
CONFIGS[BEAM_TRUTH] = CONFIGS[BEAM]
#: The configurations started at the truth: oracles, never screened or chosen.
TRUTH_STARTS = (TRUTH_START, BEAM_SKIP_TRUTH, BEAM_TRUTH)
TRUTH_SPREAD = (0.1, 0.1, np.deg2rad(2.0))  # [m, m, rad] standard deviations of the particles around the truth

_WORK = {}


def wilson(k, n, z=1.96):
    """Wilson score interval of a binomial proportion k / n."""
    if n == 0:
        return (0.0, 1.0)
    p = k / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return (max(0.0, centre - half), min(1.0, centre + half))


def make_params(overrides, sensor_offset=cmu.CMU_SENSOR_OFFSET, z_max=cmu.CMU_MAX_RANGE):
    """``MCLParams`` with the Wean Hall laser's constants (offset, maximum range, range bias) and `overrides`."""
    top, aug = {"range_bias": cmu.CMU_RANGE_BIAS}, {}
    for key, value in overrides.items():
        if key.startswith("augmented."):
            aug[key.split(".", 1)[1]] = value
        else:
            top[key] = value
    params = sl.MCLParams(sensor_offset=sensor_offset, z_max=z_max, **top)
    return dataclasses.replace(params, augmented=dataclasses.replace(params.augmented, **aug)) if aug else params


# --------------------------------------------------------------------------- simulated trials
def _roadmap(grid, field, free_threshold):
    """Nodes of a 0.5 m lattice with clearance, their 8-connected graph."""
    step = 5  # cells of 0.1 m
    rows, cols = np.mgrid[step // 2:grid.shape[0]:step, step // 2:grid.shape[1]:step]
    xy = np.column_stack([grid.origin[0] + (cols.ravel() + 0.5) * grid.resolution,
                          grid.origin[1] + (rows.ravel() + 0.5) * grid.resolution])
    ok = grid.is_free(xy, free_threshold) & (field.distance_at(xy) >= CLEARANCE)
    ok = ok & np.isfinite(field.distance_at(xy))
    node = -np.ones(xy.shape[0], dtype=np.intp)
    node[ok] = np.arange(ok.sum())
    node = node.reshape(rows.shape)
    i, j, d = [], [], []
    H, W = node.shape
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        c0, c1 = max(0, -dc), W - max(0, dc)
        a, b = node[0:H - dr, c0:c1], node[dr:H, c0 + dc:c1 + dc]
        both = (a >= 0) & (b >= 0)
        i.append(a[both]), j.append(b[both]), d.append(np.full(both.sum(), 0.5 * np.hypot(dr, dc)))
    i, j, d = np.concatenate(i), np.concatenate(j), np.concatenate(d)
    n = int(ok.sum())
    g = sparse.coo_matrix((np.r_[d, d], (np.r_[i, j], np.r_[j, i])), shape=(n, n)).tocsr()
    return xy[ok], g


def simulate_trial(grid, field, roadmap, params, angles, n_updates, rng):
    """A random collision-free drive, its scans (beam-model noise) and its odometry (motion-model noise)."""
    nodes, g = roadmap
    length = SIM_STEP * (n_updates - 1)
    for _ in range(100):
        a = int(rng.integers(nodes.shape[0]))
        dist, pred = csgraph.dijkstra(g, indices=a, return_predecessors=True)
        far = np.flatnonzero((dist > length + 2.0) & np.isfinite(dist))
        if far.size == 0:
            continue
        b = int(far[rng.integers(far.size)])
        path = [b]
        while path[-1] != a:
            path.append(pred[path[-1]])
        wp = nodes[path[::-1]]
        seg = np.r_[0.0, np.cumsum(np.hypot(*np.diff(wp, axis=0).T))]
        s = np.arange(0.0, seg[-1], 0.05)
        xy = np.column_stack([np.interp(s, seg, wp[:, 0]), np.interp(s, seg, wp[:, 1])])
        k = 15  # smooth the lattice's corners over 0.75 m
        pad = np.r_[np.repeat(xy[:1], k, 0), xy, np.repeat(xy[-1:], k, 0)]
        xy = np.column_stack([np.convolve(pad[:, c], np.ones(2 * k + 1) / (2 * k + 1), "valid") for c in (0, 1)])
        seg = np.r_[0.0, np.cumsum(np.hypot(*np.diff(xy, axis=0).T))]
        if seg[-1] < length + 0.5:
            continue
        s = np.arange(n_updates) * SIM_STEP + 0.25
        pos = np.column_stack([np.interp(s, seg, xy[:, 0]), np.interp(s, seg, xy[:, 1])])
        ahead = np.column_stack([np.interp(s + 0.1, seg, xy[:, 0]), np.interp(s + 0.1, seg, xy[:, 1])])
        truth = np.column_stack([pos, np.arctan2(*(ahead - pos)[:, ::-1].T)])
        if not (grid.is_free(truth[:, :2], params.free_threshold).all() and field.distance_at(truth[:, :2]).min() >= 0.25):
            continue
        break
    else:
        raise RuntimeError("no collision-free trajectory found")
    # the beam model's expected range: the laser sees the walls range_bias beyond the map's faces
    z_star = sl.ray_cast(grid, truth, angles, params.z_max, sensor_offset=params.sensor_offset,
                         threshold=params.occupied_threshold, range_bias=params.range_bias)
    w = np.array([params.w_hit, params.w_short, params.w_max, params.w_rand])
    kind = rng.choice(4, size=z_star.shape, p=w / w.sum())
    hit = z_star + params.sigma_hit * rng.standard_normal(z_star.shape)
    # short: exponential with rate lambda_short truncated to [0, z*] (inverse CDF)
    e = rng.uniform(size=z_star.shape)
    short = -np.log1p(-e * (1.0 - np.exp(-params.lambda_short * z_star))) / params.lambda_short
    rand = rng.uniform(0.0, params.z_max, z_star.shape)
    z = np.choose(kind, [hit, short, np.full(z_star.shape, params.z_max), rand])
    z = np.clip(z, 0.0, params.z_max)
    u = sl.odometry_from_poses(truth[:-1], truth[1:])
    odom = np.zeros_like(truth)
    for t in range(1, n_updates):  # odometry = the true increment with the motion model's noise
        odom[t] = sl.sample_motion_model_odometry(odom[t - 1], u[t - 1], params.alpha, rng=rng)
    times = np.arange(n_updates) * SIM_STEP / SIM_SPEED
    return dict(odom=odom, ranges=z, truth=truth, times=times)


# --------------------------------------------------------------------------- log trials
def truth_at(ref, odom, scans):
    """Reference pose at any scan: the last update's pose moved by the odometry since it."""
    k = np.searchsorted(ref.scan_index, scans, side="right") - 1
    i = ref.scan_index[k]
    return sl.odometry_motion(ref.mean[k], sl.odometry_from_poses(odom[i], odom[scans]))


# --------------------------------------------------------------------------- model checks
SHIFTS = np.round(np.arange(-0.5, 0.501, 0.05), 2)  # [m] along the heading


def field_offset(model, trial, angles):
    """The shift along the heading at which the filter's scan likelihood of a simulated drive peaks.

    The drive's true poses are moved by each of ``SHIFTS`` along their headings and the scan
    log-likelihoods of all its scans are summed; 0 when the filter's model agrees with the simulator.
    """
    truth = trial["truth"]
    c, s = np.cos(truth[:, 2]), np.sin(truth[:, 2])
    total = []
    for d in SHIFTS:
        moved = truth + np.column_stack([d * c, d * s, np.zeros(len(truth))])
        total.append(sum(float(sl.scan_log_likelihood(model, moved[k:k + 1], trial["ranges"][k], angles)[0])
                         for k in range(len(truth))))
    return float(SHIFTS[int(np.argmax(total))])


def odometry_error_ratio(log, ref, alpha):
    """The odometry's error per update against the reference track, over the motion model's standard deviation.

    Returns ``{"translation": ..., "heading": ...}``: the standard deviation of the translation error and
    of the heading-change error, each divided per update by the one Table 5.6 gives with `alpha` at the
    reference's increments (as the simulator draws it); 1 when the odometry is as noisy as the model says.
    """
    a = np.asarray(alpha, dtype=float)
    odom, truth = log.laser_pose[ref.scan_index], ref.mean
    u = sl.odometry_from_poses(odom[:-1], odom[1:])
    u_ref = sl.odometry_from_poses(truth[:-1], truth[1:])
    r1, t, r2 = u_ref.T  # the simulator draws the odometry around the true increments, with their variances
    var_r1, var_t, var_r2 = a[0] * r1**2 + a[1] * t**2, a[2] * t**2 + a[3] * (r1**2 + r2**2), a[0] * r2**2 + a[1] * t**2
    e_t = u[:, 1] - t
    e_h = sl.wrap_angle(np.diff(odom[:, 2]) - np.diff(truth[:, 2]))
    return dict(translation=float(np.std(e_t / np.sqrt(var_t))), heading=float(np.std(e_h / np.sqrt(var_r1 + var_r2))))


def range_excess(grid, log, ref, threshold):
    """Median of measured minus ray-cast range over the log's beams within 1 m of the map's, at the reference track."""
    z = log.ranges[ref.scan_index]
    z_star = sl.ray_cast(grid, ref.mean, log.angles, log.max_range, sensor_offset=log.sensor_offset,
                         threshold=threshold)
    e = (z - z_star)[(z < log.max_range) & (z_star < log.max_range)]
    return float(np.median(e[np.abs(e) < 1.0]))

# --------------------------------------------------------------------------- what the scans tell apart
#: Where alias_evidence looks for each pose's best fit: within 0.25 m and 4 degrees (the reference track's
#: own error), 5 x 5 x 5 poses, the pose itself among them.
ALIAS_SEARCH = np.array(np.meshgrid(np.linspace(-0.25, 0.25, 5), np.linspace(-0.25, 0.25, 5),
                                    np.deg2rad(np.linspace(-4.0, 4.0, 5)))).reshape(3, -1).T
#: How far the wrong track may move from the odometry at each update, to follow the scans (the robot's
#: odometry errs by about 0.02 m and 0.3 degrees per update): 0.05 m and 1 degree, 3 x 3 x 3 poses.
ALIAS_STEP = np.array(np.meshgrid(np.linspace(-0.05, 0.05, 3), np.linspace(-0.05, 0.05, 3),
                                  np.deg2rad(np.linspace(-1.0, 1.0, 3)))).reshape(3, -1).T


def alias_track(model, odom, ranges, angles, scan_index, end):
    """The track that ends at pose `end` and moved as the odometry says, kept on the scans.

    From `end`, each earlier pose is the odometry's increment carried back from the later one, moved
    within ``ALIAS_STEP`` to where the scan of that update fits best, so that the odometry's drift
    does not carry the track off its place over a long trial.
    """
    track = np.empty((len(scan_index), 3))
    track[-1] = end
    for t in range(len(scan_index) - 2, -1, -1):
        u = sl.odometry_from_poses(odom[scan_index[t + 1]], odom[scan_index[t]])
        guess = sl.odometry_motion(track[t + 1], u) + ALIAS_STEP
        track[t] = guess[np.argmax(sl.scan_log_likelihood(model, guess, ranges[scan_index[t]], angles))]
    return track


def alias_evidence(model, odom, ranges, angles, scan_index, end, truth):
    """How much better the scans fit the wrong place a run ended at than the truth (tempered log-likelihood ratio).

    The final estimate `end`, carried back through the odometry to every update of the run
    (:func:`alias_track`), is a track that moved as the true one did: two hypotheses that the motion
    model cannot tell apart. The sum over the run's updates of
    ``tau (log p(z | alias, m) - log p(z | truth, m))``, each pose at its best fit within
    ``ALIAS_SEARCH``, is about the log of the odds between the two tracks that any Bayes filter with
    this sensor model and map reaches from a uniform prior, weighed as the filter weighs a scan (every
    beam of ``beam_step``, tempered by ``likelihood_exponent``; beam skipping not applied). It weighs
    the scans alone: a pose in a wall or in unknown space is not rejected (``reject_unknown``), since
    the track carried back through the odometry can graze a wall the filter's particles went around.
    Above 0 the scans favour the wrong place, below 0 the truth; but the measure has a spread of its
    own, which :func:`alias_null` measures: only a value beyond it decides. The wrong track follows
    the scans only within ``ALIAS_STEP`` per update, the truth is the reference at each update: where
    the method errs, it errs against the wrong place.

    `odom` and `ranges` are the run's arrays (`scan_index`, the run's ``res.scan_index``, indexes
    them), `truth` the true pose at each update.
    """
    idx = scan_index
    tau = model.params.likelihood_exponent
    model = dataclasses.replace(model, params=dataclasses.replace(model.params, reject_unknown=False))
    alias = alias_track(model, odom, ranges, angles, idx, end)

    def best(pose, t):
        return float(np.max(sl.scan_log_likelihood(model, pose + ALIAS_SEARCH, ranges[idx[t]], angles)))

    return tau * sum(best(alias[t], t) - best(truth[t], t) for t in range(len(idx)))


def alias_null(model, odom, ranges, angles, n_updates, truth_at_scans):
    """``alias_evidence`` of a trial's true end against its truth: the measure's spread where it should be 0.

    The true track, chained back from its last pose as a wrong one would be, is weighed against the
    reference poses; the spread of these values over a set's trials is how far from 0 the measure
    strays between two tracks that are both the truth. The trial's update scans are those the filter
    uses (:func:`slamlib.odometry_steps`, the first `n_updates`); ``truth_at_scans(idx)`` gives the
    true poses at them.
    """
    p = model.params
    idx = sl.odometry_steps(odom, min_translation=p.min_translation, min_rotation=p.min_rotation)[0][:n_updates]
    truth = truth_at_scans(idx)
    return alias_evidence(model, odom, ranges, angles, idx, truth[-1], truth)


def alias_verdict(value, band):
    """``"wrong place"`` beyond the band, ``"truth"`` below minus the band, else ``"tie"``; None for no value."""
    if value is None:
        return None
    return "wrong place" if value > band else ("truth" if value < -band else "tie")


# --------------------------------------------------------------------------- running
def judge(res, truth):
    err = np.hypot(*(res.estimate[:, :2] - truth[:, :2]).T)
    half = err[len(err) // 2:]
    wrong_sure = (err > RADIUS) & (res.mode_mass > CONFIDENT)
    wrong_conf = (err > RADIUS) & (res.confidence > CONFIDENT)
    return dict(strict=bool(np.all(half < RADIUS)), share=float(np.mean(half < RADIUS)),
                confidently_wrong=int(wrong_sure.sum()), confidently_wrong_conf=int(wrong_conf.sum()), updates=len(res), runtime=float(res.runtime),
                final_error=float(err[-1]), final_mode_mass=float(res.mode_mass[-1]),
                median_n_modes_2nd_half=float(np.median(res.n_modes[len(err) // 2:])))


def _init(data):
    _WORK.update(data)
    _WORK["grid"] = cmu.load_cmu_map()


def _yardstick(params, model="likelihood_field"):
    """The defaults' model for a laser with `params`' sensor offset and maximum range (kept per worker), or
    with ``model="beam"`` the defaults with the beam model in place of the likelihood field."""
    key = (params.sensor_offset, params.z_max, model)
    if key not in _WORK.setdefault("yardsticks", {}):
        _WORK["yardsticks"][key] = sl.prepare_mcl(_WORK["grid"], make_params({"model": model}, *key[:2]))
    return _WORK["yardsticks"][key]


def _run(job):
    config, kind, key, seed = job
    variant, overrides = CONFIGS[config]
    grid = _WORK["grid"]
    rng = np.random.default_rng(seed)

    def start(params, pose):  # None: global localization; the ceiling starts around the true pose
        if config not in TRUTH_STARTS:
            return None
        return pose + rng.normal(size=(params.n_particles, 3)) * TRUTH_SPREAD

    if kind == "sim":
        trial = _WORK["sims"][key]
        model = sl.prepare_mcl(grid, make_params(overrides))
        res = sl.run_mcl(model, trial["odom"], trial["ranges"], _WORK["angles"], rng=rng, variant=variant,
                         init=start(model.params, trial["truth"][0]), times=trial["times"])
        truth = trial["truth"][res.scan_index]
        odom, ranges, angles = trial["odom"], trial["ranges"], _WORK["angles"]
    else:
        n, j = key
        log, ref = _WORK["logs"][n], _WORK["refs"][n]
        model = sl.prepare_mcl(grid, make_params(overrides, log.sensor_offset, log.max_range))
        a = ref.scan_index[j]
        res = sl.run_mcl(model, log.laser_pose[a:], log.ranges[a:], log.angles, rng=rng, variant=variant,
                         init=start(model.params, truth_at(ref, log.laser_pose, np.array([a]))[0]),
                         times=log.laser_t[a:], max_steps=_WORK["updates"])
        truth = truth_at(ref, log.laser_pose, res.scan_index + a)
        odom, ranges, angles = log.laser_pose[a:], log.ranges[a:], log.angles
    out = judge(res, truth)
    # only a run that ends on a wrong place has an alias to weigh against the truth, by the defaults' sensor model
    # (every configuration on one scale, the one alias_null's band is measured on)
    out["alias_evidence"] = alias_evidence(_yardstick(model.params), odom, ranges, angles, res.scan_index,
                                           res.estimate[-1], truth) if out["final_error"] > RADIUS else None
    # the defaults' wrong endings on the logs, weighed also by the beam model, which charges a beam for passing
    # where the map has a wall (the likelihood field looks at the endpoint alone): would it tell the tracks apart?
    if config == "defaults" and kind == "logs" and out["alias_evidence"] is not None:
        out["alias_evidence_beam"] = alias_evidence(_yardstick(model.params, "beam"), odom, ranges, angles,
                                                    res.scan_index, res.estimate[-1], truth)
    out.update(config=config, set=kind, trial=key if kind == "sim" else list(key), seed=seed,
               duration=float(res.t[-1] - res.t[0]))
    return out


def summarize(runs, band=0.0):
    n = len(runs)
    k = sum(r["strict"] for r in runs)
    lo, hi = wilson(k, n)
    cw = sum(r["confidently_wrong"] for r in runs)
    return dict(trials=n, strict=k, strict_rate=k / n if n else float("nan"), strict_ci=[lo, hi],
                share_within=float(np.mean([r["share"] for r in runs])) if n else float("nan"),
                confidently_wrong_updates=cw, confidently_wrong_trials=sum(r["confidently_wrong"] > 0 for r in runs),
                confidently_wrong_conf_updates=sum(r.get("confidently_wrong_conf", 0) for r in runs),
                confidently_wrong_conf_trials=sum(r.get("confidently_wrong_conf", 0) > 0 for r in runs),
                wrong_at_end=sum(r["final_error"] > RADIUS for r in runs),
                **{f"alias_{v.replace(' ', '_')}": sum(alias_verdict(r.get("alias_evidence"), band) == v for r in runs)
                   for v in ("wrong place", "tie", "truth")},
                updates=sum(r["updates"] for r in runs), cpu_s=float(sum(r["runtime"] for r in runs)),
                real_time_factor=float(sum(r["duration"] for r in runs) / max(sum(r["runtime"] for r in runs), 1e-9)))


def choose(table, configs, on):
    """The configuration with the best strict success on set `on` (then fewer confidently wrong, less CPU)."""
    return max(configs, key=lambda c: (table[c][on]["strict"] / max(table[c][on]["trials"], 1),
                                       -table[c][on]["confidently_wrong_updates"], -table[c][on]["cpu_s"]))


def _key(job):
    config, kind, key, seed = job
    return json.dumps([config, kind, key if kind == "sim" else list(key), seed])


def _call_indexed(args):
    worker, i, job = args
    return i, worker(job)


def resumable_runs(jobs, job_key, worker, cache_path, *, processes, initializer, initargs, every=20, run=True):
    """Run ``worker(job)`` for every job not yet in the JSON-lines file `cache_path`; return ``{key: run}``.

    Every finished run is appended to the file at once with its key (``job_key(job)``) as ``cache_key``,
    so an interrupted study resumes where it stopped. The jobs run in a pool of `processes` forked
    workers set up by ``initializer(*initargs)``. With ``run=False`` nothing runs: the cached runs only.
    """
    done = {}
    if os.path.exists(cache_path):
        with open(cache_path) as f:
            for line in f:
                r = json.loads(line)
                done[r["cache_key"]] = r
    missing = [j for j in jobs if job_key(j) not in done]
    todo = missing if run else []
    print(f"{len(jobs)} runs, {len(jobs) - len(missing)} of them cached in {cache_path}", flush=True)
    t1 = time.perf_counter()
    if todo:
        with open(cache_path, "a") as f, get_context("fork").Pool(processes, initializer=initializer,
                                                                 initargs=initargs) as pool:
            calls = [(worker, i, j) for i, j in enumerate(todo)]
            for n, (i, r) in enumerate(pool.imap_unordered(_call_indexed, calls, chunksize=1)):
                r["cache_key"] = job_key(todo[i])
                f.write(json.dumps(r) + "\n")
                f.flush()
                done[r["cache_key"]] = r
                if (n + 1) % every == 0:
                    print(f"  {n + 1}/{len(todo)} runs, {time.perf_counter() - t1:.0f} s", flush=True)
    return done, len(todo), time.perf_counter() - t1


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--configs", nargs="+", default=["defaults", "plain MCL"],
                    help="configurations run on every trial (default: the defaults and plain MCL)")
    ap.add_argument("--screen", nargs="*", default=[], metavar="CONFIG",
                    help="configurations run on the development subset only (the first --screen-sim simulated "
                         "trials and --screen-offsets offsets per log); 'all' for every other configuration")
    ap.add_argument("--sim-trials", type=int, default=100)
    ap.add_argument("--offsets", type=int, default=10, help="start offsets per log")
    ap.add_argument("--screen-sim", type=int, default=12)
    ap.add_argument("--screen-offsets", type=int, default=2)
    ap.add_argument("--updates", type=int, default=40, help="filter updates per trial")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--cache", default=os.path.join(tempfile.gettempdir(), "mcl_study_runs.jsonl"),
                    help="every finished run is appended here; runs already in it are not repeated")
    ap.add_argument("--json", help="write the summary and every trial to this file")
    ap.add_argument("--cached-only", action="store_true", help="summarise the cached runs, run nothing")
    args = ap.parse_args(argv)
    for name, low in {'sim_trials': 1, 'offsets': 1, 'screen_sim': 0, 'screen_offsets': 0, 'updates': 2, 'jobs': 1, 'seed': 0}.items():  # counts at least 1, seeds at least 0
        value = getattr(args, name)
        if value is not None and min(value if isinstance(value, list) else [value]) < low:
            ap.error(f"--{name.replace('_', '-')} must be at least {low}, got {value}")
    screen = [c for c in CONFIGS if c not in args.configs and c not in TRUTH_STARTS] if args.screen == ["all"] \
        else args.screen
    for c in list(args.configs) + list(screen):
        if c not in CONFIGS:
            raise SystemExit(f"unknown configuration {c!r}; one of {list(CONFIGS)}")

    t0 = time.perf_counter()
    grid = cmu.load_cmu_map()
    base = make_params({})
    field = sl.likelihood_field(grid, max_dist=base.max_dist, threshold=base.occupied_threshold)
    logs = {n: cmu.load_cmu_log(log=n) for n in (1, 2)}
    angles = logs[1].angles
    refs = {n: reference_track(grid, lg, n)[0] for n, lg in logs.items()}
    ss = np.random.SeedSequence(args.seed)
    sim_ss, run_ss = ss.spawn(2)
    roadmap = _roadmap(grid, field, base.free_threshold)
    robot = dataclasses.replace(base, alpha=tuple(a * SIM_ODOMETRY_STD**2 for a in base.alpha))  # the robot's odometry
    sims = [simulate_trial(grid, field, roadmap, robot, angles, args.updates, np.random.default_rng(s))
            for s in sim_ss.spawn(args.sim_trials)]
    log_keys = [(n, int(j)) for n in (1, 2)
                for j in np.linspace(0, len(refs[n]) - args.updates - 1, args.offsets).round().astype(int)]
    seeds = [int(s.generate_state(1)[0]) for s in run_ss.spawn(len(sims) + len(log_keys))]
    trials = [("sim", i, seeds[i]) for i in range(len(sims))] + \
             [("logs", key, seeds[len(sims) + i]) for i, key in enumerate(log_keys)]
    sub_logs = set(log_keys[n * args.offsets + i] for n in range(2)
                   for i in np.linspace(0, args.offsets - 1, args.screen_offsets).round().astype(int))
    subset = [t for t in trials if (t[0] == "sim" and t[1] < args.screen_sim) or (t[0] == "logs" and t[1] in sub_logs)]
    print(f"{len(sims)} simulated trials ({args.updates} updates, {(args.updates - 1) * SIM_STEP:.1f} m, "
          f"{(args.updates - 1) * SIM_STEP / SIM_SPEED:.0f} s each), {len(log_keys)} log trials "
          f"({args.offsets} start offsets per log, {args.updates} updates each); development subset "
          f"{len(subset)} trials; set-up {time.perf_counter() - t0:.0f} s", flush=True)
    jobs = [(c, kind, key, seed) for c in args.configs for kind, key, seed in trials] + \
           [(c, kind, key, seed) for c in screen for kind, key, seed in subset]
    data = dict(sims=sims, logs=logs, refs=refs, angles=angles, updates=args.updates)
    done, n_new, wall = resumable_runs(jobs, _key, _run, args.cache + f".u{args.updates}", processes=args.jobs,
                                       initializer=_init, initargs=(data,), run=not args.cached_only)
    if args.cached_only:
        jobs = [j for j in jobs if _key(j) in done]
    runs = [done[_key(j)] for j in jobs]
    # the spread of alias_evidence between two tracks that are both the truth, per set: the band within which
    # a wrong ending is too close to call (the defaults' sensor model, every trial of the full study)
    t_null = time.perf_counter()
    sim_model = sl.prepare_mcl(grid, base)  # the defaults' model: the band's scale, and the model checks
    null = {"sim": [float(alias_null(sim_model, s["odom"], s["ranges"], angles, args.updates,
                                     lambda idx, s=s: s["truth"][idx])) for s in sims]}
    log_models = {n: sl.prepare_mcl(grid, make_params({}, lg.sensor_offset, lg.max_range)) for n, lg in logs.items()}
    null["logs"] = [float(alias_null(log_models[n], logs[n].laser_pose[refs[n].scan_index[j]:],
                                     logs[n].ranges[refs[n].scan_index[j]:], logs[n].angles, args.updates,
                                     lambda idx, n=n, a=refs[n].scan_index[j]: truth_at(refs[n], logs[n].laser_pose, idx + a)))
                    for n, j in log_keys]
    band = {k: float(np.max(np.abs(v))) for k, v in null.items()}
    # the same band by the beam model, for the defaults' wrong endings on the logs weighed by it (_run)
    t_beam = time.perf_counter()
    beam_models = {n: sl.prepare_mcl(grid, make_params({"model": "beam"}, lg.sensor_offset, lg.max_range))
                   for n, lg in logs.items()}
    null_beam = [float(alias_null(beam_models[n], logs[n].laser_pose[refs[n].scan_index[j]:],
                                  logs[n].ranges[refs[n].scan_index[j]:], logs[n].angles, args.updates,
                                  lambda idx, n=n, a=refs[n].scan_index[j]: truth_at(refs[n], logs[n].laser_pose,
                                                                                     idx + a)))
                 for n, j in log_keys]
    band_beam = float(np.max(np.abs(null_beam)))
    ev_beam = [r.get("alias_evidence_beam") for r in runs if r["config"] == "defaults" and r["set"] == "logs"
               and r["alias_evidence"] is not None]
    if None in ev_beam:
        raise SystemExit("cached runs of the defaults lack alias_evidence_beam: run them again (a new --cache)")
    print(f"the defaults' {len(ev_beam)} wrong endings on the log starts, weighed by the beam model (band "
          f"{band_beam:.2f}, {time.perf_counter() - t_beam:.0f} s): "
          + ", ".join(f"{sum(alias_verdict(v, band_beam) == w for v in ev_beam)} {w}"
                      for w in ("wrong place", "tie", "truth")), flush=True)
    print(f"alias evidence between two tracks that are both the truth: within {band['sim']:.2f} (simulated drives) and "
          f"{band['logs']:.2f} (log starts), {time.perf_counter() - t_null:.0f} s", flush=True)

    def table_for(configs, trial_list):
        keys = {(k, json.dumps(key if k == "sim" else list(key))) for k, key, _ in trial_list}
        return {c: {s: summarize([r for r in runs if r["config"] == c and r["set"] == s
                                  and (s, json.dumps(r["trial"])) in keys], band[s]) for s in ("sim", "logs")}
                for c in configs}

    def show(table, title):
        print(f"\n{title}")
        print(f"{'configuration':32s} {'set':5s} {'strict success (95 % CI)':>28s} {'share within':>12s} "
              f"{'conf. wrong upd (trials)':>25s} {'by confidence':>14s} {'ends wrong (scans: wrong/tie/truth)':>36s} {'CPU [s]':>8s} "
              f"{'x real time':>11s}")
        for c, row in table.items():
            for s in ("sim", "logs"):
                t = row[s]
                print(f"{c:32s} {s:5s} {t['strict']:4d}/{t['trials']:<4d} = {t['strict_rate']:5.0%} "
                      f"[{t['strict_ci'][0]:4.0%}, {t['strict_ci'][1]:4.0%}]   {t['share_within']:10.0%} "
                      f"{t['confidently_wrong_updates']:17d} ({t['confidently_wrong_trials']:3d}) "
                      f"{t['confidently_wrong_conf_updates']:7d} ({t['confidently_wrong_conf_trials']:3d}) "
                      f"{t['wrong_at_end']:19d} ({t['alias_wrong_place']:3d}/{t['alias_tie']:3d}/{t['alias_truth']:3d}) "
                      f"{t['cpu_s']:8.0f} "
                      f"{t['real_time_factor']:10.1f}x")

    table = table_for(args.configs, trials)
    show(table, "the full study")
    screen_table = table_for([c for c in args.configs if c not in TRUTH_STARTS] + list(screen), subset) if screen else {}
    if screen:
        show(screen_table, f"the development subset ({args.screen_sim} simulated trials, {args.screen_offsets} offsets per log): "
                           "one mechanism changed at a time")
    cv = {}
    candidates = screen_table or {c: row for c, row in table.items() if c not in TRUTH_STARTS}  # never an oracle
    if len(candidates) > 1:
        print("\ncross-validation: chosen on one set (development subset), reported on the other")
        for tune, report in (("sim", "logs"), ("logs", "sim")):
            c = choose(candidates, list(candidates), tune)
            t = table[c][report] if c in table else candidates[c][report]
            cv[f"tuned on {tune}"] = dict(chosen=c, reported_on=report, **t)
            print(f"  tuned on {tune:4s}: {c!r}; on {report}: strict {t['strict']}/{t['trials']} = {t['strict_rate']:.0%} "
                  f"[{t['strict_ci'][0]:.0%}, {t['strict_ci'][1]:.0%}], confidently wrong {t['confidently_wrong_updates']}")
    print(f"\nthe defaults: {make_params({})}")
    print(f"wall time {wall:.0f} s with {args.jobs} process(es), {n_new} new runs, "
          f"CPU in the filters (all {len(runs)} runs) {sum(r['runtime'] for r in runs):.0f} s")
    offsets = [field_offset(sim_model, t, angles) for t in sims[:20]]
    checks = dict(sim_field_offset=float(np.median(offsets)), sim_field_offsets=offsets,
                  log_range_excess={n: range_excess(grid, logs[n], refs[n], base.occupied_threshold) for n in logs},
                  odometry_error_ratio={n: odometry_error_ratio(logs[n], refs[n], base.alpha) for n in logs},
                  alias_null=null, alias_band=band, alias_null_beam_logs=null_beam,
                  alias_band_beam_logs=band_beam)
    print(f"model checks: the filter's scan likelihood of the first {len(offsets)} simulated drives peaks "
          f"{checks['sim_field_offset']:+.2f} m along the heading from the truth (median); measured ranges exceed "
          f"the map's at the logs' reference tracks by a median of "
          + ", ".join(f"{v:.2f} m (log {n})" for n, v in checks["log_range_excess"].items())
          + "; the odometry's error per update is " + ", ".join(
              f"{v['translation']:.2f} (translation) and {v['heading']:.2f} (heading) of the motion model's "
              f"standard deviation (log {n})" for n, v in checks["odometry_error_ratio"].items())
          + f"; the simulator draws {SIM_ODOMETRY_STD:.2f}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(dict(settings=dict(updates=args.updates, sim_trials=len(sims), offsets_per_log=args.offsets,
                                         screen_sim=args.screen_sim, screen_offsets=args.screen_offsets,
                                         radius=RADIUS, confident=CONFIDENT, sim_step=SIM_STEP, sim_speed=SIM_SPEED,
                                         seed=args.seed, range_bias=base.range_bias, sim_odometry_std=SIM_ODOMETRY_STD, log_updates={n: len(r) for n, r in refs.items()},
                                         truth_spread=[float(v) for v in TRUTH_SPREAD],
                                         alias_search=dict(position=float(ALIAS_SEARCH[:, 0].max()),
                                                           heading_deg=float(np.degrees(ALIAS_SEARCH[:, 2].max()))),
                                         alias_step=dict(position=float(ALIAS_STEP[:, 0].max()),
                                                         heading_deg=float(np.degrees(ALIAS_STEP[:, 2].max()))),
                                         model_checks=checks),
                           configs={c: dict(variant=CONFIGS[c][0], overrides=CONFIGS[c][1])
                                    for c in list(args.configs) + list(screen)},
                           table=table, screen=screen_table, cross_validation=cv,
                           runs=[{k: round(v, 4) if isinstance(v, float) else v for k, v in r.items() if k != "cache_key"}
                                 for r in runs]),
                      f, indent=None)
    return table, runs


if __name__ == "__main__":
    main()
