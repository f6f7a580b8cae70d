"""Tests of slamlib.mapping: Table 9.2, the vectorised ray traversal, log-odds mapping, map agreement."""

import numpy as np
import pytest

import slamlib as sl
from slamlib import mapping as mp

P = mp.OccupancyParams(alpha=0.2, beta=np.deg2rad(2.0), p_occ=0.75, p_free=0.35)


# --------------------------------------------------------------------------- Table 9.2 by hand
def test_inverse_sensor_model_table_9_2_hand_cases():
    pose = np.array([1.0, 2.0, np.pi / 2])  # facing +y
    angles = np.deg2rad([-10.0, 0.0, 10.0])
    ranges = np.array([3.0, 2.0, 5.0])  # the middle beam (straight ahead, +y) hits at 2 m; z_max = 5
    ahead = lambda r: [1.0, 2.0 + r]  # noqa: E731
    cells = np.array([
        ahead(1.0),  # on the middle beam before the hit: free (line 9-10)
        ahead(2.05),  # |r - z| = 0.05 < alpha/2: occupied (lines 7-8)
        ahead(1.95),  # just before the hit, within alpha/2: occupied
        ahead(2.2),  # r = 2.2 > z + alpha/2 = 2.1: outside the field, l0 (line 5)
        [1.0 + 3.0 * np.sin(np.deg2rad(10)), 2.0 + 3.0 * np.cos(np.deg2rad(10))],  # on the right beam at its hit
        [1.0 + 0.5, 2.0 + 1.0],  # bearing 26.6 deg from the heading: no beam within beta/2, l0
        [1.0 - 4.0 * np.sin(np.deg2rad(10)), 2.0 + 4.0 * np.cos(np.deg2rad(10))],  # max-range beam at 4 m: free
        [1.0 - 5.0 * np.sin(np.deg2rad(10)), 2.0 + 5.0 * np.cos(np.deg2rad(10))],  # at z_max: z_k < z_max fails, free
        [1.0 - 5.2 * np.sin(np.deg2rad(10)), 2.0 + 5.2 * np.cos(np.deg2rad(10))],  # beyond z_max: l0
        [1.0, 1.0],  # behind the robot: l0
    ])
    got = sl.inverse_range_sensor_model(cells, pose, ranges, angles, z_max=5.0, params=P)
    lo, lf, l0 = P.l_occ, P.l_free, P.l0
    np.testing.assert_allclose(got, [lf, lo, lo, l0, lo, l0, lf, lf, l0, l0])
    assert lo == pytest.approx(np.log(3.0)) and lf == pytest.approx(np.log(0.35 / 0.65)) and l0 == 0.0


def test_inverse_sensor_model_sensor_offset_moves_the_origin():
    cells = np.array([[2.0, 0.0], [2.25, 0.0]])
    # laser 0.25 m ahead: a 2 m reading ends at x = 2.25; the cell at x = 2 is 1.75 m from the laser
    got = sl.inverse_range_sensor_model(cells, [0.0, 0.0, 0.0], [2.0], [0.0], z_max=10.0, params=P,
                                        sensor_offset=0.25)
    np.testing.assert_allclose(got, [P.l_free, P.l_occ])
    got = sl.inverse_range_sensor_model(cells, [0.0, 0.0, 0.0], [2.0], [0.0], z_max=10.0, params=P)
    np.testing.assert_allclose(got, [P.l_occ, P.l0])


# --------------------------------------------------------------------------- the ray traversal
def _walk(s, e):
    """Amanatides-Woo, one beam at a time, in grid units: the cells (row, col) the segment s -> e visits."""
    cell = np.floor(s).astype(int)
    end = np.floor(e).astype(int)
    d = e - s
    step = np.sign(d).astype(int)
    t_max = np.empty(2)
    t_delta = np.empty(2)
    for ax in range(2):
        if d[ax] == 0:
            t_max[ax] = t_delta[ax] = np.inf
        else:
            nxt = cell[ax] + (step[ax] > 0)
            t_max[ax] = (nxt - s[ax]) / d[ax]
            t_delta[ax] = abs(1.0 / d[ax])
    cells = [(cell[1], cell[0])]
    while not np.array_equal(cell, end):
        ax = 0 if t_max[0] < t_max[1] else 1
        cell[ax] += step[ax]
        t_max[ax] += t_delta[ax]
        cells.append((cell[1], cell[0]))
        assert len(cells) < 10_000
    return set(cells)


def test_vectorised_traversal_equals_the_per_beam_walk():
    rng = np.random.default_rng(0)
    spec = mp.GridSpec((-1.0, -2.0), 0.1, (40, 30))
    start = np.array([0.43, -0.77])
    ends = start + rng.uniform(-2.5, 2.5, size=(60, 2))
    ends[:4] = start + [[0.0, 1.234], [-1.777, 0.0], [0.02, 0.03], [0.0, -0.001]]  # axis-parallel, short, in-cell
    beam, rc = sl.traverse_rays(spec, start, ends)
    for k in range(ends.shape[0]):
        s = (start - spec.origin) / spec.resolution
        e = (ends[k] - spec.origin) / spec.resolution
        got = set(map(tuple, rc[beam == k]))
        assert got == _walk(s, e), k
        # and the vectorised path lists each cell once per beam (no duplicates but the start cell)
        assert np.count_nonzero(beam == k) == len(got)


def test_scan_update_cells_agree_with_table_9_2():
    """The beam-by-beam update gives the cells Table 9.2 marks occupied, and free cells Table 9.2 calls free."""
    from test_scan_matching import ANGLES as angles, ROOM, _cast

    spec = mp.GridSpec((-6.0, -6.0), 0.1, (120, 120))
    pose = np.array([0.3, -0.2, 0.4])
    ranges = _cast(pose, ROOM, angles, max_range=8.0)
    ranges[::17] = 8.0  # no return
    occ, free = sl.scan_update_cells(spec, pose, ranges, angles, z_max=8.0, params=P)
    assert np.intersect1d(occ, free).size == 0 and np.unique(occ).size == occ.size
    H, W = spec.shape
    centres = lambda idx: np.column_stack([spec.origin[0] + (idx % W + 0.5) * 0.1,  # noqa: E731
                                           spec.origin[1] + (idx // W + 0.5) * 0.1])
    table_occ = sl.inverse_range_sensor_model(centres(occ), pose, ranges, angles, z_max=8.0, params=P)
    table_free = sl.inverse_range_sensor_model(centres(np.unique(free)), pose, ranges, angles, z_max=8.0, params=P)
    # Table 9.2 takes the beam nearest in bearing; the walk the beam crossing the cell: they differ only at
    # the edges of beams whose neighbours are much shorter
    assert np.mean(table_occ == P.l_occ) > 0.8, np.mean(table_occ == P.l_occ)
    assert np.mean(table_free == P.l_free) > 0.9, np.mean(table_free == P.l_free)
    assert np.mean(table_free == P.l_occ) < 0.05


def test_one_scan_updates_each_cell_once():
    spec = mp.GridSpec((-3.0, -3.0), 0.1, (60, 60))
    angles = np.linspace(-0.3, 0.3, 61)  # 61 beams all crossing the cells next to the sensor
    grid, lo = sl.occupancy_grid_mapping(np.zeros((1, 3)), np.full((1, 61), 2.0), angles, z_max=10.0, spec=spec,
                                         params=P)
    vals = np.unique(np.round(lo[~np.isnan(grid.occupancy)], 12))
    np.testing.assert_allclose(np.sort(vals), np.sort([P.l_free - P.l0, P.l_occ - P.l0]))
    sensor_cell = (30, 30)
    assert lo[sensor_cell] == pytest.approx(P.l_free)
    # two identical scans: the evidence adds up (Table 9.1 line 4)
    _, lo2 = sl.occupancy_grid_mapping(np.zeros((2, 3)), np.full((2, 61), 2.0), angles, z_max=10.0, spec=spec,
                                       params=P)
    assert lo2[sensor_cell] == pytest.approx(2 * P.l_free)


def test_mapping_a_room_with_known_poses():
    """A square room scanned from a few known poses: walls occupied, the inside free, the outside unknown."""
    from test_scan_matching import ANGLES, _box, _cast

    room = _box(-2.0, -1.5, 3.0, 2.5)
    poses = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 2.0], [-1.0, 0.5, -2.5], [2.0, -0.5, 1.6]])
    ranges = np.array([_cast(p + [0.25 * np.cos(p[2]), 0.25 * np.sin(p[2]), 0.0], room, ANGLES) for p in poses])
    grid, _ = sl.occupancy_grid_mapping(poses, ranges, ANGLES, z_max=30.0, resolution=0.05, sensor_offset=0.25)
    cls = sl.classify_occupancy(grid)
    inside = grid.world_to_cell(np.array([[0.5, 0.5], [-1.5, -1.0], [2.5, 2.0], [0.0, 2.2]]))
    assert np.all(cls[inside[:, 0], inside[:, 1]] == sl.FREE)
    walls = grid.world_to_cell(np.array([[0.5, 2.5 + 0.02], [-2.0 - 0.02, 0.0], [3.0 + 0.02, 1.0], [1.0, -1.5 - 0.02]]))
    assert np.all(cls[walls[:, 0], walls[:, 1]] == sl.OCCUPIED)
    outside = grid.world_to_cell(np.array([[0.5, 3.5], [4.0, 0.0]]))
    ok = grid.in_bounds(outside)
    assert np.all(cls[outside[ok, 0], outside[ok, 1]] == sl.UNKNOWN)
    # the map agrees with a rasterised copy of the room
    truth = np.full(grid.shape, 0.0)
    occ = np.zeros(grid.shape, bool)
    xy = grid.cell_to_world(np.argwhere(np.ones(grid.shape, bool))).reshape(grid.shape + (2,))
    on_wall = lambda v, w: np.abs(v - w) < 0.05  # noqa: E731
    occ |= (on_wall(xy[..., 0], -2.0) | on_wall(xy[..., 0], 3.0)) & (xy[..., 1] > -1.6) & (xy[..., 1] < 2.6)
    occ |= (on_wall(xy[..., 1], -1.5) | on_wall(xy[..., 1], 2.5)) & (xy[..., 0] > -2.1) & (xy[..., 0] < 3.1)
    truth[occ] = 1.0
    outside_room = (xy[..., 0] < -2.1) | (xy[..., 0] > 3.1) | (xy[..., 1] < -1.6) | (xy[..., 1] > 2.6)
    truth[outside_room] = np.nan
    score = sl.map_agreement(grid, sl.OccupancyGrid(truth, grid.resolution, grid.origin), tolerance=0.1)
    assert score.occupied > 0.95 and score.free > 0.97, score
    # a map shifted by 0.3 m in x and y agrees much less
    shifted = sl.map_agreement(grid, sl.OccupancyGrid(truth, grid.resolution, grid.origin + [0.3, 0.3]),
                               tolerance=0.1)
    assert shifted.occupied < 0.5, shifted


def test_log_odds_to_grid_and_classification():
    spec = mp.GridSpec((0.0, 0.0), 1.0, (1, 4))
    g = sl.log_odds_to_grid(np.array([[0.0, np.log(4.0), -np.log(4.0), 0.0]]), spec,
                            seen=np.array([[False, True, True, True]]))
    np.testing.assert_allclose(g.occupancy, [[np.nan, 0.8, 0.2, 0.5]])
    np.testing.assert_array_equal(sl.classify_occupancy(g), [[sl.UNKNOWN, sl.OCCUPIED, sl.FREE, sl.UNKNOWN]])


def test_mapping_bad_input():
    angles = np.linspace(-1, 1, 5)
    with pytest.raises(ValueError, match="ranges must be finite"):
        sl.occupancy_grid_mapping(np.zeros((2, 3)), [[1.0, 2, 3, 4, 5], [1.0, np.nan, 3, 4, 5]], angles, z_max=10.0)
    with pytest.raises(ValueError, match="same length"):
        sl.occupancy_grid_mapping(np.zeros((2, 3)), [[1.0, 2, 3, 4, 5], [1.0, 2, 3, 4]], angles, z_max=10.0)
    with pytest.raises(ValueError, match="beams per scan but angles has"):
        sl.occupancy_grid_mapping(np.zeros((1, 3)), [[1.0, 2, 3, 4]], angles, z_max=10.0)
    with pytest.raises(ValueError, match="one scan per pose"):
        sl.occupancy_grid_mapping(np.zeros((3, 3)), np.ones((2, 5)), angles, z_max=10.0)
    with pytest.raises(ValueError, match=r"ranges \(4,\) and angles \(5,\)"):
        sl.scan_update_cells(mp.GridSpec((0.0, 0.0), 0.1, (10, 10)), np.zeros(3), np.ones(4), angles, z_max=10.0)
    with pytest.raises(ValueError, match="ranges must be finite"):
        sl.inverse_range_sensor_model(np.zeros((1, 2)), np.zeros(3), [np.nan] * 5, angles, z_max=10.0)
    with pytest.raises(ValueError, match="p_occ"):
        mp.OccupancyParams(p_occ=1.0)
