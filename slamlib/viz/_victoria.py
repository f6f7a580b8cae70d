"""Plots of the Victoria Park runs: paths and maps over the GPS fixes, the map's
growth, and the time of a filter step against the size of the map.

matplotlib is imported inside the functions only (through ``_axes``); every
function takes an optional ``ax`` and returns it.
"""

from __future__ import annotations

import numpy as np

from .._checks import as_array
from ._core import _axes
from ._real_data import _colors, _finish_map, _legend_outside

__all__ = ["plot_gps_paths", "plot_map_growth", "plot_step_time"]


def plot_gps_paths(gps, paths, *, maps=None, colors=None, ax=None, title=None):
    """Estimated paths (and maps) in the GPS frame over the GPS fixes.

    Parameters
    ----------
    gps : ndarray, shape (G, 3)
        GPS fixes ``[t, x, y]``.
    paths : dict of str to ndarray, shape (K, 2)
        Positions per method, already aligned to the GPS frame
        (:func:`slamlib.datasets.victoria.victoria_gps_ate`).
    maps : dict of str to ndarray, shape (L, 2), optional, keyword-only
        Landmarks per method in the GPS frame.
    colors : dict, optional, keyword-only
        Colour per method (as :func:`slamlib.viz.plot_real_trajectories`).
    ax : matplotlib.axes.Axes, optional, keyword-only
    title : str, optional, keyword-only

    Returns
    -------
    matplotlib.axes.Axes
    """
    gps = as_array(gps, "gps", (None, 3))
    if not isinstance(paths, dict):
        raise TypeError("paths must be a dict mapping a method name to positions of shape (K, 2)")
    maps = {} if maps is None else maps
    col = _colors(list(paths), colors)
    ax = _axes(ax, figsize=(7.5, 6.5))
    ax.plot(gps[:, 1], gps[:, 2], ".", color="0.55", ms=2.5, label="GPS fixes")
    for name, xy in paths.items():
        xy = as_array(xy, f"paths[{name!r}]", (None, 2))
        ax.plot(xy[:, 0], xy[:, 1], color=col[name], lw=0.9, label=name)
        if name in maps:
            m = as_array(maps[name], f"maps[{name!r}]", (None, 2))
            ax.plot(m[:, 0], m[:, 1], "+", color=col[name], ms=4, mew=0.8, label=f"{name}: map")
    return _finish_map(ax, title)


def plot_map_growth(t, counts, *, colors=None, ax=None, title=None):
    """Number of landmarks in the map over time, per method.

    Parameters
    ----------
    t : ndarray, shape (K,)
        Times, seconds.
    counts : dict of str to ndarray, shape (K,)
        Landmarks in the map at those times.

    Returns
    -------
    matplotlib.axes.Axes
    """
    t = as_array(t, "t", (None,))
    col = _colors(list(counts), colors)
    ax = _axes(ax, figsize=(6.5, 3.2))
    for name, n in counts.items():
        n = as_array(n, f"counts[{name!r}]", t.shape)
        ax.plot(t, n, color=col[name], label=name)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("landmarks in the map")
    _legend_outside(ax)
    if title:
        ax.set_title(title)
    return ax


def plot_step_time(table, *, ax=None, title=None):
    """Time of one EKF SLAM step against the number of landmarks, beside the bare-numpy floor.

    Parameters
    ----------
    table : ndarray, shape (S, 3)
        Rows ``[N, step_ms, floor_ms]`` (``benchmarks/victoria_park.py``).

    Returns
    -------
    matplotlib.axes.Axes
    """
    table = as_array(table, "table", (None, 3))
    ax = _axes(ax, figsize=(5.5, 3.6))
    N = table[:, 0]
    ax.loglog(N, table[:, 1], "o-", label="EKF SLAM step")
    ax.loglog(N, table[:, 2], "s--", color="0.4", label="bare numpy: rank-2 updates")
    ref = table[-1, 2] * (N / N[-1]) ** 2
    ax.loglog(N, ref, ":", color="0.6", label=r"$\propto N^2$")
    ax.set_xticks(N, [str(int(n)) for n in N])
    ax.minorticks_off()
    ax.set_xlabel("landmarks N")
    ax.set_ylabel("ms per step")
    ax.legend(fontsize=8)
    if title:
        ax.set_title(title)
    return ax
