"""Maps: occupancy grids and landmark worlds.

Axis convention of :class:`OccupancyGrid` (used by every grid function):
the world frame has x to the right and y up; ``occupancy[row, col]`` is the
cell whose **row is the y index and column the x index**, cell ``(0, 0)``
being the one with the smallest x and y. Cell ``(r, c)`` covers
``[ox + c res, ox + (c+1) res) x [oy + r res, oy + (r+1) res)`` with
``origin = (ox, oy)``. Draw it with ``imshow(occupancy, origin="lower",
extent=grid.extent)``.

References
----------
Thrun, Burgard & Fox, *Probabilistic Robotics* (2005), Sec. 6.2 (maps),
Sec. 9.1-9.2 (occupancy grids).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._checks import as_array, as_index, as_scalar, check_rng, check_type

__all__ = ["OccupancyGrid", "sample_free_poses", "make_landmark_world"]


def _as_points(xy):
    """World points ``(..., 2)`` (checked: numeric, finite)."""
    xy = as_array(xy, "xy", ndim=range(1, 33))
    if xy.shape[-1] != 2:
        raise ValueError(f"xy must have shape (..., 2), got {xy.shape}")
    return xy


@dataclass(frozen=True, eq=False)
class OccupancyGrid:
    """A 2-D occupancy grid map.

    Parameters
    ----------
    occupancy : ndarray, shape (H, W)
        Probability that each cell is occupied, in ``[0, 1]``; NaN marks an
        unknown cell. Stored as a read-only float64 copy.
    resolution : float
        Side of a cell in metres.
    origin : ndarray, shape (2,)
        World ``(x, y)`` of the outer corner of cell ``(0, 0)`` (smallest x
        and y); default ``(0, 0)``.

    Notes
    -----
    Row = y index, column = x index; x to the right, y up (module docstring).

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 9.1 (occupancy grid maps, Eq. 9.1).
    """

    occupancy: np.ndarray
    resolution: float
    origin: np.ndarray = None

    def __post_init__(self):
        occ = as_array(self.occupancy, "occupancy", ndim=2, finite=False)
        if occ.size == 0:
            raise ValueError("occupancy must not be empty")
        if np.any(np.isinf(occ)):
            raise ValueError("occupancy must be in [0, 1] or NaN (unknown), found inf")
        known = occ[~np.isnan(occ)]
        if np.any((known < 0) | (known > 1)):
            raise ValueError("occupancy must be in [0, 1] or NaN (unknown)")
        occ.setflags(write=False)
        res = as_scalar(self.resolution, "resolution", positive=True)
        origin = np.zeros(2) if self.origin is None else as_array(self.origin, "origin", (2,))
        origin.setflags(write=False)
        object.__setattr__(self, "occupancy", occ)
        object.__setattr__(self, "resolution", res)
        object.__setattr__(self, "origin", origin)
        object.__setattr__(self, "_free_tables", {})  # threshold -> free_mask, flat, False appended (_flat_cells)

    # ------------------------------------------------------------------ geometry
    @property
    def shape(self):
        """``(H, W)``: number of rows (y) and columns (x)."""
        return self.occupancy.shape

    @property
    def extent(self):
        """``(left, right, bottom, top)`` in metres, for ``imshow(..., origin="lower")``."""
        H, W = self.shape
        ox, oy = self.origin
        return (float(ox), float(ox + W * self.resolution), float(oy), float(oy + H * self.resolution))

    def world_to_cell(self, xy):
        """Cell indices of world points.

        Parameters
        ----------
        xy : ndarray, shape (..., 2)
            World points ``(x, y)``.

        Returns
        -------
        ndarray of int64, shape (..., 2)
            ``(row, col) = (floor((y - oy) / res), floor((x - ox) / res))``;
            may lie outside the grid (see :meth:`in_bounds`).

        References
        ----------
        Thrun, Burgard & Fox (2005), Sec. 9.1 (grid cells ``m_i``).
        """
        xy = _as_points(xy)
        row, col = self._cell_floats(xy[..., 0], xy[..., 1])
        return np.stack([row, col], axis=-1).astype(np.int64)

    def _cell_floats(self, x, y):
        """``(row, col)`` of :meth:`world_to_cell` as floats, for unchecked arrays ``x``, ``y`` of one shape."""
        return np.floor((y - self.origin[1]) / self.resolution), np.floor((x - self.origin[0]) / self.resolution)

    def _flat_cells(self, x, y):
        """Flat indices ``row * W + col`` of the cells of :meth:`world_to_cell` holding the world points
        ``(x, y)`` (arrays of one shape, unchecked), ``H * W`` outside the grid: indices into a table of the
        cells, flattened, with one entry appended for "outside"."""
        H, W = self.shape
        row, col = self._cell_floats(x, y)
        ok = (row >= 0.0) & (row < H) & (col >= 0.0) & (col < W)
        return np.where(ok, row * W + col, H * W).astype(np.intp)

    def cell_to_world(self, rc):
        """World coordinates of cell centres.

        Parameters
        ----------
        rc : ndarray, shape (..., 2)
            Cell indices ``(row, col)``.

        Returns
        -------
        ndarray, shape (..., 2)
            ``(x, y) = (ox + (col + 1/2) res, oy + (row + 1/2) res)``.

        References
        ----------
        Thrun, Burgard & Fox (2005), Sec. 9.1 (grid cells ``m_i``).
        """
        rc = as_array(rc, "rc", ndim=range(1, 33))
        if rc.shape[-1] != 2:
            raise ValueError(f"rc must have shape (..., 2), got {rc.shape}")
        x = self.origin[0] + (rc[..., 1] + 0.5) * self.resolution
        y = self.origin[1] + (rc[..., 0] + 0.5) * self.resolution
        return np.stack([x, y], axis=-1)

    def in_bounds(self, rc):
        """Whether cells lie in the grid.

        Parameters
        ----------
        rc : ndarray of int, shape (..., 2)
            Cell indices ``(row, col)``.

        Returns
        -------
        ndarray of bool, shape (...,)
            ``0 <= row < H and 0 <= col < W``.

        References
        ----------
        Thrun, Burgard & Fox (2005), Sec. 9.1 (grid cells ``m_i``).
        """
        rc = np.asarray(rc)
        if rc.ndim < 1 or rc.shape[-1] != 2:
            raise ValueError(f"rc must have shape (..., 2), got {rc.shape}")
        H, W = self.shape
        return (rc[..., 0] >= 0) & (rc[..., 0] < H) & (rc[..., 1] >= 0) & (rc[..., 1] < W)

    # ------------------------------------------------------------------ occupancy
    def occupied_mask(self, threshold=0.5, *, unknown_occupied=False):
        """Cells that block beams.

        Parameters
        ----------
        threshold : float
            Smallest occupancy probability counted as occupied.
        unknown_occupied : bool, keyword-only
            Count unknown (NaN) cells as occupied.

        Returns
        -------
        ndarray of bool, shape (H, W)
            ``occupancy >= threshold`` (plus unknown cells if asked).

        References
        ----------
        Thrun, Burgard & Fox (2005), Sec. 9.1 (grid cells ``m_i``).
        """
        threshold = as_scalar(threshold, "threshold")
        occ = self.occupancy
        with np.errstate(invalid="ignore"):
            mask = occ >= threshold
        if unknown_occupied:
            mask |= np.isnan(occ)
        return mask

    def free_mask(self, threshold=0.2):
        """Known cells that count as free.

        Parameters
        ----------
        threshold : float
            Largest occupancy probability counted as free.

        Returns
        -------
        ndarray of bool, shape (H, W)
            ``occupancy <= threshold``; False in unknown cells.

        References
        ----------
        Thrun, Burgard & Fox (2005), Sec. 9.1 (grid cells ``m_i``).
        """
        threshold = as_scalar(threshold, "threshold")
        occ = self.occupancy
        with np.errstate(invalid="ignore"):
            return occ <= threshold

    def is_free(self, xy, threshold=0.2):
        """Whether world points lie in known cells with occupancy ``<= threshold``.

        Parameters
        ----------
        xy : ndarray, shape (..., 2)
            World points.
        threshold : float
            Largest occupancy probability counted as free.

        Returns
        -------
        ndarray of bool, shape (...,)
            False outside the grid and in unknown cells.

        References
        ----------
        Thrun, Burgard & Fox (2005), Sec. 9.1 (grid cells ``m_i``).
        """
        xy = _as_points(xy)
        threshold = as_scalar(threshold, "threshold")
        table = self._free_tables.get(threshold)
        if table is None:
            table = np.append(self.free_mask(threshold).ravel(), False)
            if len(self._free_tables) >= 8:
                self._free_tables.clear()
            self._free_tables[threshold] = table
        return table[self._flat_cells(xy[..., 0], xy[..., 1])]

    def free_cells(self, threshold=0.2):
        """Centres of the free cells.

        Parameters
        ----------
        threshold : float
            Largest occupancy probability counted as free.

        Returns
        -------
        ndarray, shape (F, 2)
            World ``(x, y)`` of every cell with occupancy ``<= threshold``.

        References
        ----------
        Thrun, Burgard & Fox (2005), Sec. 9.1 (grid cells ``m_i``).
        """
        rc = np.argwhere(self.free_mask(threshold))
        return self.cell_to_world(rc).reshape(-1, 2)


def sample_free_poses(grid, n, *, rng, threshold=0.2):
    """Poses drawn uniformly over the free space of a grid.

    Parameters
    ----------
    grid : OccupancyGrid
        The map.
    n : int
        Number of poses.
    rng : numpy.random.Generator
        Draws, in order: ``integers(F, size=n)`` (free cell), ``uniform(size=(n, 2))``
        (position within the cell), ``uniform(-pi, pi, size=n)`` (heading).
    threshold : float, keyword-only
        Largest occupancy counted as free.

    Returns
    -------
    ndarray, shape (n, 3)
        Positions uniform over the union of free cells, headings uniform on
        ``[-pi, pi)``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 8.2 (MCL initialisation for global
    localization: particles uniform over the free space).
    """
    check_type(grid, OccupancyGrid, "grid")
    n = as_index(n, "n")
    check_rng(rng)
    rc = np.argwhere(grid.free_mask(threshold))
    if rc.shape[0] == 0:
        raise ValueError("grid has no free cell to sample from")
    pick = rc[rng.integers(rc.shape[0], size=n)]
    frac = rng.uniform(size=(n, 2))
    out = np.empty((n, 3))
    out[:, 0] = grid.origin[0] + (pick[:, 1] + frac[:, 0]) * grid.resolution
    out[:, 1] = grid.origin[1] + (pick[:, 0] + frac[:, 1]) * grid.resolution
    out[:, 2] = rng.uniform(-np.pi, np.pi, size=n)
    return out


def make_landmark_world(n, *, extent=10.0, min_separation=1.0, rng, max_tries=10000):
    """Random point landmarks in a square, at least `min_separation` apart.

    Parameters
    ----------
    n : int
        Number of landmarks.
    extent : float, keyword-only
        Side of the square ``[-extent/2, extent/2]^2`` (metres), centred on
        the origin.
    min_separation : float, keyword-only
        Smallest distance between two landmarks.
    rng : numpy.random.Generator
        Landmarks are placed one after another by rejection, each candidate
        drawn with ``uniform(-extent/2, extent/2, size=2)``.
    max_tries : int, keyword-only
        Candidates allowed in total before giving up.

    Returns
    -------
    ndarray, shape (n, 2)
        Landmark positions.

    Raises
    ------
    ValueError
        If `n` landmarks cannot be placed (square too small for the separation).

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 6.2 (feature-based maps
    ``m = {m_1, ..., m_N}``).
    """
    n = as_index(n, "n")
    extent = as_scalar(extent, "extent", positive=True)
    min_separation = as_scalar(min_separation, "min_separation", nonnegative=True)
    max_tries = as_index(max_tries, "max_tries", lower=1)
    check_rng(rng)
    pts = np.empty((n, 2))
    k = tries = 0
    while k < n:
        if tries >= max_tries:
            raise ValueError(
                f"could not place n={n} landmarks {min_separation} apart in a square of extent {extent}"
                f" (placed {k} in {max_tries} tries)")
        cand = rng.uniform(-extent / 2, extent / 2, size=2)
        tries += 1
        if k == 0 or np.min(np.hypot(*(pts[:k] - cand).T)) >= min_separation:
            pts[k] = cand
            k += 1
    return pts
