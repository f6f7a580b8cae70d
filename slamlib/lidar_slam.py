"""A small lidar SLAM: ICP odometry, loop closures, a pose graph and an occupancy grid.

The pipeline on a log of odometry and laser scans (the CMU Wean Hall log):

1. **Keyframes.** A scan becomes a keyframe once the wheel odometry has moved
   ``min_translation`` or turned ``min_rotation`` since the last one
   (:func:`~slamlib.mcl.odometry_steps`, the rule MCL uses).
2. **Front end: ICP odometry.** Each keyframe's scan is matched to the previous
   one by point-to-line ICP (:mod:`slamlib.scan_matching`) from the odometry
   increment as initial guess. The ICP estimate and the odometry increment are
   fused by their information matrices, so that in a degenerate direction (a
   featureless corridor, flagged by ICP's degeneracy check) the odometry
   decides, and a failed match falls back to the odometry alone.
3. **Loop closures.** Keyframes that the ICP odometry puts within
   ``loop_radius`` of an older keyframe, at least ``loop_min_path`` metres of
   travel earlier, are candidates. ICP of the new scan against a local map
   around the older keyframe (its neighbouring scans placed by the ICP
   odometry: the robot often passes a place facing the other way, and a
   180-degree scan then shares little with the single older scan) verifies
   them, and only matches that converge, fit (RMS distance, share of points
   matched) and are not degenerate become edges.
4. **Back end.** The keyframe poses are the solution of the pose graph of the
   sequential and loop edges (:func:`~slamlib.graph_slam.optimize_pose_graph`,
   Levenberg-Marquardt with a Cauchy kernel, so that a wrong loop closure that
   got through the checks is down-weighted instead of bending the map).
5. **Map.** Occupancy-grid mapping with the optimised poses as known poses
   (:func:`~slamlib.mapping.occupancy_grid_mapping`).

:func:`cmu_reference_track` makes the MCL reference track of the Wean Hall log
(MCL started around the scan-matched start pose, as in chapter 5 and
``tests/test_mcl.py``), and :func:`score_lidar_slam` scores raw odometry, ICP
odometry and the full pipeline against it (ATE after a rigid alignment) and
against the shipped map (:func:`~slamlib.mapping.map_agreement`, the map moved
by the trajectory's alignment).

References
----------
F. Lu, E. Milios, "Globally consistent range scan alignment for environment
mapping", Autonomous Robots 4:333-349, 1997 (scan matching and a pose graph);
G. Grisetti, R. Kuemmerle, C. Stachniss, W. Burgard, "A tutorial on graph-based
SLAM", IEEE ITS Magazine 2(4):31-43, 2010; Besl & McKay (1992); Censi (2008);
Thrun, Burgard & Fox, *Probabilistic Robotics* (2005), Table 9.1 (mapping with
known poses), Table 8.2 (MCL, for the reference track), Sec. 11 (GraphSLAM).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ._checks import as_array, as_index, as_scalar, check_rng
from .angles import wrap_angle
from .graph_slam import _compose, _relative, optimize_pose_graph
from .mapping import OccupancyParams, map_agreement, occupancy_grid_mapping
from .mcl import AugmentedParams, MCLParams, odometry_steps, prepare_mcl, run_mcl
from .scan_matching import _icp_result, _prepare_target, _scan_points
from .scoring import score_trajectory

__all__ = [
    "LidarSlamParams",
    "LidarSlamResult",
    "run_lidar_slam",
    "poses_at_scans",
    "cmu_reference_track",
    "score_lidar_slam",
]


@dataclass(frozen=True)
class LidarSlamParams:
    """Settings of :func:`run_lidar_slam`.

    Attributes
    ----------
    min_translation, min_rotation : float
        Keyframe spacing [m, rad] (:func:`~slamlib.mcl.odometry_steps`).
    beam_step : int
        Use every `beam_step`-th beam of each scan for ICP.
    max_range : float
        Readings at or beyond it [m] are not used by ICP.
    icp_max_dist, icp_trim : float
        Gate [m] and kept fraction of scan-to-scan ICP.
    odom_sigma : tuple of 4 float
        Odometry noise per keyframe step: ``(a, b, c, d)`` gives standard
        deviations ``a + b * distance`` [m] in translation and ``c + d * |turn|``
        [rad] in heading.
    icp_sigma : tuple of 2 float
        Floors [m, rad] added to ICP's own standard deviations, whose
        ``J^T J`` covariance ignores association and model errors (too
        optimistic, Censi 2007).
    max_rmse : float
        Largest RMS pair distance [m] of an accepted scan-to-scan match.
    loop_radius : float
        Candidate loop closures lie within this distance [m] in the ICP odometry.
    loop_min_path : float
        ... and at least this much travel [m] apart.
    loop_max_candidates : int
        Nearest candidates tried per keyframe.
    loop_stride : int
        Look for loop closures at every `loop_stride`-th keyframe.
    loop_window : int
        A candidate is matched against the local map of keyframes
        ``i - loop_window .. i + loop_window`` around the older keyframe ``i``.
    loop_max_dist, loop_trim : float
        Gate [m] and kept fraction of loop-closure ICP.
    loop_max_rmse, loop_min_match : float
        Acceptance: RMS pair distance [m] at most; share of the scan's points
        inside the gate at least.
    loop_max_correction : float
        A match moving the pose by more than this [m] from the ICP odometry's
        guess is rejected.
    loop_sigma : tuple of 2 float
        Standard deviations [m, rad] of a loop-closure edge.
    robust : {None, "huber", "cauchy"}
        Kernel of the pose-graph optimisation.
    map_resolution : float
        Cell side [m] of the occupancy grid.
    occupancy : OccupancyParams
        Inverse sensor model of the mapping.
    """

    min_translation: float = 0.2
    min_rotation: float = 0.2
    beam_step: int = 1
    max_range: float = 40.0
    icp_max_dist: float = 0.3
    icp_trim: float = 0.8
    odom_sigma: tuple = (0.02, 0.1, 0.01, 0.1)
    icp_sigma: tuple = (0.01, 0.005)
    max_rmse: float = 0.15
    loop_radius: float = 2.0
    loop_min_path: float = 5.0
    loop_max_candidates: int = 2
    loop_stride: int = 2
    loop_max_dist: float = 0.5
    loop_trim: float = 0.8
    loop_max_rmse: float = 0.08
    loop_min_match: float = 0.7
    loop_max_correction: float = 1.0
    loop_window: int = 15
    loop_sigma: tuple = (0.05, 0.02)
    robust: str = "cauchy"
    map_resolution: float = 0.1
    occupancy: OccupancyParams = field(default_factory=OccupancyParams)


@dataclass(frozen=True, eq=False)
class LidarSlamResult:
    """Result of :func:`run_lidar_slam`.

    Attributes
    ----------
    scan_index : ndarray of int, shape (n,)
        The keyframes' scan indices.
    odometry : ndarray, shape (n, 3)
        Raw wheel odometry at the keyframes, moved to start at ``x0``.
    icp_odometry : ndarray, shape (n, 3)
        The front end's chain of fused ICP / odometry increments (no loop closures).
    poses : ndarray, shape (n, 3)
        The pose-graph solution.
    edges : ndarray of int, shape (E, 2)
        Sequential edges first (``n - 1``), then the accepted loop closures.
    Z, Omega : ndarray, shapes (E, 3) and (E, 3, 3)
        Edge measurements and information matrices.
    n_sequential : int
        ``n - 1``.
    icp_status : ndarray of str, shape (n - 1,)
        Per sequential step: ``"icp"``, ``"degenerate"`` (ICP fused with
        odometry in its weak direction) or ``"odometry"`` (ICP rejected).
    loop_tried, loop_rejected : int
        Loop-closure candidates matched, and those the checks turned down.
    graph : PoseGraphResult
        The optimisation's record (``chi2`` per iteration, weights).
    grid : OccupancyGrid
        The occupancy grid from `poses`.
    timing : dict
        Seconds spent in ``front_end``, ``loops``, ``back_end``, ``mapping``.
    """

    scan_index: np.ndarray
    odometry: np.ndarray
    icp_odometry: np.ndarray
    poses: np.ndarray
    edges: np.ndarray
    Z: np.ndarray
    Omega: np.ndarray
    n_sequential: int
    icp_status: np.ndarray
    loop_tried: int
    loop_rejected: int
    graph: object
    grid: object
    timing: dict


def _odom_information(inc, sig):
    a, b, c, d = sig
    st = a + b * np.hypot(inc[..., 0], inc[..., 1])
    sr = c + d * np.abs(inc[..., 2])
    om = np.zeros(inc.shape[:-1] + (3, 3))
    om[..., 0, 0] = om[..., 1, 1] = 1.0 / st**2
    om[..., 2, 2] = 1.0 / sr**2
    return om


def _icp_information(res, floor):
    # covariance of the match, with floors for what J^T J leaves out; pinv'd by ICP where degenerate
    cov = np.nan_to_num(res.cov, nan=1e6)
    cov = cov + np.diag([floor[0] ** 2, floor[0] ** 2, floor[1] ** 2])
    return np.linalg.inv(0.5 * (cov + cov.T))


def _fuse(z_a, om_a, z_b, om_b):
    """Product of two Gaussians on a relative pose: ``(Om_a + Om_b)^-1 (Om_a z_a + Om_b z_b)`` around z_a."""
    d = z_b - z_a
    d[2] = wrap_angle(d[2])
    om = om_a + om_b
    z = z_a + np.linalg.solve(om, om_b @ d)
    z[2] = wrap_angle(z[2])
    return z, om


def _local_map(pts, X, i, window):
    """Points of keyframes ``i - window .. i + window`` in the frame of keyframe ``i`` (ICP-odometry poses).

    A scan of a 180-degree laser shares little with a scan taken at the same place facing the other
    way; the scans before and after keyframe ``i`` saw what lies behind it.
    """
    lo, hi = max(0, i - window), min(len(pts), i + window + 1)
    parts = []
    for k in range(lo, hi):  # a loop over the few scans of the window
        rel = _relative(X[i], X[k])
        c, s = np.cos(rel[2]), np.sin(rel[2])
        q = pts[k]
        parts.append(np.column_stack([c * q[:, 0] - s * q[:, 1] + rel[0], s * q[:, 0] + c * q[:, 1] + rel[1]]))
    merged = np.vstack(parts)
    # thin the merged cloud to one point per 5 cm cell: overlapping scans would otherwise repeat each wall
    key = np.floor(merged / 0.05).astype(np.int64)
    _, first = np.unique(key[:, 0] * 1_000_003 + key[:, 1], return_index=True)
    merged = merged[np.sort(first)]
    return _prepare_target(merged) if merged.shape[0] >= 3 else None


def run_lidar_slam(odom_poses, ranges, angles, *, z_max, sensor_offset=0.0, params=None, x0=(0.0, 0.0, 0.0),
                   start=0, stop=None, rng=None, init_noise=(0.0, 0.0)):
    """Lidar SLAM on a log: ICP odometry, verified loop closures, a pose graph, an occupancy grid.

    Parameters
    ----------
    odom_poses : ndarray, shape (L, 3)
        Wheel-odometry pose of the robot centre at every scan.
    ranges : ndarray, shape (L, K)
        The scans [m], all of the same length, no NaN.
    angles : ndarray, shape (K,)
        Beam angles [rad].
    z_max : float, keyword-only
        The laser's no-return reading [m].
    sensor_offset : float, keyword-only
        Distance of the laser ahead of the robot centre [m].
    params : LidarSlamParams, keyword-only
        Settings (the defaults are the ones the chapter uses).
    x0 : ndarray, shape (3,), keyword-only
        Pose of the first keyframe (the gauge: the first pose is held fixed).
    start, stop : int, keyword-only
        Use scans ``start .. stop - 1`` of the log.
    rng : numpy.random.Generator, keyword-only, optional
        Only with `init_noise`: draws ``normal(size=3)`` per ICP call to perturb
        its initial guess (a robustness check of the front end).
    init_noise : tuple of 2 float, keyword-only
        Standard deviations [m, rad] of that perturbation.

    Returns
    -------
    LidarSlamResult

    Raises
    ------
    ValueError
        On NaN in the scans, scans of different lengths, mismatched shapes.

    References
    ----------
    Lu & Milios (1997); Grisetti et al. (2010); Besl & McKay (1992); Censi
    (2008); Thrun, Burgard & Fox (2005), Table 9.1.
    """
    p = LidarSlamParams() if params is None else params
    if not isinstance(p, LidarSlamParams):
        raise TypeError(f"params must be a LidarSlamParams, got {type(p).__name__}")
    odom = as_array(odom_poses, "odom_poses", (None, 3))
    L = odom.shape[0]
    if L < 2:
        raise ValueError(f"odom_poses must hold at least two poses, one per scan (a map needs two keyframes), got {L}")
    try:
        Z_all = as_array(ranges, "ranges", (L, None))
    except ValueError as exc:
        if "finite" in str(exc):
            raise
        raise ValueError(f"ranges must hold one scan per odometry pose ({L}), all of the same length: {exc}") from None
    ang = as_array(angles, "angles", (Z_all.shape[1],))
    if np.any(Z_all < 0):
        raise ValueError("ranges must be non-negative")
    z_max = as_scalar(z_max, "z_max", positive=True, finite=False)
    off = as_scalar(sensor_offset, "sensor_offset")
    x0 = as_array(x0, "x0", (3,))
    start = as_index(start, "start", L)
    stop = L if stop is None else as_index(stop, "stop", L + 1, lower=start + 2)
    noise = np.asarray(init_noise, dtype=float)
    if noise.shape != (2,) or np.any(noise < 0):
        raise ValueError(f"init_noise must be two non-negative standard deviations, got {init_noise!r}")
    if np.any(noise > 0):
        check_rng(rng)
    step = as_index(p.beam_step, "params.beam_step", lower=1)
    timing = {}

    # 1. keyframes
    t0 = time.perf_counter()
    index, _ = odometry_steps(odom[start:stop], min_translation=p.min_translation, min_rotation=p.min_rotation)
    index = index + start
    n = index.size
    if n < 2:
        raise ValueError("the odometry never moves: fewer than two keyframes")
    a_sub = ang[::step]
    usable = min(p.max_range, z_max)
    pts = [_scan_points(Z_all[k, ::step], a_sub, usable, 0.0, off) for k in index]
    targets = [_prepare_target(q) if q.shape[0] >= 3 else None for q in pts]
    odo_inc = _relative(odom[index[:-1]], odom[index[1:]])
    om_odo = _odom_information(odo_inc, p.odom_sigma)

    def perturb(z):
        if not np.any(noise > 0):
            return z
        d = rng.normal(size=3) * [noise[0], noise[0], noise[1]]
        return np.array([z[0] + d[0], z[1] + d[1], wrap_angle(z[2] + d[2])])

    # 2. front end: scan-to-scan ICP from the odometry increment, fused with it
    seq_Z = np.empty((n - 1, 3))
    seq_Om = np.empty((n - 1, 3, 3))
    status = []
    for t in range(1, n):  # a loop over keyframes (time); each match is vectorised over points
        z_o = odo_inc[t - 1]
        res = None
        if targets[t - 1] is not None and pts[t].shape[0] >= 10:
            res = _icp_result(pts[t], targets[t - 1], perturb(z_o), "point_to_line", 30, p.icp_max_dist, p.icp_trim,
                              1e-4, 10, 0.02)
        if res is None or res.rmse > p.max_rmse or "matched" in res.reason:
            seq_Z[t - 1], seq_Om[t - 1] = z_o, om_odo[t - 1]
            status.append("odometry")
            continue
        seq_Z[t - 1], seq_Om[t - 1] = _fuse(res.pose, _icp_information(res, p.icp_sigma), z_o, om_odo[t - 1])
        status.append("degenerate" if res.degenerate else "icp")
    X_icp = np.empty((n, 3))
    X_icp[0] = x0
    for t in range(1, n):
        X_icp[t] = _compose(X_icp[t - 1], seq_Z[t - 1])
    timing["front_end"] = time.perf_counter() - t0

    # 3. loop closures, verified by ICP
    t0 = time.perf_counter()
    path = np.r_[0.0, np.cumsum(np.hypot(*np.diff(X_icp[:, :2], axis=0).T))]
    om_loop = np.diag([1 / p.loop_sigma[0] ** 2, 1 / p.loop_sigma[0] ** 2, 1 / p.loop_sigma[1] ** 2])
    loops, tried, rejected = [], 0, 0
    for j in range(0, n, max(1, int(p.loop_stride))):
        old = np.flatnonzero(path <= path[j] - p.loop_min_path)
        if old.size == 0 or pts[j].shape[0] < 10:
            continue
        d = np.hypot(*(X_icp[old, :2] - X_icp[j, :2]).T)
        near = old[d < p.loop_radius]
        near = near[np.argsort(d[d < p.loop_radius])][: p.loop_max_candidates]
        for i in near:
            target = _local_map(pts, X_icp, i, p.loop_window)
            if target is None:
                continue
            guess = _relative(X_icp[i], X_icp[j])
            res = _icp_result(pts[j], target, perturb(guess), "point_to_line", 50, p.loop_max_dist, p.loop_trim,
                              1e-4, 10, 0.02)
            tried += 1
            moved = np.hypot(*(res.pose[:2] - guess[:2]))
            ok = (res.converged and not res.degenerate and res.rmse <= p.loop_max_rmse
                  and res.match_fraction >= p.loop_min_match * p.loop_trim  # share inside the gate
                  and moved <= p.loop_max_correction)
            if ok:
                loops.append((i, j, res.pose))
            else:
                rejected += 1
    timing["loops"] = time.perf_counter() - t0

    # 4. back end
    t0 = time.perf_counter()
    seq_edges = np.column_stack([np.arange(n - 1), np.arange(1, n)])
    if loops:
        loop_edges = np.array([(i, j) for i, j, _ in loops], dtype=np.intp)
        loop_Z = np.array([z for _, _, z in loops])
        edges = np.vstack([seq_edges, loop_edges])
        Zs = np.vstack([seq_Z, loop_Z])
        Om = np.concatenate([seq_Om, np.broadcast_to(om_loop, (len(loops), 3, 3))])
    else:
        edges, Zs, Om = seq_edges, seq_Z, seq_Om
    graph = optimize_pose_graph(X_icp, edges, Zs, Om, method="lm", max_iter=100, robust=p.robust)
    timing["back_end"] = time.perf_counter() - t0

    # 5. map from the optimised poses
    t0 = time.perf_counter()
    grid, _ = occupancy_grid_mapping(graph.X, Z_all[index], ang, z_max=z_max, resolution=p.map_resolution,
                                     params=p.occupancy, sensor_offset=off)
    timing["mapping"] = time.perf_counter() - t0
    odometry = _compose(x0, _relative(odom[index[0]], odom[index]))
    return LidarSlamResult(scan_index=index, odometry=odometry, icp_odometry=X_icp, poses=graph.X,
                           edges=edges, Z=Zs, Omega=Om, n_sequential=n - 1, icp_status=np.array(status),
                           loop_tried=tried, loop_rejected=rejected, graph=graph, grid=grid, timing=timing)


def poses_at_scans(key_index, key_poses, odom_poses, scans):
    """Poses at any scans, from keyframe poses and the odometry since the last keyframe.

    Parameters
    ----------
    key_index : ndarray of int, shape (n,)
        Increasing scan indices of the keyframes.
    key_poses : ndarray, shape (n, 3)
        Their poses.
    odom_poses : ndarray, shape (L, 3)
        Wheel odometry at every scan.
    scans : ndarray of int, shape (S,)
        Scans wanted, ``>= key_index[0]``.

    Returns
    -------
    ndarray, shape (S, 3)
        ``key_poses[k] (+) (odom[k_scan]^-1 (+) odom[s])`` with ``k`` the last keyframe at or before each scan.

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 5.4 (odometry as relative motion).
    """
    key_index = np.asarray(key_index, dtype=np.intp)
    key_poses = as_array(key_poses, "key_poses", (key_index.size, 3))
    odom = as_array(odom_poses, "odom_poses", (None, 3))
    scans = np.asarray(scans, dtype=np.intp)
    if scans.size and key_index.size == 0:
        raise ValueError("key_index must hold at least one keyframe (the poses are composed from the last one)")
    if scans.size and scans.min() < key_index[0]:
        raise ValueError(f"scans must not precede the first keyframe (scan {key_index[0]})")
    k = np.searchsorted(key_index, scans, side="right") - 1
    return _compose(key_poses[k], _relative(odom[key_index[k]], odom[scans]))


#: The reference track's filter, fixed (see :func:`cmu_reference_track`).
_REFERENCE_MODELS = dict(mode_particles=0, likelihood_exponent=0.2, model="likelihood_field", sigma_hit=0.3,
                         beam_step=10, alpha=(0.05, 0.005, 0.05, 0.005), init_candidates=200_000,
                         augmented=AugmentedParams(p_min=0.01, proposal="sensor", candidates=10_000))


def cmu_reference_track(grid=None, log=None, *, rng, n_particles=2000, spread=(0.1, 0.1, np.deg2rad(2.0))):
    """The MCL reference track of the Wean Hall log.

    There is no ground truth for the log. The reference is MCL that knows where
    it starts: `n_particles` particles in a small cloud around the scan-matched
    start pose ``CMU_LOG_START``, as in chapter 5 and ``tests/test_mcl.py``
    (whose tests check such a track against the map). It is filtered over the
    whole log with :func:`~slamlib.mcl.run_mcl`'s default variant (Augmented
    MCL) and plain low-variance resampling (``mode_particles=0``): a tracking
    run has one mode, and keeping the modes of the few particles sensor
    resetting adds would only spend particles on them. Its models are fixed
    here (tempering ``likelihood_exponent = 0.2``, the kidnap prior
    ``p_min = 0.01``), the values at which the track was checked against the
    map and against lidar SLAM, so that a change of the filter's defaults does
    not move the reference that other methods are judged against.

    Parameters
    ----------
    grid : OccupancyGrid, optional
        The Wean Hall map (default :func:`~slamlib.datasets.cmu.load_cmu_map`).
    log : CmuLog, optional
        The log (default :func:`~slamlib.datasets.cmu.load_cmu_log`).
    rng : numpy.random.Generator
        Draws the initial cloud, ``normal(size=(n_particles, 3))``, then the filter's draws.
    n_particles : int
        Particles of the initial cloud.
    spread : tuple of 3 float
        Standard deviations of the initial cloud [m, m, rad].

    Returns
    -------
    MCLResult
        ``scan_index`` (the filter's updates, the scans of
        :func:`~slamlib.mcl.odometry_steps`) and ``mean`` (the track, in the map frame).

    References
    ----------
    Thrun, Burgard & Fox (2005), Tables 8.2 and 8.3 (MCL and Augmented MCL, position tracking).
    """
    from .datasets import cmu

    check_rng(rng)
    grid = cmu.load_cmu_map() if grid is None else grid
    log = cmu.load_cmu_log() if log is None else log
    n_particles = as_index(n_particles, "n_particles", lower=1)
    model = prepare_mcl(grid, MCLParams(sensor_offset=log.sensor_offset, z_max=log.max_range, **_REFERENCE_MODELS))
    init = np.asarray(cmu.CMU_LOG_START) + rng.normal(size=(n_particles, 3)) * np.asarray(spread, dtype=float)
    return run_mcl(model, log.laser_pose, log.ranges, log.angles, rng=rng, init=init, times=log.laser_t)


@dataclass(frozen=True)
class _Row:
    name: str
    ate: float
    heading_rmse: float
    occupied: float
    free: float
    score: float


def score_lidar_slam(result, reference_index, reference_poses, odom_poses, ranges, angles, reference_map, *, z_max,
                     sensor_offset=0.0, tolerance=0.15):
    """Score raw odometry, ICP odometry and the full pipeline against a reference track and map.

    Each trajectory is evaluated at the reference's scans (poses between
    keyframes by :func:`poses_at_scans`), aligned to the reference by the
    least-squares rigid transform (:func:`~slamlib.scoring.align_se2`), and
    scored by its ATE and heading RMSE (:func:`~slamlib.scoring.score_trajectory`).
    Its occupancy grid (from the keyframe poses) is moved by the same
    transform and compared with `reference_map` (:func:`~slamlib.mapping.map_agreement`).

    Parameters
    ----------
    result : LidarSlamResult
        A run of :func:`run_lidar_slam`.
    reference_index : ndarray of int, shape (S,)
        Scans of the reference track.
    reference_poses : ndarray, shape (S, 3)
        The reference poses (map frame).
    odom_poses, ranges, angles
        The log given to :func:`run_lidar_slam`.
    reference_map : OccupancyGrid
        The map in the reference frame.
    z_max, sensor_offset : float, keyword-only
        As given to :func:`run_lidar_slam`.
    tolerance : float, keyword-only
        Slack of the map agreement [m].

    Returns
    -------
    list of rows
        One per trajectory (``"odometry"``, ``"ICP odometry"``, ``"ICP + loop closure"``) with
        ``name``, ``ate``, ``heading_rmse``, ``occupied``, ``free``, ``score``.

    References
    ----------
    Umeyama (1991) (alignment); Thrun, Burgard & Fox (2005), Sec. 9.2 (maps).
    """
    ref_idx = np.asarray(reference_index, dtype=np.intp)
    ref = as_array(reference_poses, "reference_poses", (ref_idx.size, 3))
    keep = (ref_idx >= result.scan_index[0]) & (ref_idx <= result.scan_index[-1])
    ref_idx, ref = ref_idx[keep], ref[keep]
    rows = []
    spec_res = result.grid.resolution
    for name, key in (("odometry", result.odometry), ("ICP odometry", result.icp_odometry),
                      ("ICP + loop closure", result.poses)):
        est = poses_at_scans(result.scan_index, key, odom_poses, ref_idx)
        sc = score_trajectory(est, ref)
        if key is result.poses:
            grid = result.grid
        else:
            grid, _ = occupancy_grid_mapping(key, np.asarray(ranges)[result.scan_index], angles, z_max=z_max,
                                             resolution=spec_res, sensor_offset=sensor_offset)
        ag = map_agreement(grid, reference_map, transform=(sc.R, sc.t), tolerance=tolerance)
        rows.append(_Row(name, sc.ate, sc.heading_rmse, ag.occupied, ag.free, ag.score))
    return rows
