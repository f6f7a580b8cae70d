"""Tests of slamlib.viz._scan: the scan-matching and mapping plots draw with Agg and return their axes."""

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import slamlib as sl  # noqa: E402


@pytest.fixture
def ax():
    fig, ax = plt.subplots()
    yield ax
    plt.close(fig)


def _scans():
    t = np.linspace(0.0, 1.0, 40)
    target = np.r_[np.c_[t * 4, np.full(40, 1.0)], np.c_[t * 4, np.full(40, -1.0)], np.c_[np.full(40, 4.0), t * 2 - 1]]
    truth = np.array([0.2, 0.1, 0.05])
    c, s = np.cos(truth[2]), np.sin(truth[2])
    source = (target - truth[:2]) @ np.array([[c, -s], [s, c]])  # target seen from the pose `truth`
    return source, target, truth


def test_icp_convergence_plot_has_one_line_per_run(ax):
    source, target, truth = _scans()
    runs = {m: sl.icp(source, target, method=m, max_dist=1.0, trim=1.0) for m in ("point_to_line", "point_to_point")}
    assert sl.viz.plot_icp_convergence(runs, truth, ax=ax) is ax
    assert len(ax.lines) == 2
    # each line has one point per round, starting from the initial guess
    assert [len(line.get_xdata()) for line in ax.lines] == [r.iterations + 1 for r in runs.values()]


def test_animate_icp_renders_html_with_at_most_max_frames():
    source, target, truth = _scans()
    res = sl.icp(source, target, max_dist=1.0, trim=1.0)
    html = sl.viz.animate_icp(source, target, res, truth=truth, max_frames=3, dpi=20, figsize=(2, 2)).data
    assert "<script" in html and html.count("data:image/png;base64") <= 3


def test_map_overlay_moves_the_cells(ax):
    ref = sl.OccupancyGrid(np.zeros((20, 20)), 0.1)
    occ = np.full((10, 10), np.nan)
    occ[5, 5] = 1.0
    grid = sl.OccupancyGrid(occ, 0.1)
    assert sl.viz.plot_map_overlay(grid, ref, (np.eye(2), np.array([1.0, 0.5])), ax=ax) is ax
    xy = ax.collections[-1].get_offsets()
    np.testing.assert_allclose(xy, [[1.55, 1.05]])
