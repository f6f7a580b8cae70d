"""Plots of the Foundations part: discrete beliefs, densities and sensor models.

Beliefs of the histogram filters (the 1-D corridor with doors, 2-D grids), 2-D
densities over world coordinates, the beam model of range finders, a histogram
of real range readings and the likelihood field of a map.

matplotlib is imported inside the functions only. Every function that draws on
one axes takes an optional ``ax`` and returns it; the sequence plots create their
own figure and return the array of axes.
"""

from __future__ import annotations

import numpy as np

from .._checks import as_array
from . import _core
from ._core import TRUTH_COLOR, _axes

__all__ = [
    "plot_belief_1d",
    "plot_belief_sequence",
    "plot_belief_2d",
    "plot_belief_2d_sequence",
    "plot_density_2d",
    "plot_beam_model",
    "plot_range_histogram",
    "plot_likelihood_field",
    "plot_motion_samples",
    "plot_likelihood_panels",
    "plot_map_and_field",
]

_DOOR_COLOR = "#c8a46e"



def _draw_doors(ax, doors):
    doors = np.asarray(doors, dtype=bool)
    edges = np.diff(np.concatenate([[False], doors, [False]]).astype(int))
    for start, stop in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)):
        # a faint band behind the bars and a solid strip along the top, visible whatever the bars
        ax.axvspan(start - 0.5, stop - 0.5, color=_DOOR_COLOR, alpha=0.35, lw=0, zorder=0)
        ax.axvspan(start - 0.5, stop - 0.5, ymin=0.9, ymax=1.0, color=_DOOR_COLOR, lw=0, zorder=3)


def plot_belief_1d(belief, *, doors=None, true_x=None, predicted=None, ax=None, title=None, color="C0",
                   ylim=None, legend=False):
    """Bar plot of a belief over the cells of a 1-D corridor.

    Parameters
    ----------
    belief : ndarray, shape (n,)
        Probabilities per cell.
    doors : ndarray of bool, shape (n,), optional
        Door map; door cells are shaded.
    true_x : int, optional
        True cell of the robot, marked by a triangle under the axis.
    predicted : ndarray, shape (n,), optional
        A second belief (e.g. the prediction ``bel_bar``) drawn as a step outline.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    title : str, optional
        Axes title.
    color : str
        Bar colour.
    ylim : float, optional
        Upper limit of the y axis (default: automatic).
    legend : bool
        Draw a legend.

    Returns
    -------
    matplotlib.axes.Axes
    """
    belief = as_array(belief, "belief", ndim=1)
    n = belief.size
    ax = _axes(ax, (8, 2.2))
    if doors is not None:
        doors = as_array(doors, "doors", (n,))
        _draw_doors(ax, doors)
        ax.plot([], [], color=_DOOR_COLOR, lw=6, label="door")
    edges = np.arange(n + 1) - 0.5
    # one filled staircase (one artist) instead of n bars: same picture, much faster to draw
    ax.stairs(belief, edges, fill=True, color=color, label=r"$bel(x)$")
    if predicted is not None:
        predicted = as_array(predicted, "predicted", (n,))
        ax.stairs(predicted, edges, color="0.3", lw=1.2, label=r"$\overline{bel}(x)$")
    if true_x is not None:
        ax.plot([true_x], [0], marker="^", ms=9, color=TRUTH_COLOR, clip_on=False, zorder=5,
                transform=ax.get_xaxis_transform(), label="true position")
    ax.set_xlim(-0.5, n - 0.5)
    if ylim is None:
        top = max(float(belief.max()), 0.0 if predicted is None else float(predicted.max()))
        ylim = 1.15 * top if top > 0 else 1.0  # headroom for the door strip
    ax.set_ylim(0, ylim)
    ax.set_xlabel("cell $x$")
    ax.set_ylabel("probability")
    if title:
        ax.set_title(title, fontsize=10, loc="left")
    if legend:
        ax.legend(loc="lower right", bbox_to_anchor=(1.0, 1.0), fontsize=8, ncol=4, frameon=False,
                  borderaxespad=0.1)
    return ax


def plot_belief_sequence(beliefs, *, doors=None, true_x=None, predicted=None, titles=None, ylim=None):
    """Stacked bar plots of 1-D beliefs, one row per step (belief over time).

    Parameters
    ----------
    beliefs : ndarray, shape (T, n)
        The beliefs to show, in order.
    doors : ndarray of bool, shape (n,), optional
        Door map, shaded in every row.
    true_x : ndarray of int, shape (T,), optional
        True cell in each row.
    predicted : ndarray, shape (T, n), optional
        Predicted beliefs drawn as outlines.
    titles : sequence of str, optional
        One title per row.
    ylim : float, optional
        Common upper y limit (default: each row scaled to its own maximum).

    Returns
    -------
    ndarray of matplotlib.axes.Axes, shape (T,)
    """
    import matplotlib.pyplot as plt

    beliefs = as_array(beliefs, "beliefs", ndim=2)
    steps = beliefs.shape[0]
    _, axes = plt.subplots(steps, 1, figsize=(8, 1.45 * steps + 0.4), sharex=True, layout="constrained",
                           squeeze=False)
    axes = axes[:, 0]
    for t, ax in enumerate(axes):
        plot_belief_1d(beliefs[t], doors=doors, ax=ax, ylim=ylim,
                       true_x=None if true_x is None else int(np.asarray(true_x)[t]),
                       predicted=None if predicted is None else np.asarray(predicted)[t],
                       title=None if titles is None else titles[t], legend=(t == 0))
        ax.set_ylabel("")
        if t < steps - 1:
            ax.set_xlabel("")
    return axes


def plot_belief_2d(belief, *, free=None, true_xy=None, path=None, ax=None, title=None, cmap="viridis",
                   colorbar=False):
    """Heat map of a belief over a 2-D grid, with the walls drawn.

    Parameters
    ----------
    belief : ndarray, shape (H, W)
        Probabilities per cell, rows ``y`` and columns ``x`` (row 0 at the bottom).
    free : ndarray of bool, shape (H, W), optional
        Free cells; occupied cells are drawn dark grey.
    true_xy : ndarray, shape (2,), optional
        True cell ``(x, y)`` of the robot, marked by a red cross.
    path : ndarray, shape (T, 2), optional
        Cells ``(x, y)`` the robot visited, drawn as a line.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    title : str, optional
        Axes title.
    cmap : str
        Colour map of the belief.
    colorbar : bool
        Add a colour bar.

    Returns
    -------
    matplotlib.axes.Axes
    """
    belief = as_array(belief, "belief", ndim=2)
    H, W = belief.shape
    ax = _axes(ax, (6, 6 * H / W + 0.6))
    shown = belief
    if free is not None:
        free = as_array(free, "free", (H, W)).astype(bool)
        shown = np.ma.masked_array(belief, mask=~free)
    im = ax.imshow(shown, origin="lower", cmap=cmap, interpolation="nearest", vmin=0,
                   extent=(-0.5, W - 0.5, -0.5, H - 0.5))
    if free is not None:
        walls = np.ma.masked_array(np.ones((H, W)), mask=free)
        ax.imshow(walls, origin="lower", cmap="gray", vmin=0, vmax=3.5, interpolation="nearest",
                  extent=(-0.5, W - 0.5, -0.5, H - 0.5))
    if path is not None:
        path = as_array(path, "path", (None, 2))
        ax.plot(path[:, 0], path[:, 1], color="w", lw=1, alpha=0.8)
    if true_xy is not None:
        true_xy = as_array(true_xy, "true_xy", (2,))
        ax.plot(true_xy[0], true_xy[1], marker="x", ms=9, mew=2.5, color=TRUTH_COLOR)
    ax.set_xlabel("$x$ [cells]")
    ax.set_ylabel("$y$ [cells]")
    if title:
        ax.set_title(title, fontsize=10)
    if colorbar:
        ax.figure.colorbar(im, ax=ax, shrink=0.8, label="probability")
    return ax


def plot_belief_2d_sequence(beliefs, *, free=None, true_xy=None, titles=None, ncols=3):
    """A grid of 2-D belief heat maps (belief over time).

    Parameters
    ----------
    beliefs : ndarray, shape (T, H, W)
        The beliefs to show, in order.
    free : ndarray of bool, shape (H, W), optional
        Free cells (walls drawn dark grey).
    true_xy : ndarray, shape (T, 2), optional
        True cell ``(x, y)`` in each panel.
    titles : sequence of str, optional
        One title per panel.
    ncols : int
        Panels per row.

    Returns
    -------
    ndarray of matplotlib.axes.Axes, shape (T,)
    """
    import matplotlib.pyplot as plt

    beliefs = as_array(beliefs, "beliefs", ndim=3)
    steps, H, W = beliefs.shape
    ncols = min(ncols, steps)
    nrows = -(-steps // ncols)
    width = 3.2 * ncols
    _, axes = plt.subplots(nrows, ncols, figsize=(width, nrows * 3.2 * H / W + 0.5 * nrows + 0.2),
                           squeeze=False, layout="constrained")
    axes = axes.ravel()
    for t, ax in enumerate(axes):
        if t >= steps:
            ax.set_axis_off()
            continue
        plot_belief_2d(beliefs[t], free=free, ax=ax, title=None if titles is None else titles[t],
                       true_xy=None if true_xy is None else np.asarray(true_xy)[t])
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_xlabel("")
        ax.set_ylabel("")
    return axes[:steps]


def plot_density_2d(density, extent, *, ax=None, contour=False, levels=6, cmap="viridis", color="k",
                    title=None, colorbar=False, label="density"):
    """A density (or likelihood) over a rectangle of the plane, as an image or contour lines.

    Parameters
    ----------
    density : ndarray, shape (H, W)
        Values on a regular grid, rows ``y`` (row 0 at the bottom) and columns ``x``;
        NaN cells are left blank.
    extent : sequence of 4 floats
        ``(left, right, bottom, top)`` of the grid in world units (the outer edges
        of the first and last cells).
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    contour : bool
        Draw `levels` contour lines (to overlay on samples) instead of an image.
    levels : int or sequence of float
        Contour levels (``contour=True`` only).
    cmap : str
        Colour map of the image.
    color : str
        Colour of the contour lines.
    title : str, optional
        Axes title.
    colorbar : bool
        Add a colour bar (image only).
    label : str
        Colour-bar label.

    Returns
    -------
    matplotlib.axes.Axes
    """
    density = as_array(density, "density", ndim=2, finite=False)
    extent = as_array(extent, "extent", (4,))
    aspect = (extent[3] - extent[2]) / (extent[1] - extent[0])
    ax = _axes(ax, (6.0, min(max(6.0 * aspect, 2.0), 8.0) + 0.8))
    if contour:
        H, W = density.shape
        xs = extent[0] + (np.arange(W) + 0.5) * (extent[1] - extent[0]) / W
        ys = extent[2] + (np.arange(H) + 0.5) * (extent[3] - extent[2]) / H
        ax.contour(xs, ys, density, levels=levels, colors=color, linewidths=0.9)
    else:
        im = ax.imshow(np.ma.masked_invalid(density), origin="lower", extent=tuple(extent), cmap=cmap,
                       interpolation="nearest", aspect="equal")
        if colorbar:
            ax.figure.colorbar(im, ax=ax, shrink=0.8, label=label)
    ax.set_aspect("equal")
    ax.set_xlabel("$x$ [m]")
    ax.set_ylabel("$y$ [m]")
    if title:
        ax.set_title(title, fontsize=10)
    return ax


def plot_beam_model(z_star, *, z_max, sigma_hit, lambda_short, w_hit, w_short, w_max, w_rand, ax=None,
                    n_points=2001):
    """The beam model of a range finder: its four weighted components and their mixture.

    Each component is evaluated with ``slamlib.beam_range_finder_model`` (its own
    weight set to 1, the others to 0). The densities are drawn on ``[0, z_max)``;
    the max-range component, a point mass of probability `w_max` at `z_max`, is
    drawn as a stem with its probability written next to it.

    Parameters
    ----------
    z_star : float
        Expected range.
    z_max, sigma_hit, lambda_short, w_hit, w_short, w_max, w_rand : float
        Parameters of ``slamlib.beam_range_finder_model``.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    n_points : int
        Number of ranges evaluated.

    Returns
    -------
    matplotlib.axes.Axes
    """
    from ..sensors import beam_range_finder_model

    params = dict(z_max=z_max, sigma_hit=sigma_hit, lambda_short=lambda_short)
    z = np.linspace(0.0, z_max, n_points)[:-1]
    star = np.full_like(z, float(z_star))
    names = {"w_hit": ("hit", w_hit), "w_short": ("short", w_short), "w_rand": ("random", w_rand)}
    ax = _axes(ax, (7, 3))
    for i, (key, (name, w)) in enumerate(names.items()):
        unit = {k: 0.0 for k in ("w_hit", "w_short", "w_max", "w_rand")}
        unit[key] = 1.0
        p = beam_range_finder_model(z, star, **params, **unit)
        ax.plot(z, w * p, ls="--", lw=1.2, color=f"C{i + 1}", label=f"{name} ({w:g} $p_{{{name}}}$)")
    p = beam_range_finder_model(z, star, **params, w_hit=w_hit, w_short=w_short, w_max=w_max, w_rand=w_rand)
    ax.plot(z, p, color="C0", lw=2, label="mixture $p(z \\mid z^*)$")
    top = float(p.max())
    ax.vlines(z_max, 0, 0.35 * top, color="C4", lw=3, label=f"max range: point mass {w_max:g}")
    ax.plot([z_max], [0.35 * top], marker="^", color="C4", ms=8)
    ax.axvline(z_star, color="0.5", lw=0.8, ls=":")
    ax.text(z_star, 1.02 * top, "$z^*$", ha="center", va="bottom", color="0.3")
    ax.set_xlim(0, 1.03 * z_max)
    ax.set_ylim(0, 1.12 * top)
    ax.set_xlabel("measured range $z$ [m]")
    ax.set_ylabel("density")
    ax.legend(fontsize=8, frameon=False, loc="upper left")
    return ax


def plot_range_histogram(ranges, *, max_range, display_max=None, bins=60, ax=None, title=None):
    """Histogram of measured ranges, with the max-range readings ("no return") as a separate bar.

    Parameters
    ----------
    ranges : ndarray, any shape
        Range readings (all beams of all scans).
    max_range : float
        The sensor's maximum reading; readings ``>= max_range`` are counted apart.
    display_max : float, optional
        Right end of the histogram (default `max_range`); readings between it and
        `max_range` are left out.
    bins : int
        Number of bins on ``[0, display_max]``.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    title : str, optional
        Axes title.

    Returns
    -------
    matplotlib.axes.Axes
    """
    ranges = as_array(ranges, "ranges", ndim=range(1, 33)).ravel()
    top = float(max_range if display_max is None else display_max)
    ax = _axes(ax, (7, 3))
    at_max = ranges >= max_range
    shown = ranges[~at_max & (ranges <= top)]
    ax.hist(shown, bins=bins, range=(0, top), color="C0", weights=np.full(shown.size, 1.0 / ranges.size),
            label="readings")
    width = top / bins
    frac = at_max.mean()
    ax.bar(top + 2 * width, frac, width=2 * width, color="C4",
           label=f"no return ({max_range:g} m): {frac:.2%}")
    ax.set_xlim(0, top + 4 * width)
    ax.set_xlabel("measured range [m]")
    ax.set_ylabel("fraction of readings")
    ax.legend(fontsize=8, frameon=False)
    if title:
        ax.set_title(title, fontsize=10)
    return ax


def plot_likelihood_field(field, *, sigma_hit, ax=None, title=None, colorbar=True):
    """The likelihood field of a map: ``exp(-dist^2 / (2 sigma_hit^2))`` of every cell.

    Parameters
    ----------
    field : slamlib.LikelihoodField
        From ``slamlib.likelihood_field`` (its ``dist`` and ``grid``).
    sigma_hit : float
        Standard deviation of the hit term, metres.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    title : str, optional
        Axes title.
    colorbar : bool
        Add a colour bar.

    Returns
    -------
    matplotlib.axes.Axes
        Unknown cells (infinite distance) are left blank.
    """
    dist = np.asarray(field.dist, dtype=float)
    with np.errstate(invalid="ignore", over="ignore"):
        value = np.where(np.isfinite(dist), np.exp(-0.5 * (dist / float(sigma_hit)) ** 2), np.nan)
    ax = plot_density_2d(value, field.grid.extent, ax=ax, cmap="magma", title=title, colorbar=colorbar,
                         label=r"$\exp(-d^2 / 2\sigma_{hit}^2)$")
    return ax


def plot_motion_samples(samples, *, start, end=None, titles=None, densities=None, extent=None, size=3.7):
    """Side-by-side panels of poses sampled from a motion model.

    Each panel shows one set of samples (``slamlib.viz.plot_particles``), the start
    pose in black and, if given, the noise-free end pose in red; optionally contour
    lines of a density over the end position.

    Parameters
    ----------
    samples : sequence of ndarray, shape (M, 3)
        One set of sampled poses per panel.
    start : ndarray, shape (3,)
        Pose before the motion.
    end : ndarray, shape (3,), optional
        Noise-free pose after the motion.
    titles : sequence of str, optional
        One title per panel.
    densities : sequence of (ndarray, shape (H, W) or None), optional
        A density over positions per panel, drawn as contours (see :func:`plot_density_2d`).
    extent : sequence of 4 floats, optional
        ``(left, right, bottom, top)`` of the density grids.
    size : float
        Width of a panel, inches.

    Returns
    -------
    ndarray of matplotlib.axes.Axes, shape (P,)
    """
    import matplotlib.pyplot as plt

    samples = [as_array(s, "samples", (None, 3)) for s in samples]
    start = as_array(start, "start", (3,))
    n = len(samples)
    # one square window for all panels (axes are not shared: the pose plots fix an equal aspect)
    pts = np.concatenate([s[:, :2] for s in samples] + [start[None, :2]]
                         + ([] if end is None else [as_array(end, "end", (3,))[None, :2]]))
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre, half = (lo + hi) / 2, 0.55 * float(np.max(hi - lo)) + 0.1
    _, axes = plt.subplots(1, n, figsize=(size * n, size + 0.2), layout="constrained", squeeze=False)
    axes = axes[0]
    for k, (ax, pts) in enumerate(zip(axes, samples)):
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] - half, centre[1] + half)
        _core.plot_particles(pts, ax=ax, s=4, alpha=0.5)
        if densities is not None and densities[k] is not None:
            plot_density_2d(densities[k], extent, ax=ax, contour=True)
        _core.plot_pose(start, ax=ax, color="k")
        if end is not None:
            _core.plot_pose(end, ax=ax, color="C3")
        ax.set_aspect("equal", adjustable="box")  # fixed limits: let the box, not the data limits, adapt
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] - half, centre[1] + half)
        ax.set_xlabel("$x$ [m]")
        ax.set_ylabel("$y$ [m]" if k == 0 else "")
        if titles is not None:
            ax.set_title(titles[k], fontsize=10)
    return axes


def plot_likelihood_panels(likelihoods, extent, *, landmarks, pose=None, titles=None, size=3.7):
    """Side-by-side images of measurement likelihoods over robot positions, with landmarks.

    Parameters
    ----------
    likelihoods : sequence of ndarray, shape (H, W)
        One likelihood grid per panel (rows ``y``, columns ``x``).
    extent : sequence of 4 floats
        ``(left, right, bottom, top)`` of the grids.
    landmarks : sequence of ndarray, shape (K, 2)
        The landmarks to draw in each panel.
    pose : ndarray, shape (3,), optional
        True pose, drawn in red.
    titles : sequence of str, optional
        One title per panel.
    size : float
        Width of a panel, inches.

    Returns
    -------
    ndarray of matplotlib.axes.Axes, shape (P,)
    """
    import matplotlib.pyplot as plt

    n = len(likelihoods)
    _, axes = plt.subplots(1, n, figsize=(size * n, size + 0.3), layout="constrained", squeeze=False)
    axes = axes[0]
    for k, ax in enumerate(axes):
        plot_density_2d(likelihoods[k], extent, ax=ax, title=None if titles is None else titles[k])
        _core.plot_landmarks(as_array(landmarks[k], "landmarks", (None, 2)), ax=ax)
        if pose is not None:
            _core.plot_pose(pose, ax=ax, color="C3")
        ax.set_aspect("equal", adjustable="box")
        ax.set_xlim(extent[0], extent[1])
        ax.set_ylim(extent[2], extent[3])
        if k:
            ax.set_ylabel("")
    return axes


def plot_map_and_field(grid, field, *, sigma_hit, xlim=None, ylim=None, size=5.5):
    """An occupancy grid next to its likelihood field.

    Parameters
    ----------
    grid : slamlib.OccupancyGrid
        The map (drawn with ``slamlib.viz.plot_grid``).
    field : slamlib.LikelihoodField
        Its likelihood field (:func:`plot_likelihood_field`).
    sigma_hit : float
        Standard deviation of the hit term, metres.
    xlim, ylim : (float, float), optional
        Region to show, metres.
    size : float
        Width of a panel, inches.

    Returns
    -------
    ndarray of matplotlib.axes.Axes, shape (2,)
    """
    import matplotlib.pyplot as plt

    _, axes = plt.subplots(1, 2, figsize=(2 * size, size * 0.75), layout="constrained")
    _core.plot_grid(grid, ax=axes[0])
    axes[0].set_title("occupancy map", fontsize=10)
    plot_likelihood_field(field, sigma_hit=sigma_hit, ax=axes[1], title="likelihood field")
    axes[1].set_ylabel("")
    for ax in axes:
        if xlim is not None:
            ax.set_xlim(*xlim)
        if ylim is not None:
            ax.set_ylim(*ylim)
    return axes
