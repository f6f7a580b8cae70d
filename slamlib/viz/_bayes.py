"""Plots of discrete beliefs: the 1-D corridor with doors and 2-D grid beliefs.

matplotlib is imported inside the functions only. Every function that draws on
one axes takes an optional ``ax`` and returns it; the sequence plots create their
own figure and return the array of axes.
"""

from __future__ import annotations

import numpy as np

from .._checks import as_array

__all__ = ["plot_belief_1d", "plot_belief_sequence", "plot_belief_2d", "plot_belief_2d_sequence"]

_DOOR_COLOR = "#c8a46e"
_TRUE_COLOR = "C3"


def _axes(ax, figsize):
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=figsize, layout="constrained")
    return ax


def _draw_doors(ax, doors):
    doors = np.asarray(doors, dtype=bool)
    edges = np.diff(np.concatenate([[False], doors, [False]]).astype(int))
    for start, stop in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)):
        ax.axvspan(start - 0.5, stop - 0.5, color=_DOOR_COLOR, alpha=0.35, lw=0, zorder=0)


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
        ax.plot([], [], color=_DOOR_COLOR, alpha=0.6, lw=6, label="door")
    cells = np.arange(n)
    ax.bar(cells, belief, width=0.9, color=color, label=r"$bel(x)$")
    if predicted is not None:
        predicted = as_array(predicted, "predicted", (n,))
        ax.step(cells, predicted, where="mid", color="0.3", lw=1.2, label=r"$\overline{bel}(x)$")
    if true_x is not None:
        ax.plot([true_x], [0], marker="^", ms=9, color=_TRUE_COLOR, clip_on=False, zorder=5,
                transform=ax.get_xaxis_transform(), label="true position")
    ax.set_xlim(-0.5, n - 0.5)
    if ylim is not None:
        ax.set_ylim(0, ylim)
    else:
        ax.set_ylim(0, None)
    ax.set_xlabel("cell $x$")
    ax.set_ylabel("probability")
    if title:
        ax.set_title(title, fontsize=10)
    if legend:
        ax.legend(loc="upper right", fontsize=8, ncol=4, frameon=False)
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
        ax.plot(true_xy[0], true_xy[1], marker="x", ms=9, mew=2.5, color=_TRUE_COLOR)
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
