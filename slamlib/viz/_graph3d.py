"""Plots of the 3-D part: rotations (gimbal lock) and 3-D pose graphs.

matplotlib is imported inside the functions only; each function makes its own figure (3-D axes)
and returns its axes.
"""

from __future__ import annotations

import numpy as np

from .._checks import as_array

__all__ = ["plot_pose_graphs3d", "plot_euler_conditioning", "plot_incremental_step_times"]

_TRUTH = "0.15"


def plot_pose_graphs3d(panels, *, truth=None, size=4.2, elev=25.0, azim=-60.0):
    """Positions of 3-D pose graphs side by side (one 3-D axes per panel).

    Parameters
    ----------
    panels : dict of str -> ndarray, shape (n, 4, 4) or (n, 3)
        Title -> poses (or positions).
    truth : ndarray, shape (n, 4, 4) or (n, 3), optional, keyword-only
        Drawn thin and dark in every panel.
    size : float, keyword-only
        Panel size in inches.
    elev, azim : float, keyword-only
        View angles.

    Returns
    -------
    list of matplotlib axes
    """
    import matplotlib.pyplot as plt

    def pos(P, name):
        P = as_array(P, name, ndim=(2, 3))
        return P[:, :3, 3] if P.ndim == 3 else P[:, :3]

    fig = plt.figure(figsize=(size * len(panels), size), layout="constrained")
    axes = []
    for k, (title, P) in enumerate(panels.items()):
        ax = fig.add_subplot(1, len(panels), k + 1, projection="3d")
        p = pos(P, title)
        if truth is not None:
            t = pos(truth, "truth")
            ax.plot(t[:, 0], t[:, 1], t[:, 2], color=_TRUTH, lw=0.4, label="truth")
        ax.plot(p[:, 0], p[:, 1], p[:, 2], color="C0", lw=0.6, label="estimate")
        ax.set_title(title)
        ax.view_init(elev=elev, azim=azim)
        ax.set_box_aspect((1, 1, 1))
        ax.set_xticklabels([])
        ax.set_yticklabels([])
        ax.set_zticklabels([])
        axes.append(ax)
    if truth is not None:
        axes[0].legend(loc="upper left", fontsize="small")
    return axes


def plot_euler_conditioning(pitch, singular_values, *, ax=None):
    """Singular values of the Jacobian of a rotation with respect to its Euler angles, against the pitch.

    Parameters
    ----------
    pitch : ndarray, shape (K,)
        Pitch angles (radians).
    singular_values : ndarray, shape (K, 3)
        The three singular values at each pitch (largest first).
    ax : matplotlib axes, optional
        A new figure when omitted.

    Returns
    -------
    matplotlib axes
    """
    import matplotlib.pyplot as plt

    pitch = as_array(pitch, "pitch", ndim=1)
    sv = as_array(singular_values, "singular_values", (pitch.size, 3))
    if ax is None:
        _, ax = plt.subplots(figsize=(6.0, 3.4), layout="constrained")
    for k in range(3):
        ax.plot(np.degrees(pitch), sv[:, k], lw=2.0 - 0.5 * k, label=f"singular value {k + 1}")
    ax.axvline(90.0, color="0.5", lw=0.8, ls="--")
    ax.set_xlabel("pitch [deg]")
    ax.set_ylabel("singular value")
    ax.legend()
    return ax


def plot_incremental_step_times(series, bin_size, *, ax=None, marks=None):
    """Mean time per measurement of incremental solvers, in bins of measurements (log scale).

    Parameters
    ----------
    series : dict of str -> sequence of float
        Label -> mean milliseconds per measurement in each bin.
    bin_size : int
        Measurements per bin.
    ax : matplotlib axes, optional, keyword-only
    marks : sequence of int, optional, keyword-only
        Measurements to mark with thin vertical lines (e.g. full solves).

    Returns
    -------
    matplotlib axes
    """
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(6.5, 3.4), layout="constrained")
    for k, (label, ms) in enumerate(series.items()):
        ms = as_array(ms, label, ndim=1)
        ax.step((np.arange(ms.size) + 1) * bin_size, ms, where="pre", color=f"C{k}", label=label)
    for m in marks or ():
        ax.axvline(m, color="0.7", lw=0.6, zorder=0)
    ax.set_yscale("log")
    ax.set_xlabel("measurements so far")
    ax.set_ylabel(f"mean time per measurement [ms] (bins of {bin_size})")
    ax.legend()
    return ax
