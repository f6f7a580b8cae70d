"""Plots for Monte Carlo localization: particle clouds over a map, scans drawn
from a pose, a run's spread and particle count, Augmented MCL's averages, and
an animation of a run.

matplotlib is imported inside the functions only (through ``_core``).

References
----------
Thrun, Burgard & Fox, *Probabilistic Robotics* (2005), Ch. 8 (Figs. 8.11-8.13:
MCL on a real map; Fig. 8.15: KLD-sampling's sample set size); Ch. 6 (beam
model and likelihood field compared along pose offsets).
"""

from __future__ import annotations

import numpy as np

from .._checks import as_array, as_scalar
from ._core import _axes, animate, plot_grid, plot_particles, plot_pose

__all__ = [
    "plot_mcl_particles",
    "plot_scan_endpoints",
    "plot_mcl_run",
    "plot_augmented_averages",
    "plot_position_error",
    "plot_likelihood_profiles",
    "animate_mcl",
]


def _window(ax, center, half_width):
    if center is not None and half_width is not None:
        c = as_array(center, "center", ndim=1)[:2]
        h = as_scalar(half_width, "half_width", positive=True)
        ax.set_xlim(c[0] - h, c[0] + h)
        ax.set_ylim(c[1] - h, c[1] + h)


def _poses_of(particles):
    poses = getattr(particles, "poses", particles)
    return as_array(poses, "particles", (None, 3))


def plot_mcl_particles(grid, particles, ax=None, *, mean=None, center=None, half_width=None, max_points=5000,
                       color="C3", title=None):
    """Particles of an MCL filter drawn over the occupancy grid.

    Parameters
    ----------
    grid : OccupancyGrid
        The map.
    particles : MCLState or ndarray, shape (M, 3)
        The particle set (weights are not drawn: after resampling they are equal).
    ax : matplotlib.axes.Axes, optional
        Axes to draw on (default: a new figure).
    mean : ndarray, shape (3,), keyword-only, optional
        The filter's estimate, drawn as a pose.
    center : ndarray, shape (2,) or (3,), keyword-only, optional
        Centre of a zoom window (with `half_width`).
    half_width : float, keyword-only, optional
        Half side of the zoom window [m].
    max_points : int, keyword-only
        At most this many particles are drawn (every k-th), to keep figures light.
    color : color, keyword-only
        Particle colour.
    title : str, keyword-only, optional
        Axes title.

    Returns
    -------
    matplotlib.axes.Axes

    References
    ----------
    Thrun, Burgard & Fox (2005), Fig. 8.11 (global localization in an
    occupancy grid map).
    """
    poses = _poses_of(particles)
    ax = _axes(ax)
    plot_grid(grid, ax)
    step = max(1, int(np.ceil(poses.shape[0] / max(1, int(max_points)))))
    plot_particles(poses[::step], ax=ax, color=color, s=3.0, alpha=0.5, zorder=3)
    # plot_particles leaves adjustable="datalim", with which matplotlib overrides (and warns about)
    # limits set on both axes, as a zoom window does; "box" keeps the map's aspect and the limits
    ax.set_aspect("equal", adjustable="box")
    if mean is not None:
        plot_pose(as_array(mean, "mean", (3,)), ax=ax, color="C0", zorder=4)
    if center is None and half_width is not None:
        center = poses[:, :2].mean(axis=0)
    _window(ax, center, half_width)
    if title is not None:
        ax.set_title(title)
    return ax


def plot_scan_endpoints(pose, ranges, angles, ax=None, *, z_max=np.inf, sensor_offset=0.25, rays=False, **kw):
    """End points of a laser scan as seen from a pose (e.g. the MCL estimate).

    If the pose is right, the points fall on the map's walls.

    Parameters
    ----------
    pose : ndarray, shape (3,)
        Robot pose ``[x, y, theta]``.
    ranges : ndarray, shape (K,)
        Ranges [m].
    angles : ndarray, shape (K,)
        Beam angles in the laser frame [rad].
    ax : matplotlib.axes.Axes, optional
        Axes to draw on (default: a new figure).
    z_max : float, keyword-only
        Readings at or beyond it are not drawn.
    sensor_offset : float, keyword-only
        Forward offset of the laser [m].
    rays : bool, keyword-only
        Also draw the beams as thin lines from the sensor.
    **kw
        Passed to ``ax.scatter``.

    Returns
    -------
    matplotlib.axes.Axes

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 6.3 lines 4-5 (end point of a beam).
    """
    from ..mcl import scan_endpoints

    pose = as_array(pose, "pose", (3,))
    pts = scan_endpoints(pose, ranges, angles, z_max=z_max, sensor_offset=sensor_offset)
    ax = _axes(ax)
    if rays:
        s = pose[:2] + sensor_offset * np.array([np.cos(pose[2]), np.sin(pose[2])])
        for p in pts:
            ax.plot([s[0], p[0]], [s[1], p[1]], color="C1", lw=0.3, alpha=0.5)
    kw.setdefault("s", 6)
    kw.setdefault("color", "C1")
    kw.setdefault("zorder", 5)
    kw.setdefault("label", "scan end points")
    ax.scatter(pts[:, 0], pts[:, 1], **kw)
    return ax


def plot_mcl_run(results, axes=None, *, labels=None, converged=0.5):
    """Spread and particle count of one or more MCL runs over time.

    Parameters
    ----------
    results : MCLResult or sequence of MCLResult
        Runs of :func:`~slamlib.mcl.run_mcl`.
    axes : sequence of 2 matplotlib.axes.Axes, optional
        Axes for the spread (log scale) and the particle count; a new figure
        if omitted.
    labels : sequence of str, optional
        Legend labels, one per run.
    converged : float, keyword-only
        Spread [m] drawn as a dashed line (the convergence threshold).

    Returns
    -------
    ndarray of matplotlib.axes.Axes, shape (2,)

    References
    ----------
    Thrun, Burgard & Fox (2005), Fig. 8.15 (sample set size of KLD-sampling
    during global localization).
    """
    import matplotlib.pyplot as plt

    runs = [results] if hasattr(results, "spread") else list(results)
    labels = [None] * len(runs) if labels is None else list(labels)
    if len(labels) != len(runs):
        raise ValueError(f"labels must have one entry per run ({len(runs)}), got {len(labels)}")
    if axes is None:
        _, axes = plt.subplots(1, 2, figsize=(10, 3.2))
    axes = np.asarray(axes)
    for k, (r, lab) in enumerate(zip(runs, labels)):
        axes[0].semilogy(r.t - r.t[0], np.maximum(r.spread, 1e-3), color=f"C{k}", label=lab)
        axes[1].plot(r.t - r.t[0], r.n_particles, color=f"C{k}", label=lab)
    axes[0].axhline(converged, color="k", ls="--", lw=0.8)
    axes[0].set_xlabel("time [s]")
    axes[0].set_ylabel("spread [m]")
    axes[1].set_xlabel("time [s]")
    axes[1].set_ylabel("number of particles")
    axes[1].set_ylim(bottom=0)
    if any(lab is not None for lab in labels):
        axes[0].legend()
    return axes


def plot_augmented_averages(result, ax=None):
    """Augmented MCL's averages ``w_avg``, ``w_slow``, ``w_fast`` (log scale) and the new particles.

    Parameters
    ----------
    result : MCLResult
        A run of :func:`~slamlib.mcl.run_mcl`.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on (a new figure if omitted); the number of new particles
        goes on a twin axis.

    Returns
    -------
    matplotlib.axes.Axes

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 8.3.
    """
    ax = _axes(ax)
    t = result.t - result.t[0]
    ax.plot(t, result.log_w_avg, color="0.6", lw=0.8, label=r"$\log w_\mathrm{avg}$")
    ax.plot(t, result.log_w_slow, color="C0", label=r"$\log w_\mathrm{slow}$")
    ax.plot(t, result.log_w_fast, color="C1", label=r"$\log w_\mathrm{fast}$")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("log average likelihood (tempered)")
    tw = ax.twinx()
    tw.bar(t, result.n_injected, width=0.4, color="C3", alpha=0.4, label="new particles")
    tw.set_ylabel("new particles", color="C3")
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = tw.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, loc="upper right", fontsize=8)
    return ax


def plot_position_error(t, errors, ax=None, *, ylabel="distance [m]", log=True):
    """Position errors (or distances to a reference) of several runs over time.

    Parameters
    ----------
    t : dict of str to ndarray, shape (S_i,), or ndarray, shape (S,)
        Times [s] per run (or one time axis shared by all).
    errors : dict of str to ndarray, shape (S_i,)
        Errors [m] of each run, keyed by label.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on (default: a new figure).
    ylabel : str, keyword-only
        Label of the y axis.
    log : bool, keyword-only
        Logarithmic y axis.

    Returns
    -------
    matplotlib.axes.Axes

    References
    ----------
    Thrun, Burgard & Fox (2005), Fig. 8.13 (localization error of MCL variants).
    """
    ax = _axes(ax)
    for k, (lab, e) in enumerate(errors.items()):
        tt = t[lab] if isinstance(t, dict) else t
        tt = as_array(tt, "t", ndim=1)
        e = as_array(e, "errors", tt.shape)
        (ax.semilogy if log else ax.plot)(tt, np.maximum(e, 1e-3) if log else e, color=f"C{k}", label=lab)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(ylabel)
    ax.legend()
    return ax


def plot_likelihood_profiles(offsets, profiles, axes=None, *, xlabels=None, titles=None):
    """Scan log-likelihood along pose offsets, one panel per offset direction.

    Every curve is shifted so that its maximum is 0, which compares the shapes
    (width, smoothness, local maxima) of several measurement models.

    Parameters
    ----------
    offsets : sequence of ndarray, shape (N_p,)
        Offsets of each panel ``p`` (e.g. along-track [m], cross-track [m],
        heading [deg]).
    profiles : dict of str to sequence of ndarray, shape (N_p,)
        Log-likelihoods of each model (key: legend label), one array per
        panel, evaluated at the offsets.
    axes : sequence of matplotlib.axes.Axes, optional
        One axes per panel; a new row of panels if omitted.
    xlabels, titles : sequence of str, keyword-only, optional
        Axis label and title of each panel.

    Returns
    -------
    ndarray of matplotlib.axes.Axes, shape (P,)

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 6.4 (the likelihood field is smooth in
    the pose, the beam model is not).
    """
    import matplotlib.pyplot as plt

    offs = [as_array(o, "offsets", ndim=1) for o in offsets]
    n = len(offs)
    if axes is None:
        _, axes = plt.subplots(1, n, figsize=(3.4 * n, 3.0), layout="constrained")
    axes = np.atleast_1d(np.asarray(axes, dtype=object))
    if axes.size != n:
        raise ValueError(f"axes must hold one axes per panel ({n}), got {axes.size}")
    for k, (label, curves) in enumerate(profiles.items()):
        curves = list(curves)
        if len(curves) != n:
            raise ValueError(f"profiles[{label!r}] must hold one curve per panel ({n}), got {len(curves)}")
        for p, (ax, o, c) in enumerate(zip(axes, offs, curves)):
            c = as_array(c, "profiles", o.shape, finite=False)
            ax.plot(o, c - np.max(c), color=f"C{k}", label=label if p == 0 else None)
    for p, ax in enumerate(axes):
        ax.axvline(0.0, color="k", lw=0.6, ls=":")
        if xlabels is not None:
            ax.set_xlabel(xlabels[p])
        if titles is not None:
            ax.set_title(titles[p], fontsize=10)
    axes[0].set_ylabel("log-likelihood - max")
    axes[0].legend(fontsize=8)
    return axes


def animate_mcl(grid, result, *, scans=None, angles=None, sensor_offset=0.25, z_max=np.inf, window=None,
                interval=300, dpi=60, figsize=(6.0, 4.2), max_points=3000):
    """Animate the snapshots of an MCL run over the map (HTML for the static book).

    Parameters
    ----------
    grid : OccupancyGrid
        The map.
    result : MCLResult
        A run of :func:`~slamlib.mcl.run_mcl` with ``snapshots`` stored; one
        frame per snapshot.
    scans : ndarray, shape (L, K), keyword-only, optional
        The log's scans; with `angles`, the scan of each frame is drawn from
        the filter's mean pose.
    angles : ndarray, shape (K,), keyword-only, optional
        Beam angles [rad].
    sensor_offset : float, keyword-only
        Forward offset of the laser [m].
    z_max : float, keyword-only
        Readings at or beyond it are not drawn.
    window : tuple of 4 float, keyword-only, optional
        ``(xmin, xmax, ymin, ymax)`` shown; the map's known part if omitted.
    interval : float, keyword-only
        Milliseconds between frames.
    dpi : float, keyword-only
        Resolution of the frames (keep it modest: every frame is embedded).
    figsize : tuple of 2 float, keyword-only
        Figure size in inches.
    max_points : int, keyword-only
        At most this many particles are drawn per frame.

    Returns
    -------
    IPython.display.HTML
        The animation with play controls (``slamlib.viz.animate``).

    References
    ----------
    Thrun, Burgard & Fox (2005), Fig. 8.11 (global localization, a sequence
    of particle sets).
    """
    import matplotlib.pyplot as plt

    if not result.snapshots:
        raise ValueError("result has no snapshots: run run_mcl with snapshots=N")
    if window is None:
        known = np.argwhere(~np.isnan(grid.occupancy))
        lo = grid.cell_to_world(known.min(axis=0))
        hi = grid.cell_to_world(known.max(axis=0))
        window = (lo[0], hi[0], lo[1], hi[1])
    fig, ax = plt.subplots(figsize=figsize)
    steps = list(result.snapshot_steps)

    def update(i):
        ax.clear()
        s = steps[i]
        plot_mcl_particles(grid, result.snapshots[i], ax, mean=result.mean[s], max_points=max_points)
        if scans is not None and angles is not None:
            plot_scan_endpoints(result.mean[s], scans[result.scan_index[s]], angles, ax, z_max=z_max,
                                sensor_offset=sensor_offset, s=3)
        ax.set_xlim(window[0], window[1])
        ax.set_ylim(window[2], window[3])
        ax.set_title(f"t = {result.t[s] - result.t[0]:5.1f} s   M = {result.n_particles[s]}   "
                     f"spread = {result.spread[s]:.2f} m", fontsize=9)

    fig.tight_layout()
    alt = (f"Monte Carlo localization in {len(steps)} frames: the particles (dots) on the map, the mean pose"
           + (" and the laser scan drawn from it" if scans is not None and angles is not None else "")
           + "; each frame's title gives the time, the number of particles and their spread.")
    return animate(fig, update, len(steps), alt=alt, interval=interval, dpi=dpi)
