"""Occupancy-grid mapping with known poses.

The map is a grid of binary cells ``m_i`` (occupied or free); each cell's
posterior is kept as a log odds ``l_i = log p(m_i | z, x) / (1 - p(m_i | z, x))``
and updated scan by scan (Thrun, Burgard & Fox, Table 9.1):

``l_{t,i} = l_{t-1,i} + inverse_sensor_model(m_i, x_t, z_t) - l_0``

for the cells in the perceptual field of the scan. The inverse range-sensor
model (Table 9.2) says what a beam tells about a cell: cells the beam passed
through are probably free, cells within half an obstacle thickness ``alpha / 2``
of its end point probably occupied, everything else unknown (``l_0``).

Two implementations of the same model:

* :func:`inverse_range_sensor_model` evaluates Table 9.2 cell by cell (the
  nearest beam in bearing, its range), vectorised over cells; it is the
  textbook definition, used to check the fast path.
* :func:`scan_update_cells` goes beam by beam, as implementations do: every
  cell each beam crosses (an exact grid traversal, vectorised over all beams
  and all crossings at once, no loop over beams or cells) is classified by the
  range of its centre against the beam's range. :func:`occupancy_grid_mapping`
  applies it to a whole log.

The grid conventions are those of :class:`~slamlib.maps.OccupancyGrid` (row = y,
column = x); the result is an ``OccupancyGrid`` with NaN in cells no beam
reached, classified into free / occupied / unknown by
:func:`classify_occupancy`. :func:`map_agreement` scores a map against a
reference map after a rigid alignment.

References
----------
Thrun, Burgard & Fox, *Probabilistic Robotics* (2005), Ch. 9: Table 9.1
(occupancy grid mapping), Table 9.2 (inverse range sensor model), Eqs. 9.5-9.7
(log odds). H. Moravec, A. Elfes, "High resolution maps from wide angle sonar",
ICRA 1985; A. Elfes, "Using occupancy grids for mobile robot perception and
navigation", Computer 22(6):46-57, 1989. J. Amanatides, A. Woo, "A fast voxel
traversal algorithm for ray tracing", Eurographics 1987 (the cells a ray crosses).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ._checks import as_array, as_scalar, as_scan
from .angles import wrap_angle
from .maps import OccupancyGrid

__all__ = [
    "OccupancyParams",
    "GridSpec",
    "inverse_range_sensor_model",
    "traverse_rays",
    "scan_update_cells",
    "occupancy_grid_mapping",
    "log_odds_to_grid",
    "classify_occupancy",
    "UNKNOWN",
    "FREE",
    "OCCUPIED",
    "MapAgreement",
    "map_agreement",
]

#: Codes of :func:`classify_occupancy`.
UNKNOWN, FREE, OCCUPIED = -1, 0, 1


def _logit(p):
    return float(np.log(p / (1.0 - p)))


@dataclass(frozen=True)
class OccupancyParams:
    """Parameters of the inverse range-sensor model and the log-odds update.

    Attributes
    ----------
    alpha : float
        Thickness of obstacles [m] (Table 9.2): cells whose centre lies
        within ``alpha / 2`` of a beam's end point are occupied evidence.
    beta : float
        Opening angle of a beam [rad] (Table 9.2); used by the cell-by-cell
        model only (the beam-by-beam update follows the beam's centre line).
    p_occ, p_free, p_prior : float
        Probabilities behind ``l_occ``, ``l_free`` and ``l_0`` (Eq. 9.7).
    range_limit : float
        Readings longer than this [m] are cut to it and give free evidence
        only, like a reading without return; long readings of the CMU laser
        are imprecise and the long beams dominate the update's cost.
    clamp : float
        Log odds are kept in ``[-clamp, clamp]`` so that a map can still
        change after many consistent scans (``inf`` disables).
    """

    alpha: float = 0.2
    beta: float = np.deg2rad(2.0)
    p_occ: float = 0.75
    p_free: float = 0.35
    p_prior: float = 0.5
    range_limit: float = 20.0
    clamp: float = 10.0

    def __post_init__(self):
        as_scalar(self.alpha, "alpha", positive=True)
        as_scalar(self.beta, "beta", positive=True)
        for name in ("p_occ", "p_free", "p_prior"):
            p = as_scalar(getattr(self, name), name)
            if not 0.0 < p < 1.0:
                raise ValueError(f"{name} must be in (0, 1), got {p}")
        as_scalar(self.range_limit, "range_limit", positive=True, finite=False)
        as_scalar(self.clamp, "clamp", positive=True, finite=False)

    @property
    def l_occ(self):
        """``log(p_occ / (1 - p_occ))``."""
        return _logit(self.p_occ)

    @property
    def l_free(self):
        """``log(p_free / (1 - p_free))``."""
        return _logit(self.p_free)

    @property
    def l0(self):
        """Prior log odds ``l_0 = log(p_prior / (1 - p_prior))`` (Eq. 9.7)."""
        return _logit(self.p_prior)


@dataclass(frozen=True)
class GridSpec:
    """Geometry of a grid: ``origin`` (world x, y of the corner of cell (0, 0)), cell side, ``(H, W)``."""

    origin: tuple
    resolution: float
    shape: tuple

    @classmethod
    def of(cls, grid):
        """The geometry of an :class:`~slamlib.maps.OccupancyGrid`."""
        if not isinstance(grid, OccupancyGrid):
            raise TypeError(f"grid must be an OccupancyGrid, got {type(grid).__name__}")
        return cls((float(grid.origin[0]), float(grid.origin[1])), grid.resolution, grid.shape)

    @classmethod
    def covering(cls, points, resolution, margin=0.0):
        """The smallest grid of cell side `resolution` holding `points` (N, 2) plus `margin` metres."""
        pts = as_array(points, "points", (None, 2))
        if pts.shape[0] == 0:
            raise ValueError("points must hold at least one point")
        res = as_scalar(resolution, "resolution", positive=True)
        margin = as_scalar(margin, "margin", nonnegative=True)
        lo = np.floor((pts.min(axis=0) - margin) / res) * res
        hi = pts.max(axis=0) + margin
        W, H = (np.ceil((hi - lo) / res).astype(int) + 1).tolist()
        return cls((float(lo[0]), float(lo[1])), res, (H, W))


def _spec(spec):
    if isinstance(spec, OccupancyGrid):
        return GridSpec.of(spec)
    if not isinstance(spec, GridSpec):
        raise TypeError(f"spec must be a GridSpec or an OccupancyGrid, got {type(spec).__name__}")
    return spec


# --------------------------------------------------------------------------- Table 9.2, cell by cell
def inverse_range_sensor_model(cells, pose, ranges, angles, *, z_max, params=None, sensor_offset=0.0):
    """Table 9.2: the log odds a scan assigns to each cell, evaluated cell by cell.

    Parameters
    ----------
    cells : ndarray, shape (N, 2)
        World coordinates ``(x_i, y_i)`` of the cells' centres of mass.
    pose : ndarray, shape (3,)
        Robot pose ``[x, y, theta]``.
    ranges : ndarray, shape (K,)
        The scan [m].
    angles : ndarray, shape (K,)
        Beam angles ``theta_k`` relative to the heading [rad].
    z_max : float, keyword-only
        The sensor's maximum range (a reading ``>= z_max`` has no return).
    params : OccupancyParams, keyword-only
        ``alpha``, ``beta``, ``l_occ``, ``l_free``, ``l_0``.
    sensor_offset : float, keyword-only
        Distance of the sensor ahead of the robot centre [m]; ranges and
        bearings are measured from the sensor.

    Returns
    -------
    ndarray, shape (N,)
        ``l_0`` outside the perceptual field (``r > min(z_max, z_k + alpha/2)``
        or ``|phi - theta_k| > beta/2``), ``l_occ`` where ``z_k < z_max`` and
        ``|r - z_k| < alpha/2``, ``l_free`` where ``r <= z_k``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 9.2 (lines 2-11).
    """
    params = OccupancyParams() if params is None else params
    if not isinstance(params, OccupancyParams):
        raise TypeError(f"params must be an OccupancyParams, got {type(params).__name__}")
    cells = as_array(cells, "cells", (None, 2))
    pose = as_array(pose, "pose", (3,))
    ranges, angles = as_scan(ranges, angles)
    z_max = as_scalar(z_max, "z_max", positive=True, finite=False)
    off = as_scalar(sensor_offset, "sensor_offset")
    if ranges.size == 0:  # no beam: every cell is outside the perceptual field
        return np.full(cells.shape[0], params.l0)
    sx, sy = pose[0] + off * np.cos(pose[2]), pose[1] + off * np.sin(pose[2])
    r = np.hypot(cells[:, 0] - sx, cells[:, 1] - sy)  # (Table 9.2 line 2)
    phi = np.arctan2(cells[:, 1] - sy, cells[:, 0] - sx) - pose[2]  # (line 3)
    dphi = np.abs(wrap_angle(phi[:, None] - angles[None, :]))
    k = np.argmin(dphi, axis=1)  # k = argmin_j |phi - theta_j|  (line 4)
    zk, dk = ranges[k], dphi[np.arange(k.size), k]
    out = np.full(cells.shape[0], params.l0)
    outside = (r > np.minimum(z_max, zk + params.alpha / 2)) | (dk > params.beta / 2)  # (line 5)
    occ = ~outside & (zk < z_max) & (np.abs(r - zk) < params.alpha / 2)  # (line 7)
    free = ~outside & ~occ & (r <= zk)  # (line 9)
    out[occ] = params.l_occ  # (line 8)
    out[free] = params.l_free  # (line 10)
    return out


# --------------------------------------------------------------------------- beam by beam
def _crossings(s, e, axis):
    """The cell each segment s -> e (grid units) enters at each crossing of a grid line ``axis = m``.

    A segment crossing the line ``x = m`` enters column ``m`` (moving towards +x)
    or ``m - 1`` (towards -x), in the row where it meets the line. Returns
    ``(beam, row, col)`` arrays, one entry per crossing.
    """
    other = 1 - axis
    ea = e[:, axis]
    a = np.floor(np.minimum(s[axis], ea))
    n = (np.floor(np.maximum(s[axis], ea)) - a).astype(np.intp)  # lines m with floor(min) < m <= floor(max)
    total = int(n.sum())
    if total == 0:
        empty = np.empty(0, np.intp)
        return empty, empty, empty
    beam = np.repeat(np.arange(e.shape[0]), n)
    first = np.repeat(np.cumsum(n) - n, n)
    m = np.repeat(a + 1.0, n) + (np.arange(total) - first)
    d = e - s
    u = (m - s[axis]) / np.repeat(d[:, axis], n)  # where the segment meets the line
    w = np.floor(s[other] + u * np.repeat(d[:, other], n)).astype(np.intp)  # cell index along the other axis
    entered = m.astype(np.intp) - np.repeat(d[:, axis] < 0, n)  # m when moving up, m - 1 when moving down
    if axis == 0:  # x lines: the column changes, the row is w
        return beam, w, entered
    return beam, entered, w


def traverse_rays(spec, start, ends):
    """Every grid cell crossed by each segment from one start point to many end points.

    Vectorised over segments and crossings (no loop over beams or cells): a
    segment enters a new cell exactly where it crosses a grid line, and a
    segment that crosses the line ``x = m`` enters column ``m`` (or ``m - 1``
    when it runs towards -x) in the row where it meets the line. The cells
    it crosses are therefore the start cell plus one cell per crossing of a
    vertical or horizontal grid line, computed for all crossings at once:
    the cells the Amanatides-Woo walk visits. (A segment passing exactly
    through a grid corner enters the diagonal cell; the walk may list one of
    the two side cells instead.)

    Parameters
    ----------
    spec : GridSpec or OccupancyGrid
        Grid geometry.
    start : ndarray, shape (2,)
        World coordinates of the common start (the sensor).
    ends : ndarray, shape (K, 2)
        World coordinates of the end points.

    Returns
    -------
    beam : ndarray of int, shape (C,)
        Segment index of each entry.
    rc : ndarray of int, shape (C, 2)
        ``(row, col)`` of the cell; cells may repeat (within a segment and
        across segments) and may lie outside the grid.

    References
    ----------
    Amanatides & Woo (1987); Thrun, Burgard & Fox (2005), Sec. 9.2 (the cells
    in the perceptual field of a beam).
    """
    spec = _spec(spec)
    start = as_array(start, "start", (2,))
    ends = as_array(ends, "ends", (None, 2))
    beam, row, col = _traverse(spec, start, ends)
    return beam, np.column_stack([row, col])


def _traverse(spec, start, ends):
    o = np.asarray(spec.origin)
    s = (start - o) / spec.resolution  # grid units: x -> column, y -> row
    e = (ends - o) / spec.resolution
    bx, rx, cx = _crossings(s, e, 0)
    by, ry, cy = _crossings(s, e, 1)
    K = ends.shape[0]
    s_cell = np.floor(s).astype(np.intp)
    beam = np.concatenate([np.arange(K), bx, by])
    row = np.concatenate([np.full(K, s_cell[1]), rx, ry])
    col = np.concatenate([np.full(K, s_cell[0]), cx, cy])
    return beam, row, col


def scan_update_cells(spec, pose, ranges, angles, *, z_max, params=None, sensor_offset=0.0):
    """The cells one scan updates, beam by beam: the occupied and the free evidence.

    Each beam is followed from the sensor to ``z + alpha/2`` (to
    ``range_limit`` for a reading without return or longer than it). Every
    crossed cell is classified by the distance ``r`` of its centre from the
    sensor as in Table 9.2: occupied when the beam has a return and
    ``|r - z| < alpha/2``, free when ``r <= z``. A cell reached by several
    beams of the scan counts once, occupied taking precedence over free (as in
    Table 9.2, where a cell gets a single value per scan).

    Parameters
    ----------
    spec : GridSpec or OccupancyGrid
        Grid geometry.
    pose : ndarray, shape (3,)
        Robot pose.
    ranges, angles : ndarray, shape (K,)
        The scan [m] and its beam angles [rad].
    z_max : float, keyword-only
        The sensor's no-return reading.
    params : OccupancyParams, keyword-only
        Model parameters.
    sensor_offset : float, keyword-only
        Distance of the sensor ahead of the robot centre [m].

    Returns
    -------
    occupied : ndarray of int, shape (A,)
        Flat indices (``row * W + col``) of the distinct in-grid cells with occupied evidence.
    free : ndarray of int, shape (B,)
        Flat indices of the cells with free evidence (none of them in `occupied`;
        they may repeat).

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 9.2 (the classification), Table 9.1
    line 3 (the cells in the perceptual field); Amanatides & Woo (1987).
    """
    spec = _spec(spec)
    params = OccupancyParams() if params is None else params
    if not isinstance(params, OccupancyParams):
        raise TypeError(f"params must be an OccupancyParams, got {type(params).__name__}")
    pose = as_array(pose, "pose", (3,))
    ranges, angles = as_scan(ranges, angles)
    z_max = as_scalar(z_max, "z_max", positive=True, finite=False)
    off = as_scalar(sensor_offset, "sensor_offset")
    return _scan_cells(spec, pose, ranges, angles, z_max, params, off)


def _scan_cells(spec, pose, ranges, angles, z_max, params, off):
    H, W = spec.shape
    c, s = np.cos(pose[2]), np.sin(pose[2])
    sensor = np.array([pose[0] + off * c, pose[1] + off * s])
    hit = ranges < min(z_max, params.range_limit)
    z = np.where(hit, ranges, min(z_max, params.range_limit))
    reach = np.where(hit, z + params.alpha / 2, z)  # beyond z + alpha/2 a cell is outside the field (line 5)
    a = pose[2] + angles
    ends = sensor + reach[:, None] * np.column_stack([np.cos(a), np.sin(a)])
    beam, row, col = _traverse(spec, sensor, ends)
    inside = (row >= 0) & (row < H) & (col >= 0) & (col < W)
    beam, row, col = beam[inside], row[inside], col[inside]
    # r: distance of the cell's centre from the sensor  (Table 9.2 line 2)
    cx = spec.origin[0] + (col + 0.5) * spec.resolution
    cy = spec.origin[1] + (row + 0.5) * spec.resolution
    r = np.hypot(cx - sensor[0], cy - sensor[1])
    zb = z[beam]
    occ = hit[beam] & (np.abs(r - zb) < params.alpha / 2)  # (line 7)
    free = ~occ & (r <= zb)  # (line 9)
    flat = row * W + col
    occ_idx = np.unique(flat[occ])
    free_idx = flat[free]
    if occ_idx.size:
        # occupied wins: drop free entries of cells that some beam of this scan marks occupied
        mark = np.zeros(H * W, dtype=bool)
        mark[occ_idx] = True
        free_idx = free_idx[~mark[free_idx]]
    return occ_idx, free_idx


def _apply(logodds, seen, occ_idx, free_idx, params):
    """In-place log-odds update of a private buffer: ``l += l_inv - l_0`` (Table 9.1 line 4)."""
    flat = logodds.reshape(-1)
    # a[idx] += v adds once per distinct index even when idx repeats: one update per cell and scan
    flat[free_idx] += params.l_free - params.l0
    flat[occ_idx] += params.l_occ - params.l0
    if np.isfinite(params.clamp):
        flat[free_idx] = np.maximum(flat[free_idx], -params.clamp)
        flat[occ_idx] = np.minimum(flat[occ_idx], params.clamp)
    seen_flat = seen.reshape(-1)
    seen_flat[free_idx] = True
    seen_flat[occ_idx] = True


def occupancy_grid_mapping(poses, ranges, angles, *, z_max, spec=None, resolution=0.1, params=None,
                           sensor_offset=0.0, margin=2.0):
    """Occupancy grid mapping with known poses (Table 9.1) over a sequence of scans.

    Parameters
    ----------
    poses : ndarray, shape (T, 3)
        Robot pose at each scan.
    ranges : ndarray, shape (T, K)
        The scans [m]; every scan has the same number of beams.
    angles : ndarray, shape (K,)
        Beam angles [rad].
    z_max : float, keyword-only
        The sensor's no-return reading.
    spec : GridSpec or OccupancyGrid, keyword-only, optional
        The grid to fill; default the smallest grid of cell side `resolution`
        holding every pose and every end point within ``params.range_limit``
        plus `margin`.
    resolution : float, keyword-only
        Cell side [m] when `spec` is not given.
    params : OccupancyParams, keyword-only
        Inverse sensor model and log-odds parameters.
    sensor_offset : float, keyword-only
        Distance of the sensor ahead of the robot centre [m].
    margin : float, keyword-only
        Extra border [m] of the default grid.

    Returns
    -------
    grid : OccupancyGrid
        ``p(m_i | z_1:T, x_1:T) = 1 - 1 / (1 + exp(l_i))`` (Table 9.1 / Eq. 9.6),
        NaN in cells no beam reached.
    log_odds : ndarray, shape (H, W)
        The log odds ``l_i`` (``l_0`` where unseen).

    Raises
    ------
    ValueError
        On NaN in a scan, scans of different lengths, or wrong shapes.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 9.1 (the loop over cells in the
    perceptual field, here beam by beam), Table 9.2, Eqs. 9.5-9.7.
    """
    params = OccupancyParams() if params is None else params
    if not isinstance(params, OccupancyParams):
        raise TypeError(f"params must be an OccupancyParams, got {type(params).__name__}")
    poses = as_array(poses, "poses", (None, 3))
    T = poses.shape[0]
    try:
        Z = as_array(ranges, "ranges", ndim=2)
    except ValueError as exc:
        if "numeric array" in str(exc) or "inhomogeneous" in str(exc):
            raise ValueError(f"ranges must hold one scan per pose, all of the same length: {exc}") from None
        raise
    if Z.shape[0] != T:
        raise ValueError(f"ranges must hold one scan per pose: {T} poses, got ranges of shape {Z.shape}")
    angles = as_array(angles, "angles", ndim=1)
    if Z.shape[1] != angles.shape[0]:
        raise ValueError(f"ranges has {Z.shape[1]} beams per scan but angles has {angles.shape[0]}")
    if np.any(Z < 0):
        raise ValueError("ranges must be non-negative")
    z_max = as_scalar(z_max, "z_max", positive=True, finite=False)
    off = as_scalar(sensor_offset, "sensor_offset")
    if spec is None:
        if T == 0:
            raise ValueError("poses must hold at least one pose to size the map, or give spec")
        reach = min(z_max, params.range_limit)
        ends = poses[:, None, :2] + np.minimum(Z, reach)[..., None] * np.stack(
            [np.cos(poses[:, None, 2] + angles), np.sin(poses[:, None, 2] + angles)], axis=-1)
        spec = GridSpec.covering(np.vstack([poses[:, :2], ends.reshape(-1, 2)]), resolution, margin + abs(off) + 1.0)
    spec = _spec(spec)
    logodds = np.full(spec.shape, params.l0)
    seen = np.zeros(spec.shape, dtype=bool)
    for t in range(T):  # a loop over time (scans); each scan is vectorised over beams and cells
        occ_idx, free_idx = _scan_cells(spec, poses[t], Z[t], angles, z_max, params, off)
        _apply(logodds, seen, occ_idx, free_idx, params)
    return log_odds_to_grid(logodds, spec, seen=seen), logodds


def log_odds_to_grid(log_odds, spec, *, seen=None):
    """Turn log odds into an :class:`~slamlib.maps.OccupancyGrid` of probabilities.

    Parameters
    ----------
    log_odds : ndarray, shape (H, W)
        ``l_i``.
    spec : GridSpec or OccupancyGrid
        Geometry (``shape`` must be ``(H, W)``).
    seen : ndarray of bool, shape (H, W), keyword-only, optional
        Cells with at least one update; the others become NaN (unknown).
        Default: cells whose log odds differ from 0.

    Returns
    -------
    OccupancyGrid
        ``p = 1 - 1 / (1 + exp(l))``  (Table 9.1 / Eq. 9.6).

    References
    ----------
    Thrun, Burgard & Fox (2005), Eq. 9.6 (recovering the probability from
    the log odds).
    """
    spec = _spec(spec)
    lo = as_array(log_odds, "log_odds", spec.shape)
    seen = lo != 0 if seen is None else np.asarray(seen, dtype=bool)
    if seen.shape != lo.shape:
        raise ValueError(f"seen must have shape {lo.shape}, got {seen.shape}")
    p = 1.0 - 1.0 / (1.0 + np.exp(lo))  # (Eq. 9.6)
    p = np.where(seen, p, np.nan)
    return OccupancyGrid(occupancy=p, resolution=spec.resolution, origin=np.asarray(spec.origin, dtype=float))


def classify_occupancy(grid, *, free=0.4, occupied=0.6):
    """Free / occupied / unknown classification of a grid's cells.

    Parameters
    ----------
    grid : OccupancyGrid
        The map.
    free : float, keyword-only
        Cells with occupancy ``<= free`` are free (the default 0.4 takes one
        free observation with ``p_free = 0.35`` as enough).
    occupied : float, keyword-only
        Cells with occupancy ``>= occupied`` are occupied.

    Returns
    -------
    ndarray of int8, shape (H, W)
        ``FREE`` (0), ``OCCUPIED`` (1), or ``UNKNOWN`` (-1: never seen, or in
        between the thresholds).

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 9.2 (maps thresholded for display and
    planning).
    """
    if not isinstance(grid, OccupancyGrid):
        raise TypeError(f"grid must be an OccupancyGrid, got {type(grid).__name__}")
    free = as_scalar(free, "free")
    occupied = as_scalar(occupied, "occupied")
    if not free < occupied:
        raise ValueError(f"free ({free}) must be below occupied ({occupied})")
    out = np.full(grid.shape, UNKNOWN, dtype=np.int8)
    out[grid.free_mask(free)] = FREE
    out[grid.occupied_mask(occupied)] = OCCUPIED
    return out


# --------------------------------------------------------------------------- scoring against a reference map
@dataclass(frozen=True)
class MapAgreement:
    """Agreement of a map with a reference map (see :func:`map_agreement`).

    Attributes
    ----------
    occupied : float
        Share of the map's occupied cells within `tolerance` of an occupied
        reference cell (are the walls where the reference has walls?).
    free : float
        Share of the map's free cells within `tolerance` of a free reference
        cell (is the free space free in the reference?).
    score : float
        ``(occupied + free) / 2``.
    n_occupied, n_free : int
        Cells of the map compared (those that fall on known reference cells).
    """

    occupied: float
    free: float
    score: float
    n_occupied: int
    n_free: int


def map_agreement(grid, reference, *, transform=None, tolerance=0.15, free=0.4, occupied=0.6, ref_free=0.2,
                  ref_occupied=0.65):
    """Agreement of the free and occupied cells of a map with a reference map.

    The centres of the map's classified cells are moved into the reference
    frame by the rigid `transform` ``(R, t)`` (``x_ref = R x + t``), looked up
    in the reference, and counted as agreeing when a reference cell of the
    same class lies within `tolerance` (a cell's width of slack, because walls
    drawn in two grids rarely fall in the same cells). Cells falling outside
    the reference, or on reference cells that are neither free nor occupied
    (unknown, or between the thresholds), are not counted.

    Parameters
    ----------
    grid : OccupancyGrid
        The map to score.
    reference : OccupancyGrid
        The reference map.
    transform : tuple (R (2, 2), t (2,)), keyword-only, optional
        Rigid transform from the map's frame to the reference's (default identity).
    tolerance : float, keyword-only
        Slack [m].
    free, occupied : float, keyword-only
        Thresholds classifying the map (:func:`classify_occupancy`).
    ref_free, ref_occupied : float, keyword-only
        Thresholds classifying the reference.

    Returns
    -------
    MapAgreement

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 9.2 (occupancy grid maps); the map is
    moved with the transform fitted on the trajectory, as in
    :func:`~slamlib.scoring.score_run`.
    """
    if not isinstance(grid, OccupancyGrid):
        raise TypeError(f"grid must be an OccupancyGrid, got {type(grid).__name__}")
    if not isinstance(reference, OccupancyGrid):
        raise TypeError(f"reference must be an OccupancyGrid, got {type(reference).__name__}")
    if transform is None:
        R, t = np.eye(2), np.zeros(2)
    else:
        R = as_array(transform[0], "transform[0]", (2, 2))
        t = as_array(transform[1], "transform[1]", (2,))
    tol = as_scalar(tolerance, "tolerance", nonnegative=True)
    cls = classify_occupancy(grid, free=free, occupied=occupied)
    ref_cls = classify_occupancy(reference, free=ref_free, occupied=ref_occupied)
    known = ref_cls != UNKNOWN  # unseen or ambiguous reference cells say nothing either way
    px = tol / reference.resolution
    # distance [cells] from every reference cell to the nearest reference cell of each class
    d_occ = ndimage.distance_transform_edt(ref_cls != OCCUPIED)
    d_free = ndimage.distance_transform_edt(ref_cls != FREE)
    out = []
    for code, dist in ((OCCUPIED, d_occ), (FREE, d_free)):
        rc = np.argwhere(cls == code)
        xy = grid.cell_to_world(rc).reshape(-1, 2) @ R.T + t
        ref_rc = reference.world_to_cell(xy)
        ok = reference.in_bounds(ref_rc)
        ref_rc = ref_rc[ok]
        ok2 = known[ref_rc[:, 0], ref_rc[:, 1]]
        ref_rc = ref_rc[ok2]
        n = ref_rc.shape[0]
        agree = float(np.mean(dist[ref_rc[:, 0], ref_rc[:, 1]] <= px)) if n else float("nan")
        out.append((agree, n))
    (occ_a, n_occ), (free_a, n_free) = out
    return MapAgreement(occupied=occ_a, free=free_a, score=0.5 * (occ_a + free_a), n_occupied=n_occ, n_free=n_free)
