"""Tests of slamlib.maps: grid geometry, free space, sampling, landmark worlds."""

import numpy as np
import pytest
from scipy import stats

import slamlib as sl


def grid():
    occ = np.zeros((4, 6))
    occ[0, :] = 1.0  # bottom row (smallest y) occupied
    occ[2, 3] = np.nan  # one unknown cell
    occ[3, 5] = 0.6
    return sl.OccupancyGrid(occ, 0.5, origin=np.array([-1.0, 2.0]))


def test_axis_convention_and_roundtrip():
    g = grid()
    assert g.shape == (4, 6)
    assert g.extent == (-1.0, 2.0, 2.0, 4.0)
    # a point just right of and above the origin is cell (0, 0); x moves columns, y moves rows
    np.testing.assert_array_equal(g.world_to_cell([-0.99, 2.01]), [0, 0])
    np.testing.assert_array_equal(g.world_to_cell([0.6, 2.01]), [0, 3])
    np.testing.assert_array_equal(g.world_to_cell([-0.99, 3.6]), [3, 0])
    np.testing.assert_allclose(g.cell_to_world([3, 0]), [-0.75, 3.75])
    rc = np.argwhere(np.ones(g.shape, bool))
    np.testing.assert_array_equal(g.world_to_cell(g.cell_to_world(rc)), rc)
    assert g.world_to_cell(np.zeros((2, 5, 2))).dtype.kind == "i"
    np.testing.assert_array_equal(g.in_bounds(np.array([[0, 0], [-1, 0], [3, 5], [4, 0], [0, 6]])),
                                  [True, False, True, False, False])


def test_free_space_queries():
    g = grid()
    assert g.is_free([[0.0, 2.9]]).tolist() == [True]
    assert g.is_free(np.array([[0.0, 2.2], [0.6, 3.2], [1.9, 3.9], [50.0, 0.0]])).tolist() == [False, False, False, False]
    free = g.free_cells()
    assert free.shape == (6 * 4 - 6 - 1 - 1, 2)
    assert np.all(g.is_free(free))
    assert g.occupied_mask().sum() == 7 and g.occupied_mask(unknown_occupied=True).sum() == 8


def test_grid_is_immutable_copy():
    occ = np.zeros((3, 3))
    g = sl.OccupancyGrid(occ, 1.0)
    occ[0, 0] = 1.0
    assert g.occupancy[0, 0] == 0.0
    with pytest.raises(ValueError):
        g.occupancy[0, 0] = 1.0
    with pytest.raises(AttributeError):
        g.resolution = 2.0


@pytest.mark.parametrize("kw, name", [
    (dict(occupancy=np.zeros(3), resolution=1.0), "occupancy"),
    (dict(occupancy=np.full((2, 2), 1.5), resolution=1.0), "occupancy"),
    (dict(occupancy=np.zeros((2, 2)), resolution=0.0), "resolution"),
    (dict(occupancy=np.zeros((2, 2)), resolution=1.0, origin=[0.0]), "origin"),
])
def test_bad_grids(kw, name):
    with pytest.raises((ValueError, TypeError), match=name):
        sl.OccupancyGrid(**kw)


def test_sample_free_poses_uniform_over_free_space():
    occ = np.ones((10, 10))
    occ[2:5, 1:9] = 0.0  # a 0.8 x 0.3 m free strip (cells of 0.1 m)
    g = sl.OccupancyGrid(occ, 0.1)
    X = sl.sample_free_poses(g, 20000, rng=np.random.default_rng(0))
    assert X.shape == (20000, 3)
    assert np.all(g.is_free(X[:, :2]))
    assert stats.kstest((X[:, 0] - 0.1) / 0.8, "uniform").pvalue > 0.01
    assert stats.kstest((X[:, 1] - 0.2) / 0.3, "uniform").pvalue > 0.01
    assert stats.kstest((X[:, 2] + np.pi) / (2 * np.pi), "uniform").pvalue > 0.01
    with pytest.raises(TypeError, match="rng"):
        sl.sample_free_poses(g, 3, rng=None)
    with pytest.raises(ValueError, match="free"):
        sl.sample_free_poses(sl.OccupancyGrid(np.ones((2, 2)), 1.0), 3, rng=np.random.default_rng(0))


def test_make_landmark_world():
    lm = sl.make_landmark_world(25, extent=10.0, min_separation=1.2, rng=np.random.default_rng(1))
    assert lm.shape == (25, 2)
    assert np.all(np.abs(lm) <= 5.0)
    d = np.linalg.norm(lm[:, None] - lm[None], axis=-1) + np.eye(25) * 99
    assert d.min() >= 1.2
    a = sl.make_landmark_world(5, rng=np.random.default_rng(2))
    np.testing.assert_array_equal(a, sl.make_landmark_world(5, rng=np.random.default_rng(2)))
    with pytest.raises(ValueError, match="could not place"):
        sl.make_landmark_world(50, extent=2.0, min_separation=1.0, rng=np.random.default_rng(0), max_tries=500)
    with pytest.raises(ValueError, match="extent"):
        sl.make_landmark_world(5, extent=-1.0, rng=np.random.default_rng(0))
