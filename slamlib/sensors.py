"""Measurement models: range-bearing landmarks and range finders.

* Landmarks: ``z = [r, phi]`` with ``r = |m - (x, y)|`` and
  ``phi = wrap(atan2(m_y - y, m_x - x) - theta)``, its Jacobians and inverse.
* Range finders on an :class:`~slamlib.maps.OccupancyGrid`: the beam model
  (mixture of hit, short, max and random), ray casting, and the likelihood
  field.

Every function broadcasts over leading axes; bearings are wrapped to
``[-pi, pi)``.

References
----------
Thrun, Burgard & Fox, *Probabilistic Robotics* (2005), Sec. 6.3 (Table 6.1,
Eqs. 6.4-6.10), Sec. 6.4 (Table 6.3), Sec. 6.6 (Eq. 6.40), Table 7.2
lines 12-14 (range-bearing prediction and Jacobian), Table 10.1 line 10 (inverse).
"""

from __future__ import annotations

from dataclasses import dataclass, field as _field

import math

import numpy as np
from scipy import ndimage
from scipy.special import ndtr

from ._checks import as_array, as_index, as_poses, as_scalar, as_vector, check_batch, check_type
from .angles import _wrap, _wrap1
from .maps import OccupancyGrid

__all__ = [
    "landmark_measurement",
    "landmark_from_measurement",
    "beam_range_finder_model",
    "beam_range_finder_log_likelihood",
    "ray_cast",
    "RangeTable",
    "range_table",
    "LikelihoodField",
    "likelihood_field",
    "likelihood_field_log_likelihood",
]

#: Ranges below this (metres) make the landmark Jacobians undefined.
MIN_RANGE = 1e-12
_LOG_2PI = float(np.log(2.0 * np.pi))


# --------------------------------------------------------------------------- landmarks
def landmark_measurement(x, m):
    """Expected range-bearing measurement of a landmark and its Jacobians.

    Parameters
    ----------
    x : ndarray, shape (3,) or (..., 3)
        Pose(s) ``[x, y, theta]``.
    m : ndarray, shape (2,) or (..., 2)
        Landmark position(s) ``[m_x, m_y]``; broadcasts against `x`.

    Returns
    -------
    z_hat : ndarray, shape (..., 2)
        ``[r, phi]``, ``r = sqrt(q)``, ``q = dx^2 + dy^2``,
        ``phi = wrap(atan2(dy, dx) - theta)``.
    Hx : ndarray, shape (..., 2, 3)
        ``d z_hat / d x = [[-dx/r, -dy/r, 0], [dy/q, -dx/q, -1]]``.
    Hm : ndarray, shape (..., 2, 2)
        ``d z_hat / d m = [[dx/r, dy/r], [-dy/q, dx/q]]``.

    Raises
    ------
    ValueError
        If a landmark lies on a pose (range below ``1e-12``), where the
        bearing and the Jacobians are undefined.

    References
    ----------
    Thrun, Burgard & Fox (2005), Eq. 6.40 and Table 7.2 lines 11-13.
    """
    x = as_poses(x, "x", batched=True)
    m = as_vector(m, "m", 2)
    check_batch((x, 1, "x"), (m, 1, "m"))
    return _landmark_measurement(x, m)


def _landmark_measurement(x, m):
    """Unchecked core of :func:`landmark_measurement` for broadcasting ``x (..., 3)``, ``m (..., 2)``."""
    shape = np.broadcast_shapes(x.shape[:-1], m.shape[:-1])
    dx = m[..., 0] - x[..., 0]
    dy = m[..., 1] - x[..., 1]
    q = dx**2 + dy**2
    r = np.sqrt(q)
    if np.any(r < MIN_RANGE):
        raise ValueError("m coincides with the pose x (range 0): bearing and Jacobians are undefined")
    z_hat = np.empty(shape + (2,))
    # z_hat = [sqrt(q), atan2(dy, dx) - theta]  (Eq. 6.40, Table 7.2 lines 11-12)
    z_hat[..., 0] = r
    z_hat[..., 1] = _wrap(np.arctan2(dy, dx) - x[..., 2])
    # H = d h / d x  (Table 7.2 line 13)
    Hx = np.zeros(shape + (2, 3))
    Hx[..., 0, 0] = -dx / r
    Hx[..., 0, 1] = -dy / r
    Hx[..., 1, 0] = dy / q
    Hx[..., 1, 1] = -dx / q
    Hx[..., 1, 2] = -1.0
    Hm = np.empty(shape + (2, 2))
    Hm[..., 0, 0] = dx / r
    Hm[..., 0, 1] = dy / r
    Hm[..., 1, 0] = -dy / q
    Hm[..., 1, 1] = dx / q
    return z_hat, Hx, Hm


def _rbh1(x, y, th, mx, my):
    """Range-bearing model of one pose and one landmark with Python floats: the scalar path of
    :func:`landmark_measurement`.

    Returns ``r_hat``, ``phi_hat`` (floats) and ``h = [Hx Hm]``, shape ``(2, 5)``
    (the tests check it against ``landmark_measurement``).
    """
    r, phi, dx, dy, q = _rb1(x, y, th, mx, my)
    # h_t^j = 1/q [[-r dx, -r dy, 0, r dx, r dy], [dy, -dx, -q, -dy, dx]]  (Eq. 17.3)
    h = np.array([[-dx / r, -dy / r, 0.0, dx / r, dy / r], [dy / q, -dx / q, -1.0, -dy / q, dx / q]])
    return r, phi, h


def _rb1(x, y, th, mx, my):
    """Range-bearing model of one pose ``(x, y, th)`` and one landmark ``(mx, my)`` in Python floats.

    Returns ``r_hat, phi_hat, dx, dy, q`` (``q = dx^2 + dy^2``, bearing
    wrapped), from which the callers build their Jacobians.
    """
    dx, dy = float(mx) - float(x), float(my) - float(y)
    q = dx * dx + dy * dy  # q = delta^T delta  (Algorithm 1 line 13)
    r = math.sqrt(q)
    if r < MIN_RANGE:
        raise ValueError("m coincides with the pose x (range 0): bearing and Jacobians are undefined")
    # z_hat = [sqrt(q), atan2(dy, dx) - theta]  (Eq. 6.40, Eq. 17.2)
    return r, _wrap1(math.atan2(dy, dx) - float(th)), dx, dy, q


def landmark_from_measurement(x, z):
    """Landmark position implied by a range-bearing measurement.

    Parameters
    ----------
    x : ndarray, shape (3,) or (..., 3)
        Pose(s) ``[x, y, theta]``.
    z : ndarray, shape (2,) or (..., 2)
        Measurement(s) ``[r, phi]``; broadcasts against `x`.

    Returns
    -------
    m : ndarray, shape (..., 2)
        ``[x + r cos(theta + phi), y + r sin(theta + phi)]``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 10.1 line 10 (inverse of Eq. 6.40).
    """
    x = as_poses(x, "x", batched=True)
    z = as_vector(z, "z", 2)
    shape = check_batch((x, 1, "x"), (z, 1, "z"))
    ang = x[..., 2] + z[..., 1]
    m = np.empty(shape + (2,))
    # mu_j = (x + r cos(phi + theta), y + r sin(phi + theta))  (Table 10.1 line 10)
    m[..., 0] = x[..., 0] + z[..., 0] * np.cos(ang)
    m[..., 1] = x[..., 1] + z[..., 0] * np.sin(ang)
    return m


# --------------------------------------------------------------------------- beam model
def _beam_params(z_max, sigma_hit, lambda_short, w_hit, w_short, w_max, w_rand):
    z_max = as_scalar(z_max, "z_max", positive=True)
    sigma_hit = as_scalar(sigma_hit, "sigma_hit", positive=True)
    lambda_short = as_scalar(lambda_short, "lambda_short", positive=True)
    ws = [as_scalar(w, n, nonnegative=True) for w, n in
          ((w_hit, "w_hit"), (w_short, "w_short"), (w_max, "w_max"), (w_rand, "w_rand"))]
    return z_max, sigma_hit, lambda_short, ws


def _beam_mixture(z, z_star, z_max, sigma, lam, ws):
    w_hit, w_short, w_max, w_rand = ws
    inside = z <= z_max
    # p_hit: N(z; z*, sigma^2) renormalised on [0, z_max]  (Eqs. 6.4-6.6)
    eta = ndtr((z_max - z_star) / sigma) - ndtr(-z_star / sigma)
    p_hit = np.where(inside, np.exp(-0.5 * ((z - z_star) / sigma) ** 2) / (np.sqrt(2 * np.pi) * sigma) / eta, 0.0)
    # p_short: lambda e^{-lambda z} / (1 - e^{-lambda z*}) on [0, z*]  (Eqs. 6.7-6.8)
    norm = -np.expm1(-lam * z_star)
    pos = z_star > 0
    p_short = np.where(pos & (z <= z_star), lam * np.exp(-lam * z) / np.where(pos, norm, 1.0), 0.0)
    # p_max: point mass at z >= z_max  (Eq. 6.9); p_rand: 1 / z_max on [0, z_max)  (Eq. 6.10)
    p_max = (z >= z_max).astype(float)
    p_rand = np.where(z < z_max, 1.0 / z_max, 0.0)
    # p = w_hit p_hit + w_short p_short + w_max p_max + w_rand p_rand  (Table 6.1 line 5)
    return w_hit * p_hit + w_short * p_short + w_max * p_max + w_rand * p_rand


def _beam_inputs(z, z_star, z_max):
    z = as_array(z, "z", ndim=range(0, 33))
    z_star = as_array(z_star, "z_star", ndim=range(0, 33))
    try:
        np.broadcast_shapes(z.shape, z_star.shape)
    except ValueError:
        raise ValueError(f"z {z.shape} and z_star {z_star.shape} do not broadcast") from None
    if np.any(z < 0):
        raise ValueError("z must be non-negative ranges")
    if np.any(z_star < 0) or np.any(z_star > z_max):
        raise ValueError(f"z_star must lie in [0, z_max] = [0, {z_max}]")
    return z, z_star


def beam_range_finder_model(z, z_star, *, z_max, sigma_hit, lambda_short, w_hit, w_short, w_max, w_rand):
    """Per-beam likelihood of the beam model of range finders.

    Parameters
    ----------
    z : ndarray, shape (K,) or (..., K)
        Measured ranges, non-negative.
    z_star : ndarray, shape (K,) or (..., K)
        Expected ranges (e.g. from :func:`ray_cast`), in ``[0, z_max]``;
        broadcasts against `z`.
    z_max : float
        Maximum range of the sensor.
    sigma_hit : float
        Standard deviation of the hit component.
    lambda_short : float
        Rate of the exponential short component.
    w_hit, w_short, w_max, w_rand : float
        Non-negative mixture weights, used as given (not renormalised).

    Returns
    -------
    ndarray, shape (..., K)
        ``w_hit p_hit + w_short p_short + w_max p_max + w_rand p_rand`` with
        ``p_hit`` the normal ``N(z; z_star, sigma_hit^2)`` truncated and
        renormalised to ``[0, z_max]``; ``p_short = lambda e^{-lambda z} /
        (1 - e^{-lambda z_star})`` on ``[0, z_star]`` (0 when ``z_star = 0``);
        ``p_max = 1`` for ``z >= z_max``; ``p_rand = 1 / z_max`` on
        ``[0, z_max)``. With weights summing to 1 it is a density on
        ``[0, z_max)`` plus a point mass ``w_max`` at ``z_max``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 6.1, Eqs. 6.4-6.10.
    """
    z_max, sigma, lam, ws = _beam_params(z_max, sigma_hit, lambda_short, w_hit, w_short, w_max, w_rand)
    z, z_star = _beam_inputs(z, z_star, z_max)
    return _beam_mixture(z, z_star, z_max, sigma, lam, ws)


def beam_range_finder_log_likelihood(z, z_star, *, z_max, sigma_hit, lambda_short, w_hit, w_short, w_max, w_rand):
    """Log-likelihood of a whole scan under the beam model.

    Parameters
    ----------
    z : ndarray, shape (K,) or (..., K)
        Measured ranges of one scan.
    z_star : ndarray, shape (K,) or (..., K)
        Expected ranges, e.g. ``(P, K)`` from :func:`ray_cast` for ``P``
        particles; broadcasts against `z`.
    z_max, sigma_hit, lambda_short, w_hit, w_short, w_max, w_rand : float
        As in :func:`beam_range_finder_model`.

    Returns
    -------
    ndarray, shape (...)
        ``sum_k log p(z_k | z_star_k)`` over the last axis (``-inf`` where a
        beam has zero likelihood).

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 6.1 lines 2-7 (product in log space).
    """
    p = beam_range_finder_model(z, z_star, z_max=z_max, sigma_hit=sigma_hit, lambda_short=lambda_short,
                                w_hit=w_hit, w_short=w_short, w_max=w_max, w_rand=w_rand)
    if p.ndim == 0:
        raise ValueError("z must have at least one axis (the beams)")
    with np.errstate(divide="ignore"):
        # q = prod_k p  (Table 6.1 line 6), in log space
        return np.sum(np.log(p), axis=-1)


# --------------------------------------------------------------------------- ray casting
def ray_cast(grid, poses, angles, max_range, *, sensor_offset=0.0, threshold=0.5, unknown_occupied=False,
             range_bias=0.0):
    """Expected ranges of beams cast from poses through an occupancy grid.

    All rays are traversed together, cell by cell (a vectorised
    Amanatides-Woo DDA over the grid): a ray stops on entering the first
    occupied cell, and its range is the exact distance to that cell's face.

    Parameters
    ----------
    grid : OccupancyGrid
        The map. A cell is occupied when its occupancy is ``>= threshold``;
        unknown (NaN) cells are free unless `unknown_occupied`; the world
        outside the grid is free.
    poses : ndarray, shape (P, 3) or (3,)
        Robot poses ``[x, y, theta]``.
    angles : ndarray, shape (K,)
        Beam angles relative to the heading (counter-clockwise positive).
    max_range : float
        Range returned by a beam that hits nothing within it (may be ``inf``
        on a map closed by walls).
    sensor_offset : float, keyword-only
        Distance (metres) of the sensor ahead of the robot centre along the
        heading; ranges are measured from the sensor.
    threshold : float, keyword-only
        Occupancy from which a cell blocks beams.
    unknown_occupied : bool, keyword-only
        Treat unknown cells as occupied.
    range_bias : float, keyword-only
        Added to every range below `max_range` (the result clipped to
        ``[0, max_range]``): how much further the sensor sees the walls than
        the faces of the map's occupied cells (``MCLParams.range_bias``).

    Returns
    -------
    ranges : ndarray, shape (P, K) or (K,)
        ``min(distance to the first occupied cell, max_range)``; 0 for a
        sensor inside an occupied cell; plus `range_bias` where below
        `max_range`.

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 6.3.1 (``z_k^*`` computed by ray
    casting, Table 6.1 line 4).
    """
    grid = check_type(grid, OccupancyGrid, "grid")
    single = np.ndim(poses) == 1
    poses = np.atleast_2d(as_poses(poses, "poses", ndim=(1, 2)))
    angles = as_array(angles, "angles", ndim=1)
    max_range = as_scalar(max_range, "max_range", positive=True, finite=False)
    if np.isnan(max_range):
        raise ValueError("max_range must be positive, got nan")
    sensor_offset = as_scalar(sensor_offset, "sensor_offset")
    threshold = as_scalar(threshold, "threshold")
    range_bias = as_scalar(range_bias, "range_bias")
    occ = grid.occupied_mask(threshold, unknown_occupied=unknown_occupied)
    out = _biased_ranges(_dda(occ, grid.resolution, grid.origin, poses, angles, max_range, sensor_offset),
                        range_bias, max_range)
    return out[0] if single else out


def _biased_ranges(ranges, range_bias, max_range):
    """Cast ranges moved `range_bias` further where below `max_range`, clipped to ``[0, max_range]``.

    The expected range of the beam model when the map's occupied cells begin
    in front of the surfaces the sensor sees (``MCLParams.range_bias``); the
    ranges of :func:`ray_cast` and of a :class:`RangeTable` (unchecked).
    """
    if not range_bias:
        return ranges
    return np.where(ranges < max_range, np.clip(ranges + range_bias, 0.0, max_range), ranges)


def _dda(occ, res, origin, poses, angles, max_range, offset):
    H, W = occ.shape
    P, K = poses.shape[0], angles.shape[0]
    th = poses[:, 2]
    sx = poses[:, 0] + offset * np.cos(th)
    sy = poses[:, 1] + offset * np.sin(th)
    ang = (th[:, None] + angles[None, :]).ravel()
    dx, dy = np.cos(ang), np.sin(ang)
    gx = np.repeat((sx - origin[0]) / res, K)  # continuous column coordinate
    gy = np.repeat((sy - origin[1]) / res, K)  # continuous row coordinate
    col = np.floor(gx).astype(np.int64)
    row = np.floor(gy).astype(np.int64)
    step_c = np.where(dx > 0, 1, -1)
    step_r = np.where(dy > 0, 1, -1)
    nzx, nzy = dx != 0, dy != 0
    inv_x = 1.0 / np.where(nzx, np.abs(dx), 1.0)
    inv_y = 1.0 / np.where(nzy, np.abs(dy), 1.0)
    # distance (metres) along the ray to the next column / row boundary, and between boundaries
    bx = np.where(dx > 0, col + 1 - gx, gx - col)
    by = np.where(dy > 0, row + 1 - gy, gy - row)
    t_x = np.where(nzx, bx * res * inv_x, np.inf)
    t_y = np.where(nzy, by * res * inv_y, np.inf)
    d_x = np.where(nzx, res * inv_x, np.inf)
    d_y = np.where(nzy, res * inv_y, np.inf)

    out = np.full(P * K, max_range)
    inb = (row >= 0) & (row < H) & (col >= 0) & (col < W)
    start_hit = np.zeros(P * K, dtype=bool)
    start_hit[inb] = occ[row[inb], col[inb]]
    out[start_hit] = 0.0
    idx = np.flatnonzero(~start_hit)
    state = [a[idx] for a in (row, col, t_x, t_y, d_x, d_y, step_r, step_c)]
    row, col, t_x, t_y, d_x, d_y, step_r, step_c = state
    while idx.size:
        go_x = t_x < t_y
        t = np.where(go_x, t_x, t_y)
        col = np.where(go_x, col + step_c, col)
        row = np.where(go_x, row, row + step_r)
        t_x = np.where(go_x, t_x + d_x, t_x)
        t_y = np.where(go_x, t_y, t_y + d_y)
        inb = (row >= 0) & (row < H) & (col >= 0) & (col < W)
        hit = np.zeros(idx.size, dtype=bool)
        hit[inb] = occ[row[inb], col[inb]]
        hit &= t < max_range
        out[idx[hit]] = t[hit]
        # a ray outside the grid and heading away from it can never come back
        gone = ((col < 0) & (step_c < 0)) | ((col >= W) & (step_c > 0)) | ((row < 0) & (step_r < 0)) | ((row >= H) & (step_r > 0))
        done = hit | gone | (t >= max_range)
        keep = ~done
        idx = idx[keep]
        row, col, t_x, t_y, d_x, d_y, step_r, step_c = (
            a[keep] for a in (row, col, t_x, t_y, d_x, d_y, step_r, step_c))
    return out.reshape(P, K)


# --------------------------------------------------------------------------- pre-cached ray casting
@dataclass(frozen=True, eq=False)
class RangeTable:
    """Ray casting pre-cached per grid cell and beam direction.

    The expected range ``z^*`` of a beam depends on the sensor's position and
    the beam's direction in the world only, so it can be kept in a table
    indexed by the cell holding the sensor and the direction rounded to one of
    ``n_angles`` bins (Thrun et al., Sec. 6.3.4). Entries are cast the first
    time they are asked for (from the cell's centre at the bin's direction,
    with :func:`ray_cast`'s exact traversal) and kept, so a filter pays for
    each place and direction once; the values do not depend on the order in
    which they were asked for. Build it with :func:`range_table`.

    Attributes
    ----------
    grid : OccupancyGrid
        The map.
    threshold : float
        Occupancy from which a cell blocks beams.
    max_range : float
        Range of a beam that hits nothing.
    n_angles : int
        Direction bins over the full circle.
    index : ndarray of int, shape (H, W)
        Row of `table` for each cell of the table's region, ``-1`` elsewhere
        (beams from there are cast exactly, every time).
    cells : ndarray of int, shape (cells, 2)
        ``(row, col)`` of each row of `table`.
    table : ndarray of float16, shape (cells, n_angles)
        Cached ranges (half precision: within 0.03 m below 64 m, 0.06 m
        beyond); NaN where not yet cast.
    occ : ndarray of bool, shape (H, W)
        The cells that block beams.
    """

    grid: OccupancyGrid
    threshold: float
    max_range: float
    n_angles: int
    index: np.ndarray
    cells: np.ndarray
    table: np.ndarray
    occ: np.ndarray

    def ranges(self, poses, angles, *, sensor_offset=0.0):
        """Expected ranges of beams from poses, read from (and filling) the table.

        Parameters
        ----------
        poses : ndarray, shape (P, 3)
            Robot poses ``[x, y, theta]``.
        angles : ndarray, shape (K,)
            Beam angles relative to the heading.
        sensor_offset : float, keyword-only
            Distance of the sensor ahead of the robot centre [m].

        Returns
        -------
        ndarray, shape (P, K)
            The range cast from the centre of the cell holding each sensor
            along the beam direction rounded to the table's bins; the exact
            :func:`ray_cast` for sensors outside the table's region.

        References
        ----------
        Thrun, Burgard & Fox (2005), Sec. 6.3.4 (pre-caching the ray
        casting).
        """
        poses = np.atleast_2d(as_poses(poses, "poses", ndim=(1, 2)))
        angles = as_array(angles, "angles", ndim=1)
        sensor_offset = as_scalar(sensor_offset, "sensor_offset")
        g = self.grid
        th = poses[:, 2]
        sxy = np.column_stack([poses[:, 0] + sensor_offset * np.cos(th), poses[:, 1] + sensor_offset * np.sin(th)])
        rc = g.world_to_cell(sxy)
        inb = g.in_bounds(rc)
        row = np.full(poses.shape[0], -1, dtype=np.int64)
        row[inb] = self.index[rc[inb, 0], rc[inb, 1]]
        cached = row >= 0
        out = np.empty((poses.shape[0], angles.shape[0]))
        if np.any(~cached):
            out[~cached] = _dda(self.occ, g.resolution, g.origin, poses[~cached], angles, self.max_range,
                                sensor_offset)
        if np.any(cached):
            n = self.n_angles
            b = np.rint((th[cached, None] + angles[None, :]) * (n / (2.0 * np.pi))).astype(np.int64) % n
            flat = self.table.reshape(-1)
            lin = row[cached, None] * n + b
            vals = flat[lin]
            miss = np.isnan(vals)
            if miss.any():
                todo = np.unique(lin[miss])
                cells = self.cells[todo // n]
                centre = g.cell_to_world(cells)
                src = np.column_stack([centre, (todo % n) * (2.0 * np.pi / n)])
                flat[todo] = _dda(self.occ, g.resolution, g.origin, src, np.zeros(1), self.max_range, 0.0)[:, 0]
                vals = flat[lin]
            # a beam that hit nothing is stored as max_range's half-precision neighbour: give back max_range
            # (np.where with a float16 array would round it back to the neighbour)
            top = vals >= self.table.dtype.type(self.max_range)
            vals = vals.astype(np.float64)
            vals[top] = self.max_range
            out[cached] = vals
        return out


def range_table(grid, *, max_range, threshold=0.5, n_angles=360, region=None):
    """An empty :class:`RangeTable` for a grid (entries are cast on first use).

    Parameters
    ----------
    grid : OccupancyGrid
        The map.
    max_range : float, keyword-only
        Range of a beam that hits nothing.
    threshold : float, keyword-only
        Occupancy from which a cell blocks beams.
    n_angles : int, keyword-only
        Direction bins over the full circle (360: one degree; at 5 m a beam
        is then at most 0.044 m to the side of the direction it stands for).
    region : ndarray of bool, shape (H, W), optional
        Cells whose beams are cached (default: the known cells that do not
        block beams). Memory is ``2 n_angles`` bytes per cell of the region.

    Returns
    -------
    RangeTable

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 6.3.4.
    """
    grid = check_type(grid, OccupancyGrid, "grid")
    max_range = as_scalar(max_range, "max_range", positive=True)
    threshold = as_scalar(threshold, "threshold")
    n_angles = as_index(n_angles, "n_angles", lower=1)
    occ = grid.occupied_mask(threshold)
    if region is None:
        region = ~occ & ~np.isnan(grid.occupancy)
    else:
        region = np.asarray(region)
        if region.dtype != bool or region.shape != grid.shape:
            raise ValueError(f"region must be a boolean array of shape {grid.shape}, got "
                             f"{region.dtype} {region.shape}")
    cells = np.argwhere(region)
    index = np.full(grid.shape, -1, dtype=np.int64)
    index[cells[:, 0], cells[:, 1]] = np.arange(cells.shape[0])
    for a in (index, cells, occ):
        a.setflags(write=False)
    table = np.full((cells.shape[0], n_angles), np.nan, dtype=np.float16)
    return RangeTable(grid=grid, threshold=threshold, max_range=max_range, n_angles=n_angles, index=index,
                      cells=cells, table=table, occ=occ)


# --------------------------------------------------------------------------- likelihood field
@dataclass(frozen=True, eq=False)
class LikelihoodField:
    """Distance to the nearest obstacle for every cell of a grid.

    Attributes
    ----------
    grid : OccupancyGrid
        The map the field was computed from.
    dist : ndarray, shape (H, W)
        Distance (metres) from each cell centre to the nearest occupied cell
        centre, clipped at `max_dist`; ``inf`` in unknown cells (their
        endpoints get only the random term).
    max_dist : float
        Clipping distance.

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 6.4, Table 6.3 line 7 and Fig. 6.8.
    """

    grid: OccupancyGrid
    dist: np.ndarray
    max_dist: float
    #: Tables over the cells, flattened, one entry appended for "outside the grid" (OccupancyGrid._flat_cells):
    #: the distances, and each beam's log-likelihood term per (sigma_hit, w_hit, w_rand, z_max).
    _tables: dict = _field(default_factory=dict, init=False, repr=False, compare=False)

    def distance_at(self, xy):
        """Distance to the nearest obstacle at world points.

        Parameters
        ----------
        xy : ndarray, shape (..., 2)
            World points.

        Returns
        -------
        ndarray, shape (...,)
            Distance (metres) stored for the cell holding each point; ``inf``
            outside the grid and in unknown cells.

        References
        ----------
        Thrun, Burgard & Fox (2005), Table 6.3 line 7.
        """
        xy = as_vector(xy, "xy", 2)
        return self._lookup(xy)

    def _lookup(self, xy):
        return self._table(None)[self.grid._flat_cells(xy[..., 0], xy[..., 1])]

    def _table(self, key):
        """The distances (``key`` None) or the beam terms ``key = (sigma, w_hit, w_rand, z_max)`` of every cell."""
        table = self._tables.get(key)
        if table is None:
            if key is None:
                table = np.append(self.dist.ravel(), np.inf)  # outside the grid: as an unknown cell
            else:
                table = _field_beam_log_likelihood(self._table(None), *key)
                if len(self._tables) >= 8:
                    self._tables.clear()
            table.setflags(write=False)
            self._tables[key] = table
        return table


def likelihood_field(grid, *, max_dist=2.0, threshold=0.5):
    """Precompute the likelihood field (obstacle distance map) of a grid.

    Parameters
    ----------
    grid : OccupancyGrid
        The map; cells with occupancy ``>= threshold`` are the obstacles.
    max_dist : float, keyword-only
        Distances are clipped at this value (metres).
    threshold : float, keyword-only
        Occupancy from which a cell counts as an obstacle.

    Returns
    -------
    LikelihoodField
        Distances computed once with ``scipy.ndimage.distance_transform_edt``
        (in metres, between cell centres). Unknown cells are not obstacles
        and hold ``inf``: an endpoint there, or outside the grid, scores only
        ``w_rand / z_max`` (Thrun et al., Sec. 6.4).

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 6.4 (Table 6.3 line 7, Fig. 6.8).
    """
    grid = check_type(grid, OccupancyGrid, "grid")
    max_dist = as_scalar(max_dist, "max_dist", positive=True, finite=False)
    threshold = as_scalar(threshold, "threshold")
    occ = grid.occupied_mask(threshold)
    if occ.any():
        dist = ndimage.distance_transform_edt(~occ, sampling=grid.resolution)
    else:
        dist = np.full(occ.shape, np.inf)
    dist = np.minimum(dist, max_dist)
    dist[np.isnan(grid.occupancy)] = np.inf
    dist.setflags(write=False)
    return LikelihoodField(grid=grid, dist=dist, max_dist=max_dist)


def _field_beam_log_likelihood(dist, sigma, w_hit, w_rand, z_max):
    """One beam's term of the likelihood field at obstacle distance ``dist`` (unchecked)."""
    # q = q * (z_hit prob(dist, sigma_hit) + z_random / z_max)  (Table 6.3 line 8)
    p = w_hit * np.exp(-0.5 * (dist / sigma) ** 2) / (np.sqrt(2 * np.pi) * sigma) + w_rand / z_max
    with np.errstate(divide="ignore"):
        return np.log(p)


def likelihood_field_log_likelihood(field, poses, ranges, angles, *, z_max, sigma_hit, w_hit, w_rand, sensor_offset=0.0,
                                    per_beam=False):
    """Log-likelihood of a scan under the likelihood-field model, per pose.

    Parameters
    ----------
    field : LikelihoodField
        From :func:`likelihood_field` (the distance transform is done once
        there; here each endpoint costs one table look-up).
    poses : ndarray, shape (P, 3) or (3,)
        Robot poses.
    ranges : ndarray, shape (K,)
        Measured ranges; beams with ``ranges >= z_max`` are skipped.
    angles : ndarray, shape (K,)
        Beam angles relative to the heading.
    z_max, sigma_hit : float
        Maximum range and standard deviation of the hit term.
    w_hit, w_rand : float
        Non-negative mixture weights.
    sensor_offset : float, keyword-only
        Sensor position ahead of the robot centre (metres).
    per_beam : bool, keyword-only
        Return every beam's term instead of their sum: shape ``(P, K)`` (or
        ``(K,)`` for one pose), 0 for the max-range beams.

    Returns
    -------
    ndarray, shape (P,) or ()
        ``sum_k log(w_hit prob(dist_k, sigma_hit^2) + w_rand / z_max)`` over the
        non-max beams, where ``dist_k`` is the obstacle distance at the beam's
        endpoint and ``prob`` a zero-mean normal density.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 6.3.
    """
    check_type(field, LikelihoodField, "field")
    single = np.ndim(poses) == 1
    poses = np.atleast_2d(as_poses(poses, "poses", ndim=(1, 2)))
    ranges = as_array(ranges, "ranges", ndim=1)
    angles = as_array(angles, "angles", ranges.shape, ref="ranges")
    if np.any(ranges < 0):
        raise ValueError("ranges must be non-negative")
    z_max = as_scalar(z_max, "z_max", positive=True)
    sigma = as_scalar(sigma_hit, "sigma_hit", positive=True)
    w_hit = as_scalar(w_hit, "w_hit", nonnegative=True)
    w_rand = as_scalar(w_rand, "w_rand", nonnegative=True)
    sensor_offset = as_scalar(sensor_offset, "sensor_offset")
    if not isinstance(per_beam, (bool, np.bool_)):
        raise TypeError(f"per_beam must be a bool, got {type(per_beam).__name__}")
    use = ranges < z_max  # (Table 6.3 line 4: skip max-range readings)
    r, a = ranges[use], angles[use]
    th = poses[:, 2:3]
    # endpoint x_zk = x + x_sens cos(theta) + z_k cos(theta + theta_sens)  (Table 6.3 lines 5-6)
    ex = poses[:, 0:1] + sensor_offset * np.cos(th) + r * np.cos(th + a)
    ey = poses[:, 1:2] + sensor_offset * np.sin(th) + r * np.sin(th + a)
    # log(z_hit prob(dist, sigma_hit) + z_random / z_max) at each endpoint's cell  (Table 6.3 lines 7-8),
    # computed once per cell of the map (LikelihoodField._table)
    terms = field._table((sigma, w_hit, w_rand, z_max))[field.grid._flat_cells(ex, ey)]
    if per_beam:
        out = np.zeros((poses.shape[0], ranges.size))
        out[:, use] = terms
    else:
        out = np.sum(terms, axis=-1)
    return out[0] if single else out
