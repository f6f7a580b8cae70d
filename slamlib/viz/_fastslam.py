"""Plots for the FastSLAM chapter: particles with their maps, weights and ESS, path diversity.

matplotlib is imported inside the functions only. Every function that draws on
one axes takes an optional ``ax`` and returns it; functions that draw several
panels take an optional ``axes`` and return the array of axes.
"""

from __future__ import annotations

import numpy as np

from .._checks import as_array, as_scalar, check_type
from . import _core
from ._core import TRUTH_COLOR, _axes

__all__ = [
    "plot_fastslam_particles",
    "plot_fastslam_run",
    "plot_fastslam_diagnostics",
    "plot_weight_comparison",
    "plot_fastslam_vs_ekf",
]

_EST_COLOR = "C0"
_BEST_COLOR = "C2"



def _panels(axes, n, figsize):
    import matplotlib.pyplot as plt

    if axes is None:
        _, axes = plt.subplots(1, n, figsize=figsize, layout="constrained")
    return np.atleast_1d(axes)


def _finish(ax, title, legend):
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    if title:
        ax.set_title(title)
    if legend:
        ax.legend(loc="upper right", fontsize=8, framealpha=0.85)
    return ax


def plot_fastslam_particles(state, *, landmarks=None, x_true=None, n_std=2.0, max_maps=60, n_ellipses=1, zoom=True,
                            ax=None, title=None, legend=True):
    """A FastSLAM particle set: every particle's pose and its own map.

    Parameters
    ----------
    state : FastSLAMState
        The particle set (for instance ``FastSLAMResult.state``).
    landmarks : ndarray, shape (N, 2), optional
        True landmark positions.
    x_true : ndarray, shape (T+1, 3), optional
        True path.
    n_std : float, keyword-only
        Landmark ellipses enclose `n_std` standard deviations.
    max_maps : int, keyword-only
        Draw the landmark means of at most this many particles (the most
        likely ones).
    n_ellipses : int, keyword-only
        Draw the landmark ellipses of this many particles (the most likely
        ones, the first in green, the others in grey).
    zoom : bool or tuple (x, y, half_width), keyword-only
        ``True``: limit the axes to the particles and the landmarks they have
        seen (with a 2 m margin). A tuple: show the square of half-width
        `half_width` around ``(x, y)``. ``False``: automatic limits.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    title : str, optional
        Axes title.
    legend : bool, keyword-only
        Draw a legend.

    Returns
    -------
    matplotlib.axes.Axes

    Notes
    -----
    Pose dots are sized by weight. Each particle's landmark means form a
    small cloud around each landmark: the spread of those clouds is the map
    uncertainty that comes from the path, which FastSLAM keeps in the particle
    set rather than in any one particle's covariances.

    References
    ----------
    Thrun, Burgard & Fox (2005), Chapter 13 (particles, each with its own
    map); course text, Eq. 17.4.
    """
    from ..fastslam import FastSLAMState

    state = check_type(state, FastSLAMState, "state")
    ax = _axes(ax, (6.0, 6.0))
    w = np.exp(state.log_weights - state.log_weights.max())
    order = np.argsort(-w)
    if landmarks is not None:
        _core.plot_landmarks(as_array(landmarks, "landmarks", (None, 2)), ax=ax)
    if x_true is not None:
        xt = as_array(x_true, "x_true", (None, 3))
        ax.plot(xt[:, 0], xt[:, 1], color=TRUTH_COLOR, lw=1.0, label="true path")
    shown = order[:max(int(max_maps), 1)]
    pts = np.concatenate([state.mu[k][state.seen[k]] for k in shown])
    ax.scatter(pts[:, 0], pts[:, 1], s=4, color=_EST_COLOR, alpha=0.5, lw=0, zorder=3,
               label=f"landmark means of {shown.size} particles")
    _core.plot_particles(state.poses, w, ax=ax, color="0.25", alpha=0.6, label="particle poses (area: weight)")
    for rank, k in enumerate(order[:max(int(n_ellipses), 1)]):
        color, lw = (_BEST_COLOR, 1.0) if rank == 0 else ("0.5", 0.6)
        for m, P in zip(state.mu[k][state.seen[k]], state.Sigma[k][state.seen[k]]):
            _core.plot_covariance_ellipse(m, P, n_std=n_std, ax=ax, color=color, lw=lw, zorder=2 if rank else 3)
    ax.plot([], [], color=_BEST_COLOR, lw=1.0, label=rf"most likely particle's map, ${n_std:g}\sigma$")
    if n_ellipses > 1:
        ax.plot([], [], color="0.5", lw=0.6, label=f"maps of the next {int(n_ellipses) - 1} particles")
    if zoom is True:
        box = np.vstack([state.poses[:, :2], pts])
        lo, hi = box.min(axis=0) - 2.0, box.max(axis=0) + 2.0
    elif zoom:
        cx, cy, half = (float(v) for v in zoom)
        lo, hi = np.array([cx - half, cy - half]), np.array([cx + half, cy + half])
    if zoom:
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_aspect("equal", adjustable="box")
    return _finish(ax, title, legend)


def plot_fastslam_run(run, result, *, n_std=2.0, label="FastSLAM", ax=None, title=None, legend=True):
    """A FastSLAM run: true and estimated paths, and the most likely particle's map.

    Parameters
    ----------
    run : LandmarkRun
        Ground truth (:func:`slamlib.simulate_landmark_run`).
    result : FastSLAMResult
        From :func:`slamlib.run_fastslam`.
    n_std : float, keyword-only
        Landmark ellipses enclose `n_std` standard deviations.
    label : str, keyword-only
        Name of the filter in the legend.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    title : str, optional
        Axes title.
    legend : bool, keyword-only
        Draw a legend.

    Returns
    -------
    matplotlib.axes.Axes

    Notes
    -----
    Two path estimates are drawn: the weighted mean of the particles at each
    step (a filtering estimate) and the whole path of the final most likely
    particle (a sample of FastSLAM's path posterior, smooth because it is one
    particle's own history).

    References
    ----------
    Thrun, Burgard & Fox (2005), Chapter 13; course text, Algorithm 3.
    """
    ax = _axes(ax, (6.0, 6.0))
    _core.plot_landmarks(run.landmarks, ax=ax)
    ax.plot(run.x_true[:, 0], run.x_true[:, 1], color=TRUTH_COLOR, lw=1.2, label="true path")
    x = as_array(result.x_est, "result.x_est", (None, 3))
    p = as_array(result.path_best, "result.path_best", x.shape)
    ax.plot(x[:, 0], x[:, 1], color=_EST_COLOR, lw=1.2, ls="--", label=f"{label}: weighted mean")
    ax.plot(p[:, 0], p[:, 1], color=_BEST_COLOR, lw=1.0, ls="-.", label=f"{label}: path of the best particle")
    seen = np.asarray(result.seen, dtype=bool)
    for m, P in zip(result.landmarks[seen], result.landmark_cov[seen]):
        _core.plot_covariance_ellipse(m, P, n_std=n_std, ax=ax, color=_BEST_COLOR, lw=1.0)
    ax.scatter(result.landmarks[seen, 0], result.landmarks[seen, 1], s=12, color=_BEST_COLOR, zorder=4,
               label=rf"its map, ${n_std:g}\sigma$")
    _core.plot_pose(p[-1], ax=ax, color=_BEST_COLOR)
    return _finish(ax, title, legend)


def plot_fastslam_diagnostics(results, labels, *, n_particles, dt=1.0, panels=("ess", "ancestors"), ess_steps=None,
                              axes=None):
    """Effective sample size and path diversity over time, for several runs.

    Parameters
    ----------
    results : sequence of FastSLAMResult
        From :func:`slamlib.run_fastslam`.
    labels : sequence of str
        Legend entries.
    n_particles : int or sequence of int, keyword-only
        Number of particles of each run (both quantities are shown as a
        fraction of it).
    dt : float, keyword-only
        Step duration (seconds); ``1`` labels the axis in steps.
    panels : sequence of {"ess", "ancestors"}, keyword-only
        Which panels to draw, in this order.
    ess_steps : ndarray of int, optional, keyword-only
        Steps (0-based update indices) at which to show the ESS, e.g. only
        the steps that had measurements; default all.
    axes : array of matplotlib.axes.Axes, optional
        One axes per panel; a new figure if omitted.

    Returns
    -------
    ndarray of matplotlib.axes.Axes
        ``"ess"``: ESS / M after each update (log scale). ``"ancestors"``: the
        number of distinct ancestors, at each time, of the final particles'
        paths: going back in time the lineages merge, and the early path (with
        the map built along it) rests on fewer and fewer hypotheses.

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 4.3 (particle deprivation) and
    Chapter 13 (FastSLAM's loss of path diversity).
    """
    panels = tuple(panels)
    if not panels or any(p not in ("ess", "ancestors") for p in panels):
        raise ValueError(f"panels must be a non-empty sequence of 'ess' and 'ancestors', got {panels!r}")
    axes = _panels(axes, len(panels), (5.0 * len(panels), 3.4))
    ax_of = dict(zip(panels, axes))
    ns = np.broadcast_to(np.asarray(n_particles), (len(results),))
    unit = "time [s]" if dt != 1.0 else "step"
    for k, (res, lab, n) in enumerate(zip(results, labels, ns)):
        n = as_scalar(n, "n_particles", positive=True)
        if "ess" in ax_of:
            ess = np.asarray(res.ess)
            steps = np.arange(ess.size) if ess_steps is None else np.asarray(ess_steps)
            ax_of["ess"].plot((steps + 1) * dt, ess[steps] / n, color=f"C{k}", lw=1.0, marker=".", ms=3,
                              label=lab)
        if "ancestors" in ax_of:
            anc = np.asarray(res.n_ancestors)
            ax_of["ancestors"].step(np.arange(anc.size) * dt, anc / n, where="post", color=f"C{k}", lw=1.4,
                                    label=lab)
    if "ess" in ax_of:
        ax = ax_of["ess"]
        ax.set_yscale("log")
        ax.set_xlabel(unit)
        ax.set_ylabel("ESS / M")
        ax.legend(fontsize=8, loc="lower left")
    if "ancestors" in ax_of:
        ax = ax_of["ancestors"]
        ax.set_yscale("log")
        ax.set_xlabel(unit)
        ax.set_ylabel("distinct ancestors / M")
        ax.set_title("poses on the final particles' paths", fontsize=9)
        ax.legend(fontsize=8, loc="upper left")
    return axes


def plot_weight_comparison(pose, mu, w_S, w_text, *, landmark=None, lam=None, ess_S=None, ess_text=None, theory=None,
                           axes=None):
    """The importance weight with ``S`` and the course text's printed weight, and what they do to the ESS.

    Parameters
    ----------
    pose : ndarray, shape (3,)
        The robot pose shared by the particles of the experiment.
    mu : ndarray, shape (M, 2)
        Each particle's landmark mean.
    w_S, w_text : ndarray, shape (M,)
        Their weights ``N(nu; 0, S)`` and the course text's
        ``|2 pi S|^-1/2 exp(-1/2 nu^T Q^-1 nu)`` (any scale).
    landmark : ndarray, shape (2,), optional
        True landmark position.
    lam : ndarray, shape (L,), optional
        Ratios ``lambda`` of landmark to sensor uncertainty for the right panel.
    ess_S, ess_text : ndarray, shape (L,), optional
        Measured ESS / M for each ``lambda``.
    theory : tuple of 3 ndarrays, optional
        ``(lam_grid, ess_S_theory, ess_text_theory)`` curves for the right panel.
    axes : array of 3 matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.

    Returns
    -------
    ndarray of matplotlib.axes.Axes
        Landmark hypotheses shaded by their normalised weight (with ``S``,
        with the text's formula), and ESS / M against ``lambda``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 13.1 lines 14-18.
    """
    mu = as_array(mu, "mu", (None, 2))
    w_S = as_array(w_S, "w_S", (mu.shape[0],))
    w_text = as_array(w_text, "w_text", (mu.shape[0],))
    pose = as_array(pose, "pose", (3,))
    axes = _panels(axes, 3, (12.0, 3.9))
    names = (r"$N(\nu; 0, S)$, $S = H\Sigma H^T + Q$", r"$|2\pi S|^{-1/2} e^{-\nu^T Q^{-1} \nu / 2}$ (course text)")
    for ax, w, name in zip(axes[:2], (w_S, w_text), names):
        wn = w / w.max()
        order = np.argsort(wn)
        sc = ax.scatter(mu[order, 0], mu[order, 1], c=wn[order], s=5, cmap="viridis", vmin=0, vmax=1, lw=0)
        if landmark is not None:
            lm = as_array(landmark, "landmark", (2,))
            ax.plot(*lm, marker="*", color=TRUTH_COLOR, ms=12, ls="none", label="true landmark")
            ax.legend(fontsize=8, loc="upper left")
        ess = w.sum() ** 2 / (w**2).sum() / w.size
        ax.set_title(f"{name}\nESS / M = {ess:.2f}", fontsize=9)
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
    import matplotlib.pyplot as plt

    plt.colorbar(sc, ax=axes[1], label="weight / max weight", shrink=0.85)
    ax = axes[2]
    if theory is not None:
        grid, tS, tT = (as_array(a, "theory", ndim=1) for a in theory)
        ax.plot(grid, tS, color="C0", lw=1.2, label="theory, S")
        ax.plot(grid, tT, color="C1", lw=1.2, label="theory, course text")
    if lam is not None:
        lam = as_array(lam, "lam", ndim=1)
        if ess_S is not None:
            ax.plot(lam, as_array(ess_S, "ess_S", lam.shape), "o", color="C0", ms=5, label="measured, S")
        if ess_text is not None:
            ax.plot(lam, as_array(ess_text, "ess_text", lam.shape), "s", color="C1", ms=5, label="measured, text")
    ax.set_xscale("log")
    ax.set_ylim(0, 1.02)
    ax.set_xlabel(r"$\lambda$: landmark variance / sensor variance, along the line of sight")
    ax.set_ylabel("ESS / M after one update")
    ax.legend(fontsize=8, loc="lower left")
    return axes


def plot_fastslam_vs_ekf(run, fastslam, ekf, *, labels=("FastSLAM", "EKF SLAM"), dt=None, axes=None):
    """FastSLAM and EKF SLAM on the same run: paths and maps, and position error over time.

    Parameters
    ----------
    run : LandmarkRun
        Ground truth.
    fastslam : FastSLAMResult
        From :func:`slamlib.run_fastslam`.
    ekf : EKFSLAMResult
        From :func:`slamlib.run_ekf_slam`.
    labels : tuple of 2 str, keyword-only
        Legend names of the two filters.
    dt : float, optional, keyword-only
        Step duration for the time axis (default ``run.dt``).
    axes : array of 2 matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.

    Returns
    -------
    ndarray of matplotlib.axes.Axes

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 10.1 and Table 13.1; course text,
    Algorithms 1 and 3.
    """
    axes = _panels(axes, 2, (11.5, 4.6))
    ax = axes[0]
    _core.plot_landmarks(run.landmarks, ax=ax)
    ax.plot(run.x_true[:, 0], run.x_true[:, 1], color=TRUTH_COLOR, lw=1.2, label="true path")
    xf = as_array(fastslam.x_est, "fastslam.x_est", (None, 3))
    xe = as_array(ekf.x, "ekf.x", xf.shape)
    ax.plot(xf[:, 0], xf[:, 1], color="C0", lw=1.1, ls="--", label=labels[0])
    ax.plot(xe[:, 0], xe[:, 1], color="C1", lw=1.1, ls="-.", label=labels[1])
    seen = np.asarray(fastslam.seen, dtype=bool)
    ax.scatter(fastslam.landmarks[seen, 0], fastslam.landmarks[seen, 1], s=16, marker="o", facecolor="none",
               edgecolor="C0", label=f"{labels[0]} map")
    ax.scatter(ekf.landmarks[:, 0], ekf.landmarks[:, 1], s=16, marker="x", color="C1", label=f"{labels[1]} map")
    _finish(ax, None, True)
    ax = axes[1]
    step = run.dt if dt is None else as_scalar(dt, "dt", positive=True)
    t = np.arange(xf.shape[0]) * step
    true = np.asarray(run.x_true)
    ax.plot(t, np.linalg.norm(xf[:, :2] - true[:, :2], axis=1), color="C0", lw=1.1, label=labels[0])
    ax.plot(t, np.linalg.norm(xe[:, :2] - true[:, :2], axis=1), color="C1", lw=1.1, label=labels[1])
    ax.set_xlabel("time [s]")
    ax.set_ylabel("position error [m]")
    ax.legend(fontsize=8)
    return axes
