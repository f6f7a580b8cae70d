"""Plots of real-data runs: sightings over the ground truth, estimated paths and
maps over the Vicon ground truth, errors over time, residual histograms, and
NEES over time with its chi-square band.

matplotlib is imported inside the functions only. Functions drawing on one axes
take an optional ``ax`` and return it; :func:`plot_residual_histograms` draws two
panels and returns both axes.
"""

from __future__ import annotations

import numpy as np

from .._checks import as_array, as_covariance
from ._core import TRUTH_COLOR, _axes

__all__ = ["plot_sightings", "plot_real_trajectories", "plot_error_over_time", "plot_residual_histograms",
           "plot_nees_runs"]

_LANDMARK = "C3"
#: Colours reserved for methods that appear in several figures of a chapter.
_RESERVED = {"dead reckoning": "C1"}
#: Colours of the other methods, in the order they are given.
_CYCLE = ("C0", "C2", "C4", "C5", "C6", "C8", "C9")


def _colors(names, colors):
    """Colour per method: `colors` first, then the reserved ones, then the cycle in order."""
    if colors is not None and not isinstance(colors, dict):
        raise TypeError("colors must be a dict mapping a method name to a matplotlib colour")
    out, k = {}, 0
    for name in names:
        if colors and name in colors:
            out[name] = colors[name]
        elif name in _RESERVED:
            out[name] = _RESERVED[name]
        else:
            out[name] = _CYCLE[k % len(_CYCLE)]
            k += 1
    return out


def _legend_outside(ax):
    ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8, borderaxespad=0.0)



def _finish_map(ax, title):
    """Equal axes in metres, the legend outside, the title: the last touches of a map-frame plot."""
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    _legend_outside(ax)
    if title:
        ax.set_title(title)
    return ax


def _estimates(estimates, name="estimates"):
    if not isinstance(estimates, dict):
        raise TypeError(f"{name} must be a dict mapping a method name to poses of shape (T, 3)")
    return {str(k): as_array(v, f"{name}[{k!r}]", (None, 3)) for k, v in estimates.items()}


def _aligned(est, true, align):
    from ..scoring import align_se2, apply_se2

    if not align:
        return est, (np.eye(2), np.zeros(2))
    R, t = align_se2(est[:, :2], true[:, :2])
    return apply_se2(R, t, est), (R, t)


def plot_sightings(run, *, ax=None, max_rays=400, title=None):
    """Vicon path, true landmarks and the landmark sightings drawn from the true poses.

    Each sighting ``z = [r, phi]`` of step ``k`` is drawn as a ray from the
    true pose ``x_true[k + 1]`` to the point it implies; rays that end near
    their landmark show how good the camera's ranges and bearings are.

    Parameters
    ----------
    run : MRCLAMRun or LandmarkRun
        Uses ``x_true``, ``z``, ``ids`` and ``landmarks``.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    max_rays : int, keyword-only
        Draw at most this many rays (evenly spread over the run).
    title : str, optional, keyword-only
        Axes title.

    Returns
    -------
    matplotlib.axes.Axes

    References
    ----------
    Thrun, Burgard & Fox (2005), Eq. 6.40 (range-bearing measurement) and
    Table 10.1 line 10 (the landmark a measurement implies).
    """
    from matplotlib.collections import LineCollection

    from ..sensors import landmark_from_measurement

    x_true = as_array(run.x_true, "run.x_true", (None, 3))
    landmarks = as_array(run.landmarks, "run.landmarks", (None, 2))
    ax = _axes(ax, figsize=(7.0, 6.5))
    counts = [len(i) for i in run.ids]
    n = int(sum(counts))
    ax.plot(x_true[:, 0], x_true[:, 1], color=TRUTH_COLOR, lw=0.8, label="Vicon path")
    if n:
        Z = np.concatenate([np.reshape(z, (-1, 2)) for z in run.z])
        step = np.repeat(np.arange(len(counts)), counts)
        pick = np.unique(np.linspace(0, n - 1, min(n, int(max_rays))).round().astype(int))
        poses = x_true[step[pick] + 1]
        ends = landmark_from_measurement(poses, Z[pick])
        segs = np.stack([poses[:, :2], ends], axis=1)
        ax.add_collection(LineCollection(segs, colors="C0", linewidths=0.5, alpha=0.35,
                                         label=f"sightings ({pick.size} of {n})"))
        ax.plot(ends[:, 0], ends[:, 1], ".", color="C0", ms=2)
    ax.plot(landmarks[:, 0], landmarks[:, 1], "*", color=_LANDMARK, ms=11, mec="k", mew=0.5, label="landmarks (Vicon)")
    for j, (mx, my) in enumerate(landmarks):
        ax.annotate(str(j), (mx, my), textcoords="offset points", xytext=(5, 4), fontsize=7)
    ax.plot(*x_true[0, :2], "o", color="k", ms=6, label="start")
    return _finish_map(ax, title)


def plot_real_trajectories(x_true, estimates, *, landmarks=None, maps=None, align=True, colors=None, ax=None,
                           title=None):
    """Estimated paths and maps over the ground-truth path and landmarks.

    Parameters
    ----------
    x_true : ndarray, shape (T, 3)
        Ground-truth poses.
    estimates : dict of str to ndarray, shape (T, 3)
        Estimated poses per method, at the same times as `x_true`.
    landmarks : ndarray, shape (N, 2), optional, keyword-only
        True landmark positions.
    maps : dict of str to ndarray, shape (L, 2), optional, keyword-only
        Estimated landmarks per method (keys among those of `estimates`).
    align : bool, keyword-only
        Draw each method after the rigid alignment of its path onto
        `x_true` (:func:`slamlib.align_se2`), applied to its map as well.
    colors : dict of str to colour, optional, keyword-only
        Colour per method; by default "dead reckoning" is always orange and
        the other methods take the colour cycle in order, so that the same
        methods get the same colours in :func:`plot_error_over_time`.
    ax : matplotlib.axes.Axes, optional, keyword-only
        Axes to draw on; a new figure if omitted.
    title : str, optional, keyword-only
        Axes title.

    Returns
    -------
    matplotlib.axes.Axes

    References
    ----------
    Umeyama (1991) (the alignment); Thrun, Burgard & Fox (2005), Sec. 10.1.
    """
    from ..scoring import apply_se2

    x_true = as_array(x_true, "x_true", (None, 3))
    est = _estimates(estimates)
    maps = {} if maps is None else maps
    if not isinstance(maps, dict):
        raise TypeError("maps must be a dict mapping a method name to landmarks of shape (L, 2)")
    unknown = set(maps) - set(est)
    if unknown:
        raise ValueError(f"maps has methods without an estimate: {sorted(unknown)}")
    col = _colors(list(est), colors)
    ax = _axes(ax, figsize=(7.0, 6.5))
    ax.plot(x_true[:, 0], x_true[:, 1], color=TRUTH_COLOR, lw=1.6, label="Vicon")
    for name, x in est.items():
        c = col[name]
        if x.shape != x_true.shape:
            raise ValueError(f"estimates[{name!r}] must have the shape of x_true {x_true.shape}, got {x.shape}")
        xa, (R, t) = _aligned(x, x_true, align)
        ax.plot(xa[:, 0], xa[:, 1], color=c, lw=1.0, label=name)
        if name in maps:
            m = as_array(maps[name], f"maps[{name!r}]", (None, 2))
            if m.shape[0]:
                ma = apply_se2(R, t, m)
                ax.plot(ma[:, 0], ma[:, 1], "+", color=c, ms=10, mew=1.8, label=f"{name}: map")
    if landmarks is not None:
        lm = as_array(landmarks, "landmarks", (None, 2))
        ax.plot(lm[:, 0], lm[:, 1], "*", color=_LANDMARK, ms=10, mec="k", mew=0.5, label="landmarks (Vicon)")
    ax.plot(*x_true[0, :2], "o", color="k", ms=6, label="start")
    return _finish_map(ax, title)


def plot_error_over_time(t, x_true, estimates, *, align=True, log=False, colors=None, ax=None, title=None):
    """Position error of each method over time.

    Parameters
    ----------
    t : ndarray, shape (T,)
        Times (seconds).
    x_true : ndarray, shape (T, 3)
        Ground-truth poses.
    estimates : dict of str to ndarray, shape (T, 3)
        Estimated poses per method.
    align : bool, keyword-only
        Errors after each method's rigid alignment (as the ATE uses).
    log : bool, keyword-only
        Logarithmic error axis.
    colors : dict of str to colour, optional, keyword-only
        Colour per method (default as in :func:`plot_real_trajectories`).
    ax : matplotlib.axes.Axes, optional, keyword-only
        Axes to draw on; a new figure if omitted.
    title : str, optional, keyword-only
        Axes title.

    Returns
    -------
    matplotlib.axes.Axes

    References
    ----------
    Umeyama (1991); Thrun, Burgard & Fox (2005), Sec. 10.1.
    """
    t = as_array(t, "t", (None,))
    x_true = as_array(x_true, "x_true", (t.shape[0], 3))
    est = _estimates(estimates)
    col = _colors(list(est), colors)
    ax = _axes(ax, figsize=(7.5, 3.2))
    for name, x in est.items():
        c = col[name]
        if x.shape != x_true.shape:
            raise ValueError(f"estimates[{name!r}] must have the shape of x_true {x_true.shape}, got {x.shape}")
        xa, _ = _aligned(x, x_true, align)
        err = np.hypot(xa[:, 0] - x_true[:, 0], xa[:, 1] - x_true[:, 1])
        ax.plot(t, err, color=c, lw=1.0, label=name)
    if log:
        ax.set_yscale("log")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("position error [m]" + (" (aligned)" if align else ""))
    ax.set_xlim(t[0], t[-1])
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    if title:
        ax.set_title(title)
    return ax


def plot_residual_histograms(residuals, *, Q=None, axes=None, bins=60):
    """Histograms of range and bearing residuals, with the Gaussian of a chosen ``Q``.

    Parameters
    ----------
    residuals : ndarray, shape (K, 2) or dict of str to ndarray, shape (K, 2)
        Residuals ``[r, phi]`` (e.g. from :func:`slamlib.measurement_residuals`),
        or several sets by name (one histogram each).
    Q : ndarray, shape (2, 2), optional, keyword-only
        Measurement noise to overlay: the densities ``N(0, Q[0, 0])`` and
        ``N(0, Q[1, 1])``, scaled to the first set's counts.
    axes : sequence of two matplotlib.axes.Axes, optional, keyword-only
        Axes for range and bearing; a new figure if omitted.
    bins : int, keyword-only
        Number of bins.

    Returns
    -------
    ndarray of matplotlib.axes.Axes, shape (2,)

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 6.7 (estimating sensor-model parameters
    from data with ground truth).
    """
    import matplotlib.pyplot as plt

    sets = residuals if isinstance(residuals, dict) else {"residuals": residuals}
    sets = {str(k): as_array(v, f"residuals[{k!r}]" if isinstance(residuals, dict) else "residuals", (None, 2))
            for k, v in sets.items()}
    if axes is None:
        _, axes = plt.subplots(1, 2, figsize=(8.5, 3.0), layout="constrained")
    axes = np.asarray(axes).reshape(-1)
    if axes.shape != (2,):
        raise ValueError("axes must hold exactly two axes (range, bearing)")
    first = next(iter(sets.values()))
    lims = [np.quantile(np.abs(np.concatenate([s[:, c] for s in sets.values()])), 0.995) * 1.1 + 1e-9 for c in (0, 1)]
    for c, ax, unit in ((0, axes[0], "range residual [m]"), (1, axes[1], "bearing residual [rad]")):
        edges = np.linspace(-lims[c], lims[c], int(bins) + 1)
        for col, (name, s) in zip(_CYCLE * 4, sets.items()):
            ax.hist(np.clip(s[:, c], -lims[c], lims[c]), bins=edges, color=col, alpha=0.5,
                    label=f"{name} (std {s[:, c].std():.3g})")
        if Q is not None:
            Qm = as_covariance(Q, "Q", 2)
            sd = float(np.sqrt(Qm[c, c]))
            g = np.linspace(edges[0], edges[-1], 400)
            scale = first.shape[0] * (edges[1] - edges[0])
            ax.plot(g, scale * np.exp(-0.5 * (g / sd) ** 2) / (sd * np.sqrt(2 * np.pi)), color="k", lw=1.2,
                    label=f"N(0, {sd:.3g}$^2$) of Q")
        ax.set_xlabel(unit)
        ax.legend(fontsize=7, loc="upper left")
    axes[0].set_ylabel("sightings")
    return axes


def plot_nees_runs(t, nees, *, dof=3, p=0.95, window=None, axes=None, title=None):
    """NEES over time of several runs, one panel each, with the chi-square band of a consistent filter.

    Parameters
    ----------
    t : ndarray, shape (T,) or dict of str to ndarray, shape (T_k,)
        Times (seconds), shared or per run.
    nees : dict of str to ndarray, shape (T,) or dict of str to dict of str to ndarray
        ``{run: nees}``, or ``{run: {label: nees}}`` to compare settings on
        the same run (e.g. before and after a recalibration).
    dof : int, keyword-only
        Dimension of the state whose NEES is drawn (3 for a pose).
    p : float, keyword-only
        Probability inside the band: ``[chi2.ppf((1-p)/2, dof), chi2.ppf((1+p)/2, dof)]``
        (:func:`slamlib.nees_band` with one run).
    window : int, optional, keyword-only
        Also draw the moving average over this many steps.
    axes : sequence of matplotlib.axes.Axes, optional, keyword-only
        One axes per run; a new figure (runs stacked) if omitted.
    title : str, optional, keyword-only
        Figure title.

    Returns
    -------
    list of matplotlib.axes.Axes

    References
    ----------
    Bar-Shalom, Li & Kirubarajan (2001), Sec. 5.4.2 (NEES and its chi-square
    acceptance region).
    """
    import matplotlib.pyplot as plt

    from ..metrics import nees_band

    if not isinstance(nees, dict) or not nees:
        raise TypeError("nees must be a non-empty dict mapping a run name to NEES values (or to a dict of them)")
    runs = {str(k): (v if isinstance(v, dict) else {"": v}) for k, v in nees.items()}
    lo, hi = nees_band(dof, 1, p)
    if axes is None:
        fig, axes = plt.subplots(len(runs), 1, figsize=(7.5, 1.5 + 1.3 * len(runs)), sharex=True,
                                 layout="constrained", squeeze=False)
        axes = list(axes[:, 0])
        if title:
            fig.suptitle(title)
    elif len(axes) != len(runs):
        raise ValueError(f"axes must hold one axes per run ({len(runs)}), got {len(axes)}")
    for k, (ax, (name, series)) in enumerate(zip(axes, runs.items())):
        tk = as_array(t[name] if isinstance(t, dict) else t, "t", (None,))
        ax.axhspan(lo, hi, color="0.85", zorder=0, label=f"{p:.0%} band of $\\chi^2_{dof}$" if k == 0 else None)
        ax.axhline(dof, color="0.4", lw=0.8, ls="--")
        for i, (label, v) in enumerate(series.items()):
            v = as_array(v, f"nees[{name!r}]", (tk.shape[0],))
            c = _CYCLE[i % len(_CYCLE)]
            ax.plot(tk, v, color=c, lw=0.6, alpha=0.35 if window else 1.0)
            if window:
                avg = np.convolve(v, np.ones(window) / window, mode="same")
                ax.plot(tk, avg, color=c, lw=1.2, label=(label or None) if k == 0 else None)
            elif k == 0 and label:
                ax.lines[-1].set_label(label)
            ax.text(1.01, 0.85 - 0.2 * i, f"{label + ': ' if label else ''}mean {v.mean():.1f}", color=c,
                    transform=ax.transAxes, fontsize=8, va="top")
        ax.set_yscale("log")
        ax.set_ylim(0.05, None)
        ax.set_ylabel(name, fontsize=9)
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper left", fontsize=7, ncol=3)
    axes[-1].set_xlabel("time [s]")
    return axes
