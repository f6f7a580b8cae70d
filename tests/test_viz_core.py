"""Tests of slamlib.viz._core: every helper draws with Agg and returns its axes."""

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import slamlib as sl  # noqa: E402
from slamlib.viz import _core as viz  # noqa: E402


@pytest.fixture
def ax():
    fig, ax = plt.subplots()
    yield ax
    plt.close(fig)


def test_plot_pose_and_trajectory(ax):
    assert viz.plot_pose(np.array([1.0, 2.0, 0.5]), ax=ax, color="k") is ax
    assert len(ax.patches) == 1
    tri = ax.patches[0].get_xy()
    # the tip points along the heading
    tip = tri[0]
    np.testing.assert_allclose(np.arctan2(tip[1] - 2.0, tip[0] - 1.0), 0.5, atol=1e-12)
    xs = np.c_[np.linspace(0, 1, 5), np.zeros(5), np.zeros(5)]
    assert viz.plot_trajectory(xs, ax=ax, label="path") is ax
    assert len(ax.lines) == 1
    with pytest.raises(ValueError, match="xs"):
        viz.plot_trajectory(np.zeros(4), ax=ax)


def test_plot_covariance_ellipse_axes(ax):
    cov = np.array([[4.0, 0.0], [0.0, 1.0]])
    assert viz.plot_covariance_ellipse(np.array([1.0, 1.0]), cov, n_sigma=2.0, ax=ax) is ax
    e = ax.patches[-1]
    assert {round(e.width, 12), round(e.height, 12)} == {8.0, 4.0}
    viz.plot_covariance_ellipse(np.zeros(2), cov, ax=ax, n_std=3.0, ls=":")
    assert max(ax.patches[-1].width, ax.patches[-1].height) == pytest.approx(12.0)
    with pytest.raises(ValueError, match="cov"):
        viz.plot_covariance_ellipse(np.zeros(2), -np.eye(2), ax=ax)


def test_plot_particles_landmarks_grid(ax):
    rng = np.random.default_rng(0)
    P = rng.normal(size=(50, 3))
    assert viz.plot_particles(P, ax=ax) is ax
    assert viz.plot_particles(P, weights=rng.uniform(size=50), ax=ax, arrows=True, color="C2") is ax
    with pytest.raises(ValueError, match="weights"):
        viz.plot_particles(P, weights=np.ones(3), ax=ax)
    assert viz.plot_landmarks(rng.normal(size=(4, 2)), ax=ax, labels=True) is ax
    assert len(ax.texts) == 4
    occ = np.zeros((5, 8))
    occ[0] = 1.0
    occ[2, 2] = np.nan
    g = sl.OccupancyGrid(occ, 0.5, origin=np.array([1.0, -1.0]))
    assert viz.plot_grid(g, ax=ax) is ax
    assert tuple(ax.images[-1].get_extent()) == g.extent
    with pytest.raises(TypeError, match="grid"):
        viz.plot_grid(occ, ax=ax)


def test_ax_none_means_a_new_figure():
    fig, ax = plt.subplots()
    grid = sl.OccupancyGrid(np.zeros((4, 5)), 0.5)
    calls = [
        lambda: viz.plot_pose(np.zeros(3)),
        lambda: viz.plot_trajectory(np.zeros((3, 3))),
        lambda: viz.plot_covariance_ellipse(np.zeros(2), np.eye(2)),
        lambda: viz.plot_particles(np.zeros((5, 3))),
        lambda: viz.plot_landmarks(np.zeros((2, 2))),
        lambda: viz.plot_grid(grid),
        lambda: sl.viz.plot_mcl_particles(grid, np.zeros((5, 3))),
        lambda: sl.viz.plot_scan_endpoints(np.zeros(3), np.ones(3), np.zeros(3)),
        lambda: sl.viz.plot_position_error(np.arange(3.0), {"a": np.ones(3)}),
    ]
    try:
        for call in calls:
            out = call()
            assert out is not ax and out.figure is not fig  # never drawn on the current axes
            plt.close(out.figure)
    finally:
        plt.close("all")


def test_one_truth_colour():
    from slamlib.viz import _bayes, _core, _fastslam, _filters, _real_data, _slam

    for mod in (_bayes, _fastslam, _filters, _real_data, _slam):
        assert mod.TRUTH_COLOR is _core.TRUTH_COLOR
        assert not any(name in vars(mod) for name in ("_TRUE_COLOR", "_TRUTH"))
        assert "_axes" not in mod.__dict__ or mod._axes is _core._axes


def test_animate_returns_html_with_controls():
    fig, ax = plt.subplots(figsize=(2, 2))
    (line,) = ax.plot([], [])
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)

    def update(k):
        line.set_data([0, k / 4], [0, k / 4])
        return (line,)

    n_before = len(plt.get_fignums())
    html = viz.animate(fig, update, 4, alt="a line growing <from> the origin", interval=50)
    text = html.data
    assert "<script" in text
    assert 'class="anim-controls"' in text and "play_animation()" in text  # the jshtml player
    assert text.count("data:image/png;base64") == 4  # one embedded image per frame
    assert len(plt.get_fignums()) == n_before - 1  # the figure was closed
    assert len(text) < 300_000
    # the book reads offline: nothing is fetched from the network, every button has a visible glyph
    assert "http://" not in text and "https://" not in text, "the animation links to a remote resource"
    assert '<i class="fa' not in text
    assert text.count('class="anim-glyph"') == text.count("<button") == 9
    # accessible: the frame has its text alternative (escaped), the slider its label
    assert 'alt="a line growing &lt;from&gt; the origin"' in text
    assert 'type="range" aria-label="Frame"' in text
    with pytest.raises(TypeError, match="update"):
        viz.animate(plt.figure(), None, 3, alt="x")
    with pytest.raises(ValueError, match="alt"):
        viz.animate(plt.figure(), update, 3, alt=" ")


def test_exported_through_viz():
    for name in viz.__all__:
        assert getattr(sl.viz, name) is getattr(viz, name)


@pytest.mark.parametrize("package", ["slamlib", "slamlib.viz", "slamlib.datasets"])
def test_star_exports_never_shadow_each_other(package):
    """A package that re-exports its modules with ``import *`` hands on each public name once: two
    modules exporting the same name would leave only the last one reachable (and break the callers
    of the first)."""
    import importlib
    import pkgutil

    pkg = importlib.import_module(package)
    owners = {}
    for info in pkgutil.iter_modules(pkg.__path__):
        mod = importlib.import_module(f"{package}.{info.name}")
        for name in getattr(mod, "__all__", ()):
            owners.setdefault(name, []).append(mod)
    clashes = {name: [m.__name__ for m in mods] for name, mods in owners.items()
               if len({id(getattr(m, name)) for m in mods}) > 1}
    assert not clashes, f"{package}: names exported by more than one module: {clashes}"
