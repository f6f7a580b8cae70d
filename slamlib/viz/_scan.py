"""Plots for scan matching and mapping: an ICP run as an animation, its convergence, and a
map laid over a reference map (pose graphs are drawn by
``_graph.plot_pose_graph``).

matplotlib is imported inside the functions only (through ``_core``).

References
----------
Besl & McKay (1992) and Censi (2008) (ICP);
Thrun, Burgard & Fox, *Probabilistic Robotics* (2005), Ch. 9 (Figs. 9.5-9.7: occupancy grid
maps built from range scans).
"""

from __future__ import annotations

import numpy as np

from .._checks import as_array
from ._core import _axes, animate, plot_grid

__all__ = ["animate_icp", "plot_icp_convergence", "plot_map_overlay"]


def _moved(pose, pts):
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return pts @ np.array([[c, s], [-s, c]]) + pose[:2]


def animate_icp(source, target, result, *, truth=None, window=None, figsize=(6.0, 4.0), interval=500, dpi=60,
                max_frames=10):
    """An ICP run as an animation: the source scan moving onto the target, round by round.

    Parameters
    ----------
    source : ndarray, shape (N, 2)
        The source points.
    target : ndarray, shape (M, 2)
        The target points.
    result : ICPResult
        The run (its ``history`` gives the frames).
    truth : ndarray, shape (3,), keyword-only, optional
        A reference pose; the error to it is shown in the title.
    window : tuple (xmin, xmax, ymin, ymax), keyword-only, optional
        Axes limits.
    figsize, interval, dpi
        Figure size, milliseconds between frames, resolution of the frames.
    max_frames : int, keyword-only
        At most this many rounds are shown (evenly spaced, the first and the
        last included): every frame is an embedded image.

    Returns
    -------
    IPython.display.HTML
        Self-contained animation (:func:`animate`).

    References
    ----------
    Besl & McKay (1992), Sec. III (the iteration).
    """
    import matplotlib.pyplot as plt

    src = as_array(source, "source", (None, 2))
    tgt = as_array(target, "target", (None, 2))
    hist = np.asarray(result.history)
    fig, ax = plt.subplots(figsize=figsize, layout="constrained")
    ax.scatter(tgt[:, 0], tgt[:, 1], s=4, color="k", label="target")
    pts = ax.scatter(*_moved(hist[0], src).T, s=4, color="C1", label="source")
    if window is not None:
        ax.set_xlim(window[:2])
        ax.set_ylim(window[2:])
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(loc="upper right", fontsize=8)

    def update(k):
        pts.set_offsets(_moved(hist[k], src))
        txt = f"round {k} of {len(hist) - 1}"
        if truth is not None:
            err = np.hypot(*(hist[k, :2] - truth[:2]))
            txt += f": {100 * err:.0f} cm, {np.rad2deg(abs(np.angle(np.exp(1j * (hist[k, 2] - truth[2]))))):.1f} deg off"
        ax.set_title(txt, fontsize=9)

    frames = np.unique(np.round(np.linspace(0, len(hist) - 1, min(len(hist), int(max_frames)))).astype(int))
    update(0)
    alt = (f"ICP in {len(frames)} rounds: the source scan (orange) moves onto the target scan (black); each "
           "frame's title gives the round" + (" and the distance from the reference pose." if truth is not None else "."))
    return animate(fig, update, frames, alt=alt, interval=interval, dpi=dpi)


def plot_icp_convergence(results, truth, ax=None):
    """Distance of each round's pose from a reference pose, for one or more ICP runs.

    Parameters
    ----------
    results : dict of str -> ICPResult
        Runs to compare (e.g. point-to-point and point-to-line).
    truth : ndarray, shape (3,)
        Reference pose.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on.

    Returns
    -------
    matplotlib.axes.Axes

    References
    ----------
    Censi (2008), Fig. 4 (convergence of point-to-point and point-to-line ICP).
    """
    truth = as_array(truth, "truth", (3,))
    ax = _axes(ax)
    for k, (name, res) in enumerate(results.items()):
        h = np.asarray(res.history)
        err = np.hypot(h[:, 0] - truth[0], h[:, 1] - truth[1])
        ax.semilogy(np.arange(h.shape[0]), np.maximum(err, 1e-5), "o-", ms=3, color=f"C{k}", label=name)
    ax.set_xlabel("ICP round")
    ax.set_ylabel("position error [m]")
    ax.legend()
    return ax


def plot_map_overlay(grid, reference, transform=None, ax=None, *, occupied=0.6, title=None, s=3.0):
    """A map's occupied cells (red) over a reference map, after a rigid transform.

    Parameters
    ----------
    grid : OccupancyGrid
        The map built by the robot.
    reference : OccupancyGrid
        The reference map, drawn underneath.
    transform : tuple (R (2, 2), t (2,)), optional
        Rigid transform from the map's frame to the reference's.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on.
    occupied : float, keyword-only
        Occupancy from which a cell is drawn.
    title : str, keyword-only, optional
        Axes title.
    s : float, keyword-only
        Marker size.

    Returns
    -------
    matplotlib.axes.Axes

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 9.2 (occupancy grid maps).
    """
    R, t = (np.eye(2), np.zeros(2)) if transform is None else transform
    ax = _axes(ax)
    plot_grid(reference, ax, alpha=0.6)
    rc = np.argwhere(grid.occupied_mask(occupied))
    xy = grid.cell_to_world(rc).reshape(-1, 2) @ np.asarray(R).T + np.asarray(t)
    ax.scatter(xy[:, 0], xy[:, 1], s=s, color="C3", marker="s", linewidths=0, label="occupied cells of the map",
               zorder=3)
    if xy.shape[0]:
        lo, hi = xy.min(axis=0) - 3.0, xy.max(axis=0) + 3.0
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
    if title is not None:
        ax.set_title(title)
    return ax
